"""calib/cli/main.py: the parser assembled from one module per subcommand, one registration
style, one output policy, and a start-up that leaves numpy and Pinocchio to the command run."""
from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys

import pytest

import calib.design.poses
from calib.cli.main import COMMAND_NAMES, build_parser, command_module, main

from conftest import BUNDLED_URDF, ROOT

#: The subcommands as ``calib --help`` lists them.
NAMES = ["identifiability", "simulate", "calibrate", "evaluate", "select-poses", "plan", "compensate", "export",
         "formats"]


def _subparsers(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(action.choices)


def test_each_subcommand_module_registers_itself_and_runs_its_own_run():
    subs = _subparsers(build_parser())
    assert list(subs) == NAMES and list(COMMAND_NAMES) == NAMES
    for name in NAMES:
        module = command_module(name)
        assert module.__name__ == "calib.cli." + name.replace("-", "_")
        assert subs[name].get_default("func") is module.run


def test_each_subcommand_module_adds_one_parser_to_any_subparsers():
    """``add_parser`` works on subparsers it did not make (a script's own parser)."""
    for name in NAMES:
        parser = argparse.ArgumentParser(prog="x")
        sub = parser.add_subparsers(dest="command")
        returned = command_module(name).add_parser(sub)
        assert list(_subparsers(parser)) == [name]
        assert _subparsers(parser)[name] is returned


def test_importing_the_cli_loads_neither_numpy_nor_pinocchio():
    """``calib --help`` and the signal handlers of calib._entry come before the heavy imports."""
    code = ("import sys, calib.cli.main\n"
            "print(sorted(m for m in ('numpy', 'scipy', 'pinocchio') if m in sys.modules))\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT,
                         check=True).stdout
    assert out == "[]\n"


def test_the_command_runs_with_one_blas_thread():
    """main_entry comes before numpy: the commands' BLAS has one thread (threadpoolctl at that
    point limited no library, and they ran with one per core)."""
    code = ("import calib.cli.main as m\n"
            "def fake():\n"
            "    import numpy\n"
            "    from threadpoolctl import threadpool_info\n"
            "    print(max(i['num_threads'] for i in threadpool_info() if i['user_api'] == 'blas'))\n"
            "    return 0\n"
            "m.main = fake\n"
            "m.main_entry()\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    env["PYTHONPATH"] = str(ROOT)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "1\n"


@pytest.mark.parametrize("output, message", [
    ("/dev/null", "/dev/null: is not a regular file"),
    (str(BUNDLED_URDF), "refusing to overwrite an input file"),
])
def test_select_poses_refuses_a_bad_output_before_any_work(output, message, capsys, monkeypatch):
    """The practice commands share the others' output policy: the path is checked first."""
    def never(*args, **kwargs):
        raise AssertionError("the poses were selected before the output path was checked")

    monkeypatch.setattr(calib.design.poses, "design_poses", never)
    code = main(["select-poses", str(BUNDLED_URDF), "-n", "5", "-o", output])
    out, err = capsys.readouterr()
    assert (code, out) == (2, "")
    assert err.startswith("calib: error: ") and message in err and err.count("\n") == 1


def test_select_poses_writes_nothing_when_the_folder_is_missing(tmp_path, capsys):
    code = main(["select-poses", str(BUNDLED_URDF), "-n", "5", "-o", str(tmp_path / "no" / "poses.csv")])
    out, err = capsys.readouterr()
    assert (code, out) == (2, "")
    assert "folder" in err and "does not exist" in err
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_signal_while_the_parser_imports_the_library_ends_with_one_line(signum, code):
    """A command imports the library when it runs (the parser does not: its choices are in
    calib.choices): a signal while it loads ends the command like a signal anywhere else, one
    line and 128 + signal."""
    code_text = ("import sys, time, calib._entry as e\n"
                 "class Slow:\n"
                 "    def find_spec(self, name, path=None, target=None):\n"
                 "        if name == 'calib.model.identifiability':\n"
                 "            print('importing', file=sys.stderr, flush=True); time.sleep(3)\n"
                 "sys.meta_path.insert(0, Slow())\n"
                 "e.main()\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, "-c", code_text, "identifiability", str(BUNDLED_URDF)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env, cwd=ROOT, text=True)
    assert proc.stderr.readline() == "importing\n"
    proc.send_signal(signum)
    stdout, err = proc.communicate(timeout=60)
    assert (proc.returncode, stdout) == (code, "")
    assert err == f"calib: interrupted by {signal.Signals(signum).name}\n"


def test_help_loads_neither_numpy_nor_pinocchio():
    """``calib --help`` and a subcommand's help build every parser from calib.choices: no numpy,
    no Pinocchio (issue 27: help within 1.5x the start of numpy alone)."""
    code = ("import sys, contextlib, io, calib._entry as e\n"
            "for argv in (['--help'], ['calibrate', '--help'], ['compensate', '--help'], ['select-poses', '--help']):\n"
            "    sys.argv = ['calib'] + argv\n"
            "    with contextlib.redirect_stdout(io.StringIO()):\n"
            "        try:\n"
            "            e.main()\n"
            "        except SystemExit:\n"
            "            pass\n"
            "print(sorted(m for m in ('numpy', 'pinocchio', 'scipy') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert out.stdout.strip().splitlines()[-1] == "[]", out.stderr


def test_a_named_command_is_parsed_by_its_own_parser_alone():
    """main builds only the named subcommand's parser (start-up): the same arguments, help and
    errors as the whole parser; help, version, unknown commands and anything else before the
    command take the whole parser."""
    from calib.cli.main import _named_command

    assert _named_command(["calibrate", "a.urdf"]) == "calibrate"
    assert _named_command(["-vv", "--verbose", "select-poses"]) == "select-poses"
    for argv in ([], ["--help", "calibrate"], ["-h", "calibrate"], ["--version"], ["--", "calibrate"],
                 ["calibrat"], ["-x", "calibrate"], ["--verb", "calibrate"]):
        assert _named_command(argv) is None
    for name in NAMES:
        alone, whole = _subparsers(build_parser(name)), _subparsers(build_parser())
        assert list(alone) == [name]
        assert alone[name].format_help() == whole[name].format_help()
    argv = ["-v", "calibrate", "r.urdf", "m.csv", "-o", "c.urdf", "--cv", "3", "--params", "paper"]
    assert vars(build_parser("calibrate").parse_args(argv)) == vars(build_parser().parse_args(argv))
    assert build_parser("calibrate").parse_args(argv).cv == 3


def test_the_console_ends_without_the_teardown_and_keeps_every_line(tmp_path):
    """calib._entry.console (the console script, python -m calib) ends the process once the exit
    handlers ran and the streams are flushed (the interpreter's teardown of the modules is
    skipped: a module's __del__ is not called), with the command's exit code and every line of
    its output."""
    code = ("import atexit, sys, calib._entry as e\n"
            "class Torn:\n"
            "    def __del__(self): print('teardown')\n"
            "sys.modules['torn'] = Torn()\n"
            "atexit.register(print, 'exit handler')\n"
            "e.console()\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    example = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
    out = tmp_path / "c.urdf"
    run = subprocess.run([sys.executable, "-c", code, "calibrate", str(BUNDLED_URDF), str(example), "-o", str(out)],
                         capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
    assert run.returncode == 0, run.stderr
    assert "teardown" not in run.stdout
    assert f"wrote {out}" in run.stdout and run.stdout.endswith("use them by default)\nexit handler\n")
    assert out.stat().st_size > 1000
    bad = subprocess.run([sys.executable, "-c", code, "calibrate", str(BUNDLED_URDF)], capture_output=True,
                         text=True, env=env, cwd=tmp_path, timeout=300)
    assert (bad.returncode, bad.stdout, len(bad.stderr.splitlines())) == (2, "exit handler\n", 2)   # usage, error


def test_the_console_command_runs_with_the_larger_first_gc_generation(monkeypatch):
    """calib._entry.main sets the first generation's threshold to GC_THRESHOLD (50,000) before
    the imports and the command (start-up without repeated collections), the older ones kept."""
    import gc

    import calib._entry as entry
    import calib.cli.main as cli_main

    seen = []
    monkeypatch.setattr(cli_main, "main_entry", lambda: seen.append(gc.get_threshold()))
    before = gc.get_threshold()
    try:
        entry.main()
    finally:
        gc.set_threshold(*before)
    assert seen == [(50_000, *before[1:])]
