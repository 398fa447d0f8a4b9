"""Stable colours for the viewer and the renderer: one per marker label, one per file.

A label's colour depends only on the label text (a CRC-32 hash, not Python's salted
``hash``), so the same marker has the same colour in every file and every session:
overlay a raw and a cleaned take and ``LASI`` is the same hue in both. A subject
prefix (``Alice:LASI``) is ignored so that Vicon-style names match plain ones.
Grey is kept for invented samples and unlabelled fragments (``*17``): label colours
are always saturated.
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence

import numpy as np

__all__ = [
    "INVENTED_COLOUR",
    "FRAGMENT_COLOUR",
    "label_key",
    "label_colours",
    "file_tint",
    "hsv_to_rgb",
]

#: (3,) uint8 colour of samples a gap filler invented (mid grey, seen on the white page).
INVENTED_COLOUR = np.array([128, 128, 128], dtype=np.uint8)
#: (3,) uint8 colour of unlabelled fragments (``*N``): light grey, no identity yet.
FRAGMENT_COLOUR = np.array([178, 178, 178], dtype=np.uint8)

# Hue-spread tints for whole files (raw, cleaned, ...); index 0 is a blue, 1 an orange.
_FILE_TINTS = np.array(
    [
        [31, 119, 180],
        [255, 127, 14],
        [44, 160, 44],
        [214, 39, 40],
        [148, 103, 189],
        [23, 190, 207],
        [227, 119, 194],
        [140, 86, 75],
    ],
    dtype=np.uint8,
)


def label_key(label: str) -> str:
    """The part of a marker label that decides its colour.

    The text after the last ``:`` (a Vicon subject prefix is dropped), stripped.

    >>> label_key("Alice:LASI")
    'LASI'
    """
    return label.rsplit(":", 1)[-1].strip()


def hsv_to_rgb(hsv: np.ndarray) -> np.ndarray:
    """Convert HSV colours to RGB.

    Parameters
    ----------
    hsv : (..., 3) float
        Hue, saturation and value, each in [0, 1].

    Returns
    -------
    (..., 3) uint8
        RGB in [0, 255].
    """
    hsv = np.asarray(hsv, dtype=np.float64)
    h, s, v = hsv[..., 0] % 1.0, hsv[..., 1], hsv[..., 2]
    i = np.floor(h * 6.0).astype(np.int64) % 6
    f = h * 6.0 - np.floor(h * 6.0)
    p = v * (1.0 - s)
    q = v * (1.0 - s * f)
    t = v * (1.0 - s * (1.0 - f))
    # rows: the six hue sectors; columns: which of v, t, p, q goes to r, g, b
    table = np.stack(
        [
            np.stack([v, t, p], -1),
            np.stack([q, v, p], -1),
            np.stack([p, v, t], -1),
            np.stack([p, q, v], -1),
            np.stack([t, p, v], -1),
            np.stack([v, p, q], -1),
        ],
        axis=-2,
    )  # (..., 6, 3)
    rgb = np.take_along_axis(table, i[..., None, None], axis=-2)[..., 0, :]
    return np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)


def label_colours(labels: Sequence[str]) -> np.ndarray:
    """One stable, saturated colour per marker label.

    Parameters
    ----------
    labels : sequence of N str
        Marker labels; only :func:`label_key` of each matters.

    Returns
    -------
    (N, 3) uint8
        RGB colours. Equal keys give equal colours in any file and session;
        saturation is at least 0.6 so no label looks like the grey of
        :data:`INVENTED_COLOUR`. Unlabelled fragments (``*N``) are
        :data:`FRAGMENT_COLOUR`.
    """
    codes = np.array(
        [zlib.crc32(label_key(str(s)).encode("utf-8")) for s in labels], dtype=np.uint64
    ).reshape(-1)
    hue = (codes & np.uint64(0xFFFF)).astype(np.float64) / 65536.0
    sat = 0.6 + 0.35 * ((codes >> np.uint64(16)) & np.uint64(0xFF)).astype(np.float64) / 255.0
    val = 0.75 + 0.2 * ((codes >> np.uint64(24)) & np.uint64(0xFF)).astype(np.float64) / 255.0
    rgb = hsv_to_rgb(np.stack([hue, sat, val], axis=-1)).reshape(-1, 3)
    fragment = np.array([str(s).startswith("*") for s in labels], dtype=bool).reshape(-1)
    rgb[fragment] = FRAGMENT_COLOUR
    return rgb


def file_tint(index: int) -> np.ndarray:
    """The tint of the ``index``-th file of a scene (cycles after eight files).

    Returns
    -------
    (3,) uint8
    """
    return _FILE_TINTS[int(index) % len(_FILE_TINTS)].copy()
