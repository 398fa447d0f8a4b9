"""The command line: ``skincap VERB ...``, the only layer that parses arguments or prints.

``_app`` holds the Typer application, the consoles, the error handling and the
progress bars; each other module registers one verb (or one family of verbs) on it
when imported, and the work itself is done in :mod:`skincap.workflows`. Importing
this package imports them all, in the order ``skincap --help`` lists them; heavy
imports stay inside the commands. Options several verbs share are ``Annotated``
aliases in ``_options``.
"""

from skincap.cli import (  # noqa: F401, I001  (registers the verbs in --help order)
    info,
    convert,
    skin,
    animate,
    synth,
    demo,
    bench,
    clean,
    render,
    track,
    solve,
    view,
    batch,
)
from skincap.cli._app import app, main, reflow_help

reflow_help(app)

__all__ = ["app", "main"]
