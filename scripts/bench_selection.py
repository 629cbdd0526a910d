"""Which selection rule of ``params="auto"`` generalises: the lowest cross-validated score, or the
one-standard-error rule toward the smaller set, judged on fresh rows.

For each robot (the bundled one, example-robot-data's UR5 and Panda), number of calibration rows
(15-40), kind of deviation and seed: simulate full-pose calibration rows of a perturbed robot
with millimetre noise (1 mm, 5 mrad per axis; a small unmodelled joint-angle error of 0.3 mrad)
and 2000 fresh configurations; fit the identifiable set (noise estimated, outlier check), the
nested candidates of model selection (each its own maximal identifiable subset), score them by
cross-validation as ``calibrate`` does, and evaluate every candidate's fit at the fresh
configurations against the true robot (position RMS, mm: the error above the noise floor of
fresh measured rows). Each rule picks a candidate from the same scores; the script prints, per
robot and rule, the mean error of its choices, and over the cases where the rules disagree how
often each one's choice was worse on the fresh configurations and by how much.

Deviations: "general" (every parameter, 1 mm / 2 mrad standard deviation) and "offsets" (the
same on the joint offsets and frames, the rest x0.05: the case the small candidates are for).

Measured (2026-11, complete candidates, 40 seeds, 720 cases each): full poses: the rules
disagree in 65 cases, the lowest score's choice worse in 34 and the other's in 31 (sign test
p = 0.80), mean error 0.9756 vs 0.9742 mm (paired difference +0.0013 +- 0.0058 mm); positions
only: they disagree in 109, the lowest score's choice worse in 48 and the other's in 61
(p = 0.25), 1.1680 vs 1.1744 mm (-0.0063 +- 0.0093). Neither rule does better on fresh
configurations, so ``params="auto"`` takes the plain one, the lowest score.

    python scripts/bench_selection.py [--seeds 6] [--rows 15 25 40] [--robots bundled ur5 panda]
                                      [--position-only] [--first-seed 0]
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench  # noqa: E402,F401  (one BLAS thread)

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import calib  # noqa: E402
from calib.calibration.options import resolve_options  # noqa: E402
from calib.calibration.parameters import choose_parameters  # noqa: E402
from calib.calibration.prepare import prepare  # noqa: E402
from calib.calibration.estimators.selection import (  # noqa: E402
    auto_candidates,
    fit_identifiable,
    lowest_score,
    one_standard_error,
    select_model,
    selection_folds,
)
from calib.model.kinematics import ChainKinematics  # noqa: E402
from calib.model.simulate import apply_deviations, random_deviations, simulate_measurements  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RULES = {"lowest score": lowest_score, "one standard error": one_standard_error}
SIGMA_POS, SIGMA_ROT, UNMODELLED = 1.0e-3, 0.005, 3e-4


def _load(name: str) -> calib.RobotModel:
    if name == "bundled":
        return calib.load_robot(ROOT / "robots" / "brtirus0707a" / "brtirus0707a.urdf")
    import example_robot_data as erd

    return calib.load_robot(erd.load(name).urdf)


def run(robot: calib.RobotModel, rows: int, kind: str, seed: int, position_only: bool = False) -> dict:
    """The fresh-configuration error (m) of every candidate's fit and each rule's choice."""
    rng = np.random.default_rng(seed)
    dev = random_deviations(robot, 1e-3, rng)
    if kind == "offsets":
        small = {p.name for p in robot.parameters if p.group in ("u", "v") or p.kind == "theta"}
        dev = {k: v if k in small else 0.05 * v for k, v in dev.items()}
    true = apply_deviations(robot, dev)
    meas = simulate_measurements(true, robot.random_configurations(rows, rng), sigma_pos=SIGMA_POS,
                                 sigma_rot=SIGMA_ROT, rng=rng, unmodelled=UNMODELLED, position_only=position_only)
    Qf = robot.random_configurations(2000, rng)
    _, p_true = ChainKinematics(true).frame_poses(Qf)
    opts = resolve_options(robot, meas, params="auto")
    setup, _ = prepare(robot, meas, None, opts.init_frames)
    choice = choose_parameters(setup, opts)
    kin = setup.kin or ChainKinematics(setup.start)
    full, problem, solve = fit_identifiable(setup, choice.free, opts, kin)
    selection, fits = select_model(setup, auto_candidates(setup, choice.free, full, opts), full, problem,
                                   solve, selection_folds(full, opts), kin, opts.lm)
    err = {}
    for c in selection.candidates:
        _, p = ChainKinematics(fits[c.label][0].model).frame_poses(Qf)
        err[c.label] = float(np.sqrt(np.mean(np.sum((p - p_true) ** 2, axis=1))))
    out = {"candidates": {c.label: len(c.free) for c in selection.candidates}, "err": err}
    out["chosen"] = {name: rule(selection.candidates).label for name, rule in RULES.items()}
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, default=6)
    ap.add_argument("--rows", type=int, nargs="+", default=[15, 25, 40])
    ap.add_argument("--robots", nargs="+", default=["bundled", "ur5", "panda"])
    ap.add_argument("--position-only", action="store_true", help="position-only rows (a marker, no orientation)")
    ap.add_argument("--first-seed", type=int, default=0)
    args = ap.parse_args(argv)
    print(f"# bench_selection: {_bench.machine()}; {args.seeds} seeds x rows {args.rows} x deviations "
          f"general/offsets; {'positions only' if args.position_only else 'full poses'}, noise "
          f"{SIGMA_POS * 1e3:g} mm / {SIGMA_ROT:g} rad; error at 2000 fresh configurations against the truth (mm)")
    names = list(RULES)
    total = {"cases": 0, "differ": 0, "worse": dict.fromkeys(names, 0), "excess": {n: [] for n in names},
             "mean": {n: [] for n in names}, "oracle": []}
    for rname in args.robots:
        robot = _load(rname)
        per = {n: [] for n in names}
        for rows in args.rows:
            for kind in ("general", "offsets"):
                for seed in range(args.first_seed, args.first_seed + args.seeds):
                    try:
                        r = run(robot, rows, kind, 1000 * rows + seed, args.position_only)
                    except calib.CalibError as exc:
                        print(f"  {rname} {rows} rows {kind} seed {seed}: skipped ({exc})")
                        continue
                    e = {n: r["err"][r["chosen"][n]] for n in names}
                    for n in names:
                        per[n].append(e[n])
                        total["mean"][n].append(e[n])
                    total["oracle"].append(min(r["err"].values()))
                    total["cases"] += 1
                    if len({r["chosen"][n] for n in names}) > 1:
                        total["differ"] += 1
                        for n in names:
                            other = [m for m in names if m != n][0]
                            total["excess"][n].append(e[n] / e[other] - 1.0)
                            total["worse"][n] += e[n] > e[other]
                    print(f"  {rname:<8}{rows:>3} rows {kind:<8} seed {seed}: "
                          + "  ".join(f"{k} ({r['candidates'][k]}) {v * 1e3:.3f}" for k, v in r["err"].items())
                          + "  | " + ", ".join(f"{n}: {r['chosen'][n]}" for n in names), flush=True)
        print(f"{rname}: mean error of the chosen fit, mm: "
              + ", ".join(f"{n} {np.mean(per[n]) * 1e3:.4f}" for n in names), flush=True)
    print(f"\n{total['cases']} cases; the rules chose differently in {total['differ']}")
    print(f"mean error of the chosen fit over all cases (mm): "
          + ", ".join(f"{n} {np.mean(total['mean'][n]) * 1e3:.4f}" for n in names)
          + f"; best candidate in hindsight {np.mean(total['oracle']) * 1e3:.4f}")
    a, b = (np.array(total["mean"][n]) for n in names)
    d = a - b
    print(f"paired difference ({names[0]} - {names[1]}) over all cases: {np.mean(d) * 1e3:+.4f} mm "
          f"+- {np.std(d, ddof=1) / np.sqrt(len(d)) * 1e3:.4f} (standard error)")
    k, m = total["worse"][names[0]], total["differ"]
    if m:
        from math import comb

        tail = sum(comb(m, j) for j in range(min(k, m - k) + 1)) / 2 ** m
        print(f"where they differ: {names[0]} worse in {k}, {names[1]} worse in {total['worse'][names[1]]} of {m} "
              f"(two-sided sign test p = {min(1.0, 2 * tail):.2f}); geometric mean error ratio "
              f"{names[0]} / {names[1]} {np.exp(np.mean(np.log(1 + np.array(total['excess'][names[0]])))):.3f}, "
              f"range {np.min(total['excess'][names[0]]) * 100 + 100:.0f}-{np.max(total['excess'][names[0]]) * 100 + 100:.0f} %")


if __name__ == "__main__":
    main()
