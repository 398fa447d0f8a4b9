"""A subject's dense rig, built once and reused for every take (Park & Hodgins 2006, §5).

The paper registered the body, segmented the marker surface and computed the weights
once per subject; every later take of that subject only runs the per-frame fits
(eqs. 6-9). :class:`DenseRig` is that once-per-subject data: the registered mesh, the
marker labels and their reference pose, the marker-surface triangles, the part of
every marker, the marker weights α and the vertex weights β. It holds nothing that
depends on the deformation variant, so one rig serves ``rigid`` … ``quadratic_rbf``.

:func:`build_dense_rig` makes one from a range-of-motion take; :meth:`DenseRig.deformer`
binds it; :meth:`DenseRig.columns_of` finds its markers in another take by label.
Saving and loading (NPZ + JSON sidecar) is :mod:`skincap.io.dense_rig`, which sees
only the plain arrays of :meth:`DenseRig.to_arrays`.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np

from skincap.deform.dense.deformer import DenseDeformer, choose_quadratic_parts
from skincap.deform.dense.parts import part_frames
from skincap.deform.dense.segmentation import segment_marker_surface
from skincap.deform.dense.weights import (
    candidates_from_triangle_parts,
    marker_blend_weights,
    marker_part_weights,
    seam_vertex_weights,
    spread_candidates,
    vertex_part_weights,
)
from skincap.errors import SkincapWarning, ValidationError

__all__ = ["DenseRig", "build_dense_rig", "marker_weights_of", "RIG_ARRAYS"]

#: The arrays of a rig, as :meth:`DenseRig.to_arrays` names them.
RIG_ARRAYS = (
    "vertices",
    "faces",
    "reference",
    "surface_faces",
    "marker_parts",
    "marker_weights",
    "vertex_weights",
)


@dataclass(eq=False)
class DenseRig:
    """The once-per-subject part of the dense chain.

    Attributes
    ----------
    vertices : (V, 3) float64, metres
        The (registered) body mesh in the markers' reference pose.
    faces : (F, 3) int64
        Its triangles.
    labels : tuple of N str
        Marker labels, in the column order of every array below.
    reference : (N, 3) float64, metres
        Marker positions in the reference pose (finite).
    surface_faces : (S, 3) int64
        Marker-surface triangles (marker columns).
    marker_parts : (N,) int64
        The part of every marker (-1 for a marker on no surface triangle).
    marker_weights : (N, P) float64
        α; rows sum to 1.
    vertex_weights : (V, P) float64
        β; rows sum to 1.
    settings : dict
        How the rig was built (JSON-serialisable: parts asked for, bandwidth,
        reference frame, source files, registration distances…).
    """

    vertices: np.ndarray
    faces: np.ndarray
    labels: tuple[str, ...]
    reference: np.ndarray
    surface_faces: np.ndarray
    marker_parts: np.ndarray
    marker_weights: np.ndarray
    vertex_weights: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.vertices = np.asarray(self.vertices, dtype=np.float64)
        self.faces = np.asarray(self.faces, dtype=np.int64).reshape(-1, 3)
        self.labels = tuple(str(s) for s in self.labels)
        self.reference = np.asarray(self.reference, dtype=np.float64)
        self.surface_faces = np.asarray(self.surface_faces, dtype=np.int64).reshape(-1, 3)
        self.marker_parts = np.asarray(self.marker_parts, dtype=np.int64)
        self.marker_weights = np.asarray(self.marker_weights, dtype=np.float64)
        self.vertex_weights = np.asarray(self.vertex_weights, dtype=np.float64)
        n, v = len(self.labels), self.vertices.shape[0]
        p = self.marker_weights.shape[1] if self.marker_weights.ndim == 2 else -1
        expected = {
            "vertices": ((v, 3), self.vertices.shape),
            "reference": ((n, 3), self.reference.shape),
            "marker_parts": ((n,), self.marker_parts.shape),
            "marker_weights": ((n, p), self.marker_weights.shape),
            "vertex_weights": ((v, p), self.vertex_weights.shape),
        }
        for name, (want, got) in expected.items():
            if want != got or p < 1:
                raise ValidationError(f"{name} must have shape {want} for {n} labels; got {got}")
        if len(set(self.labels)) != n:
            raise ValidationError("labels must be unique")
        if not (np.isfinite(self.vertices).all() and np.isfinite(self.reference).all()):
            raise ValidationError("vertices and reference must be finite")
        for name, faces, count in (
            ("faces", self.faces, v),
            ("surface_faces", self.surface_faces, n),
        ):
            if faces.size and (faces.min() < 0 or faces.max() >= count):
                raise ValidationError(f"{name}: indices must be in 0..{count - 1}")
        if self.faces.shape[0] == 0:
            raise ValidationError("faces: the mesh has no triangles")

    @property
    def n_parts(self) -> int:
        return int(self.marker_weights.shape[1])

    @property
    def n_markers(self) -> int:
        return len(self.labels)

    def deformer(self) -> DenseDeformer:
        """The deformer of this rig (any of the four variants)."""
        parts = part_frames(self.reference, self.marker_weights, surface_faces=self.surface_faces)
        seam = seam_vertex_weights(
            self.vertices, self.reference, self.surface_faces, self.marker_weights > 0
        )
        return DenseDeformer(
            parts,
            self.vertices,
            self.vertex_weights,
            seam_weights=seam,
            quadratic_parts=self.quadratic_parts,
        )

    @property
    def quadratic_parts(self) -> np.ndarray | None:
        """(P,) bool: the parts ``quadratic_rbf`` gives a quadratic base, as
        :func:`~skincap.deform.dense.deformer.choose_quadratic_parts` chose them on the
        range of motion (``settings["quadratic_parts"]``); None (every part) for a rig
        saved without the choice."""
        chosen = self.settings.get("quadratic_parts")
        if chosen is None:
            return None
        flags = np.asarray(chosen, dtype=bool)
        if flags.shape != (self.n_parts,):
            raise ValidationError(
                f"settings quadratic_parts: expected {self.n_parts} flags; got {flags.shape}"
            )
        return flags

    def columns_of(self, labels: Sequence[str]) -> np.ndarray:
        """Column of each of the rig's markers in a take with these labels.

        Parameters
        ----------
        labels : sequence of str
            The take's column labels.

        Returns
        -------
        (N,) int64
            ``take.positions[:, columns]`` is in the rig's marker order.

        Raises
        ------
        ValidationError
            A rig marker the take does not have (the message names a few).
        """
        where = {str(lab): i for i, lab in enumerate(labels)}
        missing = [lab for lab in self.labels if lab not in where]
        if missing:
            shown = ", ".join(missing[:5]) + (" …" if len(missing) > 5 else "")
            raise ValidationError(
                f"the rig was built for another marker set: {len(missing)} of its "
                f"{self.n_markers} markers are not in the take ({shown})"
            )
        return np.array([where[lab] for lab in self.labels], dtype=np.int64)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """The numeric arrays (:data:`RIG_ARRAYS`), for :mod:`skincap.io.dense_rig`."""
        return {name: getattr(self, name) for name in RIG_ARRAYS}

    @classmethod
    def from_arrays(
        cls, arrays: Mapping[str, np.ndarray], labels: Sequence[str], settings: dict[str, Any]
    ) -> DenseRig:
        """Inverse of :meth:`to_arrays` (shapes are checked)."""
        missing = [name for name in RIG_ARRAYS if name not in arrays]
        if missing:
            raise ValidationError(f"rig arrays missing: {', '.join(missing)}")
        return cls(
            labels=tuple(labels),
            settings=dict(settings),
            **{name: np.asarray(arrays[name]) for name in RIG_ARRAYS},
        )


def build_dense_rig(
    vertices: np.ndarray,
    faces: np.ndarray,
    labels: Sequence[str],
    reference: np.ndarray,
    surface_faces: np.ndarray,
    range_of_motion: np.ndarray,
    *,
    n_parts: int = 17,
    marker_weights: Literal["blend", "gaussian"] = "blend",
    settings: dict[str, Any] | None = None,
    progress: Callable[[float], None] | None = None,
) -> DenseRig:
    """Segment the marker surface, weigh markers and vertices: the subject's rig (§5.2).

    Parameters
    ----------
    vertices : (V, 3) float, metres
        The body mesh, registered to ``reference``.
    faces : (F, 3) int
    labels : sequence of N str
    reference : (N, 3) float, metres
        The markers in the reference pose (finite).
    surface_faces : (S, 3) int
        Marker-surface triangles over the N markers.
    range_of_motion : (T, N, 3) float, metres, NaN where missing
        The take the parts and the boundary weights are learnt from.
    n_parts : int, default 17
        Target part count (:func:`segment_marker_surface`).
    marker_weights : {"blend", "gaussian"}
        ``"blend"`` (default): a marker on or next to a seam takes the least-squares
        convex blend of its candidate parts' rigid motions
        (:func:`~skincap.deform.dense.weights.marker_blend_weights`; candidates: the parts
        of its triangles and its neighbours'); ``"gaussian"``: the paper's likelihoods
        over the parts of its own triangles, thresholded at 0.2
        (:func:`~skincap.deform.dense.weights.marker_part_weights`).
    settings : dict, optional
        Recorded in the rig (with ``n_parts`` and the segmentation's figures added).
    progress : callable(fraction), optional
        The segmentation's progress.

    Returns
    -------
    DenseRig

    Warns
    -----
    SkincapWarning
        Fewer parts than ``n_parts`` came out: the take moves too little to segment, or
        the marker surface is in fewer pieces than that and they move alike; or more:
        the surface is in more separate pieces than ``n_parts``, each a part.
    """
    ref = np.asarray(reference, dtype=np.float64)
    rom = np.asarray(range_of_motion, dtype=np.float64)
    if rom.ndim != 3 or rom.shape[1:] != ref.shape:
        raise ValidationError(
            f"range_of_motion must have shape (T, {ref.shape[0]}, 3); got {rom.shape}"
        )
    seg = segment_marker_surface(rom, ref, surface_faces, n_parts=n_parts, progress=progress)
    if seg.n_parts < int(n_parts):
        warnings.warn(
            f"range of motion: {seg.n_parts} near-rigid parts found of the {int(n_parts)} asked "
            f"(mean shift: {seg.mean_shift_groups} group(s)); either the take moves too little "
            "to tell the parts apart or its marker surface has fewer connected pieces; "
            "a range-of-motion take that moves every joint (--rom) segments the body",
            SkincapWarning,
            stacklevel=2,
        )
    elif seg.n_parts > int(n_parts):
        # a part is connected on the marker surface, so every separate piece of the
        # surface is a part at least (cmu_85_02's 41 markers make 3 pieces: --parts 1
        # gave 3 parts and said nothing)
        warnings.warn(
            f"range of motion: {seg.n_parts} near-rigid parts of the {int(n_parts)} asked: "
            "the marker surface falls in separate pieces and each is a part of its own",
            SkincapWarning,
            stacklevel=2,
        )
    candidates = candidates_from_triangle_parts(
        surface_faces, seg.triangle_parts, ref.shape[0], seg.n_parts
    )
    alpha = marker_weights_of(rom, ref, candidates, surface_faces, marker_weights)
    beta = vertex_part_weights(vertices, ref, surface_faces, alpha)
    parts = part_frames(ref, alpha, surface_faces=surface_faces)
    quadratic_parts = choose_quadratic_parts(rom, parts)
    info = dict(settings or {})
    info.update(
        n_parts_requested=int(n_parts),
        n_parts=int(seg.n_parts),
        mean_shift_groups=int(seg.mean_shift_groups),
        bandwidth=float(seg.bandwidth),
        range_of_motion_frames=int(rom.shape[0]),
        marker_weights=str(marker_weights),
        quadratic_parts=[bool(q) for q in quadratic_parts],
    )
    return DenseRig(
        vertices=vertices,
        faces=faces,
        labels=tuple(labels),
        reference=ref,
        surface_faces=surface_faces,
        marker_parts=seg.marker_parts,
        marker_weights=alpha,
        vertex_weights=beta,
        settings=info,
    )


def marker_weights_of(
    positions: np.ndarray,
    reference: np.ndarray,
    candidates: np.ndarray,
    surface_faces: np.ndarray,
    kind: str = "blend",
) -> np.ndarray:
    """Marker weights α of a segmentation, by either rule of :func:`build_dense_rig`.

    Parameters
    ----------
    positions : (T, N, 3) float, metres, NaN where missing (the range of motion)
    reference : (N, 3) float, metres
    candidates : (N, P) bool
        The parts of each marker's triangles.
    surface_faces : (S, 3) int
    kind : {"blend", "gaussian"}

    Returns
    -------
    (N, P) float64, rows sum to 1
    """
    if kind == "gaussian":
        return marker_part_weights(positions, reference, candidates)
    if kind != "blend":
        raise ValidationError(f"marker_weights: expected 'blend' or 'gaussian'; got {kind!r}")
    cand = np.asarray(candidates, dtype=bool)
    inside = cand & (cand.sum(axis=1) == 1)[:, None]
    # a part's motion from its inside markers; a part with fewer than three, from all its own
    members = np.where((inside.sum(axis=0) >= 3)[None, :], inside, cand)
    return marker_blend_weights(
        positions, reference, members, spread_candidates(cand, surface_faces)
    )
