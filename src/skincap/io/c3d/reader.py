"""``read_c3d``: a C3D file into a :class:`~skincap.types.MarkerSet` (see :mod:`skincap.io.c3d`)."""

from __future__ import annotations

import os
import tempfile
import warnings
from pathlib import Path
from typing import Any, Literal

import numpy as np

from skincap.errors import (
    FormatError,
    MissingDependencyError,
    SkincapWarning,
    UnitWarning,
    ValidationError,
)
from skincap.io._common import (
    UNIT_TO_METRES,
    check_readable,
    read_file_bytes,
    unit_scale,
    up_rotation,
)
from skincap.io.c3d.checks import check_before_ezc3d
from skincap.io.c3d.content import (
    C3dContent,
    C3dGroup,
    HeaderEvents,
)
from skincap.io.c3d.repair import intel_copy_of_mips, repaired_parameter_section
from skincap.io.c3d.scan import (
    BONE_SUFFIXES,
    MODEL_OUTPUT_GROUPS,
    C3dLayout,
    decode_floats,
    scan_c3d,
)
from skincap.io.c3d.up_axis import guess_up_from_markers
from skincap.types import MarkerSet

__all__ = ["read_c3d"]


# ---------------------------------------------------------------------------- read
def _import_ezc3d() -> Any:
    try:
        import ezc3d  # noqa: F401
        from ezc3d import ezc3d as swig
    except ImportError:  # pragma: no cover - ezc3d is a core dependency
        raise MissingDependencyError("ezc3d", "c3d", "reading and writing C3D files") from None
    return swig


def _labels(layout: C3dLayout, key: str) -> list[str]:
    """POINT:<key>, <key>2, <key>3… concatenated."""
    out: list[str] = []
    first = layout.params.get(("POINT", key))
    if not isinstance(first, list):
        return out
    out.extend(first)
    k = 2
    while isinstance(layout.params.get(("POINT", f"{key}{k}")), list):
        out.extend(layout.params[("POINT", f"{key}{k}")])
        k += 1
    return out


def _unique_labels(raw: list[str]) -> tuple[list[str], dict[str, str]]:
    """Deterministic unique labels: empty -> point_<i>, repeats -> name_2, name_3…"""
    out: list[str] = []
    renamed: dict[str, str] = {}
    real = set(raw)
    taken: set[str] = set()
    for i, lab in enumerate(raw):
        base = lab if lab else f"point_{i + 1}"
        new = base
        k = 2
        # never take a label already used, nor one a later column really has
        while new in taken or (new != lab and new in real):
            new = f"{base}_{k}"
            k += 1
        if new != lab:
            renamed[new] = lab
        taken.add(new)
        out.append(new)
    return out, renamed


def _up_from_screen(
    layout: C3dLayout, path: Path, m_xyz: np.ndarray, m_miss: np.ndarray, scale: float
) -> tuple[str, bool]:
    """Source up axis from POINT:Y_SCREEN, or (absent) from the markers'
    (:func:`~skincap.io.c3d.up_axis.guess_up_from_markers`); (axis, guessed)."""
    ys = layout.params.get(("POINT", "Y_SCREEN"))
    if not isinstance(ys, list) or not ys or not ys[0].strip():
        up = guess_up_from_markers(m_xyz, m_miss, scale)
        if up == "y":
            warnings.warn(
                f"{path}: POINT:Y_SCREEN not given; the markers stand along the file's y, "
                "read as Y up (pass up='z' to override)",
                UnitWarning,
                stacklevel=3,
            )
        return up, True
    val = ys[0].strip().upper().lstrip("+")
    if val in ("Z", "Y"):
        return val.lower(), False
    warnings.warn(
        f"{path}: POINT:Y_SCREEN is {ys[0]!r}; skincap handles Y or Z up only, assuming Z up",
        UnitWarning,
        stacklevel=3,
    )
    return "z", True


def _analog_samples(layout: C3dLayout, data: bytes, n_frames: int) -> tuple[np.ndarray, int]:
    """Analog samples as stored, (C, n_frames * ratio) float64, and the ratio."""
    n_analog = layout.n_analog_per_frame
    if not n_analog:
        return np.zeros((0, 0)), 0
    used = layout.params[("ANALOG", "USED")]
    channels = int(used[0])  # the scan checked it is there and divides n_analog
    ratio = n_analog // channels
    words = 4 * layout.n_points + n_analog
    is_float = layout.scale < 0
    size = 4 if is_float else 2
    block = data[layout.data_offset : layout.data_offset + n_frames * words * size]
    if is_float:
        with np.errstate(invalid="ignore"):  # NaN samples are carried as they are
            flat = decode_floats(block, layout.processor)
    else:
        fmt = layout.params.get(("ANALOG", "FORMAT"))
        unsigned = isinstance(fmt, list) and bool(fmt) and fmt[0].strip().upper() == "UNSIGNED"
        ie = ">" if layout.processor == "mips" else "<"
        flat = np.frombuffer(block, dtype=f"{ie}{'u2' if unsigned else 'i2'}").astype(np.float64)
    frames = flat.reshape(n_frames, words)[:, 4 * layout.n_points :]  # (T, ratio * C)
    # each frame holds `ratio` sub-frames of every channel: -> (C, T * ratio)
    samples = frames.reshape(n_frames, ratio, channels).transpose(2, 0, 1)
    return samples.reshape(channels, n_frames * ratio), ratio


def _header_events(layout: C3dLayout, data: bytes) -> HeaderEvents | None:
    """The header's event block (bytes 294-467), or None when it holds no event."""
    ie = ">" if layout.processor == "mips" else "<"
    w = np.frombuffer(data[294:302], dtype=f"{ie}u2").astype(np.int64)
    count = int(w[3])
    if not 0 < count <= 18:
        return None
    return HeaderEvents(
        count=count,
        times=decode_floats(data[304:376], layout.processor),
        display=bytes(data[376:394]),
        labels=bytes(data[396:468]),
        label_range_present=int(w[0]),
        label_range_block=int(w[1]),
    )


def _content(layout: C3dLayout, data: bytes, n_frames: int) -> C3dContent:
    """meta["c3d"]: the file's parameters, analog samples and header events."""
    analogs, ratio = _analog_samples(layout, data, n_frames)
    groups = tuple(
        C3dGroup(name=name, description=desc, locked=locked, parameters=tuple(params.values()))
        for name, desc, locked, params in layout.records.values()
    )
    return C3dContent(
        groups=groups,
        analogs=analogs,
        analog_ratio=ratio,
        n_frames=n_frames,
        first_frame=layout.first_frame,
        events=_header_events(layout, data),
        processor=layout.processor,
    )


def _guess_units(xyz: np.ndarray) -> str:
    """'m' when every coordinate (NaN ignored) is within 20 units of the origin, else 'mm'."""
    if xyz.size == 0:
        return "mm"
    biggest = float(np.fmax.reduce(np.abs(xyz).ravel()))  # NaN only when all are NaN
    return "m" if biggest < 20.0 else "mm"


def read_c3d(path: str | os.PathLike[str], *, up: Literal["auto", "y", "z"] = "auto") -> MarkerSet:
    """Read the labelled marker trajectories of a C3D file.

    Parameters
    ----------
    path : str or PathLike
        The ``.c3d`` file (Intel, DEC or MIPS; integer or float data).
    up : {"auto", "y", "z"}
        The file's up axis. ``"auto"`` reads ``POINT:Y_SCREEN`` (``"+Z"`` means Z up,
        ``"+Y"`` Y up); when it is absent, Z up unless the markers clearly stand along
        the file's y (:func:`~skincap.io.c3d.up_axis.guess_up_from_markers`, with a
        warning), ``meta["up_guessed"]``.

    Returns
    -------
    MarkerSet
        ``positions`` (T, N, 3) float64 metres, Y up, NaN where missing (residual < 0
        or exactly (0, 0, 0)); ``residuals`` (T, N) float64 metres, NaN where missing;
        ``invented`` (T, N) bool for files written by skincap with invented samples,
        else None; ``rate`` the exact POINT:RATE (the float32 in the file printed at
        its shortest round-trip precision, so 59.94 stays 59.94). ``meta`` holds
        ``source_units``, ``up``, ``first_frame`` (the header's own frame number),
        ``model_outputs`` ({group: {label: (T, 3) float64}} in the file's units,
        NaN where missing), ``model_output_units``, ``descriptions``,
        ``renamed_labels``, ``zeros_as_missing``, ``point_scale``, ``screen_axes``.

    Raises
    ------
    FormatError
        Missing, truncated, corrupted or inconsistent file (with the byte offset).

    Warns
    -----
    UnitWarning
        ``POINT:UNITS`` empty or unknown: the unit is guessed (mm unless every
        coordinate is within 20 units of the origin, then m).
    """
    p = check_readable(path)
    if up not in ("auto", "y", "z"):
        raise ValidationError(f"up: expected 'auto', 'y' or 'z', got {up!r}")
    data = read_file_bytes(p)
    data, repaired = _checked_or_repaired(p, data)
    layout = scan_c3d(p, data)
    _warn_scale_disagreement(p, layout)
    c3d, points, residuals, n_frames, rate_ez = _decode_with_ezc3d(p, data, layout, repaired)
    n = layout.n_points

    raw_labels = _labels(layout, "LABELS")
    if len(raw_labels) < n:
        raw_labels = raw_labels + [""] * (n - len(raw_labels))
    raw_labels = [s.strip() for s in raw_labels[:n]]
    descriptions = _labels(layout, "DESCRIPTIONS")
    descriptions = (descriptions + [""] * n)[:n]

    # work on ezc3d's (component, N, T) planes; one transposed copy at the end
    xyz = points[:3]  # (3, N, T) file units, view
    res_nt = residuals[0]  # (N, T)
    if np.isinf(xyz).any():
        raise FormatError(p, "point data contains infinite coordinates")
    nan_nt = np.isnan(xyz[0]) | np.isnan(xyz[1]) | np.isnan(xyz[2])
    neg_nt = res_nt < 0
    zero_nt = (xyz[0] == 0.0) & (xyz[1] == 0.0) & (xyz[2] == 0.0)
    invalid_nt = nan_nt | neg_nt  # the C3D rule
    missing_nt = invalid_nt | zero_nt  # plus exporters' (0, 0, 0)
    n_zero = int((zero_nt & ~invalid_nt).sum())

    output_cols, taken = _model_output_columns(layout, raw_labels)
    marker_cols = np.array([i for i in range(n) if i not in taken], dtype=np.int64)
    all_markers = marker_cols.size == n
    m_xyz = xyz if all_markers else xyz[:, marker_cols]  # (3, N', T)
    m_miss = missing_nt if all_markers else missing_nt[marker_cols]  # (N', T)
    m_res = res_nt if all_markers else res_nt[marker_cols]  # (N', T)
    units_str, units_guessed = _point_units(layout, m_xyz, p)
    scale = unit_scale(units_str)

    up_src, up_guessed = (
        _up_from_screen(layout, p, m_xyz, m_miss, scale) if up == "auto" else (up, False)
    )
    model_outputs, model_units = _model_outputs(
        layout, xyz, invalid_nt, output_cols, raw_labels, units_str
    )
    mpos, mres = _markers_in_metres(m_xyz, m_res, m_miss, up_src, scale)
    labels, renamed = _unique_labels([raw_labels[i] for i in marker_cols])
    camera_bits = _camera_bits(c3d, layout, p)
    if camera_bits is not None:
        camera_bits = camera_bits[:, marker_cols]  # (T, N') int
    invented = _invented_samples(camera_bits, layout, m_miss.T)
    camera_masks = _measured_camera_masks(camera_bits, m_miss.T, invented)
    rate = _frame_rate(layout, rate_ez, p)

    xs = layout.params.get(("POINT", "X_SCREEN"))
    ys = layout.params.get(("POINT", "Y_SCREEN"))
    meta: dict[str, Any] = {
        "source_format": "c3d",
        "source_path": str(p),
        "source_units": units_str,
        "units_guessed": units_guessed,
        "up": up_src,
        "up_guessed": up_guessed,
        "first_frame": int(layout.first_frame),
        "point_scale": abs(float(layout.scale)),
        "model_outputs": model_outputs,
        "model_output_units": model_units,
        "descriptions": [descriptions[i] for i in marker_cols],
        "renamed_labels": renamed,
        "zeros_as_missing": n_zero,
        "c3d": _content(layout, data, n_frames),
    }
    if isinstance(xs, list) and xs and isinstance(ys, list) and ys:
        meta["screen_axes"] = (xs[0].strip(), ys[0].strip())
    return MarkerSet(
        positions=mpos,
        labels=labels,
        rate=rate,
        residuals=mres,
        invented=invented,
        meta=meta,
        camera_masks=camera_masks,
    )


def _checked_or_repaired(p: Path, data: bytes) -> tuple[bytes, bool]:
    """The file's bytes once they pass the checks before ezc3d, and whether its
    parameter records had to be rewritten (:mod:`skincap.io.c3d.repair`, with a
    warning naming what changed) to pass them; else the checks' FormatError."""
    intel = intel_copy_of_mips(data)
    if intel is not None:
        data = intel
    try:
        check_before_ezc3d(p, data)
        return data, intel is not None
    except FormatError as exc:
        fixed = repaired_parameter_section(data)
        if fixed is None:
            raise
        try:
            check_before_ezc3d(p, fixed[0])
        except FormatError:
            raise exc from None
    changes = fixed[1]
    more = f" and {len(changes) - 3} more" if len(changes) > 3 else ""
    warnings.warn(
        f"{p}: parameter records read by their pointers ({'; '.join(changes[:3])}{more})",
        SkincapWarning,
        stacklevel=3,
    )
    return fixed[0], True


def _warn_scale_disagreement(p: Path, layout: C3dLayout) -> None:
    """Warn when an integer file's ``POINT:SCALE`` and its header's scale disagree.

    The coordinates follow ``POINT:SCALE`` (as ezc3d and the format have it); c3d.org
    sample06 (Motion Analysis, ``MACsample.c3d``) stores 0.0215 there and 0.0551 in
    its header, so its body reads 2.6 times smaller than with the header's.
    """
    value = layout.params.get(("POINT", "SCALE"))
    if value is None or layout.scale <= 0 or isinstance(value, list) or np.size(value) == 0:
        return
    param = float(np.ravel(value)[0])
    if param > 0 and not np.isclose(param, layout.scale, rtol=1e-4):
        warnings.warn(
            f"{p}: POINT:SCALE {param:.6g} and the header's point scale {layout.scale:.6g} "
            f"disagree; coordinates use POINT:SCALE (the header's would make them "
            f"{layout.scale / param:.3g} times as large)",
            UnitWarning,
            stacklevel=3,
        )


def _decode_with_ezc3d(
    p: Path, data: bytes, layout: C3dLayout, repaired: bool = False
) -> tuple[Any, np.ndarray, np.ndarray, int, float]:
    """ezc3d's reading of the file: (c3d object, points (4, N, T), residuals (1, N, T),
    frame count T, header rate in Hz), held to the header's frame count. A ``repaired``
    file's bytes are handed to ezc3d through a temporary copy.

    FormatError when ezc3d fails, the file is shorter than its frames need, or the
    arrays are not of the scanned shape.
    """
    swig = _import_ezc3d()
    try:
        if repaired:
            with tempfile.TemporaryDirectory(prefix="skincap-c3d-") as tmp:
                copy = Path(tmp) / "repaired.c3d"
                copy.write_bytes(data)
                c3d = swig.c3d(str(copy), swig.Options(False, False))
        else:
            c3d = swig.c3d(str(p), swig.Options(False, False))
        points = c3d.get_points()
        residuals = c3d.get_point_residuals()
        n_frames = int(c3d.header().nbFrames())
        rate_ez = float(c3d.header().frameRate())
    except (RuntimeError, OSError, ValueError, IndexError, MemoryError, TypeError) as exc:
        raise FormatError(p, f"ezc3d could not read the file: {exc}") from None
    if int(c3d.header().nbAnalogsMeasurement()) != layout.n_analog_per_frame:
        # ezc3d derives the analog samples per frame from ANALOG:RATE; a file without
        # it (BTS: c3d.org sample28) still stores the header's count in every frame,
        # and ezc3d would read the points at the wrong stride
        points, residuals = _points_by_header(layout, data, n_frames)
    word = 4 if layout.scale < 0 else 2
    frame_bytes = (4 * layout.n_points + layout.n_analog_per_frame) * word
    # ezc3d stops quietly at the end of a truncated file: hold it to the header's count
    declared = max(n_frames, layout.last_frame - layout.first_frame + 1)
    need = layout.data_offset + declared * frame_bytes
    if need > len(data):
        raise FormatError(
            p,
            f"truncated: {declared} frames of {frame_bytes} bytes from byte {layout.data_offset} need {need} bytes, the file has {len(data)}",
            offset=len(data),
        )
    n = layout.n_points
    if points.shape != (4, n, n_frames) or residuals.shape != (1, n, n_frames):
        raise FormatError(
            p, f"ezc3d returned points of shape {points.shape}, expected (4, {n}, {n_frames})"
        )
    return c3d, points, residuals, n_frames, rate_ez


def _points_by_header(
    layout: C3dLayout, data: bytes, n_frames: int
) -> tuple[np.ndarray, np.ndarray]:
    """The points as ezc3d decodes them, at the header's frame layout: points (4, N, T)
    in file units (NaN where the residual word is negative, last row 1) and residuals
    (1, N, T) (the residual word's high byte times the point scale, -1 where invalid).

    Only the data section's bytes the header declares are read (the caller checks the
    file holds them).
    """
    n = layout.n_points
    words = 4 * n + layout.n_analog_per_frame
    is_float = layout.scale < 0
    size = 4 if is_float else 2
    need = n_frames * words * size
    block = data[layout.data_offset : layout.data_offset + need]
    if len(block) < need:
        block = block + bytes(need - len(block))  # the caller refuses a truncated file
    if is_float:
        with np.errstate(invalid="ignore", over="ignore"):
            flat = decode_floats(block, layout.processor)
    else:
        ie = ">" if layout.processor == "mips" else "<"
        flat = np.frombuffer(block, dtype=f"{ie}i2").astype(np.float64)
    per_point = flat.reshape(n_frames, words)[:, : 4 * n].reshape(n_frames, n, 4)
    xyz = per_point[..., :3].transpose(2, 1, 0)  # (3, N, T)
    if not is_float:
        xyz = xyz * abs(layout.scale)
    fourth = per_point[..., 3].T  # (N, T)
    with np.errstate(invalid="ignore"):
        word4 = np.clip(np.where(np.isfinite(fourth), np.trunc(fourth), -1.0), -1, 0xFFFF)
    word4 = word4.astype(np.int64)
    invalid = word4 < 0
    residuals = np.where(invalid, -1.0, ((word4 >> 8) & 0xFF) * abs(layout.scale))
    points = np.ones((4, n, n_frames))
    points[:3] = np.where(invalid[None], np.nan, xyz)
    return points, residuals[None]


def _model_output_columns(
    layout: C3dLayout, raw_labels: list[str]
) -> tuple[dict[str, list[int]], set[int]]:
    """Point columns that are model outputs, by lower-case group, and all of them.

    A group is one of MODEL_OUTPUT_GROUPS or ``POINT:TYPE_GROUPS`` listing its labels in
    ``POINT:<GROUP>``; ``"bones"`` are unlisted segment axes recognised by their
    labels (``<name>O`` plus the BONE_SUFFIXES). A column belongs to one group only.
    """
    label_index = {lab: i for i, lab in enumerate(raw_labels) if lab}
    group_names = list(MODEL_OUTPUT_GROUPS)
    tg = layout.params.get(("POINT", "TYPE_GROUPS"))
    if isinstance(tg, list):
        for g in tg:
            g = g.strip().upper()
            if g and g not in group_names and isinstance(layout.params.get(("POINT", g)), list):
                group_names.append(g)
    output_cols: dict[str, list[int]] = {}
    taken: set[int] = set()
    for g in group_names:
        listed = _labels(layout, g)
        if not listed:
            continue
        cols = [
            label_index[s.strip()]
            for s in listed
            if s.strip() in label_index and label_index[s.strip()] not in taken
        ]
        if cols:
            output_cols[g.lower()] = cols
            taken.update(cols)
    bone_cols = []
    for i, lab in enumerate(raw_labels):
        if i in taken or len(lab) < 2 or lab.startswith("*") or lab[-1] != "O":
            continue
        quad = [label_index.get(lab[:-1] + s) for s in BONE_SUFFIXES]
        found = [q for q in quad if q is not None and q not in taken]
        if len(found) == len(quad):
            bone_cols.extend(found)
    if bone_cols:
        output_cols["bones"] = bone_cols
        taken.update(bone_cols)
    return output_cols, taken


def _point_units(layout: C3dLayout, m_xyz: np.ndarray, p: Path) -> tuple[str, bool]:
    """``POINT:UNITS`` lower-cased, or guessed from the markers' (3, N', T) coordinates.

    Returns (unit, guessed); a guess warns (UnitWarning, at read_c3d's caller).
    """
    units_raw = layout.params.get(("POINT", "UNITS"))
    units_str = units_raw[0].strip().lower() if isinstance(units_raw, list) and units_raw else ""
    units_guessed = units_str not in UNIT_TO_METRES
    if units_guessed:
        guess = _guess_units(m_xyz)
        what = "empty" if not units_str else f"{units_str!r}, not a known length unit"
        if layout.n_points:  # a file with no POINT (EMG alone) has no length to guess
            warnings.warn(
                f"{p}: POINT:UNITS is {what}; guessing {guess!r}", UnitWarning, stacklevel=3
            )
        units_str = guess
    return units_str, units_guessed


def _model_outputs(
    layout: C3dLayout,
    xyz: np.ndarray,
    invalid_nt: np.ndarray,
    output_cols: dict[str, list[int]],
    raw_labels: list[str],
    units_str: str,
) -> tuple[dict[str, dict[str, np.ndarray]], dict[str, str]]:
    """Model outputs {group: {label: (T, 3)}} in file units, NaN where invalid, and
    their units by group.

    ``xyz`` (3, N, T) and ``invalid_nt`` (N, T) are every point column of the file.
    """
    model_outputs: dict[str, dict[str, np.ndarray]] = {}
    model_units: dict[str, str] = {}
    for g, cols in output_cols.items():
        arr = np.ascontiguousarray(xyz[:, cols].transpose(2, 1, 0))  # (T, k, 3)
        arr[invalid_nt[cols].T] = np.nan
        model_outputs[g] = {raw_labels[c]: arr[:, k] for k, c in enumerate(cols)}
        unit_param = MODEL_OUTPUT_GROUPS.get(g.upper(), g.upper().rstrip("S") + "_UNITS")
        u = layout.params.get(("POINT", unit_param))
        if g == "bones":
            model_units[g] = units_str
        elif isinstance(u, list) and u and u[0].strip():
            model_units[g] = u[0].strip()
    return model_outputs, model_units


def _markers_in_metres(
    m_xyz: np.ndarray, m_res: np.ndarray, m_miss: np.ndarray, up_src: str, scale: float
) -> tuple[np.ndarray, np.ndarray]:
    """Marker positions (T, N', 3) metres Y up and residuals (T, N') metres, NaN where missing.

    ``m_xyz`` (3, N', T), ``m_res`` and ``m_miss`` (N', T) in file units, ``up_src`` up;
    ``scale`` metres per file unit.
    """
    n_m, t_n = m_miss.shape
    rot = up_rotation(up_src)  # each row picks one source axis, with a sign
    mpos = np.zeros((t_n, n_m, 3))  # (T, N', 3) metres, Y up
    for k in range(3):  # three coordinates, not a loop over data
        axis = int(np.argmax(np.abs(rot[k])))
        np.multiply(m_xyz[axis].T, rot[k, axis] * scale, out=mpos[..., k])
    mmiss = m_miss.T  # (T, N')
    mpos[mmiss] = np.nan
    mres = np.zeros((t_n, n_m))
    np.multiply(m_res.T, scale, out=mres)
    mres[mmiss] = np.nan
    return mpos, mres


def _camera_bits(c3d: Any, layout: C3dLayout, p: Path) -> np.ndarray | None:
    """(T, N) int64: every POINT column's seven camera bits, as stored; None when ezc3d
    cannot give them (a FormatError instead when the file declares invented samples,
    which are recognised by them)."""
    try:
        masks = c3d.get_point_camera_masks()  # (7, N, T) bool
    except (RuntimeError, ValueError) as exc:
        if ("SKINCAP", "INVENTED_CAMERA_MASK") in layout.params:
            raise FormatError(p, f"ezc3d could not read the camera masks: {exc}") from None
        return None
    return (np.asarray(masks, dtype=np.int64) << np.arange(7)[:, None, None]).sum(axis=0).T


def _invented_samples(
    bits: np.ndarray | None, layout: C3dLayout, mmiss: np.ndarray
) -> np.ndarray | None:
    """(T, N') bool: present samples whose camera mask ``bits`` (T, N') is
    ``SKINCAP:INVENTED_CAMERA_MASK``; None when the file does not declare it."""
    sk = layout.params.get(("SKINCAP", "INVENTED_CAMERA_MASK"))
    if sk is None or len(sk) < 1 or bits is None:
        return None
    return (bits == int(round(float(sk[0])))) & ~mmiss


def _measured_camera_masks(
    bits: np.ndarray | None, mmiss: np.ndarray, invented: np.ndarray | None
) -> np.ndarray | None:
    """(T, N') uint8 camera masks of the measured samples (0 where missing or invented);
    None when no sample has a camera bit."""
    if bits is None:
        return None
    keep = ~mmiss if invented is None else ~mmiss & ~invented
    out = np.where(keep, bits, 0).astype(np.uint8)
    return out if out.any() else None


def _frame_rate(layout: C3dLayout, rate_ez: float, p: Path) -> float:
    """POINT:RATE in Hz (else the header's ``rate_ez``), the float32 at its shortest
    round-trip precision (59.94 stays 59.94); FormatError unless positive."""
    rate_p = layout.params.get(("POINT", "RATE"))
    rate32 = (
        float(rate_p[0])
        if isinstance(rate_p, np.ndarray) and rate_p.size and rate_p[0] > 0
        else rate_ez
    )
    if not (np.isfinite(rate32) and rate32 > 0):
        raise FormatError(p, f"frame rate {rate32} is not a positive number", offset=20)
    return float(str(np.float32(rate32)))
