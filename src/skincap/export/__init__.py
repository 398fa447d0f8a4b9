"""Exports other tools open: skinned glTF, point caches (PC2, OBJ sequence), USD.

Each module is imported on first use (USD needs the optional ``usd`` extra).
"""

from __future__ import annotations

from typing import Any

__all__ = ["write_glb", "write_pc2", "read_pc2", "write_obj_sequence", "write_usd"]

_WHERE = {
    "write_glb": "skincap.export.gltf",
    "write_pc2": "skincap.export.pc2",
    "read_pc2": "skincap.export.pc2",
    "write_obj_sequence": "skincap.export.obj_sequence",
    "write_usd": "skincap.export.usd",
}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        import importlib

        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'skincap.export' has no attribute {name!r}")
