"""The certificate of the real TIAGo example (issue 26 item 4's acceptance): the HTML headlines
the registered "before" and the without-outliers "after", and marks the rows the fit flags
(31-33: the three markers of the tenth configuration, 55-67 mm off)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

from calib.cli.main import main

pytestmark = pytest.mark.slow
ROOT = Path(__file__).resolve().parents[2]
TIAGO = ROOT / "examples" / "tiago_qualisys" / "measurements.csv"


def test_tiago_certificate_shows_the_without_outliers_figures_and_marks_rows_31_to_33(capsys, tmp_path):
    out, rep, page = tmp_path / "t.urdf", tmp_path / "t.json", tmp_path / "t.html"
    code = main(["calibrate", "tiago", str(TIAGO), "-o", str(out), "--report", str(rep), "--html", str(page),
                 "--plots", str(tmp_path / "plots"), "--tolerance-mm", "8",
                 "--meta", "robot_serial=TIAGo-demo,instrument=Qualisys,operator=calib tests"])
    text, err = capsys.readouterr()
    assert code == 0, err
    r = json.loads(rep.read_text())
    flagged = sorted(o["row"] for o in r["outliers"])
    assert flagged == [31, 32, 33] == r["certificate"]["outlier_rows"]
    acc = {g["label"]: g for g in r["certificate"]["accuracy"]}
    after = acc["calibration rows, after, without outliers"]
    assert after["n"] == 102
    assert after["position_mm"]["rms"] == pytest.approx(r["after_without_outliers"]["position_mm"]["rms"], rel=1e-9)
    assert after["position_mm"]["rms"] < 3.0                      # 2.57 mm (10.5 with the outliers)
    before = acc["calibration rows, before"]["position_mm"]
    assert before["rms"] == pytest.approx(r["before_registered"]["calibration"]["position_mm"]["rms"], rel=1e-9)
    assert before["rms"] < 20 < r["before"]["position_mm"]["rms"]  # 11 mm registered, 482 mm not
    html = page.read_text()
    headline = html.split('<table class="headline">')[1].split("</table>")[0]
    assert f"<b>{after['position_mm']['rms']:.4g}</b>" in headline
    assert f"<b>{before['rms']:.4g}</b>" in headline
    assert f"{r['before']['position_mm']['rms']:.4g}" not in headline   # the unregistered 482 mm is not a headline
    assert re.findall(r'<tr class="out"><td>(\d+)</td>', html) == ["31", "32", "33"]
    assert 'class="verdict pass">PASS<' in html and "TIAGo-demo" in html
    assert html.count("data:image/png;base64,") == 3               # position-only: no orientation plot
