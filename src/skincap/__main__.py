"""``python -m skincap``: the same as the ``skincap`` command."""

from skincap.cli import main

if __name__ == "__main__":  # importing the module (pkgutil.walk_packages) runs nothing
    main()
