"""The model wing imports no file reading or writing: nothing under calib/model imports
calib.io (the URDF it was read from travels as ``RobotModel.source``, declared there as a
protocol), and calib/checks.py names no domain type."""
from __future__ import annotations

import ast
from pathlib import Path

CALIB = Path(__file__).resolve().parents[2] / "calib"


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at the top or inside a function."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            out.add(node.module)
    return out


def test_model_imports_no_io():
    offending = {f"{p.name}: {m}" for p in (CALIB / "model").glob("*.py") for m in _imports(p)
                 if m == "calib.io" or m.startswith("calib.io.")}
    assert not offending


def test_checks_know_no_domain_types():
    assert {m for m in _imports(CALIB / "checks.py") if m.startswith("calib.")} == {"calib.errors"}
    text = (CALIB / "checks.py").read_text(encoding="utf-8")
    assert "RobotModel" not in text and "Measurements" not in text
