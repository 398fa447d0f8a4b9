"""matplotlib on its Agg backend, for every PNG skincap draws (no display needed)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from skincap.errors import MissingDependencyError
from skincap.io._common import atomic_output

__all__ = ["agg_pyplot", "save_png"]


def agg_pyplot(feature: str) -> Any:
    """``matplotlib.pyplot`` with the Agg backend selected.

    Parameters
    ----------
    feature : str
        What needs it, named in the error when matplotlib is missing.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    try:
        import matplotlib
    except ImportError:
        raise MissingDependencyError("matplotlib", "plot", feature) from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(
    fig: Any, path: str | os.PathLike[str], *, force: bool = False, dpi: float | None = None
) -> Path:
    """Write a matplotlib figure to ``path`` as PNG, atomically (no partial file; an
    existing file only with ``force``); ``dpi`` default: the figure's own."""
    with atomic_output(path, force=force) as tmp:
        fig.savefig(tmp, format="png", **({} if dpi is None else {"dpi": dpi}))
    return Path(path)
