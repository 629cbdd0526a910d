"""The URDF reader (calib.io.urdf.reader): a URDF is parsed and built in Pinocchio once per run,
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
from calib.io.urdf.document import UrdfDocument
from calib.io.urdf.reader import read_urdf_chain, robot_from_chain

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


def test_compensate_and_evaluate_read_each_urdf_once(tmp_path, count_reads, capsys):
    """compensate reads and builds the calibrated and the nominal URDF once each (the frames the
    calibrated URDF records and the joint-target check use the document its model carries);
    evaluate reads and builds its URDF once."""
    cal = tmp_path / "cal.urdf"
    assert main(["calibrate", str(BUNDLED), str(EXAMPLE), "-o", str(cal)]) == 0
    count_reads.update(build=0, read=0)
    assert main(["compensate", str(cal), str(BUNDLED), str(ROOT / "examples" / "brtirus0707a" / "targets.csv"),
                 "-o", str(tmp_path / "corrected.csv")]) == 0
    assert count_reads == {"build": 2, "read": 2}
    count_reads.update(build=0, read=0)
    assert main(["evaluate", str(cal), str(EXAMPLE)]) == 0
    assert count_reads == {"build": 1, "read": 1}


def test_the_model_carries_its_source():
    """load_robot's model carries the parsed chain; derived models keep it; urdf_path is its path."""
    chain = read_urdf_chain(BUNDLED)
    robot = robot_from_chain(chain)
    assert robot.source is chain and robot.urdf_path == BUNDLED
    derived = [robot.with_values(robot.values * 1.0), robot.with_changes(d2=1e-4),
               robot.with_target_offsets({"A": [0, 0, 0.01], "B": [0, 0.01, 0]}).for_target("B"),
               replace(robot, tool_frame=robot.tool_frame)]
    assert all(r.source is chain for r in derived)
    assert replace(robot, source=None).urdf_path is None
    with pytest.raises(AttributeError):
        robot.urdf_path = Path("other.urdf")
    # the same kinematics as a fresh load (to rounding: the same arithmetic)
    q = robot.random_configurations(5, rng=1)
    fresh = calib.load_robot(BUNDLED)
    assert np.array_equal(np.array([robot.T_meas_tool(x) for x in q]), np.array([fresh.T_meas_tool(x) for x in q]))


def test_a_model_with_its_source_pickles(tmp_path, capsys):
    """A model goes to another process with what it carries (the document is pickled as its
    text): same kinematics, same recorded frames, and it can still be written."""
    import pickle

    cal = tmp_path / "cal.urdf"
    assert main(["calibrate", str(BUNDLED), str(EXAMPLE), "-o", str(cal)]) == 0
    robot = calib.load_robot(cal)
    back = pickle.loads(pickle.dumps(robot))
    assert back.urdf_path == robot.urdf_path and back.source.document.frames == robot.source.document.frames
    q = robot.random_configurations(3, rng=0)
    assert np.array_equal(np.array([back.T_meas_tool(x) for x in q]), np.array([robot.T_meas_tool(x) for x in q]))
    calib.write_calibrated_urdf(robot, tmp_path / "a.urdf")
    calib.write_calibrated_urdf(back, tmp_path / "b.urdf")
    assert (tmp_path / "a.urdf").read_bytes() == (tmp_path / "b.urdf").read_bytes()


@pytest.mark.parametrize("value", ["1e300", "-2e4"])
def test_an_absurd_joint_origin_is_refused_naming_the_joint(tmp_path, value):
    """An origin of 1e300 m overflowed the kinematics (an IndexError in the identifiability
    analysis, exit 1); now the reader refuses it, naming the joint (exit 2 from the CLI)."""
    import re

    from calib import URDFError, load_robot

    text = BUNDLED.read_text()
    third = [m.start() for m in re.finditer(r"<joint ", text)][3]
    j = text.index('<origin xyz="', third)
    k = text.index('"', j + len('<origin xyz="'))
    bad = tmp_path / "bad.urdf"
    bad.write_text(text[:j] + f'<origin xyz="{value} 0 0' + text[k:])
    with pytest.raises(URDFError, match="joint 'joint3': origin xyz"):
        load_robot(bad)


def test_a_model_beyond_the_dof_bound_is_refused_before_pinocchio_builds_its_workspace(tmp_path):
    """A 1,000-joint URDF took 18 GB in 30 s, then a MemoryError; beyond MAX_MODEL_DOF the reader
    refuses it with one message (exit 2 from the CLI)."""
    from calib import URDFError, load_robot
    from calib.io.urdf.reader import MAX_MODEL_DOF

    n = MAX_MODEL_DOF + 1
    parts = ['<robot name="snake">', '<link name="l0"/>']
    for i in range(1, n + 1):
        parts.append(f'<link name="l{i}"/><joint name="j{i}" type="revolute"><parent link="l{i - 1}"/>'
                     f'<child link="l{i}"/><origin xyz="0 0 0.01"/><axis xyz="0 {i % 2} {1 - i % 2}"/>'
                     f'<limit lower="-1" upper="1" effort="1" velocity="1"/></joint>')
    path = tmp_path / "snake.urdf"
    path.write_text("\n".join(parts + ["</robot>"]))
    with pytest.raises(URDFError, match=f"{n} moving degrees of freedom"):
        load_robot(path)
    assert main(["identifiability", str(path)]) == 2


def test_the_last_chain_derived_is_kept():
    """robot_from_chain of the chain the loader read (the writer's check before a fit) is the
    loaded model itself, not a second derivation; another threshold derives again."""
    robot = calib.load_robot(BUNDLED)
    assert robot_from_chain(robot.source, robot.parallel_threshold) is robot
    other = robot_from_chain(robot.source, robot.parallel_threshold / 2)
    assert other is not robot and other.n_params == robot.n_params == 37
