"""Output paths: a symbolic link loop is refused with one line, exit 2, nothing written."""
from __future__ import annotations

import os

import pytest

from calib.errors import OutputError
from calib.io.fileio import check_not_input
from conftest import BUNDLED_URDF, ROOT


def test_a_link_loop_as_output_is_an_output_error(tmp_path):
    os.symlink(tmp_path / "b", tmp_path / "a")
    os.symlink(tmp_path / "a", tmp_path / "b")
    with pytest.raises(OutputError, match="symbolic link loop"):
        check_not_input(tmp_path / "a", [BUNDLED_URDF])
    # an input that is a loop is not an output error: its reader says it cannot be read
    check_not_input(tmp_path / "out.urdf", [tmp_path / "a"])


def test_cli_refuses_a_link_loop_output_and_writes_nothing(tmp_path, capsys):
    from calib.cli.main import main

    os.symlink(tmp_path / "loop.urdf", tmp_path / "loop.urdf")
    before = sorted(os.listdir(tmp_path))
    code = main(["calibrate", str(BUNDLED_URDF), str(ROOT / "examples" / "brtirus0707a" / "measurements.csv"),
                 "-o", str(tmp_path / "loop.urdf")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    assert len(err) == 1 and "symbolic link loop" in err[0]
    assert sorted(os.listdir(tmp_path)) == before
