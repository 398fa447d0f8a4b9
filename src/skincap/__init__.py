"""skincap: optical motion capture to moving human skin.

The core types live in :mod:`skincap.types`; readers and writers in :mod:`skincap.io`.
"""

from __future__ import annotations

from skincap.errors import FormatError, SkincapError, SkincapWarning, ValidationError
from skincap.types import MarkerSet, Mesh, MeshAnimation, Motion, PointCloud, Skeleton, Skin

__version__ = "0.1.0"

__all__ = [
    "FormatError",
    "MarkerSet",
    "Mesh",
    "MeshAnimation",
    "Motion",
    "PointCloud",
    "Skeleton",
    "Skin",
    "SkincapError",
    "SkincapWarning",
    "ValidationError",
    "__version__",
]
