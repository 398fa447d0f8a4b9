"""``skeleton_rbf`` measured: the skeleton solved from the markers, skinned, plus the
markers' residuals (:mod:`skincap.deform.dense.skeleton_rbf`), against the true skin and
on held-out markers.

The skeleton is solved here (evaluation sits above both ``solve`` and ``deform``):
calibrated on the range-of-motion take when one is given (``--template auto`` by
default: no truth is read), then posed on the take by inverse kinematics.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = ["held_out_skeleton_rbf", "skeleton_rbf_frames", "solved_skeleton"]


def solved_skeleton(
    positions: np.ndarray,
    labels: Sequence[str],
    rate: float,
    *,
    range_of_motion: np.ndarray | None = None,
    template: Any = "auto",
) -> tuple[Any, dict[str, Any]]:
    """The take's skeleton motion solved from its own markers.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    labels : N str
    rate : float, Hz
    range_of_motion : (T', N, 3) float, optional
        The calibration take, same markers (default the take).
    template : str
        ``"auto"``, a built-in template name or a JSON file.

    Returns
    -------
    motion : Motion (T frames, metres)
    figures : dict
        ``joints``, ``markers_used``, ``residual_rms_m``, ``cpu_seconds``.
    """
    import time

    from skincap.solve.with_rom import solve_with_range_of_motion
    from skincap.types import MarkerSet

    cpu0 = time.process_time()
    take = MarkerSet(positions=np.asarray(positions, float), labels=list(labels), rate=rate)
    rom = None
    if range_of_motion is not None:
        rom = MarkerSet(
            positions=np.asarray(range_of_motion, float), labels=list(labels), rate=rate
        )
    solved = solve_with_range_of_motion(take, rom, template=template)
    return solved.motion, {
        "joints": int(solved.motion.skeleton.n_joints),
        "markers_used": len(solved.model.marker_labels),
        "residual_rms_m": float(np.sqrt(np.nanmean(solved.residuals**2))),
        "cpu_seconds": time.process_time() - cpu0,
    }


def skeleton_rbf_frames(
    vertices: np.ndarray,
    faces: np.ndarray,
    positions: np.ndarray,
    motion: Any,
    *,
    reference_frame: int = 0,
    kernel: str = "thin_plate",
    skin_weights: str = "fitted",
) -> np.ndarray:
    """(T, V, 3) deformed vertices of the mesh (in the pose of ``reference_frame``); the
    skin weights fitted to the take's markers unless ``skin_weights="bone_heat"``."""
    from skincap.deform.dense.skeleton_rbf import build_skeleton_rbf

    x = np.asarray(positions, dtype=np.float64)
    deformer = build_skeleton_rbf(
        vertices, faces, x[reference_frame], motion, reference_frame, positions=x,
        skin_weights=skin_weights, kernel=kernel,
    )  # fmt: skip
    return np.concatenate(list(deformer.deform(x, motion)))


def held_out_skeleton_rbf(
    positions: np.ndarray,
    surface_faces: np.ndarray,
    labels: Sequence[str],
    rate: float,
    *,
    range_of_motion: np.ndarray | None = None,
    reference_frame: int = 0,
    fraction: float = 0.1,
    seed: int = 0,
    template: Any = "auto",
    kernel: str = "thin_plate",
    skin_weights: str = "fitted",
) -> dict[str, Any]:
    """Leave ``fraction`` of the markers out of the solve and the residual fit, predict them.

    The held-out markers are points of the body: their skin weights come from bone heat on
    the marker surface (all markers as its vertices, bound to the skeleton solved from the
    kept markers in the reference frame), so no truth and no mesh is needed, and they take
    no part in the solve or the residual interpolation. With ``skin_weights="fitted"``
    the kept markers' weights are fitted to their trajectories and the corrections
    carried to every marker-surface vertex (kept and held out) as they are to a mesh's
    vertices; the held-out markers' own motion is not used. The same seeded choice as
    :func:`skincap.evaluate.animate.held_out_marker_errors`.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing
    surface_faces : (F, 3) int, marker-surface triangles
    labels : N str; rate : float, Hz
    range_of_motion : (T', N, 3), optional
    reference_frame, fraction, seed, template, kernel

    Returns
    -------
    dict
        ``held_out``, ``markers``, ``mean_m``, ``p95_m``, ``max_m`` over the measured
        samples outside the reference frame, ``skeleton`` (:func:`solved_skeleton`'s figures).
    """
    from skincap.deform.dense.skeleton_rbf import SkeletonRBFDeformer
    from skincap.deform.skeletal.bind import bind_mesh
    from skincap.geometry.kinematics import forward_kinematics
    from skincap.types import Mesh

    x = np.asarray(positions, dtype=np.float64)
    f = np.asarray(surface_faces, dtype=np.int64).reshape(-1, 3)
    present = np.flatnonzero(np.isfinite(x[reference_frame]).all(axis=1))
    if present.size < 10:
        raise ValidationError(f"{present.size} markers in the reference frame; 10 needed")
    rng = np.random.default_rng(seed)
    n_out = max(1, int(round(fraction * present.size)))
    out = np.sort(rng.choice(present, size=n_out, replace=False))
    keep = np.setdiff1d(present, out)
    rom = None if range_of_motion is None else np.asarray(range_of_motion, float)[:, keep]
    motion, figures = solved_skeleton(
        x[:, keep], [labels[i] for i in keep], rate, range_of_motion=rom, template=template
    )
    # the marker surface over the reference frame's markers (missing ones: no triangle)
    ref = x[reference_frame]
    usable = f[np.isin(f, present).all(axis=1)]
    index = np.full(x.shape[1], -1)
    index[present] = np.arange(present.size)
    world = forward_kinematics(motion)
    surface = bind_mesh(
        Mesh(vertices=ref[present], faces=index[usable]), motion.skeleton,
        rest_world=world[reference_frame],
    )  # fmt: skip
    assert surface.skin is not None  # bind_mesh always gives one
    idx, w = surface.skin.joint_indices, surface.skin.joint_weights
    kept_rows, out_rows = index[keep], index[out]
    if skin_weights == "fitted":
        from skincap.deform.skeletal.fit_weights import (
            carry_weight_corrections,
            dense_weights,
            fit_point_skin_weights,
        )

        n_j = motion.skeleton.n_joints
        prior = dense_weights(idx, w, n_j)  # (present, J)
        skinning = np.einsum("tjab,jbc->tjac", world, np.linalg.inv(world[reference_frame]))
        fitted = fit_point_skin_weights(
            ref[keep], x[:, keep], skinning, prior[kept_rows], motion.skeleton.parents
        )
        idx, w = carry_weight_corrections(
            ref[present], prior, ref[keep], prior[kept_rows], fitted,
            max_influences=idx.shape[1],
        )  # fmt: skip
    deformer = SkeletonRBFDeformer(
        ref[keep], idx[kept_rows], w[kept_rows], ref[keep], idx[kept_rows], w[kept_rows],
        world[reference_frame], kernel=kernel,
    )  # fmt: skip
    predicted = deformer.deform_frames(
        x[:, keep], world, points=ref[out],
        point_joint_indices=idx[out_rows], point_joint_weights=w[out_rows],
    )  # fmt: skip
    d = np.linalg.norm(predicted - x[:, out], axis=-1)
    d[reference_frame] = np.nan  # as held_out_marker_errors: exact there by construction
    dd = d[np.isfinite(d)]
    return {
        "method": "skeleton_rbf",
        "held_out": int(n_out),
        "markers": int(present.size),
        "mean_m": float(dd.mean()) if dd.size else None,
        "p95_m": float(np.percentile(dd, 95)) if dd.size else None,
        "max_m": float(dd.max()) if dd.size else None,
        "skeleton": figures,
    }


def held_out_skeleton_rbf_on_capture(
    markers: Any,
    *,
    fraction: float = 0.1,
    seed: int = 0,
    template: Any = "auto",
    skin_weights: str = "fitted",
) -> dict[str, Any]:
    """:func:`held_out_skeleton_rbf` on any labelled capture (real ones included).

    Like :func:`skincap.evaluate.animate.held_out_on_capture`: the labelled columns,
    the marker surface built from the take, the frame with the most markers as the
    reference, the take as its own calibration.

    Returns
    -------
    dict
        :func:`held_out_skeleton_rbf`'s figures plus ``reference_frame``; or ``mean_m``
        None and a ``note`` when the kept markers calibrate no skeleton on ``template``.
    """
    from skincap.evaluate.capture_surface import labelled_capture_surface

    x, labels, frame, faces = labelled_capture_surface(markers)
    try:
        out = held_out_skeleton_rbf(
            x, faces, labels, float(markers.rate),
            reference_frame=frame, fraction=fraction, seed=seed, template=template,
            skin_weights=skin_weights,
        )  # fmt: skip
    except ValidationError as exc:  # the kept markers do not calibrate a skeleton
        return {"method": "skeleton_rbf", "mean_m": None, "note": f"not measured: {exc}"}
    return {**out, "reference_frame": frame}
