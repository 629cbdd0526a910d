"""Exports of a calibrated URDF (calib.io.exports.export, calib export): each file is read back the way
its consumer reads it and must give the calibrated forward kinematics.

* ur-yaml: the URDF that ur_description's template (urdf/ur_macro.xacro of ur_description 2.4.5,
  its lines quoted in tests/ur_template.py) makes from the YAML is built here, by those lines,
  and its tool0 must follow the calibrated URDF's flange to 1e-9 m / 1e-9 rad over random
  configurations (exact arithmetic: only rounding separates them). The published numbers:
  tests/io/test_export_ur.py.
* joint-origins-yaml: the nominal URDF with the YAML's origins put in (as a xacro would) must be
  the calibrated URDF, link by link.
* mdh-csv: read back by calib.read_mdh_csv, calib's MDH model must give the calibrated kinematics;
  with a calibration report, its values and standard deviations are the report's.
"""
from __future__ import annotations

import json
import math
import re
import subprocess
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
import yaml
from lxml import etree

import calib
from calib.io.exports.ur import UR_SEGMENTS
from calib.io.exports.mdh import rotation_angle
from calib.io.urdf.reader import read_urdf_chain
from calib.io.urdf.writer import write_calibrated_urdf
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations, random_deviations

from conftest import BUNDLED_URDF, erd_urdf
from ur_template import xacro_urdf

#: Tolerance of every round trip: the files hold full double precision (repr), so only the
#: rounding of the products separates the kinematics (observed ~1e-15; the URDF writer's 12
#: digits and a near-gimbal rpy of the old UR URDFs ~5e-12).
TOL = 1e-9


def _calibrated(tmp_path, urdf, scale=1e-3, seed=1, name="calibrated.urdf"):
    """A URDF perturbed as a calibration would leave it: random MDH deviations (``scale`` m,
    2 scale rad) of every parameter, base and tool included, written by calib's URDF writer."""
    nominal = calib.load_robot(urdf)
    true = apply_deviations(nominal, random_deviations(nominal, scale, rng=seed))
    out = tmp_path / name
    write_calibrated_urdf(true, out, nominal=nominal)
    return out, true


def _fk(model, data, frame_ids, q_full):
    pin.framesForwardKinematics(model, data, q_full)
    return {name: data.oMf[k].homogeneous.copy() for name, k in frame_ids.items()}


def _compare(A, B):
    """(position m, rotation rad) difference of two poses (4, 4)."""
    return float(np.linalg.norm(A[:3, 3] - B[:3, 3])), rotation_angle(A[:3, :3].T @ B[:3, :3])


# ====================================================================== ur-yaml
def _template_difference(cal, doc, n=30) -> np.ndarray:
    """Largest (m, rad) differences over n random configurations between the template URDF made
    from ``doc`` (the YAML) and the URDF ``cal``: of tool0 (the template's) against the URDF's
    tool0, and of tool0 . tool_in_tool0 against the URDF's tool frame; both in the base frames."""
    tmpl = pin.buildModelFromXML(xacro_urdf(doc["kinematics"]))
    tdata = tmpl.createData()
    tids = {n: tmpl.getFrameId(n) for n in ("base_link", "tool0")}
    chain = read_urdf_chain(cal)
    cm, cdata = chain.model, chain.model.createData()
    cids = {"base": chain.base_frame_id, "tool0": cm.getFrameId("tool0"), "tool": chain.tool_frame_id}
    tb = doc["calib"]["tool_in_tool0"]
    T_tool0_tool = np.eye(4)
    T_tool0_tool[:3, :3] = pin.rpy.rpyToMatrix(tb["roll"], tb["pitch"], tb["yaw"])
    T_tool0_tool[:3, 3] = (tb["x"], tb["y"], tb["z"])
    worst = np.zeros(4)
    for q in np.random.default_rng(3).uniform(-np.pi, np.pi, (n, 6)):
        t = _fk(tmpl, tdata, tids, q)        # the template's joints are the chain's, in order
        c = _fk(cm, cdata, cids, chain.configuration(q))
        T_tmpl = np.linalg.inv(t["base_link"]) @ t["tool0"]
        worst[:2] = np.maximum(worst[:2], _compare(T_tmpl, np.linalg.inv(c["base"]) @ c["tool0"]))
        worst[2:] = np.maximum(worst[2:], _compare(T_tmpl @ T_tool0_tool, np.linalg.inv(c["base"]) @ c["tool"]))
    return worst


@pytest.mark.parametrize("arm", ["ur5", "ur10"])
def test_ur_yaml_through_the_ur_description_template_gives_the_calibrated_kinematics(tmp_path, arm):
    """ur5 / ur10 of example-robot-data (joints about y and z, fixed tool0 past wrist_3_link),
    perturbed by ~1 mm / 2 mrad per parameter: the template URDF built from the exported YAML
    puts tool0 where the calibrated URDF has tool0 (its flange), and tool0 . tool_in_tool0 where
    it has the calibration's tool frame, to 1e-9 m / 1e-9 rad over 30 random configurations."""
    cal, _ = _calibrated(tmp_path, erd_urdf(arm))
    out = tmp_path / "kinematics.yaml"
    res = calib.export_calibration(cal, "ur-yaml", out)
    doc = yaml.safe_load(out.read_text())
    assert list(doc["kinematics"]) == list(UR_SEGMENTS) + ["hash"]
    assert doc["kinematics"]["hash"].startswith("calib_") and doc["calib"]["flange_frame"] == "tool0"
    assert res.read_back[0] < TOL and res.read_back[1] < TOL
    worst = _template_difference(cal, doc)
    assert worst.max() < TOL, worst
    # the perturbation is in the file: the nominal arm's template misses the calibrated flange by mm
    nominal_doc = yaml.safe_load(calib.export_calibration(erd_urdf(arm), "ur-yaml").text)
    assert _template_difference(cal, nominal_doc, n=5)[0] > 1e-3


def test_ur_yaml_of_a_calibration_of_simulated_data(tmp_path):
    """The whole path: a UR5 calibrated from 60 simulated poses (calib.calibrate, then its
    URDF writer, which adds the tool link), exported: the template gives the calibrated tool0 and
    tool to 1e-9 m / rad, and follows the true robot's tool to the calibration's accuracy."""
    nominal = calib.load_robot(erd_urdf("ur5"))
    true = apply_deviations(nominal, random_deviations(nominal, 1e-3, rng=7))
    meas = calib.simulate_measurements(true, nominal.random_configurations(60, 8), rng=9)
    res = calib.calibrate(nominal, meas, cv=0)
    assert res.status == "converged"
    res.write_urdf(tmp_path / "cal.urdf")
    doc = yaml.safe_load(calib.export_calibration(tmp_path / "cal.urdf", "ur-yaml").text)
    worst = _template_difference(tmp_path / "cal.urdf", doc)
    assert worst.max() < TOL, worst


def test_ur_yaml_notes_a_base_frame_away_from_the_robots_mount(tmp_path):
    """A UR5 on a 0.8 m pedestal (world -> base_link): exported from world, the shoulder entry
    holds the pedestal and a note says so; from --base-frame base_link it does not."""
    text = Path(erd_urdf("ur5")).read_text()
    joint = text[text.index('<joint name="world_joint"'):]
    joint = joint[:joint.index("</joint>")]
    (tmp_path / "ped.urdf").write_text(text.replace(joint, joint.replace('xyz="0.0 0.0 0.0"', 'xyz="0.0 0.0 0.8"')))
    res = calib.export_calibration(tmp_path / "ped.urdf", "ur-yaml")
    assert any("800 mm" in n and "--base-frame base_link" in n for n in res.notes)
    assert yaml.safe_load(res.text)["kinematics"]["shoulder"]["z"] == pytest.approx(0.889159, abs=1e-12)
    res = calib.export_calibration(tmp_path / "ped.urdf", "ur-yaml", base_frame="base_link")
    assert not any("parent link of the first joint" in n for n in res.notes)
    assert yaml.safe_load(res.text)["kinematics"]["shoulder"]["z"] == pytest.approx(0.089159, abs=1e-12)


def test_ur_yaml_hash_is_the_users_or_a_content_hash(tmp_path):
    """--hash sets kinematics.hash; the default is calib_<digits> and changes with the numbers."""
    cal, _ = _calibrated(tmp_path, erd_urdf("ur5"))
    given = yaml.safe_load(calib.export_calibration(cal, "ur-yaml", kinematics_hash="calib_lab2").text)
    default = yaml.safe_load(calib.export_calibration(cal, "ur-yaml").text)
    nominal = yaml.safe_load(calib.export_calibration(erd_urdf("ur5"), "ur-yaml").text)
    assert given["kinematics"]["hash"] == "calib_lab2"
    assert default["kinematics"]["hash"][6:].isdigit()
    assert default["kinematics"]["hash"] != nominal["kinematics"]["hash"]
    assert default["kinematics"]["hash"] == yaml.safe_load(calib.export_calibration(cal, "ur-yaml").text)["kinematics"]["hash"]
    for bad in ("", "two\nlines", 7):
        with pytest.raises(calib.CalibError, match="hash"):
            calib.export_calibration(cal, "ur-yaml", kinematics_hash=bad)


def test_ur_yaml_with_an_off_axis_flange_projects_it_and_says_so(tmp_path):
    """--flange naming a link off axis 6 (the writer's tool link of a perturbed tool): tool0 is
    its projection, a note says by how much, and tool_in_tool0 still gives the tool exactly."""
    cal, _ = _calibrated(tmp_path, erd_urdf("ur5"))
    res = calib.export_calibration(cal, "ur-yaml", flange_frame="tool")
    assert any("off axis 6" in n for n in res.notes)
    assert res.read_back[0] < TOL and res.read_back[1] < TOL
    with pytest.raises(calib.CalibError, match="not fixed to the link of the last joint"):
        calib.export_calibration(cal, "ur-yaml", flange_frame="forearm_link")
    with pytest.raises(calib.FrameNotFound):
        calib.export_calibration(cal, "ur-yaml", flange_frame="no_such_link")


@pytest.mark.parametrize("urdf, reason", [
    ("panda", "7 moving joints"),
    (str(BUNDLED_URDF), "joints 3 (joint3) and 4 (joint4) are 90.0 deg apart"),
])
def test_ur_yaml_refuses_a_chain_that_is_not_ur_like(urdf, reason):
    """Mapping by chain order needs six revolute joints in the UR structure; a 7-joint arm and a
    spherical-wrist 6R arm are refused, naming the rule."""
    with pytest.raises(calib.ChainError, match=re.escape(reason)) as info:
        calib.export_calibration(urdf if urdf.endswith(".urdf") else erd_urdf(urdf), "ur-yaml")
    assert "maps the chain's moving joints by order" in str(info.value)


# ====================================================================== joint-origins-yaml
def _apply_origins(nominal_urdf, joints: dict) -> str:
    """What a xacro does with the file: each joint of the nominal URDF takes the YAML's origin
    (and axis) text; joints the nominal lacks (links a calibration added) are added with their
    child link."""
    tree = etree.parse(str(nominal_urdf))
    root = tree.getroot()
    have = {el.get("name"): el for el in root.findall("joint")}
    for name, e in joints.items():
        el = have.get(name)
        if el is None:
            etree.SubElement(root, "link", name=e["child"])
            el = etree.SubElement(root, "joint", name=name, type=e["type"])
            etree.SubElement(el, "parent", link=e["parent"])
            etree.SubElement(el, "child", link=e["child"])
        origin = el.find("origin")
        if origin is None:
            origin = etree.SubElement(el, "origin")
        origin.set("xyz", e["xyz"])
        origin.set("rpy", e["rpy"])
        if "axis" in e:
            axis = el.find("axis")
            if axis is None:
                axis = etree.SubElement(el, "axis")
            axis.set("xyz", e["axis"])
    return etree.tostring(root, encoding="unicode")


@pytest.mark.parametrize("arm", ["panda", "bundled"])
def test_joint_origins_yaml_put_into_the_nominal_urdf_gives_the_calibrated_urdf(tmp_path, arm):
    """Panda (a 7-joint arm whose tool side has fixed joints) and the bundled robot, perturbed:
    the nominal URDF with the exported origins has every link of the calibrated URDF where the
    calibrated URDF has it, to 1e-9 m / 1e-9 rad over 20 random configurations."""
    nominal = BUNDLED_URDF if arm == "bundled" else erd_urdf(arm)
    cal, _ = _calibrated(tmp_path, nominal)
    out = tmp_path / "joints.yaml"
    calib.export_calibration(cal, "joint-origins-yaml", out)
    doc = yaml.safe_load(out.read_text())
    cal_model = pin.buildModelFromUrdf(str(cal))
    rebuilt = pin.buildModelFromXML(_apply_origins(nominal, doc["joints"]))
    assert [cal_model.names[j] for j in range(cal_model.njoints)] == [rebuilt.names[j] for j in range(rebuilt.njoints)]
    changed = [n for n, e in doc["joints"].items()
               if n in {el.get("name") for el in etree.parse(str(nominal)).getroot().findall("joint")}
               and e["xyz"] != " ".join(repr(float(v)) for v in
                                       (etree.parse(str(nominal)).getroot().find(f"joint[@name='{n}']/origin")
                                        .get("xyz") or "0 0 0").split())]
    assert len(changed) >= len(doc["chain"])          # the calibration moved the chain's origins
    links = [f.name for f in cal_model.frames if f.type == pin.FrameType.BODY]
    ids_c = {n: cal_model.getFrameId(n) for n in links}
    ids_r = {n: rebuilt.getFrameId(n) for n in links}
    dc, dr_ = cal_model.createData(), rebuilt.createData()
    worst = np.zeros(2)
    for seed in range(20):
        q = pin.randomConfiguration(cal_model, -np.ones(cal_model.nq), np.ones(cal_model.nq)) if seed else \
            pin.neutral(cal_model)
        a, b = _fk(cal_model, dc, ids_c, q), _fk(rebuilt, dr_, ids_r, q)
        for n in links:
            worst = np.maximum(worst, _compare(a[n], b[n]))
    assert worst.max() < TOL, worst


# ====================================================================== mdh-csv
@pytest.mark.parametrize("arm", ["bundled", "ur5", "panda"])
def test_mdh_csv_read_back_gives_the_calibrated_kinematics(tmp_path, arm):
    """read_mdh_csv of the export: calib's MDH model (Eq. 1 products, base and tool transforms of
    Eq. 3) gives Pinocchio's kinematics of the calibrated URDF to 1e-9 m / 1e-9 rad; units mm and
    deg in the column names."""
    cal, _ = _calibrated(tmp_path, BUNDLED_URDF if arm == "bundled" else erd_urdf(arm))
    out = tmp_path / "mdh.csv"
    calib.export_calibration(cal, "mdh-csv", out)
    header = next(l for l in out.read_text().splitlines() if not l.startswith("#")).split(",")
    assert header[3:8] == ["theta_deg", "d_mm", "a_mm", "alpha_deg", "beta_deg"]
    model = calib.read_mdh_csv(out)
    chain = read_urdf_chain(cal)
    assert model.joint_names == tuple(j.name for j in chain.joints)
    Q = calib.load_robot(cal).random_configurations(20, 4)
    T_urdf = chain.T_meas_tool(Q)
    worst = np.max([_compare(model.T_meas_tool(q), T) for q, T in zip(Q, T_urdf)], axis=0)
    assert worst.max() < TOL, worst


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    """A calibration of the bundled robot (paper deviations, 40 simulated poses): its URDF and
    JSON report."""
    d = tmp_path_factory.mktemp("cal")
    robot = calib.load_robot(BUNDLED_URDF)
    meas = calib.simulate_measurements(apply_deviations(robot, PAPER_DEVIATIONS), robot.random_configurations(40, 1),
                                       rng=2)
    res = calib.calibrate(robot, meas, cv=0)
    res.write_urdf(d / "cal.urdf")
    report = calib.build_report(res, meas)
    (d / "report.json").write_text(json.dumps(report))
    return d / "cal.urdf", d / "report.json", res


def test_mdh_csv_with_the_report_holds_its_values_and_standard_deviations(calibration, tmp_path):
    """With --report: each free parameter's std (1 sigma) is the report's, in the CSV's units;
    fixed ones are empty; the values read back give the calibrated URDF's kinematics."""
    urdf, report, res = calibration
    out = tmp_path / "mdh.csv"
    calib.export_calibration(urdf, "mdh-csv", out, report=report)
    lines = [l for l in out.read_text().splitlines() if not l.startswith("#")]
    rows = [dict(zip(lines[0].split(","), l.split(","))) for l in lines[1:]]
    joints = [r for r in rows if r["item"] == "joint"]
    base = next(r for r in rows if r["item"] == "base")
    tool = next(r for r in rows if r["item"] == "tool")
    scale = {"m": 1e3, "rad": 180 / math.pi}
    checked = 0
    for p in res.parameters:
        meta = res.robot.parameters[res.robot.index(p.name)]
        if meta.group == "joint":
            cell = joints[meta.joint - 1][f"{meta.kind}_std_{'mm' if p.unit == 'm' else 'deg'}"]
        else:
            row = base if meta.group == "u" else tool
            kind = {"alpha": "rz", "beta": "ry", "gamma": "rx"}.get(meta.kind, meta.kind)
            cell = row[f"{kind}_std_{'mm' if p.unit == 'm' else 'deg'}"]
        if p.free:
            assert float(cell) == pytest.approx(p.std * scale[p.unit], rel=1e-12), p.name
            checked += 1
        else:
            assert cell == "", p.name
    assert checked == len(res.free) > 20
    model = calib.read_mdh_csv(out)
    assert float(joints[1]["a_mm"]) == pytest.approx(res.robot.value("a2") * 1e3, rel=1e-12)
    Q = res.robot.random_configurations(10, 5)
    T_urdf = read_urdf_chain(urdf).T_meas_tool(Q)
    worst = np.max([_compare(model.T_meas_tool(q), T) for q, T in zip(Q, T_urdf)], axis=0)
    assert worst.max() < TOL, worst


def test_mdh_csv_refuses_a_report_of_another_calibration(calibration, tmp_path):
    """A report whose parameters give other kinematics than the URDF (here a2 changed by 0.1 mm)
    is refused, naming the difference; nothing written."""
    urdf, report, _ = calibration
    doc = json.loads(report.read_text())
    for p in doc["parameters"]:
        if p["name"] == "a2":
            p["identified"] += 0.1
    other = tmp_path / "other.json"
    other.write_text(json.dumps(doc))
    out = tmp_path / "mdh.csv"
    with pytest.raises(calib.CalibError, match=r"do not describe .* kinematics differ by 0\.1"):
        calib.export_calibration(urdf, "mdh-csv", out, report=other)
    assert not out.exists()
    with pytest.raises(calib.CalibError, match="not a JSON report"):
        calib.export_calibration(urdf, "mdh-csv", out, report=urdf)
    # a touch calibration's report (free parameters only, SI values without units)
    touch = tmp_path / "touch.json"
    touch.write_text(json.dumps({"kind": "touch", "parameters": [{"name": "theta1", "value": 0.001, "std": 1e-5}]}))
    with pytest.raises(calib.CalibError, match="touch calibration .* export without --report"):
        calib.export_calibration(urdf, "mdh-csv", out, report=touch)
    assert not out.exists()


def test_read_mdh_csv_names_row_and_column_of_a_bad_cell(tmp_path):
    text = calib.export_calibration(BUNDLED_URDF, "mdh-csv").text
    bad = tmp_path / "bad.csv"
    bad.write_text(text.replace("joint,joint2,revolute,", "joint,joint2,revolute,x", 1))
    line = next(k for k, l in enumerate(bad.read_text().splitlines(), 1) if l.startswith("joint,joint2"))
    with pytest.raises(calib.MeasurementFormatError, match=rf"row {line}, column 'theta_deg': 'x.*' is not a finite"):
        calib.read_mdh_csv(bad)


# ====================================================================== the command
def test_export_command_writes_and_refuses_bad_input_with_one_line(tmp_path, capsys):
    """One run that writes, then each kind of bad input: exit 2, one line on stderr, no file
    written and the input untouched."""
    from calib.cli.main import main

    def _run(*argv):
        code = main(["export", *map(str, argv)])
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(argv, code, out, err)

    cal, _ = _calibrated(tmp_path, erd_urdf("ur5"))
    before = cal.read_bytes()
    ok = _run(cal, "--format", "ur-yaml", "-o", tmp_path / "k.yaml", "--hash", "calib_1")
    assert ok.returncode == 0, ok.stderr
    assert ok.stdout.startswith(f"wrote {tmp_path / 'k.yaml'} (ur-yaml; read back")
    assert yaml.safe_load((tmp_path / "k.yaml").read_text())["kinematics"]["hash"] == "calib_1"
    (tmp_path / "not.urdf").write_text("x,y\n1,2\n")
    cases = [
        ((tmp_path / "not.urdf", "--format", "mdh-csv", "-o", tmp_path / "a.csv"), "malformed XML"),
        ((cal, "--format", "dh", "-o", tmp_path / "b.csv"), "invalid choice"),
        ((erd_urdf("panda"), "--format", "ur-yaml", "-o", tmp_path / "c.yaml"), "not a UR-like chain"),
        ((cal, "--format", "mdh-csv", "-o", cal), "refusing to overwrite an input"),
        ((cal, "--format", "mdh-csv", "-o", tmp_path / "d.csv", "--hash", "x"), "--hash applies to --format ur-yaml"),
    ]
    for argv, message in cases:
        out = _run(*argv)
        assert out.returncode == 2, (argv, out.stderr)
        assert message in out.stderr.splitlines()[-1], out.stderr
        assert len([l for l in out.stderr.splitlines() if l.startswith("calib: error")]) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["calibrated.urdf", "k.yaml", "not.urdf"]
    assert cal.read_bytes() == before


def test_mdh_csv_of_a_calibration_of_several_targets(tmp_path):
    """Three reflectors (targets A, B, C): one tool row per target, named by its id, with the
    report's std; read back, a model of the three targets with the calibrated URDF's kinematics
    (each target's link) to 1e-9 m / rad."""
    from calib.io.exports.mdh import kinematics_difference

    robot = calib.load_robot(BUNDLED_URDF).with_target_offsets({"A": [0, 0, 0], "B": [0.05, 0, 0.02],
                                                                "C": [0, 0.05, 0]})
    true = apply_deviations(robot, random_deviations(robot, 5e-4, rng=3))
    meas = calib.simulate_measurements(true, robot.random_configurations(60, 1), rng=2,
                                       targets=[("A", "B", "C")[k % 3] for k in range(60)])
    res = calib.calibrate(robot, meas, cv=0)
    res.write_urdf(tmp_path / "cal.urdf")
    (tmp_path / "r.json").write_text(json.dumps(calib.build_report(res, meas)))
    calib.export_calibration(tmp_path / "cal.urdf", "mdh-csv", tmp_path / "mdh.csv", report=tmp_path / "r.json")
    rows = [l.split(",") for l in (tmp_path / "mdh.csv").read_text().splitlines() if l.startswith("tool,")]
    assert [r[1] for r in rows] == ["A", "B", "C"]
    header = next(l for l in (tmp_path / "mdh.csv").read_text().splitlines() if l.startswith("item,")).split(",")
    assert float(rows[1][header.index("x_std_mm")]) == pytest.approx(res.parameter("v_x@B").std * 1e3, rel=1e-12)
    back = calib.read_mdh_csv(tmp_path / "mdh.csv")
    assert back.targets == ("A", "B", "C")
    dp, dr = kinematics_difference(back, calib.load_robot(tmp_path / "cal.urdf"), n=10)
    assert dp < TOL and dr < TOL


def test_mdh_csv_of_tiago_whose_tool_frame_is_at_zyx_gimbal_lock(tmp_path):
    """TIAGo's hand_palm_link is turned by -90 deg about y (1.2e-11 rad from the ZYX lock): its
    mdh-csv reads back to 1e-9 (it was refused: 'read back differs ... by 1.73e-05 rad')."""
    from conftest import erd_urdf

    out = tmp_path / "tiago.csv"
    calib.export_calibration(erd_urdf("tiago"), "mdh-csv", out)
    assert out.exists() and "tool," in out.read_text()
