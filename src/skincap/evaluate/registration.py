"""How well a registered template matches the true skin (issue #16's registration row).

A template registered to markers (:func:`skincap.deform.dense.registration.register_mesh`)
has other vertices than the skin the markers were captured on, so it is compared
surface to surface, both ways (the scan-to-mesh measure of Allen et al. 2003 and
MoSh++, in both directions so that neither a shrunken nor a bloated fit hides):

- every registered vertex to the true skin surface (closest point on its triangles);
- every true skin vertex to the registered surface (a fold or a missed limb shows here).

Plus each marker's distance to the registered surface (how closely the data term was
met). Nothing here prints.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.errors import ValidationError
from skincap.geometry.raycast import closest_points_on_mesh

__all__ = ["REGISTRATION_TARGETS", "registration_errors"]

#: The targets of issue #16 for the registration, metres.
REGISTRATION_TARGETS: dict[str, float] = {
    "markers_to_surface_mean_m": 0.001,
    "surface_to_true_skin_mean_m": 0.003,
    "surface_to_true_skin_p95_m": 0.008,
}


#: Query points per closest-point call: bounds the memory of the candidate pairs. A
#: registered template may carry a few long (stretched) edges, and every query then
#: meets every triangle within its nearest-vertex distance plus the longest edge: the
#: MakeHuman body on the procedural markers peaked at 1.07 GB with blocks of 2000,
#: 0.32 GB with blocks of 100, at the same CPU time.
_QUERY_BLOCK = 100


def _distances_to_surface(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """(N,) distance of each of ``points`` (N, 3) to the mesh, metres, in blocks of points."""
    return np.concatenate(
        [
            closest_points_on_mesh(vertices, faces, points[k : k + _QUERY_BLOCK])[0]
            for k in range(0, points.shape[0], _QUERY_BLOCK)
        ]
    )


def _summary(d: np.ndarray) -> tuple[float, float, float]:
    return float(d.mean()), float(np.percentile(d, 95)), float(d.max())


def registration_errors(
    registered: np.ndarray,
    faces: np.ndarray,
    true_vertices: np.ndarray,
    true_faces: np.ndarray,
    marker_distance: np.ndarray | None = None,
) -> dict[str, Any]:
    """Distances between a registered template and the true skin, both ways, metres.

    Parameters
    ----------
    registered : (V, 3) float, metres
        The registered template's vertices.
    faces : (F, 3) int
        Its triangles.
    true_vertices : (V', 3) float, metres
        The true skin in the same pose (the capture's reference frame).
    true_faces : (F', 3) int
        Its triangles.
    marker_distance : (M,) float, metres, optional
        Each marker's residual: its distance to the registered surface, less the
        marker radius when the surface was fitted under the marker centres (NaN:
        unseen, skipped).

    Returns
    -------
    dict
        ``surface_to_true_skin_{mean,p95,max}_m`` (registered vertices to the true
        surface), ``true_skin_to_surface_{mean,p95,max}_m`` (the reverse),
        ``markers_to_surface_{mean,p95}_m`` when ``marker_distance`` is given, and
        ``targets``: each issue target with its value and whether it is met.

    Raises
    ------
    ValidationError
        An array of the wrong shape or with NaN vertices.
    """
    reg = np.asarray(registered, dtype=np.float64)
    true = np.asarray(true_vertices, dtype=np.float64)
    for name, value in (("registered", reg), ("true_vertices", true)):
        if value.ndim != 2 or value.shape[1] != 3 or value.shape[0] == 0:
            raise ValidationError(f"{name}: expected shape (V, 3), got {value.shape}")
        if not np.isfinite(value).all():
            raise ValidationError(f"{name}: vertices must be finite")
    forward = _distances_to_surface(true, np.asarray(true_faces), reg)
    backward = _distances_to_surface(reg, np.asarray(faces), true)
    out: dict[str, Any] = {}
    for prefix, d in (("surface_to_true_skin", forward), ("true_skin_to_surface", backward)):
        mean, p95, top = _summary(d)
        out |= {f"{prefix}_mean_m": mean, f"{prefix}_p95_m": p95, f"{prefix}_max_m": top}
    if marker_distance is not None:
        md = np.asarray(marker_distance, dtype=np.float64).ravel()
        md = md[np.isfinite(md)]
        if md.size:
            out["markers_to_surface_mean_m"] = float(md.mean())
            out["markers_to_surface_p95_m"] = float(np.percentile(md, 95))
    out["targets"] = {
        name: {
            "value": out.get(name),
            "target": target,
            "met": None if out.get(name) is None else bool(out[name] <= target),
        }
        for name, target in REGISTRATION_TARGETS.items()
    }
    return out
