"""How well a registered template matches the true skin (issue #16's registration row).

A template registered to markers (:func:`skincap.deform.dense.registration.register_mesh`)
has other vertices than the skin the markers were captured on, so it is compared
surface to surface, both ways (the scan-to-mesh measure of Allen et al. 2003 and
MoSh++, in both directions so that neither a shrunken nor a bloated fit hides):

- every registered vertex to the true skin surface (closest point on its triangles);
- every true skin vertex to the registered surface (a fold or a missed limb shows here).

Plus each marker's distance to the registered surface (how closely the data term was
met), and, given a region name per true-skin vertex (the dominant joint of its skin
weights), the registered surface's distance per region with each region's share of
the worst 5 % (where the p95 comes from) and on which side of the skin it lies (a
surface sunk under the skin between sparse markers, or bulging out of it).

And what the markers can say at all (:func:`marker_surface_bound`): the registration's
reverse data term (:mod:`skincap.deform.dense.surface_targets`) evaluated on the true
skin itself, as if the template were already exact -- how much of the skin the smoothed
marker surface covers and how far its targets lie from the skin there, per region.
Where it covers little (feet, head, hands) or misses by more than a target allows,
only the template's own shape can do better. The Phong lift is only as good as the
normals at the markers, so :func:`marker_normal_errors` measures the registration's own
(the registered template's, as its last iteration takes them) against the true skin's at
each marker, in degrees, and the bound is also given with the true skin's normals at the
markers (``exact_normals``): what any better estimate of them could gain at most.
Nothing here prints.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from skincap.deform.dense.surface_targets import lift_normals, marker_surface_targets
from skincap.errors import ValidationError
from skincap.geometry.normals import area_weighted_vertex_normals
from skincap.geometry.raycast import closest_points_on_mesh

__all__ = [
    "REGISTRATION_TARGETS",
    "marker_normal_errors",
    "marker_surface_bound",
    "region_breakdown",
    "true_marker_normals",
    "registration_errors",
]

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


def _closest_on_surface(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closest point of each of ``points`` (N, 3) on the mesh, in blocks of points.

    Returns distance (N,) metres, face (N,) and barycentric weights (N, 3).
    """
    parts = [
        closest_points_on_mesh(vertices, faces, points[k : k + _QUERY_BLOCK])
        for k in range(0, points.shape[0], _QUERY_BLOCK)
    ]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]


def _distances_to_surface(
    vertices: np.ndarray, faces: np.ndarray, points: np.ndarray
) -> np.ndarray:
    """(N,) distance of each of ``points`` (N, 3) to the mesh, metres, in blocks of points."""
    return _closest_on_surface(vertices, faces, points)[0]


def region_breakdown(
    distance: np.ndarray, region: np.ndarray, signed: np.ndarray | None = None
) -> list[dict[str, Any]]:
    """Distances grouped by region, the regions holding most of the worst 5 % first.

    Parameters
    ----------
    distance : (N,) float, metres
        Each registered vertex's distance to the true skin.
    region : (N,) str
        The region of each (of its closest true-skin point).
    signed : (N,) float, metres, optional
        The same distances signed by side: positive outside the true skin, negative
        under it.

    Returns
    -------
    list of dict
        One per region: ``region``, ``vertices``, ``mean_m``, ``p95_m``, ``max_m`` and
        ``tail_share`` (its fraction of the vertices at or beyond the overall 95th percentile),
        sorted by ``tail_share`` then ``mean_m``, both descending. With ``signed``, also
        ``signed_mean_m`` (the region's mean signed distance, metres) and
        ``tail_inside_fraction`` (the fraction of its worst-5 % vertices under the skin;
        None when it has none).
    """
    d = np.asarray(distance, dtype=np.float64).ravel()
    names = np.asarray(region).astype(str).ravel()
    if names.shape != d.shape:
        raise ValidationError(f"regions: expected {d.size} names, got {names.size}")
    side = None if signed is None else np.asarray(signed, dtype=np.float64).ravel()
    if side is not None and side.shape != d.shape:
        raise ValidationError(f"signed: expected {d.size} distances, got {side.size}")
    if d.size == 0:
        return []
    tail = d >= np.percentile(d, 95)
    n_tail = max(int(tail.sum()), 1)
    keys, inverse = np.unique(names, return_inverse=True)
    rows = []
    for k, key in enumerate(keys):
        s = inverse == k
        mean, p95, top = _summary(d[s])
        row: dict[str, Any] = {
            "region": str(key),
            "vertices": int(s.sum()),
            "mean_m": mean,
            "p95_m": p95,
            "max_m": top,
            "tail_share": float(tail[s].sum() / n_tail),
        }
        if side is not None:
            in_tail = tail & s
            row["signed_mean_m"] = float(side[s].mean())
            row["tail_inside_fraction"] = (
                float((side[in_tail] < 0).mean()) if in_tail.any() else None
            )
        rows.append(row)
    rows.sort(key=lambda r: (-r["tail_share"], -r["mean_m"]))
    return rows


def _side(
    true_vertices: np.ndarray,
    true_faces: np.ndarray,
    points: np.ndarray,
    face: np.ndarray,
    bary: np.ndarray,
) -> np.ndarray:
    """(N,) +1 for a point outside the true skin, -1 under it, from its closest point.

    The side is that of the offset from the closest point along the skin's normal
    there, blended from its triangle's corner normals (the face normal alone flips at
    a closest point on an edge or a corner of a convex region).
    """
    normals = area_weighted_vertex_normals(true_vertices, true_faces)
    corners = true_faces[face]  # (N, 3)
    at = np.einsum("nc,ncx->nx", bary, normals[corners])
    closest = np.einsum("nc,ncx->nx", bary, true_vertices[corners])
    return np.where(np.einsum("nx,nx->n", points - closest, at) < 0, -1.0, 1.0)


def _summary(d: np.ndarray) -> tuple[float, float, float]:
    return float(d.mean()), float(np.percentile(d, 95)), float(d.max())


def registration_errors(
    registered: np.ndarray,
    faces: np.ndarray,
    true_vertices: np.ndarray,
    true_faces: np.ndarray,
    marker_distance: np.ndarray | None = None,
    regions: np.ndarray | None = None,
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
    regions : (V',) str, optional
        A region name per true-skin vertex (e.g. the joint weighing most on it); a
        registered vertex takes the region of the corner nearest its closest point.

    Returns
    -------
    dict
        ``surface_to_true_skin_{mean,p95,max}_m`` (registered vertices to the true
        surface), ``true_skin_to_surface_{mean,p95,max}_m`` (the reverse),
        ``surface_to_true_skin_inside_fraction`` (the fraction of registered vertices
        under the true skin: a registration sunk in or bulging out),
        ``markers_to_surface_{mean,p95}_m`` when ``marker_distance`` is given,
        ``regions`` (:func:`region_breakdown` of the registered vertices, with their
        signed distances) when
        ``regions`` is given, and ``targets``: each issue target with its value and whether it is met.

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
    true_f = np.asarray(true_faces)
    if regions is not None and np.asarray(regions).shape != (true.shape[0],):
        raise ValidationError(
            f"regions: expected one name per true-skin vertex ({true.shape[0]}), "
            f"got shape {np.asarray(regions).shape}"
        )
    forward, face, bary = _closest_on_surface(true, true_f, reg)
    backward = _distances_to_surface(reg, np.asarray(faces), true)
    out: dict[str, Any] = {}
    for prefix, d in (("surface_to_true_skin", forward), ("true_skin_to_surface", backward)):
        mean, p95, top = _summary(d)
        out |= {f"{prefix}_mean_m": mean, f"{prefix}_p95_m": p95, f"{prefix}_max_m": top}
    signed = forward * _side(true, true_f, reg, face, bary)
    out["surface_to_true_skin_inside_fraction"] = float((signed < 0).mean())
    if regions is not None:
        corner = true_f[face, np.argmax(bary, axis=1)]
        out["regions"] = region_breakdown(forward, np.asarray(regions).astype(str)[corner], signed)
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


def _vertex_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(V,) a third of the area of each vertex's triangles, square metres."""
    p = vertices[faces]
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    return np.bincount(faces.ravel(), np.repeat(area / 3.0, 3), minlength=vertices.shape[0])


def _weighted_p95(d: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(d)
    cumulative = np.cumsum(w[order])
    return float(d[order][min(np.searchsorted(cumulative, 0.95 * cumulative[-1]), d.size - 1)])


def marker_surface_bound(
    true_vertices: np.ndarray,
    true_faces: np.ndarray,
    markers: np.ndarray,
    marker_faces: np.ndarray,
    *,
    marker_radius: float,
    max_distance: float,
    patch_ratio: float,
    regions: np.ndarray | None = None,
) -> dict[str, Any]:
    """What the marker surface says about the true skin: coverage and error, area-weighted.

    The registration's reverse term pulls each template vertex to its target on the
    smoothed marker surface (:func:`skincap.deform.dense.surface_targets.marker_surface_targets`).
    Here the "template" is the true skin itself (its own normals as the reference), so
    the result is the best that term can do: the fraction of the skin's area it speaks
    for, and how far its targets lie from the skin there. A registration following the
    markers cannot beat it where it covers; where it does not, only the template's
    shape places the surface.

    Parameters
    ----------
    true_vertices : (V, 3) float, metres; true_faces : (F, 3) int
        The true skin in the markers' pose.
    markers : (M, 3) float, metres (NaN rows: unseen)
    marker_faces : (G, 3) int
        The marker surface's triangles over the marker rows.
    marker_radius, max_distance, patch_ratio : float
        As the registration uses them (:class:`skincap.deform.dense.registration.RegistrationSettings`).
    regions : (V,) str, optional
        A region name per true-skin vertex.

    Returns
    -------
    dict
        ``covered_area_fraction``, and over the covered area ``target_mean_m``,
        ``target_p95_m`` and ``target_over_8mm_area_fraction`` (area-weighted: the
        skin's measure, not its mesh's density); ``exact_normals``, the same
        ``covered_area_fraction``, ``target_mean_m`` and ``target_p95_m`` with the true
        skin's normals at the markers (:func:`true_marker_normals`) as the lift's; with ``regions`` also ``regions``,
        one row per region: ``region``, ``covered_area_fraction``, ``target_mean_m``,
        ``target_p95_m`` (None where nothing is covered), sorted by the covered
        error's p95, worst first.

    Raises
    ------
    ValidationError
        A true skin of the wrong shape or with NaN vertices; regions of the wrong length.
    """
    true = np.asarray(true_vertices, dtype=np.float64)
    if true.ndim != 2 or true.shape[1] != 3 or true.shape[0] == 0:
        raise ValidationError(f"true_vertices: expected shape (V, 3), got {true.shape}")
    if not np.isfinite(true).all():
        raise ValidationError("true_vertices: vertices must be finite")
    faces = np.asarray(true_faces, dtype=np.int64)
    if regions is not None and np.asarray(regions).shape != (true.shape[0],):
        raise ValidationError(
            f"regions: expected one name per true-skin vertex ({true.shape[0]}), "
            f"got shape {np.asarray(regions).shape}"
        )
    skin_normals = area_weighted_vertex_normals(true, faces)
    area = _vertex_areas(true, faces)

    def distances(marker_normals: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """(V,) distance of each covered skin vertex's target to the skin (0 elsewhere),
        (V,) covered; the lift's normals at the markers estimated, or ``marker_normals``."""
        targets, covered = marker_surface_targets(
            true, skin_normals, markers, marker_faces, marker_radius=marker_radius,
            max_distance=max_distance, patch_ratio=patch_ratio, marker_normals=marker_normals,
        )  # fmt: skip
        d = np.zeros(true.shape[0])
        if covered.any():
            d[covered] = _distances_to_surface(true, faces, targets[covered])
        return d, covered

    def summary(sel: np.ndarray, d: np.ndarray, covered: np.ndarray) -> dict[str, Any]:
        total = float(area[sel].sum())
        s = sel & covered
        w = area[s]
        if not s.any() or w.sum() <= 0:
            return {"covered_area_fraction": 0.0, "target_mean_m": None, "target_p95_m": None}
        return {
            "covered_area_fraction": float(w.sum() / total) if total > 0 else 0.0,
            "target_mean_m": float((w * d[s]).sum() / w.sum()),
            "target_p95_m": _weighted_p95(d[s], w),
        }

    d, covered = distances(None)
    every = np.ones(true.shape[0], dtype=bool)
    out: dict[str, Any] = summary(every, d, covered)
    w = area[covered]
    out["target_over_8mm_area_fraction"] = (
        float(w[d[covered] > 0.008].sum() / w.sum()) if w.sum() > 0 else None
    )
    # the same with the true skin's normals at the markers: the ceiling of the normals
    out["exact_normals"] = summary(every, *distances(true_marker_normals(true, faces, markers)))
    if regions is not None:
        names = np.asarray(regions).astype(str)
        rows = [
            {"region": str(key)} | summary(names == key, d, covered) for key in np.unique(names)
        ]
        rows.sort(key=lambda r: (r["target_p95_m"] is None, -(r["target_p95_m"] or 0.0)))
        out["regions"] = rows
    return out


def true_marker_normals(
    true_vertices: np.ndarray, true_faces: np.ndarray, markers: np.ndarray
) -> np.ndarray:
    """(M, 3) the true skin's unit normal under each marker; zero for an unseen marker.

    The area-weighted vertex normals interpolated at each marker's closest point on the
    skin (as ``skincap synth`` lifts a marker off it by its radius).

    Parameters
    ----------
    true_vertices : (V, 3) float, metres; true_faces : (F, 3) int
    markers : (M, 3) float, metres (NaN rows: unseen)
    """
    true = np.asarray(true_vertices, dtype=np.float64)
    faces = np.asarray(true_faces, dtype=np.int64)
    m = np.asarray(markers, dtype=np.float64)
    out = np.zeros_like(m)
    seen = np.isfinite(m).all(axis=1)
    if not seen.any():
        return out
    _, face, bary = _closest_on_surface(true, faces, m[seen])
    normals = area_weighted_vertex_normals(true, faces)
    n = np.einsum("kc,kcx->kx", bary, normals[faces[face]])
    out[seen] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    return out


def marker_normal_errors(
    registered_vertices: np.ndarray,
    registered_faces: np.ndarray,
    true_vertices: np.ndarray,
    true_faces: np.ndarray,
    markers: np.ndarray,
    marker_faces: np.ndarray,
    *,
    patch_ratio: float,
    regions: np.ndarray | None = None,
) -> dict[str, Any]:
    """The registration's normals at the markers against the true skin's, in degrees.

    The normals are those the registration's last iteration lifts the marker surface
    with (:func:`skincap.deform.dense.surface_targets.lift_normals` over the registered
    mesh), the truth :func:`true_marker_normals`; only the markers the lift uses count.

    Parameters
    ----------
    registered_vertices : (V, 3) float, metres; registered_faces : (F, 3) int
    true_vertices : (W, 3) float, metres; true_faces : (G, 3) int
        The true skin in the markers' pose.
    markers : (M, 3) float, metres (NaN rows: unseen)
    marker_faces : (S, 3) int, the marker surface's triangles over the marker rows
    patch_ratio : float, as the registration uses it
    regions : (W,) str, optional
        A region name per true-skin vertex; a marker takes the region of its closest
        true-skin point's nearest corner.

    Returns
    -------
    dict
        ``markers`` (how many count), ``error_mean_deg``, ``error_p95_deg`` (None
        when no marker counts); with ``regions`` also ``regions``, one row per region
        (``region``, ``markers``, ``error_mean_deg``), the worst mean first.

    Raises
    ------
    ValidationError
        Regions of the wrong length.
    """
    reg = np.asarray(registered_vertices, dtype=np.float64)
    reg_faces = np.asarray(registered_faces, dtype=np.int64)
    true = np.asarray(true_vertices, dtype=np.float64)
    faces = np.asarray(true_faces, dtype=np.int64)
    if regions is not None and np.asarray(regions).shape != (true.shape[0],):
        raise ValidationError(
            f"regions: expected one name per true-skin vertex ({true.shape[0]}), "
            f"got shape {np.asarray(regions).shape}"
        )
    estimate = lift_normals(
        reg, area_weighted_vertex_normals(reg, reg_faces), markers, marker_faces,
        patch_ratio=patch_ratio,
    )  # fmt: skip
    used = np.nonzero(np.linalg.norm(estimate, axis=1) > 0.5)[0]
    if used.size == 0:
        return {"markers": 0, "error_mean_deg": None, "error_p95_deg": None}
    m = np.asarray(markers, dtype=np.float64)[used]
    _, face, bary = _closest_on_surface(true, faces, m)
    truth = true_marker_normals(true, faces, m)
    cosine = np.clip(np.einsum("kx,kx->k", estimate[used], truth), -1.0, 1.0)
    angle = np.degrees(np.arccos(cosine))
    out: dict[str, Any] = {
        "markers": int(used.size),
        "error_mean_deg": float(angle.mean()),
        "error_p95_deg": float(np.percentile(angle, 95)),
    }
    if regions is not None:
        names = np.asarray(regions).astype(str)[faces[face, np.argmax(bary, axis=1)]]
        rows: list[dict[str, Any]] = [
            {
                "region": str(key),
                "markers": int((names == key).sum()),
                "error_mean_deg": float(angle[names == key].mean()),
            }
            for key in np.unique(names)
        ]
        rows.sort(key=lambda r: -r["error_mean_deg"])
        out["regions"] = rows
    return out
