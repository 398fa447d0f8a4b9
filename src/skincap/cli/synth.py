"""``skincap synth``: a synthetic capture with exact ground truth, written to a folder."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from skincap.cli._app import _user_errors, app, check_seed, out, stage_progress
from skincap.cli._options import ForceOption, OutputFolderOption

# one alias per option, so the verb's signature reads as a list
_Body = Annotated[
    str,
    typer.Option(help="procedural (swept elliptic sections) or makehuman (shipped CC0 rig)."),
]
_Motion = Annotated[
    str,
    typer.Option(
        help="A clip (tpose, flex, twist, squat, punch, jumprope, breathe, rom) or a .bvh file."
    ),
]
_Markers = Annotated[
    str, typer.Option(help="dense (~350, Park & Hodgins) or sparse (~41 landmarks).")
]
_Rope = Annotated[
    str, typer.Option(help="none, jump (both ends in the hands) or whip (one end held).")
]
_Frames = Annotated[
    int | None,
    typer.Option(help="Length in frames (default: the clip's 4 s, or the whole BVH)."),
]
_Seconds = Annotated[float | None, typer.Option(help="Length in seconds (instead of --frames).")]
_Rate = Annotated[float, typer.Option(help="Capture rate of built-in clips, Hz.")]
_Vertices = Annotated[
    int, typer.Option(help="Procedural body resolution (about 5k to 80k vertices).")
]
_NoiseMm = Annotated[float, typer.Option(help="Gaussian noise of reconstructed markers, mm.")]
_SoftTissue = Annotated[
    float, typer.Option(help="Scale of bulge, jiggle and breathing (0 switches them off).")
]
_Units = Annotated[
    str | None, typer.Option(help="Length unit of a BVH motion (guessed when omitted).")
]
_Spikes = Annotated[
    int,
    typer.Option(help="Spikes put into capture.c3d: a marker jumps 4-6 cm for 1-3 frames."),
]
_Swaps = Annotated[
    int,
    typer.Option(
        help="Label swaps put into capture.c3d: two labelled markers within 12 cm "
        "exchange labels for 5-40 frames."
    ),
]
_Prop = Annotated[
    bool,
    typer.Option("--prop", help="Add a 4-marker rigid prop moving on its own beside the body."),
]
_Seed = Annotated[int, typer.Option(help="Random seed: the same seed gives the same bytes.")]
_RealMarkers = Annotated[
    Path | None,
    typer.Option(
        help="A labelled capture (C3D, TRC, CSV) as the body instead of a synthetic one: "
        "its real markers, with a PBD-simulated rope (--rope whip|jump) in the hands."
    ),
]
_Hands = Annotated[
    str | None,
    typer.Option(
        help="With --real-markers: marker names of the left[:right] hand, e.g. "
        "LWRA,LWRB:RWRA,RWRB (found by name when omitted); a whip is held in the last."
    ),
]


@app.command()
def synth(
    output: OutputFolderOption,
    body: _Body = "procedural",
    motion: _Motion = "jumprope",
    markers: _Markers = "dense",
    rope: _Rope = "none",
    frames: _Frames = None,
    seconds: _Seconds = None,
    rate: _Rate = 120.0,
    vertices: _Vertices = 20_000,
    noise_mm: _NoiseMm = 0.5,
    soft_tissue: _SoftTissue = 1.0,
    units: _Units = None,
    spikes: _Spikes = 0,
    swaps: _Swaps = 0,
    prop: _Prop = False,
    seed: _Seed = 0,
    real_markers: _RealMarkers = None,
    hands: _Hands = None,
    force: ForceOption = False,
) -> None:
    """Generate a synthetic optical capture with exact ground truth.

    Writes capture.c3d (first-frame labels plus *N fragments), capture_points.csv
    (un-indexed), summary.json and truth/ (clean markers, fragment and point truth,
    marker surface, motion, animated skin, the rigged body, and corruption.json: where
    --spikes, --swaps and --prop put real-world corruption into capture.c3d; the
    un-indexed capture_points.csv is left as the cameras saw it).

    With --real-markers the body is a real labelled capture (its markers un-indexed in
    capture_points.csv, with the take's own gaps, the first pose held 0.5 s) and the
    rope, held by the hand markers, is simulated by position-based dynamics; there is
    no skin or motion truth.

    Example: skincap synth --motion jumprope --rope jump --frames 1000 -o take1

    Example: skincap synth --real-markers walk.c3d --rope whip --seconds 4 -o real_whip
    """
    from skincap.workflows.synth_folder import real_rope_folder, synth_folder

    if real_markers is not None:
        with _user_errors(), stage_progress("reading") as progress:
            result = real_rope_folder(
                output,
                real_markers,
                rope=rope,
                hands=hands,
                frames=frames,
                seconds=seconds,
                noise_mm=noise_mm,
                seed=check_seed(seed),
                force=force,
                progress=progress,
            )
        s = result.summary
        out.print(
            f"synth: {s['frames']} frames of {real_markers}, {s['markers']} real markers + "
            f"{s['rope_markers']} rope markers ({s['rope']}, held by "
            f"{' and '.join('+'.join(h) for h in s['hands'])}) -> {s['fragments']} "
            f"fragments, {s['ghosts']} ghosts; wrote {output}",
            markup=False,
            soft_wrap=True,
        )
        return

    with _user_errors(), stage_progress("body") as progress:
        result = synth_folder(
            output,
            body=body,
            motion=motion,
            markers=markers,
            rope=rope,
            frames=frames,
            seconds=seconds,
            rate=rate,
            vertices=vertices,
            noise_mm=noise_mm,
            soft_tissue=soft_tissue,
            units=units,
            spikes=spikes,
            swaps=swaps,
            prop=prop,
            seed=check_seed(seed),
            force=force,
            progress=progress,
        )
    s = result.summary
    out.print(
        f"synth: {s['frames']} frames, {s['markers']} markers + {s['rope_markers']} rope markers -> "
        f"{s['fragments']} fragments, {100 * s['missing_fraction']:.1f}% missing, {s['ghosts']} ghosts; wrote {output}",
        markup=False,
        soft_wrap=True,
    )
