"""Skinning deformers: linear blend skinning and dual-quaternion skinning.

Both deformers share one interface. They are built from a rest mesh's vertices and
its per-vertex joint influences, and turn skinning matrices ``S = W @ inverse_bind``
(joint world transform times inverse bind matrix, identity in the bind pose) into
vertex positions:

- :class:`LinearBlendSkinning` (LBS): ``p' = sum_k w_k S_{j_k} p``. Fast and what
  glTF defines, but it averages matrices, so a joint twisted by 180 degrees collapses
  to a line (the "candy wrapper") and a bent elbow loses volume.
- :class:`DualQuaternionSkinning` (DQS, Kavan, Collins, Zara & O'Sullivan 2008,
  "Geometric skinning with approximate dual quaternion blending"): each ``S_j`` as a
  unit dual quaternion ``q_j``; per vertex ``b = sum_k s_k w_k q_{j_k}`` with the
  antipodality fix ``s_k = sign(<real(q_{j_k}), real(q_pivot)>)`` (``-1`` only when
  the dot product is negative), where the pivot is the vertex's largest-weight
  influence (the first of equal ones) -- the same pivot as usd-core's UsdSkel --
  then ``b / |real(b)|`` is applied to ``p``. The result is always a rigid
  transform of ``p``: no collapse.

Non-rigid skinning matrices (scale, shear, reflection): LBS applies them as they are.
DQS follows Kavan et al.'s two-phase scheme (section 4.3 of the paper): each
``S_j``'s 3x3 part is split by the polar decomposition ``A_j = R_j P_j`` (``R_j`` a
proper rotation, ``P_j`` symmetric; a reflection ends up in ``P_j``), the vertex is
first moved by the linear blend of the stretches ``p_s = sum_k w_k P_{j_k} p``, then
by the dual-quaternion blend of the rigid parts ``(R_j, t_j)``. For one influence
this is exactly ``S_j p``; when every ``S_j`` is rigid (within 1e-9) the first phase
is skipped. The bottom row of every matrix is ignored (affine transforms).

Kernels: a plain NumPy implementation is the reference and always available; a
parallel numba kernel per method (numba is a core dependency) agrees with it to
rounding and is what ``backend="auto"`` runs. Each kernel compiles once per machine
into numba's on-disk cache; until it is there, ``auto`` runs the NumPy reference and
compiles the kernel in a background process (:mod:`skincap.backends`).

Weights are used as given (they should sum to 1 per vertex; LBS scales the result
by the sum, DQS normalises it away). NaN in a skinning matrix gives NaN for the
vertices that joint influences, and nowhere else, without warnings.
"""

from __future__ import annotations

import abc
import functools
from collections.abc import Callable, Iterator
from typing import Any, Literal

import numpy as np
import scipy.sparse

from skincap import backends
from skincap.backends import numba_available, resolve_backend
from skincap.errors import ValidationError
from skincap.geometry.dual_quaternions import dq_from_quat_translation
from skincap.geometry.kinematics import forward_kinematics_arrays
from skincap.geometry.rotations import matrix_to_quat
from skincap.types import Mesh, MeshAnimation, Motion

__all__ = [
    "LinearBlendSkinning",
    "DualQuaternionSkinning",
    "SkinningDeformer",
    "deformed_chunks",
    "make_deformer",
    "skin_motion",
    "numba_available",
]

Method = Literal["lbs", "dqs"]
Backend = Literal["auto", "numba", "numpy"]

# below this largest deviation of A^T A from I (and det A > 0) a matrix counts as rigid
_RIGID_TOL = 1e-9


# ------------------------------------------------------------------------ numba
@functools.cache
def _numba_kernels() -> tuple[Callable[..., None], Callable[..., None]]:
    """The two parallel skinning kernels (numba dispatchers; each compiles, or loads
    from numba's on-disk cache, on its first call)."""
    import numba

    @numba.njit(parallel=True, cache=True, nogil=True, fastmath={"contract"})
    def lbs_kernel(rest, idx, w, aff, out):  # pragma: no cover - runs compiled
        # rest (V,3), idx (V,K), w (V,K), aff (T,J,3,4), out (T,V,3)
        n_v, n_k = idx.shape
        for t in range(aff.shape[0]):
            for v in numba.prange(n_v):
                x = rest[v, 0]
                y = rest[v, 1]
                z = rest[v, 2]
                ox = 0.0
                oy = 0.0
                oz = 0.0
                for k in range(n_k):
                    wk = w[v, k]
                    a = aff[t, idx[v, k]]
                    ox += wk * (a[0, 0] * x + a[0, 1] * y + a[0, 2] * z + a[0, 3])
                    oy += wk * (a[1, 0] * x + a[1, 1] * y + a[1, 2] * z + a[1, 3])
                    oz += wk * (a[2, 0] * x + a[2, 1] * y + a[2, 2] * z + a[2, 3])
                out[t, v, 0] = ox
                out[t, v, 1] = oy
                out[t, v, 2] = oz

    @numba.njit(parallel=True, cache=True, nogil=True, fastmath={"contract"})
    def dqs_kernel(rest, idx, w, pivot, dq, stretch, has_stretch, out):  # pragma: no cover
        # rest (V,3), idx (V,K), w (V,K), pivot (V,) joint, dq (T,J,8),
        # stretch (T,J,3,3) (read only when has_stretch), out (T,V,3)
        n_v, n_k = idx.shape
        for t in range(dq.shape[0]):
            for v in numba.prange(n_v):
                x = rest[v, 0]
                y = rest[v, 1]
                z = rest[v, 2]
                if has_stretch:
                    sx = 0.0
                    sy = 0.0
                    sz = 0.0
                    for k in range(n_k):
                        wk = w[v, k]
                        p = stretch[t, idx[v, k]]
                        sx += wk * (p[0, 0] * x + p[0, 1] * y + p[0, 2] * z)
                        sy += wk * (p[1, 0] * x + p[1, 1] * y + p[1, 2] * z)
                        sz += wk * (p[2, 0] * x + p[2, 1] * y + p[2, 2] * z)
                    x = sx
                    y = sy
                    z = sz
                pv = dq[t, pivot[v]]
                b0 = 0.0
                b1 = 0.0
                b2 = 0.0
                b3 = 0.0
                b4 = 0.0
                b5 = 0.0
                b6 = 0.0
                b7 = 0.0
                for k in range(n_k):
                    q = dq[t, idx[v, k]]
                    wk = w[v, k]
                    if q[0] * pv[0] + q[1] * pv[1] + q[2] * pv[2] + q[3] * pv[3] < 0.0:
                        wk = -wk
                    b0 += wk * q[0]
                    b1 += wk * q[1]
                    b2 += wk * q[2]
                    b3 += wk * q[3]
                    b4 += wk * q[4]
                    b5 += wk * q[5]
                    b6 += wk * q[6]
                    b7 += wk * q[7]
                inv = 1.0 / np.sqrt(b0 * b0 + b1 * b1 + b2 * b2 + b3 * b3)
                rx = b0 * inv
                ry = b1 * inv
                rz = b2 * inv
                rw = b3 * inv
                dx = b4 * inv
                dy = b5 * inv
                dz = b6 * inv
                dw = b7 * inv
                # rotation: p + 2 (w (r x p) + r x (r x p))
                ux = ry * z - rz * y
                uy = rz * x - rx * z
                uz = rx * y - ry * x
                vx = ry * uz - rz * uy
                vy = rz * ux - rx * uz
                vz = rx * uy - ry * ux
                # translation: 2 vec(d r*) = 2 (rw d - dw r + r x d)
                out[t, v, 0] = (
                    x + 2.0 * (rw * ux + vx) + 2.0 * (rw * dx - dw * rx + ry * dz - rz * dy)
                )
                out[t, v, 1] = (
                    y + 2.0 * (rw * uy + vy) + 2.0 * (rw * dy - dw * ry + rz * dx - rx * dz)
                )
                out[t, v, 2] = (
                    z + 2.0 * (rw * uz + vz) + 2.0 * (rw * dz - dw * rz + rx * dy - ry * dx)
                )

    return lbs_kernel, dqs_kernel


def _lbs_dispatcher() -> Any:
    return _numba_kernels()[0]


def _dqs_dispatcher() -> Any:
    return _numba_kernels()[1]


_KERNELS = {"lbs": ("skinning.lbs", _lbs_dispatcher), "dqs": ("skinning.dqs", _dqs_dispatcher)}


def warm_up_lbs() -> None:
    """Compile the LBS kernel into numba's cache (run by the background compile)."""
    LinearBlendSkinning(np.zeros((2, 3)), [[0], [0]], [[1.0], [1.0]], backend="numba").deform(
        np.eye(4)[None]
    )


def warm_up_dqs() -> None:
    """Compile the DQS kernel into numba's cache (run by the background compile)."""
    DualQuaternionSkinning(np.zeros((2, 3)), [[0], [0]], [[1.0], [1.0]], backend="numba").deform(
        np.eye(4)[None]
    )


# ------------------------------------------------------------------- validation
def _resolve_backend(backend: str, method: str = "lbs") -> str:
    return resolve_backend(
        backend,
        numba_installed=numba_available(),
        feature="the numba skinning kernels",
        kernel=_KERNELS.get(method),
    )


def _split_rigid(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """Rigid parts (R, t) as dual quaternions and the stretches P of ``A = R P``.

    Parameters
    ----------
    matrices : (T, J, 4, 4) float64

    Returns
    -------
    dq : (T, J, 8) float64
        Unit dual quaternions of ``[R_j | t_j]``; NaN where a matrix has NaN.
    stretch : (T, J, 3, 3) float64 or None
        ``P_j`` (identity for rigid joints); None when every matrix is rigid.
    """
    a = matrices[..., :3, :3]
    finite = np.isfinite(matrices).all(axis=(-2, -1))
    with np.errstate(invalid="ignore"):
        gram_err = np.abs(np.einsum("...ji,...jk->...ik", a, a) - np.eye(3)).max(axis=(-2, -1))
        det = np.linalg.det(a)
    nonrigid = finite & ((gram_err > _RIGID_TOL) | (det <= 0.0))
    stretch = None
    rot = a
    if nonrigid.any():
        rot = a.copy()
        stretch = np.broadcast_to(np.eye(3), a.shape).copy()
        an = a[nonrigid]
        u, _, vt = np.linalg.svd(an)
        d = np.sign(np.linalg.det(u @ vt))
        d = np.where(d == 0, 1.0, d)
        u[..., :, 2] *= d[:, None]
        r = u @ vt  # proper rotation nearest to A (polar factor with det +1)
        rot[nonrigid] = r
        stretch[nonrigid] = np.swapaxes(r, -1, -2) @ an  # P = R^T A, symmetric
    with np.errstate(invalid="ignore"):
        q = matrix_to_quat(rot)
    return dq_from_quat_translation(q, matrices[..., :3, 3]), stretch


class SkinningDeformer(abc.ABC):
    """Common interface of the skinning deformers (use a subclass).

    Parameters
    ----------
    rest_vertices : (V, 3) float, metres
        Vertex positions in the bind pose. Must be finite.
    joint_indices : (V, K) int
        Influencing joints per vertex.
    joint_weights : (V, K) float
        Non-negative, finite; each row should sum to 1 and must not be all zero.
    n_joints : int, optional
        Number of joints the skinning matrices will have (e.g. the skeleton's).
        Default: any number larger than the largest index.
    backend : {"auto", "numba", "numpy"}, default "auto"
        ``"auto"`` uses the numba kernel when it is compiled (in this process or in
        numba's on-disk cache), and otherwise NumPy while the kernel compiles in the
        background (:func:`skincap.backends.resolve_backend`); ``"numba"`` compiles
        on first use if needed, and raises
        :class:`~skincap.errors.MissingDependencyError` without numba.

    Attributes
    ----------
    method : str
        ``"lbs"`` or ``"dqs"``.
    backend : str
        The kernel in use, ``"numba"`` or ``"numpy"``. With ``backend="auto"`` on a
        cold cache it starts as ``"numpy"`` and becomes ``"numba"`` at the first
        :meth:`deform` after the background compile has cached the kernel (checked
        at most once a second), so a long take streamed chunk by chunk runs compiled
        from then on.
    """

    method: str = ""

    def __init__(
        self,
        rest_vertices: np.ndarray,
        joint_indices: np.ndarray,
        joint_weights: np.ndarray,
        *,
        n_joints: int | None = None,
        backend: Backend = "auto",
    ) -> None:
        v = np.asarray(rest_vertices, dtype=np.float64)
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValidationError(f"rest_vertices: expected shape (V, 3), got {v.shape}")
        if not np.isfinite(v).all():
            raise ValidationError("rest_vertices: must be finite")
        n_v = v.shape[0]
        w = np.asarray(joint_weights, dtype=np.float64)
        if w.ndim != 2 or w.shape[0] != n_v or w.shape[1] < 1:
            raise ValidationError(
                f"joint_weights: expected shape ({n_v}, K) with K >= 1, got {w.shape}"
            )
        idx = np.asarray(joint_indices)
        if idx.shape != w.shape:
            raise ValidationError(
                f"joint_indices: expected shape {w.shape} like joint_weights, got {idx.shape}"
            )
        if idx.size and not np.issubdtype(idx.dtype, np.integer):
            raise ValidationError(f"joint_indices: expected integers, got dtype {idx.dtype}")
        idx = idx.astype(np.int64)
        if not np.isfinite(w).all() or (w < 0).any():
            raise ValidationError("joint_weights: must be finite and non-negative")
        if n_v and (w.sum(axis=1) <= 0).any():
            bad = int(np.argmax(w.sum(axis=1) <= 0))
            raise ValidationError(f"joint_weights: vertex {bad} has no influence (all weights 0)")
        if idx.size and idx.min() < 0:
            raise ValidationError(f"joint_indices: must be >= 0, minimum is {idx.min()}")
        max_index = int(idx.max()) if idx.size else -1
        if n_joints is not None:
            if isinstance(n_joints, bool) or not isinstance(n_joints, (int, np.integer)):
                raise ValidationError(f"n_joints: expected an integer, got {n_joints!r}")
            n_joints = int(n_joints)
            if max_index >= n_joints:
                raise ValidationError(
                    f"joint_indices: index {max_index} out of range for {n_joints} joints"
                )
        # C-contiguous and writeable: a read-only input would be another numba
        # signature, compiled on the spot instead of loaded from the cache
        self.rest_vertices = np.require(v, requirements=("C", "W"))
        self.joint_indices = np.require(idx, requirements=("C", "W"))
        self.joint_weights = np.require(w, requirements=("C", "W"))
        self.n_joints = n_joints
        self._used_joints = max(max_index + 1, 1)
        self.backend = _resolve_backend(backend, self.method)
        # "auto" got NumPy because the kernel is compiling in the background: take the
        # kernel as soon as it lands in the cache (a long take is not NumPy throughout)
        self._kernel_watch = backends.KernelWatch(
            _KERNELS[self.method][1],
            backend == "auto" and self.backend == "numpy" and numba_available(),
        )
        # NumPy kernels work on batches of about 2**19 vertex-frames: the temporaries
        # stay a few MB and the per-call overheads are shared by several frames
        self._numpy_step = max(1, 2**19 // max(1, n_v))
        self._prepare()

    # -- the kernels of a subclass
    @abc.abstractmethod
    def _prepare(self) -> None:
        """Precompute what the NumPy kernel needs from the rest pose and weights."""

    @abc.abstractmethod
    def _numpy_batch(self, matrices: np.ndarray, out: np.ndarray) -> None:
        """Reference kernel: (t, J, 4, 4) matrices -> ``out`` (t, V, 3), a few frames."""

    @abc.abstractmethod
    def _numba_all(self, matrices: np.ndarray, out: np.ndarray) -> None:
        """numba kernel: (T, J, 4, 4) matrices -> ``out`` (T, V, 3)."""

    # -- public
    @property
    def n_vertices(self) -> int:
        return int(self.rest_vertices.shape[0])

    @property
    def n_influences(self) -> int:
        return int(self.joint_weights.shape[1])

    def _check_matrices(self, matrices: Any) -> np.ndarray:
        m = np.asarray(matrices, dtype=np.float64)
        if m.ndim not in (3, 4) or m.shape[-2:] != (4, 4):
            raise ValidationError(
                f"matrices: expected skinning matrices of shape (J, 4, 4) or (T, J, 4, 4), got {m.shape}"
            )
        j = m.shape[-3]
        if self.n_joints is not None and j != self.n_joints:
            raise ValidationError(f"matrices: expected {self.n_joints} joints, got {j}")
        if self.n_vertices and j < self._used_joints:
            raise ValidationError(
                f"matrices: the weights use joint {self._used_joints - 1} but only {j} joints were given"
            )
        return m

    def deform(self, matrices: np.ndarray, *, out: np.ndarray | None = None) -> np.ndarray:
        """Deform the rest vertices by one pose or by a batch of frames.

        Parameters
        ----------
        matrices : (J, 4, 4) or (T, J, 4, 4) float
            Skinning matrices ``S = W @ inverse_bind`` (metres), acting on column
            vectors; identity in the bind pose. The bottom row is ignored.
        out : (V, 3) or (T, V, 3) float64 array, optional
            C-contiguous array to write the result into (reusing one buffer saves
            the allocation and page faults when streaming).

        Returns
        -------
        (V, 3) or (T, V, 3) float64, metres
            Deformed vertices (``out`` when given). NaN in a joint's matrix gives NaN
            for the vertices that list that joint among their influences, nowhere
            else, without warnings.

        Examples
        --------
        >>> lbs = LinearBlendSkinning([[0.0, 1.0, 0.0]], [[0]], [[1.0]])
        >>> lift = np.eye(4); lift[1, 3] = 0.5
        >>> lbs.deform(lift[None])
        array([[0. , 1.5, 0. ]])
        """
        m = self._check_matrices(matrices)
        single = m.ndim == 3
        m = np.ascontiguousarray(m[None] if single else m)
        shape = (m.shape[0], self.n_vertices, 3)
        if out is None:
            result = np.zeros(shape)
        else:
            want = shape[1:] if single else shape
            if (
                not isinstance(out, np.ndarray)
                or out.shape != want
                or out.dtype != np.float64
                or not out.flags.c_contiguous
                or not out.flags.writeable
            ):
                raise ValidationError(
                    f"out: expected a writeable C-contiguous float64 array of shape {want}, got "
                    + (
                        f"{out.shape} {out.dtype}"
                        if isinstance(out, np.ndarray)
                        else type(out).__name__
                    )
                )
            result = out.reshape(shape)
        if shape[0] and shape[1]:
            if self._kernel_watch.landed():
                self.backend = "numba"
            if self.backend == "numba":
                self._numba_all(m, result)
            else:
                step = self._numpy_step
                for s in range(0, shape[0], step):
                    self._numpy_batch(m[s : s + step], result[s : s + step])
        if out is not None:
            return out
        return result[0] if single else result

    def deform_chunks(self, matrices: np.ndarray, chunk: int = 64) -> Iterator[np.ndarray]:
        """Deform a whole motion chunk by chunk.

        Parameters
        ----------
        matrices : (T, J, 4, 4) float
            Skinning matrices of every frame.
        chunk : int, default 64
            Frames per yielded block.

        Yields
        ------
        (t, V, 3) float64, metres
            ``t <= chunk`` frames at a time, in order (a new array each time).
        """
        m = self._check_matrices(matrices)
        if m.ndim != 4:
            raise ValidationError(f"matrices: expected shape (T, J, 4, 4), got {m.shape}")
        chunk = _check_chunk(chunk)
        return (self.deform(m[s : s + chunk]) for s in range(0, m.shape[0], chunk))


class LinearBlendSkinning(SkinningDeformer):
    """Linear blend skinning: ``p' = sum_k w_k S_{j_k} [p; 1]``.

    See :class:`SkinningDeformer` for the parameters and :meth:`SkinningDeformer.deform`.
    The NumPy kernel is one sparse product per batch of frames: a constant
    ``(V, 4 J)`` matrix holding ``w_k [x, y, z, 1]`` (libigl's ``lbs_matrix``, kept
    sparse) times the stacked transposed skinning matrices ``(4 J, 3 t)``.

    Examples
    --------
    >>> lbs = LinearBlendSkinning([[1.0, 0.0, 0.0]], [[0, 1]], [[0.5, 0.5]])
    >>> shift = np.eye(4); shift[0, 3] = 2.0
    >>> lbs.deform(np.stack([np.eye(4), shift]))
    array([[2., 0., 0.]])
    """

    method = "lbs"

    def _prepare(self) -> None:
        n_v, n_k = self.joint_weights.shape
        vh = np.concatenate([self.rest_vertices, np.ones((n_v, 1))], axis=1)  # (V, 4)
        vals = self.joint_weights[:, :, None] * vh[:, None, :]  # (V, K, 4)
        cols = 4 * self.joint_indices[:, :, None] + np.arange(4)  # (V, K, 4)
        rows = np.repeat(np.arange(n_v), n_k * 4)
        self._lbs_matrix = scipy.sparse.csr_matrix(
            (vals.ravel(), (rows, cols.ravel())), shape=(n_v, 4 * self._used_joints)
        )

    def _numpy_batch(self, matrices: np.ndarray, out: np.ndarray) -> None:
        n_t = matrices.shape[0]
        j = self._used_joints
        # stacked (4 J, 3 t): row 4 j + c, column 3 f + r holds S[f, j, r, c]
        stacked = np.ascontiguousarray(matrices[:, :j, :3, :].transpose(1, 3, 0, 2))
        prod = self._lbs_matrix @ stacked.reshape(4 * j, 3 * n_t)  # (V, 3 t)
        out[...] = prod.reshape(-1, n_t, 3).transpose(1, 0, 2)

    def _numba_all(self, matrices: np.ndarray, out: np.ndarray) -> None:
        aff = np.ascontiguousarray(matrices[:, :, :3, :])
        _lbs_dispatcher()(self.rest_vertices, self.joint_indices, self.joint_weights, aff, out)


class DualQuaternionSkinning(SkinningDeformer):
    """Dual-quaternion skinning (Kavan et al. 2008) with the antipodality fix.

    See the module docstring for the algorithm (pivot = largest-weight influence;
    non-rigid matrices: linear blend of the stretch, then DQS of the rigid part)
    and :class:`SkinningDeformer` for the parameters.

    Examples
    --------
    >>> dqs = DualQuaternionSkinning([[1.0, 0.0, 0.0]], [[0, 1]], [[0.5, 0.5]])
    >>> turn = np.diag([-1.0, -1.0, 1.0, 1.0])  # 180 degrees about z
    >>> np.round(dqs.deform(np.stack([np.eye(4), turn])), 12) + 0.0  # half-way: 90 degrees
    array([[0., 1., 0.]])
    """

    method = "dqs"

    def _prepare(self) -> None:
        first_max = np.argmax(self.joint_weights, axis=1)  # (V,)
        self._pivot = np.ascontiguousarray(
            np.take_along_axis(self.joint_indices, first_max[:, None], axis=1)[:, 0]
        )
        self._stretch_matrix: scipy.sparse.csr_matrix | None = None
        self._rest_components = np.ascontiguousarray(self.rest_vertices.T)  # (3, V)

    def _numpy_batch(self, matrices: np.ndarray, out: np.ndarray) -> None:
        """Reference DQS on a batch of frames: (t, J, 4, 4) -> ``out`` (t, V, 3).

        The blend ``b = sum_k s_k w_k q_{j_k}`` of all t frames is one sparse product
        (block-diagonal over frames); the signs ``s_k`` come from the per-frame Gram
        matrix of the real parts, looked up at (pivot, joint) pairs.
        """
        dq, stretch = _split_rigid(matrices)  # (t, J, 8), (t, J, 3, 3) | None
        n_t, n_j = dq.shape[:2]
        n_v, n_k = self.joint_indices.shape
        real = dq[..., :4]
        gram = np.einsum("tjc,tkc->tjk", real, real).reshape(n_t, n_j * n_j)  # (t, J*J)
        pair = self._pivot[:, None] * n_j + self.joint_indices  # (V, K)
        dots = np.take(gram, pair.ravel(), axis=1)  # <real(q_k), real(q_pivot)>  (t, V*K)
        w = self.joint_weights.ravel()
        coef = np.where(dots < 0.0, -w, w)  # s_k w_k  (t, V*K)
        itype = np.int32 if n_t * max(n_j, n_v * n_k) < 2**31 - 1 else np.int64
        cols = (
            np.arange(n_t, dtype=itype)[:, None] * n_j
            + self.joint_indices.ravel().astype(itype)[None]
        )  # (t, V*K): joint j of frame f is column f*J + j
        rows = np.arange(0, n_t * n_v * n_k + 1, n_k, dtype=itype)
        blend_matrix = scipy.sparse.csr_matrix(
            (coef.ravel(), cols.ravel(), rows), shape=(n_t * n_v, n_t * n_j)
        )
        blend = blend_matrix @ dq.reshape(n_t * n_j, 8)  # (t*V, 8)
        # components as contiguous (t, V) arrays
        rx, ry, rz, rw, dx, dy, dz, dw = np.ascontiguousarray(blend.T).reshape(8, n_t, n_v)
        if stretch is None:
            x, y, z = self._rest_components  # (V,) each
        else:
            x, y, z = self._stretched(stretch)  # (t, V) each
        # b / |real(b)| applied to p: rotation p + 2 (rw u + r x u), u = r x p, and
        # translation 2 (rw d - dw r + r x d); both are quadratic in b, so the
        # normalisation is the one factor 2 / |real(b)|^2 (never 0: the pivot's
        # own term keeps <real(b), real(q_pivot)> >= its weight)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = 2.0 / (rx * rx + ry * ry + rz * rz + rw * rw)
        ux = ry * z - rz * y
        uy = rz * x - rx * z
        uz = rx * y - ry * x
        out[..., 0] = x + scale * (rw * (ux + dx) + ry * uz - rz * uy - dw * rx + ry * dz - rz * dy)
        out[..., 1] = y + scale * (rw * (uy + dy) + rz * ux - rx * uz - dw * ry + rz * dx - rx * dz)
        out[..., 2] = z + scale * (rw * (uz + dz) + rx * uy - ry * ux - dw * rz + rx * dy - ry * dx)

    def _stretched(self, stretch: np.ndarray) -> np.ndarray:
        """First phase for non-rigid matrices: ``sum_k w_k P_{j_k} p`` as (3, t, V)."""
        j = self._used_joints
        if self._stretch_matrix is None:
            n_v, n_k = self.joint_weights.shape
            vals = self.joint_weights[:, :, None] * self.rest_vertices[:, None, :]  # (V, K, 3)
            cols = 3 * self.joint_indices[:, :, None] + np.arange(3)  # (V, K, 3)
            rows = np.repeat(np.arange(n_v), n_k * 3)
            self._stretch_matrix = scipy.sparse.csr_matrix(
                (vals.ravel(), (rows, cols.ravel())), shape=(n_v, 3 * j)
            )
        n_t = stretch.shape[0]
        # row 3 j + c, column 3 f + r holds P[f, j, r, c]
        stacked = np.ascontiguousarray(stretch[:, :j].transpose(1, 3, 0, 2))
        prod = self._stretch_matrix @ stacked.reshape(3 * j, 3 * n_t)  # (V, 3 t)
        return np.ascontiguousarray(prod.reshape(-1, n_t, 3).transpose(2, 1, 0))

    def _numba_all(self, matrices: np.ndarray, out: np.ndarray) -> None:
        dq, stretch = _split_rigid(matrices)
        has_stretch = stretch is not None
        if stretch is None:
            stretch = np.zeros((1, 1, 3, 3))
        _dqs_dispatcher()(
            self.rest_vertices,
            self.joint_indices,
            self.joint_weights,
            self._pivot,
            np.ascontiguousarray(dq),
            np.ascontiguousarray(stretch),
            has_stretch,
            out,
        )


_DEFORMERS: dict[str, type[SkinningDeformer]] = {
    "lbs": LinearBlendSkinning,
    "dqs": DualQuaternionSkinning,
}


def _check_method(method: str) -> type[SkinningDeformer]:
    if method not in _DEFORMERS:
        raise ValidationError(f"method: expected 'lbs' or 'dqs', got {method!r}")
    return _DEFORMERS[method]


def _check_chunk(chunk: Any) -> int:
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise ValidationError(f"chunk: expected a positive number of frames, got {chunk!r}")
    return int(chunk)


def make_deformer(method: Method, mesh: Mesh, *, backend: Backend = "auto") -> SkinningDeformer:
    """The deformer for ``method`` over a skinned mesh.

    Parameters
    ----------
    method : {"lbs", "dqs"}
    mesh : Mesh
        With a :class:`~skincap.types.Skin`; its rest ``vertices`` (V, 3) metres are
        the bind pose.
    backend : {"auto", "numba", "numpy"}, default "auto"

    Returns
    -------
    SkinningDeformer
        :class:`LinearBlendSkinning` or :class:`DualQuaternionSkinning` expecting
        ``(…, J, 4, 4)`` matrices for the skin's J joints.
    """
    cls = _check_method(method)
    if not isinstance(mesh, Mesh):
        raise ValidationError(f"mesh: expected a Mesh, got {type(mesh).__name__}")
    if mesh.skin is None:
        raise ValidationError("mesh: has no skin (bind it to a skeleton first)")
    skin = mesh.skin
    return cls(
        mesh.vertices,
        skin.joint_indices,
        skin.joint_weights,
        n_joints=skin.skeleton.n_joints,
        backend=backend,
    )


def _check_same_skeleton(mesh: Mesh, motion: Motion) -> None:
    want = mesh.skin.skeleton  # type: ignore[union-attr]
    have = motion.skeleton
    for k, (a, b) in enumerate(zip(want.names, have.names, strict=False)):
        if a != b:
            raise ValidationError(
                f"motion: not on the mesh's skeleton: joint {k} is '{b}', the skin's is '{a}'"
            )
    if len(want.names) != len(have.names):
        k = min(len(want.names), len(have.names))
        extra = (want.names if len(want.names) > k else have.names)[k]
        raise ValidationError(
            f"motion: not on the mesh's skeleton: {len(have.names)} joints against the skin's "
            f"{len(want.names)} (first unmatched joint '{extra}')"
        )
    diff = np.nonzero(want.parents != have.parents)[0]
    if diff.size:
        k = int(diff[0])
        raise ValidationError(
            f"motion: not on the mesh's skeleton: joint '{want.names[k]}' has a different parent"
        )


def skin_motion(
    mesh: Mesh,
    motion: Motion,
    *,
    method: Method = "lbs",
    chunk: int = 64,
    progress: Callable[[float], object] | None = None,
    backend: Backend = "auto",
) -> MeshAnimation:
    """Skin a motion on a mesh, streaming the frames chunk by chunk.

    Parameters
    ----------
    mesh : Mesh
        With a :class:`~skincap.types.Skin` (rest vertices in the bind pose, metres).
    motion : Motion
        On the skin's own skeleton: same joint names in the same order (and the
        same parents). Forward kinematics gives ``W (T, J, 4, 4)``; the skinning
        matrices are ``W @ skin.inverse_bind``.
    method : {"lbs", "dqs"}, default "lbs"
    chunk : int, default 64
        Frames computed per block.
    progress : callable, optional
        Called with the fraction of frames done (0..1] after each block, as the
        frames are consumed.
    backend : {"auto", "numba", "numpy"}, default "auto"

    Returns
    -------
    MeshAnimation
        ``rest`` is ``mesh``; ``frames`` is a one-shot iterator of (t, V, 3) float64
        chunks in metres; ``n_frames`` = ``motion.n_frames``; ``rate`` =
        ``motion.rate``; ``meta`` has ``skinning_method`` and ``skinning_backend``.

    Raises
    ------
    ValidationError
        Unknown method, bad chunk, a mesh without a skin, or a motion on another
        skeleton (the message names the first joint that differs). Raised here,
        before any frame is computed.
    """
    cls = _check_method(method)
    chunk = _check_chunk(chunk)
    if not isinstance(motion, Motion):
        raise ValidationError(f"motion: expected a Motion, got {type(motion).__name__}")
    if progress is not None and not callable(progress):
        raise ValidationError("progress: expected a callable taking a fraction, or None")
    deformer = make_deformer(method, mesh, backend=backend)
    _check_same_skeleton(mesh, motion)
    return MeshAnimation(
        rest=mesh,
        frames=deformed_chunks(deformer, mesh, motion, chunk, progress),
        rate=motion.rate,
        n_frames=motion.n_frames,
        meta={"skinning_method": cls.method, "skinning_backend": deformer.backend},
    )


def deformed_chunks(
    deformer: Any,
    mesh: Mesh,
    motion: Motion,
    chunk: int,
    progress: Callable[[float], None] | None = None,
) -> Iterator[np.ndarray]:
    """``motion``'s frames deformed ``chunk`` at a time: ``(t, V, 3)`` arrays, metres.

    ``deformer.deform`` takes ``(t, J, 4, 4)`` skinning matrices (forward kinematics
    times ``mesh.skin.inverse_bind``); ``progress`` gets the fraction done after each
    chunk. The skeletons must already match (:func:`skin_motion` checks them)."""
    inverse_bind = mesh.skin.inverse_bind  # type: ignore[union-attr]
    n_frames = motion.n_frames
    for s in range(0, n_frames, chunk):
        e = min(n_frames, s + chunk)
        world = forward_kinematics_arrays(
            motion.skeleton, motion.rotations[s:e], motion.translations[s:e]
        )  # (t, J, 4, 4)
        yield deformer.deform(np.matmul(world, inverse_bind))
        if progress is not None:
            progress(e / n_frames)
