"""Deformers: every one takes a rest mesh and per-frame inputs and yields a MeshAnimation."""
