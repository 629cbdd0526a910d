"""The documents' commands run and print what the documents show (issue 42).

README.md and docs/*.md mark their runnable examples in the fence's info string (the syntax is
documented in docs/index.md, "How these pages stay true"):

- ```` ```sh run ```` (or ```` ```python run ````, run by ``python``): a shell block run by bash in the document's working directory (a temporary
  folder holding copies of robots/, examples/ and scripts/, and calib/ as a link), with ``calib``
  and ``python`` the interpreter running the tests and this checkout on ``PYTHONPATH``. Every
  command must exit 0 (``set -e``), or the block ends with the status ``exit=N`` names.
  ``slow``: run in a fresh folder, as a test of its own with the ``slow`` mark. ``bench``: minutes
  of a benchmark or data outside the repository (../shared): run only with ``--docs-bench``.
  A line ``NAME=...`` assigning a shell variable stays set for the document's later blocks.
- ```` ```text output ````: the first fenced block after a run block with this mark is what the
  block prints (stdout and stderr together). Its lines must appear in that order among the printed
  lines, not necessarily next to each other (a note added later does not break a document); a
  line ``...`` is a reader's hint of lines left out; ``...`` inside a line matches any text.
  Numbers are compared to the digits shown (0.0088 matches 0.008812, not 0.0089); numbers
  followed by a unit of time (ms, s, min) are not compared, and the working directory's path
  reads as ``.``.
- ```` ```csv file=NAME ````: the block's text is written to NAME in the working directory
  before the blocks that follow it run.

``python -m pytest tests/test_docs.py --update-docs`` rewrites the numbers of every output block
from what the commands print now (to the digits shown; an empty output block receives the whole
output); a shown line whose text no printed line has any more is reported, for a person to mend.
"""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

#: What a run block's folder holds: copies (a command may write into them), and the package as a
#: link (``PYTHONPATH=.`` finds this checkout).
COPIED = ("robots", "examples", "scripts")
#: The seconds one run block may take.
TIMEOUT_S = 900
#: The setup commands the README opens with: shown to be typed on a fresh machine (they install
#: the package), not run by this test; tests/cli/test_commands.py checks them and .ci/run.
SETUP_COMMANDS = (
    "pip install -e . && calib calibrate robots/brtirus0707a/brtirus0707a.urdf "
    "examples/brtirus0707a/measurements.csv -o calibrated.urdf",
    'pip install -e ".[test]" && python -m pytest -q',
)

_FENCE = re.compile(r"^(?P<indent> *)(?P<ticks>`{3,})(?P<info>[^`]*)$")
#: A number as the documents and calib write them; not a digit inside a name (theta1, v_x@M3).
_NUMBER = r"(?<![\w.])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\d])"
_TIME_UNIT = re.compile(r"\s?(?:ms|s|min)(?![\w/])")
_VARIABLE = re.compile(r"^[A-Za-z_]\w*=\S")


# ====================================================================== the blocks of a document
@dataclass(eq=False)
class Block:
    path: Path
    line: int                      # 1-based line of the opening fence
    lang: str
    marks: dict                    # info tokens: run, output, slow, bench -> True; file, exit -> value
    body: list[str]
    first: int                     # 0-based index of the first content line in the document
    output: "Block | None" = field(default=None, repr=False)

    @property
    def where(self) -> str:
        return f"{self.path.relative_to(ROOT)}:{self.line}"


def parse_blocks(path: Path, text: str | None = None) -> list[Block]:
    """Every fenced block of a Markdown file, with its info-string marks; each run block gets the
    first output block that follows it (before the next run block)."""
    lines = (path.read_text() if text is None else text).splitlines()
    blocks, i = [], 0
    while i < len(lines):
        m = _FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, ticks = m["indent"], m["ticks"]
        words = m["info"].split()
        lang = words[0] if words else ""
        marks = {}
        for w in words[1:]:
            key, _, value = w.partition("=")
            marks[key] = value if value else True
        j = i + 1
        while j < len(lines) and not re.match(rf"^{indent}{ticks}`*\s*$", lines[j]):
            j += 1
        body = [l[len(indent):] if l.startswith(indent) else l.lstrip() for l in lines[i + 1:j]]
        blocks.append(Block(path, i + 1, lang, marks, body, i + 1))
        i = j + 1
    last_run = None
    for b in blocks:
        if "run" in b.marks:
            last_run = b
        elif "output" in b.marks:
            if last_run is None or last_run.output is not None:
                raise AssertionError(f"{b.where}: an output block with no run block before it")
            last_run.output = b
    return blocks


# ====================================================================== comparing output
def _pattern(shown: str) -> tuple[re.Pattern, list[str], list[bool]]:
    """A regular expression for the printed line a shown line stands for: its text as is
    (whitespace runs as any whitespace), ``...`` as any text, each number as any number (captured,
    with its shown form and whether it is a time, which is not compared)."""
    parts, numbers, timed, pos = [], [], [], 0
    for m in re.finditer(rf"\.\.\.|{_NUMBER}", shown):
        parts.append(_text(shown[pos:m.start()]))
        if m.group() == "...":
            parts.append(".*?")
        else:
            parts.append(f"({_NUMBER})")
            numbers.append(m.group())
            timed.append(bool(_TIME_UNIT.match(shown, m.end())))
        pos = m.end()
    parts.append(_text(shown[pos:]))
    return re.compile("".join(parts)), numbers, timed


def _text(s: str) -> str:
    return r"\s+".join(re.escape(w) for w in re.split(r"\s+", s)) if s.strip() else (r"\s+" if s else "")


def _tolerance(shown: str) -> float:
    """Half a unit of the last digit shown: 0.0088 -> 5e-5, 4.0e-4 -> 5e-6, 25 -> 0.5."""
    mantissa, _, exponent = shown.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (int(exponent or 0) - decimals) * (1 + 1e-9)


def _numbers_agree(shown: list[str], printed: tuple, timed: list[bool]) -> bool:
    return all(t or abs(float(p) - float(s)) <= _tolerance(s) for s, p, t in zip(shown, printed, timed))


def _matches(pattern, printed_line: str):
    return pattern.fullmatch(printed_line.strip())


def compare(shown_lines: list[str], printed: str) -> tuple[list[str], list[str]]:
    """(problems, the shown lines updated): each shown line, in order, must match a later printed
    line, its numbers to the digits shown. The update takes the printed numbers (at the digits
    shown) of the first later printed line with the same text."""
    out = printed.splitlines()
    problems, updated, k = [], [], 0
    for shown in shown_lines:
        if not shown.strip() or shown.strip() == "...":
            updated.append(shown)
            continue
        pattern, numbers, timed = _pattern(shown.strip())
        hit = same_text = None
        for j in range(k, len(out)):
            m = _matches(pattern, out[j])
            if m is None:
                continue
            if same_text is None:
                same_text = (j, m)
            if _numbers_agree(numbers, m.groups(), timed):
                hit = j
                break
        if hit is not None:
            updated.append(shown)
            k = hit + 1
        elif same_text is not None:
            j, m = same_text
            problems.append(f"shown:   {shown.strip()}\n  printed: {out[j].strip()}")
            updated.append(_renumber(shown, numbers, m.groups(), timed))
            k = j + 1
        else:
            problems.append(f"shown:   {shown.strip()}\n  printed: no line with this text "
                            f"(after printed line {k})")
            updated.append(shown)
    return problems, updated


def _renumber(shown: str, numbers: list[str], printed: tuple, timed: list[bool]) -> str:
    """The shown line with each compared number replaced by the printed one at the shown digits."""
    it = iter(zip(numbers, printed, timed))

    def repl(m):
        if m.group() == "...":
            return m.group()
        s, p, t = next(it)
        return s if t or abs(float(p) - float(s)) <= _tolerance(s) else _format_like(s, float(p))

    return re.sub(rf"\.\.\.|{_NUMBER}", repl, shown)


def _format_like(shown: str, value: float) -> str:
    mantissa, e, exponent = shown.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    if e:
        text = f"{value:.{decimals}e}"
        m, _, x = text.partition("e")
        x = int(x)
        text = f"{m}e{'-' if x < 0 else ('+' if exponent.startswith('+') else '')}" \
               f"{abs(x):0{len(exponent.lstrip('+-'))}d}"
    else:
        text = f"{value:.{decimals}f}"
        if "." in mantissa and not mantissa.partition(".")[2]:
            text += "."
    return ("+" + text) if shown.startswith("+") and value >= 0 else text


# ====================================================================== running a document
@pytest.fixture(scope="module")
def shims(tmp_path_factory) -> Path:
    """``calib`` and ``python`` as the interpreter running the tests, on this checkout."""
    d = tmp_path_factory.mktemp("bin")
    for name, run in (("calib", f'"{sys.executable}" -m calib'), ("python", f'"{sys.executable}"')):
        p = d / name
        p.write_text(f'#!/bin/sh\nexec {run} "$@"\n')
        p.chmod(0o755)
    return d


def _workdir(tmp: Path) -> Path:
    """``tmp/repo``: the copies and the package link; ``tmp/shared`` links the folder beside the
    repository (``../shared``: the real data sets) where it exists."""
    path = tmp / "repo"
    for name in COPIED:
        shutil.copytree(ROOT / name, path / name, ignore=shutil.ignore_patterns("__pycache__"))
    (path / "calib").symlink_to(ROOT / "calib")
    if (ROOT.parent / "shared").is_dir():
        (tmp / "shared").symlink_to(ROOT.parent / "shared")
    return path


def _run(block: Block, workdir: Path, shims: Path, variables: list[str]) -> tuple[int, str]:
    expected = int(block.marks.get("exit", 0))
    body = block.body
    if block.lang == "python":
        body = ["python - <<'CALIB_DOCS_EOF'", *body, "CALIB_DOCS_EOF"]
    script = "\n".join([*variables, "" if expected else "set -e", *body, ""])
    env = dict(os.environ, PATH=f"{shims}{os.pathsep}{os.environ.get('PATH', '')}",
               PYTHONPATH=os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]),
               PYTHONUNBUFFERED="1", MPLBACKEND="Agg", COLUMNS="100")
    proc = subprocess.run(["bash", "-c", script], cwd=workdir, env=env, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, timeout=TIMEOUT_S)
    printed = proc.stdout.replace(str(workdir) + os.sep, "").replace(str(workdir), ".")
    return proc.returncode, printed


def _check_document(path: Path, blocks: list[Block], selected, workdir: Path, shims: Path,
                    update: bool) -> None:
    """Write the file blocks and run the selected run blocks in order; compare (or update) their
    output blocks. Raises with every problem of the document."""
    problems, edits, variables = [], {}, []
    for b in blocks:
        if "file" in b.marks:
            target = workdir / b.marks["file"]
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text("\n".join(b.body) + "\n")
            continue
        if "run" not in b.marks:
            continue
        if b in selected:
            code, printed = _run(b, workdir, shims, variables)
            expected = int(b.marks.get("exit", 0))
            if code != expected:
                problems.append(f"{b.where}: exit status {code}, expected {expected}; printed:\n{printed}")
            elif b.output is not None:
                if update and not any(l.strip() for l in b.output.body):
                    edits[b.output] = printed.rstrip("\n").splitlines()
                else:
                    found, updated = compare(b.output.body, printed)
                    if found:
                        problems.append(f"{b.output.where}: the output shown differs from what "
                                        f"{b.where} prints:\n  " + "\n  ".join(found))
                        if updated != b.output.body:
                            edits[b.output] = updated
        variables += [l for l in b.body if _VARIABLE.match(l)]
    if update and edits:
        _rewrite(path, edits)
        problems = [p for p in problems if "no line with this text" in p]
    if problems:
        pytest.fail("\n\n".join(problems), pytrace=False)


def _rewrite(path: Path, edits: dict) -> None:
    lines = path.read_text().splitlines(keepends=True)
    for block in sorted(edits, key=lambda b: -b.first):
        indent = re.match(r" *", lines[block.line - 1]).group()
        new = [f"{indent}{l}\n" if l else "\n" for l in edits[block]]
        lines[block.first:block.first + len(block.body)] = new
    path.write_text("".join(lines))


def _cases():
    for path in DOCS:
        blocks = parse_blocks(path)
        runs = [b for b in blocks if "run" in b.marks]
        name = str(path.relative_to(ROOT))
        quick = [b for b in runs if not {"slow", "bench"} & set(b.marks)]
        if quick:
            yield pytest.param(path, tuple(quick), id=name)
        for b in runs:
            if "bench" in b.marks:
                yield pytest.param(path, (b,), id=f"{name}:{b.line}", marks=pytest.mark.bench)
            elif "slow" in b.marks:
                yield pytest.param(path, (b,), id=f"{name}:{b.line}", marks=pytest.mark.slow)


@pytest.mark.parametrize("path, selected", list(_cases()))
def test_document_commands_print_what_the_document_shows(path, selected, tmp_path, shims, request):
    marks = selected[0].marks
    if "bench" in marks and not request.config.getoption("--docs-bench"):
        pytest.skip("a benchmark of minutes: --docs-bench runs it")
    if "needs" in marks and not (ROOT / marks["needs"]).exists():
        pytest.skip(f"needs {marks['needs']} (beside the repository), absent here")
    blocks = parse_blocks(path)
    chosen = [b for b in blocks if any(b.where == s.where for s in selected)]
    _check_document(path, blocks, chosen, _workdir(tmp_path), shims, request.config.getoption("--update-docs"))
