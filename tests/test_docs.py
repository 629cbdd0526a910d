"""The documents' commands run and print what the documents show (issue 42).

README.md, docs/*.md and examples/*/README.md mark their runnable examples in the fence's info
string (the syntax is documented in docs/index.md, "How these pages stay true"):

- ```` ```sh run ````: a shell block run by bash (```` ```python run ````: by ``python``) in the
  document's working directory (a temporary folder holding copies of robots/, examples/ and
  scripts/, and calib/ and tests/ as links), with ``calib`` and ``python`` the interpreter running the
  tests and this checkout on ``PYTHONPATH``. Every
  command must exit 0 (``set -e``), or the block ends with the status ``exit=N`` names.
  The blocks of a document run as one test with the ``slow`` mark (the inner loop,
  ``-m "not slow"``, keeps the structure checks below); ``slow`` on a block: run in a fresh
  folder, as a test of its own. ``bench``: minutes
  of a benchmark: run only with ``--docs-bench``. ``needs=../shared/realdata``: skipped where
  the folder beside the repository is absent (``CALIB_DOCS_SHARED`` names it elsewhere; in a
  worktree, e.g. ``CALIB_DOCS_SHARED=/work/shared``); on a quick block it starts a part of the
  document that runs as a test of its own, in a fresh folder, up to the next block with
  ``needs=`` (the blocks before it run, and are checked, where the folder is absent).
  A line ``NAME=...`` assigning a shell variable stays set for the document's later blocks.
- ```` ```text output ````: the first fenced block after a run block with this mark is what the
  block prints (stdout and stderr together). Its lines must appear in that order among the printed
  lines, not necessarily next to each other (a note added later does not break a document); a
  line ``...`` is a reader's hint of lines left out; ``...`` inside a line matches any text.
  Numbers are compared to the digits shown (0.0088 matches 0.008812, not 0.0089), to ten
  significant digits at most, and any two below 1e-9 agree (round-off: a residual of
  2.9e-13 mm changes with the BLAS build); numbers
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
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "examples").glob("**/README.md"))]

#: What a run block's folder holds: copies (a command may write into them), and the package as a
#: link (``PYTHONPATH=.`` finds this checkout).
COPIED = ("robots", "examples", "scripts")
#: The folder beside the repository that ``needs=../shared/...`` blocks read (the real data sets);
#: CALIB_DOCS_SHARED names it where the checkout is elsewhere (a worktree).
SHARED = Path(os.environ.get("CALIB_DOCS_SHARED", ROOT.parent / "shared"))
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
#: A line that only sets a shell variable (``UR10=$(python -c ...)``, not ``PYTHONPATH=. python ...``).
_VARIABLE = re.compile(r"[A-Za-z_]\w*=(\$\(.*\)|\S*)")


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


#: Below this magnitude a number is round-off (a solved target's residual of 2.9e-13 mm, 4e-16 rad):
#: its digits change with the BLAS build and the order of sums, so any two such numbers agree.
ROUND_OFF = 1e-9
#: Beyond ten significant digits the last places are round-off too (a YAML's 0.161364677509343).
RELATIVE = 1e-10


def _agree(shown: str, printed: str) -> bool:
    """The printed number is the shown one: to the digits shown, to ten significant digits at
    most, or both round-off."""
    s, p = float(shown), float(printed)
    if abs(s) < ROUND_OFF and abs(p) < ROUND_OFF:
        return True
    return abs(p - s) <= max(_tolerance(shown), RELATIVE * abs(s))


def _numbers_agree(shown: list[str], printed: tuple, timed: list[bool]) -> bool:
    return all(t or _agree(s, p) for s, p, t in zip(shown, printed, timed))


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
        if t or _agree(s, p):
            return s
        # the printed text where the shown one is as precise (give or take the trailing zero a %g
        # format drops): a number padded to the shown digits was never printed
        return p if _significant(p) <= _significant(s) + 1 else _format_like(s, float(p))

    return re.sub(rf"\.\.\.|{_NUMBER}", repl, shown)


def _significant(number: str) -> int:
    """The significant digits of a number as written: 0.0088 -> 2, 3.140e-13 -> 4, 25 -> 2."""
    digits = re.sub(r"\D", "", number.lower().partition("e")[0])
    return max(len(digits.lstrip("0")), 1)


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
    """``tmp/repo``: the copies and the links; ``tmp/shared`` links the folder beside the
    repository (``../shared``: the real data sets) where it exists."""
    path = tmp / "repo"
    for name in COPIED:
        shutil.copytree(ROOT / name, path / name, ignore=shutil.ignore_patterns("__pycache__"))
    (path / "calib").symlink_to(ROOT / "calib")
    (path / "tests").symlink_to(ROOT / "tests")      # (scripts/bench_bag.py writes bags with its helpers)
    if SHARED.is_dir():
        (tmp / "shared").symlink_to(SHARED)
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
        variables += [l for l in b.body if _VARIABLE.fullmatch(l)]
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
    """(document, the ordinals of its run blocks a test runs): the quick blocks of a document
    together, each slow or bench block alone. Ordinals, not line numbers: --update-docs moves
    the lines of a document while its other blocks wait to run."""
    for path in DOCS:
        runs = [b for b in parse_blocks(path) if "run" in b.marks]
        name = str(path.relative_to(ROOT))
        parts, part = [], None      # the quick blocks; a block with needs= starts a part of its own
        for k, b in enumerate(runs):
            if {"slow", "bench"} & set(b.marks):
                continue
            if part is None or "needs" in b.marks:
                part = []
                parts.append(part)
            part.append(k)
        for part in parts:      # (slow too: they run the command line, tens of processes; CI runs them)
            first = runs[part[0]]
            yield pytest.param(path, tuple(part), id=f"{name}:{first.line}" if "needs" in first.marks else name,
                               marks=pytest.mark.slow)
        for k, b in enumerate(runs):
            if "bench" in b.marks:
                yield pytest.param(path, (k,), id=f"{name}:{b.line}", marks=pytest.mark.bench)
            elif "slow" in b.marks:
                yield pytest.param(path, (k,), id=f"{name}:{b.line}", marks=pytest.mark.slow)


@pytest.mark.parametrize("path, selected", list(_cases()))
def test_document_commands_print_what_the_document_shows(path, selected, tmp_path, shims, request):
    blocks = parse_blocks(path)
    runs = [b for b in blocks if "run" in b.marks]
    chosen = [runs[k] for k in selected]
    marks = chosen[0].marks
    if "bench" in marks and not request.config.getoption("--docs-bench"):
        pytest.skip("a benchmark of minutes: --docs-bench runs it")
    needed = Path(str(marks.get("needs", "")))
    if needed.parts[:2] == ("..", "shared"):
        needed = SHARED.joinpath(*needed.parts[2:])
    if "needs" in marks and not (needed if needed.is_absolute() else ROOT / needed).exists():
        pytest.skip(f"needs {marks['needs']} (beside the repository), absent here")
    _check_document(path, blocks, chosen, _workdir(tmp_path), shims, request.config.getoption("--update-docs"))


# ====================================================================== the comparison itself
PRINTED = """Calibration: SEARCH-LM, parameter set 'base' (30 identified of 37), converged
  5 LM iterations in all (every fit of the calibration), 1 rounds, 102.8 ms
  note: something added later
validation rows, after         200 |     0.0324    0.0350    0.0856    0.0063  |   3.341e-03  3.651e-03
predicted RMS error (Cramer-Rao): position 0.01072 mm, orientation 0.000423 rad
wrote /tmp/x/calibrated.urdf"""


def test_shown_lines_match_in_order_numbers_to_the_digits_shown():
    shown = ["Calibration: SEARCH-LM, parameter set 'base' (30 identified of 37), converged",
             "  5 LM iterations in all (every fit of the calibration), 1 rounds, 9.1 ms",   # a time
             "...",
             "validation rows, after 200 | 0.032 0.035 0.086 0.006 | 3.34e-03 3.65e-03",    # fewer digits
             "predicted RMS error (Cramer-Rao): position 0.0107 mm, orientation 4.2e-4 rad",
             "wrote .../calibrated.urdf"]
    assert compare(shown, PRINTED) == ([], shown)


def test_the_update_takes_the_printed_text_unless_the_page_shows_fewer_digits():
    printed = "largest joint change joint1 0.276 deg, joint2 -3.105912923 deg, joint3 0.008812 deg, r 3.14e-07 mm"
    shown = "largest joint change joint1 0.1175 deg, joint2 -3.10074777 deg, joint3 0.0071 deg, r 2e-07 mm"
    problems, updated = compare([shown], printed)
    assert problems and updated == ["largest joint change joint1 0.276 deg, joint2 -3.105912923 deg, "
                                    "joint3 0.0088 deg, r 3e-07 mm"]


@pytest.mark.parametrize("shown", [
    "predicted RMS error (Cramer-Rao): position 0.01072 mm, orientation 0.000424 rad",  # one digit
    "predicted RMS error (Cramer-Rao): position 0.0108 mm, orientation 0.000423 rad",   # rounded wrong
    "validation rows, after 200 | 0.0324 0.0350 0.0856 0.0063 | 3.341e-03 3.652e-03",
    "predicted RMS error (Cramer-Rao): position 0.01072 mm, orientation 0.000423 rad RMS",  # text
    "Calibration: SEARCH-LM, parameter set 'base' (31 identified of 37), converged"])
def test_a_one_digit_change_fails_and_the_update_restores_it(shown):
    problems, updated = compare([shown], PRINTED)
    assert len(problems) == 1
    if not shown.endswith("RMS"):             # same text: the update takes the printed figure
        assert compare(updated, PRINTED) == ([], updated)
        assert updated != [shown]


def test_order_counts_and_every_shown_line_must_be_found():
    lines = PRINTED.splitlines()
    assert compare([lines[3], lines[0]], PRINTED)[0]           # out of order
    assert compare([lines[0], lines[0]], PRINTED)[0]           # once printed, once matched
    assert compare(["a line nobody printed"], PRINTED)[0]


def test_number_forms():
    assert _tolerance("0.0088") == pytest.approx(5e-5) and _tolerance("4.0e-4") == pytest.approx(5e-6)
    assert _tolerance("25") == pytest.approx(0.5)
    assert _format_like("4.0e-4", 4.27e-4) == "4.3e-4" and _format_like("0.0100", 0.01234) == "0.0123"
    assert _format_like("1.2e-05", 3.456e-6) == "3.5e-06"
    assert _significant("0.0088") == 2 and _significant("-3.140e-13") == 4 and _significant("0") == 1
    # digits inside names are text: theta1 stays theta1, v_x@M3 stays v_x@M3
    assert compare(["theta1 -0.0035"], "theta1 -0.003507")[0] == []
    assert compare(["theta2 -0.0035"], "theta1 -0.003507")[0]
    # round-off agrees with round-off, and beyond ten significant digits; a real figure does not
    assert compare(["residual 2.88e-13 mm, 4.25e-16 rad"], "residual 1.67e-13 mm, 3.04e-16 rad")[0] == []
    assert compare(["z: 0.161364677509343"], "z: 0.161364677509477")[0] == []
    assert compare(["z: 0.161364677509343"], "z: 0.161364677609343")[0]
    assert compare(["residual 2.88e-13 mm"], "residual 2.88e-08 mm")[0]


# ====================================================================== the documents' structure
def _runnable_lines() -> set[str]:
    return {l.strip() for p in DOCS for b in parse_blocks(p) if "run" in b.marks for l in b.body}


def test_every_workflow_command_of_the_readme_is_a_runnable_line():
    """The README's table of workflows: each command (inline code starting with calib) is a line
    of a run block of README.md or docs/, run by this test as a user types it."""
    readme = (ROOT / "README.md").read_text()
    table = [l for l in readme.splitlines() if l.startswith("| ")]
    commands = [c for l in table for c in re.findall(r"`(calib [^`]+)`", l)]
    assert len(commands) >= 8
    missing = [c for c in commands if c not in _runnable_lines()]
    assert not missing, missing


def test_readme_is_short_and_opens_with_the_setup_commands():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 200
    sh = [b for b in parse_blocks(ROOT / "README.md") if b.lang == "sh" and "run" not in b.marks]
    assert [b.body for b in sh[:2]] == [[c] for c in SETUP_COMMANDS]


def test_the_index_lists_every_page():
    """docs/index.md's contents link every page of docs/ (a page added without it is found by
    no reader of the index)."""
    text = (ROOT / "docs" / "index.md").read_text()
    contents = text[text.index("## Contents"):text.index("## How these pages stay true")]
    linked = set(re.findall(r"\]\(([\w-]+\.md)\)", contents))
    assert linked == {p.name for p in (ROOT / "docs").glob("*.md")} - {"index.md"}


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but - and _ dropped, spaces to -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
    return {_slug(m) for m in re.findall(r"^#+ (.*)$", text, flags=re.M)}


def test_relative_links_and_anchors_resolve():
    """Every relative link of the documents names a file that exists, and its #anchor a heading
    of that file (the check a documentation site's strict build would make)."""
    broken = []
    for path in DOCS:
        text = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue
            file, _, anchor = target.partition("#")
            dest = (path.parent / file).resolve() if file else path
            if not dest.exists():
                broken.append(f"{path.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                broken.append(f"{path.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, "\n".join(broken)


#: Scripts named in the documents' prose whose figures no block runs, and why.
NOT_RUN = {
    "bench_selection.py": "an hour of computing; the figures are in its docstring, not quoted in the pages",
    "bench_compliance.py": "named for what it repeats over seeds; the page's figures come from its run blocks",
    "make_tracker_example.py": "writes examples/tracker/, which test_make_tracker_example_writes_the_bundled_files checks",
    "convert_figaroh_tiago.py": "the converter of the real TIAGo data: no figure",
    "reproduce_paper.py": "writes docs/reproduction.md, whose tables test_reproduction_tables_are_what_the_script_writes checks",
    "render_certificate.py": "renders a certificate to PNG and PDF in headless Chromium, which "
                             "tests/report/test_report_print.py drives; no figure",
}


def test_scripts_named_in_prose_are_run_by_a_block():
    """A figure quoted from a script comes from a block that runs it on the same page (its output
    block shows the figure), unless NOT_RUN says why not. The development page lists them all."""
    unrun = []
    for path in DOCS:
        if path.name in ("development.md", "reproduction.md"):
            continue
        blocks = parse_blocks(path)
        run = " ".join(l for b in blocks if "run" in b.marks for l in b.body)
        prose = re.sub(r"^```.*?^```", "", path.read_text(), flags=re.S | re.M)
        for script in sorted(set(re.findall(r"scripts/(\w+\.py)", prose))):
            if f"scripts/{script}" not in run and script not in NOT_RUN:
                unrun.append(f"{path.relative_to(ROOT)}: scripts/{script}")
    assert not unrun, unrun


# ====================================================================== docs/reproduction.md
#: The sections of docs/reproduction.md that do not depend on the convergence grid: written again
#: by the script with the smallest grid, they must read as the page does (timings aside).
REPRODUCTION_SECTIONS = ("## Tables 6-7", "## Table 9", "## Tables 10-11")


def _section(text: str, heading: str) -> list[str]:
    start = text.index(heading)
    end = min(i for i in (text.find("\n## ", start + 1), text.find("\n### Figure 5", start + 1), len(text)) if i > 0)
    return text[start:end].splitlines()


@pytest.mark.slow
def test_reproduction_tables_are_what_the_script_writes(tmp_path):
    """docs/reproduction.md is written by scripts/reproduce_paper.py: its Tables 6-7, 9 and 10-11
    (the calibrations, the Cramer-Rao bound and the Monte Carlo spread; not the convergence study,
    which takes minutes) are what the script writes today, to the digits shown."""
    out = tmp_path / "docs"
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / "reproduce_paper.py"), "--grid", "2", "--workers", "1",
                           "--sweep", "0", "--default-grid", "0", "--sample-grid", "0", "--paper-variants-grid", "0",
                           "--out", str(out)], cwd=tmp_path, capture_output=True, text=True, timeout=TIMEOUT_S,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), MPLBACKEND="Agg"))
    assert proc.returncode == 0, proc.stderr
    page, written = (ROOT / "docs" / "reproduction.md").read_text(), (out / "reproduction.md").read_text()
    for heading in REPRODUCTION_SECTIONS:
        shown, printed = _section(page, heading), _section(written, heading)
        assert len(shown) == len(printed), heading
        problems, _ = compare(shown, "\n".join(printed))
        assert not problems, "\n".join(problems)
