"""The inputs of a synthetic capture: the body to skin and the motion to play on it.

``build_body`` makes or loads the skinned body; ``build_motion`` makes a built-in clip or
reads a BVH, retargeted onto that body's rig.
"""

from __future__ import annotations

from pathlib import Path

from skincap.errors import FormatError, ValidationError, naming_file
from skincap.types import Mesh, Motion

__all__ = ["build_body", "build_motion"]


def build_body(kind: str, *, n_vertices: int = 20_000, seed: int = 0) -> Mesh:
    """The skinned body: ``procedural`` (swept elliptic sections) or ``makehuman`` (shipped CC0 rig)."""
    if kind == "procedural":
        from skincap.synth.body import procedural_body
        from skincap.synth.skeleton import synth_skeleton

        return procedural_body(synth_skeleton(), n_vertices=n_vertices, seed=seed)
    if kind == "makehuman":
        from skincap.data import path as shipped_file
        from skincap.io.makehuman import read_makehuman

        return read_makehuman(shipped_file("makehuman_base.obj"))
    raise ValidationError(f"body: expected 'procedural' or 'makehuman', got {kind!r}")


def build_motion(
    body: Mesh,
    motion: str,
    *,
    frames: int | None = None,
    seconds: float | None = None,
    rate: float = 120.0,
    units: str | None = None,
    seed: int = 0,
) -> Motion:
    """A motion on ``body``'s skeleton: a built-in clip name or a BVH file path.

    Clips are made on skincap's T-pose skeleton and retargeted when the body has
    another rig; a BVH is retargeted onto the body and cut to ``frames``/``seconds``.
    """
    from skincap.deform.skeletal.retarget import retarget
    from skincap.synth.clips import CLIPS, clip_frame_count, make_clip
    from skincap.synth.skeleton import synth_skeleton

    if body.skin is None:
        raise ValidationError("body: needs a skin")
    if motion in CLIPS:
        clip = make_clip(
            motion, synth_skeleton(), frames=frames, seconds=seconds, rate=rate, seed=seed
        )
        if clip.skeleton.names == body.skin.skeleton.names:
            return Motion(
                body.skin.skeleton,
                clip.rotations,
                clip.translations,
                clip.rate,
                clip.channels,
                clip.meta,
            )
        return retarget(clip, body)
    path = Path(motion)
    if path.suffix.lower() != ".bvh":
        raise ValidationError(
            f"motion: expected one of {', '.join(CLIPS)} or a .bvh file, got {motion!r}"
        )
    from skincap.io.bvh import read_bvh

    source = read_bvh(path, units=units)
    if source.n_frames == 0:
        raise FormatError(path, "no motion frames ('Frames: 0'); a synthetic take needs one")
    n = source.n_frames
    if frames is not None or seconds is not None:
        # the clips' own check: frames a positive integer, seconds positive, not both
        n = min(n, clip_frame_count(frames, seconds, source.rate))
    if n < source.n_frames:
        source = Motion(
            source.skeleton,
            source.rotations[:n],
            source.translations[:n],
            source.rate,
            source.channels,
            source.meta,
        )
    # a skeleton retarget cannot pair (no shared names or landmarks) is the file's fault
    with naming_file(path):
        return retarget(source, body)
