"""Joint compliance under gravity (calib.model.compliance): torques, Jacobian columns, identification,
sidecar and compensation, bad input."""
from __future__ import annotations

import json

import numpy as np
import pinocchio as pin
import pytest

import calib
from calib.cli.main import main
from calib.io.compliance_file import apply_record, read_compliance, sidecar_path
from calib.model.compliance import GravityModel, Payload, effective_configurations, with_gravity
from calib.model.jacobian import pose_jacobian
from calib.model.kinematics import ChainKinematics
from calib.model.spatial import log3_batch

PAYLOAD = Payload(10.0, np.array([0.0, 0.03, 0.1]))
TRUE_C = np.array([0.0, 3e-6, 4e-6, 5e-6, 0.0, 0.0])        # rad/(N m)
SIGMA_POS, SIGMA_ROT = 0.02e-3, 0.0002


@pytest.fixture(scope="module")
def ur10():
    return calib.load_robot("ur10")


@pytest.fixture(scope="module")
def ur10_c(ur10):
    return with_gravity(ur10, payload=PAYLOAD, values=TRUE_C)


def test_model_without_compliance_is_unchanged(ur10):
    # the default model has no c<i>: same names, count and kinematics as before
    assert ur10.n_params == 38 and not any(n.startswith("c") for n in ur10.names)
    assert ChainKinematics(ur10).compliance is None
    rc = with_gravity(ur10, payload=PAYLOAD)
    assert rc.n_params == 44 and rc.names[-6:] == ("c1", "c2", "c3", "c4", "c5", "c6")
    assert rc.geometry().names == ur10.names and rc.geometry().gravity is None
    # zero compliance: the same poses to rounding
    Q = ur10.random_configurations(5, 3)
    _, p0 = ChainKinematics(ur10).frame_poses(Q)
    _, p1 = ChainKinematics(rc).frame_poses(Q)
    assert np.abs(p1 - p0).max() < 1e-15


def test_torques_are_minus_the_potential_gradient(ur10):
    # tau = -dV/dq (V the potential energy of links and payload), by central differences of
    # Pinocchio's potential energy: checks the sign convention and the payload placement
    gm = GravityModel.for_robot(ur10, payload=PAYLOAD)
    Q = ur10.random_configurations(4, 7)
    tau = gm.torques(Q)
    data = gm.model.createData()
    h = 1e-6
    for k, q in enumerate(Q):
        fd = []
        for i in range(6):
            e = np.zeros(6)
            e[i] = h
            vp = pin.computePotentialEnergy(gm.model, data, gm.chain.configuration(q + e))
            vm = pin.computePotentialEnergy(gm.model, data, gm.chain.configuration(q - e))
            fd.append(-(vp - vm) / (2 * h))
        assert np.abs(tau[k] - fd).max() < 1e-5          # N m; torques ~100 N m
    # joint 1 turns about the vertical: gravity exerts no torque on it
    assert np.abs(tau[:, 0]).max() < 1e-9
    # the payload adds 10 kg: joint 2's torque changes by about m g r (r up to ~1.3 m)
    tau0 = GravityModel.for_robot(ur10).torques(Q)
    assert 1.0 < np.abs(tau - tau0)[:, 1].max() < 10.0 * 9.81 * 1.4


def test_torques_are_cached_by_content_and_shared(ur10):
    # the cache (whole arrays and single configurations) returns Pinocchio's torques at each
    # configuration, for the array, a subset of its rows, and new rows mixed in; every
    # kinematics object of a model uses its one gravity model's cache
    gm = GravityModel.for_robot(ur10, payload=PAYLOAD)
    Q = ur10.random_configurations(30, 11)
    data = gm.model.createData()
    direct = np.array([-pin.computeGeneralizedGravity(gm.model, data, gm.chain.configuration(q)) for q in Q])
    tau = gm.torques(Q)
    assert np.array_equal(tau, direct)
    assert gm.torques(Q.copy()) is tau                                   # same content: same array
    mixed = np.vstack([Q[::3], ur10.random_configurations(4, 12)])
    d_new = [-pin.computeGeneralizedGravity(gm.model, data, gm.chain.configuration(q)) for q in mixed[-4:]]
    assert np.array_equal(gm.torques(mixed), np.vstack([direct[::3], d_new]))
    rc = with_gravity(ur10, payload=PAYLOAD, values=TRUE_C)
    assert ChainKinematics(rc).compliance.gravity_model is ChainKinematics(rc).compliance.gravity_model



def test_gravity_models_are_shared_per_chain_payload_and_gravity_and_go_with_the_chain(tmp_path):
    """from_chain returns the model it made for the same chain, payload and gravity (the joint-term
    candidates and the final fit share its torques), another for a payload of the same mass with
    another centre of mass; the models are kept on the chain: dropping the robot frees them and
    their torque memos (a process-wide table held them, 95 MB for 400k rows), and a pickled robot
    does not carry them."""
    import gc
    import pickle
    import weakref

    robot = calib.load_robot("ur10")
    gm = GravityModel.for_robot(robot, payload=PAYLOAD)
    assert GravityModel.for_robot(robot, payload=Payload(10.0, np.array([0.0, 0.03, 0.1]))) is gm
    other = GravityModel.for_robot(robot, payload=Payload(10.0, np.array([0.0, 0.03, 0.2])))
    Q = robot.random_configurations(20, 3)
    assert np.max(np.abs(other.torques(Q) - gm.torques(Q))) > 0.1          # N m: another load
    assert GravityModel.for_robot(robot, payload=PAYLOAD, gravity=[0.0, 0.0, -9.0]) is not gm
    size = len(pickle.dumps(robot))
    gm.torques(robot.random_configurations(2000, 4))                       # (a memo of 2,000 rows)
    assert len(pickle.dumps(robot)) == size
    chain = weakref.ref(robot.source)
    del robot, gm, other
    calib.load_robot("panda")       # (the reader keeps its last chain)
    gc.collect()
    assert chain() is None


def test_compliance_jacobian_matches_finite_differences(ur10_c):
    Q = ur10_c.random_configurations(6, 11)
    kin = ChainKinematics(ur10_c)
    _, _, J = pose_jacobian(kin, Q)
    v = ur10_c.values
    for name in ("c2", "c3", "c4", "c6", "theta2", "a2"):
        k = ur10_c.index(name)
        h = 1e-7
        vp, vm = v.copy(), v.copy()
        vp[k] += h
        vm[k] -= h
        kin.set_values(vp)
        Rp, pp = kin.frame_poses(Q)
        kin.set_values(vm)
        Rm, pm = kin.frame_poses(Q)
        dp = (pp - pm) / (2 * h)
        dw = log3_batch(Rp @ np.transpose(Rm, (0, 2, 1))) / (2 * h)
        scale = max(np.abs(J[:, :3, k]).max(), 1.0)
        # central differences of the exact model; relative 1e-6 (rounding of h = 1e-7)
        assert np.abs(dp - J[:, :3, k]).max() < 1e-6 * scale, name
        assert np.abs(dw - J[:, 3:, k]).max() < 1e-6 * max(np.abs(J[:, 3:, k]).max(), 1.0), name
    # the effective joints are q + c tau
    kin.set_values(v)
    tau = ur10_c.gravity.torques(Q)
    assert np.allclose(effective_configurations(ur10_c, Q), Q + TRUE_C * tau, rtol=0, atol=1e-15)


def test_identifiability_reports_unseen_compliance(ur10_c):
    rep = calib.analyze_identifiability(ur10_c, n_poses=60, seed=0)
    unseen = {r.parameter: r for r in rep.unidentifiable}
    assert "c1" in unseen and unseen["c1"].partners == ()          # no torque about the vertical
    assert {"c2", "c3", "c4"} <= set(rep.identifiable)


@pytest.fixture(scope="module")
def loop(ur10, ur10_c):
    true = ur10_c.with_changes(d2=3e-4, a2=-4e-4, theta3=1e-3, alpha2=5e-4)
    Q = ur10.random_configurations(120, 1)
    m = calib.simulate_measurements(true, Q, sigma_pos=SIGMA_POS, sigma_rot=SIGMA_ROT, rng=2,
                                    sets=np.array(["cal"] * 80 + ["val"] * 40))
    geo = calib.calibrate(ur10, m, method="lm", params="base", cv=0, sigma_pos=SIGMA_POS,
                          sigma_rot=SIGMA_ROT)
    comp = calib.calibrate(ur10, m, method="lm", params="base", cv=0, sigma_pos=SIGMA_POS,
                           sigma_rot=SIGMA_ROT, compliance=True, payload=PAYLOAD)
    return true, m, geo, comp


def test_identification_recovers_compliance(loop):
    true, m, geo, comp = loop
    floor = SIGMA_POS * np.sqrt(3)         # RMS length of 3-axis noise: 0.035 mm
    assert geo.validation_after.position["rms"] > 4 * floor          # geometry alone: ~0.33 mm
    assert comp.success and comp.validation_after.position["rms"] < 1.3 * floor
    for name in ("c2", "c3", "c4", "c5", "c6"):
        pe = comp.parameter(name)
        assert pe.free and abs(pe.identified - true.value(name)) < 3 * pe.std, name
    assert comp.parameter("c2").std < 1e-7                            # well seen: 0.02 urad/(N m)
    assert not comp.parameter("c1").free
    assert any("c1" in n and "not identifiable" in n for n in comp.notes)
    d = comp.to_dict()
    assert d["compliance"]["compliance"]["c2"] == pytest.approx(comp.parameter("c2").identified, rel=1e-12)
    assert [p["unit"] for p in d["parameters"] if p["name"] == "c3"] == ["urad/(N m)"]
    assert "geometry only" in d["compliance"]["note"] and "geometry only" in comp.format()


def test_sidecar_round_trip_and_compensation(loop, tmp_path, ur10):
    true, m, _, comp = loop
    out = tmp_path / "cal.urdf"
    comp.write_urdf(out)
    side = sidecar_path(out)
    rec = read_compliance(side)
    assert side.name == "cal.compliance.json"
    assert np.array_equal(rec.values, comp.robot.compliances())
    assert rec.payload.mass == 10.0 and np.allclose(rec.payload.com_tool, PAYLOAD.com_tool, atol=1e-15)
    # the URDF holds the geometry; with the sidecar the model is the identified one
    geo = calib.load_robot(out, base_frame=ur10.base_frame)
    assert geo.n_params == ur10.n_params
    model = apply_record(geo, rec, torques_from=ur10)     # torques of the nominal URDF, as calibrated
    Q = m.q[:20]
    _, p_id = ChainKinematics(comp.robot).frame_poses(Q)
    _, p_rt = ChainKinematics(model).frame_poses(Q)
    assert np.abs(p_rt - p_id).max() < 1e-9          # metres: the URDF round trip (~1e-12)
    # the public model is the fitted one: result.robot.T_meas_tool(q) includes the sag (it left
    # it out before: ~0.3 mm off here), and so does the URDF read with its sidecar
    T_api = np.array([comp.robot.T_meas_tool(q) for q in Q])
    T_rt = np.array([model.T_meas_tool(q) for q in Q])
    assert np.abs(T_api[:, :3, 3] - p_id).max() < 1e-12 and np.abs(T_rt[:, :3, 3] - p_id).max() < 1e-9
    _, p_geo = ChainKinematics(comp.robot.geometry()).frame_poses(Q)
    assert np.linalg.norm(p_geo - p_id, axis=1).max() > 0.1e-3
    # torques from the calibrated URDF instead: its geometry moves them by ~1e-3 (< 1 um here)
    _, p_cal = ChainKinematics(apply_record(geo, rec)).frame_poses(Q)
    assert 1e-9 < np.abs(p_cal - p_id).max() < 1e-6
    # compensation with compliance: the true arm reaches the nominal poses to the calibration's
    # accuracy (Cramer-Rao ~0.01 mm), without it it misses by the sag (~0.3 mm)
    q_nom = ur10.random_configurations(10, 5)
    R_t, p_t = ChainKinematics(ur10).frame_poses(q_nom)
    with_c = calib.compensate(comp.robot, ur10, q_nom)
    no_c = calib.compensate(comp.robot.geometry(), ur10, q_nom)
    ok = with_c.ok & no_c.ok                # near-singular targets are reported, not reached
    assert ok.sum() >= 8
    _, p_a = ChainKinematics(true).frame_poses(with_c.q[ok])
    _, p_b = ChainKinematics(true).frame_poses(no_c.q[ok])
    # (the Newton steps neglect d tau / d q in the Jacobian and still reach 1e-9 m)
    assert with_c.position_error[ok].max() < 1e-9
    assert np.linalg.norm(p_a - p_t[ok], axis=1).max() < 0.05e-3
    assert np.linalg.norm(p_b - p_t[ok], axis=1).max() > 0.1e-3


def test_report_is_a_compliance_file(loop, tmp_path):
    *_, comp = loop
    path = tmp_path / "rep.json"
    path.write_text(comp.to_json())
    assert np.array_equal(read_compliance(path).values, comp.robot.compliances())
    geo_only = tmp_path / "geo.json"
    geo_only.write_text(json.dumps({"status": "converged", "compliance": None}))
    with pytest.raises(calib.ParameterError, match="no compliance record"):
        read_compliance(geo_only)


def test_urdf_without_inertias_uses_the_payload_alone():
    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")
    gm = GravityModel.for_robot(robot, payload=Payload(5.0))
    assert gm.link_mass == 0.0 and "payload alone" in gm.note
    tau = gm.torques(robot.random_configurations(3, 0))
    assert np.abs(tau[:, 1]).max() > 1.0                  # N m from 5 kg


@pytest.mark.parametrize("value, match", [
    ((-1.0, np.zeros(3)), "payload mass must be a finite number of kg >= 0, got -1.0"),
    ((float("nan"), np.zeros(3)), "payload mass must be a finite number"),
    ((1.0, [0.0, np.inf, 0.0]), "payload centre of mass must be 3 finite numbers"),
])
def test_bad_payload(value, match):
    with pytest.raises(calib.ParameterError, match=match):
        Payload(*value)


def test_payload_without_compliance_is_refused(ur10, loop):
    m = loop[1]
    with pytest.raises(calib.ParameterError, match="pass compliance=True"):
        calib.calibrate(ur10, m, payload=PAYLOAD)
    built = calib.RobotModel.from_mdh(ur10.joints, *[ur10.mdh_table()[k] for k in ("theta", "d", "a", "alpha")])
    with pytest.raises(calib.ParameterError, match="needs the robot's URDF"):
        with_gravity(built, payload=PAYLOAD)


@pytest.mark.parametrize("extra, message", [
    (["--payload-kg", "-2"], "--payload-kg -2: expected a finite mass >= 0 kg"),
    (["--payload-kg", "1", "--payload-com-mm", "1,2"], "--payload-com-mm '1,2': expected three"),
    (["--payload-kg", "1", "--gravity", "0,0,nan"], "--gravity '0,0,nan': expected three finite numbers"),
    (["--payload-com-mm", "0,0,1"], "--payload-com-mm without --payload-kg"),
])
def test_cli_bad_compliance_options(tmp_path, capsys, extra, message):
    out = tmp_path / "m.csv"
    code = main(["simulate", "ur10", "-o", str(out), "--poses", "5", *extra])
    err = capsys.readouterr().err
    assert code == 2 and message in err and err.count("\n") == 1
    assert not out.exists()


def test_cli_loop(tmp_path, capsys):
    dev = tmp_path / "dev.json"
    dev.write_text(json.dumps({"c2": 3e-6, "c3": 4e-6, "d2": 3e-4}))
    meas, cal = tmp_path / "m.csv", tmp_path / "cal.urdf"
    assert main(["simulate", "ur10", "-o", str(meas), "--poses", "60", "--deviations", str(dev),
                 "--payload-kg", "10", "--payload-com-mm", "0,0,100", "--sigma-rot-rad", "0.0002"]) == 0
    assert "c2        urad/(N m)             3" in capsys.readouterr().out
    # a payload without --compliance: refused, nothing written
    assert main(["calibrate", "ur10", str(meas), "-o", str(cal), "--payload-kg", "10"]) == 2
    assert "only matter with --compliance" in capsys.readouterr().err and not cal.exists()
    assert main(["calibrate", "ur10", str(meas), "-o", str(cal), "--compliance", "--payload-kg", "10",
                 "--payload-com-mm", "0,0,100", "--params", "base", "--method", "lm", "--cv", "0"]) == 0
    text = capsys.readouterr().out
    assert "cal.compliance.json" in text
    rec = read_compliance(sidecar_path(cal))
    assert rec.values[1] == pytest.approx(3e-6, abs=0.2e-6) and rec.payload.mass == 10.0


def test_cli_simulate_targets_with_compliance(tmp_path, capsys):
    """simulate --target with compliance deviations and a payload, then calibrate --compliance:
    three reflectors measured in position only see the sag of joints 2 and 3."""
    dev = tmp_path / "dev.json"
    dev.write_text(json.dumps({"c2": 3e-6, "c3": 4e-6, "d2": 3e-4, "v_x@B": 2e-4}))
    meas, cal = tmp_path / "m.csv", tmp_path / "cal.urdf"
    assert main(["simulate", "ur10", "-o", str(meas), "--poses", "40", "--deviations", str(dev),
                 "--payload-kg", "10", "--position-only", "--target", "A=100,0,50",
                 "--target", "B=-50,80,50", "--target", "C=0,-70,100"]) == 0
    out = capsys.readouterr().out
    assert "(one row per target, 120 rows)" in out and "v_x@B" in out
    assert main(["calibrate", "ur10", str(meas), "-o", str(cal), "--compliance", "--payload-kg", "10",
                 "--params", "base", "--cv", "0", "--report", str(tmp_path / "r.json")]) == 0
    capsys.readouterr()
    rep = json.loads((tmp_path / "r.json").read_text())
    par = {p["name"]: p for p in rep["parameters"]}
    for name, true in (("c2", 3.0), ("c3", 4.0)):            # urad/(N m)
        assert abs(par[name]["identified"] - true) < 4 * par[name]["std"], name
    assert par["d2"]["deviation"] == pytest.approx(0.3, abs=4 * par["d2"]["std"])   # mm
    assert rep["targets"]["C"]["after"]["n_poses"] == 40
    # evaluate with the sidecar and the nominal URDF's torques: calibrate's numbers, per target too
    side = sidecar_path(cal)
    assert main(["evaluate", str(cal), str(meas), "--json", "--compliance", str(side), "--nominal", "ur10"]) == 0
    ev = json.loads(capsys.readouterr().out)
    for got, want in ((ev["all"], rep["after"]), (ev["targets"]["B"], rep["targets"]["B"]["after"])):
        assert got["n_poses"] == want["n_poses"]
        for k in ("mean", "rms", "max", "min"):
            assert abs(got["position_mm"][k] - want["position_mm"][k]) < 1e-6, k
    # without --nominal the calibrated URDF's tool is target A's: refused, one line
    assert main(["evaluate", str(cal), str(meas), "--compliance", str(side)]) == 2
    err = capsys.readouterr().err
    assert err == (f"calib: error: --compliance: {cal} holds 3 targets and its tool frame is target A's, "
                   f"not the tool the payload was given in: give --nominal NOMINAL.urdf (the URDF "
                   f"calibrate started from) for the gravity torques\n")


def test_targets_keep_the_compliance_parameters(ur10_c):
    multi = ur10_c.with_targets(("A", "B"))
    assert multi.names[-6:] == ("c1", "c2", "c3", "c4", "c5", "c6") and "v_x@B" in multi.names
    assert np.array_equal(multi.compliances(), TRUE_C) and multi.gravity is ur10_c.gravity
    one = multi.for_target("B")
    assert one.names == ur10_c.names and np.array_equal(one.values, ur10_c.values)


@pytest.mark.parametrize("kwargs, match", [
    ({"payload": Payload(1e12)}, "payload of 1e\\+12 kg"),
    ({"payload": Payload(5000.0)}, "10 times the"),                      # 5 kg written in grams
    ({"payload": Payload(5.0, [0.0, 0.0, 112.0])}, "centre of mass 112 m"),
    ({"gravity": [0.0, 0.0, -9810.0]}, "gravity of 9810 m/s\\^2"),
    ({"gravity": [0.0, 0.0, 0.0]}, "gravity of 0 m/s\\^2"),
])
def test_absurd_payload_or_gravity_is_refused(kwargs, match):
    """A 1e12 kg payload collapsed the identifiable set to 3 parameters with exit 0; a payload in
    grams, a centre of mass 112 m away or gravity in mm/s^2 were taken silently."""
    robot = calib.load_robot("ur10")
    with pytest.raises(calib.ParameterError, match=match):
        with_gravity(robot, **kwargs)


def test_gravity_along_plus_z_is_a_ceiling_mount_and_accepted():
    robot = with_gravity(calib.load_robot("ur10"), payload=Payload(5.0), gravity=[0.0, 0.0, 9.81])
    assert np.allclose(robot.gravity.gravity, [0.0, 0.0, 9.81])


def test_placeholder_link_masses_do_not_bound_the_payload(tmp_path):
    """Kinematics-only URDFs often carry 1 g placeholder inertias: the 10x-the-arm rule would
    refuse any real payload there, so it applies only to arms of 1 kg or more."""
    import re

    from conftest import BUNDLED_URDF

    text = re.sub(r'<link name="([^"]+)"\s*/>', r'<link name="\1"><inertial><mass value="0.001"/>'
                  r'<inertia ixx="1e-6" ixy="0" ixz="0" iyy="1e-6" iyz="0" izz="1e-6"/></inertial></link>',
                  BUNDLED_URDF.read_text())
    path = tmp_path / "placeholder.urdf"
    path.write_text(text)
    robot = calib.load_robot(path)
    assert 0 < with_gravity(robot, payload=Payload(20.0)).gravity.link_mass < 1.0


def test_identifiability_cache_tells_payloads_apart():
    """The identifiable set of a model with compliance is kept by content: the content includes
    the gravity load (the same values and configurations, no payload: no torque, no compliance
    seen; 5 kg: c2..c5 seen), not the first answer for both."""
    from calib.model.identifiability import identifiable_names

    robot = calib.load_robot("robots/brtirus0707a/brtirus0707a.urdf")     # (no link inertias)
    Q = robot.random_configurations(60, 0)
    unloaded = identifiable_names(with_gravity(robot, payload=Payload(0.0)), Q)
    loaded = identifiable_names(with_gravity(robot, payload=Payload(5.0, np.array([0.0, 0.0, 0.1]))), Q)
    assert [n for n in unloaded if n.startswith("c")] == []
    assert [n for n in loaded if n.startswith("c")] == ["c2", "c3", "c4", "c5"]


def test_a_torque_model_of_another_kind_keys_the_cache_by_identity():
    """RobotModel.with_compliance takes any object with torques(Q): identifiability keys it by
    identity (it has no content_key), with the same answer as the gravity model it wraps."""
    from calib.model.compliance import GravityModel
    from calib.model.identifiability import identifiable_names

    robot = calib.load_robot("ur10")

    class Torques:
        def __init__(self, gm):
            self.gm = gm

        def torques(self, Q):
            return self.gm.torques(Q)

    gm = GravityModel.for_robot(robot, payload=PAYLOAD)
    Q = robot.random_configurations(60, 0)
    assert identifiable_names(robot.with_compliance(Torques(gm)), Q) == identifiable_names(robot.with_compliance(gm), Q)
