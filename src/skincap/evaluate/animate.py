"""The dense chain measured against the true skin: Park & Hodgins' Fig. 7 and Fig. 8 as numbers.

On a synthetic dense take (``skincap synth``'s folder: ``truth/markers.c3d``,
``truth/mesh.pc2``, ``truth/marker_surface.ply``, ``truth/body.glb``,
``truth/motion.bvh``), every row is the vertex error against the true skin over all
frames and vertices:

* ``same_body`` rows: the four dense variants (``rigid`` … ``quadratic_rbf``) on the
  body the capture was made on, in the reference pose (frame 0 of the true skin), the
  rig segmented on the take itself;
* ``lbs`` and ``dqs``: skeletal skinning of the same body driven by the true skeleton
  (what a conventional capture gives at best, Fig. 8);
* ``global_rbf``: one global scattered-data interpolation of the marker displacements
  (scipy's ``RBFInterpolator``, thin-plate spline): what §5 argues against.

The held-out test works on any labelled capture, real ones included: 10 % of the
markers (seeded) are left out of the rig, the rest drive it, and each held-out marker
is moved as a point of the body (its part weights from the nearest marker-surface
triangle, or, far from the kept markers' surface, from its nearest kept markers:
:func:`skincap.deform.dense.weights.surface_interpolation`); the row is the distance
between where the deformation puts it and where it was measured. Segmentation is scored against ``truth/marker_parts.csv`` (``label,part``)
by the adjusted Rand index when that file exists.

Where the error sits: the ``regions`` table splits every vertex row by region, the
joint that weighs most on the vertex in the body's own skin weights
(``truth/body.glb``: ``RightShoulder`` is the upper arm, ``Chest2`` the upper chest),
with each method's vertex RMS there (:func:`region_errors`); the ``seams`` table splits
it by the rig instead (:func:`seam_split`): the vertices whose part weights β blend two
or more parts (eq. 9: on the marker-surface triangles at a seam between parts) and
those inside one part. The dense chain interpolates between markers, so the two tell
an error of the blending at seams from one of a part's own fields. The ``stretch``
table splits it by how far the take stretches or compresses the skin between the
markers around each vertex (:func:`vertex_surface_strain`: the largest relative length
change an edge of the vertex's marker-surface triangle goes through): where the skin
between two markers changes length by a third or more, no interpolation of those
markers knows how the skin between them folds or spreads, and ``dqs`` (the synthetic
skin is DQS plus soft tissue, so that row is the soft tissue alone) against ``lbs``
says how much of the skeleton's own error lies there.

With a *different template* (another body mesh), it is registered to the reference-pose
markers (§5.1, :mod:`skincap.deform.dense.registration`), rigged and deformed like the
capture's own body; since its vertices do not correspond to the true skin's, that row
is the distance from its deformed vertices to the true skin surface (on 8 frames), the
scan-to-mesh measure of MoSh++. Nothing here prints; the CLI (``skincap eval animate``) writes the JSON and
the colour maps.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from skincap._arrays import Progress
from skincap.errors import FormatError, ValidationError
from skincap.io.synth_truth import read_marker_parts

__all__ = [
    "SYNTH_MARKER_HEIGHT_M",
    "TARGETS",
    "adjusted_rand_index",
    "evaluate_animate",
    "held_out_marker_errors",
    "held_out_on_capture",
    "global_rbf_frames",
    "plot_vertex_errors",
    "region_errors",
    "seam_split",
    "stretch_split",
    "vertex_errors",
    "vertex_surface_strain",
]

#: Height of a synthetic marker's centre above the skin, metres: the ``radius`` of
#: :func:`skincap.synth.markers.place_markers` (a test keeps the two equal). The
#: registered-template row registers to markers that sit this far out by default.
SYNTH_MARKER_HEIGHT_M = 0.0015

#: Relative length change of a marker-surface edge (|L / L0 - 1|) beyond which
#: :func:`stretch_split` calls the vertices on its triangles stretched.
STRETCH_THRESHOLD = 0.3

#: Frames per block of :func:`vertex_surface_strain`.
_STRAIN_FRAMES = 256

#: The targets of issue #16 (metres or fractions).
TARGETS: dict[str, Any] = {
    "quadratic_rbf_same_body_rms_m": 0.003,
    "quadratic_rbf_registered_template_rms_m": 0.005,
    "quadratic_rbf_vs_rigid_reduction": 0.5,
    "quadratic_rbf_vs_lbs_reduction": 0.4,
    # beyond the paper: the same row for the solved skeleton's DQS + the markers' residuals
    "skeleton_rbf_vs_lbs_reduction": 0.4,
    "held_out_mean_m": 0.004,
    "segmentation_ari": 0.85,
}


def vertex_errors(frames: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    """Vertex error figures of an animation against the truth.

    Parameters
    ----------
    frames, truth : (T, V, 3) float, metres (NaN frames of ``frames`` are excluded)

    Returns
    -------
    dict
        ``rms_m``, ``mean_m``, ``p95_m``, ``max_m`` over all frames and vertices,
        ``nan_fraction``, and ``per_vertex_rms_m`` (V,) ndarray (not JSON: popped by
        the caller).
    """
    f = np.asarray(frames, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    if f.shape != t.shape:
        raise ValidationError(f"frames {f.shape} and truth {t.shape} differ in shape")
    d = np.linalg.norm(f - t, axis=-1)  # (T, V)
    ok = np.isfinite(d)
    dd = d[ok]
    if dd.size == 0:
        raise ValidationError("no finite vertex to compare")
    per_vertex = np.sqrt((np.where(ok, d, 0.0) ** 2).sum(0) / np.maximum(ok.sum(0), 1))
    return {
        "rms_m": float(np.sqrt(np.mean(dd**2))),
        "mean_m": float(dd.mean()),
        "p95_m": float(np.percentile(dd, 95)),
        "max_m": float(dd.max()),
        "nan_fraction": float(1.0 - ok.mean()),
        "per_vertex_rms_m": per_vertex,
    }


def region_errors(
    per_vertex_rms: dict[str, np.ndarray], regions: Sequence[str] | np.ndarray
) -> list[dict[str, Any]]:
    """Every method's vertex RMS within each region of the body.

    Parameters
    ----------
    per_vertex_rms : method -> (V,) float, metres
        Per-vertex RMS over the frames (:func:`vertex_errors`' ``per_vertex_rms_m``).
    regions : (V,) str
        The region of every vertex.

    Returns
    -------
    list of dict
        One per region, in name order: ``region``, ``vertices`` and ``rms_m``
        (method -> RMS over the region's vertices, metres), then an ``all`` row.
    """
    names = np.asarray(regions).astype(str)
    errors = {m: np.asarray(e, dtype=np.float64) for m, e in per_vertex_rms.items()}
    for method, e in errors.items():
        if e.shape != names.shape:
            raise ValidationError(
                f"per_vertex_rms[{method!r}] has shape {e.shape} for {names.size} regions"
            )
    rows = []
    for region in [*np.unique(names).tolist(), None]:
        chosen = np.ones(names.size, bool) if region is None else names == region
        rows.append(
            {
                "region": "all" if region is None else region,
                "vertices": int(chosen.sum()),
                "rms_m": {m: float(np.sqrt(np.mean(e[chosen] ** 2))) for m, e in errors.items()},
            }
        )
    return rows


def seam_split(vertex_weights: np.ndarray) -> np.ndarray:
    """Which vertices a dense rig blends from several parts.

    Parameters
    ----------
    vertex_weights : (V, P) float
        β (:attr:`skincap.deform.dense.rig.DenseRig.vertex_weights`).

    Returns
    -------
    (V,) str
        ``"seam"`` where two or more parts have a positive weight, ``"one part"``
        elsewhere; the regions of :func:`region_errors`.
    """
    beta = np.asarray(vertex_weights, dtype=np.float64)
    if beta.ndim != 2:
        raise ValidationError(f"vertex_weights must have shape (V, P); got {beta.shape}")
    return np.where((beta > 0).sum(axis=1) >= 2, "seam", "one part")


def vertex_surface_strain(
    vertices: np.ndarray,
    reference: np.ndarray,
    surface_faces: np.ndarray,
    positions: np.ndarray,
) -> np.ndarray:
    """How far a take stretches the marker surface around every vertex.

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The body in the reference pose.
    reference : (N, 3) float, metres
        The markers in the reference pose (NaN: a marker no triangle uses).
    surface_faces : (F, 3) int
        Marker-surface triangles.
    positions : (T, N, 3) float, metres, NaN where missing

    Returns
    -------
    (V,) float64
        For the marker-surface triangle nearest each vertex in the reference pose (the
        one its part weights β come from), the largest ``|L(t) / L0 - 1|`` of its three
        edges over the frames where both ends are measured (0 where never measured):
        0.5 means an edge grew to 1.5 times or shrank to half its reference length.
    """
    from skincap.geometry.raycast import closest_points_on_mesh

    v = np.asarray(vertices, dtype=np.float64)
    ref = np.asarray(reference, dtype=np.float64)
    x = np.asarray(positions, dtype=np.float64)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    if x.ndim != 3 or x.shape[1:] != ref.shape or ref.ndim != 2 or ref.shape[1] != 3:
        raise ValidationError(
            f"positions (T, N, 3) and reference (N, 3) expected; got {x.shape} and {ref.shape}"
        )
    if f.size and (f.min() < 0 or f.max() >= ref.shape[0]):
        raise ValidationError(f"surface_faces: indices must be in 0..{ref.shape[0] - 1}")
    usable = np.isfinite(ref).all(axis=1)
    f = f[usable[f].all(axis=1)]
    if f.shape[0] == 0:
        raise ValidationError("surface_faces: no triangle with all three markers in the reference")
    a, b = f, np.roll(f, -1, axis=1)  # (F, 3) the three edges a -> b of every triangle
    rest = np.linalg.norm(ref[a] - ref[b], axis=-1)  # (F, 3)
    strain = np.zeros(f.shape[0])
    for t0 in range(0, x.shape[0], _STRAIN_FRAMES):  # blocks of frames bound the temporaries
        block = x[t0 : t0 + _STRAIN_FRAMES]
        length = np.linalg.norm(block[:, a] - block[:, b], axis=-1)  # (t, F, 3), NaN: unmeasured
        ratio = np.divide(length, rest, out=np.full_like(length, np.nan), where=rest > 0)
        change = np.where(np.isfinite(ratio), np.abs(ratio - 1.0), 0.0).max(axis=(0, 2))
        np.maximum(strain, change, out=strain)
    _, face, _ = closest_points_on_mesh(np.where(usable[:, None], ref, 0.0), f, v)
    return strain[face]


def stretch_split(strain: np.ndarray, threshold: float = STRETCH_THRESHOLD) -> np.ndarray:
    """Vertices on stretched marker-surface triangles and the rest.

    Parameters
    ----------
    strain : (V,) float
        :func:`vertex_surface_strain`.
    threshold : float
        Default :data:`STRETCH_THRESHOLD`.

    Returns
    -------
    (V,) str
        ``"stretched"`` where ``strain > threshold``, ``"not stretched"`` elsewhere; the
        regions of :func:`region_errors`.
    """
    e = np.asarray(strain, dtype=np.float64)
    if e.ndim != 1:
        raise ValidationError(f"strain must have shape (V,); got {e.shape}")
    return np.where(e > float(threshold), "stretched", "not stretched")


def global_rbf_frames(
    reference: np.ndarray, positions: np.ndarray, vertices: np.ndarray
) -> np.ndarray:
    """One global RBF interpolation of the marker displacements, applied to the vertices.

    Parameters
    ----------
    reference : (N, 3) float, metres, finite
    positions : (T, N, 3) float, metres (a marker missing at a frame gets the
        displacement of the reference, 0, there)
    vertices : (V, 3) float, metres, in the reference pose

    Returns
    -------
    (T, V, 3) float64, metres
        One thin-plate-spline ``RBFInterpolator`` fitted to all frames' displacements
        at once (values (N, 3T)).
    """
    from scipy.interpolate import RBFInterpolator

    ref = np.asarray(reference, dtype=np.float64)
    x = np.asarray(positions, dtype=np.float64)
    n_t = x.shape[0]
    disp = np.where(np.isfinite(x), x - ref[None], 0.0)  # (T, N, 3)
    values = disp.transpose(1, 0, 2).reshape(ref.shape[0], 3 * n_t)
    moved = RBFInterpolator(ref, values)(np.asarray(vertices, dtype=np.float64))
    return np.asarray(vertices)[None] + moved.reshape(-1, n_t, 3).transpose(1, 0, 2)


def adjusted_rand_index(a: Sequence[int] | np.ndarray, b: Sequence[int] | np.ndarray) -> float:
    """Adjusted Rand index of two labelings of the same items (Hubert & Arabie 1985).

    Parameters
    ----------
    a, b : (n,) int

    Returns
    -------
    float
        1 for identical partitions (up to renaming), about 0 for chance.
    """
    from scipy.special import comb

    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape or a.ndim != 1:
        raise ValidationError(f"labelings must be 1-d of one length; got {a.shape} and {b.shape}")
    _, ia = np.unique(a, return_inverse=True)
    _, ib = np.unique(b, return_inverse=True)
    table = np.zeros((ia.max() + 1, ib.max() + 1))
    np.add.at(table, (ia, ib), 1.0)
    sum_cells = comb(table, 2).sum()
    sum_a = comb(table.sum(1), 2).sum()
    sum_b = comb(table.sum(0), 2).sum()
    expected = sum_a * sum_b / comb(a.size, 2)
    top = 0.5 * (sum_a + sum_b)
    if top == expected:
        return 1.0
    return float((sum_cells - expected) / (top - expected))


def held_out_marker_errors(
    positions: np.ndarray,
    surface_faces: np.ndarray,
    *,
    range_of_motion: np.ndarray | None = None,
    reference_frame: int = 0,
    fraction: float = 0.1,
    n_parts: int = 17,
    method: str = "quadratic_rbf",
    seed: int = 0,
    labels: Sequence[str] | None = None,
) -> dict[str, Any]:
    """Leave ``fraction`` of the markers out, deform, measure where the rest put them.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    surface_faces : (F, 3) int, marker-surface triangles over the N columns
    range_of_motion : (T', N, 3) float, optional
        The take the parts and weights are learnt from (default ``positions``).
    reference_frame : int
        Markers missing there take no part.
    fraction : float
        Share of the markers held out (seeded choice).
    n_parts : int
        Parts of the rig the kept markers build (fewer when the markers are few: at
        least six kept markers a part).
    method : str
    seed : int
    labels : sequence of N str, optional
        Names the worst held-out marker (default: its column number).

    Returns
    -------
    dict
        ``held_out`` count, ``mean_m``, ``p95_m``, ``max_m`` over the measured samples
        of the held-out markers outside the reference frame (where every marker sits
        exactly, so it would only dilute them), ``n_parts``, and ``worst``: the held-out marker with the
        largest error (``marker``, its ``max_m`` and ``mean_m``, the ``frame`` of the max,
        ``nearest_kept_m`` the distance to the nearest kept marker and
        ``to_kept_surface_m`` to the kept markers' surface in the reference frame: how far
        the deformation had to reach for it), or None when no sample was measured.
    """
    from skincap.deform.dense.deformer import DenseDeformer, choose_quadratic_parts
    from skincap.deform.dense.parts import part_frames
    from skincap.deform.dense.rig import marker_weights_of
    from skincap.deform.dense.segmentation import segment_marker_surface
    from skincap.deform.dense.weights import (
        candidates_from_triangle_parts,
        seam_vertex_weights,
        vertex_part_weights,
    )

    x = np.asarray(positions, dtype=np.float64)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    present = np.flatnonzero(np.isfinite(x[reference_frame]).all(axis=1))
    rng = np.random.default_rng(seed)
    n_out = max(1, int(round(fraction * present.size)))
    out = np.sort(rng.choice(present, size=n_out, replace=False))
    keep = np.setdiff1d(present, out)
    new_index = np.full(x.shape[1], -1)
    new_index[keep] = np.arange(keep.size)
    kept_faces = new_index[f]
    kept_faces = kept_faces[(kept_faces >= 0).all(axis=1)]
    ref = x[reference_frame, keep]
    rom = (x if range_of_motion is None else np.asarray(range_of_motion, float))[:, keep]
    parts = int(max(1, min(n_parts, keep.size // 6)))
    seg = segment_marker_surface(rom, ref, kept_faces, n_parts=parts)
    cand = candidates_from_triangle_parts(kept_faces, seg.triangle_parts, keep.size, seg.n_parts)
    alpha = marker_weights_of(rom, ref, cand, kept_faces)
    held_ref = x[reference_frame, out]
    beta = vertex_part_weights(held_ref, ref, kept_faces, alpha)
    seam = seam_vertex_weights(held_ref, ref, kept_faces, alpha > 0)
    frames = part_frames(ref, alpha, surface_faces=kept_faces)
    deformer = DenseDeformer(
        frames, held_ref, beta, seam_weights=seam,
        quadratic_parts=choose_quadratic_parts(rom, frames),
    )  # fmt: skip
    predicted = np.concatenate(list(deformer.deform(x[:, keep], method)))  # type: ignore[arg-type]
    d = np.linalg.norm(predicted - x[:, out], axis=-1)  # (T, held out)
    # the reference frame is where the rig was built: every marker sits there exactly
    d[reference_frame] = np.nan
    dd = d[np.isfinite(d)]
    return {
        "held_out": int(n_out),
        "markers": int(present.size),
        "n_parts": int(seg.n_parts),
        "method": method,
        "mean_m": float(dd.mean()) if dd.size else None,
        "p95_m": float(np.percentile(dd, 95)) if dd.size else None,
        "max_m": float(dd.max()) if dd.size else None,
        "worst": _worst_held_out(d, out, held_ref, ref, kept_faces, labels) if dd.size else None,
    }


def _worst_held_out(
    d: np.ndarray,
    out: np.ndarray,
    held_ref: np.ndarray,
    kept_ref: np.ndarray,
    kept_faces: np.ndarray,
    labels: Sequence[str] | None,
) -> dict[str, Any]:
    """The held-out marker of the largest error ``d`` (T, H) and how far it was from the
    kept markers (``out`` (H,) its columns, ``held_ref`` (H, 3), ``kept_ref`` (K, 3) and
    ``kept_faces`` the kept markers' surface, reference frame)."""
    from scipy.spatial import cKDTree

    from skincap.geometry.raycast import closest_points_on_mesh

    finite = np.isfinite(d)
    worst = np.where(finite, d, -np.inf)
    frame, k = np.unravel_index(int(np.argmax(worst)), d.shape)
    column = int(out[k])
    to_surface = (
        float(closest_points_on_mesh(kept_ref, kept_faces, held_ref[k : k + 1])[0][0])
        if kept_faces.shape[0]
        else None
    )
    return {
        "marker": str(labels[column]) if labels is not None else str(column),
        "max_m": float(d[frame, k]),
        "mean_m": float(d[finite[:, k], k].mean()),
        "frame": int(frame),
        "nearest_kept_m": float(cKDTree(kept_ref).query(held_ref[k])[0]),
        "to_kept_surface_m": to_surface,
    }


def held_out_on_capture(
    markers: Any, *, fraction: float = 0.1, n_parts: int = 17, seed: int = 0
) -> dict[str, Any]:
    """The held-out test on any labelled capture (real ones included).

    The labelled columns (not ``*N``) are used; the marker surface is built from the
    take (:func:`skincap.cleanup.surface.build_marker_surface`), the reference frame is
    the one with the most markers and the take is its own range of motion.

    Parameters
    ----------
    markers : MarkerSet
    fraction, n_parts, seed : see :func:`held_out_marker_errors`

    Returns
    -------
    dict
        :func:`held_out_marker_errors`'s figures plus ``reference_frame`` and
        ``surface_triangles``.
    """
    from skincap.evaluate.capture_surface import labelled_capture_surface

    x, labels, frame, faces = labelled_capture_surface(markers)
    out = held_out_marker_errors(
        x, faces, reference_frame=frame, fraction=fraction, n_parts=n_parts, seed=seed,
        labels=labels,
    )  # fmt: skip
    return {**out, "reference_frame": frame, "surface_triangles": int(faces.shape[0])}


def _read_marker_parts(path: Path, labels: Sequence[str]) -> np.ndarray | None:
    """``truth/marker_parts.csv`` (synth's ``marker,part``) as part numbers (M,) in label
    order, or None when the folder has no such file."""
    if not path.is_file():
        return None
    parts = read_marker_parts(path)
    missing = [lab for lab in labels if lab not in parts]
    if missing:
        raise FormatError(path, f"does not name every marker of the take (no {missing[0]!r})")
    names = sorted(set(parts.values()))
    return np.array([names.index(parts[lab]) for lab in labels])


def evaluate_animate(
    folder: str | os.PathLike[str],
    *,
    methods: Sequence[str] | None = None,
    rom: str | os.PathLike[str] | None = None,
    template: Any = None,
    template_landmarks: dict[str, int] | None = None,
    marker_radius: float = SYNTH_MARKER_HEIGHT_M,
    n_parts: int = 17,
    held_out_fraction: float = 0.1,
    seed: int = 0,
    skeleton_template: str | None = "auto",
    progress: Progress | None = None,
) -> dict[str, Any]:
    """Every row of the dense chain's evaluation on one synthetic take folder.

    Parameters
    ----------
    folder : path-like
        Written by ``skincap synth`` (dense markers).
    methods : sequence of str, optional
        Dense variants (default all four).
    rom : path-like, optional
        A synthetic range-of-motion take of the same body and markers (``skincap synth
        --motion rom``, same seed and resolution) the parts are learnt from; default
        the take itself.
    template : Mesh, optional
        A different body to register to the reference-pose markers (§5.1) and deform:
        the ``registered_template`` row (distances to the true skin surface, since its
        vertices do not correspond to the true skin's).
    template_landmarks : dict of str to int, optional
        Marker label -> template vertex (default: found automatically).
    marker_radius : float, metres
        Height of the marker centres above the skin, for the registration (default
        :data:`SYNTH_MARKER_HEIGHT_M`, where ``skincap synth`` puts them).
    n_parts : int
    held_out_fraction : float
    seed : int
        Of the held-out choice.
    skeleton_template : str or None
        The solve template of the ``skeleton_rbf`` rows (beyond the paper: a skeleton
        solved from the take's markers and calibrated on the take itself, skinned, plus
        the markers' residuals; :mod:`skincap.evaluate.skeleton_rbf`); None leaves them
        out.
    progress : callable(fraction, label), optional

    Returns
    -------
    dict
        ``skeleton`` (the solved skeleton's figures) and ``held_out_skeleton_rbf`` (its
        held-out test, the same markers held out) with ``skeleton_template``;
        ``rows`` (one per case and method: ``case``, ``method``, ``rms_m``, ``mean_m``,
        ``p95_m``, ``max_m``…), ``held_out``, ``segmentation``, ``regions``
        (:func:`region_errors` by the body's dominant skin joint; None without
        ``truth/body.glb``), ``seams`` (:func:`region_errors` by :func:`seam_split` of
        the same-body rig), ``stretch`` (:func:`region_errors` by :func:`stretch_split`
        of the take's own strain of the marker surface), ``targets`` (value,
        target, met), ``per_vertex_rms_m`` (method -> (V,) array, for the colour maps;
        not JSON), ``vertices`` (V, 3) reference-pose vertices and ``faces``.
    """
    from skincap.deform.dense.rig import build_dense_rig

    root = Path(folder)
    step = _stepper(progress)
    take = _read_synthetic_take(root)
    labels, x, truth = take["labels"], take["positions"], take["truth"]
    vertices = truth[0]  # the body in the markers' reference pose (frame 0)
    step(0.05, "segmentation")
    rom_x = x if rom is None else _read_rom_positions(Path(rom), labels)
    surface_faces = take["surface_faces"]
    rig = build_dense_rig(
        vertices, take["faces"], labels, x[0], surface_faces, rom_x, n_parts=n_parts
    )
    rows, per_vertex = _dense_rows(rig, x, truth, methods, step)
    step(0.6, "skeletal skinning")
    rows += _skeletal_rows(root / "truth", truth, per_vertex)
    step(0.75, "global RBF")
    _add_row(
        rows, per_vertex, "same_body", "global_rbf", global_rbf_frames(x[0], x, vertices), truth
    )
    motion = skeleton = None
    if skeleton_template is not None:
        from skincap.evaluate.skeleton_rbf import skeleton_rbf_frames, solved_skeleton

        step(0.76, "skeleton_rbf")
        # calibrated on the take itself: --template auto on the 354-marker ROM took over
        # ten CPU minutes (its loose-marker search), on the take ~15 s
        motion, skeleton = solved_skeleton(x, labels, take["rate"], template=skeleton_template)
        frames = skeleton_rbf_frames(vertices, take["faces"], x, motion)
        _add_row(rows, per_vertex, "same_body", "skeleton_rbf", frames, truth)
    registration: dict[str, Any] | None = None
    regions = _vertex_regions(root / "truth" / "body.glb", vertices.shape[0])
    if template is None:
        rows.append(
            {
                "case": "registered_template",
                "method": "quadratic_rbf",
                "measured": False,
                "note": "no template given (eval animate --template MESH|makehuman)",
            }
        )
    else:
        step(0.77, "registering the template")
        template_rows, registration = _registered_template_row(
            template, take["faces"], labels, x, rom_x, surface_faces, truth,
            n_parts=n_parts, marker_radius=marker_radius, landmarks=template_landmarks,
            regions=regions, motion=motion,
        )  # fmt: skip
        rows += template_rows
    step(0.8, "held-out markers")
    held = held_out_marker_errors(
        x, surface_faces, range_of_motion=rom_x, fraction=held_out_fraction,
        n_parts=n_parts, seed=seed, labels=labels,
    )  # fmt: skip
    held_skeleton = None
    if skeleton_template is not None:
        from skincap.evaluate.skeleton_rbf import held_out_skeleton_rbf

        held_skeleton = held_out_skeleton_rbf(
            x, surface_faces, labels, take["rate"], fraction=held_out_fraction, seed=seed,
            template=skeleton_template,
        )  # fmt: skip
    segmentation = _segmentation_figures(rig, root / "truth" / "marker_parts.csv", labels)
    step(1.0, "done")
    return {
        "folder": str(root),
        "rom": None if rom is None else str(rom),
        "frames": int(x.shape[0]),
        "vertices_count": int(vertices.shape[0]),
        "markers": len(labels),
        "rows": rows,
        "held_out": held,
        "held_out_skeleton_rbf": held_skeleton,
        "skeleton_template": skeleton_template,
        "skeleton": skeleton,
        "segmentation": segmentation,
        "registration": registration,
        "regions": None if regions is None else region_errors(per_vertex, regions),
        "seams": region_errors(per_vertex, seam_split(rig.vertex_weights)),
        "stretch": region_errors(
            per_vertex, stretch_split(vertex_surface_strain(vertices, x[0], surface_faces, x))
        ),
        "targets": _targets(rows, held, segmentation),
        "per_vertex_rms_m": per_vertex,
        "vertices": vertices,
        "faces": take["faces"],
    }


def _read_synthetic_take(root: Path) -> dict[str, Any]:
    """The body markers, the true skin and the marker surface of a synth folder.

    Returns a dict: ``labels`` (N,), ``positions`` (T, N, 3) metres, ``truth``
    (T, V, 3) metres, ``faces`` (F, 3) of the skin, ``surface_faces`` (S, 3); T is the
    shorter of the markers and the skin. Rope markers are left out.
    """
    from skincap import io
    from skincap.io.pc2 import read_pc2

    truth_dir = root / "truth"
    for name in ("markers.c3d", "mesh.pc2", "mesh.obj", "marker_surface.ply"):
        if not (truth_dir / name).is_file():
            raise FormatError(root, f"not a synthetic dense take: truth/{name} is missing")
    markers = io.read(truth_dir / "markers.c3d")
    columns = [i for i, s in enumerate(markers.labels) if not str(s).startswith("rope")]
    labels = [str(markers.labels[i]) for i in columns]
    truth = np.asarray(read_pc2(truth_dir / "mesh.pc2").frames, dtype=np.float64)
    surface = io.read(truth_dir / "marker_surface.ply")
    if surface.n_vertices != len(labels):
        raise FormatError(
            truth_dir / "marker_surface.ply",
            f"{surface.n_vertices} vertices for {len(labels)} body markers",
        )
    n_t = min(markers.positions.shape[0], truth.shape[0])
    return {
        "labels": labels,
        "positions": markers.positions[:n_t, columns],
        "truth": truth[:n_t],
        "faces": io.read(truth_dir / "mesh.obj").faces,
        "surface_faces": surface.faces,
        "rate": float(markers.rate),
    }


def _vertex_regions(body_path: Path, n_vertices: int) -> np.ndarray | None:
    """(V,) str: the joint weighing most on every vertex in the body's skin weights, or
    None without ``truth/body.glb``, a skin, or one vertex per skin vertex."""
    from skincap import io

    if not body_path.is_file():
        return None
    skin = io.read_mesh(body_path).skin
    if skin is None or skin.joint_weights.shape[0] != n_vertices:
        return None
    rows = np.arange(n_vertices)
    dominant = skin.joint_indices[rows, np.argmax(skin.joint_weights, axis=1)]
    return np.asarray(skin.skeleton.names, dtype=str)[dominant]


def _read_rom_positions(rom: Path, labels: Sequence[str]) -> np.ndarray:
    """(T', N, 3) positions of a synthetic range-of-motion take, in ``labels`` order."""
    from skincap import io

    rom_markers = io.read(rom / "truth" / "markers.c3d")
    where = {str(s): i for i, s in enumerate(rom_markers.labels)}
    if any(lab not in where for lab in labels):
        raise FormatError(rom, "the range-of-motion take has other markers")
    return rom_markers.positions[:, [where[lab] for lab in labels]]


def _dense_rows(
    rig: Any,
    x: np.ndarray,
    truth: np.ndarray,
    methods: Sequence[str] | None,
    step: Callable[[float, str], None],
) -> tuple[list[dict[str, Any]], dict[str, np.ndarray]]:
    """One ``same_body`` row per dense variant, and each one's per-vertex RMS."""
    from skincap.deform.dense.deformer import METHODS

    rows: list[dict[str, Any]] = []
    per_vertex: dict[str, np.ndarray] = {}
    deformer = rig.deformer()
    chosen = list(METHODS if methods is None else methods)
    for i, method in enumerate(chosen):
        step(0.1 + 0.5 * i / len(chosen), f"deforming ({method})")
        frames = np.concatenate(list(deformer.deform(x, method)))
        _add_row(rows, per_vertex, "same_body", method, frames, truth)
    return rows, per_vertex


def _segmentation_figures(rig: Any, parts_file: Path, labels: Sequence[str]) -> dict[str, Any]:
    """Part count, markers per part and, with ``truth/marker_parts.csv``, the ARI."""
    segmentation: dict[str, Any] = {
        "n_parts": rig.n_parts,
        "markers_per_part": [int(c) for c in (rig.marker_weights > 0).sum(0)],
    }
    true_parts = _read_marker_parts(parts_file, labels)
    if true_parts is not None:
        seen = rig.marker_parts >= 0
        segmentation["ari"] = adjusted_rand_index(true_parts[seen], rig.marker_parts[seen])
    return segmentation


def _stepper(progress: Progress | None) -> Callable[[float, str], None]:
    def step(fraction: float, label: str) -> None:
        if progress is not None:
            progress(fraction, label)

    return step


def _add_row(
    rows: list[dict[str, Any]],
    per_vertex: dict[str, np.ndarray],
    case: str,
    method: str,
    frames: np.ndarray,
    truth: np.ndarray,
) -> None:
    figures = vertex_errors(frames, truth)
    per_vertex[method] = figures.pop("per_vertex_rms_m")
    rows.append({"case": case, "method": method, "measured": True, **figures})


def _surface_distances(
    frames: np.ndarray, truth: np.ndarray, faces: np.ndarray, picks: np.ndarray
) -> np.ndarray:
    """(len(picks), V') distance of every deformed vertex to the true skin surface, metres."""
    from skincap.geometry.raycast import closest_points_on_mesh

    # one closest-point query per picked frame (a handful): the surface changes per frame
    return np.stack([closest_points_on_mesh(truth[t], faces, frames[t])[0] for t in picks])


def _registered_template_row(
    template: Any,
    skin_faces: np.ndarray,
    labels: list[str],
    x: np.ndarray,
    rom_x: np.ndarray,
    surface_faces: np.ndarray,
    truth: np.ndarray,
    *,
    n_parts: int,
    marker_radius: float,
    landmarks: dict[str, int] | None,
    regions: np.ndarray | None = None,
    motion: Any = None,
) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Register another body to the markers, deform it, measure it against the true skin.

    ``regions`` (V,) names each true-skin vertex's region (its dominant skin joint): the
    registration's figures then break down by region (where its p95 comes from). With
    ``motion`` (the skeleton solved from the markers) a ``skeleton_rbf`` row follows the
    ``quadratic_rbf`` one.
    """
    from skincap.deform.dense.registration import RegistrationSettings, register_mesh
    from skincap.deform.dense.rig import build_dense_rig
    from skincap.evaluate.registration import (
        marker_normal_errors,
        marker_surface_bound,
        registration_errors,
    )

    settings = RegistrationSettings(marker_radius=marker_radius)
    t0, cpu0 = time.perf_counter(), time.process_time()
    reg = register_mesh(
        template.vertices, template.faces, x[0], labels, landmarks=landmarks,
        marker_faces=surface_faces, settings=settings,
    )  # fmt: skip
    registration = {
        "template_vertices": int(template.vertices.shape[0]),
        "landmarks": len(reg.landmarks),
        "seconds": time.perf_counter() - t0,
        "cpu_seconds": time.process_time() - cpu0,
        # the markers' residual: their centres sit one marker radius above the skin
        **registration_errors(
            reg.vertices,
            template.faces,
            truth[0],
            skin_faces,
            np.abs(reg.marker_distance - marker_radius),
            regions,
        ),
        # what the markers can say at all: the reverse term's targets at the true skin
        "marker_surface_bound": marker_surface_bound(
            truth[0],
            skin_faces,
            x[0],
            surface_faces,
            marker_radius=marker_radius,
            max_distance=settings.surface_max_distance,
            patch_ratio=settings.normal_patch_ratio,
            regions=regions,
        ),
        # the normals the registration lifted the marker surface with, against the truth
        "marker_normals": marker_normal_errors(
            reg.vertices,
            template.faces,
            truth[0],
            skin_faces,
            x[0],
            surface_faces,
            patch_ratio=settings.normal_patch_ratio,
            regions=regions,
        ),
    }
    rig = build_dense_rig(
        reg.vertices, template.faces, labels, x[0], surface_faces, rom_x, n_parts=n_parts
    )
    picks = np.unique(np.linspace(0, x.shape[0] - 1, 8).round().astype(int))
    methods = {
        "quadratic_rbf": lambda: np.concatenate(list(rig.deformer().deform(x, "quadratic_rbf")))
    }
    if motion is not None:
        from skincap.evaluate.skeleton_rbf import skeleton_rbf_frames

        methods["skeleton_rbf"] = lambda: skeleton_rbf_frames(
            reg.vertices, template.faces, x, motion
        )
    rows = []
    for method, deform in methods.items():
        d = _surface_distances(deform(), truth, skin_faces, picks).ravel()
        rows.append(
            {
                "case": "registered_template",
                "method": method,
                "measured": True,
                "metric": "deformed template vertex to the true skin surface, 8 frames",
                "rms_m": float(np.sqrt(np.mean(d**2))),
                "mean_m": float(d.mean()),
                "p95_m": float(np.percentile(d, 95)),
                "max_m": float(d.max()),
                "nan_fraction": 0.0,
            }
        )
    return rows, registration


def _skeletal_rows(
    truth_dir: Path, truth: np.ndarray, per_vertex: dict[str, np.ndarray]
) -> list[dict[str, Any]]:
    """LBS and DQS of the synthetic body driven by the true skeleton."""
    from skincap import io
    from skincap.deform.skeletal.deformers import skin_motion
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.io.bvh import read_bvh

    body_path, motion_path = truth_dir / "body.glb", truth_dir / "motion.bvh"
    if not (body_path.is_file() and motion_path.is_file()):
        return [{"case": "true_skeleton", "method": m, "measured": False,
                 "note": "truth/body.glb or truth/motion.bvh missing"} for m in ("lbs", "dqs")]  # fmt: skip
    setup = prepare_skinning(io.read_mesh(body_path), read_bvh(motion_path))
    rows: list[dict[str, Any]] = []
    for method in ("lbs", "dqs"):
        anim = skin_motion(setup.mesh, setup.motion, method=method)
        frames = np.concatenate(list(anim.iter_chunks()))[: truth.shape[0]]
        if frames.shape != truth.shape:
            rows.append({"case": "true_skeleton", "method": method, "measured": False,
                         "note": f"skinned body {frames.shape} does not match the skin {truth.shape}"})  # fmt: skip
            continue
        _add_row(rows, per_vertex, "true_skeleton", method, frames, truth)
    return rows


def _targets(
    rows: list[dict[str, Any]], held: dict[str, Any], segmentation: dict[str, Any]
) -> dict[str, dict[str, Any]]:
    rms = {
        r["method"]: r["rms_m"]
        for r in rows
        if r.get("measured") and r["case"] != "registered_template"
    }
    registered = [
        r["rms_m"]
        for r in rows
        if r["case"] == "registered_template"
        and r.get("measured")
        and r["method"] == "quadratic_rbf"
    ]
    q = rms.get("quadratic_rbf")

    def reduction(base: str, method: str = "quadratic_rbf") -> float | None:
        ours = rms.get(method)
        return None if ours is None or base not in rms else 1.0 - ours / rms[base]

    values: dict[str, float | None] = {
        "quadratic_rbf_same_body_rms_m": q,
        "quadratic_rbf_registered_template_rms_m": registered[0] if registered else None,
        "quadratic_rbf_vs_rigid_reduction": reduction("rigid"),
        "quadratic_rbf_vs_lbs_reduction": reduction("lbs"),
        "skeleton_rbf_vs_lbs_reduction": reduction("lbs", "skeleton_rbf"),
        "held_out_mean_m": held.get("mean_m"),
        "segmentation_ari": segmentation.get("ari"),
    }
    out: dict[str, dict[str, Any]] = {}
    for name, target in TARGETS.items():
        value = values[name]
        higher = name.endswith("reduction") or name == "segmentation_ari"
        met = None if value is None else (value >= target if higher else value <= target)
        out[name] = {"value": value, "target": target, "met": met}
    return out


def plot_vertex_errors(
    vertices: np.ndarray,
    per_vertex_rms: dict[str, np.ndarray],
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    title: str | None = None,
) -> Path:
    """Error colour maps on the body, front view, one panel per method, one shared scale.

    Parameters
    ----------
    vertices : (V, 3) float, metres, Y up, facing +Z
    per_vertex_rms : method -> (V,) float, metres
    path : path-like, ``.png`` (written atomically)

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed (extra ``plot``).
    """
    from skincap.io._common import atomic_output
    from skincap.viz.plotting import agg_pyplot

    plt = agg_pyplot("PNG plots")
    v = np.asarray(vertices, dtype=np.float64)
    names = list(per_vertex_rms)
    top = max(float(np.percentile(per_vertex_rms[m], 99)) for m in names) * 1e3
    order = np.argsort(v[:, 2])  # far vertices drawn first
    # at most four panels a row, rows filled evenly, each big enough to see an upper arm
    n_rows = -(-len(names) // 4)
    n_cols = -(-len(names) // n_rows)
    fig, axes = plt.subplots(
        n_rows,
        n_cols,
        figsize=(3.3 * n_cols + 0.9, 3.3 * n_rows + 0.4),
        dpi=110,
        squeeze=False,
        layout="constrained",
    )
    # dots (area, points²) about one vertex spacing across, whatever the mesh's resolution
    dot = float(np.clip(7.0 * 5000.0 / max(len(v), 1), 0.3, 12.0))
    lo, hi = v[:, :2].min(axis=0), v[:, :2].max(axis=0)
    pad = 0.03 * float((hi - lo).max())
    try:
        for ax in axes.ravel()[len(names) :]:
            ax.axis("off")
        for ax, name in zip(axes.ravel(), names, strict=False):
            err = per_vertex_rms[name][order] * 1e3
            sc = ax.scatter(
                v[order, 0], v[order, 1], c=err, s=dot, cmap="magma", vmin=0, vmax=top, lw=0
            )
            rms = float(np.sqrt(np.mean(per_vertex_rms[name] ** 2)) * 1e3)
            ax.set_title(f"{name}\n{rms:.2f} mm RMS", fontsize=9)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.set_aspect("equal")
            ax.axis("off")
        fig.colorbar(sc, ax=axes.ravel().tolist(), shrink=0.7, label="vertex RMS error (mm)")
        if title:
            fig.suptitle(title, fontsize=10)
        with atomic_output(path, force=force) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return Path(path)
