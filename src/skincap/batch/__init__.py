"""Many takes on Dask: ``skincap batch VERB INPUTS... -o OUT`` and :func:`run_batch`.

Every take (one input file) runs through one workflow of :mod:`skincap.workflows` as
one task, on local worker processes, an existing Dask cluster or, one after another,
in the calling process; a failing take is recorded and the others finish
(:mod:`skincap.batch.runner`). What each verb writes per take is in
:mod:`skincap.batch.verbs`. Dask (``dask[distributed]``, the ``batch`` extra) is
imported only when a batch runs.
"""

from skincap.batch.runner import SUMMARY_NAMES, BatchResult, Take, collect_inputs, run_batch
from skincap.batch.verbs import BATCH_VERBS, BatchVerb

__all__ = [
    "BATCH_VERBS",
    "SUMMARY_NAMES",
    "BatchResult",
    "BatchVerb",
    "Take",
    "collect_inputs",
    "run_batch",
]
