"""The URDF reader (calib.io.urdf_reader): a URDF is parsed and built in Pinocchio once per run,
and the model carries what was parsed (issue 21: "the source read once")."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest

import calib
from calib.cli.main import main
from calib.io.urdf import UrdfDocument
from calib.io.urdf_reader import read_urdf_chain, robot_from_chain

ROOT = Path(__file__).resolve().parents[2]
BUNDLED = ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf"
EXAMPLE = ROOT / "examples" / "brtirus0707a" / "measurements.csv"


@pytest.fixture
def count_reads(monkeypatch):
    """Counts of Pinocchio URDF builds and URDF document reads while the test runs."""
    counts = {"build": 0, "read": 0}
    build, read = pin.buildModelFromUrdf, UrdfDocument.read.__func__

    def counting_build(*args, **kwargs):
        counts["build"] += 1
        return build(*args, **kwargs)

    def counting_read(cls, *args, **kwargs):
        counts["read"] += 1
        return read(cls, *args, **kwargs)

    monkeypatch.setattr(pin, "buildModelFromUrdf", counting_build)
    monkeypatch.setattr(UrdfDocument, "read", classmethod(counting_read))
    return counts


def test_readme_calibrate_builds_the_urdf_once(tmp_path, count_reads, capsys):
    """The README's main command: one Pinocchio build and one document read of the URDF."""
    out = tmp_path / "cal.urdf"
    assert main(["calibrate", str(BUNDLED), str(EXAMPLE), "-o", str(out)]) == 0
    assert out.is_file()
    assert count_reads == {"build": 1, "read": 1}


def test_calibrate_with_compliance_builds_the_urdf_once(tmp_path, count_reads, capsys):
    """--compliance (ur10, whose URDF has inertias): the gravity model copies the carried
    Pinocchio model instead of building the URDF again."""
    dev = tmp_path / "dev.json"
    dev.write_text(json.dumps({"c2": 3e-6, "d2": 3e-4}))
    meas, out = tmp_path / "m.csv", tmp_path / "cal.urdf"
    assert main(["simulate", "ur10", "-o", str(meas), "--poses", "40", "--deviations", str(dev),
                 "--payload-kg", "10"]) == 0
    count_reads.update(build=0, read=0)
    assert main(["calibrate", "ur10", str(meas), "-o", str(out), "--compliance", "--payload-kg", "10",
                 "--params", "base", "--method", "lm", "--cv", "0"]) == 0
    assert out.is_file() and out.with_name("cal.compliance.json").is_file()
    assert count_reads == {"build": 1, "read": 1}
