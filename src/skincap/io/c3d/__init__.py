"""C3D marker files: read through ezc3d, written by skincap (:mod:`skincap.io.c3d.encode`).

skincap validates the whole C3D structure in Python before ezc3d sees a file
(header, every parameter record, the size of the data section): ezc3d can crash the
interpreter or loop forever on a corrupted parameter section, so only files whose
structure is consistent reach it, and every problem is a :class:`FormatError` with the
byte offset at fault.

What the reader keeps
---------------------
* Marker columns: every POINT that is not a model output; labels from ``POINT:LABELS``,
  ``LABELS2``, ``LABELS3``… (the first ``POINT:USED`` of them, old files list more).
  Empty labels become ``point_<column>`` and duplicates ``name_2``, ``name_3``… in
  column order; ``meta["renamed_labels"]`` maps each new label to the file's label.
* Missing samples: residual < 0 (the C3D rule) and samples exactly at (0, 0, 0), which
  many exporters write for a missing marker (a real marker exactly on the lab origin to
  float precision does not happen); both are NaN. ``meta["zeros_as_missing"]`` counts
  the (0, 0, 0) samples.
* Model outputs stored as POINTs (labels listed in ``POINT:ANGLES``, ``FORCES``,
  ``MOMENTS``, ``POWERS``, ``SCALARS``, ``REACTIONS`` or in a parameter named by
  ``POINT:TYPE_GROUPS``, plus Plug-in Gait segment axes: four labels ``XO XA XL XP``
  sharing a prefix, group ``"bones"``) go to ``meta["model_outputs"]`` in their own
  units, neither scaled nor rotated.
* Camera masks (which of seven cameras saw each sample) of the measured marker
  samples: ``MarkerSet.camera_masks`` (None when no sample has a camera bit).
* Invented samples: files written by skincap mark them with camera mask 0b1111111
  (another one when a measured sample has that mask) and declare it in
  ``SKINCAP:INVENTED_CAMERA_MASK``; without that parameter ``invented`` is None.
* Everything else, for the writer (``meta["c3d"]``, a
  :class:`~skincap.io.c3d.content.C3dContent`): every parameter group and parameter
  (type, dimensions, values, description, name as written), the analog samples as
  stored and the header's events. Text is UTF-8, or Latin-1 where it is not valid
  UTF-8.

What the writer writes
----------------------
The points from the MarkerSet (POINT's labels, descriptions, units, scale, rate and
frame count rewritten from it, its other parameters kept; residuals and camera masks
per sample), and ``meta["c3d"]`` as it
came: analog samples with ``ANALOG`` unchanged (so ``SCALE``, ``OFFSET`` and
``GEN_SCALE`` give the same values), ``FORCE_PLATFORM``, ``EVENT``,
``EVENT_CONTEXT``, header events, vendor groups. Columns added on the same frames
(cleanup's ``U1``…) keep the analogs aligned. When the frame count differs from the
source's, the analog samples cannot be realigned (which frames went is unknown): they
and the force plates are left out with a :class:`SkincapWarning`, never written
misaligned; events (in seconds) and the other groups stay. Refusing would block the
markers, the product asked for, with no way around; the warning names what is lost.
A take with no POINT at all is written only when it carries the source's analogs
(an EMG or force-plate take: the header and the analog samples keep its frame count).
The TRC and CSV writers warn once with what of this a C3D source loses there (camera
masks, residuals, analogs, force plates, events, vendor groups).
"""

from skincap.io.c3d.reader import read_c3d
from skincap.io.c3d.scan import MODEL_OUTPUT_GROUPS
from skincap.io.c3d.writer import c3d_emptiness, write_c3d

__all__ = ["read_c3d", "write_c3d", "c3d_emptiness", "MODEL_OUTPUT_GROUPS"]
