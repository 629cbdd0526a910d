"""The plots' worker process (calib.cli.plot_worker): the same images as drawn in process, its
failures raised in the command, and the process stopped on every path of ``calib calibrate``."""
from __future__ import annotations

import sys
from dataclasses import replace
from types import MappingProxyType

import numpy as np
import pytest

import calib.cli.plot_worker
from calib.report.plots import plot_rows
from calib.report.rows import PoseDeviations, ReportRows
from calib.cli.main import main
from calib.cli.plot_worker import PlotWorker

from conftest import BUNDLED_URDF, ROOT

EXAMPLE = ROOT / "examples" / "brtirus0707a" / "measurements.csv"


def _rows(n: int, seed: int = 0) -> ReportRows:
    rng = np.random.default_rng(seed)
    after = PoseDeviations(rng.normal(0, 0.05e-3, (n, 3)), rng.normal(0, 1e-4, (n, 3)))
    before = PoseDeviations(rng.normal(0, 1e-3, (n, 3)), rng.normal(0, 1e-3, (n, 3)))
    outlier = np.zeros(n, bool)
    outlier[3] = True
    return ReportRows(np.full(n, "measurements"), np.arange(2, n + 2), np.full(n, "cal"), None,
                      np.zeros((n, 6)), before, after, outlier, np.arange(n) % 4 == 0,
                      rng.uniform(-1, 1, (n, 3)), "nominal model",
                      columns=MappingProxyType({"time_s": np.arange(n, dtype=float)}))   # (as Measurements)


@pytest.mark.slow
def test_worker_draws_the_images_of_the_process_itself():
    """Byte for byte the PNGs plot_rows draws here (drift included), in its order, with progress
    calls counting up to the 5 plots."""
    rows = _rows(200)
    seen = []
    with PlotWorker() as worker:
        worker.submit(rows, tolerance_m=0.1e-3)
        images = worker.images(progress=lambda k, n: seen.append((k, n)))
    assert images == plot_rows(rows, tolerance_m=0.1e-3)
    assert list(images) == list(plot_rows(rows)) and len(images) == 5
    assert seen[-1] == (5, 5) and all(n == 5 and 0 < k for k, n in seen) and sorted(seen) == seen
    assert worker._proc.returncode == 0


@pytest.mark.slow
def test_threaded_process_starts_a_new_interpreter_with_the_same_images():
    """A process with threads is not forked (a fork copies their locks, not the threads): the
    worker is then a new interpreter (subprocess.Popen), drawing the same images."""
    import subprocess
    import threading

    rows, stop = _rows(50, seed=1), threading.Event()
    other = threading.Thread(target=stop.wait)
    other.start()
    try:
        with PlotWorker() as worker:
            assert isinstance(worker._proc, subprocess.Popen)
            worker.submit(rows)
            images = worker.images()
    finally:
        stop.set()
        other.join()
    assert images == plot_rows(rows) and len(images) == 5 and worker._proc.returncode == 0


@pytest.mark.slow
def test_worker_imports_matplotlib_without_the_property_docstrings():
    """In a new interpreter the worker's import writes no property table into the artists'
    set() docstrings (Line2D.set's is several thousand characters otherwise): the 40 % of the
    import it saves is still saved with this matplotlib. (The images are those of a full import:
    the test above draws them in a new interpreter and compares bytes.)"""
    import subprocess

    code = ("import sys; from calib.cli.plot_worker import _without_property_docs as lean\n"
            "lean() if sys.argv[1] == 'lean' else None\n"
            "import matplotlib.figure, matplotlib.lines as ml\n"
            "print(len(ml.Line2D.set.__doc__ or ''), 'linestyle' in str(ml.Line2D.set.__signature__)"
            " if hasattr(ml.Line2D.set, '__signature__') else None)")
    out = {how: subprocess.run([sys.executable, "-c", code, how], capture_output=True, text=True, check=True,
                               cwd=ROOT).stdout.split() for how in ("lean", "full")}
    assert out["lean"] == ["0", "None"]
    assert int(out["full"][0]) > 2000 and out["full"][1] == "True"


@pytest.mark.skipif(not calib.cli.plot_worker._can_fork(), reason="the worker is forked on Linux only")
def test_the_command_collects_its_garbage_again_after_forking_the_worker(monkeypatch):
    """gc.freeze() around the fork: the command's objects are unfrozen again at once (0 frozen),
    also when the fork fails (the error is the command's to report)."""
    import gc

    with PlotWorker() as worker:
        assert isinstance(worker._proc, calib.cli.plot_worker._Forked) and gc.get_freeze_count() == 0
    monkeypatch.setattr("os.fork", lambda: (_ for _ in ()).throw(BlockingIOError(11, "fork refused")))
    with pytest.raises(BlockingIOError):
        calib.cli.plot_worker._Forked()
    assert gc.get_freeze_count() == 0
    monkeypatch.undo()
    # a program that runs the command in its own process and froze objects itself keeps them frozen
    keep = [object() for _ in range(100)]
    gc.freeze()
    try:
        frozen = gc.get_freeze_count()
        with PlotWorker():
            assert gc.get_freeze_count() == frozen > 100
    finally:
        gc.unfreeze()
    del keep


def test_worker_failure_is_raised_and_closing_stops_it():
    with PlotWorker() as worker:
        worker.submit(replace(_rows(50), point_base=np.zeros((3, 3))))    # 3 points for 50 rows
        with pytest.raises(RuntimeError, match="(?s)drawing the plots failed in the worker process.*IndexError"):
            worker.images()
    assert worker._proc.returncode == 1
    idle = PlotWorker()           # never sent anything: stopped (killed) by close
    idle.close()
    assert idle._proc.returncode is not None


def _group_states(group: int) -> list[str]:
    """The states of the processes of process group ``group`` (Linux /proc): "Z" for a dead one
    not yet reaped, "killed" for one with a SIGKILL pending (it dies when next scheduled), else
    its state letter (R, S, ...)."""
    from pathlib import Path

    states = []
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            fields = (proc / "stat").read_text().rsplit(")", 1)[1].split()
            status = (proc / "status").read_text()
        except OSError:            # (ended meanwhile)
            continue
        if int(fields[2]) != group:
            continue
        pending = [int(line.split()[1], 16) for line in status.splitlines() if line.startswith(("SigPnd", "ShdPnd"))]
        states.append("killed" if fields[0] != "Z" and any(m >> (9 - 1) & 1 for m in pending) else fields[0])
    return states


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="process groups read from /proc")
def test_closing_a_drawing_worker_stops_the_fork_drawing_its_other_half_too():
    """close() while both processes draw (200,000 rows: over a second) ends the worker's whole
    process group at once: nothing keeps drawing for a command that has stopped (killing the
    worker alone left its fork drawing)."""
    import signal

    worker = PlotWorker()
    worker.submit(_rows(200_000))
    assert worker._proc.stdout.peek(1)       # the first progress message: both halves draw
    group = worker._proc.pid
    assert len(_group_states(group)) == 2
    worker.close()
    assert worker._proc.returncode == -signal.SIGKILL
    assert set(_group_states(group)) <= {"Z", "killed"}     # gone, dead (not yet reaped by init) or dying


@pytest.fixture
def workers(monkeypatch):
    """The PlotWorkers the command starts."""
    started = []

    class Recorded(PlotWorker):
        def __init__(self):
            super().__init__()
            started.append(self)
    monkeypatch.setattr(calib.cli.plot_worker, "PlotWorker", Recorded)
    return started


@pytest.mark.parametrize("command", ["calibrate", "evaluate"])
def test_command_stops_its_worker_on_bad_input_and_writes_nothing(command, tmp_path, capsys, workers):
    bad = tmp_path / "m.csv"
    lines = EXAMPLE.read_text().splitlines()
    lines[5] = ",".join(["abc" if k == 2 else v for k, v in enumerate(lines[5].split(","))])
    bad.write_text("\n".join(lines) + "\n")
    out = tmp_path / "out"
    out.mkdir()
    extra = ["-o", str(out / "c.urdf")] if command == "calibrate" else []
    code = main([command, str(BUNDLED_URDF), str(bad), *extra, "--html", str(out / "r.html"),
                 "--plots", str(out / "plots")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith(f"calib: error: {bad}") and "row 6" in err and list(out.iterdir()) == []
    assert len(workers) == 1 and workers[0]._proc.returncode is not None


def test_calibrate_plots_from_the_worker(tmp_path, capsys, workers):
    plots = tmp_path / "plots"
    code = main(["calibrate", str(BUNDLED_URDF), str(EXAMPLE), "-o", str(tmp_path / "c.urdf"), "--html",
                 str(tmp_path / "r.html"), "--plots", str(plots)])
    assert code == 0, capsys.readouterr().err
    assert len(workers) == 1 and workers[0]._proc.returncode == 0
    names = sorted(p.name for p in plots.iterdir())
    assert names == ["error_histograms.png", "error_map.png", "orientation_errors.png", "position_errors.png"]
    page = (tmp_path / "r.html").read_text()
    assert page.count("data:image/png;base64,") == 4
