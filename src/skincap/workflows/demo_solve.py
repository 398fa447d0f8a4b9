"""The demo's real-capture chain: a shipped CMU capture -> clean -> solve a skeleton -> skin.

What a user with only a C3D does: ``skincap clean``, ``skincap solve``, ``skincap skin``.
Here the three run in one process on ``cmu_85_02.c3d`` (41 CMU markers, 120 Hz) and the
MakeHuman body, writing ``real/`` beside the demo's other outputs.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from skincap._arrays import Progress
from skincap.data import path as shipped_file

__all__ = ["REAL_CAPTURE", "REAL_OUTPUTS", "clean_solve_skin"]

#: The shipped real capture the chain starts from (CMU marker set, template ``cmu41``).
REAL_CAPTURE = "cmu_85_02.c3d"
#: Files written under ``folder/real``.
REAL_OUTPUTS = ("cleaned.c3d", "solved.bvh", "solve_report.json", "solved_body.glb")


def clean_solve_skin(
    folder: Path, body: Any, *, force: bool, progress: Progress | None = None
) -> tuple[dict[str, Any], list[Path]]:
    """Clean the shipped CMU capture, solve its skeleton, skin ``body`` with it.

    Parameters
    ----------
    folder : Path
        ``folder/real`` receives :data:`REAL_OUTPUTS`.
    body : Mesh
        A skinned body (the MakeHuman body); the solved BVH is retargeted onto its rig
        exactly as ``skincap skin BODY solved.bvh`` would.
    force : bool
        Replace earlier outputs.
    progress : callable(fraction, label), optional

    Returns
    -------
    figures : dict
        ``frames``, ``markers``, ``joints``, ``template``, ``rms_cm`` and ``max_cm``
        (model markers against the cleaned capture), ``clean_filled`` (samples filled),
        ``glb`` (the skinned body's path).
    outputs : list of Path
    """
    import json

    from skincap import io
    from skincap.cleanup.pipeline import clean_markers
    from skincap.cleanup.settings import CleanSettings
    from skincap.deform.skeletal.pipeline import prepare_skinning
    from skincap.io._common import atomic_output
    from skincap.io.gltf.writer import write_glb
    from skincap.solve.pipeline import solve_markers

    def report(fraction: float, label: str) -> None:
        if progress is not None:
            progress(fraction, label)

    real = folder / "real"
    real.mkdir(exist_ok=True)
    markers = io.read(shipped_file(REAL_CAPTURE))
    report(0.0, "cleaning the real capture")
    cleaned, clean_report = clean_markers(markers, CleanSettings())
    io.write(cleaned, real / "cleaned.c3d", force=force)
    report(0.3, "solving its skeleton")
    solved = solve_markers(cleaned, "cmu41", progress=lambda f, label: report(0.3 + 0.4 * f, label))
    io.write(solved.motion, real / "solved.bvh", units="cm", force=force)
    residuals = solved.report()
    with atomic_output(real / "solve_report.json", force=force) as tmp:
        tmp.write_text(json.dumps(residuals, indent=2) + "\n", encoding="utf-8")
    report(0.7, "skinning the body with the solved skeleton")
    setup = prepare_skinning(body, solved.motion)
    write_glb(setup.mesh, setup.motion, real / "solved_body.glb", force=force)
    overall = residuals["overall"]
    figures = {
        "capture": REAL_CAPTURE,
        "frames": int(cleaned.n_frames),
        "markers": int(cleaned.n_markers),
        "template": residuals["template"],
        "joints": int(residuals["joints"]),
        "markers_used": int(residuals["markers_used"]),
        "rms_cm": 100.0 * overall["rms_m"],
        "max_cm": 100.0 * overall["max_m"],
        "clean_filled": int(clean_report.guard.filled_samples),
        "glb": str(real / "solved_body.glb"),
    }
    return figures, [real / name for name in REAL_OUTPUTS]
