"""The package's layering (ARCHITECTURE.md): every wing imports only from itself and the wings
below it, and no modules import each other in a circle. Read from the source (every import
statement, those inside functions too), so a lazy import cannot hide an upward dependency."""
from __future__ import annotations

import ast
from functools import lru_cache
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


@lru_cache(maxsize=None)
def _tree(path: Path) -> ast.Module:
    """The module's syntax tree, parsed once for all the checks (read only)."""
    return ast.parse(path.read_text())


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PACKAGE.rglob("*.py")}


def _imports(path: Path, name: str, known: set[str], typing: bool = False) -> set[str]:
    """The calib modules ``path`` imports (``from calib.x import y`` counts calib.x.y when that
    is a module), at any depth; those under ``if TYPE_CHECKING:`` only with ``typing``."""
    is_pkg = path.name == "__init__.py"
    out = set()
    tree = _tree(path)
    # imports for type annotations only (``if TYPE_CHECKING:``) are no dependency at run time
    typing_only = {id(n) for block in ast.walk(tree) if isinstance(block, ast.If)
                   and getattr(block.test, "id", getattr(block.test, "attr", None)) == "TYPE_CHECKING"
                   for stmt in block.body for n in ast.walk(stmt)}
    for node in ast.walk(tree):
        if id(node) in typing_only and not typing:
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


@lru_cache(maxsize=None)
def _graph(typing: bool = False) -> dict[str, set[str]]:
    """Module -> the calib modules it imports (with ``typing``, its TYPE_CHECKING imports too);
    built once per kind for all the checks (read only)."""
    mods = _modules()
    known = set(mods)
    # calib/__init__.py loads the public names lazily by name (PEP 562), not by import statements
    return {m: _imports(p, m, known, typing) - {"calib"} for m, p in mods.items()}


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
    """No circle, TYPE_CHECKING imports included: a circle closed for the type checker only is
    still two modules that cannot be read apart."""
    graph = _graph(typing=True)
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


def test_no_function_exceeds_100_lines():
    long = []
    for m, p in _modules().items():
        for node in ast.walk(_tree(p)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and node.end_lineno - node.lineno >= 100:
                long.append(f"{m}.{node.name}: {node.end_lineno - node.lineno + 1}")
    assert sorted(long) == []


def test_no_folder_exceeds_16_modules_or_5000_lines():
    """Each folder of the package, its own modules (not its subfolders'): a wing a reader can hold."""
    big = []
    for folder in [PACKAGE, *(d for d in PACKAGE.rglob("*") if d.is_dir() and d.name != "__pycache__")]:
        mods = [p for p in folder.glob("*.py") if p.name != "__init__.py"]
        lines = sum(len(p.read_text().splitlines()) for p in mods)
        if len(mods) > 16 or lines > 5000:
            big.append(f"{folder.relative_to(PACKAGE.parent)}: {len(mods)} modules, {lines} lines")
    assert big == []


#: Private names that one module may import from another (at most a handful, each with a reason).
PRIVATE_IMPORTS_ALLOWED: set[tuple[str, str]] = set()


def test_no_private_name_is_imported_across_modules():
    """A leading underscore says "mine": another module importing it reaches into a module's
    inside (dunders such as __version__ are public)."""
    found = []
    for m, p in _modules().items():
        for node in ast.walk(_tree(p)):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("calib"):
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__") \
                            and (node.module, a.name) not in PRIVATE_IMPORTS_ALLOWED:
                        found.append(f"{m}: {node.module}.{a.name}")
    assert sorted(found) == []


def test_frozen_instances_are_written_in_post_init_only():
    """``object.__setattr__`` (the way around a frozen dataclass) only inside ``__post_init__``;
    values computed from an immutable instance are cached properties, not writes into it."""
    found = []
    for m, p in _modules().items():
        tree = _tree(p)
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)) or fn.name == "__post_init__":
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Call) and ast.unparse(node.func) == "object.__setattr__":
                    found.append(f"{m}.{fn.name}")
                if isinstance(node, ast.Subscript) and isinstance(node.ctx, ast.Store) \
                        and ast.unparse(node.value).endswith(".__dict__"):
                    found.append(f"{m}.{fn.name}")
    assert sorted(set(found)) == []


def test_module_level_caches_are_memos():
    """Module-level tables that a function fills are :class:`calib.memo.Memo` instances, owned
    by ``calib.memo.MEMOS`` (one ``clear()``): no bare dict, list or OrderedDict filled at run
    time, no functools cache. (The CLI's module state is a command's run state, reset by each
    ``main()``: the signal received late, the files written.)"""
    found = []
    for m, p in _modules().items():
        if _wing(m) == "cli":
            continue
        tree = _tree(p)
        for node in tree.body:
            target = node.targets[0] if isinstance(node, ast.Assign) else node.target if isinstance(node, ast.AnnAssign) else None
            value = getattr(node, "value", None)
            if target is None or value is None:
                continue
            text = ast.unparse(value)
            if text in ("{}", "[]", "dict()", "list()", "set()", "OrderedDict()") or text.startswith("[None"):
                found.append(f"{m}.{ast.unparse(target)}")
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                for d in node.decorator_list:
                    if any(k in ast.unparse(d) for k in ("lru_cache", "functools.cache", "cache")) \
                            and "cached_property" not in ast.unparse(d):
                        found.append(f"{m}.{node.name} (@{ast.unparse(d)})")
    assert sorted(found) == []
