"""A certificate a customer signs (issue 37 item 5), from the files a cell writes: a controller's
joint log with ISO 8601 times and a tracker's export (``;``, decimal commas, units in brackets,
6-DoF poses, a pose id per stop, five stops visited four times) joined by the nearest time
(scripts/render_certificate.py writes them). Every input file is hashed, the verdict rests on
held-out rows only, ISO 9283 poses carry the file's pose id, the number is derived from the
files' sha256 (or given), the measurement date comes from the data (else the file date, said
so), the instrument and its own calibration date and the signature block are on the page and in
the JSON, and no number is printed as a signed zero.

Every expectation is computed here from the files themselves (hashlib, csv, datetime), not from
calib's reading of them."""
from __future__ import annotations

import csv
import datetime
import hashlib
import json
import os
import re
from pathlib import Path

import pytest

import calib
from calib.report.build import report_json_text
from calib.report.identity import certificate_number, measurement_date, parse_date
from calib.cli.main import main
from calib.errors import ParameterError
from calib.io.report_meta import read_meta
from calib.units import format_number
from conftest import load_script

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
EXAMPLE = ROOT / "examples" / "brtirus0707a" / "measurements.csv"
#: A number printed with a minus sign: the sign and its digits (not a date's or an id's dash).
SIGNED = re.compile(r"(?<![\w.:-])-(\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)(?![\w.])")


@pytest.fixture(scope="module")
def render():
    return load_script("render_certificate")


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def _calibrate(folder: Path, argv: list[str]):
    code = main(argv)
    assert code == 0
    return json.loads((folder / "certificate.json").read_text()), (folder / "certificate.html").read_text()


@pytest.fixture(scope="module")
def case(render, tmp_path_factory):
    """The case with held-out rows (set=val in the joint log): (folder, JSON report, page)."""
    d = tmp_path_factory.mktemp("cert")
    report, page = _calibrate(d, render.write_case(d, validation="rows"))
    return d, report, page


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _rows(path: Path, delimiter: str) -> list[dict]:
    return list(csv.DictReader(Path(path).read_text().splitlines(), delimiter=delimiter))


# ====================================================================== provenance and number
def test_every_input_file_is_hashed_the_tracker_file_too(case):
    d, report, page = case
    inputs = report["provenance"]["inputs"]
    files = {"robot": BUNDLED, "measurements": d / "joints.csv", "tracker": d / "tracker.csv",
             "meta": d / "identity.yaml"}
    assert sorted(inputs) == sorted(files)
    for role, path in files.items():
        assert inputs[role]["sha256"] == _sha(path) and inputs[role]["bytes"] == path.stat().st_size
        assert f"sha256 {_sha(path)}" in page
    mtime = datetime.datetime.fromtimestamp((d / "tracker.csv").stat().st_mtime, datetime.timezone.utc)
    assert inputs["tracker"]["modified"] == mtime.strftime("%Y-%m-%dT%H:%M:%SZ")


def test_certificate_number_is_derived_from_the_data_files_sha256(case):
    """CAL- and the first 12 hex digits of the sha256 of 'ROLE SHA256' lines of the data files
    (not the identity file): anyone holding the files can check the number."""
    d, report, page = case
    text = "".join(f"{role} {_sha(p)}\n" for role, p in (("robot", BUNDLED), ("measurements", d / "joints.csv"),
                                                          ("tracker", d / "tracker.csv")))
    h = hashlib.sha256(text.encode()).hexdigest().upper()
    number = f"CAL-{h[:4]}-{h[4:8]}-{h[8:12]}"
    cert = report["certificate"]
    assert cert["number"] == number and cert["number_from"] == "input sha256"
    assert cert["number_inputs"] == ["robot", "measurements", "tracker"]
    assert f"Certificate <b>{number}</b>" in page
    # the same files give the same number; a given one wins
    prov = report["provenance"]["inputs"]
    assert certificate_number(prov, {})["number"] == number
    assert certificate_number(prov, {"certificate_number": "KC-2026/0417"}) == {
        "number": "KC-2026/0417", "from": "meta", "roles": []}
    changed = {**prov, "tracker": {**prov["tracker"], "sha256": "0" * 64}}
    assert certificate_number(changed, {})["number"] != number


# ====================================================================== verdict
def test_verdict_rests_on_the_held_out_rows_only(case):
    d, report, page = case
    held_out = [r for r in _rows(d / "joints.csv", ",") if r["set"] == "val"]
    cert = report["certificate"]
    tol = cert["tolerance"]
    assert len(held_out) == 9 and tol["n"] == 9 and tol["rows"] == "validation rows (held out)"
    assert cert["basis"] == tol["basis"] == "held-out rows"
    assert tol["max_mm"] == pytest.approx(report["validation"]["after"]["position_mm"]["max"], rel=1e-12)
    assert tol["verdict"] == ("PASS" if tol["max_mm"] <= 0.1 else "FAIL") == "PASS" and tol["pass"] is True
    assert 'class="verdict pass">PASS<' in page and "Fit residuals." not in page


def test_without_held_out_rows_the_page_says_fit_residuals_and_gives_no_verdict(render, tmp_path, capsys):
    argv = render.write_case(tmp_path, validation=None)
    code, out, err = run(capsys, *argv)
    assert code == 0, err
    report = json.loads((tmp_path / "certificate.json").read_text())
    page = (tmp_path / "certificate.html").read_text()
    tol = report["certificate"]["tolerance"]
    n_rows = len(_rows(tmp_path / "tracker.csv", ";"))
    assert tol["n"] == n_rows == 56 and tol["basis"] == "fit residuals" and report["certificate"]["basis"] == tol["basis"]
    assert tol["pass"] is None and tol["verdict"] is None and tol["max_mm"] <= 0.1
    assert "PASS" not in page and "FAIL" not in page and "PASS" not in out and "FAIL" not in out
    assert 'class="verdict none">no verdict<' in page and "<b>Fit residuals.</b>" in page
    assert (f"tolerance 0.1 mm: no verdict (no verification rows: --validate VAL.csv, or rows with set=val); "
            f"fit residuals: largest {tol['max_mm']:.4g} mm over 56 calibration rows, 0 beyond") in out


def test_a_validation_file_carries_the_verdict(render, tmp_path):
    report, page = _calibrate(tmp_path, render.write_case(tmp_path, validation="file"))
    tol, inputs = report["certificate"]["tolerance"], report["provenance"]["inputs"]
    val_rows = [l for l in (tmp_path / "validation.csv").read_text().splitlines() if l and not l.startswith("#")]
    assert tol["n"] == len(val_rows) - 1 == 12 and tol["basis"] == "held-out rows" and tol["verdict"] in ("PASS", "FAIL")
    assert inputs["validation"]["sha256"] == _sha(tmp_path / "validation.csv")
    assert report["certificate"]["number_inputs"] == ["robot", "measurements", "tracker", "validation"]


# ====================================================================== ISO 9283
def test_iso9283_poses_are_named_by_the_files_pose_id(case):
    d, report, page = case
    rows = _rows(d / "tracker.csv", ";")
    first = {}
    for k, r in enumerate(rows):                   # the file's line of each id's first visit
        first.setdefault(r["pose_id"], k + 2)
    visits = {i: sum(r["pose_id"] == i for r in rows) for i in first}
    iso = report["certificate"]["iso9283"]
    repeated = [i for i in first if visits[i] > 1]
    assert [p["pose_id"] for p in iso["poses"]] == repeated == ["R1", "R2", "R3", "R4", "R5"]
    assert [p["visits"] for p in iso["poses"]] == [visits[i] for i in repeated] == [4] * 5
    # one row per stop: the joint log's lines, which are the tracker file's (one header line each)
    assert [p["first_row"] for p in iso["poses"]] == [first[i] for i in repeated]
    table = page.split("ISO 9283 pose accuracy")[1]
    assert '<th class="l">pose id</th>' in table and '<td class="l">R3</td>' in table
    assert "the same pose id" in table


# ====================================================================== dates, instrument, signatures
def _utc(stamp: str) -> datetime.datetime:
    return datetime.datetime.fromisoformat(stamp.replace(",", ".")).replace(tzinfo=datetime.timezone.utc)


def test_measurement_date_is_the_data_time_column(case):
    d, report, page = case
    stamps = sorted(_utc(r["time"]) for r in _rows(d / "tracker.csv", ";"))
    when = report["certificate"]["measurement_date"]
    fmt = "%Y-%m-%dT%H:%M:%SZ"
    assert when["source"] == "data" and when["rows"] == len(stamps) == 56
    assert (when["first"], when["last"]) == (stamps[0].strftime(fmt), stamps[-1].strftime(fmt))
    label = f"{stamps[0]:%Y-%m-%d %H:%M:%S} to {stamps[-1]:%H:%M:%S} UTC"
    assert when["label"].startswith(label) and f"measured {label}" in page
    # the rows' own stamps, as read by the join
    robot = calib.load_robot(BUNDLED)
    m = calib.read_measurements(d / "joints.csv", robot, tracker=d / "tracker.csv",
                                options=calib.ReadOptions(join="nearest-time", time="time", max_gap=1.0))
    got = sorted(m.columns["unix_time_s"])
    assert got == pytest.approx([s.timestamp() for s in stamps], abs=1e-6)


def test_measurement_date_without_dates_in_the_data_is_the_file_date_labelled_so(tmp_path, capsys):
    meas = tmp_path / "measurements.csv"
    meas.write_bytes(EXAMPLE.read_bytes())
    t = datetime.datetime(2026, 10, 1, 12, 0, tzinfo=datetime.timezone.utc).timestamp()
    os.utime(meas, (t, t))
    argv = ["calibrate", BUNDLED, meas, "-o", tmp_path / "c.urdf", "--report", tmp_path / "r.json"]
    code, _, err = run(capsys, *argv)
    assert code == 0, err
    when = json.loads((tmp_path / "r.json").read_text())["certificate"]["measurement_date"]
    assert when["source"] == "file date" and when["first"] == "2026-10-01T12:00:00Z"
    assert when["label"] == "file date 2026-10-01 (last modified: measurements.csv; the data carry no dates)"
    code, _, err = run(capsys, *argv, "--meta", "measurement_date=2026-09-30")
    assert code == 0, err
    when = json.loads((tmp_path / "r.json").read_text())["certificate"]["measurement_date"]
    assert when == {"first": "2026-09-30", "last": "2026-09-30", "source": "meta",
                    "label": "2026-09-30 (as given: measurement_date)"}


def test_instrument_its_calibration_and_the_signature_block(case):
    d, report, page = case
    fields = read_meta(d / "identity.yaml")
    assert fields["instrument_calibration_date"] == "2026-03-02"        # YAML's unquoted date, as written
    cert = report["certificate"]
    assert cert["instrument"] == {"name": "Leica AT960 with T-Mac", "serial": "392117",
                                  "calibration_date": "2026-03-02", "certificate": "LGS-2026-0311"}
    assert cert["signatures"] == [{"role": "measured by", "name": "J. Doe"},
                                  {"role": "approved by", "name": "A. N. Other"}]
    assert report["meta"] == fields and cert["notes"] == []
    assert "<td class=\"l\">Leica AT960 with T-Mac, serial 392117</td>" in page
    assert "<td class=\"l\">2026-03-02, certificate LGS-2026-0311</td>" in page
    block = page.split('<section class="signature-block">')[1].split("</section>")[0]
    assert re.search(r'<th class="l">measured by</th><td class="l">J\. Doe</td><td class="l"></td>', block)
    assert re.search(r'<th class="l">approved by</th><td class="l">A\. N\. Other</td><td class="l"></td>', block)
    # the terminal block is its own section, which the print styles hide
    assert '<section class="terminal">' in page and page.index(".terminal{display:none}") > page.index("@media print{")


def test_an_instrument_calibrated_after_the_measurement_is_noted(case):
    d, report, _ = case
    from calib.report.identity import certificate_identity

    ident = certificate_identity(report["provenance"], {"instrument_calibration_date": "2026-12-01"},
                                 {"unix_time_s": [_utc("2026-11-25T09:12:00").timestamp()]})
    assert ident["notes"] == ["the instrument's calibration (2026-12-01) is dated after the measurement (2026-11-25)"]
    assert certificate_identity(report["provenance"], {"instrument_calibration_date": "2026-11-25"},
                                {"unix_time_s": [_utc("2026-11-25T09:12:00").timestamp()]})["notes"] == []


def test_measurement_date_without_anything_says_how_to_give_it():
    when = measurement_date({}, {}, {})
    assert when["source"] == "unknown" and "--meta measurement_date=YYYY-MM-DD" in when["label"]


@pytest.mark.parametrize("extra, message", [
    (["--meta", "instrument_calibration_date=02.03.2026"],
     "meta instrument_calibration_date: '02.03.2026' is not a date: expected YYYY-MM-DD"),
    (["--meta", "measurement_date=2026-13-01"], "meta measurement_date: '2026-13-01' is not a date"),
    (["--meta", "NUMBER.yaml"], "meta certificate_number: 'A\\nB' is not a certificate number"),
])
def test_bad_identity_fields_are_one_line_exit_2_before_any_work(capsys, tmp_path, extra, message):
    (tmp_path / "NUMBER.yaml").write_text('certificate_number: "A\\nB"\n')
    extra = [str(tmp_path / e) if e.endswith(".yaml") else e for e in extra]
    out, page = tmp_path / "c.urdf", tmp_path / "r.html"
    code, text, err = run(capsys, "calibrate", BUNDLED, EXAMPLE, "-o", out, "--html", page, *extra)
    lines = [l for l in err.strip().splitlines() if not l.startswith("usage:")]
    assert code == 2 and len(lines) == 1 and message in lines[0], err
    assert not out.exists() and not page.exists() and text == ""
    with pytest.raises(ParameterError, match="not a date"):
        parse_date("25/11/2026", "measurement_date")
    assert parse_date("2026-11-25T10:00:07Z") == datetime.datetime(2026, 11, 25, 10, 0, 7,
                                                                    tzinfo=datetime.timezone.utc)


# ====================================================================== signed zeros
def test_format_number_prints_no_signed_zero():
    assert [format_number(v, s) for v, s in ((-0.0, ".6f"), (-4e-9, ".6f"), (-4e-9, ">12.6f"), (-4e-9, "<12.6f"),
                                             (-0.0, ".4g"), (-4e-9, ".4g"), (-0.5, ".3f"))] == \
        ["0.000000", "0.000000", "    0.000000", "0.000000    ", "0", "-4e-09", "-0.500"]
    assert json.loads(report_json_text({"a": -0.0, "b": [-0.0, 1.5, -2.0], "c": [[-0.0]]})) == \
        {"a": 0.0, "b": [0.0, 1.5, -2.0], "c": [[0.0]]}
    assert "-0" not in report_json_text({"a": -0.0, "b": [-0.0, 1.5, 2.0]})


def test_no_signed_zero_in_the_json_the_page_the_residuals_or_the_text(tmp_path, capsys):
    """The bundled robot's nominal values hold -1e-17 and fixed parameters whose deviation is
    -0.0: the printed tables, the page (its terminal block too), the JSON and the residuals CSV
    print them as zeros."""
    files = [tmp_path / n for n in ("r.json", "r.html", "r.residuals.csv")]
    code, out, err = run(capsys, "calibrate", BUNDLED, EXAMPLE, "-o", tmp_path / "c.urdf", "--report", files[0],
                         "--html", files[1], "--residuals", "csv", "--meta", "robot_serial=BR-0707-17")
    assert code == 0, err
    for name, text in [(f.name, f.read_text()) for f in files] + [("stdout", out)]:
        zeros = [m.group(0) for m in SIGNED.finditer(text) if float(m.group(1)) == 0.0]
        assert zeros == [], (name, zeros[:5])
    # (the scan finds them: the numbers the page prints include negative ones)
    assert any(float(m.group(1)) > 0 for m in SIGNED.finditer(files[1].read_text()))
    assert SIGNED.findall("d5 mm -0.000000 x -0 <td>-0.0000</td>") == ["0.000000", "0", "0.0000"]

