"""The command line: ``skincap VERB ...``, the only layer that parses arguments or prints.

``_app`` holds the Typer application, the consoles and the error handling; each other
module registers one verb (or one family of verbs) on it when imported. Importing this
package imports them all, so ``app`` below has every command.
"""

from skincap.cli import clean, render, track, view  # noqa: F401  (registers their verbs)
from skincap.cli._app import app, main

__all__ = ["app", "main"]
