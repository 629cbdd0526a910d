"""API fuzz (issues 13 and 23): every public function, constructor and method of calib, each
argument replaced in turn by each of a set of hostile values, raises a :class:`calib.CalibError`
or succeeds, never a bare TypeError / ValueError / AttributeError / IndexError / KeyError; a
model it returns holds finite values only (``with_changes(d2=nan)`` returned a NaN model).

The table covers every callable name of ``calib.__all__`` (a test fails when a new public name
has no entry) and the public methods of the values the API returns. Before issue 23's fixes
the same fuzz found 944 bare exceptions in 3,456 calls; the old fuzz covered ten functions.
"""
from __future__ import annotations

import inspect
import signal
import warnings

import numpy as np
import pytest

import calib
from calib.model.kinematics import ChainKinematics
from calib.model.simulate import PAPER_DEVIATIONS, apply_deviations
from calib.solvers.problem import Problem

from conftest import BUNDLED_URDF

HOSTILE = [None, "x", "", float("nan"), float("inf"), -1, 0, 10 ** 30, [], {}, ("x",), object(), True, 1e308,
           np.full((2, 6), np.nan), b"x"]
#: Public classes whose instances calib builds (results and parsed files): their constructors
#: are not fuzzed (they take what calib computed), their public methods are.
BUILT_BY_CALIB = {"IdentifiabilityReport", "CalibrationResult", "ParameterEstimate", "TargetAccuracy",
                  "RecordedFrames", "PoseDesign", "CompensationResult", "PaperLMResult", "GravityModel",
                  "CompensationTargets", "AccuracyStats", "ExportResult", "MeasurementFrame", "FeatureFit",
                  "XacroText", "MeasurementPlan", "TouchPlan"}
#: Per call: a result slower than this is a failure (10**30 poses, rounds, candidates...).
CALL_LIMIT_S = 10


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    """{label: (callable, good keyword arguments)} over the whole public API, and the folder the
    calls run in (a path "x" is a valid file name: written there)."""
    d = tmp_path_factory.mktemp("fuzz")
    robot = calib.load_robot(BUNDLED_URDF)
    true = apply_deviations(robot, PAPER_DEVIATIONS)
    meas = calib.simulate_measurements(true, robot.random_configurations(30, 1), rng=2)
    calib.write_measurements(d / "m.csv", meas)
    calib.write_poses(d / "p.csv", robot, meas.q[:3])
    res = calib.calibrate(robot, meas, params="base", cv=0)
    q = np.zeros((2, 6))
    T = np.stack([robot.T_meas_tool(x) for x in meas.q[:2]])
    design = calib.design_poses(robot, 30, candidates=60, seed=0)
    comp = calib.compensate(res.robot, robot, meas.q[:2])
    mframe = calib.robot_base_frame(res.robot, robot, covariance=res.covariance, free=res.free)
    ident = calib.analyze_identifiability(robot, n_poses=20)
    idx = robot.indices(res.free)
    prob = Problem(ChainKinematics(robot), meas.q, meas.position, meas.rotation, robot.values, idx, 2e-5, 2e-3)
    angular = np.array([robot.parameters[k].is_angular for k in idx])
    gm = calib.GravityModel.for_robot(robot)
    mdh = robot.mdh_table()
    point = calib.Feature("point", "P1")
    touch = calib.simulate_touch(robot, [point], [6], rng=0).data
    calib.write_touch(d / "t.csv", touch, robot)
    calib.export_calibration(BUNDLED_URDF, "mdh-csv", d / "mdh.csv")
    touch_res = calib.calibrate(robot, touch, params="tool", cv=0)
    (d / "log.csv").write_text("time_s,q1_deg,q2_deg,q3_deg,q4_deg,q5_deg,q6_deg\n0,0,0,0,0,0,0\n0.01,1,0,0,0,0,0\n")
    (d / "trk.csv").write_text("time_s,point,target,x_mm,y_mm,z_mm\n0.002,P1_A,A,441,0,-36.5\n")
    timed = calib.ReadOptions(join="nearest-time", time="time_s", max_gap=0.005)
    # a xacro and a bag (issue 41): the description's own URDF, wrapped; a short ROS 2 bag
    (d / "robot.urdf.xacro").write_text(BUNDLED_URDF.read_text().replace(
        "<robot ", '<robot xmlns:xacro="http://www.ros.org/wiki/xacro" ', 1))
    xacro_text = calib.expand_xacro(d / "robot.urdf.xacro")
    from rosbag_writer import T0_NS, joint_state, pose_stamped, typestore, write_bag

    ts = typestore("mcap")
    bag_messages = []
    for i in range(100):                      # 1 s still at meas.q[0], the pose measured 8 times
        msgtype, msg = joint_state(ts, T0_NS + 10 ** 7 * i, robot.joint_names, meas.q[0])
        bag_messages.append(("/joint_states", msgtype, T0_NS + 10 ** 7 * i, msg))
    for i in range(1, 9):
        msgtype, msg = pose_stamped(ts, T0_NS + 10 ** 8 * i + 10 ** 6, "tracker", T[0])
        bag_messages.append(("/pose", msgtype, T0_NS + 10 ** 8 * i + 10 ** 6, msg))
    bag = write_bag(d / "bag", "mcap", sorted(bag_messages, key=lambda m: m[2]), ts)
    # a plan (issue 40): a UR5 of example-robot-data (collision meshes), a tracker, few candidates
    from calib.io.cell import Nest, Target, Tracker
    from conftest import erd_urdf

    ur5 = calib.load_robot(erd_urdf("ur5"), tool_frame="tool0")
    tracker = dict(instrument=Tracker([2.0, 0.0, 0.7]), targets=(Target("S", [0.0, 0.0, 0.05]),),
                   home=np.radians([0.0, -90.0, 0.0, -90.0, 0.0, 0.0]))
    cell = calib.Cell(**tracker)
    (d / "cell.yaml").write_text("tracker:\n  position_mm: [2000, 0, 700]\n")
    plan_kw = dict(robot=ur5, n=10, cell=cell, candidates=80, seed=0, exchange_passes=0, travel_budget=0.0)
    plan = calib.plan_measurements(**plan_kw)
    nest = calib.Cell(features=(Nest("N", [0.4, 0.0, 0.3], poses=3),), tip=np.array([0.0, 0.0, 0.15]))
    touch_kw = dict(robot=ur5, cell=nest, candidates=25, seed=0)
    tplan = calib.plan_touch(**touch_kw)
    t = {
        "load_robot": (calib.load_robot, dict(urdf_path=BUNDLED_URDF)),
        "robot_path": (calib.robot_path, dict(robot=BUNDLED_URDF)),
        "ChainJoint": (calib.ChainJoint, dict(name="j", kind="revolute", lower=-1.0, upper=1.0)),
        "Parameter": (calib.Parameter, dict(name="d1", group="joint", kind="d", joint=1, unit="m")),
        "RobotModel": (calib.RobotModel, dict(joints=robot.joints, parameters=robot.parameters, values=robot.values)),
        "identification_jacobian": (calib.identification_jacobian, dict(robot=robot, Q=q)),
        "analyze_identifiability": (calib.analyze_identifiability, dict(robot=robot, n_poses=20)),
        "Measurements": (calib.Measurements, dict(q=meas.q, position=meas.position, rotation=meas.rotation)),
        "read_measurements": (calib.read_measurements, dict(csv_path=d / "m.csv", robot=robot)),
        "write_measurements": (calib.write_measurements, dict(path=d / "w.csv", measurements=meas)),
        "ReadOptions": (calib.ReadOptions, {}),
        "ReadOptions.nearest_time": (calib.ReadOptions, dict(join="nearest-time", time="time_s", max_gap=0.01)),
        "ReadOptions.target_from": (calib.ReadOptions, dict(key="point", target_from=r"(?P<key>P\d+)_(?P<target>\w+)")),
        "read_measurements.nearest_time": (calib.read_measurements, dict(csv_path=d / "log.csv", robot=robot,
                                                                         tracker=d / "trk.csv", options=timed)),
        "read_targets": (calib.read_targets, dict(path=d / "p.csv", nominal=robot)),
        "write_compensation": (calib.write_compensation, dict(path=d / "c.csv", result=comp)),
        "calibrate": (calib.calibrate, dict(robot=robot, measurements=meas, params="base", cv=0)),
        "evaluate": (calib.evaluate, dict(robot=robot, measurements=meas)),
        "apply_deviations": (calib.apply_deviations, dict(robot=robot, deviations={"d2": 1e-4})),
        "random_deviations": (calib.random_deviations, dict(robot=robot, scale=1e-4)),
        "simulate_measurements": (calib.simulate_measurements, dict(true_robot=robot, Q=q)),
        "write_calibrated_urdf": (calib.write_calibrated_urdf, dict(robot=res.robot, path=d / "c.urdf")),
        "check_writable": (calib.check_writable, dict(robot=robot)),
        "build_report": (calib.build_report, dict(result=res, measurements=meas)),
        "render_html": (calib.render_html, dict(report=calib.build_report(res, meas), text="t")),
        "design_poses": (calib.design_poses, dict(robot=robot, n=30, candidates=60, seed=0)),
        "select_poses": (calib.select_poses, dict(robot=robot, n=30, candidates=60, seed=0)),
        "read_poses": (calib.read_poses, dict(path=d / "p.csv", robot=robot)),
        "write_poses": (calib.write_poses, dict(path=d / "w2.csv", robot=robot, q=q)),
        "compensate": (calib.compensate, dict(calibrated=res.robot, nominal=robot, q_nominal=q)),
        "compensate_poses": (calib.compensate_poses, dict(calibrated=res.robot, T_meas_tool=T)),
        "with_frame_uncertainty": (calib.with_frame_uncertainty, dict(result=comp, T_meas_base=np.eye(4),
                                                                      covariance=np.eye(6) * 1e-10)),
        "pose_targets_in_base": (calib.pose_targets_in_base, dict(T_meas_base=np.eye(4), T_meas_tool=T)),
        "robot_base_frame": (calib.robot_base_frame, dict(calibrated=res.robot, nominal=robot,
                                                          covariance=res.covariance, free=res.free)),
        "in_base_frame": (calib.in_base_frame, dict(robot=res.robot, frame=np.eye(4))),
        "MeasurementFrame.format": (mframe.format, {}),
        "MeasurementFrame.to_dict": (mframe.to_dict, {}),
        "MeasurementFrame.xyz_rpy": (mframe.xyz_rpy, {}),
        "CalibrationResult.base_robot": (res.base_robot, {}),
        "CalibrationResult.flange_robot": (res.flange_robot, {}),
        "CalibrationResult.write_urdf_only": (res.write_urdf_only, dict(path=d / "r2.urdf")),
        "CalibrationResult.urdf_text": (res.urdf_text, dict(measurement_link=None)),
        "Payload": (calib.Payload, dict(mass=1.0)),
        "PaperLMOptions": (calib.PaperLMOptions, {}),
        "paper_lm": (calib.paper_lm, dict(problem=prob, x0=robot.values[idx], angular=angular)),
        "paper_cross_lm": (calib.paper_cross_lm, dict(problem=prob, x0=robot.values[idx], angular=angular)),
        "Feature": (calib.Feature, dict(kind="point", id="P1")),
        "TouchData": (calib.TouchData, dict(q=touch.q, feature=touch.feature, features=touch.features)),
        "simulate_touch": (calib.simulate_touch, dict(true_robot=robot, features=[point], rows=[6], rng=0)),
        "read_touch": (calib.read_touch, dict(csv_path=d / "t.csv", robot=robot)),
        "write_touch": (calib.write_touch, dict(path=d / "t2.csv", data=touch, robot=robot)),
        "calibrate.touch": (calib.calibrate, dict(robot=robot, measurements=touch, params="tool", cv=0)),
        "export_calibration": (calib.export_calibration, dict(urdf_path=BUNDLED_URDF, format="mdh-csv", output=d / "e.csv")),
        "read_mdh_csv": (calib.read_mdh_csv, dict(path=d / "mdh.csv")),
        "clear_caches": (calib.clear_caches, {}),
        "expand_xacro": (calib.expand_xacro, dict(path=d / "robot.urdf.xacro", args={"a": "1"}, packages={})),
        "RosPackages": (calib.RosPackages, {}),
        "RosPackages.from_options": (calib.RosPackages.from_options, dict(packages={"p": d}, environ={})),
        "RosPackages.table": (calib.RosPackages.from_options(environ={}).table, dict(description=d / "robot.urdf.xacro")),
        "RosPackages.searched": (calib.RosPackages().searched, {}),
        "XacroText.document": (xacro_text.document, {}),
        "XacroText.kinematics_file": (xacro_text.kinematics_file, {}),
        "BagOptions": (calib.BagOptions, dict(pose="/pose", min_still_s=0.2)),
        "read_bag": (calib.read_bag, dict(path=bag, robot=robot, options=calib.BagOptions(pose="/pose", min_still_s=0.2))),
        "Cell": (calib.Cell, tracker),
        "read_cell": (calib.read_cell, dict(path=d / "cell.yaml")),
        "plan_measurements": (calib.plan_measurements, plan_kw),
        "plan_touch": (calib.plan_touch, touch_kw),
        "MeasurementPlan.format": (plan.format, {}),
        "MeasurementPlan.accuracy_loss": (plan.accuracy_loss, dict(where="cell")),
        "TouchPlan.format": (tplan.format, {}),
        # methods of the values the API returns
        "TouchData.subset": (touch.subset, dict(keep=np.ones(touch.n_rows, bool))),
        "TouchData.rows_of": (touch.rows_of, dict(k=0)),
        "CalibrationResult.format.touch": (touch_res.format, {}),
        "CalibrationResult.group": (touch_res.group, dict(name="touch")),
        "CalibrationResult.touch_dict": (touch_res.touch_dict, {}),
        "FeatureFit.to_dict": (touch_res.features.to_dict, {}),
        "FeatureFit.format": (touch_res.features.format, {}),
        "Measurements.from_arrays": (calib.Measurements.from_arrays, dict(q=meas.q, position=meas.position)),
        "Measurements.subset": (meas.subset, dict(index_or_mask=[0, 1])),
        "Measurements.calibration": (meas.calibration, {}),
        "Measurements.validation": (meas.validation, {}),
        "AccuracyStats.from_residuals": (calib.AccuracyStats.from_residuals, dict(dp=np.zeros((2, 3)), dr=None)),
        "AccuracyStats.subset": (res.after.subset, dict(mask=np.ones(30, bool))),
        "AccuracyStats.to_dict": (res.after.to_dict, {}),
        "PoseDesign.evaluate": (design.evaluate, dict(Q=q)),
        "PoseDesign.format": (design.format, {}),
        "CompensationResult.format": (comp.format, {}),
        "CompensationResult.describe": (comp.describe, dict(k=0)),
        "CompensationResult.counts": (comp.counts, {}),
        "IdentifiabilityReport.format": (ident.format, {}),
        "IdentifiabilityReport.to_json": (ident.to_json, {}),
        "IdentifiabilityReport.to_dict": (ident.to_dict, {}),
        "CalibrationResult.format": (res.format, {}),
        "CalibrationResult.to_json": (res.to_json, {}),
        "CalibrationResult.to_dict": (res.to_dict, {}),
        "CalibrationResult.parameter": (res.parameter, dict(name="d2")),
        "CalibrationResult.write_urdf": (res.write_urdf, dict(path=d / "r.urdf")),
        "CalibrationResult.compliance_record": (res.compliance_record, {}),
        "GravityModel.for_robot": (calib.GravityModel.for_robot, dict(robot=robot)),
        "GravityModel.torques": (gm.torques, dict(Q=q)),
        "GravityModel.from_chain": (calib.GravityModel.from_chain, dict(chain=robot.source)),
        "TargetAccuracy.to_dict": (calib.TargetAccuracy("a", res.after, res.after).to_dict, {}),
        "Payload.to_dict": (calib.Payload(1.0).to_dict, {}),
        "RecordedFrames.element": (calib.check_writable(robot).element, {}),
        "RecordedFrames.to_dict": (calib.check_writable(robot).to_dict, {}),
    }
    robot_args = {
        "random_configurations": dict(n=3), "with_compliance": dict(gravity=gm), "with_targets": dict(targets=["a", "b"]),
        "T_base_flange": dict(q=np.zeros(6)), "T_meas_tool": dict(q=np.zeros(6)), "index": dict(name="d2"),
        "indices": dict(names=["d2"]), "value": dict(name="d2"), "with_values": dict(values=robot.values),
        "with_target_offsets": dict(offsets={"a": [0, 0, 0], "b": [0, 0, 0.1]}), "target_rows": dict(target_ids=None),
        "has_beta": dict(joint=2), "with_changes": dict(d2=1e-4),
        "from_mdh": dict(joints=robot.joints, **{k: mdh[k] for k in ("theta", "d", "a", "alpha")})}
    for name, _ in inspect.getmembers(calib.RobotModel, callable):
        if not name.startswith("_"):
            t[f"RobotModel.{name}"] = (getattr(robot, name), robot_args.get(name, {}))
    return t, d


@pytest.mark.slow
def test_the_fuzz_covers_every_public_name(table):
    """Every callable of calib.__all__ (exceptions aside) has an entry, or is a value calib
    builds whose public methods have entries."""
    t, _ = table
    names = {label.split(".")[0] for label in t}
    missing = []
    for n in calib.__all__:
        v = getattr(calib, n)
        if not callable(v) or (inspect.isclass(v) and issubclass(v, Exception)):
            continue
        if n in BUILT_BY_CALIB:
            methods = [m for m, _ in inspect.getmembers(v, callable) if not m.startswith("_")]
            missing += [f"{n}.{m}" for m in methods if f"{n}.{m}" not in t and m not in ("has_compliance",)]
        elif n not in names:
            missing.append(n)
    assert missing == []


def _call(fn, kwargs, bare, label, name, value):
    signal.alarm(CALL_LIMIT_S)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            out = fn(**{**kwargs, name: value})
        if isinstance(out, calib.RobotModel) and not np.isfinite(out.values).all():
            bare.append(f"{label}({name}={value!r:.40}): a model with non-finite values")
    except calib.CalibError:
        pass
    except TimeoutError:
        bare.append(f"{label}({name}={value!r:.40}): still running after {CALL_LIMIT_S} s")
    except Exception as exc:  # noqa: BLE001 - what the test looks for
        bare.append(f"{label}({name}={value!r:.40}): {type(exc).__name__}: {exc}")
    finally:
        signal.alarm(0)


@pytest.mark.slow
def test_api_fuzz_never_raises_a_bare_exception(table, monkeypatch):
    """3,000-odd calls (2 s): a CalibError or success, a finite model, within the call limit."""
    t, d = table
    monkeypatch.chdir(d)

    def alarm(*_):
        raise TimeoutError

    old = signal.signal(signal.SIGALRM, alarm)
    bare: list[str] = []
    try:
        for label, (fn, kwargs) in t.items():
            params = inspect.signature(fn).parameters.values()
            names = [p.name for p in params if p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)]
            if any(p.kind == p.VAR_KEYWORD for p in params):
                names.append("d2")      # (with_changes(**deltas), from_mdh(**fields))
            for name in names:
                for value in HOSTILE:
                    _call(fn, kwargs, bare, label, name, value)
    finally:
        signal.signal(signal.SIGALRM, old)
    assert bare == []


def test_no_nan_model_from_a_nan_argument(table):
    """with_changes(d2=nan) returned a model of NaN values silently; with_values and the
    constructor took NaN too."""
    t, _ = table
    robot = t["RobotModel.with_changes"][0].__self__
    for call in (lambda: robot.with_changes(d2=float("nan")), lambda: robot.with_changes(a3=float("inf")),
                 lambda: robot.with_values(np.full(robot.n_params, np.nan))):
        with pytest.raises(calib.ParameterError, match=r"finite"):
            call()
