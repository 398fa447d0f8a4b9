"""``write_c3d``: a :class:`~skincap.types.MarkerSet` to C3D, the source's content kept
(see :mod:`skincap.io.c3d`).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Literal

import numpy as np

from skincap.errors import (
    FormatError,
    SkincapWarning,
    ValidationError,
)
from skincap.io._common import (
    UNIT_TO_METRES,
    atomic_output,
    from_y_up,
    unit_scale,
)
from skincap.io.c3d.content import (
    C3dContent,
    C3dGroup,
    C3dParameter,
)
from skincap.io.c3d.encode import C3dFrames, char_parameter, encode_c3d, number_parameter
from skincap.io.c3d.scan import INVENTED_MASK, MODEL_OUTPUT_GROUPS
from skincap.io.narrowing import FLOAT32_MAX, check_float32
from skincap.types import MarkerSet

__all__ = ["write_c3d", "c3d_emptiness"]


# --------------------------------------------------------------------------- write
def write_c3d(
    markers: MarkerSet,
    path: str | os.PathLike[str],
    *,
    force: bool = False,
    units: str | None = None,
    up: Literal["y", "z"] | None = None,
) -> None:
    """Write a MarkerSet (its model outputs and ``meta["c3d"]``) as a float C3D.

    Parameters
    ----------
    markers : MarkerSet
        ``positions`` (T, N, 3) metres Y up; NaN samples are written as (0, 0, 0)
        with residual -1 (the C3D "invalid" mark; ezc3d and other readers return
        them as missing). ``residuals`` (T, N) metres are written back (0 where
        None); they are stored as a byte times ``POINT:SCALE`` so they are quantised
        to ``meta["point_scale"]`` (the source file's, when the residuals fit in its
        255 steps) or else to the smallest power of ten (file units) whose 255 steps
        hold the largest residual.
        ``camera_masks`` are written back on the measured samples; ``invented``
        samples get camera mask 0b1111111 (or, when a measured sample has that mask,
        one no measured sample has), declared in ``SKINCAP:INVENTED_CAMERA_MASK``. ``meta["model_outputs"]`` groups are
        written as extra POINTs listed in ``POINT:<GROUP>`` and ``POINT:TYPE_GROUPS``.
        Labels beyond 255 go to ``POINT:LABELS2``, ``LABELS3``…, and
        ``meta["descriptions"]`` to ``DESCRIPTIONS``, ``DESCRIPTIONS2``…; text is
        UTF-8. ``meta["c3d"]`` (from :func:`read_c3d`) is written back as the
        module docstring says: analogs kept when the frame count is the source's,
        else left out with a SkincapWarning.
    path : str or PathLike
        Output file; refused if it exists unless ``force``.
    units : str, optional
        Length unit of the file; default ``meta["source_units"]`` or ``"mm"``.
    up : {"y", "z"}, optional
        Up axis of the file; default ``meta["up"]`` or ``"z"``.

    Raises
    ------
    OutputExistsError, ValidationError
        ValidationError also for 0 frames, or 0 markers and no model outputs
        (:func:`c3d_emptiness`).
    FormatError
        A value the file cannot hold (a coordinate beyond float32, a label over 255
        bytes), naming the value and where it is; nothing is written.

    Warns
    -----
    SkincapWarning
        The source's analog channels (and force plates) are left out because the
        frame count changed.
    """
    if not isinstance(markers, MarkerSet):
        raise ValidationError(f"markers: expected a MarkerSet, got {type(markers).__name__}")
    meta = markers.meta
    units = str(units if units is not None else meta.get("source_units", "mm"))
    unit_scale(units)  # an unknown unit is refused before anything else
    up_key = str(up if up is not None else meta.get("up", "z")).lower()
    if up_key not in ("y", "z"):
        raise ValidationError(f"up: expected 'y' or 'z', got {up_key!r}")
    empty = c3d_emptiness(markers)
    if empty is not None:
        raise ValidationError(f"markers: {empty}")
    target = Path(path)

    points = _points_to_write(markers, units, up_key)
    pscale, steps = _residual_steps(points, meta)
    _check_storable(points, markers.rate, target, units)
    first = int(meta.get("first_frame", 1))
    if first < 0 or first > 65535:
        raise ValidationError(f"meta['first_frame']: must be in 0..65535, got {first}")

    content = meta.get("c3d")
    if not isinstance(content, C3dContent):
        content = None
    keep_analogs = _analogs_kept(content, markers.n_frames, target)
    if keep_analogs and content is not None:
        analogs, ratio = content.analogs, content.analog_ratio
    else:
        analogs, ratio = np.zeros((0, 0)), 0

    source_groups = list(content.groups) if content is not None else []
    # the source's points go out in its column order (model outputs between markers)
    order = _source_order(points.labels, content)
    point = _point_parameters(markers, points, pscale, units, up_key, content, target, order)
    out_groups = _merged_groups(
        source_groups, point, points.groups, keep_analogs, target, float(markers.rate) * ratio
    )
    masks = _camera_masks(markers, len(points.labels), out_groups, target)
    cols = slice(None) if order is None else order

    frames = C3dFrames(
        xyz=points.xyz[:, cols],
        invalid=points.invalid[:, cols],
        residual_steps=steps[:, cols],
        camera_masks=masks[:, cols],
        analogs=analogs,
        ratio=ratio,
    )
    payload = encode_c3d(
        out_groups,
        frames,
        first_frame=first,
        rate=float(markers.rate),
        point_scale=pscale,
        events=content.events if content is not None else None,
        target=target,
    )
    with atomic_output(target, force=force) as tmp:
        tmp.write_bytes(payload)


@dataclass
class _Points:
    """Every POINT the file holds: the markers, then the model outputs, in file units.

    ``labels`` (P,) with P = N markers + the model outputs; ``xyz`` (T, P, 3) file
    units, 0 where ``invalid`` (T, P) bool; ``residuals`` (T, P) file units, 0 where
    absent; ``groups`` maps a model-output group (``"ANGLES"``…) to its labels;
    ``model_units`` the model outputs' units by (source-case) group name.
    """

    labels: list[str]
    xyz: np.ndarray
    invalid: np.ndarray
    residuals: np.ndarray
    groups: dict[str, list[str]]
    model_units: dict[str, Any]


def c3d_emptiness(markers: MarkerSet) -> str | None:
    """Why ``markers`` cannot be a C3D because it is empty, or None if it is not.

    A C3D needs at least one frame, and at least one POINT (a marker or a
    ``meta["model_outputs"]`` series) or the source's analog channels: an
    analog-only file (EMG, force plates alone) keeps its frame count in its
    header and analog samples, while a file with neither would read back with 0
    frames, so it is refused rather than written with the frame count lost.
    """
    if markers.n_frames == 0:
        return "a C3D needs at least one frame, got 0 frames"
    model_outputs = markers.meta.get("model_outputs") or {}
    if markers.n_markers == 0 and not any(model_outputs.values()):
        content = markers.meta.get("c3d")
        if (
            isinstance(content, C3dContent)
            and content.n_analog_channels
            and content.analog_ratio
            and content.n_frames == markers.n_frames
        ):
            return None
        return "a C3D needs at least one marker or analog channel, got 0 markers"
    return None


def _points_to_write(markers: MarkerSet, units: str, up_key: str) -> _Points:
    """The markers then ``meta["model_outputs"]`` as POINTs in file ``units``, ``up_key`` up.

    Model outputs of another known length unit are converted to ``units``; a model
    output of the wrong shape or named like a marker is a ValidationError.
    """
    meta = markers.meta
    t, n = markers.n_frames, markers.n_markers
    scale = unit_scale(units)
    pos = from_y_up(markers.positions, up_key) / scale  # (T, N, 3) file units
    miss = markers.missing
    res = np.zeros((t, n)) if markers.residuals is None else markers.residuals / scale
    res = np.where(np.isnan(res), 0.0, res)
    if (res < 0).any():
        raise ValidationError("markers.residuals: must be >= 0 (NaN allowed) where present")

    labels = list(markers.labels)
    out_pos = [pos]
    out_miss = [miss]
    out_res = [res]
    groups: dict[str, list[str]] = {}
    model_outputs = meta.get("model_outputs") or {}
    model_units = dict(meta.get("model_output_units") or {})
    for g, series in model_outputs.items():
        if not series:
            continue
        gname = str(g).upper()
        names = [str(k) for k in series]
        arr = np.stack([np.asarray(v, dtype=np.float64) for v in series.values()], axis=1)
        if arr.shape != (t, len(names), 3):
            raise ValidationError(
                f"meta['model_outputs'][{g!r}]: expected arrays of shape ({t}, 3), got {arr.shape[::2]}"
            )
        gu = model_units.get(g)
        if gu in UNIT_TO_METRES and gu != units:
            arr = arr * (UNIT_TO_METRES[gu] / scale)
            model_units[g] = units
        clash = set(names) & set(labels)
        if clash:
            raise ValidationError(
                f"meta['model_outputs'][{g!r}]: labels {sorted(clash)[:5]} are also marker labels"
            )
        labels.extend(names)
        out_pos.append(arr)
        out_miss.append(np.asarray(np.isnan(arr).any(axis=2)))
        out_res.append(np.zeros((t, len(names))))
        groups[gname] = names
    all_pos = np.concatenate(out_pos, axis=1)
    all_miss = np.concatenate(out_miss, axis=1)
    all_pos[all_miss] = 0.0
    return _Points(
        labels=labels,
        xyz=all_pos,
        invalid=all_miss,
        residuals=np.concatenate(out_res, axis=1),
        groups=groups,
        model_units=model_units,
    )


def _residual_steps(points: _Points, meta: dict[str, Any]) -> tuple[float, np.ndarray]:
    """``POINT:SCALE`` magnitude (file units per step) and the residual bytes (T, P) int.

    The source's ``meta["point_scale"]`` when its 255 steps hold the largest residual,
    else the smallest power of ten that does.
    """
    finite_res = points.residuals[~points.invalid]
    rmax = float(finite_res.max()) if finite_res.size else 0.0
    pscale = float(meta.get("point_scale", 0.0) or 0.0)
    if not (np.isfinite(pscale) and pscale > 0 and rmax <= 255 * pscale * (1 + 1e-6)):
        # the smallest power of ten whose 255 steps hold the largest residual
        pscale = 10.0 ** np.ceil(np.log10(rmax / 255.0)) if rmax > 0 else 1.0
    # stored as a byte k with residual = k * |SCALE|
    steps = np.clip(np.round(points.residuals / pscale), 0, 255).astype(np.int64)
    return pscale, steps


def _check_storable(points: _Points, rate: float, target: Path, units: str) -> None:
    """FormatError naming the first coordinate (file ``units``) or a rate beyond float32."""
    where_names = points.labels

    def where(idx: tuple[int, ...]) -> str:
        return f"point {where_names[idx[1]]!r}, frame {idx[0]}, {'xyz'[idx[2]]}"

    check_float32(np.where(points.invalid[..., None], 0.0, points.xyz), target, where, unit=units)
    if not (np.isfinite(rate) and 0 < rate <= FLOAT32_MAX):
        raise FormatError(target, f"frame rate {rate} cannot be stored as a float32")


def _analogs_kept(content: C3dContent | None, n_frames: int, target: Path) -> bool:
    """Whether the source's analogs go out: only when its frame count is ``n_frames``.

    Warns (SkincapWarning, at write_c3d's caller) when analog channels are dropped.
    """
    keep_analogs = content is not None and content.n_frames == n_frames
    if content is not None and not keep_analogs and content.n_analog_channels:
        fp = content.n_force_plates()
        warnings.warn(
            f"{target}: the markers have {n_frames} frames, the source's {content.n_analog_channels} "
            f"analog channels were aligned with {content.n_frames}: analog data"
            f"{f' and {fp} force plates' if fp else ''} not written (they cannot be "
            "realigned with frames that changed)",
            SkincapWarning,
            stacklevel=3,
        )
    return keep_analogs


def _number(target: Path) -> Any:
    """``num(name, values, kind, scalar=None)``: a numeric parameter for ``target``."""

    def num(name: str, values: Any, kind: str, scalar: bool | None = None) -> C3dParameter:
        return number_parameter(name, values, kind, target=target, scalar=scalar)

    return num


def _text(target: Path) -> Any:
    """``text(name, values)``: a character parameter for ``target``."""

    def text(name: str, values: str | list[str]) -> C3dParameter:
        return char_parameter(name, values, target=target)

    return text


def _chunked(name: str, values: list[str], target: Path) -> list[C3dParameter]:
    """LABELS, LABELS2, LABELS3… of at most 255 strings each."""
    text = _text(target)
    out = [text(name, values[:255])]
    for k in range(255, len(values), 255):
        out.append(text(f"{name}{k // 255 + 1}", values[k : k + 255]))
    return out


def _point_parameters(
    markers: MarkerSet,
    points: _Points,
    pscale: float,
    units: str,
    up_key: str,
    content: C3dContent | None,
    target: Path,
    order: np.ndarray | None = None,
) -> list[C3dParameter]:
    """The POINT parameters that describe ``points``, in the source's records where equal.

    ``order`` (P,) int, optional: the column order the points are written in.

    Drops ``points.groups["BONES"]`` when the source's POINT did not list it (the reader
    recognises segment axes by their labels again).
    """
    num, text = _number(target), _text(target)
    meta = markers.meta
    t, n = markers.n_frames, markers.n_markers
    labels, groups, total = points.labels, points.groups, len(points.labels)
    point: list[C3dParameter] = [
        num("USED", total, "int"),
        # int16 read as unsigned by ezc3d up to 65535; beyond, -1 and the header decide
        num("FRAMES", t if t <= 65535 else -1, "int"),
        num("DATA_START", 0, "int"),
        num("SCALE", -pscale, "float"),
        num("RATE", float(markers.rate), "float"),
        text("UNITS", units),
    ]
    descriptions = meta.get("descriptions")
    by_label = _source_descriptions(content) if content is not None else {}
    if not (isinstance(descriptions, list) and len(descriptions) == n):
        # columns added, removed or reordered: the source's descriptions by label
        descriptions = [by_label.get(lab, "") for lab in markers.labels]
    # the model outputs keep theirs by label (Plug-in Gait names each angle and moment)
    descriptions = list(descriptions) + [by_label.get(lab, "") for lab in labels[n:total]]
    descriptions = [str(d) for d in descriptions]
    if order is not None:
        labels, descriptions = [labels[i] for i in order], [descriptions[i] for i in order]
    point += _chunked("LABELS", labels, target)
    point += _chunked("DESCRIPTIONS", descriptions, target)
    screen = meta.get("screen_axes")
    if not (
        isinstance(screen, tuple | list)
        and len(screen) == 2
        and str(screen[1]).upper().lstrip("+") == up_key.upper()
    ):
        screen = ("+X", "+Z" if up_key == "z" else "+Y")
    point += [text("X_SCREEN", str(screen[0])), text("Y_SCREEN", str(screen[1]))]
    source_groups = list(content.groups) if content is not None else []
    source_point = next((g for g in source_groups if g.name.upper() == "POINT"), None)
    if source_point is not None and source_point.get("BONES") is None:
        # segment axes the reader recognised by their labels: the source did not list
        # them, and the reader recognises them again without the list
        groups.pop("BONES", None)
    type_groups: list[str] = []
    for gname, names in groups.items():
        point += _chunked(gname, names, target)  # ANGLES, ANGLES2… like LABELS
        type_groups.extend([gname, gname[:-1] if gname.endswith("S") else gname])
        unit_param = MODEL_OUTPUT_GROUPS.get(gname, gname.rstrip("S") + "_UNITS")
        gu = points.model_units.get(gname.lower())
        if gu and gname != "BONES":
            point.append(text(unit_param, str(gu)))
    if type_groups:
        point.append(text("TYPE_GROUPS", type_groups))
    if source_point is not None:
        point = [_like_source(p, source_point.get(p.name)) for p in point]
        tg = source_point.get("TYPE_GROUPS")
        if tg is not None and tg.type == -1:
            listed = {str(v).strip().upper() for v in tg.value}
            if set(type_groups) <= listed:  # the source's list still holds: keep it as it is
                point = [p for p in point if p.name != "TYPE_GROUPS"] + [tg]
    return point


def _merged_groups(
    source_groups: list[C3dGroup],
    point: list[C3dParameter],
    groups: dict[str, list[str]],
    keep_analogs: bool,
    target: Path,
    analog_rate: float = 0.0,
) -> list[C3dGroup]:
    """The source's groups with ``point`` in POINT and the analogs dropped unless kept.

    ``groups`` are the model-output groups written (their POINT listings are replaced).
    Kept analogs get ``ANALOG:RATE = analog_rate`` (Hz) when the source gave none or 0
    (BTS), so a reader that sizes frames by it (ezc3d) finds the samples written.
    ROTATION is left out (with a SkincapWarning when it held data); POINT, ANALOG and
    FORCE_PLATFORM are added when the source had none.
    """
    num, text = _number(target), _text(target)
    written = {p.name for p in point}

    def rewritten(name: str) -> bool:
        """A POINT parameter of the source that the MarkerSet's points replace."""
        name = name.upper()
        if name in written or name in ("LONG_FRAMES", "TYPE_GROUPS"):
            return True
        # a group's *_UNITS is replaced only where written (in ``written``): the source's
        # ANGLE_UNITS, SCALAR_UNITS… stay when no such output goes out
        listing = {"LABELS", "DESCRIPTIONS", *MODEL_OUTPUT_GROUPS, *groups}
        return name.rstrip("0123456789") in listing

    out_groups: list[C3dGroup] = []
    seen: set[str] = set()
    for g in source_groups:
        key = g.name.upper()
        seen.add(key)
        if key == "POINT":
            kept = tuple(p for p in g.parameters if not rewritten(p.name))
            out_groups.append(replace(g, parameters=tuple(point) + kept))
        elif key == "ANALOG" and not keep_analogs:
            out_groups.append(replace(g, parameters=_no_analogs(num, text)))
        elif key == "ANALOG" and not _positive_rate(g.get("RATE")):
            kept = tuple(p for p in g.parameters if p.name.upper() != "RATE")
            out_groups.append(replace(g, parameters=(*kept, num("RATE", analog_rate, "float"))))
        elif key == "FORCE_PLATFORM" and not keep_analogs:
            out_groups.append(replace(g, parameters=(num("USED", 0, "int"),)))
        elif key == "TRIAL" and not keep_analogs:
            # frame numbers of another frame count
            kept = tuple(p for p in g.parameters if not p.name.upper().startswith("ACTUAL_"))
            out_groups.append(replace(g, parameters=kept))
        elif key == "ROTATION":
            # rotation samples are not read: their group (and its DATA_START, a block
            # of the source) would point at nothing in this file
            used = g.get("USED")
            if used is not None and used.type in (1, 2) and np.any(np.asarray(used.value) > 0):
                warnings.warn(
                    f"{target}: the source's ROTATION data (segment rotations) is not written",
                    SkincapWarning,
                    stacklevel=3,
                )
        elif key == "SKINCAP":
            kept = tuple(p for p in g.parameters if p.name.upper() != "INVENTED_CAMERA_MASK")
            if kept:
                out_groups.append(replace(g, parameters=kept))
        else:
            out_groups.append(g)
    if "POINT" not in seen:
        out_groups.insert(0, C3dGroup("POINT", parameters=tuple(point)))
    if "ANALOG" not in seen:
        out_groups.append(C3dGroup("ANALOG", parameters=_no_analogs(num, text)))
    if "FORCE_PLATFORM" not in seen:
        out_groups.append(C3dGroup("FORCE_PLATFORM", parameters=(num("USED", 0, "int"),)))
    return out_groups


def _camera_masks(
    markers: MarkerSet, total: int, out_groups: list[C3dGroup], target: Path
) -> np.ndarray:
    """Camera masks (T, P) int: the markers' measured ``camera_masks``, and a mask marking
    invented samples, declared in ``SKINCAP:INVENTED_CAMERA_MASK``.

    The invented mark is INVENTED_MASK (all seven bits) unless a measured sample has
    that mask; then the highest mask no measured sample has, so a measured sample never
    reads back as invented. Adds the parameter to ``out_groups`` (in place) when the
    markers carry ``invented``.
    """
    n = markers.n_markers
    masks = np.zeros((markers.n_frames, total), dtype=np.int64)
    present = ~markers.missing
    if markers.camera_masks is not None:
        masks[:, :n] = np.where(present, markers.camera_masks, 0)
    if markers.invented is not None:
        invented = markers.invented & present
        measured = masks[:, :n][~invented]
        mark = INVENTED_MASK
        used = np.zeros(INVENTED_MASK + 1, dtype=bool)
        used[np.unique(measured)] = True
        if used[mark]:
            free = np.flatnonzero(~used[1:]) + 1
            if free.size:
                mark = int(free[-1])
            else:  # every mask in use: the invented mark wins, the cameras of those are lost
                warnings.warn(
                    f"{target}: every camera mask is in use by measured samples; those with "
                    f"mask {mark} are written without their cameras to keep them apart from "
                    "invented ones",
                    SkincapWarning,
                    stacklevel=3,
                )
                masks[:, :n][masks[:, :n] == mark] = 0
        masks[:, :n] = np.where(invented, mark, masks[:, :n])
        mask_param = _number(target)("INVENTED_CAMERA_MASK", mark, "int")
        for k, g in enumerate(out_groups):
            if g.name.upper() == "SKINCAP":
                out_groups[k] = replace(g, parameters=g.parameters + (mask_param,))
                break
        else:
            out_groups.append(C3dGroup("SKINCAP", parameters=(mask_param,)))
    return masks


def _source_listing(content: C3dContent, name: str) -> list[str]:
    """The source file's POINT ``name``, ``name2``, ``name3``… strings, in order."""
    out: list[str] = []
    k = 1
    while (p := content.parameter("POINT", name + (str(k) if k > 1 else ""))) is not None:
        if p.type != -1:
            break
        out.extend(p.value)
        k += 1
    return out


def _source_descriptions(content: C3dContent) -> dict[str, str]:
    """The source file's POINT descriptions by label."""
    pairs = zip(
        _source_listing(content, "LABELS"), _source_listing(content, "DESCRIPTIONS"), strict=False
    )
    return {lab: d for lab, d in pairs if lab}


def _source_order(labels: list[str], content: C3dContent | None) -> np.ndarray | None:
    """(P,) int: the column order that puts ``labels`` (markers, then model outputs) in
    the source's POINT order; None when they are not the source's points."""
    if content is None:
        return None
    source = [str(s).strip() for s in _source_listing(content, "LABELS")][: len(labels)]
    index = {lab: i for i, lab in enumerate(labels)}
    if len(source) != len(labels) or len(index) != len(labels) or set(source) != set(index):
        return None
    order = np.array([index[lab] for lab in source], dtype=np.int64)
    return None if np.array_equal(order, np.arange(len(labels))) else order


def _like_source(new: C3dParameter, old: C3dParameter | None) -> C3dParameter:
    """The source's record when it holds the same values; else ``new`` with its description."""
    if old is None or old.name.upper() == "DATA_START":
        return new
    if old.type == new.type and old.value_equals(new):
        return old
    return replace(new, description=old.description, locked=old.locked)


def _positive_rate(p: C3dParameter | None) -> bool:
    """A numeric rate parameter whose first value is positive."""
    if p is None or p.type not in (1, 2, 4):
        return False
    v = np.asarray(p.value, dtype=np.float64).ravel()
    return bool(v.size) and bool(v[0] > 0)


def _no_analogs(num: Any, text: Any) -> tuple[C3dParameter, ...]:
    """An ANALOG group with no channel."""
    return (
        num("USED", 0, "int"),
        num("RATE", 0.0, "float"),
        num("GEN_SCALE", 1.0, "float"),
        num("SCALE", np.zeros(0), "float", False),
        num("OFFSET", np.zeros(0, dtype=np.int64), "int", False),
        text("LABELS", []),
        text("DESCRIPTIONS", []),
        text("UNITS", []),
    )
