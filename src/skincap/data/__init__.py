"""Files shipped inside the package (the demo's capture, motions and body; their licences).

``path(name)`` is the one way code finds them, so a moved module cannot lose its data.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from skincap.errors import FormatError

__all__ = ["path"]


def path(name: str) -> Path:
    """Path of the shipped data file ``name`` (e.g. ``"makehuman_base.obj"``).

    Raises :class:`FormatError` naming the file when the installation lacks it.
    """
    found = Path(str(resources.files("skincap.data") / name))
    if not found.is_file():
        raise FormatError(found, "shipped data missing from the installation; reinstall skincap")
    return found
