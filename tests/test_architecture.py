"""The package's layering (ARCHITECTURE.md): every wing imports only from itself and the wings
below it, and no modules import each other in a circle. Read from the source (every import
statement, those inside functions too), so a lazy import cannot hide an upward dependency."""
from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "calib"

#: The wings and their levels from the bottom up; the package's base modules (errors, checks,
#: ...) are level 0. Wings of one level are peers: neither imports the other.
LEVELS = {"model": 1, "solvers": 2, "io": 3, "calibration": 4, "design": 5, "compensation": 5, "report": 5,
          "cli": 6}
WINGS = tuple(LEVELS)
#: Modules above every wing: the console entry point starts the CLI.
TOP = {"calib._entry", "calib.__main__"}


def _module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE.parent).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" else rel.parts
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path, name: str, known: set[str]) -> set[str]:
    """The calib modules ``path`` imports (``from calib.x import y`` counts calib.x.y when that
    is a module), at any depth but those under ``if TYPE_CHECKING:``."""
    is_pkg = path.name == "__init__.py"
    out = set()
    tree = ast.parse(path.read_text())
    # imports for type annotations only (``if TYPE_CHECKING:``) are no dependency at run time
    typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and getattr(block.test, "id", getattr(block.test, "attr", None)) == "TYPE_CHECKING"
                   for stmt in block.body for n in ast.walk(stmt)}
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("calib")}
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = name.split(".") if is_pkg else name.split(".")[:-1]
                base = base[:len(base) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if not mod.startswith("calib"):
                continue
            subs = {f"{mod}.{a.name}" for a in node.names} & known
            out |= subs or {mod}
    return {m for m in out if m in known and m != name}


def _rank(module: str) -> int:
    if module in TOP:
        return max(LEVELS.values()) + 1
    parts = module.split(".")
    if len(parts) > 1 and parts[1] in WINGS:
        return LEVELS[parts[1]]
    return 0


def _wing(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in WINGS else ""


def _graph() -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    # calib/__init__.py loads the public names lazily by name (PEP 562), not by import statements
    return {m: _imports(p, m, known) - {"calib"} for m, p in mods.items()}


def test_every_module_is_in_a_wing_or_the_base():
    stray = [m for m in _modules() if m.count(".") >= 2 and m.split(".")[1] not in WINGS]
    assert stray == []
    assert {m.split(".")[1] for m in _modules() if m.count(".") >= 1} >= set(WINGS)


def test_no_upward_import():
    upward = sorted(f"{m} -> {d}" for m, deps in _graph().items() for d in deps if _rank(d) > _rank(m))
    assert upward == []


def test_no_import_between_peer_wings():
    """design/, compensation/ and report/ stand side by side above calibration/."""
    across = sorted(f"{m} -> {d}" for m, deps in _graph().items() for d in deps
                    if _rank(d) == _rank(m) > 0 and _wing(d) != _wing(m))
    assert across == []


def test_no_import_circle():
    graph = _graph()
    index, low, stack, on, circles = {}, {}, [], set(), []

    def visit(v):        # Tarjan's strongly connected components
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    assert circles == []


def test_the_checker_sees_an_upward_import(tmp_path):
    """The test above can fail: a model module importing the CLI is found."""
    known = {"calib.model.robot", "calib.cli.main"}
    f = tmp_path / "robot.py"
    f.write_text("def f():\n    from calib.cli.main import main\n")
    deps = _imports(f, "calib.model.robot", known)
    assert deps == {"calib.cli.main"} and _rank("calib.cli.main") > _rank("calib.model.robot")


def test_no_module_exceeds_600_lines():
    long = sorted(f"{m}: {n}" for m, p in _modules().items() if (n := len(p.read_text().splitlines())) > 600)
    assert long == []
