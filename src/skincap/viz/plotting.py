"""matplotlib on its Agg backend, for every PNG skincap draws (no display needed)."""

from __future__ import annotations

from typing import Any

from skincap.errors import MissingDependencyError

__all__ = ["agg_pyplot"]


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
