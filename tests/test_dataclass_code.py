"""calib.dataclass_code: calib's dataclasses get the very methods dataclasses would compile, from
a file beside the bytecode after the first run; every other dataclass is left alone."""
from __future__ import annotations

import ast
import dataclasses
import inspect
import json
import marshal
import os
import subprocess
import sys
import typing
from pathlib import Path

import calib.dataclass_code as dc

from conftest import ROOT

PACKAGE = ROOT / "calib"

#: A process that imports every calib module and prints, for each of calib's dataclasses, the
#: marshalled code of each generated method (hex; marshal's version 2 writes no reference flags,
#: which depend on reference counts), and what the cache did.
CHILD = """
import os
os.umask(int(os.environ.get("CALIB_TEST_UMASK", "0o22"), 8))
import dataclasses, importlib, json, marshal, pkgutil, sys
import calib, calib.dataclass_code as dc
for m in pkgutil.walk_packages(calib.__path__, "calib."):
    if m.name.rsplit(".", 1)[-1] not in ("__main__", "plot_worker"):
        importlib.import_module(m.name)
codes = {}
for name, module in sorted(sys.modules.items()):
    if not name.startswith("calib."):
        continue
    for cls in vars(module).values():
        if isinstance(cls, type) and cls.__module__ == name and dataclasses.is_dataclass(cls):
            codes[cls.__qualname__ + "@" + name] = {
                meth: marshal.dumps(getattr(cls, meth).__code__, 2).hex()
                for meth in ("__init__", "__repr__", "__eq__", "__hash__", "__setattr__", "__delattr__")
                if getattr(getattr(cls, meth, None), "__code__", None) is not None
                and getattr(cls, meth).__code__.co_filename == "<string>"}
print(json.dumps({"codes": codes, "new": sorted(dc._new), "used": sorted(dc._used),
                  "hooked": vars(dataclasses).get("exec") is dc._exec, "path": dc.cache_path()}))
"""


def _child(prefix: Path, **env) -> dict:
    base = {k: v for k, v in os.environ.items() if k not in ("PYTHONDONTWRITEBYTECODE", dc.ENV_OFF)}
    out = subprocess.run([sys.executable, "-c", CHILD], capture_output=True, text=True, check=True, cwd=ROOT,
                         env=dict(base, PYTHONPATH=str(ROOT), PYTHONPYCACHEPREFIX=str(prefix), **env)).stdout
    return json.loads(out.splitlines()[-1])


def _entries(path: str) -> dict:
    blob = Path(path).read_bytes()
    from importlib.util import MAGIC_NUMBER

    assert blob.startswith(MAGIC_NUMBER)
    return {m: marshal.loads(b) for m, b in marshal.loads(blob[len(MAGIC_NUMBER):]).items()}


def test_the_methods_are_those_dataclasses_compiles_and_the_second_run_compiles_none(tmp_path):
    off = _child(tmp_path / "off", **{dc.ENV_OFF: "0"})
    assert not off["hooked"] and not Path(off["path"]).exists() and off["new"] == off["used"] == []
    first = _child(tmp_path / "on")
    second = _child(tmp_path / "on")
    assert first["hooked"] and second["hooked"]
    # every class of every calib module, ~70 of them, with 3 to 6 generated methods each
    assert len(off["codes"]) >= 60 and sum(map(len, off["codes"].values())) >= 200
    # the same code objects, byte for byte, compiled here or read back from the file
    assert first["codes"] == off["codes"] and second["codes"] == off["codes"]
    assert first["new"] == first["used"] and len(first["used"]) >= 40
    assert second["new"] == [] and second["used"] == first["used"]
    assert Path(first["path"]).is_relative_to(tmp_path / "on")
    entries = _entries(first["path"])
    assert sorted(entries) == first["used"]
    # (at least one text per method the classes have: dataclasses also compiles the methods a class
    # body defines itself, and discards them)
    assert sum(map(len, entries.values())) >= sum(map(len, off["codes"].values()))


def test_an_edited_class_leaves_no_stale_code_and_a_bad_file_is_ignored(tmp_path):
    first = _child(tmp_path)
    path = first["path"]
    entries = _entries(path)
    from importlib.util import MAGIC_NUMBER

    stale_text = "def __create_fn__():\n def f():\n  return 1\n return f"
    stale_code = compile(stale_text, "<string>", "exec")
    # calib.io.urdf's entry: a text no class makes any more, and one of its own lost (an edited
    # class): it compiles that one again and writes the texts its classes used, the stale one gone
    urdf = dict(entries["calib.io.urdf"], **{stale_text: stale_code})
    urdf.pop(next(iter(entries["calib.io.urdf"])))
    # calib.model.chain's: a text too many, nothing lost: not rewritten
    chain = dict(entries["calib.model.chain"], **{stale_text: stale_code})
    blob = {m: marshal.dumps(c) for m, c in entries.items()}
    blob.update({"calib.io.urdf": marshal.dumps(urdf), "calib.model.chain": marshal.dumps(chain),
                 "calib.io.export": b"not marshal"})
    Path(path).write_bytes(MAGIC_NUMBER + marshal.dumps(blob))
    again = _child(tmp_path)
    # (calib.io.export's entry unreadable: compiled as before)
    assert again["new"] == ["calib.io.export", "calib.io.urdf"] and again["codes"] == first["codes"]
    after = _entries(path)
    assert after["calib.io.urdf"].keys() == entries["calib.io.urdf"].keys()
    assert after["calib.io.export"].keys() == entries["calib.io.export"].keys()
    assert after["calib.model.chain"].keys() == chain.keys()
    # another interpreter's magic number, a cut file, or garbage: compiled as before, written anew
    whole = Path(path).read_bytes()
    for bad in (b"\0\0\r\n" + whole[4:], whole[:len(whole) // 2], b"not marshal"):
        Path(path).write_bytes(bad)
        run = _child(tmp_path)
        assert run["codes"] == first["codes"] and run["new"] == first["used"]
        assert _entries(path).keys() == entries.keys()


def test_the_file_is_as_private_as_the_bytecode_beside_it(tmp_path):
    run = _child(tmp_path, **{"CALIB_TEST_UMASK": "0"})
    mode = Path(run["path"]).stat().st_mode & 0o777
    assert mode == (PACKAGE / "dataclass_code.py").stat().st_mode & 0o666


def test_nothing_is_written_where_bytecode_is_not(tmp_path):
    run = _child(tmp_path, PYTHONDONTWRITEBYTECODE="1")
    assert run["hooked"] and run["new"] and not Path(run["path"]).exists()


def test_another_packages_dataclass_goes_to_the_builtin_exec():
    import calib.calibration.result  # noqa: F401 - (a calib module's classes: the hook is in place)

    used = {m: dict(c) for m, c in dc._used.items()}
    assert "calib.calibration.result" in used

    @dataclasses.dataclass(frozen=True)
    class Point:
        x: float
        y: float = 0.0

    assert dc._used == used and Point(1.0) == Point(1.0, 0.0) and repr(Point(2.0)).endswith("Point(x=2.0, y=0.0)")
    # compiled as dataclasses compiles it, without dataclass_code's __future__ annotations: the
    # field's annotations (strings here, as this file's), which typing and inspect read, not the
    # names of the values dataclasses passes ('_type_x')
    assert Point.__init__.__annotations__ == {"x": "float", "y": "float", "return": None}
    assert typing.get_type_hints(Point.__init__) == {"x": float, "y": float, "return": type(None)}
    assert str(inspect.signature(Point)) == "(x: 'float', y: 'float' = 0.0) -> None"
    assert dc.dataclass is dataclasses.dataclass


def test_every_calib_dataclass_takes_the_decorator_from_dataclass_code():
    """A module's classes are created when it is imported: the cache must be in place by then, so
    each module that makes a dataclass imports ``dataclass`` from calib.dataclass_code."""
    wrong = []
    for path in PACKAGE.rglob("*.py"):
        tree = ast.parse(path.read_text())
        decorated = any(isinstance(n, ast.ClassDef) and any("dataclass" in ast.unparse(d) for d in n.decorator_list)
                        for n in ast.walk(tree))
        ours = any(isinstance(n, ast.ImportFrom) and n.module == "calib.dataclass_code"
                   and "dataclass" in {a.name for a in n.names} for n in ast.walk(tree))
        direct = any(isinstance(n, ast.ImportFrom) and n.module == "dataclasses"
                     and "dataclass" in {a.name for a in n.names} for n in ast.walk(tree))
        if path.name != "dataclass_code.py" and (direct or (decorated and not ours)):
            wrong.append(str(path.relative_to(ROOT)))
    assert wrong == []
