"""glTF 2.0 node animation: ``read_gltf_animation`` samples a file's animation at a rate.

LINEAR, STEP and CUBICSPLINE samplers; every node's world transform per sample.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from skincap.errors import FormatError
from skincap.io._common import check_readable
from skincap.io.gltf.document import load_document, local_matrix, node_tree, node_trs

__all__ = ["read_gltf_animation", "GltfAnimation"]


class GltfAnimation(NamedTuple):
    """What :func:`read_gltf_animation` returns.

    Attributes
    ----------
    times : (T,) float64, seconds
        The sample times: ``start + arange(T) / rate``.
    rate : float, Hz
    node_world : (T, N, 4, 4) float64
        World transform of every node of the file (metres, Y up) at each sample,
        column-vector convention like glTF.
    name : str
        The animation's name (``animation<i>`` when it has none).
    """

    times: np.ndarray
    rate: float
    node_world: np.ndarray
    name: str


def read_gltf_animation(
    path: str | os.PathLike[str], *, animation: int = 0, rate: float | None = None
) -> GltfAnimation | None:
    """Sample one animation of a glTF file into per-frame node world transforms.

    ``translation``, ``rotation`` and ``scale`` channels are evaluated with their
    sampler's interpolation (``LINEAR`` — spherical for rotations — ``STEP`` or
    ``CUBICSPLINE``, the Hermite form of the glTF spec); nodes without a channel keep
    their rest transform. Morph-target ``weights`` channels are ignored.

    Parameters
    ----------
    path : str or PathLike
    animation : int, default 0
        Which of the file's animations.
    rate : float, optional, Hz
        Sampling rate. Default: the rate of the keyframes (``1 / median`` spacing of
        all key times, e.g. the capture rate for files skincap writes), at most 240.

    Returns
    -------
    GltfAnimation or None
        None when the file has no animation.

    Raises
    ------
    FormatError
        Malformed animation data (bad sampler or channel references, key times not
        increasing, output counts that do not match).
    """
    p = check_readable(path)
    try:
        return _read_gltf_animation(p, animation, rate)
    except FormatError:
        raise
    except (KeyError, TypeError, ValueError, IndexError, OverflowError, struct.error) as exc:
        raise FormatError(p, f"malformed glTF animation: {type(exc).__name__}: {exc}") from None


def _read_gltf_animation(p: Path, which: int, rate: float | None) -> GltfAnimation | None:
    g = load_document(p)
    anims = g.items("animations")
    if not anims:
        return None
    anim = g.item("animations", which)
    where = f"animations[{which}]"
    samplers = anim.get("samplers")
    channels = anim.get("channels")
    if not isinstance(samplers, list) or not isinstance(channels, list):
        raise g.fail(f"{where}: 'samplers' and 'channels' must be arrays")
    parent, _, order = node_tree(g)
    n_nodes = parent.size
    keyed: list[tuple[int, str, np.ndarray, np.ndarray, str]] = []
    for c, ch in enumerate(channels):
        target = ch.get("target") if isinstance(ch, dict) else None
        if not isinstance(target, dict):
            raise g.fail(f"{where}.channels[{c}]: missing 'target'")
        path_name = target.get("path")
        if path_name == "weights":
            continue
        if path_name not in ("translation", "rotation", "scale"):
            raise g.fail(f"{where}.channels[{c}]: unknown target path {path_name!r}")
        node = target.get("node")
        if not isinstance(node, int) or isinstance(node, bool) or not 0 <= node < n_nodes:
            raise g.fail(f"{where}.channels[{c}]: node {node!r} does not exist")
        s = ch.get("sampler")
        if not isinstance(s, int) or isinstance(s, bool) or not 0 <= s < len(samplers):
            raise g.fail(f"{where}.channels[{c}]: sampler {s!r} does not exist")
        smp = samplers[s]
        interp = smp.get("interpolation", "LINEAR")
        if interp not in ("LINEAR", "STEP", "CUBICSPLINE"):
            raise g.fail(f"{where}.samplers[{s}]: unknown interpolation {interp!r}")
        t_in = g.accessor(smp.get("input"), what=f"{where}.samplers[{s}].input").reshape(-1)
        if t_in.size > 1 and not (np.diff(t_in) > 0).all():
            raise g.fail(f"{where}.samplers[{s}]: key times must increase strictly")
        values = g.accessor(smp.get("output"), what=f"{where}.samplers[{s}].output")
        width = 4 if path_name == "rotation" else 3
        per_key = 3 if interp == "CUBICSPLINE" else 1
        if values.shape != (t_in.size * per_key, width):
            raise g.fail(
                f"{where}.samplers[{s}]: {values.shape[0]} outputs of width {values.shape[1]} "
                f"for {t_in.size} keys of {path_name}"
            )
        keyed.append((node, path_name, t_in, values.astype(np.float64), interp))
    if not keyed:
        return None
    all_times = np.unique(np.concatenate([k[2] for k in keyed]))
    start, end = float(all_times[0]), float(all_times[-1])
    if rate is None:
        step = float(np.median(np.diff(all_times))) if all_times.size > 1 else 1.0 / 30.0
        rate = min(240.0, 1.0 / step) if step > 0 else 30.0
        if abs(rate - round(rate)) < 1e-3 * rate:  # float32 key times: 120.0018 -> 120
            rate = float(round(rate))
    if not (np.isfinite(rate) and rate > 0):
        raise FormatError(p, f"sampling rate must be positive, got {rate!r}")
    n = int(np.floor((end - start) * rate + 1e-6)) + 1
    times = start + np.arange(n) / rate

    # rest TRS of every node, then overwrite the animated parts per frame
    rest_t = np.zeros((n_nodes, 3))
    rest_r = np.tile([0.0, 0.0, 0.0, 1.0], (n_nodes, 1))
    rest_s = np.ones((n_nodes, 3))
    rest_matrix: dict[int, np.ndarray] = {}
    for i in range(n_nodes):
        node = g.item("nodes", i)
        if "matrix" in node:
            rest_matrix[i] = local_matrix(g, i, node)
            continue
        rest_t[i], rest_r[i], rest_s[i] = node_trs(g, i, node)
    trs = {
        "translation": np.broadcast_to(rest_t, (n, n_nodes, 3)).copy(),
        "rotation": np.broadcast_to(rest_r, (n, n_nodes, 4)).copy(),
        "scale": np.broadcast_to(rest_s, (n, n_nodes, 3)).copy(),
    }
    animated = np.zeros(n_nodes, dtype=bool)
    for node, path_name, t_in, values, interp in keyed:
        trs[path_name][:, node] = _sample_channel(t_in, values, interp, times, path_name)
        animated[node] = True
    local = np.zeros((n, n_nodes, 4, 4))
    rot = Rotation.from_quat(trs["rotation"].reshape(-1, 4)).as_matrix().reshape(n, n_nodes, 3, 3)
    local[..., :3, :3] = rot * trs["scale"][..., None, :]
    local[..., :3, 3] = trs["translation"]
    local[..., 3, 3] = 1.0
    for i, m in rest_matrix.items():
        if not animated[i]:  # a node with a 'matrix' may not be animated (glTF spec)
            local[:, i] = m
    world = np.empty_like(local)
    for i in order:  # parents first; each step is vectorised over frames
        world[:, i] = local[:, i] if parent[i] < 0 else world[:, parent[i]] @ local[:, i]
    name = anim.get("name")
    return GltfAnimation(times, float(rate), world, str(name) if name else f"animation{which}")


def _sample_channel(
    t_in: np.ndarray, values: np.ndarray, interp: str, times: np.ndarray, path_name: str
) -> np.ndarray:
    """(T, width) channel values at ``times`` (clamped to the key range)."""
    if interp == "CUBICSPLINE":
        in_tan, vals, out_tan = values[0::3], values[1::3], values[2::3]
    else:
        vals = values
    if t_in.size == 1:
        return np.broadcast_to(vals[0], (times.size, vals.shape[1])).copy()
    tc = np.clip(times, t_in[0], t_in[-1])
    k = np.clip(np.searchsorted(t_in, tc, side="right") - 1, 0, t_in.size - 2)
    dt = t_in[k + 1] - t_in[k]
    u = ((tc - t_in[k]) / dt)[:, None]
    if interp == "STEP":
        out = np.where(u >= 1.0, vals[k + 1], vals[k])
    elif interp == "CUBICSPLINE":
        u2, u3 = u * u, u * u * u
        out = (
            (2 * u3 - 3 * u2 + 1) * vals[k]
            + (u3 - 2 * u2 + u) * dt[:, None] * out_tan[k]
            + (-2 * u3 + 3 * u2) * vals[k + 1]
            + (u3 - u2) * dt[:, None] * in_tan[k + 1]
        )
    elif path_name == "rotation":
        out = _slerp(vals[k], vals[k + 1], u[:, 0])
    else:
        out = (1.0 - u) * vals[k] + u * vals[k + 1]
    if path_name == "rotation":
        norm = np.linalg.norm(out, axis=1, keepdims=True)
        out = out / np.where(norm > 0, norm, 1.0)
    return out


def _slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Shortest-path spherical interpolation of (T, 4) unit quaternions at (T,) u."""
    q0 = q0 / np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = q1 / np.linalg.norm(q1, axis=1, keepdims=True)
    dot = np.einsum("ij,ij->i", q0, q1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    dot = np.abs(dot)
    theta = np.arccos(np.clip(dot, -1.0, 1.0))
    sin_t = np.sin(theta)
    small = sin_t < 1e-9
    safe = np.where(small, 1.0, sin_t)
    w0 = np.where(small, 1.0 - u, np.sin((1.0 - u) * theta) / safe)
    w1 = np.where(small, u, np.sin(u * theta) / safe)
    return w0[:, None] * q0 + w1[:, None] * q1
