"""BVH reader and writer: real files, round trips, bvhio cross-check, bad input, fuzzing."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from skincap.errors import (
    FormatError,
    OutputExistsError,
    SkincapError,
    UnitWarning,
    ValidationError,
)
from skincap.geometry.kinematics import joint_positions
from skincap.io.bvh import BVH_UNITS, guess_bvh_units, read_bvh, write_bvh
from skincap.types import Motion, Skeleton

DATA = Path(__file__).parents[1] / "data"
CMU = DATA / "cmu_131_01_bvh11.bvh"
MOCAPBANK = DATA / "bvhtoolbox_test_mocapbank.bvh"
MAKEHUMAN = DATA / "makehuman_tpose.bvh"
REAL = [
    (CMU, {"units": "cmu"}),
    (MOCAPBANK, {"units": "cm"}),
    (MAKEHUMAN, {"units": "dm", "up": "z", "position_channels": "add"}),
]

SMALL = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Spine
  {
    OFFSET 0 10 0
    CHANNELS 3 Xrotation Yrotation Zrotation
    End Site
    {
      OFFSET 0 50 0
    }
  }
  JOINT Leg
  {
    OFFSET 10 -5 0
    CHANNELS 4 Yposition Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -90 0
    }
  }
}
MOTION
Frames: 2
Frame Time: .0083333
1 95 2 0 0 0 0 0 90 -5 30 0 0
1 95 2 10 20 30 5 6 7 -5 0 90 45
"""
# 6 + 3 + 4 = 13 channels


def height(motion: Motion) -> float:
    p = joint_positions(motion)[0]
    return float((p.max(axis=0) - p.min(axis=0)).max())


def write_text(tmp_path: Path, text: str | bytes, name: str = "x.bvh") -> Path:
    p = tmp_path / name
    if isinstance(text, bytes):
        p.write_bytes(text)
    else:
        p.write_text(text)
    return p


# ------------------------------------------------------------------ real files
def test_cmu_file() -> None:
    m = read_bvh(CMU, units="cmu")
    assert m.rotations.shape == (994, 38, 4)
    assert m.skeleton.n_joints == 38 and sum(1 for c in m.channels if not c) == 7
    assert m.channels[0] == (
        "Xposition",
        "Yposition",
        "Zposition",
        "Zrotation",
        "Yrotation",
        "Xrotation",
    )
    assert m.meta["frame_time"] == 0.0083333 and m.meta["frame_time_text"] == ".0083333"
    assert m.rate == 1.0 / 0.0083333  # exact, not rounded to 120
    assert m.skeleton.names[6] == "LeftToe_end" and m.skeleton.parents[6] == 5
    # first row: root at (5.23, 16.9002, -33.8986) CMU units
    np.testing.assert_allclose(
        m.translations[0, 0], np.array([5.23, 16.9002, -33.8986]) * BVH_UNITS["cmu"]
    )
    # a walking adult: feet near the floor, head about 1.4 m up
    p = joint_positions(m)
    assert -0.1 < p[..., 1].min() < 0.05
    assert 1.3 < p[..., 1].max() < 1.7


def test_mocapbank_file_mixed_rotation_order() -> None:
    m = read_bvh(MOCAPBANK, units="cm")
    assert m.rotations.shape == (455, 24, 4)
    assert m.channels[1] == ("Zrotation", "Xrotation", "Yrotation")
    assert m.meta["frame_time_text"] == "0.033333"
    # joint "Chest" frame 0 values -7.98?  no: row = root 6 values then Chest Z X Y
    row = np.array([5.71, 17.50, -3.05])  # Chest: Zrot Xrot Yrot in degrees
    ref = Rotation.from_euler("ZXY", row, degrees=True).as_quat()
    got = m.rotations[0, 1]
    assert min(np.abs(got - ref).max(), np.abs(got + ref).max()) < 1e-12


def test_makehuman_tpose_is_a_tpose_with_add_convention() -> None:
    m = read_bvh(MAKEHUMAN, units="dm", up="z", position_channels="add")
    assert m.skeleton.n_joints == 173 + 49
    p = joint_positions(m)[0]
    extent = p.max(axis=0) - p.min(axis=0)
    # Y-up human 1.66 m tall with arms spread about 1.69 m along x
    assert 1.6 < extent[1] < 1.7 and 1.6 < extent[0] < 1.75 and extent[2] < 0.4
    # "replace" (the BVH norm) collapses this file: MakeHuman writes displacements
    replaced = read_bvh(MAKEHUMAN, units="dm", up="z", position_channels="replace")
    collapsed = joint_positions(replaced)[0]
    assert (collapsed.max(axis=0) - collapsed.min(axis=0)).max() < 0.3


@pytest.mark.parametrize(
    ("path", "kwargs", "unit"),
    [(CMU, {}, "cmu"), (MOCAPBANK, {}, "cm"), (MAKEHUMAN, {"up": "z"}, "dm")],
)
def test_unit_guess_warns_and_records(path: Path, kwargs: dict, unit: str) -> None:
    with pytest.warns(UnitWarning, match=rf"{path.name}.*guessed '{unit}'"):
        m = read_bvh(path, **kwargs)
    assert m.meta["source_units"] == unit and m.meta["units_guessed"] is True


@pytest.mark.parametrize(
    "path", [CMU, MOCAPBANK, MAKEHUMAN, DATA / "external" / "bvhpython_mixamo_walk.bvh"]
)
def test_unit_guess_states_the_height_info_reports(path: Path) -> None:
    # the warning's height is the standing (Y-up) extent info reports, not a T-pose's
    # arm span (the Mixamo rig: 1.94 m from fingertip to fingertip, 1.78 m tall)
    from skincap.evaluate.summary import summarize_motion

    with pytest.warns(UnitWarning) as record:
        m = read_bvh(path)
    message = next(str(w.message) for w in record if "units not given" in str(w.message))
    metres = float(message.split("(")[1].split(" m)")[0])
    assert "units tall" in message
    assert metres == pytest.approx(summarize_motion(m)["height_m"], abs=0.006)


def test_unit_guess_of_a_lying_skeleton_uses_its_largest_extent(tmp_path: Path) -> None:
    # read with the wrong up axis a standing figure lies: its extent along "up" is its
    # depth, so the guess falls back to the largest extent rather than a 10x unit
    text = SMALL.replace("OFFSET 0 10 0", "OFFSET 0 0 10").replace("OFFSET 0 50 0", "OFFSET 0 0 50")
    text = text.replace("OFFSET 0 -90 0", "OFFSET 0 0 -90").replace(
        "OFFSET 10 -5 0", "OFFSET 1 0 -5"
    )
    path = tmp_path / "lying.bvh"
    path.write_text(text)
    with pytest.warns(UnitWarning, match=r"guessed 'cm' from a skeleton 155 units across"):
        m = read_bvh(path, up="y")
    assert m.meta["source_units"] == "cm"


LOCAL_X_BONES = """HIERARCHY
ROOT Root
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT Hips
  {
    OFFSET 0 95 -450
    CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
    JOINT Spine
    {
      OFFSET 45 0 0
      CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 35 0 0
      }
    }
    JOINT UpperLeg_L
    {
      OFFSET -10 -8 0
      CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
      JOINT LowerLeg_L
      {
        OFFSET -45 0 0
        CHANNELS 3 Zrotation Xrotation Yrotation
        End Site
        {
          OFFSET -40 0 0
        }
      }
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0333333
0 0 0 0 0 0 0 95 -5 90 0 0 45 0 0 0 0 0 -10 -8 0 0 0 0 0 0 0
0 0 0 0 0 0 1 95 -5 90 0 0 45 0 0 10 0 0 -10 -8 0 0 0 0 0 0 0
"""


def test_unit_and_up_guess_read_the_first_frame_when_the_rest_pose_is_no_figure(
    tmp_path: Path,
) -> None:
    # Bandai-Namco's layout: bones along their local x, every joint with position
    # channels repeating its offset but the hips' (its rest offset 4.5 m from a root
    # joint at the origin); the first frame stands the figure 1.75 m along y
    path = tmp_path / "local_x.bvh"
    path.write_text(LOCAL_X_BONES)
    with pytest.warns(
        UnitWarning, match=r"guessed 'cm' from the first frame's pose 175 units tall"
    ):
        m = read_bvh(path)
    assert m.meta["up"] == "y" and m.meta["source_units"] == "cm"
    posed = joint_positions(m)[0]
    np.testing.assert_allclose(posed.max(axis=0) - posed.min(axis=0), [0.08, 1.75, 0.05], atol=1e-6)
    # info reports the height the warning states, not the rest pose's 0.95 m
    from skincap.evaluate.summary import summarize_motion

    assert m.meta["rest_pose_is_figure"] is False
    assert summarize_motion(m)["height_m"] == pytest.approx(1.75, abs=1e-6)


def test_guess_bvh_units_bands() -> None:
    assert guess_bvh_units(1.75) == "m"
    assert guess_bvh_units(17.5) == "dm"
    assert guess_bvh_units(175) == "cm"
    assert guess_bvh_units(1750) == "mm"
    assert guess_bvh_units(65) == "in"
    assert guess_bvh_units(24.3) == "cmu"
    assert guess_bvh_units(0.0) == "m"


def test_given_units_do_not_warn() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        m = read_bvh(MOCAPBANK, units="mm")
    assert m.meta["source_units"] == "mm" and m.meta["units_guessed"] is False
    np.testing.assert_allclose(m.skeleton.offsets[1], [-0.0001728, 0.010287, 0.0001254])


# ------------------------------------------------------------- bvhio cross-check
def bvhio_positions(path: Path, frames: list[int]) -> dict[str, np.ndarray]:
    bvhio = pytest.importorskip("bvhio")
    root = bvhio.readAsHierarchy(str(path))
    out: dict[str, list] = {}
    for f in frames:
        root.loadPose(f)
        for joint, _, _ in root.layout():
            out.setdefault(joint.Name, []).append(np.array(joint.PositionWorld, dtype=float))
    return {k: np.array(v) for k, v in out.items()}


@pytest.mark.parametrize("path", [CMU, MOCAPBANK])
def test_reader_agrees_with_bvhio(path: Path) -> None:
    frames = [0, 200, 450]
    m = read_bvh(path, units="m")  # metres = file units, as bvhio reports them
    ours = joint_positions(m)
    ref = bvhio_positions(path, frames)
    scale = height(m)
    for name, pos in ref.items():
        k = m.skeleton.index(name)
        # bvhio computes in float32
        np.testing.assert_allclose(ours[frames, k], pos, atol=2e-6 * scale)


def test_bvhio_reads_our_files(tmp_path: Path) -> None:
    m = read_bvh(CMU, units="cmu")
    out = tmp_path / "cmu.bvh"
    write_bvh(m, out)
    frames = [0, 500, 993]
    ref = bvhio_positions(out, frames)  # in the written unit (cmu)
    ours = joint_positions(m) / BVH_UNITS["cmu"]
    assert len(ref) == 31
    for name, pos in ref.items():
        np.testing.assert_allclose(pos, ours[frames, m.skeleton.index(name)], atol=2e-6 * 25)


# ----------------------------------------------------------------- round trips
def assert_same_motion(a: Motion, b: Motion, rel: float = 1e-6) -> None:
    assert a.skeleton.names == b.skeleton.names
    np.testing.assert_array_equal(a.skeleton.parents, b.skeleton.parents)
    assert a.channels == b.channels
    h = max(height(a), 1e-9)
    np.testing.assert_allclose(joint_positions(b), joint_positions(a), rtol=0, atol=rel * h)
    np.testing.assert_allclose(b.skeleton.offsets, a.skeleton.offsets, rtol=0, atol=rel * h)


@pytest.mark.parametrize(("path", "kwargs"), REAL)
def test_real_round_trip(tmp_path: Path, path: Path, kwargs: dict) -> None:
    m = read_bvh(path, **kwargs)
    out = tmp_path / "out.bvh"
    write_bvh(m, out)
    back = read_bvh(out, **kwargs)
    assert_same_motion(m, back)
    assert back.meta["frame_time_text"] == m.meta["frame_time_text"]
    assert back.rate == m.rate
    text = out.read_text()
    assert f"Frame Time: {m.meta['frame_time_text']}\n" in text
    # the layout is kept line for line
    orig = [
        ln.split()[:1] + ln.split()[2:] for ln in path.read_text().splitlines() if "CHANNELS" in ln
    ]
    new = [ln.split()[:1] + ln.split()[2:] for ln in text.splitlines() if "CHANNELS" in ln]
    assert orig == new
    assert text.count("End Site") == path.read_text().count("End Site")


def test_writer_restores_units_and_up_from_meta(tmp_path: Path) -> None:
    m = read_bvh(MAKEHUMAN, units="dm", up="z", position_channels="add")
    out = tmp_path / "mh.bvh"
    write_bvh(m, out)
    # same numbers as the source file: same unit, axes and convention
    src = np.array(MAKEHUMAN.read_text().split("Frame Time:")[1].split()[1:], dtype=float)
    ours = np.array(out.read_text().split("Frame Time:")[1].split()[1:], dtype=float)
    np.testing.assert_allclose(ours, src, atol=2e-6)


def test_writer_other_units_and_up(tmp_path: Path) -> None:
    m = read_bvh(CMU, units="cmu")
    out = tmp_path / "mm.bvh"
    write_bvh(m, out, units="mm", up="z")
    back = read_bvh(out, units="mm", up="z")
    assert_same_motion(m, back)
    with pytest.warns(UnitWarning, match="guessed 'mm'"):
        read_bvh(out, up="z")


def random_motion(seed: int, n_frames: int = 5, n_joints: int = 9, gimbal: bool = False) -> Motion:
    """Random DFS-ordered skeleton; per-joint random channel layouts; end sites named <parent>_end."""
    rng = np.random.default_rng(seed)
    names, parents, channels = [], [], []
    stack: list[int] = []
    for k in range(n_joints):
        parent = -1 if k == 0 else stack[-1]
        idx = len(names)  # list index of joint k (end sites are interleaved)
        names.append(f"j{k}")
        parents.append(parent)
        axes = list(rng.permutation(["X", "Y", "Z"]))[
            : int(rng.integers(1, 4)) if k % 3 == 2 else 3
        ]
        rot = [f"{a}rotation" for a in axes]
        pos = [f"{a}position" for a in rng.permutation(["X", "Y", "Z"])[: int(rng.integers(0, 4))]]
        ch = rot + pos if rng.random() < 0.5 else pos + rot
        if k == 0:
            ch = ["Xposition", "Yposition", "Zposition"] + rot
        channels.append(tuple(ch))
        stack.append(idx)
        # close some joints with an end site
        while len(stack) > 1 and rng.random() < 0.4:
            j = stack.pop()
            names.append(f"{names[j]}_end")
            parents.append(j)
            channels.append(())
    # end sites must follow their parent directly in DFS order; reorder as DFS
    order = _dfs(np.array(parents))
    remap = {old: new for new, old in enumerate(order)}
    names = [names[i] for i in order]
    parents = [-1 if parents[i] < 0 else remap[parents[i]] for i in order]
    channels = [channels[i] for i in order]
    j = len(names)
    offsets = rng.normal(scale=0.3, size=(j, 3))
    sk = Skeleton(names=names, parents=parents, offsets=offsets)
    rot = np.zeros((n_frames, j, 4))
    trans = np.repeat(offsets[None], n_frames, axis=0)
    for k, ch in enumerate(channels):
        seq = "".join(c[0] for c in ch if c.endswith("rotation"))
        if seq:
            ang = rng.uniform(-180, 180, size=(n_frames, len(seq)))
            if gimbal and len(seq) == 3:
                ang[:, 1] = rng.choice([90.0, -90.0, 89.99999, -90.00001], size=n_frames)
            rot[:, k] = Rotation.from_euler(seq, ang, degrees=True).as_quat()
        else:
            rot[:, k, 3] = 1.0
        for c in ch:
            if c.endswith("position"):
                trans[:, k, "XYZ".index(c[0])] = rng.normal(scale=0.5, size=n_frames)
    return Motion(
        skeleton=sk,
        rotations=rot,
        translations=trans,
        rate=float(rng.uniform(10, 200)),
        channels=channels,
    )


def _dfs(parents: np.ndarray) -> list[int]:
    children: dict[int, list[int]] = {}
    for k, p in enumerate(parents):
        children.setdefault(int(p), []).append(k)
    out, stack = [], children[-1][::-1]
    while stack:
        k = stack.pop()
        out.append(k)
        stack.extend(children.get(k, [])[::-1])
    return out


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("gimbal", [False, True])
def test_random_round_trip(tmp_path: Path, seed: int, gimbal: bool) -> None:
    m = random_motion(seed, gimbal=gimbal)
    # (channels name file axes, so a layout with partial channels only fits its own up axis)
    for unit, up in [("m", "y"), ("cm", "y"), ("in", "y")]:
        out = tmp_path / f"r{seed}{unit}.bvh"
        write_bvh(m, out, units=unit, up=up)
        back = read_bvh(out, units=unit, up=up)
        assert_same_motion(m, back)
        assert abs(back.rate - m.rate) < 1e-9 * m.rate


def test_add_convention_round_trip(tmp_path: Path) -> None:
    m = random_motion(3)
    write_bvh(m, tmp_path / "a.bvh", units="m", position_channels="add")
    back = read_bvh(tmp_path / "a.bvh", units="m", position_channels="add")
    assert_same_motion(m, back)
    assert back.meta["position_channels"] == "add"


def test_multiple_roots_and_non_dfs_order(tmp_path: Path) -> None:
    # two roots; joint 3 is a child of joint 0 listed after the second root
    sk = Skeleton(
        names=["a", "b", "c", "d", "b_end"], parents=[-1, 0, -1, 0, 1], offsets=np.eye(5, 3) + 0.5
    )
    rng = np.random.default_rng(0)
    rot = Rotation.random(3 * 5, random_state=1).as_quat().reshape(3, 5, 4)
    rot[:, 4] = [0, 0, 0, 1]
    trans = np.repeat(sk.offsets[None], 3, axis=0)
    trans[:, [0, 2]] = rng.normal(size=(3, 2, 3))
    m = Motion(skeleton=sk, rotations=rot, translations=trans, rate=50.0)
    write_bvh(m, tmp_path / "two.bvh", units="m")
    back = read_bvh(tmp_path / "two.bvh", units="m")
    # depth-first order; the channel-less leaf "d" is an end site of "a" in BVH
    assert back.skeleton.names == ["a", "b", "b_end", "a_end", "c"]
    ours = joint_positions(m)
    theirs = joint_positions(back)
    for k, name in enumerate(back.skeleton.names):
        np.testing.assert_allclose(
            theirs[:, k], ours[:, sk.index({"a_end": "d"}.get(name, name))], atol=1e-6
        )


def test_writer_refuses_what_bvh_cannot_store(tmp_path: Path) -> None:
    m = random_motion(1)
    k = next(
        i for i, c in enumerate(m.channels) if c and not any(x.endswith("position") for x in c)
    )
    trans = m.translations.copy()
    trans[1, k, 0] += 0.01
    bad = Motion(
        skeleton=m.skeleton,
        rotations=m.rotations,
        translations=trans,
        rate=m.rate,
        channels=m.channels,
    )
    with pytest.raises(ValidationError, match="position channel"):
        write_bvh(bad, tmp_path / "bad.bvh", units="m")
    assert not (tmp_path / "bad.bvh").exists()
    # a joint with only Z rotation cannot turn about X
    sk = Skeleton(names=["r", "c"], parents=[-1, 0], offsets=[[0, 0, 0], [0, 1, 0]])
    rot = np.array([[[0, 0, 0, 1.0], [np.sin(0.1), 0, 0, np.cos(0.1)]]])
    m2 = Motion(
        skeleton=sk,
        rotations=rot,
        translations=sk.offsets[None],
        rate=30,
        channels=[("Zrotation",), ("Zrotation",)],
    )
    with pytest.raises(ValidationError, match="no channel for"):
        write_bvh(m2, tmp_path / "bad2.bvh", units="m")
    with pytest.raises(ValidationError, match="names"):
        sk3 = Skeleton(names=["r", "bad\tname"], parents=[-1, 0], offsets=[[0, 0, 0], [0, 1, 0]])
        write_bvh(
            Motion(
                skeleton=sk3,
                rotations=np.tile([0, 0, 0, 1.0], (1, 2, 1)),
                translations=sk3.offsets[None],
                rate=30,
            ),
            tmp_path / "n.bvh",
        )


def test_overwrite_needs_force(tmp_path: Path) -> None:
    m = read_bvh(MOCAPBANK, units="cm")
    out = tmp_path / "o.bvh"
    write_bvh(m, out)
    before = out.read_bytes()
    with pytest.raises(OutputExistsError):
        write_bvh(m, out)
    assert out.read_bytes() == before
    write_bvh(m, out, force=True)


def test_small_file_semantics(tmp_path: Path) -> None:
    m = read_bvh(write_text(tmp_path, SMALL), units="cm")
    assert m.skeleton.names == ["Hips", "Spine", "Spine_end", "Leg", "Leg_end"]
    assert m.channels[3] == ("Yposition", "Zrotation", "Yrotation", "Xrotation")
    # Leg: Yposition -5 replaces the offset's y; x and z stay from OFFSET 10 -5 0
    np.testing.assert_allclose(m.translations[:, 3], [[0.10, -0.05, 0.0]] * 2)
    # frame 0: Leg has Zrotation 30 -> its end site swings
    p = joint_positions(m)
    leg = np.array([0.01, 0.95, 0.02]) + [0.10, -0.05, 0]
    end = leg + Rotation.from_euler("z", 30, degrees=True).apply([0, -0.9, 0])
    np.testing.assert_allclose(p[0, 4], end, atol=1e-12)
    # Spine: Xrotation 0 Yrotation 0 Zrotation 90 -> end site along -x
    np.testing.assert_allclose(p[0, 2], [0.01 - 0.5, 0.95 + 0.1, 0.02], atol=1e-12)


# ----------------------------------------------------------------- bad input
def mutate(text: str, old: str, new: str, count: int = 1) -> str:
    assert old in text
    return text.replace(old, new, count)


BAD_CASES = {
    "short row": (
        mutate(SMALL, "1 95 2 10 20 30 5 6 7 -5 0 90 45", "1 95 2 10 20 30 5 6 7 -5 0 90"),
        29,
        "has 12 values",
    ),
    "ragged rows": (
        mutate(
            mutate(SMALL, "0 0 0 0 0 90 -5 30 0 0\n", "0 0 0 0 0 90 -5 30 0\n"),
            "0 90 45\n",
            "0 90 45 1\n",
        ),
        28,
        "has 12 values",
    ),
    "fewer rows": (mutate(SMALL, "Frames: 2", "Frames: 3"), 29, "3' declared but the file has 2"),
    "more rows": (mutate(SMALL, "Frames: 2", "Frames: 1"), 29, "more motion rows"),
    "non-numeric": (mutate(SMALL, "-5 30", "-5 abc"), 28, "not a number"),
    "nan": (mutate(SMALL, "-5 30", "-5 nan"), 28, "finite"),
    "inf": (mutate(SMALL, "-5 30", "-5 inf"), 28, "finite"),
    "missing frame time": (mutate(SMALL, "Frame Time: .0083333\n", ""), 27, "Frame Time"),
    "zero frame time": (mutate(SMALL, ".0083333", "0"), 27, "positive"),
    "negative frame time": (mutate(SMALL, ".0083333", "-0.1"), 27, "positive"),
    # absurd frame times: a rate of 1e300 Hz, a denormal, a frame longer than an hour
    "tiny frame time": (mutate(SMALL, ".0083333", "1e-300"), 27, r"outside 1e-07\.\.3600 s"),
    "denormal frame time": (mutate(SMALL, ".0083333", "5e-324"), 27, "outside"),
    "hour-long frame time": (mutate(SMALL, ".0083333", "3601"), 27, "outside"),
    # 1e308 overflowed once scaled or posed, and skin's error then named its output
    "huge channel value": (mutate(SMALL, "-5 30", "-5 1e308"), 28, r"value 11: 1e\+308 is beyond"),
    "huge offset": (mutate(SMALL, "OFFSET 0 10 0", "OFFSET 0 1e300 0"), 8, "OFFSET y: '1e300'"),
    "unknown channel": (
        mutate(SMALL, "Xrotation Yrotation Zrotation", "Xrotation Yrotation Wrotation"),
        9,
        "unknown channel 'Wrotation'",
    ),
    "channel count": (
        mutate(SMALL, "CHANNELS 3 Xrotation", "CHANNELS x Xrotation"),
        9,
        "channel count",
    ),
    "missing brace": (mutate(SMALL, "  JOINT Leg\n  {", "  JOINT Leg\n"), 17, "expected '{'"),
    "unclosed": (SMALL.replace("}\nMOTION", "MOTION"), 23, "file ends inside joint 'Hips'"),
    "extra brace": (SMALL.replace("}\nMOTION", "}\n}\nMOTION"), 25, "unexpected '}'"),
    "no motion": (SMALL.split("MOTION")[0], 24, "no MOTION"),
    "truncated in hierarchy": (
        SMALL[: SMALL.index("  JOINT Leg")],
        14,
        "file ends inside joint 'Hips'",
    ),
    "truncated in motion": (SMALL[: SMALL.index("1 95 2 10")] + "1 95 2 10 20", 29, "has 5 values"),
    "bad offset": (mutate(SMALL, "OFFSET 0 10 0", "OFFSET 0 1O 0"), 8, "OFFSET y"),
    "nan offset": (mutate(SMALL, "OFFSET 0 10 0", "OFFSET 0 nan 0"), 8, "finite"),
    "no hierarchy": (SMALL.replace("HIERARCHY", "HIERARCHX"), 1, "expected 'HIERARCHY'"),
    "duplicate name": (mutate(SMALL, "JOINT Leg", "JOINT Spine"), 15, "used twice"),
    "frames text": (mutate(SMALL, "Frames: 2", "Frames: two"), 26, "whole number"),
    "channels in end site": (
        mutate(SMALL, "OFFSET 0 50 0", "OFFSET 0 50 0\n CHANNELS 1 Xrotation"),
        None,
        "End Site has no CHANNELS",
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_CASES))
def test_bad_input_is_a_format_error_with_line(tmp_path: Path, case: str) -> None:
    text, line, what = BAD_CASES[case]
    p = write_text(tmp_path, text)
    with pytest.raises(FormatError, match=what) as info:
        read_bvh(p, units="cm")
    assert info.value.path == str(p)
    if line is not None:
        assert info.value.line == line, str(info.value)


def test_empty_and_whitespace_files(tmp_path: Path) -> None:
    with pytest.raises(FormatError, match="empty"):
        read_bvh(write_text(tmp_path, b"", "e.bvh"), units="cm")
    with pytest.raises(FormatError, match="empty"):
        read_bvh(write_text(tmp_path, "  \n\n", "w.bvh"), units="cm")
    with pytest.raises(FormatError, match="no such file"):
        read_bvh(tmp_path / "missing.bvh")


def test_bad_arguments() -> None:
    with pytest.raises(ValidationError, match="units"):
        read_bvh(MOCAPBANK, units="furlong")
    with pytest.raises(ValidationError, match="up"):
        read_bvh(MOCAPBANK, units="cm", up="x")  # type: ignore[arg-type]


def test_zero_frames_and_crlf(tmp_path: Path) -> None:
    text = SMALL.split("Frames:")[0] + "Frames: 0\nFrame Time: 0.01\n"
    m = read_bvh(write_text(tmp_path, text.replace("\n", "\r\n")), units="cm")
    assert m.n_frames == 0 and m.rate == 100.0
    write_bvh(m, tmp_path / "zero.bvh")
    assert read_bvh(tmp_path / "zero.bvh", units="cm").n_frames == 0


@settings(
    max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    st.lists(
        st.tuples(
            st.sampled_from(["flip", "insert", "delete", "truncate"]),
            st.integers(0, 10**6),
            st.integers(0, 255),
        ),
        min_size=1,
        max_size=4,
    )
)
def test_fuzz_mutated_bytes(tmp_path: Path, edits: list[tuple[str, int, int]]) -> None:
    data = bytearray(SMALL.encode())
    for kind, pos, byte in edits:
        if not data:
            break
        i = pos % len(data)
        if kind == "flip":
            data[i] = byte
        elif kind == "insert":
            data.insert(i, byte)
        elif kind == "delete":
            del data[i]
        else:
            del data[i:]
    p = tmp_path / "fuzz.bvh"
    p.write_bytes(bytes(data))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        try:
            m = read_bvh(p)
        except SkincapError:
            return
    assert isinstance(m, Motion)
    assert np.isfinite(m.rotations).all() and np.isfinite(m.translations).all()


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.floats(-1e6, 1e6, allow_nan=False), min_size=3, max_size=30),
    st.integers(0, 8),
    st.sampled_from([" ", "\t", "  "]),
)
def test_fast_decimal_parser_equals_float(values: list[float], decimals: int, sep: str) -> None:
    from skincap.io.bvh.parse import _parse_plain_decimals

    n = len(values) - len(values) % 3
    tokens = [f"{v:.{decimals}f}" for v in values[:n]]
    body = "\n".join(sep.join(tokens[i : i + 3]) for i in range(0, n, 3)) + "\n"
    got = _parse_plain_decimals(body, 3)
    assert got is not None
    np.testing.assert_array_equal(got.ravel(), [float(t) for t in tokens])


def test_position_channels_auto_reads_makehuman_displacements_as_add() -> None:
    # MakeHuman writes 6 channels on every joint with values near 0: read as "replace"
    # its bones would collapse onto their parents
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        auto = read_bvh(MAKEHUMAN, up="z")
    explicit = read_bvh(MAKEHUMAN, units="dm", up="z", position_channels="add")
    assert auto.meta["position_channels"] == "add"
    np.testing.assert_array_equal(auto.translations, explicit.translations)
    collapsed = read_bvh(MAKEHUMAN, units="dm", up="z", position_channels="replace")
    bones = np.linalg.norm(explicit.skeleton.offsets[1:], axis=-1)
    assert np.median(np.linalg.norm(collapsed.translations[0, 1:], axis=-1)) < 0.2 * np.median(
        bones
    )


def test_position_channels_auto_keeps_absolute_values_as_replace(tmp_path: Path) -> None:
    # every joint with positions equal to its offsets (absolute values, the BVH norm),
    # then a stretched frame: still "replace"
    for seed in range(5):
        m = random_motion(seed)
        write_bvh(m, tmp_path / f"r{seed}.bvh", units="m", position_channels="replace")
        back = read_bvh(tmp_path / f"r{seed}.bvh", units="m", up="y")
        assert back.meta["position_channels"] == "replace"
        assert_same_motion(m, back)
    text = SMALL.replace("Frames: 2", "Frames: 2")
    path = tmp_path / "small.bvh"
    path.write_text(text)
    assert read_bvh(path, units="cm").meta["position_channels"] == "replace"


def test_up_auto_stands_the_makehuman_tpose_up() -> None:
    with pytest.warns(UnitWarning, match="stands along z"):
        auto = read_bvh(MAKEHUMAN, units="dm")
    assert auto.meta["up"] == "z"
    explicit = read_bvh(MAKEHUMAN, units="dm", up="z", position_channels="add")
    np.testing.assert_allclose(joint_positions(auto), joint_positions(explicit))


@pytest.mark.parametrize(("path", "units"), [(CMU, "cmu"), (MOCAPBANK, "cm")])
def test_up_auto_keeps_y_up_files(path: Path, units: str) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", UnitWarning)
        m = read_bvh(path, units=units)
    assert m.meta["up"] == "y"


def test_up_auto_round_trips_a_z_up_file(tmp_path: Path) -> None:
    # a Y-up standing skeleton written Z-up is read back standing
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        m = read_bvh(CMU, units="cmu")
        write_bvh(m, tmp_path / "z.bvh", units="cm", up="z")
        back = read_bvh(tmp_path / "z.bvh", units="cm")
    assert back.meta["up"] == "z"
    np.testing.assert_allclose(joint_positions(back), joint_positions(m), atol=1e-6)


def _chain_bvh(depth: int) -> str:
    """One chain of ``depth`` joints, no indentation, one frame with distinct angles."""
    parts = ["HIERARCHY\nROOT j0\n{\nOFFSET 0 0 0\nCHANNELS 6 Xposition Yposition Zposition"]
    parts.append(" Zrotation Xrotation Yrotation\n")
    for k in range(1, depth):
        parts.append(f"JOINT j{k}\n{{\nOFFSET 0 1 0\nCHANNELS 3 Zrotation Xrotation Yrotation\n")
    parts.append("End Site\n{\nOFFSET 0 1 0\n}\n" + "}\n" * depth)
    values = [0, 0, 0] + [f"{(k % 7) - 3}" for k in range(3 * depth)]
    parts.append("MOTION\nFrames: 1\nFrame Time: 0.04\n" + " ".join(map(str, values)) + "\n")
    return "".join(parts)


def test_deep_chain_is_written_in_linear_size_and_reads_back(tmp_path: Path) -> None:
    """A chain 3000 joints deep: indentation stops at 64 tabs, so the file grows linearly
    with depth (one tab per level gave N² bytes: ~20 GB for #13's 100,000-deep chain)."""
    depth = 3000
    src = tmp_path / "deep.bvh"
    src.write_text(_chain_bvh(depth))
    motion = read_bvh(src, units="m", up="y")
    assert motion.skeleton.n_joints == depth + 1
    out = tmp_path / "deep_out.bvh"
    write_bvh(motion, out)
    text = out.read_text()
    indents = [len(line) - len(line.lstrip("\t")) for line in text.splitlines()]
    assert max(indents) == 65  # 64 levels plus the CHANNELS line of the deepest ones
    # ≤ 65 tabs on each of a joint's 5 lines, plus text: under 1 kB a joint (1.3 MB);
    # one tab per level would be depth² / 2 tabs on each of 5 lines: 22 MB
    assert len(text) < 1000 * depth
    back = read_bvh(out, units="m", up="y")
    assert back.skeleton.names == motion.skeleton.names
    np.testing.assert_array_equal(back.skeleton.parents, motion.skeleton.parents)
    np.testing.assert_allclose(back.rotations, motion.rotations, atol=1e-6)


def test_shallow_skeletons_keep_one_tab_per_level(tmp_path: Path) -> None:
    motion = read_bvh(MAKEHUMAN, units="dm", up="z")
    out = tmp_path / "t.bvh"
    write_bvh(motion, out)
    lines = out.read_text().splitlines()
    joint_lines = [ln for ln in lines if ln.lstrip().startswith(("ROOT", "JOINT"))]
    depths = [len(ln) - len(ln.lstrip("\t")) for ln in joint_lines]
    # MakeHuman's deepest joint is a finger tip, well under the cap
    assert 5 < max(depths) < 64
    assert depths[0] == 0


_NO_CHANNELS = "HIERARCHY\nROOT a\n{\nOFFSET 0 0 0\nCHANNELS 0\nEnd Site\n{\nOFFSET 0 1 0\n}\n}\n"


def test_frames_without_channels_are_held_to_the_file(tmp_path: Path) -> None:
    """#13 item 3: 'Frames: 1e11' with no channels allocated (1e11, J, 3) arrays (4.4 TiB)."""
    p = tmp_path / "no_channels.bvh"
    p.write_text(_NO_CHANNELS + "MOTION\nFrames: 100000000000\nFrame Time: 0.01\n")
    with pytest.raises(FormatError, match="no channels and only 1 lines follow"):
        read_bvh(p, units="m", up="y")


def test_frames_without_channels_round_trip(tmp_path: Path) -> None:
    p = tmp_path / "no_channels.bvh"
    p.write_text(_NO_CHANNELS + "MOTION\nFrames: 3\nFrame Time: 0.01\n\n\n\n")
    motion = read_bvh(p, units="m", up="y")
    assert motion.n_frames == 3
    out = tmp_path / "out.bvh"
    write_bvh(motion, out)
    assert read_bvh(out, units="m", up="y").n_frames == 3
