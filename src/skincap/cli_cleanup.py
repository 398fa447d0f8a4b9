"""``skincap clean`` and ``skincap eval fill``: the marker-cleanup verbs.

Registered on :data:`skincap.cli.app` / :data:`skincap.cli.eval_app` when
:mod:`skincap.cli` is imported. Heavy imports stay inside the commands.
"""

from __future__ import annotations
