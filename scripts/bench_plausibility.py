"""False refusals and catch rate of calib's plausibility rules (issue 43; the rules:
calib/calibration/plausibility.py, docs/refusals.md).

Honest calibrations, simulated (``--runs``, spread evenly over the arms: the bundled
BRTIRUS0707A, ur5, ur10 and panda from example-robot-data): a true robot with random deviations of
realistic size (lengths with a standard deviation drawn log-uniform in 0.1-1 mm, angles the same
over 0.5 m: calib.random_deviations), 25-120 random configurations, noise drawn log-uniform in
0.01-0.5 mm and 0.2-3 mrad per axis with its own scale per axis (0.5-2 times), heavy-tailed:
Gaussian, Student-t (nu 3, 4 or 5, scaled to the noise's standard deviation), or a contaminated
normal (5-10 % of the rows with 5 times the noise); in a third of the runs an error the model
cannot describe (calib.simulate_measurements' unmodelled joint error, up to 3e-4 rad); in half
of them the instrument 1-3 m away from the robot's base, turned anyhow. Data
kinds, in turn: full poses, positions only (a tool point up to 150 mm off the flange), several
targets (three reflectors, positions only), and touch rows (every tenth run: a sphere and two
points, touch data). Each is calibrated with calib's defaults (``calib.calibrate``,
with touch data too); a run is refused when its status is "implausible".

The wrong classes, each on every arm (``--wrong`` runs per class and arm): a joint counted the
other way (one random revolute joint's values negated), a joint counted from another zero (+90
degrees; not the first or the last joint, whose zeros the measurement and the tool frame's
rotations take exactly), another robot's URDF (the measured robot: the same arm with every link length scaled
by 1.25-1.4, or UR10 rows on the UR5 URDF and UR5 rows on the UR10 URDF), positions in metres
read as millimetres, and compliance with the gravity direction flipped (UR10, 10 kg payload,
true compliances of a few urad/(N m)). Caught when refused.

The real data: every real set of ../shared/realdata (read as scripts/bench_realdata.py reads
them, with the inertial URDF where there is one: whole files and their 5 folds' calibration
rows) and examples/tiago_qualisys (the whole
file and each target alone), each calibrated with the defaults: none may be refused.

Prints the refusals per arm and kind, the refusal rate (target: 0, at most 1 %), the catch rate
per class, the real sets' statuses, and every refusal's message.

Run: PYTHONPATH=. python scripts/bench_plausibility.py [--runs 240] [--wrong 3] [--seed 0] [--no-real]
"""
from __future__ import annotations

import _bench  # noqa: F401  (one BLAS thread before numpy loads)

import argparse
import math
import sys
import time
import warnings
from collections import defaultdict
from pathlib import Path

import numpy as np

import calib
from calib.model.spatial import rotation_from_rotvec

ROOT = Path(__file__).resolve().parents[1]
#: The real sets (../shared/realdata from the checkout; from a worktree one level deeper).
REALDATA = next((p for p in (ROOT.parent / "shared" / "realdata", ROOT.parent.parent / "shared" / "realdata")
                 if p.is_dir()), ROOT.parent / "shared" / "realdata")
TIAGO_CSV = ROOT / "examples" / "tiago_qualisys" / "measurements.csv"
ARMS = ("bundled", "ur5", "ur10", "panda")
KINDS = ("pose", "position", "targets")
WRONG = ("joint sign", "joint zero", "another robot's URDF", "metres as mm", "gravity flipped")


#: The rules a refusal comes from, told by its message (calib/calibration/plausibility.py).
RULES = ("the chain (issue 43)", "the residuals", "the physics (compliance)", "the validation figures",
         "a misreading named (diagnose)", "the data's consistency (issue 39)", "the touch design", "another rule")


def rule(message: str) -> str:
    """Which rule of RULES refused, by the message's opening words."""
    for start, r in (("the calibrated robot is not the URDF's", RULES[0]),
                     ("the calibrated model does not describe", RULES[1]),
                     ("the fit converged but its", RULES[1]),
                     ("the fitted joint compliances", RULES[2]),
                     ("the validation rows' positions", RULES[3]),
                     ("likely cause:", RULES[4]),
                     ("the data are inconsistent", RULES[5]),
                     ("the design cannot calibrate this robot", RULES[6])):
        if message.startswith(start):
            return r
    return RULES[7]


def load(name: str):
    if name == "bundled":
        return calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    import example_robot_data as erd

    return calib.load_robot(erd.load(name).urdf)


def heavy_noise(rng, shape, sigma: float, kind: str) -> np.ndarray:
    """(shape) noise of standard deviation ``sigma`` per component: Gaussian, Student-t (nu 3-5,
    scaled to that standard deviation) or a contaminated normal (5-10 % of rows at 5 sigma)."""
    if kind == "gauss":
        return rng.normal(0.0, sigma, shape)
    if kind.startswith("t"):
        nu = int(kind[1:])
        return sigma * rng.standard_t(nu, shape) / math.sqrt(nu / (nu - 2))
    share = rng.uniform(0.05, 0.10)
    scale = np.where(rng.random(shape[0]) < share, 5.0, 1.0)[:, None]
    return rng.normal(0.0, sigma, shape) * scale / math.sqrt(1 + share * 24)


def honest_measurements(robot, true, rng, kind: str, noise: str):
    n = int(rng.integers(25, 121))
    Q = robot.random_configurations(n, rng)
    unmodelled = float(rng.uniform(0, 3e-4)) if rng.random() < 1 / 3 else 0.0
    targets = list(true.targets) * n if true.targets else None
    if true.targets:
        Q = np.repeat(Q, true.n_targets, axis=0)
    m = calib.simulate_measurements(true, Q, sigma_pos=0.0, sigma_rot=0.0, rng=rng, unmodelled=unmodelled,
                                    position_only=kind != "pose", targets=targets)
    sp = math.exp(rng.uniform(math.log(0.01e-3), math.log(0.5e-3)))
    sr = math.exp(rng.uniform(math.log(0.2e-3), math.log(3e-3)))
    axes = rng.uniform(0.5, 2.0, 3)
    pos = m.position + heavy_noise(rng, m.position.shape, sp, noise) * axes
    rot = m.rotation
    if rot is not None:
        rot = rotation_from_rotvec(heavy_noise(rng, (len(rot), 3), sr, noise)) @ rot
    from dataclasses import replace

    return replace(m, position=pos, rotation=rot), f"{n} poses, {sp * 1e3:.3g} mm, {noise}" + \
        (f", unmodelled {unmodelled:.1e} rad" if unmodelled else "")


def with_kind(robot, kind: str, rng):
    """The nominal model of a data kind: a tool point off the flange for positions, three
    targets for several targets."""
    if kind == "position":
        return robot.with_changes(v_x=float(rng.uniform(-0.15, 0.15)), v_y=float(rng.uniform(-0.15, 0.15)),
                                  v_z=float(rng.uniform(0.0, 0.15)))
    if kind == "targets":
        pts = rng.uniform(-0.12, 0.12, (3, 3))
        return robot.with_target_offsets({t: p for t, p in zip("ABC", pts)})
    return robot


def honest_run(arm: str, robot, seed: int, kind: str):
    rng = np.random.default_rng(seed)
    noise = ("gauss", "t3", "t4", "t5", "contaminated")[seed % 5]
    nominal = with_kind(robot, kind, rng)
    scale = math.exp(rng.uniform(math.log(0.1e-3), math.log(1e-3)))
    true = nominal.with_changes(**calib.random_deviations(nominal, scale, rng))
    if rng.random() < 0.5:      # an instrument 1-3 m away, turned anyhow
        from dataclasses import replace

        from scipy.spatial.transform import Rotation

        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=rng).as_matrix()
        T[:3, 3] = rng.normal(size=3) / np.linalg.norm(rng.normal(size=3)) * rng.uniform(1.0, 3.0)
        true = replace(true, T_meas_base_ref=T @ true.T_meas_base_ref)
    if kind == "touch":
        return touch_run(nominal, true, rng)
    m, what = honest_measurements(nominal, true, rng, kind, noise)
    res = calib.calibrate(nominal if kind != "targets" else robot, m)
    return res.status, res.message, what + f", deviations {scale * 1e3:.2g} mm", \
        margin(res.nominal, res.robot, "pose" if kind == "pose" else "position")


def margin(nominal, calibrated, measure: str) -> float:
    """The calibrated chain's distance from the URDF's over the chain rule's threshold, by the
    kinematics (calib.calibration.plausibility.chain_deviation without the bound from the moves;
    below 1, the frames not re-fitted: an upper bound)."""
    from calib.calibration.plausibility import CHAIN_REACH_FRACTION, CHAIN_ROT_RAD, chain_deviation

    dev = chain_deviation(nominal, calibrated, measure, bound=False)
    return max(dev.position / (CHAIN_REACH_FRACTION * dev.reach),
               0.0 if dev.rotation is None else dev.rotation / CHAIN_ROT_RAD)


def touch_run(nominal, true, rng):
    from calib.model.touch import Feature
    from calib.model.touch_simulate import simulate_touch

    feats = [Feature("sphere", "S1", radius=float(rng.uniform(0.03, 0.1))), Feature("point", "P1"),
             Feature("point", "P2")]
    sigma = math.exp(rng.uniform(math.log(0.01e-3), math.log(0.1e-3)))
    sim = simulate_touch(true, feats, [15, 12, 12], sigma=sigma, rng=rng)
    res = calib.calibrate(nominal, sim.data)
    return res.status, res.message, f"touch, 39 rows, {sigma * 1e3:.3g} mm", margin(nominal, res.robot, "position")


def wrong_run(cls: str, arm: str, robot, others: dict, seed: int):
    """(status, message, what) of one calibration of a wrong class (see the module docstring)."""
    rng = np.random.default_rng(10_000 + seed)
    from dataclasses import replace

    if cls == "gravity flipped":
        from calib.model.compliance import Payload, with_gravity

        robot = others["ur10"]
        payload = Payload(10.0, np.array([0.0, 0.05, 0.10]))
        true = with_gravity(robot, payload=payload, values=np.array([0.0, 3e-6, 4e-6, 5e-6, 5e-6, 5e-6]))
        true = true.with_changes(**calib.random_deviations(robot, 0.3e-3, rng))
        m = calib.simulate_measurements(true, robot.random_configurations(100, rng), sigma_pos=0.03e-3,
                                        sigma_rot=0.001, rng=rng)
        res = calib.calibrate(robot, m, compliance=True, payload=payload, gravity=(0.0, 0.0, 9.80665))
        return res.status, res.message, "ur10, compliance, --gravity 0,0,+9.81"
    true = robot.with_changes(**calib.random_deviations(robot, 0.3e-3, rng))
    nominal = robot
    if cls == "another robot's URDF":
        if arm in ("ur5", "ur10"):
            true = others["ur10" if arm == "ur5" else "ur5"]
            true = true.with_changes(**calib.random_deviations(true, 0.3e-3, rng))
            what = f"{'ur10' if arm == 'ur5' else 'ur5'} rows"
        else:
            f = float(rng.uniform(1.25, 1.4))
            lengths = {p.name: (f - 1) * v for p, v in zip(true.parameters, true.values)
                       if p.group == "joint" and p.unit == "m"}
            true = true.with_changes(**lengths)
            what = f"links x{f:.2f}"
    m = calib.simulate_measurements(true, robot.random_configurations(60, rng), sigma_pos=0.03e-3,
                                    sigma_rot=0.001, rng=rng)
    if cls == "joint sign" or cls == "joint zero":
        # (the first and the last joint's zeros are no error of the model: the measurement
        # frame's rotation about the first axis and the tool frame's about the last take them,
        # and the model calibrated then is exact in those frames)
        revolute = np.flatnonzero(~robot.prismatic)
        j = int(rng.choice(revolute[1:-1] if cls == "joint zero" else revolute))
        q = m.q.copy()
        q[:, j] = -q[:, j] if cls == "joint sign" else q[:, j] - math.pi / 2
        m = replace(m, q=q)
        what = f"joint {robot.joint_names[j]}"
    elif cls == "metres as mm":
        m = replace(m, position=m.position * 1e-3)
        what = "positions / 1000"
    res = calib.calibrate(nominal, m)
    return res.status, res.message, what


def real_sets():
    """(name, robot, measurements) of the real sets and their folds' calibration rows."""
    from bench_realdata import realdata_robot

    sets = []
    for name in ("rokae_cobot_lt50", "iiwa7_optical"):
        folder = REALDATA / name
        if not folder.is_dir():
            print(f"note: {folder} absent: its real set skipped")
            continue
        robot = realdata_robot(folder, name)
        sets.append((name, robot, calib.read_measurements(folder / f"{name}.csv", robot)))
        for k in range(5):
            m = calib.read_measurements(folder / "folds" / f"{name}_fold{k}.csv", robot)
            sets.append((f"{name} fold {k}", robot, m.calibration()))
    tiago = calib.load_robot("tiago")
    m = calib.read_measurements(TIAGO_CSV, tiago)
    sets.append(("tiago_qualisys", tiago, m))
    for t in m.target_ids:
        sets.append((f"tiago_qualisys {t}", tiago, m.subset(np.asarray(m.target, dtype=object) == t)))
    return sets


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=240, help="honest calibrations (default 240)")
    ap.add_argument("--wrong", type=int, default=3, help="runs per wrong class and arm (default 3)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-real", action="store_true", help="skip the real data")
    args = ap.parse_args()
    warnings.simplefilter("ignore")
    robots = {a: load(a) for a in ARMS}
    t0 = time.perf_counter()
    refused, counts, messages = defaultdict(int), defaultdict(int), []
    by_rule = defaultdict(int)
    ratios = []
    for i in range(args.runs):
        arm = ARMS[i % len(ARMS)]
        kind = "touch" if i % 10 == 9 else KINDS[(i // len(ARMS)) % len(KINDS)]
        status, message, what, ratio = honest_run(arm, robots[arm], args.seed * 100_000 + i, kind)
        ratios.append(ratio)
        counts[(arm, kind)] += 1
        if status == "implausible":
            refused[(arm, kind)] += 1
            by_rule[rule(message)] += 1
            messages.append(f"  honest {arm} {kind} (run {i}: {what}): {message}")
        elif status != "converged":
            messages.append(f"  (not refused, status {status}) honest {arm} {kind} (run {i}: {what}): {message}")
    n_ref = sum(refused.values())
    print(f"honest calibrations: {args.runs} in {time.perf_counter() - t0:.0f} s, refused {n_ref} "
          f"({100 * n_ref / max(args.runs, 1):.2f} %; target 0, at most 1 %)")
    for arm in ARMS:
        cells = [f"{kind} {refused[(arm, kind)]}/{counts[(arm, kind)]}" for kind in KINDS + ("touch",)
                 if counts[(arm, kind)]]
        print(f"  {arm:<8} refused: {', '.join(cells)}")
    for r in RULES:
        print(f"  by {r}: {by_rule[r]} ({100 * by_rule[r] / max(args.runs, 1):.2f} %)")
    if ratios:
        print(f"  the chain rule's margin: honest chains at most {max(ratios):.3f} of its threshold "
              f"(median {float(np.median(ratios)):.3f})")

    caught = defaultdict(int)
    total = defaultdict(int)
    caught_by = defaultdict(lambda: defaultdict(int))
    for cls in WRONG:
        for arm in (("ur10",) if cls == "gravity flipped" else ARMS):
            for k in range(args.wrong):
                status, message, what = wrong_run(cls, arm, robots[arm], robots, 1000 * WRONG.index(cls) + 10 * k
                                                  + ARMS.index(arm))
                total[cls] += 1
                caught[cls] += status == "implausible"
                if status == "implausible":
                    caught_by[cls][rule(message)] += 1
                if status != "implausible":
                    messages.append(f"  missed: {cls} on {arm} ({what}): status {status}")
    print("wrong classes caught (refused):")
    for cls in WRONG:
        by = ", ".join(f"{n} by {r}" for r, n in caught_by[cls].items())
        print(f"  {cls:<22} {caught[cls]}/{total[cls]}" + (f" ({by})" if by else ""))

    if not args.no_real:
        print("real data (defaults):")
        for name, robot, m in real_sets():
            res = calib.calibrate(robot, m)
            print(f"  {name:<26} {m.n_poses:>5} rows  {res.status}")
            if res.status == "implausible":
                messages.append(f"  real {name}: {res.message}")
    if messages:
        print("messages:")
        print("\n".join(messages))
    sys.exit(0)


if __name__ == "__main__":
    main()
