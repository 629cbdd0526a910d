"""``python -m calib``: the ``calib`` command (see :mod:`calib.cli`)."""
from ._entry import main

if __name__ == "__main__":
    main()
