"""The choice of joint terms (calib.calibration.terms.choose_terms) on simulated arms with known truth.

For each arm of example-robot-data (real link masses: compliance is a candidate) and each truth:
geometric deviations only; + gravity compliance (a few urad/(N m) on the joints that carry
torque); + periodic joint errors (first and second harmonics, ``--periodic-urad`` per
coefficient); + both; once-per-turn errors of the shoulder and elbow alone (``--run-out-urad`` per
coefficient, which a compliance mimics in part), calibration rows of pose data with noise, and ``choose_terms`` on them. Prints how
often each candidate is chosen over the seeds: the geometry-only truth measures the rule's false
positives (terms taken for noise), the others its power.

Beside today's rule (issue 39, item 4: the candidates compared with each other by their
cross-validated scores, the lowest kept when it beats the geometry by the margin and does not
cost the workspace more than it gains) the same tables are judged by the rule before it (the
candidates tried in order of size, each kept when it beat the current choice by the margin):
"old" counts, and how often each rule kept a candidate that did not have the lowest score of
those beating the geometry among its alternatives ("not lowest": compliance kept where the
periodic terms scored lower, or the reverse).

    python scripts/bench_terms.py [--seeds 20] [--poses 300] [--arms ur10,panda]
"""
from __future__ import annotations

import argparse
import sys
import time
from collections import Counter
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import _bench  # noqa: E402,F401  (one BLAS thread)

import numpy as np  # noqa: E402

import calib  # noqa: E402
from calib.calibration.terms import choose_terms  # noqa: E402
from calib.model.compliance import with_gravity  # noqa: E402


def truth(robot, kind: str, rng, periodic_rad: float, run_out_rad: float = 50e-6):
    true = robot.with_changes(**calib.random_deviations(robot, 3e-4, rng))
    if kind in ("compliance", "both"):
        c = rng.uniform(2e-6, 5e-6, robot.n_joints)
        true = with_gravity(true, values=c)
    if kind in ("periodic", "both"):
        n_rev = int((~robot.prismatic).sum())
        true = true.with_periodic(rng.normal(0.0, periodic_rad, 4 * n_rev))
    if kind == "shoulder run-out":
        # once-per-turn errors of the shoulder and the elbow alone (N(0, run_out_rad)): gravity's
        # torque on them turns with the same angles, so a compliance mimics part of them
        n_rev = int((~robot.prismatic).sum())
        c = np.zeros(4 * n_rev)
        c[4:6], c[8:10] = rng.normal(0.0, run_out_rad, 2), rng.normal(0.0, run_out_rad, 2)
        true = true.with_periodic(c)
    return true


#: The truths: geometric deviations only, + compliance, + periodic errors of every joint, + both,
#: and once-per-turn errors of the shoulder and the elbow alone (periodic errors a compliance
#: mimics in part: the case the rule of alternatives is for).
KINDS = ("geometry", "compliance", "periodic", "both", "shoulder run-out")


def old_rule(table, rows):
    """The rule before issue 39: from the geometry, move to a larger candidate (in order of size)
    when it beats the current choice by the margin."""
    from calib.calibration.estimators.term_selection import margin

    best = table[0]
    for t in sorted(table[1:], key=lambda t: t.n_free):
        if margin(rows, t, best) > 0:
            best = t
    return best


def not_lowest(table, rows, chosen) -> bool:
    """Whether ``chosen`` is a term candidate while an alternative to it (neither holding the
    other's terms: compliance against periodic errors) beat the geometry by the margin with a
    lower score."""
    from calib.calibration.estimators.term_selection import margin

    rivals = [t for t in table[1:] if margin(rows, t, table[0]) > 0 and t.score < chosen.score
              and not t.holds(chosen) and not chosen.holds(t)]
    return chosen is not table[0] and bool(rivals)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--arms", default="ur10,panda")
    ap.add_argument("--periodic-urad", type=float, default=100.0)
    ap.add_argument("--run-out-urad", type=float, default=50.0)
    ap.add_argument("--sigma-pos-mm", type=float, default=0.05)
    ap.add_argument("--sigma-rot-rad", type=float, default=0.0005)
    args = ap.parse_args(argv)
    print(f"{args.poses} pose rows, noise {args.sigma_pos_mm} mm / {args.sigma_rot_rad} rad per axis, "
          f"{args.seeds} seeds; periodic coefficients N(0, {args.periodic_urad:g} urad), run-out N(0, "
          f"{args.run_out_urad:g} urad)")
    import calib.calibration.terms as terms

    seen = []
    rule = terms.pick_terms

    def recording(table, rows):
        best = rule(table, rows)
        seen.append((table, rows, best))
        return best

    terms.pick_terms = recording
    for arm in args.arms.split(","):
        robot = calib.load_robot(arm)
        for kind in KINDS:
            chosen, old, t0 = Counter(), Counter(), time.perf_counter()
            off = {"today": 0, "old": 0}
            for seed in range(args.seeds):
                rng = np.random.default_rng(1000 + seed)
                true = truth(robot, kind, rng, args.periodic_urad * 1e-6, args.run_out_urad * 1e-6)
                m = calib.simulate_measurements(true, robot.random_configurations(args.poses, rng),
                                                sigma_pos=args.sigma_pos_mm * 1e-3, sigma_rot=args.sigma_rot_rad,
                                                rng=rng)
                seen.clear()
                choice = choose_terms(robot, m)
                chosen[choice.label if choice.table else "not judged"] += 1
                if not seen:            # (too few rows per parameter: nothing judged)
                    old["not judged"] += 1
                    continue
                table, rows, best = seen[-1]
                before = old_rule(table, rows)
                old[before.label] += 1
                off["today"] += not_lowest(table, rows, best)
                off["old"] += not_lowest(table, rows, before)
            per = (time.perf_counter() - t0) / args.seeds
            print(f"  {arm:<7} truth {kind:<11} chosen: " +
                  ", ".join(f"{k} {v}" for k, v in sorted(chosen.items())) + f"   ({per:.2f} s per choice)",
                  flush=True)
            print(f"  {'':<7}       {'':<11} old:    " + ", ".join(f"{k} {v}" for k, v in sorted(old.items()))
                  + f";  not lowest: today {off['today']}, old {off['old']}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
