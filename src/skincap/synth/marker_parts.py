"""The true near-rigid part of every body marker, from the body's skeleton and skin weights.

A synthetic marker rides on the skin, and the skin follows the skeleton's bones by its
skin weights; so the part a marker truly belongs to is the bone group that moves it
most. Each joint of the body's skeleton is first given an anatomical landmark (the
built-in name conventions of :mod:`skincap.deform.skeletal.name_maps`: CMU, Biovision,
MakeHuman): a landmark joint is its own, any other joint takes the landmark of its
nearest landmark ancestor (a toe end, a finger, a twist or helper bone follows the
segment it hangs from). The landmarks are then grouped into the 17 parts of Park &
Hodgins' Fig. 5(b), :data:`PART_OF_LANDMARK`:

* trunk and head: ``head`` (both neck joints and the head: the neck carries a handful
  of markers and no rigid part of its own), ``upper_chest`` (with both clavicles: the
  shoulder girdle carries 3-4 markers a side and moves with the upper chest),
  ``chest``, ``abdomen`` (the lower back joint), ``pelvis``;
* per side: ``upperarm``, ``forearm``, ``hand`` (fingers included), ``thigh``,
  ``shin``, ``foot`` (toes included).

A marker's skin weights are interpolated at its barycentric position on its triangle,
summed per part, and the part with the largest sum is the marker's true part.
``skincap synth`` writes the result to ``truth/marker_parts.csv`` (``marker,part``).
"""

from __future__ import annotations

import numpy as np

from skincap.deform.skeletal.name_maps import CONVENTIONS, detect_convention
from skincap.errors import ValidationError
from skincap.types import Mesh

__all__ = ["PART_NAMES", "PART_OF_LANDMARK", "true_marker_parts"]

#: Landmark of :data:`skincap.deform.skeletal.name_maps.LANDMARKS` -> anatomical part.
PART_OF_LANDMARK: dict[str, str] = {
    "hips": "pelvis",
    "spine": "abdomen",
    "chest": "chest",
    "upper_chest": "upper_chest",
    "neck": "head",
    "neck_upper": "head",
    "head": "head",
    "clavicle_l": "upper_chest",
    "clavicle_r": "upper_chest",
    **{
        f"{landmark}_{side}": f"{part}_{side}"
        for side in ("l", "r")
        for landmark, part in (
            ("upperarm", "upperarm"),
            ("forearm", "forearm"),
            ("hand", "hand"),
            ("thigh", "thigh"),
            ("shin", "shin"),
            ("foot", "foot"),
            ("toe", "foot"),
        )
    },
}

#: The 17 parts, trunk first, then left and right limbs.
PART_NAMES: tuple[str, ...] = tuple(dict.fromkeys(PART_OF_LANDMARK.values()))


def _joint_parts(names: list[str], parents: np.ndarray) -> np.ndarray:
    """Index into :data:`PART_NAMES` of every joint (-1 above every landmark)."""
    convention = detect_convention(names)
    if convention is None:
        raise ValidationError(
            "body: its skeleton follows no known joint-name convention "
            "(CMU, Biovision, MakeHuman); the true marker parts need one"
        )
    index = {name: j for j, name in enumerate(names)}
    part_index = {name: k for k, name in enumerate(PART_NAMES)}
    own = np.full(len(names), -1, dtype=np.int64)
    for landmark, joints in CONVENTIONS[convention].items():
        for joint in (joints,) if isinstance(joints, str) else joints:
            if joint in index:
                own[index[joint]] = part_index[PART_OF_LANDMARK[landmark]]
    part = own.copy()
    for j, parent in enumerate(np.asarray(parents)):  # parents come before children
        if part[j] < 0 and parent >= 0:
            part[j] = part[parent]
    return part


def true_marker_parts(body: Mesh, face: np.ndarray, bary: np.ndarray) -> list[str]:
    """The true part (a name of :data:`PART_NAMES`) of markers on the skin of ``body``.

    Parameters
    ----------
    body : Mesh
        A skinned body (``body.skin``) whose skeleton follows a built-in joint-name
        convention.
    face : (N,) int
        Triangle of ``body`` each marker sits on.
    bary : (N, 3) float
        Barycentric coordinates of each marker in its triangle.

    Returns
    -------
    list of N str
        The part whose bones carry the largest share of each marker's skin weight.

    Raises
    ------
    ValidationError
        No skin, an unknown skeleton, or shapes that do not match.
    """
    if body.skin is None:
        raise ValidationError("body: needs a skin to define the true marker parts")
    f = np.asarray(face, dtype=np.int64)
    b = np.asarray(bary, dtype=np.float64)
    if f.ndim != 1 or b.shape != (f.size, 3):
        raise ValidationError(f"face (N,) and bary (N, 3) expected; got {f.shape} and {b.shape}")
    if f.size and (f.min() < 0 or f.max() >= body.faces.shape[0]):
        raise ValidationError(f"face: must index the {body.faces.shape[0]} triangles of body")
    skin = body.skin
    joint_part = _joint_parts(list(skin.skeleton.names), skin.skeleton.parents)
    # per-vertex weight of each part: (V, 17); joints above every landmark count for none
    n_v, k = skin.joint_weights.shape
    part_of_influence = joint_part[skin.joint_indices]  # (V, K)
    counted = part_of_influence >= 0
    vertex_part = np.zeros((n_v, len(PART_NAMES)))
    np.add.at(
        vertex_part,
        (np.repeat(np.arange(n_v), k)[counted.ravel()], part_of_influence[counted]),
        skin.joint_weights[counted],
    )
    corner = body.faces[f]  # (N, 3) vertices of each marker's triangle
    marker_part = np.einsum("nc,ncp->np", b, vertex_part[corner])  # (N, 17)
    return [PART_NAMES[p] for p in np.argmax(marker_part, axis=1)]
