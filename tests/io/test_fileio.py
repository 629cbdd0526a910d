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


def test_a_removal_goes_with_the_outputs_or_not_at_all(tmp_path):
    """OutputSet.remove: the file is gone when the set is written, and still there when the
    commit fails before the renames (an output's folder vanished)."""
    from calib.io.fileio import OutputSet

    stale, out = tmp_path / "a.compliance.json", tmp_path / "a.urdf"
    stale.write_text("old")
    s = OutputSet()
    s.stage(out, "new")
    s.remove(stale)
    s.remove(tmp_path / "absent.json")           # nothing to remove: no error
    assert s.commit() == [out]
    assert out.read_text() == "new" and not stale.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]     # no temporary left
    stale.write_text("old")
    s = OutputSet()
    s.stage(tmp_path / "gone" / "b.urdf", "new")
    s.remove(stale)
    with pytest.raises(OutputError):
        s.commit()
    assert stale.read_text() == "old"


def test_an_output_staged_in_chunks_is_written_in_order(tmp_path):
    """OutputSet.stage takes a file's chunks of bytes (a large report's residuals are not joined
    into one more copy in memory) and writes them one after the other."""
    from calib.io.fileio import OutputSet

    out = tmp_path / "r.csv"
    s = OutputSet()
    s.stage(out, [b"a,b\n", b"1,2\n", b"", b"3,4\n"])
    assert s.commit() == [out]
    assert out.read_bytes() == b"a,b\n1,2\n3,4\n"


def test_several_outputs_written_at_once_or_none(tmp_path):
    """The files of a set are written in threads (their fsyncs overlap): each has its bytes;
    when one cannot be written (its folder is gone, the 3rd of 6) the error names the first such
    path in the order staged, and no file and no temporary file is left in any folder."""
    import threading

    from calib.io.fileio import OutputSet

    a, b = tmp_path / "a", tmp_path / "b"
    a.mkdir()
    b.mkdir()
    s = OutputSet()
    paths = [a / "0.bin", b / "1.bin", a / "2.bin", b / "3.bin", a / "4.bin", b / "5.bin"]
    for k, path in enumerate(paths):
        s.stage(path, bytes([k]) * (k * 100_000 + 1) if k % 2 else [b"x" * k, bytes([k]) * 1000])
    assert s.commit() == paths
    assert [len(p.read_bytes()) for p in paths] == [1000, 100_001, 1002, 300_001, 1004, 500_001]
    assert not [t for t in threading.enumerate() if t.name == "calib-write"]   # (joined: a fork may follow)
    s = OutputSet()
    for k, path in enumerate(paths):
        s.stage(path.with_name(f"new{k}.bin") if k != 2 else tmp_path / "gone" / "x.bin",
                bytes(10) if k != 5 else [bytes(10)] * 3)
    with pytest.raises(OutputError, match=r"gone.x\.bin.*does not exist"):
        s.commit()
    assert sorted(p.name for p in a.iterdir()) == ["0.bin", "2.bin", "4.bin"]
    assert sorted(p.name for p in b.iterdir()) == ["1.bin", "3.bin", "5.bin"]


def test_a_geometry_only_calibration_removes_an_earlier_sidecar(tmp_path, capsys):
    """An earlier calibration with joint terms left CALIBRATED.compliance.json; a calibration
    without them into the same URDF removes it (it would be read with the new URDF), and says so."""
    from calib.cli.main import main

    out = tmp_path / "cal.urdf"
    sidecar = tmp_path / "cal.compliance.json"
    sidecar.write_text('{"format": "calib-compliance/1"}')
    meas = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
    assert main(["calibrate", str(BUNDLED_URDF), str(meas), "-o", str(out), "--cv", "0"]) == 0
    assert out.exists() and not sidecar.exists()
    assert f"removed {sidecar}" in capsys.readouterr().out


INTERRUPTED = """
import os, signal, subprocess, sys, time
from pathlib import Path
import calib.io.fileio as fio
real = os.fsync
fio.os.fsync = lambda fd: (time.sleep(0.5), real(fd))          # (slow disks: the writers wait)
out = Path(sys.argv[1])
s = fio.OutputSet()
for k in range(4):
    s.stage(out / f"out{k}.txt", b"x" * 1000)
subprocess.Popen(["sh", "-c", f"for i in 1 2 3; do sleep 0.15; kill -INT {os.getpid()}; done"])
try:
    s.commit()
except KeyboardInterrupt:
    pass
try:
    time.sleep(1.0)
except KeyboardInterrupt:
    time.sleep(1.0)
"""


@pytest.mark.slow
def test_interrupts_while_the_files_are_written_leave_nothing(tmp_path):
    """Three Ctrl-C 0.15 s apart while four files are written in threads (each fsync 0.5 s): the
    clean-up is not cut short by the later ones; no output and no temporary file is left (with
    the signals not held during it, all four temporary files stayed)."""
    import subprocess
    import sys

    script = tmp_path / "interrupted.py"
    script.write_text(INTERRUPTED)
    out = tmp_path / "out"
    out.mkdir()
    subprocess.run([sys.executable, str(script), str(out)], cwd=ROOT, timeout=60,
                   env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True)
    # no temporary file; no output (or, when a loaded machine delays the signals past the
    # writes, the whole set: the renames hold them)
    assert sorted(p.name for p in out.iterdir()) in ([], [f"out{k}.txt" for k in range(4)])


def test_the_umask_is_read_once_per_set(tmp_path, monkeypatch):
    """The writer threads take the permissions read once before they start (os.umask is the
    process's: read in each thread, one of them could see the 0 another set for a moment and
    make its file world-writable); each file gets 0o666 less the umask."""
    import calib.io.fileio as fio

    calls = []
    real = fio._umask
    monkeypatch.setattr(fio, "_umask", lambda: calls.append(1) or real())
    s = fio.OutputSet()
    for k in range(5):
        s.stage(tmp_path / f"{k}.txt", b"x")
    s.commit()
    mask = real()
    assert len(calls) == 1
    assert {os.stat(tmp_path / f"{k}.txt").st_mode & 0o777 for k in range(5)} == {0o666 & ~mask}
