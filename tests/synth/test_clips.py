"""Built-in clips: T-pose start, prescribed angles, planted feet, hops, smoothness."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from skincap.errors import UnitWarning, ValidationError
from skincap.geometry.kinematics import forward_kinematics, joint_positions, rest_positions
from skincap.geometry.rotations import matrix_to_quat, quat_conjugate, quat_multiply
from skincap.io.bvh import read_bvh, write_bvh
from skincap.synth.clip_pose import find_landmarks
from skincap.synth.clips import CLIPS, HOLD_SECONDS, JUMP_HZ, make_clip
from skincap.synth.skeleton import synth_skeleton

SK = synth_skeleton()
LM = find_landmarks(SK)


@pytest.fixture(scope="module")
def clips() -> dict:
    return {name: make_clip(name, SK) for name in CLIPS}


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    return np.degrees(np.arccos(np.clip(np.sum(a * b, axis=-1), -1.0, 1.0)))


def _angular_velocity(motion) -> np.ndarray:
    """(T-1, J, 3) local angular velocity vectors, rad/s."""
    q = motion.rotations
    d = quat_multiply(quat_conjugate(q[:-1]), q[1:])
    d = d * np.where(d[..., 3:] < 0, -1.0, 1.0)
    s = np.linalg.norm(d[..., :3], axis=-1, keepdims=True)
    angle = 2 * np.arctan2(s, d[..., 3:])
    axis = d[..., :3] / np.where(s > 0, s, 1.0)
    return axis * angle * motion.rate


def test_landmarks_of_the_synth_skeleton():
    for key in ("hips", "spine", "chest", "upper_chest", "neck", "head"):
        assert key in LM
    assert SK.names[LM["upperarm_l"]] == "LeftShoulder"
    assert SK.names[LM["forearm_r"]] == "RightElbow"
    assert SK.names[LM["thigh_l"]] == "LeftHip"
    assert SK.names[LM["foot_r"]] == "RightAnkle"


@pytest.mark.parametrize("name", CLIPS)
def test_clip_starts_in_tpose_and_is_valid(clips, name):
    m = clips[name]
    assert m.n_frames == 480 and m.rate == 120.0
    assert m.meta["clip"] == name
    hold = int(HOLD_SECONDS * m.rate)
    ident = np.zeros((hold, SK.n_joints, 4))
    ident[..., 3] = 1.0
    np.testing.assert_allclose(m.rotations[:hold], ident, atol=1e-12)
    np.testing.assert_allclose(
        m.translations[:hold], np.broadcast_to(SK.offsets, (hold,) + SK.offsets.shape), atol=1e-12
    )
    assert np.isfinite(m.rotations).all() and np.isfinite(m.translations).all()
    np.testing.assert_allclose(np.linalg.norm(m.rotations, axis=-1), 1.0, atol=1e-12)
    # only the root translates
    np.testing.assert_array_equal(
        m.translations[:, 1:], np.broadcast_to(SK.offsets[1:], m.translations[:, 1:].shape)
    )
    # channels: six on the root, three rotations elsewhere, none on end sites
    assert len(m.channels[0]) == 6
    for k, ch in enumerate(m.channels[1:], start=1):
        assert len(ch) == (0 if SK.is_leaf[k] else 3)


@pytest.mark.parametrize("name", CLIPS)
def test_clip_is_smooth(clips, name):
    w = _angular_velocity(clips[name])
    speed = np.linalg.norm(w, axis=-1)
    jump = np.linalg.norm(np.diff(w, axis=0), axis=-1)
    if name == "jumprope":
        # The wind-up starts with a snap: the hands lift from the hips past the
        # shoulders within 0.4 s (a resting rope needs it to start turning, see
        # skincap.synth.rope.jump_rope_hands). Only that window is allowed to be
        # faster; everything else is held to the same limits as the other clips.
        t = np.arange(len(w)) / 120.0
        snap = (t > HOLD_SECONDS + 0.6) & (t < HOLD_SECONDS + 1.0)
        assert speed[snap].max() < 25.0 and jump[snap[:-1]].max() < 5.0
        speed, jump = speed[~snap], jump[~snap[:-1]]
    assert speed.max() < 20.0  # rad/s: below a fast human punch
    # no spikes: the angular velocity changes by < 2 rad/s per frame (240 rad/s^2)
    assert jump.max() < 2.0
    if name != "tpose":
        assert speed.max() > 0.3  # it does move


@pytest.mark.parametrize("name", CLIPS)
def test_nothing_below_the_floor(clips, name):
    p = joint_positions(clips[name])
    floor = rest_positions(SK)[:, 1].min()
    assert p[..., 1].min() >= floor - 1e-9


def test_flex_elbows_reach_150_degrees(clips):
    p = joint_positions(clips["flex"])
    for s in ("l", "r"):
        sh, el, wr = (p[:, LM[f"{k}_{s}"]] for k in ("upperarm", "forearm", "hand"))
        angle = _angle_deg(el - sh, wr - el)
        assert angle.max() == pytest.approx(150.0, abs=3.0)
        assert angle[: int(HOLD_SECONDS * 120)].max() < 1e-6
        # it flexes and extends again, at least twice
        peaks = np.sum(
            (angle[1:-1] > 140) & (angle[1:-1] >= angle[:-2]) & (angle[1:-1] > angle[2:])
        )
        assert peaks >= 2
        assert angle[-1] < 100
        # the hand stays in front of the chest (no forearm through the torso)
        chest_z = p[:, LM["upper_chest"], 2]
        flexed = angle > 120
        assert np.all(wr[flexed, 2] > chest_z[flexed] + 0.1)


def test_flex_angle_follows_frames_argument():
    short = make_clip("flex", SK, frames=100)
    p = joint_positions(short)
    sh, el, wr = (p[:, LM[f"{k}_l"]] for k in ("upperarm", "forearm", "hand"))
    assert _angle_deg(el - sh, wr - el).max() < 5.0  # 0.83 s: only the lowering started


def _twist_deg(motion, side: str) -> np.ndarray:
    """Unwrapped turn of the hand relative to the upper arm about the forearm axis."""
    w = forward_kinematics(motion)
    upper = w[:, LM[f"upperarm_{side}"], :3, :3]
    hand = w[:, LM[f"hand_{side}"], :3, :3]
    rel = np.einsum("tji,tjk->tik", upper, hand)  # upper^T hand
    axis = w[:, LM[f"hand_{side}"], :3, 3] - w[:, LM[f"forearm_{side}"], :3, 3]
    axis = np.einsum("tji,tj->ti", upper, axis / np.linalg.norm(axis, axis=1, keepdims=True))
    q = matrix_to_quat(rel)
    return np.degrees(np.unwrap(2 * np.arctan2(np.sum(q[:, :3] * axis, axis=1), q[:, 3])))


def test_twist_range_is_180_degrees(clips):
    p = joint_positions(clips["twist"])
    for s in ("l", "r"):
        tw = _twist_deg(clips["twist"], s)
        assert tw.max() - tw.min() == pytest.approx(180.0, abs=5.0)
        assert abs(tw[0]) < 1e-9
        # the elbow stays straight: the twist is about the forearm's own axis
        sh, el, wr = (p[:, LM[f"{k}_{s}"]] for k in ("upperarm", "forearm", "hand"))
        assert _angle_deg(el - sh, wr - el).max() < 1.0
        # arms held out: the hands stay near shoulder height
        assert np.abs(wr[:, 1] - sh[:, 1]).max() < 0.15


def test_squat_feet_planted_and_knees_bend(clips):
    m = clips["squat"]
    p = joint_positions(m)
    floor = rest_positions(SK)[:, 1].min()
    for s in ("l", "r"):
        for key in ("foot", "toe"):
            j = LM[f"{key}_{s}"]
            slide = np.linalg.norm(p[:, j] - p[0, j], axis=1)
            assert slide.max() < 0.01
            assert p[:, j, 1].min() >= floor - 1e-9
        hip, knee, ankle = (p[:, LM[f"{k}_{s}"]] for k in ("thigh", "shin", "foot"))
        flexion = _angle_deg(knee - hip, ankle - knee)
        assert 100.0 <= flexion.max() <= 110.0
        # the knee goes forward, not backward
        assert (knee[:, 2] - ankle[:, 2])[flexion.argmax()] > 0.1
    drop = p[0, 0, 1] - p[:, 0, 1]
    assert 0.25 < drop.max() < 0.5


@pytest.fixture(scope="module")
def jumprope_long():
    return make_clip("jumprope", SK, frames=1000)


def test_jumprope_hops_and_circles(jumprope_long):
    m = jumprope_long
    p = joint_positions(m)
    t = np.arange(m.n_frames) / m.rate
    steady = t > HOLD_SECONDS + 0.6 + 2.5 + 0.2  # after the wind-up
    duration = steady.sum() / m.rate
    for s in ("l", "r"):
        ankle = p[:, LM[f"foot_{s}"]]
        toe = p[:, LM[f"toe_{s}"]]
        lift = ankle[:, 1] - ankle[0, 1]
        toe_lift = toe[:, 1] - toe[0, 1]
        assert 0.05 <= lift.max() <= 0.10
        assert toe_lift.max() > 0.04 and toe_lift.min() > -1e-9
        # one flight per rope turn at 1.8 Hz
        air = (lift > 0.01).astype(int)
        flights = np.sum(np.diff(air[steady]) == 1)
        assert flights == pytest.approx(JUMP_HZ * duration, abs=1.5)
        # the feet do not slide horizontally
        assert np.abs(ankle[:, [0, 2]] - ankle[0, [0, 2]]).max() < 1e-6
        # knees bend on landing
        hip, knee = p[:, LM[f"thigh_{s}"]], p[:, LM[f"shin_{s}"]]
        flexion = _angle_deg(knee - hip, ankle - knee)
        assert flexion[steady].max() > 25.0
        assert flexion[steady][air[steady] == 0].max() > flexion[steady][air[steady] == 1].max()
        # skipping: hands circle near hip height, to the side, ~0.68 m apart
        wrist = p[:, LM[f"hand_{s}"]]
        pelvis = p[:, LM["hips"]]
        centre = wrist[steady].mean(axis=0)
        assert abs(centre[1] - pelvis[steady, 1].mean()) < 0.15
        assert np.abs(wrist[steady, 1] - pelvis[steady, 1]).max() < 0.3
        side = 1.0 if s == "l" else -1.0
        assert np.all(side * (wrist[steady, 0] - pelvis[steady, 0]) > 0.3)
        # the wrists draw circles in the sagittal plane, turning forward at JUMP_HZ
        rel = wrist[steady] - centre
        _, sv, vt = np.linalg.svd(rel, full_matrices=False)
        assert sv[1] / sv[0] > 0.75 and sv[2] / sv[0] < 0.15
        assert abs(vt[2, 0]) > 0.95  # the plane's normal is the body's left-right axis
        yz = rel[:, 1:]
        radius = np.linalg.norm(yz, axis=1)
        assert 0.12 < radius.mean() < 0.18
        angle = np.unwrap(np.arctan2(yz[:, 1], yz[:, 0]))  # 0 = up, +pi/2 = forward
        turns = (angle[-1] - angle[0]) / (2 * np.pi)
        assert turns == pytest.approx(JUMP_HZ * duration, rel=0.05)
        # the wind-up: a wide circle with the hands over the head first
        shoulder = p[:, LM[f"upperarm_{s}"]]
        wind = (t > HOLD_SECONDS + 0.6) & (t < HOLD_SECONDS + 2.0)
        assert (wrist[wind, 1] - shoulder[wind, 1]).max() > 0.35
        assert np.ptp(wrist[wind, 2]) > 0.6
        # elbows by the sides: below the shoulders while skipping
        elbow = p[:, LM[f"forearm_{s}"]]
        assert np.all(elbow[steady, 1] < shoulder[steady, 1] - 0.15)
    # hands still in the hold, then they come down
    hold = t < HOLD_SECONDS
    np.testing.assert_array_equal(
        p[hold, LM["hand_l"]], np.broadcast_to(p[0, LM["hand_l"]], (hold.sum(), 3))
    )


def test_jumprope_hands_follow_the_turn_rate(jumprope_long):
    """The same curve at another frame rate; a short clip is the start of a long one."""
    a = make_clip("jumprope", SK, seconds=4.0, rate=120.0)
    b = make_clip("jumprope", SK, seconds=4.0, rate=60.0)
    np.testing.assert_allclose(
        joint_positions(a)[::2, LM["hand_l"]], joint_positions(b)[:, LM["hand_l"]], atol=1e-9
    )
    np.testing.assert_allclose(
        joint_positions(a)[:, LM["hand_r"]],
        joint_positions(jumprope_long)[:480, LM["hand_r"]],
        atol=1e-9,
    )


def test_punch_extends_the_arms_alternately(clips):
    p = joint_positions(clips["punch"])
    t = np.arange(p.shape[0]) / 120.0
    reach = {}
    for s in ("l", "r"):
        sh, el, wr = (p[:, LM[f"{k}_{s}"]] for k in ("upperarm", "forearm", "hand"))
        angle = _angle_deg(el - sh, wr - el)
        assert angle[t > 1.2].max() > 90.0  # guard
        assert angle[t > 1.2].min() < 25.0  # extended punch
        reach[s] = wr[:, 2] - p[:, LM["hips"], 2]
        assert reach[s].max() > 0.5
    # never both fists out at once
    assert np.minimum(reach["l"], reach["r"]).max() < 0.45
    # the chest turns into each punch
    chest = forward_kinematics(clips["punch"])[:, LM["upper_chest"], :3, :3]
    yaw = np.degrees(np.arctan2(chest[:, 0, 2], chest[:, 2, 2]))
    assert yaw.max() > 10 and yaw.min() < -10


def test_breathe_is_small_and_periodic(clips):
    m = clips["breathe"]
    w = forward_kinematics(m)
    chest = w[:, LM["upper_chest"]]
    tilt = np.degrees(np.arctan2(-chest[:, 2, 1], chest[:, 1, 1]))
    assert 1.0 < np.ptp(tilt) < 6.0
    p = joint_positions(m)
    for s in ("l", "r"):
        j = LM[f"foot_{s}"]
        assert np.abs(p[:, j] - p[0, j]).max() < 1e-9


@pytest.mark.parametrize("name", ["flex", "jumprope"])
def test_deterministic_and_seeded(name):
    a = make_clip(name, SK, seed=3)
    b = make_clip(name, SK, seed=3)
    c = make_clip(name, SK, seed=4)
    assert a.rotations.tobytes() == b.rotations.tobytes()
    assert a.translations.tobytes() == b.translations.tobytes()
    diff = np.abs(a.rotations - c.rotations).max()
    assert 0 < diff < 0.05  # a subtle sway, not a different motion
    np.testing.assert_array_equal(a.rotations[:60], c.rotations[:60])


def test_frames_seconds_and_rate():
    assert make_clip("squat", SK, frames=37).n_frames == 37
    m = make_clip("twist", SK, seconds=2.5, rate=60.0)
    assert m.n_frames == 150 and m.rate == 60.0
    assert make_clip("breathe", SK, seconds=0.001).n_frames == 1
    # the same clip at another rate samples the same curve
    a = make_clip("flex", SK, seconds=3.0, rate=120.0)
    b = make_clip("flex", SK, seconds=3.0, rate=60.0)
    np.testing.assert_allclose(a.rotations[::2], b.rotations, atol=1e-12)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"frames": 0},
        {"frames": 2.5},
        {"frames": True},
        {"seconds": -1.0},
        {"seconds": float("nan")},
        {"seconds": "long"},
        {"frames": 10, "seconds": 1.0},
        {"rate": 0.0},
        {"rate": float("inf")},
        {"seed": -1},
        {"seed": 1.5},
    ],
)
def test_bad_arguments(kwargs):
    with pytest.raises(ValidationError):
        make_clip("flex", SK, **kwargs)


def test_bad_name_and_skeleton():
    with pytest.raises(ValidationError, match="flex"):
        make_clip("dance", SK)
    with pytest.raises(ValidationError, match="Skeleton"):
        make_clip("flex", "skeleton")  # type: ignore[arg-type]


def test_other_naming_and_missing_joints(data_dir):
    """A real CMU skeleton (arms down at rest) and a skeleton without arms still work."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UnitWarning)
        cmu = read_bvh(data_dir / "cmu_131_01_bvh11.bvh", units="cmu").skeleton
    m = make_clip("squat", cmu, frames=300)
    p = joint_positions(m)
    lm = find_landmarks(cmu)
    ankle = p[:, lm["foot_l"]]
    assert np.linalg.norm(ankle - ankle[0], axis=1).max() < 1e-6
    # drop the arms: keep the joints that are not below a collar
    keep = [
        k
        for k, n in enumerate(SK.names)
        if not any(a in n for a in ("Shoulder", "Elbow", "Wrist", "hand", "Fingers", "Thumb"))
    ]
    from skincap.types import Skeleton

    remap = {old: new for new, old in enumerate(keep)}
    armless = Skeleton(
        names=[SK.names[k] for k in keep],
        parents=np.array([remap[SK.parents[k]] if SK.parents[k] >= 0 else -1 for k in keep]),
        offsets=SK.offsets[keep],
    )
    for name in CLIPS:
        motion = make_clip(name, armless, frames=200)
        assert np.isfinite(motion.rotations).all()


def test_round_trip_through_bvh(tmp_path, clips):
    m = clips["jumprope"]
    write_bvh(m, tmp_path / "jump.bvh")
    back = read_bvh(tmp_path / "jump.bvh", units="m")
    np.testing.assert_allclose(joint_positions(back), joint_positions(m), atol=1e-5)


def test_rom_moves_every_major_joint_in_turn(clips):
    from skincap.synth.clips import _ROM_MOVES

    motion = clips["rom"]
    q = motion.rotations  # (T, J, 4) local
    angle = np.degrees(2 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3])))
    peaks = []
    for landmark in dict.fromkeys(m[1] for m in _ROM_MOVES):
        sides = [landmark] if not landmark.endswith("_l") else [landmark, landmark[:-2] + "_r"]
        for name in sides:
            j = LM[name]
            assert angle[:, j].max() >= 14.0, name  # every listed joint goes through a range
            peaks.append(int(np.argmax(angle[:, j])))
    assert len(set(peaks)) >= 6  # slot after slot, not all at once


def test_rom_moves_every_true_part_against_its_parent(clips) -> None:
    """Segmentation can only find parts that move apart: in ``rom`` every true part but the
    pelvis (which holds still) turns at one of its joints by >= 15 deg (the lower back
    too: abdomen against pelvis)."""
    from skincap.synth.marker_parts import PART_NAMES, PART_OF_LANDMARK

    rotations = clips["rom"].rotations  # (T, J, 4) local, scalar last
    angle = np.degrees(2 * np.arccos(np.clip(np.abs(rotations[..., 3]), 0.0, 1.0)))
    moved = angle.max(axis=0) - angle[0]  # (J,) degrees
    for part in PART_NAMES[1:]:
        joints = [LM[lm] for lm, p in PART_OF_LANDMARK.items() if p == part and lm in LM]
        assert max(moved[j] for j in joints) >= 15.0, part


@pytest.mark.parametrize(
    "options, message",
    [
        # 1e14 frames asked NumPy for 728 TiB (skincap synth/demo/eval animate --frames)
        (
            {"frames": 10**14},
            "frames: expected at most 1000000 for a synthetic take, got 100000000000000",
        ),
        ({"seconds": 1e300}, r"seconds: 1e\+300 s at 120 Hz is 1\.2e\+302 frames"),
        # 4 s at 1e300 Hz: int(4e300) frames, and np.arange raised a bare ValueError
        ({"rate": 1e300}, r"rate: expected 1\.\.100000 Hz, got 1e\+300"),
        ({"rate": 1e-300, "frames": 10}, r"rate: expected 1\.\.100000 Hz, got 1e-300"),
    ],
)
def test_clip_lengths_and_rates_beyond_any_take_are_refused(options, message):
    with pytest.raises(ValidationError, match=message):
        make_clip("flex", synth_skeleton(), **options)


def test_the_longest_and_slowest_clips_allowed_are_made():
    motion = make_clip("tpose", synth_skeleton(), rate=1.0, seconds=3.0)
    assert motion.rotations.shape[0] == 3 and motion.rate == 1.0
    assert np.isfinite(motion.rotations).all()
