"""The core data types of skincap.

Every array has a documented shape, dtype and unit; everything inside skincap is in
metres and seconds, right-handed with Y up (readers convert and record the source
unit and axes in ``meta``). Quaternions are scalar-last ``(x, y, z, w)``.

This module imports nothing else from skincap except :mod:`skincap.errors`, so every
other sub-package can depend on it.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from skincap.errors import ValidationError

__all__ = [
    "MarkerTrajectories",
    "MarkerSet",
    "PointCloud",
    "Skeleton",
    "Motion",
    "Skin",
    "Mesh",
    "MeshAnimation",
    "ROTATION_CHANNELS",
    "POSITION_CHANNELS",
]

POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
ROTATION_CHANNELS = ("Xrotation", "Yrotation", "Zrotation")


# --------------------------------------------------------------------------- checks
def _float_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    """Return ``value`` as a float64 array of ``shape`` (None = any size) or raise."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(
            f"{name}: expected a float array of shape {_fmt(shape)}: {exc}"
        ) from None
    _check_shape(name, arr, shape)
    return arr


def _int_array(name: str, value: Any, shape: tuple[int | None, ...]) -> np.ndarray:
    arr = np.asarray(value)
    if arr.size == 0:
        arr = arr.astype(np.int64)
    if not np.issubdtype(arr.dtype, np.integer):
        if (
            np.issubdtype(arr.dtype, np.floating)
            and np.all(np.isfinite(arr))
            and np.all(arr == np.round(arr))
        ):
            arr = arr.astype(np.int64)
        else:
            raise ValidationError(f"{name}: expected an integer array, got dtype {arr.dtype}")
    arr = arr.astype(np.int64, copy=False)
    _check_shape(name, arr, shape)
    return arr


def _fmt(shape: tuple[int | None, ...]) -> str:
    return (
        "("
        + ", ".join("*" if s is None else str(s) for s in shape)
        + ("," if len(shape) == 1 else "")
        + ")"
    )


def _check_shape(name: str, arr: np.ndarray, shape: tuple[int | None, ...]) -> None:
    ok = arr.ndim == len(shape) and all(
        s is None or s == a for s, a in zip(shape, arr.shape, strict=False)
    )
    if not ok:
        raise ValidationError(f"{name}: expected shape {_fmt(shape)}, got {arr.shape}")


def _check_rate(rate: Any) -> float:
    try:
        r = float(rate)
    except (TypeError, ValueError):
        raise ValidationError(
            f"rate: expected a positive number of frames per second, got {rate!r}"
        ) from None
    if not np.isfinite(r) or r <= 0:
        raise ValidationError(f"rate: expected a positive finite frame rate in Hz, got {rate!r}")
    return r


# ----------------------------------------------------------------------- MarkerSet
class MarkerTrajectories:
    """Counts and clock of N marker trajectories sampled at one rate.

    A base for the types that hold ``positions`` (T, N, 3) metres at ``rate`` Hz
    (:class:`MarkerSet`, the tracker's ``RopeTrack``): they get :attr:`n_frames`,
    :attr:`n_markers`, :attr:`duration` and :attr:`times` from here.
    """

    positions: np.ndarray
    rate: float

    @property
    def n_frames(self) -> int:
        return int(self.positions.shape[0])

    @property
    def n_markers(self) -> int:
        return int(self.positions.shape[1])

    @property
    def duration(self) -> float:
        """Seconds from the first to one frame past the last, ``T / rate``."""
        return self.n_frames / self.rate

    @property
    def times(self) -> np.ndarray:
        """(T,) float64 seconds from the first frame."""
        return np.arange(self.n_frames) / self.rate


@dataclass(eq=False)
class MarkerSet(MarkerTrajectories):
    """Labelled marker trajectories.

    Attributes
    ----------
    positions : (T, N, 3) float64, metres
        NaN where a marker is missing (all three coordinates together).
    labels : list of N str
        Unique labels. Unlabelled trajectory fragments have labels such as ``*17``.
    rate : float, Hz
        Exact frame rate (never rounded).
    residuals : (T, N) float64, metres, optional
        Per-sample reconstruction quality (C3D residual); NaN where missing.
    invented : (T, N) bool, optional
        True where a sample was made up by a gap filler rather than measured.
    meta : dict
        Source details: ``source_units``, ``up``, ``first_frame``, ``model_outputs``…
        From a C3D, ``c3d``: what the file carries besides the points (analogs,
        events, every parameter), immutable, written back by the C3D writer while
        the frame count is unchanged; pass ``meta`` along to keep it.
    camera_masks : (T, N) uint8, optional
        Per-sample C3D camera mask: bit k set when camera k + 1 of the seven the
        format records contributed to the sample. Measured data, written back by
        the C3D writer; 0 where missing or unknown.
    """

    positions: np.ndarray
    labels: list[str]
    rate: float
    residuals: np.ndarray | None = None
    invented: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)
    camera_masks: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.positions = _float_array("positions", self.positions, (None, None, 3))
        t, n, _ = self.positions.shape
        self.labels = [str(s) for s in self.labels]
        if len(self.labels) != n:
            raise ValidationError(
                f"labels: expected {n} labels (one per marker column), got {len(self.labels)}"
            )
        if len(set(self.labels)) != n:
            dup = sorted({s for s in self.labels if self.labels.count(s) > 1})
            raise ValidationError(f"labels: must be unique, duplicated: {dup[:5]}")
        self.rate = _check_rate(self.rate)
        if np.isinf(self.positions).any():
            raise ValidationError(
                "positions: contains infinite values (use NaN for missing samples)"
            )
        # A marker is missing as a whole: one NaN coordinate makes the sample missing.
        missing = np.isnan(self.positions).any(axis=2)
        if missing.any():
            self.positions[missing] = np.nan
        if self.residuals is not None:
            self.residuals = _float_array("residuals", self.residuals, (t, n))
        if self.invented is not None:
            inv = np.asarray(self.invented)
            _check_shape("invented", inv, (t, n))
            self.invented = inv.astype(bool)
        if self.camera_masks is not None:
            cm = np.asarray(self.camera_masks)
            _check_shape("camera_masks", cm, (t, n))
            if cm.dtype.kind not in "iub" or (cm.size and (cm.min() < 0 or cm.max() > 127)):
                raise ValidationError(
                    "camera_masks: expected integers in 0..127 (seven camera bits)"
                )
            self.camera_masks = cm.astype(np.uint8)
        self.meta = dict(self.meta)

    @property
    def missing(self) -> np.ndarray:
        """(T, N) bool: True where the marker is missing."""
        return np.isnan(self.positions[..., 0])

    @property
    def unlabelled(self) -> np.ndarray:
        """(N,) bool: True for fragment columns labelled ``*N``."""
        return np.array([s.startswith("*") for s in self.labels], dtype=bool)

    def select(self, columns: Sequence[int] | np.ndarray) -> MarkerSet:
        """A new MarkerSet holding only ``columns`` (indices or an (N,) bool mask)."""
        idx = np.arange(self.n_markers)[np.asarray(columns)]
        return MarkerSet(
            positions=self.positions[:, idx].copy(),
            labels=[self.labels[i] for i in idx],
            rate=self.rate,
            residuals=None if self.residuals is None else self.residuals[:, idx].copy(),
            invented=None if self.invented is None else self.invented[:, idx].copy(),
            meta=dict(self.meta),
            camera_masks=None if self.camera_masks is None else self.camera_masks[:, idx].copy(),
        )


# ---------------------------------------------------------------------- PointCloud
@dataclass(eq=False)
class PointCloud:
    """Un-indexed points per frame in CSR layout.

    Attributes
    ----------
    points : (M, 3) float64, metres
        All points of all frames, frame after frame. Never NaN.
    offsets : (T + 1,) int64
        Frame ``t`` is ``points[offsets[t]:offsets[t + 1]]``; ``offsets[0] == 0``,
        non-decreasing, ``offsets[-1] == M``.
    rate : float, Hz
    ids : (M,) int64, optional
        A per-point identity where the source has one (ground truth, OptiTrack ids);
        -1 where unknown.
    meta : dict
    """

    points: np.ndarray
    offsets: np.ndarray
    rate: float
    ids: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.points = _float_array("points", self.points, (None, 3))
        if not np.isfinite(self.points).all():
            raise ValidationError("points: must be finite (a point cloud has no missing samples)")
        self.offsets = _int_array("offsets", self.offsets, (None,))
        m = self.points.shape[0]
        if self.offsets.size < 1 or self.offsets[0] != 0:
            raise ValidationError("offsets: expected (T + 1,) starting at 0")
        if self.offsets[-1] != m:
            raise ValidationError(
                f"offsets: last entry must equal the number of points {m}, got {int(self.offsets[-1])}"
            )
        if np.any(np.diff(self.offsets) < 0):
            raise ValidationError("offsets: must be non-decreasing")
        if self.ids is not None:
            self.ids = _int_array("ids", self.ids, (m,))
        self.rate = _check_rate(self.rate)
        self.meta = dict(self.meta)

    @property
    def n_frames(self) -> int:
        return int(self.offsets.size - 1)

    @property
    def counts(self) -> np.ndarray:
        """(T,) int64: number of points in each frame."""
        return np.diff(self.offsets)

    @property
    def frame_index(self) -> np.ndarray:
        """(M,) int64: the frame each point belongs to."""
        return np.repeat(np.arange(self.n_frames), self.counts)

    def frame(self, t: int) -> np.ndarray:
        """(n_t, 3) float64: the points of frame ``t`` (a view)."""
        return self.points[self.offsets[t] : self.offsets[t + 1]]

    def select(self, keep: np.ndarray, n_frames: int | None = None) -> PointCloud:
        """The points where ``keep`` (M,) bool is True, each in its frame (ids and meta kept).

        ``n_frames`` (default: all) cuts the take to its first frames; ``keep`` must then
        be False for every point after them.
        """
        n = self.n_frames if n_frames is None else int(n_frames)
        counts = np.bincount(self.frame_index[keep], minlength=n)[:n]
        return PointCloud(
            points=self.points[keep],
            offsets=np.concatenate([[0], np.cumsum(counts)]).astype(np.int64),
            rate=self.rate,
            ids=None if self.ids is None else self.ids[keep],
            meta=dict(self.meta),
        )

    def to_markerset(self) -> MarkerSet:
        """Columns by point id: the inverse of :meth:`from_markerset`.

        Every distinct id becomes one column, labelled from ``meta["id_labels"]`` when
        present and ``*<id>`` otherwise; frames where an id has no point are NaN.

        Raises
        ------
        ValidationError
            The cloud has no ids, or an id appears twice in one frame.
        """
        if self.ids is None:
            raise ValidationError(
                "ids: an un-indexed point cloud has no trajectories; track it first (skincap track)"
            )
        frame = self.frame_index
        uniq, column = np.unique(self.ids, return_inverse=True)
        positions = np.full((self.n_frames, uniq.size, 3), np.nan)
        taken = np.zeros((self.n_frames, uniq.size), dtype=np.int64)
        np.add.at(taken, (frame, column), 1)
        if (taken > 1).any():
            t, c = np.argwhere(taken > 1)[0]
            raise ValidationError(
                f"ids: id {int(uniq[c])} appears {int(taken[t, c])} times in frame {int(t)}"
            )
        positions[frame, column] = self.points
        names = self.meta.get("id_labels")
        if names is not None and uniq.size and uniq.min() >= 0 and uniq.max() < len(names):
            labels = [str(names[i]) for i in uniq]
        else:
            labels = [f"*{int(i)}" for i in uniq]
        meta = {k: v for k, v in self.meta.items() if k != "id_labels"}
        return MarkerSet(positions=positions, labels=labels, rate=self.rate, meta=meta)

    @classmethod
    def from_markerset(cls, markers: MarkerSet, *, keep_ids: bool = True) -> PointCloud:
        """Drop the labels of ``markers``: every present sample becomes a point.

        Point ids are the marker column indices when ``keep_ids``.
        """
        present = ~markers.missing  # (T, N)
        t_idx, n_idx = np.nonzero(present)
        offsets = np.concatenate([[0], np.cumsum(present.sum(axis=1))])
        return cls(
            points=markers.positions[t_idx, n_idx],
            offsets=offsets,
            rate=markers.rate,
            ids=n_idx if keep_ids else None,
            meta={**markers.meta, "id_labels": list(markers.labels)}
            if keep_ids
            else dict(markers.meta),
        )


# ------------------------------------------------------------------------ Skeleton
@dataclass(eq=False)
class Skeleton:
    """A joint hierarchy in its rest (zero) pose.

    Attributes
    ----------
    names : list of J str
        Unique joint names. End sites are joints too (named ``<parent>_end`` by the
        BVH reader) and carry no channels in a :class:`Motion`.
    parents : (J,) int64
        Parent index, -1 for a root; ``parents[j] < j`` (topological order).
    offsets : (J, 3) float64, metres
        Rest translation of each joint relative to its parent (world for roots).
    """

    names: list[str]
    parents: np.ndarray
    offsets: np.ndarray

    def __post_init__(self) -> None:
        self.names = [str(s) for s in self.names]
        j = len(self.names)
        if j == 0:
            raise ValidationError("names: a skeleton needs at least one joint")
        if len(set(self.names)) != j:
            dup = sorted({s for s in self.names if self.names.count(s) > 1})
            raise ValidationError(f"names: joint names must be unique, duplicated: {dup[:5]}")
        self.parents = _int_array("parents", self.parents, (j,))
        self.offsets = _float_array("offsets", self.offsets, (j, 3))
        if not np.isfinite(self.offsets).all():
            raise ValidationError("offsets: must be finite")
        bad = np.nonzero((self.parents >= np.arange(j)) | (self.parents < -1))[0]
        if bad.size:
            k = int(bad[0])
            raise ValidationError(
                f"parents: each joint's parent must come before it (-1 for a root); "
                f"joint {k} '{self.names[k]}' has parent {int(self.parents[k])}"
            )

    @property
    def n_joints(self) -> int:
        return len(self.names)

    def index(self, name: str) -> int:
        """Index of the joint called ``name``; ValidationError if there is none."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ValidationError(f"joint '{name}' is not in the skeleton") from None

    def children(self, j: int) -> np.ndarray:
        """(k,) int64 indices of the children of joint ``j``."""
        return np.nonzero(self.parents == j)[0]

    @property
    def is_leaf(self) -> np.ndarray:
        """(J,) bool: joints with no children."""
        has_child = np.zeros(self.n_joints, dtype=bool)
        has_child[self.parents[self.parents >= 0]] = True
        return ~has_child


# -------------------------------------------------------------------------- Motion
@dataclass(eq=False)
class Motion:
    """A skeleton animated over T frames.

    Attributes
    ----------
    skeleton : Skeleton
    rotations : (T, J, 4) float64
        Local rotation of each joint relative to its parent, unit quaternions
        ``(x, y, z, w)``; identity for joints without rotation channels.
    translations : (T, J, 3) float64, metres
        Local translation of each joint relative to its parent; equal to the rest
        offset for joints without position channels.
    rate : float, Hz
        Exact frame rate, ``1 / frame_time``.
    channels : list of J tuples of str
        The BVH channel layout per joint, e.g. ``("Xposition", "Yposition",
        "Zposition", "Zrotation", "Yrotation", "Xrotation")``; empty for end sites.
    meta : dict
        ``source_units``, ``up``, ``frame_time`` (seconds, as written in the file)…
    """

    skeleton: Skeleton
    rotations: np.ndarray
    translations: np.ndarray
    rate: float
    channels: list[tuple[str, ...]] | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        j = self.skeleton.n_joints
        self.rotations = _float_array("rotations", self.rotations, (None, j, 4))
        t = self.rotations.shape[0]
        self.translations = _float_array("translations", self.translations, (t, j, 3))
        if not (np.isfinite(self.rotations).all() and np.isfinite(self.translations).all()):
            raise ValidationError("rotations/translations: must be finite")
        norms = np.linalg.norm(self.rotations, axis=-1)
        if t and np.abs(norms - 1.0).max() > 1e-6:
            raise ValidationError(
                f"rotations: expected unit quaternions (x, y, z, w), norms range {norms.min():.6g}..{norms.max():.6g}"
            )
        self.rate = _check_rate(self.rate)
        if self.channels is None:
            self.channels = [
                (POSITION_CHANNELS + ("Zrotation", "Yrotation", "Xrotation"))
                if p < 0
                else ("Zrotation", "Yrotation", "Xrotation")
                for p in self.skeleton.parents
            ]
            # joints without children are end sites unless they are roots
            leaves = self.skeleton.is_leaf
            self.channels = [
                () if leaves[k] and self.skeleton.parents[k] >= 0 else c
                for k, c in enumerate(self.channels)
            ]
        self.channels = [tuple(str(c) for c in ch) for ch in self.channels]
        if len(self.channels) != j:
            raise ValidationError(
                f"channels: expected {j} channel tuples (one per joint), got {len(self.channels)}"
            )
        known = set(POSITION_CHANNELS) | set(ROTATION_CHANNELS)
        for name, ch in zip(self.skeleton.names, self.channels, strict=True):
            unknown = [c for c in ch if c not in known]
            if unknown or len(set(ch)) != len(ch):
                raise ValidationError(f"channels: joint '{name}' has invalid channels {ch}")
        self.meta = dict(self.meta)

    @property
    def n_frames(self) -> int:
        return int(self.rotations.shape[0])

    @property
    def frame_time(self) -> float:
        """Seconds per frame; the file's own value when read from a BVH."""
        return float(self.meta.get("frame_time", 1.0 / self.rate))

    @property
    def duration(self) -> float:
        return self.n_frames / self.rate


# ---------------------------------------------------------------------------- Skin
@dataclass(eq=False)
class Skin:
    """Binding of a mesh's vertices to the joints of a skeleton.

    Attributes
    ----------
    skeleton : Skeleton
    joint_indices : (V, K) int64
        Influencing joints per vertex (index into ``skeleton``); pad with 0.
    joint_weights : (V, K) float64
        Weights; each row sums to 1 (rows with no influence are not allowed).
    inverse_bind : (J, 4, 4) float64
        Inverse of each joint's world transform in the bind pose (metres).
    """

    skeleton: Skeleton
    joint_indices: np.ndarray
    joint_weights: np.ndarray
    inverse_bind: np.ndarray

    def __post_init__(self) -> None:
        j = self.skeleton.n_joints
        self.joint_weights = _float_array("joint_weights", self.joint_weights, (None, None))
        v, k = self.joint_weights.shape
        self.joint_indices = _int_array("joint_indices", self.joint_indices, (v, k))
        self.inverse_bind = _float_array("inverse_bind", self.inverse_bind, (j, 4, 4))
        if self.joint_indices.size and (
            self.joint_indices.min() < 0 or self.joint_indices.max() >= j
        ):
            raise ValidationError(
                f"joint_indices: must index the {j} joints, range is {self.joint_indices.min()}..{self.joint_indices.max()}"
            )
        if not np.isfinite(self.joint_weights).all() or (self.joint_weights < 0).any():
            raise ValidationError("joint_weights: must be finite and non-negative")
        sums = self.joint_weights.sum(axis=1)
        if v and np.abs(sums - 1.0).max() > 1e-6:
            bad = int(np.argmax(np.abs(sums - 1.0)))
            raise ValidationError(
                f"joint_weights: rows must sum to 1; vertex {bad} sums to {sums[bad]:.6g}"
            )

    @property
    def bind_matrices(self) -> np.ndarray:
        """(J, 4, 4) world transforms of the joints in the bind pose."""
        return np.linalg.inv(self.inverse_bind)


# ---------------------------------------------------------------------------- Mesh
@dataclass(eq=False)
class Mesh:
    """A triangle mesh, optionally with its source polygons, groups, UVs and a skin.

    Attributes
    ----------
    vertices : (V, 3) float64, metres
    faces : (F, 3) int64
        Triangles (counter-clockwise seen from outside); what algorithms use.
    polygon_indices, polygon_offsets : (P,) int64 and (G + 1,) int64, optional
        The source polygons in CSR layout (polygon ``g`` is
        ``polygon_indices[polygon_offsets[g]:polygon_offsets[g + 1]]``); kept so
        exports can write quads back.
    face_polygon : (F,) int64, optional
        The source polygon each triangle came from.
    groups : dict of str to (k,) int64
        Named groups as indices of source polygons (or of triangles when there are
        no polygons).
    uv : (V, 2) float64, optional
    skin : Skin, optional
    meta : dict
    """

    vertices: np.ndarray
    faces: np.ndarray
    polygon_indices: np.ndarray | None = None
    polygon_offsets: np.ndarray | None = None
    face_polygon: np.ndarray | None = None
    groups: dict[str, np.ndarray] = field(default_factory=dict)
    uv: np.ndarray | None = None
    skin: Skin | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = _float_array("vertices", self.vertices, (None, 3))
        if not np.isfinite(self.vertices).all():
            raise ValidationError("vertices: must be finite")
        v = self.vertices.shape[0]
        self.faces = _int_array(
            "faces",
            np.asarray(self.faces).reshape(-1, 3)
            if np.asarray(self.faces).size == 0
            else self.faces,
            (None, 3),
        )
        if self.faces.size and (self.faces.min() < 0 or self.faces.max() >= v):
            raise ValidationError(
                f"faces: vertex indices must be in 0..{v - 1}, range is {self.faces.min()}..{self.faces.max()}"
            )
        if (self.polygon_indices is None) != (self.polygon_offsets is None):
            raise ValidationError("polygon_indices and polygon_offsets: give both or neither")
        if self.polygon_indices is not None:
            self.polygon_indices = _int_array("polygon_indices", self.polygon_indices, (None,))
            self.polygon_offsets = _int_array("polygon_offsets", self.polygon_offsets, (None,))
            if (
                self.polygon_offsets[0] != 0
                or self.polygon_offsets[-1] != self.polygon_indices.size
                or np.any(np.diff(self.polygon_offsets) < 3)
            ):
                raise ValidationError(
                    "polygon_offsets: expected CSR offsets from 0 to len(polygon_indices), 3+ vertices a polygon"
                )
            if self.polygon_indices.size and (
                self.polygon_indices.min() < 0 or self.polygon_indices.max() >= v
            ):
                raise ValidationError("polygon_indices: vertex index out of range")
        if self.face_polygon is not None:
            self.face_polygon = _int_array(
                "face_polygon", self.face_polygon, (self.faces.shape[0],)
            )
        self.groups = {
            str(k): _int_array(f"groups[{k!r}]", g, (None,)) for k, g in self.groups.items()
        }
        if self.uv is not None:
            self.uv = _float_array("uv", self.uv, (v, 2))
        if self.skin is not None and self.skin.joint_weights.shape[0] != v:
            raise ValidationError(
                f"skin: weights cover {self.skin.joint_weights.shape[0]} vertices, the mesh has {v}"
            )
        self.meta = dict(self.meta)

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def n_polygons(self) -> int:
        return self.n_faces if self.polygon_offsets is None else int(self.polygon_offsets.size - 1)

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: minimum and maximum corner, metres."""
        if self.n_vertices == 0:
            return np.zeros((2, 3))
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


# ------------------------------------------------------------------- MeshAnimation
@dataclass(eq=False)
class MeshAnimation:
    """A mesh whose vertices move over time.

    Attributes
    ----------
    rest : Mesh
        Topology and rest positions.
    frames : (T, V, 3) float64 array, metres, or an iterable of (t, V, 3) chunks
        Vertex positions per frame. A chunk iterable lets long takes stream: it is
        consumed once by :meth:`iter_chunks`.
    rate : float, Hz
    n_frames : int, optional
        Required when ``frames`` is an iterable (exporters write headers first).
    """

    rest: Mesh
    frames: np.ndarray | Iterable[np.ndarray]
    rate: float
    n_frames: int | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.rate = _check_rate(self.rate)
        v = self.rest.n_vertices
        if isinstance(self.frames, np.ndarray) or isinstance(self.frames, list):
            self.frames = _float_array("frames", self.frames, (None, v, 3))
            if self.n_frames is not None and self.n_frames != self.frames.shape[0]:
                raise ValidationError(
                    f"n_frames: {self.n_frames} given but frames has {self.frames.shape[0]}"
                )
            self.n_frames = int(self.frames.shape[0])
        elif self.n_frames is None:
            raise ValidationError("n_frames: required when frames is an iterator of chunks")
        self.meta = dict(self.meta)

    @property
    def is_streamed(self) -> bool:
        return not isinstance(self.frames, np.ndarray)

    def iter_chunks(self, chunk: int = 64) -> Iterator[np.ndarray]:
        """Yield (t, V, 3) float64 chunks in order, at most ``chunk`` frames each."""
        v = self.rest.n_vertices
        if isinstance(self.frames, np.ndarray):
            for s in range(0, self.frames.shape[0], chunk):
                yield self.frames[s : s + chunk]
            return
        seen = 0
        for block in self.frames:
            arr = _float_array("frames chunk", block, (None, v, 3))
            seen += arr.shape[0]
            yield arr
        if seen != self.n_frames:
            raise ValidationError(
                f"frames: iterator gave {seen} frames, n_frames says {self.n_frames}"
            )
