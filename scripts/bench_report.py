"""Cost of the report (issue 27 item 3, issue 26 items 4-5): what ``--report --html --plots`` add
to ``calib calibrate``, beside the figures measured before this work.

Prints, each a median of ``--repeats`` runs of whole ``calib`` processes (interleaved, bytecode
cached as after an install, one BLAS thread), wall and CPU time (user + system of the process):

0. The report stage alone, in a fresh process after ``calibrate()`` of the bundled example:
   CPU and wall time of importing the plotting and template code, drawing the plots, building
   the JSON report and the HTML page (with ``--compare CHECKOUT``: the same for that checkout,
   interleaved) — the figure least disturbed by other load on the machine.
1. The bundled example (BRTIRUS0707A, 300 rows): ``calib calibrate`` alone and with
   ``--report R.json --html R.html --plots DIR``; the difference. Before: 0.57 s -> 4.4 s.
2. ``--rows`` simulated rows (default 100,000; the bundled robot, pose data): the same two runs,
   the difference, peak memory (max RSS) of each, and the sizes of the JSON report, its
   residuals CSV and the HTML page. Before: +22.6 s, 512 MB, JSON 56 MB.
3. An HTML accuracy report of ``--html-rows`` rows (default 200,000; ``calib evaluate --html
   --plots``): the process's wall time and, when Chromium is installed, the time a headless
   Chromium takes to load and screenshot the page (target: under 10 s).

On a loaded machine wall times grow with the load: the load average is printed, and CPU times.

Run: python scripts/bench_report.py [--repeats 5] [--rows 100000] [--html-rows 200000] [--quick]
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread before numpy loads)

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
EXAMPLE = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
#: The issue's figures before this work (issue 27, item 3).
BEFORE = {"example_s": (0.57, 4.4), "added_100k_s": 22.6, "memory_100k_mb": 512.0, "json_100k_mb": 56.0}
TARGET = {"added_example_s": 0.5, "added_100k_s": 3.0, "html_200k_s": 10.0}
PYCACHE = Path(tempfile.gettempdir()) / "calib-bench-pycache"
#: The flags headless Chromium needs on this machine (no sandbox as root, no GPU, no network of
#: its own: QUIC, background fetches, component updates and sync each start connections).
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync")


def chromium_argv(browser: str, page: Path, profile: Path, screenshot: Path) -> list[str]:
    """The command that loads ``page`` in headless Chromium and screenshots it (1200 x 3000)."""
    return [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--screenshot={screenshot}",
            "--window-size=1200,3000", page.as_uri()]


def _env(root: Path = ROOT) -> dict:
    env = dict(os.environ, PYTHONPATH=str(root) + os.pathsep + os.environ.get("PYTHONPATH", ""),
               PYTHONPYCACHEPREFIX=str(PYCACHE / root.name))
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = "1"
    return env


def run(argv: list[str], root: Path = ROOT) -> dict:
    """One ``calib`` process (of the checkout ``root``): wall s, CPU s (user + sys), max RSS MB;
    raises on a non-zero exit."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "calib", *map(str, argv)], env=_env(root), cwd=tempfile.gettempdir(),
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode()
    proc.stderr.close()
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise SystemExit(f"calib {' '.join(map(str, argv))} exited {code}: {err.strip()[-400:]}")
    return {"wall": wall, "cpu": usage.ru_utime + usage.ru_stime, "rss_mb": usage.ru_maxrss / 1024}


def pair(base: list[str], extra: list[str], repeats: int, root: Path = ROOT) -> tuple[dict, dict]:
    """Medians of ``repeats`` interleaved runs of ``base`` and ``base + extra`` (after a warm-up)."""
    return pairs(base, extra, repeats, [root])[root]


def pairs(base: list[str], extra: list[str], repeats: int, roots: list[Path]) -> dict[Path, tuple[dict, dict]]:
    """:func:`pair` for each checkout of ``roots``, all runs interleaved (each repetition runs
    every checkout in turn), so that a change of the machine's load falls on all alike."""
    for root in roots:
        run(base, root)
    runs = {root: ([], []) for root in roots}
    for _ in range(repeats):
        for root in roots:
            runs[root][0].append(run(base, root))
            runs[root][1].append(run(base + extra, root))
    med = lambda rs: {k: statistics.median(r[k] for r in rs) for k in rs[0]}
    return {root: (med(a), med(b)) for root, (a, b) in runs.items()}


_STAGE = """
import json, sys, time
import calib
from calib.io.csv.specs import read_measurements
robot = calib.load_robot(sys.argv[1])
meas = read_measurements(sys.argv[2], robot)
res = calib.calibrate(robot, meas)
c0, w0 = time.process_time(), time.perf_counter()
from calib.report.build import build_report, render_html, render_plots
images = render_plots(res, meas)
page = render_html(build_report(res, meas), res.format(), images)
print(json.dumps({"cpu": time.process_time() - c0, "wall": time.perf_counter() - w0}))
"""


def report_stage(root: Path) -> dict:
    """CPU and wall seconds of the report stage (imports, plots, JSON, HTML) in a fresh process
    of the checkout ``root``, after calibrate() of the bundled example."""
    import json

    out = subprocess.run([sys.executable, "-c", _STAGE, str(URDF), str(EXAMPLE)], env=_env(root), cwd=tempfile.gettempdir(),
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _mb(path: Path) -> str:
    return f"{path.stat().st_size / 1e6:.2f} MB" if path.exists() else "-"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--html-rows", type=int, default=200_000)
    ap.add_argument("--quick", action="store_true", help="the bundled example only")
    ap.add_argument("--compare", type=Path, default=None, metavar="CHECKOUT",
                    help="also run the calib of another checkout (e.g. a `git archive main` snapshot), "
                         "interleaved with this one's, to compare under the same load")
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores; medians of {args.repeats} runs")
    roots = [ROOT] + ([args.compare.resolve()] if args.compare is not None else [])
    stages = {r: [] for r in roots}
    for _ in range(args.repeats):
        for r in roots:
            stages[r].append(report_stage(r))
    for r in roots:
        cpu = statistics.median(x["cpu"] for x in stages[r])
        wall = statistics.median(x["wall"] for x in stages[r])
        print(f"0. report stage of the bundled example ({'this checkout' if r == ROOT else r}): {cpu:.2f} s CPU, "
              f"{wall:.2f} s wall (imports, plots, JSON, HTML)")
    with tempfile.TemporaryDirectory(prefix="calib-bench-report-") as tmp:
        tmp = Path(tmp)
        extra = ["--report", tmp / "r.json", "--html", tmp / "r.html", "--plots", tmp / "plots"]
        base = ["calibrate", URDF, EXAMPLE, "-o", tmp / "c.urdf"]
        both = pairs(base, extra, args.repeats, roots)
        a, b = both[ROOT]
        print(f"\n1. bundled example, 300 rows: calibrate {a['wall']:.2f} s -> with --report --html --plots "
              f"{b['wall']:.2f} s wall, +{b['wall'] - a['wall']:.2f} s (CPU +{b['cpu'] - a['cpu']:.2f} s); "
              f"before: {BEFORE['example_s'][0]} s -> {BEFORE['example_s'][1]} s "
              f"(+{BEFORE['example_s'][1] - BEFORE['example_s'][0]:.2f} s); target +{TARGET['added_example_s']} s")
        print(f"   JSON {_mb(tmp / 'r.json')}, HTML {_mb(tmp / 'r.html')}")
        if args.compare is not None:
            a2, b2 = both[args.compare.resolve()]
            print(f"   {args.compare} under the same load (interleaved): {a2['wall']:.2f} s -> {b2['wall']:.2f} s wall, "
                  f"+{b2['wall'] - a2['wall']:.2f} s (CPU +{b2['cpu'] - a2['cpu']:.2f} s)")
        if args.quick:
            return
        meas = tmp / "m.csv"
        run(["simulate", URDF, "-o", meas, "--poses", args.rows, "--seed", 1, "--deviations", "random:0.3"])
        base = ["calibrate", URDF, meas, "-o", tmp / "c.urdf", "--cv", 0]
        reps = max(1, min(args.repeats, 3))
        both = pairs(base, extra, reps, roots)
        a, b = both[ROOT]
        print(f"\n2. {args.rows} rows (medians of {reps}): calibrate {a['wall']:.1f} s, {a['rss_mb']:.0f} MB -> "
              f"with --report --html --plots {b['wall']:.1f} s, {b['rss_mb']:.0f} MB: +{b['wall'] - a['wall']:.2f} s "
              f"wall (CPU +{b['cpu'] - a['cpu']:.2f} s), +{b['rss_mb'] - a['rss_mb']:.0f} MB peak; "
              f"before: +{BEFORE['added_100k_s']} s, {BEFORE['memory_100k_mb']:.0f} MB; target +{TARGET['added_100k_s']} s")
        print(f"   JSON {_mb(tmp / 'r.json')} (before: {BEFORE['json_100k_mb']:.0f} MB), residuals CSV "
              f"{_mb(tmp / 'r.residuals.csv')}, HTML {_mb(tmp / 'r.html')}")
        if args.compare is not None:
            a2, b2 = both[args.compare.resolve()]
            print(f"   {args.compare} under the same load (interleaved): {a2['wall']:.1f} s -> {b2['wall']:.1f} s "
                  f"wall, +{b2['wall'] - a2['wall']:.2f} s (CPU +{b2['cpu'] - a2['cpu']:.2f} s), "
                  f"+{b2['rss_mb'] - a2['rss_mb']:.0f} MB peak")
        big = tmp / "big.csv"
        run(["simulate", URDF, "-o", big, "--poses", args.html_rows, "--seed", 2, "--deviations", "random:0.3"])
        page = tmp / "big.html"
        t = run(["evaluate", URDF, big, "--html", page, "--plots", tmp / "bigplots"])
        print(f"\n3. HTML of {args.html_rows} rows (calib evaluate --html --plots): {t['wall']:.1f} s wall, "
              f"{t['rss_mb']:.0f} MB; page {_mb(page)}")
        browser = shutil.which("chromium") or shutil.which("chromium-browser")
        if browser:
            t0 = time.perf_counter()
            subprocess.run(chromium_argv(browser, page, tmp / "chromium", tmp / "shot.png"),
                           capture_output=True, timeout=120)
            print(f"   headless Chromium loads and screenshots it in {time.perf_counter() - t0:.1f} s "
                  f"(target: under {TARGET['html_200k_s']:.0f} s)")
        else:
            print("   (no chromium on PATH: browser time not measured)")


if __name__ == "__main__":
    main()
