"""Exports other tools open: skinned glTF, point caches (PC2, OBJ sequence), USD."""
