"""Load any files skincap reads or writes into one time-aligned scene of drawable layers.

The viewer (:mod:`skincap.viz.viewer`), the offscreen renderer (:mod:`skincap.viz.render`) and
the demo report draw what this module loads. Every layer keeps its own rate; the scene
plays on a common clock in seconds and :meth:`Scene.layer_frame` picks each layer's
nearest frame.

=====================  ==========================================================
input                  layers
=====================  ==========================================================
``.c3d .trc``          markers (a C3D of ``*N`` fragments only is still markers)
Vicon/OptiTrack CSV    markers
long point CSV         points (un-indexed)
``rope_curve.csv``     curve (``frame,s,x,y,z`` from ``skincap track``)
``.bvh``               skeleton (joint world positions by forward kinematics)
``.obj .ply``          mesh; animated when a same-stem ``.pc2`` lies beside it; a
                       MakeHuman OBJ (``.mhskel`` beside it) is read in decimetres
``.pc2``               mesh (with its same-stem ``.obj``)
``.glb .gltf``         mesh, skinned and animated by its first animation, plus the
                       skin's skeleton
``.usd .usda .usdc``   every mesh of the stage with its time-sampled points (needs
                       usd-core, the ``usd`` extra)
directory              every file above in it (not recursive); a ``.obj`` that has
                       a same-stem ``.pc2`` is loaded once, animated; a folder of
                       ``<stem>_<digits>.obj`` frames (``skincap skin -o DIR``) is
                       one animated mesh
=====================  ==========================================================

All positions are metres, Y up.
"""

from __future__ import annotations

import abc
import os
import re
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import numpy as np

from skincap.errors import FormatError, SkincapWarning, ValidationError
from skincap.types import MarkerSet, Mesh, Motion, PointCloud

__all__ = [
    "Layer",
    "MarkerLayer",
    "PointLayer",
    "SkeletonLayer",
    "MeshLayer",
    "CurveLayer",
    "Scene",
    "load_scene",
    "scene_from_objects",
    "SCENE_EXTENSIONS",
]

SCENE_EXTENSIONS = (
    ".c3d", ".trc", ".csv", ".bvh", ".obj", ".ply", ".pc2", ".glb", ".gltf", ".usd", ".usda",
    ".usdc",
)  # fmt: skip
#: Rate given to a PC2 cache when nothing else in the scene says one (PC2 stores none).
DEFAULT_PC2_RATE = 30.0

LayerKind = Literal["markers", "points", "skeleton", "mesh", "curve"]


def _finite(points: np.ndarray) -> np.ndarray:
    """Rows of a (P, 3) array that are finite."""
    return points[np.isfinite(points).all(axis=1)]


@dataclass
class Layer(abc.ABC):
    """One drawable thing of a scene.

    Attributes
    ----------
    name : str
        Unique within the scene: the file name, with ``:kind`` when a file gives
        more than one layer.
    rate : float, Hz
    source : Path or None
        The file it came from.
    """

    name: str
    rate: float
    source: Path | None

    kind: ClassVar[LayerKind]

    @property
    @abc.abstractmethod
    def n_frames(self) -> int:
        """Frames in this layer."""

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last."""
        return (self.n_frames - 1) / self.rate if self.n_frames > 1 else 0.0

    @abc.abstractmethod
    def finite_points(self) -> np.ndarray:
        """(P, 3) every finite position of the layer (a subsample for big layers)."""

    @abc.abstractmethod
    def points_at(self, k: int) -> np.ndarray:
        """(P, 3) the finite positions of frame ``k`` (a subsample for big meshes)."""


@dataclass
class _FramesArrayLayer(Layer):
    """A layer whose frames are the rows of one (T, K, 3) array, NaN where missing."""

    @abc.abstractmethod
    def _frames(self) -> np.ndarray:
        """The (T, K, 3) float64 array, metres."""

    def points_at(self, k: int) -> np.ndarray:
        return _finite(self._frames()[k])

    @property
    def n_frames(self) -> int:
        return int(self._frames().shape[0])

    def finite_points(self) -> np.ndarray:
        pts = self._frames()[:: max(1, self.n_frames // 200)].reshape(-1, 3)
        return pts[np.isfinite(pts).all(axis=1)]


@dataclass
class MarkerLayer(_FramesArrayLayer):
    """Labelled markers. ``positions`` (T, N, 3) float64 metres, NaN where missing;
    ``labels`` N strings; ``invented`` (T, N) bool, True where software made the sample."""

    positions: np.ndarray
    labels: list[str]
    invented: np.ndarray

    kind: ClassVar[LayerKind] = "markers"

    def _frames(self) -> np.ndarray:
        return self.positions


@dataclass
class PointLayer(Layer):
    """Un-indexed points: ``cloud`` (a :class:`PointCloud`), frame t is ``cloud.frame(t)``."""

    cloud: PointCloud

    kind: ClassVar[LayerKind] = "points"

    def points_at(self, k: int) -> np.ndarray:
        return _finite(self.cloud.frame(k))

    @property
    def n_frames(self) -> int:
        return self.cloud.n_frames

    def finite_points(self) -> np.ndarray:
        pts = self.cloud.points[:: max(1, self.cloud.points.shape[0] // 20000)]
        return pts[np.isfinite(pts).all(axis=1)]


@dataclass
class SkeletonLayer(Layer):
    """A skeleton: ``joints`` (T, J, 3) world positions, metres; ``parents`` (J,) int, -1
    for a root; ``names`` J strings."""

    joints: np.ndarray
    parents: np.ndarray
    names: list[str]

    kind: ClassVar[LayerKind] = "skeleton"

    def points_at(self, k: int) -> np.ndarray:
        return _finite(self.joints[k])

    @property
    def n_frames(self) -> int:
        return int(self.joints.shape[0])

    def finite_points(self) -> np.ndarray:
        pts = self.joints[:: max(1, self.n_frames // 200)].reshape(-1, 3)
        return pts[np.isfinite(pts).all(axis=1)]


@dataclass
class MeshLayer(Layer):
    """A mesh: ``faces`` (F, 3) int; ``frames`` (T, V, 3) float32 metres (T = 1 when static)."""

    faces: np.ndarray
    frames: np.ndarray

    kind: ClassVar[LayerKind] = "mesh"

    def points_at(self, k: int) -> np.ndarray:
        v = self.frames[k]
        return _finite(v[:: max(1, v.shape[0] // 2000)].astype(np.float64))

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    def finite_points(self) -> np.ndarray:
        pts = self.frames[:: max(1, self.n_frames // 50), :: max(1, self.frames.shape[1] // 2000)]
        pts = pts.reshape(-1, 3).astype(np.float64)
        return pts[np.isfinite(pts).all(axis=1)]


@dataclass
class CurveLayer(_FramesArrayLayer):
    """A polyline per frame: ``curves`` (T, K, 3) float64 metres (NaN rows are gaps)."""

    curves: np.ndarray

    kind: ClassVar[LayerKind] = "curve"

    def _frames(self) -> np.ndarray:
        return self.curves


@dataclass
class Scene:
    """Layers on one clock.

    Attributes
    ----------
    layers : list of Layer
    """

    layers: list[Layer]

    @property
    def rate(self) -> float:
        """The highest layer rate, Hz (30 for an empty scene)."""
        return max((lay.rate for lay in self.layers), default=30.0)

    @property
    def duration(self) -> float:
        """Seconds of the longest layer."""
        return max((lay.duration for lay in self.layers), default=0.0)

    @property
    def n_frames(self) -> int:
        """Frames of the scene clock at :attr:`rate`."""
        return int(round(self.duration * self.rate)) + 1

    def time_of(self, frame: int) -> float:
        """Seconds of scene frame ``frame``."""
        return frame / self.rate

    def layer_frame(self, layer: Layer, t_seconds: float) -> int:
        """The layer's frame nearest to ``t_seconds``, clipped to its range."""
        return int(np.clip(round(t_seconds * layer.rate), 0, layer.n_frames - 1))

    def bounds(self) -> np.ndarray:
        """(2, 3) lowest and highest finite position over every layer, metres.

        A unit cube around the origin when the scene holds no finite point.
        """
        pts = [lay.finite_points() for lay in self.layers]
        pts = [p for p in pts if p.size]
        if not pts:
            return np.array([[-0.5, 0.0, -0.5], [0.5, 1.0, 0.5]])
        allp = np.concatenate(pts)
        return np.stack([allp.min(axis=0), allp.max(axis=0)])

    def bounds_at(self, t_seconds: float) -> np.ndarray | None:
        """(2, 3) lowest and highest finite position at ``t_seconds``; None if nothing shows."""
        pts = [lay.points_at(self.layer_frame(lay, t_seconds)) for lay in self.layers]
        pts = [p for p in pts if p.size]
        if not pts:
            return None
        allp = np.concatenate(pts)
        return np.stack([allp.min(axis=0), allp.max(axis=0)])


# --------------------------------------------------------------------------- loading
def load_scene(
    paths: Sequence[str | os.PathLike[str]],
    *,
    units: str | None = None,
    rate: float | None = None,
) -> Scene:
    """Read files (or folders of files) into a :class:`Scene`.

    Parameters
    ----------
    paths : sequence of path-like
        Files of any kind in the module table, or directories.
    units : str, optional
        Length unit passed to readers that take one (BVH, OBJ/PLY, CSV without a
        unit). Default: each reader's own default or guess.
    rate : float, optional, Hz
        Rate for PC2 caches (PC2 stores none). Default: the rate ``skin``/``animate``
        recorded in the cache's OBJ, else the rate of the first animated skeleton or
        mesh of the scene, else 30 Hz with a warning.

    Returns
    -------
    Scene

    Raises
    ------
    FormatError
        A path that does not exist, a file skincap cannot read or with no frames,
        or a folder with nothing to show.
    """
    if not paths:
        raise ValidationError("load_scene: no paths given")
    files: list[Path] = []
    sequences: list[Path] = []
    from_folder: set[Path] = set()  # unreadable files found in a folder are skipped
    for raw in paths:
        p = Path(raw)
        if p.is_dir() and _obj_sequence(p):
            sequences.append(p)
        elif p.is_dir():
            found = _scene_files_in(p)
            if not found:
                raise FormatError(
                    p, f"folder holds no file skincap shows ({', '.join(SCENE_EXTENSIONS)})"
                )
            files.extend(found)
            from_folder.update(found)
        elif p.exists():
            files.append(p)
        else:
            raise FormatError(p, "no such file or folder")
    layers: list[Layer] = []
    pc2_pending: list[tuple[Path, Path]] = []
    for f in files:
        ext = f.suffix.lower()
        if ext == ".pc2":
            pc2_pending.append((f, _pc2_rest_obj(f)))
        elif (
            ext == ".obj" and f.with_suffix(".pc2").is_file() and f.with_suffix(".pc2") not in files
        ):
            pc2_pending.append((f.with_suffix(".pc2"), f))
        elif f in from_folder:
            try:
                layers.extend(_load_file(f, units))
            except FormatError as exc:
                warnings.warn(f"skipped: {exc}", SkincapWarning, stacklevel=2)
        else:
            layers.extend(_load_file(f, units))
    # a point cache deforms a motion: borrow the rate of a skeleton or mesh layer first
    motions = [lay.rate for lay in layers if lay.kind in ("skeleton", "mesh") and lay.n_frames > 1]
    pc2_rate = rate if rate is not None else (motions[0] if motions else None)
    for folder in sequences:
        layers.append(_load_obj_sequence(folder, rate, units, pc2_rate))
    from skincap.io.pc2 import recorded_pc2_rate

    # a cache skincap wrote has its rate noted in the OBJ beside it; --rate overrides
    cache_rates = [rate if rate is not None else recorded_pc2_rate(obj) for _, obj in pc2_pending]
    unknown = [cache for (cache, _), r in zip(pc2_pending, cache_rates, strict=True) if r is None]
    if pc2_rate is None and unknown:
        warnings.warn(
            f"{unknown[0]}: PC2 stores no frame rate and its OBJ records none; playing it at "
            f"{DEFAULT_PC2_RATE:g} Hz (pass rate= / --rate to choose)",
            SkincapWarning,
            stacklevel=2,
        )
        pc2_rate = DEFAULT_PC2_RATE
    for (cache, obj), own in zip(pc2_pending, cache_rates, strict=True):
        layers.append(_load_pc2(cache, obj, float(own if own is not None else pc2_rate), units))
    if not layers:
        raise FormatError(Path(paths[0]), "nothing in it that skincap can show")
    for lay in layers:  # a frame-less take (Frames: 0, an empty cache) has no pose to draw
        if lay.n_frames == 0:
            raise FormatError(lay.source or Path(paths[0]), "has no frames to show")
    _make_names_unique(layers)
    return Scene(layers)


def scene_from_objects(objects: Sequence[tuple[str, object]]) -> Scene:
    """Build a scene from in-memory skincap objects, each with a display name.

    Parameters
    ----------
    objects : sequence of (name, object)
        ``MarkerSet``, ``PointCloud``, ``Motion``, ``Mesh`` or ``MeshAnimation``
        (with ``frames`` as an array).
    """
    from skincap.types import MeshAnimation

    layers: list[Layer] = []
    for name, obj in objects:
        if isinstance(obj, MarkerSet):
            layers.append(_marker_layer(name, obj, None))
        elif isinstance(obj, PointCloud):
            layers.append(PointLayer(name, obj.rate, None, cloud=obj))
        elif isinstance(obj, Motion):
            layers.append(_skeleton_layer(name, obj, None))
        elif isinstance(obj, Mesh):
            layers.append(_static_mesh_layer(name, obj, None))
        elif isinstance(obj, MeshAnimation):
            frames = _float32_frames(np.asarray(obj.frames), None, name)
            layers.append(MeshLayer(name, obj.rate, None, faces=obj.rest.faces, frames=frames))
        else:
            raise ValidationError(f"scene_from_objects: cannot show a {type(obj).__name__}")
    _make_names_unique(layers)
    return Scene(layers)


def _scene_files_in(folder: Path) -> list[Path]:
    files = sorted(
        f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in SCENE_EXTENSIONS
    )
    # MakeHuman rig files and the rest OBJ of a cache are shown through their partner
    return [
        f for f in files if not (f.suffix.lower() == ".obj" and f.with_suffix(".pc2").is_file())
    ]


def _load_file(path: Path, units: str | None) -> list[Layer]:
    from skincap import io

    ext = path.suffix.lower()
    name = path.name
    if ext in (".c3d", ".trc"):
        options = {"units": units} if units and ext == ".trc" else {}
        return [_marker_layer(name, io.read(path, **options), path)]
    if ext == ".csv":
        from skincap.io.rope_curve import is_rope_curve_csv

        if is_rope_curve_csv(path):
            return [_read_rope_curve(path)]
        obj = io.read(path)  # every CSV says its unit (points CSV: metres); no units=
        if isinstance(obj, PointCloud):
            return [PointLayer(name, obj.rate, path, cloud=obj)]
        return [_marker_layer(name, obj, path)]
    if ext == ".bvh":
        options = {"units": units} if units else {}
        return [_skeleton_layer(name, io.read(path, **options), path)]
    if ext in (".gltf", ".glb"):
        return _gltf_layers(path)
    if ext in (".obj", ".ply"):
        return [_static_mesh_layer(name, _read_static_mesh(path, units), path)]
    if ext in (".usd", ".usda", ".usdc"):
        return _usd_layers(path)
    raise FormatError(path, f"skincap cannot show {ext or 'files without an extension'!r} files")


def _marker_layer(name: str, markers: MarkerSet, source: Path | None) -> MarkerLayer:
    invented = markers.invented
    if invented is None:
        invented = np.zeros(markers.positions.shape[:2], dtype=bool)
    return MarkerLayer(
        name,
        markers.rate,
        source,
        positions=markers.positions,
        labels=list(markers.labels),
        invented=np.asarray(invented, dtype=bool),
    )


def _skeleton_layer(name: str, motion: Motion, source: Path | None) -> SkeletonLayer:
    from skincap.geometry.kinematics import joint_positions

    return SkeletonLayer(
        name,
        motion.rate,
        source,
        joints=joint_positions(motion),
        parents=np.asarray(motion.skeleton.parents),
        names=list(motion.skeleton.names),
    )


def _float32_frames(frames: np.ndarray, source: Path | None, name: str) -> np.ndarray:
    """Vertex positions (T, V, 3) metres as the float32 a layer stores.

    Raises FormatError naming ``source`` (ValidationError naming ``name`` without one)
    when a finite coordinate lies beyond float32's range: an OBJ vertex at 1e308 m
    became inf in the scene, with a stray NumPy overflow warning and a blank picture.
    """
    arr = np.asarray(frames)
    if arr.dtype == np.float32:
        return arr
    limit = float(np.finfo(np.float32).max)
    beyond = np.abs(arr) > limit  # NaN (a missing sample) compares False
    if beyond.any():
        what = (
            f"a vertex coordinate of {float(arr[beyond][0]):g} m is beyond float32's "
            f"+-{limit:.3g}, which the viewer and renderer draw in"
        )
        if source is not None:
            raise FormatError(source, what)
        raise ValidationError(f"{name}: {what}")
    return arr.astype(np.float32)


def _static_mesh_layer(name: str, mesh: Mesh, source: Path | None) -> MeshLayer:
    return MeshLayer(
        name,
        30.0,
        source,
        faces=mesh.faces,
        frames=_float32_frames(mesh.vertices[None], source, name),
    )


def _read_static_mesh(path: Path, units: str | None) -> Mesh:
    from skincap.io import read_mesh

    return read_mesh(path, units=units)


def _gltf_layers(path: Path) -> list[Layer]:
    """The mesh of a glTF, skinned by its first animation, and the skin's joints."""
    from skincap.deform.skeletal.deformers import make_deformer
    from skincap.io.gltf.animation import read_gltf_animation
    from skincap.io.gltf.reader import read_gltf

    mesh = read_gltf(path)
    anim = read_gltf_animation(path) if mesh.skin is not None else None
    if anim is None or mesh.skin is None:
        return [_static_mesh_layer(path.name, mesh, path)]
    nodes = np.asarray(mesh.meta["joint_nodes"], dtype=np.int64)
    joint_world = anim.node_world[:, nodes]  # (T, J, 4, 4)
    skinning = joint_world @ mesh.skin.inverse_bind[None]
    frames = _float32_frames(make_deformer("lbs", mesh).deform(skinning), path, path.name)
    skeleton = mesh.skin.skeleton
    return [
        MeshLayer(f"{path.name}:mesh", anim.rate, path, faces=mesh.faces, frames=frames),
        SkeletonLayer(
            f"{path.name}:skeleton",
            anim.rate,
            path,
            joints=joint_world[..., :3, 3],
            parents=np.asarray(skeleton.parents),
            names=list(skeleton.names),
        ),
    ]


def _pc2_rest_obj(cache: Path) -> Path:
    obj = cache.with_suffix(".obj")
    if not obj.is_file():
        raise FormatError(cache, f"a PC2 cache needs its mesh beside it: {obj.name} not found")
    return obj


def _load_pc2(cache: Path, obj: Path, rate: float, units: str | None) -> MeshLayer:
    from skincap.io.pc2 import read_pc2

    rest = _read_static_mesh(obj, units)
    frames = read_pc2(cache).frames
    if frames.shape[1] != rest.n_vertices:
        raise FormatError(
            cache,
            f"has {frames.shape[1]} points per sample but {obj.name} has {rest.n_vertices} vertices",
        )
    return MeshLayer(cache.name, rate, cache, faces=rest.faces, frames=frames.astype(np.float32))


_OBJ_FRAME = re.compile(r"^(?P<stem>.+)_(?P<index>\d+)\.obj$", re.IGNORECASE)


def _obj_sequence(folder: Path) -> list[Path]:
    """The frames of a folder holding only ``<stem>_<digits>.obj`` files of one stem, in order."""
    objs = sorted(f for f in folder.iterdir() if f.is_file() and f.suffix.lower() == ".obj")
    others = [f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in SCENE_EXTENSIONS]
    matches = [_OBJ_FRAME.match(f.name) for f in objs]
    if len(objs) < 2 or len(others) != len(objs) or not all(matches):
        return []
    if len({m.group("stem") for m in matches if m}) != 1:
        return []
    return sorted(objs, key=lambda f: int(_OBJ_FRAME.match(f.name).group("index")))  # type: ignore[union-attr]


def _load_obj_sequence(
    folder: Path, rate: float | None, units: str | None, borrowed: float | None = None
) -> MeshLayer:
    """An OBJ-sequence folder at ``rate`` (--rate), else the rate skin/animate noted in
    its frames, else ``borrowed`` (a motion's in the scene), else 30 Hz with a warning."""
    frames = _obj_sequence(folder)
    meshes = [_read_static_mesh(f, units) for f in frames]  # one file per frame
    first = meshes[0]
    for f, m in zip(frames, meshes, strict=True):
        if m.n_vertices != first.n_vertices:
            raise FormatError(
                f, f"has {m.n_vertices} vertices, {frames[0].name} has {first.n_vertices}"
            )
    if rate is None:
        from skincap.io.mesh.obj import recorded_rate

        rate = recorded_rate(frames[0], "OBJ sequence")  # skin/animate note theirs
    if rate is None:
        rate = borrowed
    if rate is None:
        warnings.warn(
            f"{folder}: an OBJ sequence stores no frame rate; playing it at {DEFAULT_PC2_RATE:g} Hz",
            SkincapWarning,
            stacklevel=3,
        )
        rate = DEFAULT_PC2_RATE
    stack = _float32_frames(np.stack([m.vertices for m in meshes]), folder, folder.name)
    return MeshLayer(folder.name, float(rate), folder, faces=first.faces, frames=stack)


def _usd_layers(path: Path) -> list[Layer]:
    """Every UsdGeom.Mesh of a stage, its points sampled at each time code (metres, Y up)."""
    from skincap.errors import MissingDependencyError

    try:
        from pxr import Usd, UsdGeom
    except ImportError:
        raise MissingDependencyError("usd-core", "usd", "reading USD") from None
    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise FormatError(path, "USD could not open the stage")
    scale = UsdGeom.GetStageMetersPerUnit(stage) or 1.0
    z_up = UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    rate = float(stage.GetTimeCodesPerSecond() or 24.0)
    layers: list[Layer] = []
    for prim in stage.Traverse():
        if not prim.IsA(UsdGeom.Mesh):
            continue
        mesh = UsdGeom.Mesh(prim)
        counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get(), dtype=np.int64)
        indices = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64)
        points_attr = mesh.GetPointsAttr()
        times = points_attr.GetTimeSamples() or [Usd.TimeCode.Default()]
        frames = np.stack([np.asarray(points_attr.Get(t), dtype=np.float64) for t in times]) * scale
        if z_up:  # (x, y, z) Z up -> (x, z, -y) Y up
            frames = np.stack([frames[..., 0], frames[..., 2], -frames[..., 1]], axis=-1)
        faces = _fan_triangles(counts, indices, path)
        layers.append(
            MeshLayer(
                f"{path.name}:{prim.GetName()}", rate, path, faces=faces,
                frames=_float32_frames(frames, path, path.name),
            )
        )  # fmt: skip
    if not layers:
        raise FormatError(path, "the stage holds no mesh")
    return layers


def _fan_triangles(counts: np.ndarray, indices: np.ndarray, path: Path) -> np.ndarray:
    """(F, 3) triangles fanning out each polygon of ``counts`` corners over ``indices``."""
    from skincap.io.mesh import triangulate_polygons

    if counts.sum() != indices.size or (counts < 3).any():
        raise FormatError(path, "face vertex counts and indices disagree")
    faces, _ = triangulate_polygons(indices, np.concatenate([[0], np.cumsum(counts)]))
    return faces


def _read_rope_curve(path: Path) -> CurveLayer:
    from skincap.io.rope_curve import read_rope_curve

    curves, rate = read_rope_curve(path)
    return CurveLayer(path.name, rate, path, curves=curves)


def _make_names_unique(layers: list[Layer]) -> None:
    seen: dict[str, int] = {}
    for lay in layers:
        base = lay.name
        if base in seen:
            seen[base] += 1
            lay.name = f"{base} ({seen[base]})"
        else:
            seen[base] = 1
