"""``skincap track`` and ``skincap eval track``: the rope-tracking verbs.

Registered on :data:`skincap.cli.app` / :data:`skincap.cli.eval_app` when
:mod:`skincap.cli` is imported. Heavy imports stay inside the commands.
"""

from __future__ import annotations
