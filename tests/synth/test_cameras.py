"""Tests of skincap.synth.cameras: the ring, visibility and the capture simulation."""

from __future__ import annotations

import numpy as np
import pytest
from markers_posing import arm_across_belly

from skincap.errors import ValidationError
from skincap.io.makehuman import read_makehuman
from skincap.synth.cameras import (
    CameraRig,
    CaptureResult,
    occlusion_proxy,
    simulate_capture,
    visibility,
)
from skincap.synth.markers import dense_marker_layout, place_markers
from skincap.types import Mesh

DATA = "tests/data/makehuman_base.obj"


@pytest.fixture(scope="module")
def body() -> Mesh:
    return read_makehuman(DATA)


@pytest.fixture(scope="module")
def rig(body) -> CameraRig:
    return CameraRig.ring(center=(0.0, float(body.vertices[:, 1].min()), 0.0))


@pytest.fixture(scope="module")
def take(body):
    """60 frames: the left arm swings in front of the belly; dense markers on it."""
    layout = dense_marker_layout(body)
    frames = arm_across_belly(body, frames=60)
    pos, nrm = place_markers(layout, frames, body.faces)
    return layout, frames, pos, nrm


@pytest.fixture(scope="module")
def proxy(body):
    return occlusion_proxy(body.vertices, body.faces)


@pytest.fixture(scope="module")
def capture(take, rig, body) -> CaptureResult:
    layout, frames, pos, nrm = take
    return simulate_capture(pos, nrm, layout.labels, rig, frames, body.faces, seed=7)


# ------------------------------------------------------------------------- rig
def test_ring_layout(rig) -> None:
    assert rig.n_cameras == 12
    up = rig.meta["aimed_up"]
    assert up.sum() == 2
    fwd = rig.rotations[:, 2]
    assert (fwd[up, 1] > 0.1).all()  # the two low cameras look up
    assert (fwd[~up, 1] < -0.1).all()  # the others look down
    assert (rig.positions[up, 1] < rig.positions[~up, 1].min()).all()
    # every camera sees the whole subject region (a 2 m x 2 m x 2.5 m volume)
    c0 = np.array(rig.meta["center"])
    probe = c0 + np.array([[0, 0, 0], [0, 2.5, 0], [0.7, 1.2, 0.7], [-0.7, 0.1, -0.7]])
    assert rig.in_frustum(probe).all()
    # rotations are orthonormal
    r = rig.rotations
    np.testing.assert_allclose(
        np.einsum("cij,ckj->cik", r, r), np.tile(np.eye(3), (12, 1, 1)), atol=1e-12
    )
    assert not rig.in_frustum(rig.positions[0] - 0.5 * fwd[0])[0]  # behind camera 0


def test_rig_validation() -> None:
    with pytest.raises(ValidationError):
        CameraRig(np.zeros((1, 3)), np.zeros((1, 3)), 60.0)
    with pytest.raises(ValidationError):
        CameraRig(np.zeros((1, 3)), [[0, 2.0, 0]], 60.0)  # looks along the up axis
    with pytest.raises(ValidationError):
        CameraRig(np.zeros((1, 3)), [[0, 0, 1.0]], 200.0)
    with pytest.raises(ValidationError):
        CameraRig.ring(n=12, n_up=13)


# ------------------------------------------------------------------ visibility
def test_arm_hides_belly_markers(take, rig, body) -> None:
    layout, frames, pos, nrm = take
    # the torso does not move: any change of visibility there is the arm's shadow
    vis = visibility(pos[[0, -1]], nrm[[0, -1]], rig, frames[[0, -1]], body.faces, proxy=False)
    belly = (
        (np.abs(pos[0, :, 0]) < 0.15)
        & (pos[0, :, 1] > 0.05)
        & (pos[0, :, 1] < 0.45)
        & (nrm[0, :, 2] > 0.5)
        & (np.linalg.norm(pos[-1] - pos[0], axis=1) < 1e-9)  # skin the arm does not move
    )
    assert belly.sum() >= 5
    np.testing.assert_allclose(nrm[0, belly], nrm[-1, belly], atol=1e-9)
    lost = vis[0, belly] & ~vis[1, belly]  # (markers, cameras)
    assert lost.any()
    assert not (vis[1, belly] & ~vis[0, belly]).any()  # the arm never reveals anything
    front = rig.positions[:, 2] > 0.5
    # some belly marker seen by front cameras at rest is hidden from all of them by the arm
    hidden = vis[0, belly][:, front].any(axis=1) & ~vis[1, belly][:, front].any(axis=1)
    assert hidden.any()
    # the proxy agrees with the exact mesh on almost every marker-camera pair
    vp = visibility(pos[[0, -1]], nrm[[0, -1]], rig, frames[[0, -1]], body.faces, proxy=True)
    assert (vp == vis).mean() > 0.99


def test_back_markers_are_seen_from_behind_only(take, rig, body) -> None:
    layout, frames, pos, nrm = take
    vis = visibility(pos[:1], nrm[:1], rig, frames[:1], body.faces)[0]
    back = (
        (np.abs(pos[0, :, 0]) < 0.12) & (nrm[0, :, 2] < -0.8) & (np.abs(pos[0, :, 1] - 0.2) < 0.15)
    )
    assert back.sum() >= 3
    front = rig.positions[:, 2] > 1.0
    rear = rig.positions[:, 2] < -1.0
    assert not vis[back][:, front].any()
    assert vis[back][:, rear].sum(axis=1).min() >= 2
    # without normals (omnidirectional markers) the body itself hides most of them from
    # the front (a few in the lumbar hollow can be seen steeply over the flank)
    vis_omni = visibility(pos[:1], None, rig, frames[:1], body.faces)[0]
    assert (~vis_omni[back][:, front].any(axis=1)).mean() > 0.8
    assert (vis_omni >= vis).all()


def test_capsules_occlude(take, rig, body) -> None:
    layout, frames, pos, nrm = take
    vis = visibility(pos[:1], nrm[:1], rig, frames[:1], body.faces)[0]
    n, c = np.argwhere(vis)[0]
    mid = 0.5 * (pos[0, n] + rig.positions[c])
    seg = np.array([[[mid - [0.0, 0.05, 0.0], mid + [0.0, 0.05, 0.0]]]])  # (1, 1, 2, 3)
    vis2 = visibility(pos[:1], nrm[:1], rig, frames[:1], body.faces, extra_segments=seg)[0]
    assert not vis2[n, c]
    assert (vis2 <= vis).all()


def _rope_in_front(frames: int) -> tuple[np.ndarray, np.ndarray]:
    """10 rope markers and 15 rope segments (T, 15, 2, 3) swaying in front of the body."""
    sway = 0.05 * np.sin(np.arange(frames))[:, None, None]
    markers = np.linspace([-0.5, 0.2, 0.35], [0.5, 0.2, 0.35], 10)[None] + sway
    axis = np.linspace([-0.6, 0.1, 0.3], [0.6, 0.35, 0.3], 16)[None] + sway
    return markers, np.stack([axis[:, :-1], axis[:, 1:]], axis=2)


def test_capsules_are_tested_exactly_on_the_pairs_that_can_meet_them(
    take, rig, body, proxy
) -> None:
    from skincap.geometry.raycast import segments_near_capsules

    layout, frames, pos, nrm = take
    sl = slice(0, 60, 15)
    _, segs = _rope_in_front(60)
    args = (pos[sl], nrm[sl], rig, frames[sl], body.faces)
    plain = visibility(*args, proxy=proxy)
    got = visibility(*args, extra_segments=segs[sl], proxy=proxy)
    # the reference: every pair the body leaves visible against every capsule
    want = plain.copy()
    for t in range(want.shape[0]):
        ni, ci = np.nonzero(want[t])
        s = segs[sl][t]
        hit = segments_near_capsules(pos[sl][t, ni], rig.positions[ci], s[:, 0], s[:, 1], 0.01)
        want[t, ni[hit], ci[hit]] = False
    np.testing.assert_array_equal(got, want)
    assert (plain & ~got).sum() >= 20  # the rope hides markers in every tested frame


def test_capsule_candidates_keep_every_hit() -> None:
    from skincap.geometry.raycast import segments_near_capsules
    from skincap.synth.cameras import _capsule_candidates

    rng = np.random.default_rng(5)
    cams = rng.uniform(-4.0, 4.0, (6, 3))
    pts = rng.uniform(-0.5, 0.5, (3, 200, 3))
    a = rng.uniform(-0.6, 0.6, (3, 8, 3))
    segs = np.stack([a, a + rng.normal(scale=0.1, size=a.shape)], axis=2)
    # grazing pairs: markers whose ray to camera 0 passes just over 1 cm from a capsule end
    to_end = segs[:, :4, 0] - cams[0]
    side = np.cross(to_end, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side, axis=2, keepdims=True)
    pts[:, :4] = cams[0] + 1.7 * (to_end + 0.0100001 * side)
    pairs = np.ones((3, 200, 6), dtype=bool)
    cand = _capsule_candidates(pts, cams, segs, 0.01, pairs)
    hits = np.zeros_like(pairs)
    for t in range(3):
        ni, ci = np.nonzero(pairs[t])
        hits[t, ni, ci] = segments_near_capsules(
            pts[t, ni], cams[ci], segs[t, :, 0], segs[t, :, 1], 0.01
        )
    assert hits.any() and not (hits & ~cand).any()  # no hit is ever pruned
    assert cand.mean() < 0.5  # and most pairs are
    assert cand[:, :4, 0].all()  # the grazing pairs are kept for the exact test


def test_extra_markers_share_the_pass_over_the_body(take, rig, body, proxy) -> None:
    layout, frames, pos, nrm = take
    sl = slice(0, 60, 20)
    rope, segs = _rope_in_front(60)
    body_only = visibility(
        pos[sl], nrm[sl], rig, frames[sl], body.faces, extra_segments=segs[sl], proxy=proxy
    )
    rope_only = visibility(rope[sl], None, rig, frames[sl], body.faces, proxy=proxy)
    both = visibility(
        np.concatenate([pos[sl], rope[sl]], axis=1),
        np.concatenate([nrm[sl], np.zeros_like(rope[sl])], axis=1),
        rig,
        frames[sl],
        body.faces,
        extra_segments=segs[sl],
        extra_markers=np.arange(pos.shape[1] + 10) >= pos.shape[1],
        proxy=proxy,
    )
    np.testing.assert_array_equal(both, np.concatenate([body_only, rope_only], axis=1))
    assert rope_only.any() and not rope_only.all()
    with pytest.raises(ValidationError, match="extra_markers"):
        visibility(pos[:1], nrm[:1], rig, frames[:1], body.faces, extra_markers=np.ones(3, bool))


def test_occlusion_proxy_follows_the_mesh(body) -> None:
    proxy = occlusion_proxy(body.vertices, body.faces, n_vertices=1500)
    assert 1400 <= proxy.vertex_ids.size <= 1600
    assert proxy.faces.max() < proxy.vertex_ids.size
    assert proxy.stats["n_nonmanifold_edges"] == 0


# -------------------------------------------------------------------- capture
def test_fragments_map_to_one_truth(capture, take) -> None:
    layout = take[0]
    ms = capture.markers
    assert set(capture.fragment_truth) == set(ms.labels)
    truths = set(capture.fragment_truth.values())
    assert truths <= set(layout.labels) | {"ghost"}
    labelled = [s for s in ms.labels if not s.startswith("*")]
    assert len(labelled) == capture.stats["n_labelled"] <= layout.n_markers
    for s in labelled:  # a labelled fragment starts in frame 0 on its own marker
        assert not np.isnan(ms.positions[0, ms.labels.index(s)]).any()
    # every point belongs to one column and the column's samples are those points
    pc = capture.points
    assert pc.points.shape[0] == (~ms.missing).sum()
    back = pc.to_markerset()
    np.testing.assert_array_equal(back.positions, ms.positions[:, np.unique(pc.ids)])
    # truth per point: a fragment without a swap follows one marker only
    col_truth = np.array([capture.fragment_truth[s] for s in ms.labels], dtype=object)
    agree = capture.point_truth == col_truth[pc.ids]
    assert agree.mean() > 0.99
    if capture.stats["n_swaps"] == 0:
        assert agree.all()
    ghosts = capture.point_truth == "ghost"
    assert (col_truth[pc.ids][ghosts] == "ghost").all()
    assert capture.stats["n_ghosts"] == sum(v == "ghost" for v in capture.fragment_truth.values())


def test_noise_sigma(capture, take) -> None:
    pos = take[2]
    pc = capture.points
    real = capture.point_truth_index >= 0
    t = pc.frame_index[real]
    err = pc.points[real] - pos[t, capture.point_truth_index[real]]
    sigma = err.std()
    assert abs(sigma - 0.0005) < 0.05 * 0.0005
    assert abs(err.mean()) < 2e-5


def test_capture_statistics(capture, take) -> None:
    s = capture.stats
    n = take[0].n_markers
    assert s["n_frames"] == 60 and s["n_markers"] == n
    assert 0.01 < s["missing_fraction"] < 0.3
    assert s["n_fragments"] >= s["n_labelled"]
    recon = capture.reconstructed
    assert recon.shape == (60, n)
    assert (capture.visible.sum(axis=2)[recon] >= 2).all()
    assert s["holes"] == (~recon).sum()
    assert capture.markers.rate == 120.0


def test_capture_is_deterministic(take, rig, body, capture) -> None:
    layout, frames, pos, nrm = take
    sl = slice(0, 20)
    a = simulate_capture(pos[sl], nrm[sl], layout.labels, rig, frames[sl], body.faces, seed=3)
    b = simulate_capture(pos[sl], nrm[sl], layout.labels, rig, frames[sl], body.faces, seed=3)
    c = simulate_capture(pos[sl], nrm[sl], layout.labels, rig, frames[sl], body.faces, seed=4)
    assert a.markers.positions.tobytes() == b.markers.positions.tobytes()
    assert a.markers.labels == b.markers.labels
    assert a.points.points.tobytes() == b.points.points.tobytes()
    assert a.fragment_truth == b.fragment_truth
    assert a.points.points.tobytes() != c.points.points.tobytes()


def test_extra_points_and_swaps(take, rig, body) -> None:
    layout, frames, pos, nrm = take
    sl = slice(0, 30)
    # a "rope" of 10 markers in front of the body, and a twin of marker 5 riding
    # 1 cm from it: close confusions everywhere
    rope = np.linspace([-0.5, 0.2, 0.4], [0.5, 0.2, 0.4], 10)
    rope = np.repeat(rope[None], 30, axis=0) + 0.01 * np.sin(np.arange(30))[:, None, None]
    res = simulate_capture(
        pos[sl], nrm[sl], layout.labels, rig, frames[sl], body.faces,
        extra_points=rope, extra_labels=[f"rope_{k:02d}" for k in range(10)],
        confusion_distance=0.05, confusion_share=0.5, swap_rate=0.3, ghost_rate=0.5, seed=1,
    )  # fmt: skip
    assert res.truth_labels[-10:] == [f"rope_{k:02d}" for k in range(10)]
    rope_cols = [k for k, v in res.fragment_truth.items() if v.startswith("rope_")]
    assert rope_cols and all(s.startswith("*") for s in rope_cols)  # never labelled
    assert res.stats["n_swaps"] > 0 and res.stats["n_confusion_breaks"] > 0
    assert res.stats["n_ghosts"] > 0
    # swapped fragments still map to exactly one truth: the marker of most samples
    ms = res.markers
    col_truth = np.array([res.fragment_truth[s] for s in ms.labels], dtype=object)
    pt = res.points
    for col in np.unique(pt.ids):
        mine = pt.ids == col
        names, counts = np.unique(res.point_truth[mine], return_counts=True)
        assert col_truth[col] == names[np.argmax(counts)] or counts.max() == counts.min()


def test_settings_object_and_keywords_give_the_same_capture(take, rig, body) -> None:
    from skincap.synth.capture_settings import CaptureSettings

    layout, frames, pos, nrm = take
    sl = slice(0, 12)
    args = (pos[sl], nrm[sl], layout.labels, rig, frames[sl], body.faces)
    opts = {"noise_mm": 0.2, "swap_rate": 0.3, "ghost_rate": 0.5, "confusion_distance": 0.05}
    by_keywords = simulate_capture(*args, seed=2, **opts)
    by_settings = simulate_capture(*args, settings=CaptureSettings(**opts), seed=2)
    assert by_keywords.points.points.tobytes() == by_settings.points.points.tobytes()
    assert by_keywords.markers.labels == by_settings.markers.labels
    assert by_keywords.stats == by_settings.stats
    with pytest.raises(TypeError, match="unexpected keyword argument 'noise'"):
        simulate_capture(*args, noise=0.2)


def test_capture_rejects_bad_input(take, rig, body) -> None:
    layout, frames, pos, nrm = take
    with pytest.raises(ValidationError):
        simulate_capture(pos[:2], nrm[:2], layout.labels[:-1], rig, frames[:2], body.faces)
    with pytest.raises(ValidationError):
        simulate_capture(pos[:2], nrm[:3], layout.labels, rig, frames[:2], body.faces)
    with pytest.raises(ValidationError):
        simulate_capture(
            pos[:2], nrm[:2], layout.labels, rig, frames[:2], body.faces, confusion_share=2.0
        )
    with pytest.raises(ValidationError):
        visibility(pos[:2], nrm[:2], "rig", frames[:2], body.faces)
