"""``python -m calib``: the ``calib`` command (see :mod:`calib.cli`)."""
from .cli import main_entry

if __name__ == "__main__":
    main_entry()
