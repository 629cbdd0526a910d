"""Render a calibration certificate (``calib calibrate ... --html``) in headless Chromium to a PNG
(the page as a screen shows it) and a PDF (as it prints: A4, ``@media print``), to look at it.

Without ``--html`` the script first makes a certificate of its own: a tracker calibration of
the bundled BRTIRUS0707A from two files as a cell writes them, a controller's joint log with ISO
8601 times and a tracker's export (``;``, decimal commas, units in brackets, 6-DoF poses, a pose
id per stop, five stops visited four times each for ISO 9283), joined by the nearest time, with
held-out rows (``set=val``: the verdict) and an identity file (instrument, its calibration date,
operator, approver). ``--no-validation`` leaves the held-out rows out: the page then shows fit
residuals and no verdict.

Chromium is Debian's (``apt-get install chromium``: /usr/bin/chromium), driven by Playwright
from PyPI (``pip install playwright``; its own browser download, ``playwright install``, is not
used). The flags keep it off the network and the GPU (:data:`CHROMIUM_ARGS`).

Run: python scripts/render_certificate.py [-o OUT_DIR] [--html REPORT.html] [--no-validation]
Writes OUT_DIR/certificate.png and OUT_DIR/certificate.pdf (and, without --html, the inputs and
outputs of the calibration in OUT_DIR/case/), and prints their paths.
"""
from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
URDF = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
#: Debian's Chromium.
CHROMIUM = "/usr/bin/chromium"
#: Headless, as root without a sandbox, no GPU, and no network of its own (QUIC, background
#: fetches, component updates and sync each open connections).
CHROMIUM_ARGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync")
#: Stops of the case: single visits, and the poses visited several times (ISO 9283).
SINGLE_POSES, REPEATED_POSES, VISITS = 36, 5, 4
START = "2026-11-25T09:12:00"


def browser_missing() -> str | None:
    """Why the browser cannot run here (None when it can): no Chromium at :data:`CHROMIUM`, or
    no Playwright."""
    if not Path(CHROMIUM).is_file():
        return f"no Chromium at {CHROMIUM} (apt-get install -y chromium)"
    try:
        import playwright.sync_api  # noqa: F401
    except ImportError:
        return "no Playwright (pip install playwright; its browser download is not needed)"
    return None


def launch(playwright):
    """Debian's headless Chromium through Playwright."""
    return playwright.chromium.launch(executable_path=CHROMIUM, args=list(CHROMIUM_ARGS))


def render(html: Path, png: Path | None = None, pdf: Path | None = None) -> None:
    """Screenshot ``html`` (whole page, 1200 px wide) to ``png`` and print it to ``pdf`` (A4, the
    page's own margins and print styles, backgrounds printed)."""
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = launch(p)
        try:
            page = browser.new_page(viewport={"width": 1200, "height": 1400})
            page.goto(Path(html).resolve().as_uri())
            if png is not None:
                page.screenshot(path=str(png), full_page=True)
            if pdf is not None:
                page.pdf(path=str(pdf), prefer_css_page_size=True, print_background=True)
        finally:
            browser.close()


def write_case(folder: Path, *, validation: str | None = "rows", seed: int = 3) -> list[str]:
    """The files of a tracker calibration in ``folder`` (module docstring) and the ``calib
    calibrate`` arguments that certify them (outputs in ``folder``: calibrated.urdf,
    certificate.json, certificate.html). validation : ``"rows"`` (every fourth single stop
    held out: ``set=val`` in the joint log), ``"file"`` (12 more stops in validation.csv, calib's
    own format, given by --validate) or None (no held-out rows: fit residuals only)."""
    import numpy as np

    import calib

    folder.mkdir(parents=True, exist_ok=True)
    robot = calib.load_robot(URDF)
    truth = calib.apply_deviations(robot, calib.random_deviations(robot, 3e-4, seed))
    truth = truth.with_changes(u_x=2.2, u_y=-0.4, u_z=0.3, u_gamma=0.6)        # the tracker 2.2 m away
    rng = np.random.default_rng(seed)
    single = robot.random_configurations(SINGLE_POSES, seed + 1)
    repeated = robot.random_configurations(REPEATED_POSES, seed + 2)
    ids = [f"P{k + 1:03d}" for k in range(SINGLE_POSES)] + \
        [f"R{k + 1}" for k in range(REPEATED_POSES)] * VISITS
    Q = np.concatenate([single, np.tile(repeated, (VISITS, 1))])
    meas = calib.simulate_measurements(truth, Q, sigma_pos=0.015e-3, sigma_rot=2e-5, rng=seed + 3)
    sets = ["val" if validation == "rows" and k % 4 == 3 and k < SINGLE_POSES else "cal" for k in range(len(Q))]
    t0 = np.datetime64(START)
    stamps = t0 + (np.arange(len(Q)) * 20_000 + rng.integers(0, 3000, len(Q))).astype("timedelta64[ms]")
    joints = ["A1_deg", "A2_deg", "A3_deg", "A4_deg", "A5_deg", "A6_deg"]
    with open(folder / "joints.csv", "w") as fh:         # the controller's log: a row per stop
        fh.write("time," + ",".join(joints) + ",set\n")
        for k in range(len(Q)):
            fh.write(f"{np.datetime_as_string(stamps[k], unit='ms')}," + ",".join(
                repr(float(v)) for v in np.degrees(Q[k])) + f",{sets[k]}\n")
    wxyz = _quaternions(meas.rotation)
    with open(folder / "tracker.csv", "w") as fh:       # the tracker's export, 0.4 s into each stop
        fh.write("time;pose_id;X [mm];Y [mm];Z [mm];qw;qx;qy;qz\n")
        for k in range(len(Q)):
            cells = [f"{v:.4f}" for v in meas.position[k] * 1e3] + [f"{v:.7f}" for v in wxyz[k]]
            stamp = np.datetime_as_string(stamps[k] + np.timedelta64(400, "ms"), unit="ms")
            fh.write(f"{stamp};{ids[k]};" + ";".join(c.replace(".", ",") for c in cells) + "\n")
    (folder / "identity.yaml").write_text(
        "customer: Example Automotive GmbH, body shop line 3\n"
        "robot_serial: BR-0707-1742\n"
        "instrument: Leica AT960 with T-Mac\n"
        "instrument_serial: '392117'\n"
        "instrument_calibration_date: 2026-03-02\n"
        "instrument_certificate: LGS-2026-0311\n"
        "operator: J. Doe\n"
        "approved_by: A. N. Other\n")
    extra = []
    if validation == "file":
        val = calib.simulate_measurements(truth, robot.random_configurations(12, seed + 4), sigma_pos=0.015e-3,
                                          sigma_rot=2e-5, rng=seed + 5)
        calib.write_measurements(folder / "validation.csv", val)
        extra = ["--validate", str(folder / "validation.csv")]
    return ["calibrate", str(URDF), str(folder / "joints.csv"), "--tracker", str(folder / "tracker.csv"), *extra,
            "--join", "nearest-time", "--time", "time", "--max-gap", "1", "-o", str(folder / "calibrated.urdf"),
            "--report", str(folder / "certificate.json"), "--html", str(folder / "certificate.html"),
            "--meta", str(folder / "identity.yaml"), "--tolerance-mm", "0.1", "--cv", "0"]


def _quaternions(R):
    """(N, 4) unit quaternions (w, x, y, z), w >= 0, of rotation matrices (N, 3, 3)."""
    import numpy as np
    from scipy.spatial.transform import Rotation

    q = Rotation.from_matrix(R).as_quat(scalar_first=True)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("-o", "--out", type=Path, default=Path("certificate-render"), help="output folder")
    ap.add_argument("--html", type=Path, default=None, help="the HTML report to render (default: make one)")
    ap.add_argument("--no-validation", action="store_true", help="the case without held-out rows")
    args = ap.parse_args(argv)
    why = browser_missing()
    if why is not None:
        print(f"render_certificate: {why}", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    html = args.html
    if html is None:
        from calib.cli.main import main as calib_main

        case = args.out / "case"
        if case.exists():
            shutil.rmtree(case)
        code = calib_main(write_case(case, validation=None if args.no_validation else "rows"))
        if code != 0:
            print(f"render_certificate: calib calibrate exited {code}", file=sys.stderr)
            return code
        html = case / "certificate.html"
    png, pdf = args.out / "certificate.png", args.out / "certificate.pdf"
    render(html, png, pdf)
    print(f"rendered {html}\n  {png}\n  {pdf}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
