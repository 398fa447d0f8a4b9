"""Registration speed (Park & Hodgins §5.1): seconds to register an N-vertex body.

For ``skincap bench animate`` (issue #16: registration <= 60 s for 20k vertices). The
template is the procedural body at ``n_vertices``; the markers are ``n_markers`` evenly
spread points of the same body scaled by 4 % and shifted 3 cm, so every run has the
same work (a global move plus closest-point iterations). Reported beside the CPU time of
one sparse LU of the mesh's Laplacian in the same run, the unit a closest-point
iteration costs a few of, so the figure reads as a ratio on a loaded machine.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

__all__ = ["registration_seconds"]


def registration_seconds(
    n_vertices: int = 20_000, n_markers: int = 350, seed: int = 0
) -> dict[str, Any]:
    """Time one :func:`~skincap.deform.dense.registration.register_mesh` call.

    Returns
    -------
    dict
        ``vertices``, ``markers``, ``cpu_s`` and ``wall_s`` of the registration,
        ``iterations``, ``laplacian_lu_cpu_s`` (one V x V sparse LU, same run),
        ``ratio_to_lu`` (registration CPU over that), ``marker_distance_mean_m`` after
        registration and ``marker_distance_before_m`` (to the template as given).
    """
    from skincap.deform.dense.registration import _farthest_point_nodes, register_mesh
    from skincap.synth.body import procedural_body
    from skincap.synth.skeleton import synth_skeleton

    body = procedural_body(synth_skeleton(), n_vertices=int(n_vertices), seed=seed)
    v, f = body.vertices, body.faces
    rng = np.random.default_rng(seed)
    face = rng.integers(0, f.shape[0], 30 * int(n_markers))
    bary = rng.dirichlet(np.ones(3), face.size)
    candidates = np.einsum("nk,nkx->nx", bary, v[f[face]])
    markers = candidates[
        _farthest_point_nodes(candidates, min(int(n_markers), len(candidates)))
    ] * 1.04 + [0.0, 0.0, 0.03]
    labels = [f"D{i:03d}" for i in range(markers.shape[0])]

    edges = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    adjacency = sp.coo_matrix(
        (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(v),) * 2
    )
    adjacency = (adjacency + adjacency.T).tocsr()
    adjacency.data[:] = 1.0
    laplacian = sp.diags(np.asarray(adjacency.sum(axis=1)).ravel() + 1e-3) - adjacency
    t0 = time.process_time()
    spla.splu(laplacian.tocsc(), permc_spec="MMD_AT_PLUS_A")
    lu_cpu = time.process_time() - t0

    t0, w0 = time.process_time(), time.perf_counter()
    reg = register_mesh(v, f, markers, labels)
    from skincap.geometry.raycast import closest_points_on_mesh

    before, _, _ = closest_points_on_mesh(v, f, markers)
    cpu, wall = time.process_time() - t0, time.perf_counter() - w0
    return {
        "vertices": int(v.shape[0]),
        "markers": int(markers.shape[0]),
        "cpu_s": cpu,
        "wall_s": wall,
        "iterations": reg.iterations,
        "laplacian_lu_cpu_s": lu_cpu,
        "ratio_to_lu": cpu / max(lu_cpu, 1e-9),
        "marker_distance_mean_m": float(np.nanmean(reg.marker_distance)),
        "marker_distance_before_m": float(before.mean()),
    }
