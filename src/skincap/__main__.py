"""``python -m skincap``: the same as the ``skincap`` command."""

from skincap.cli import main

main()
