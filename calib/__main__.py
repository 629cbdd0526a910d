"""``python -m calib``: the ``calib`` command (see :mod:`calib.cli.main`)."""
from calib._entry import console

if __name__ == "__main__":
    console()
