"""``calib compensate CALIBRATED.urdf NOMINAL.urdf PROGRAM -o CORRECTED``: a corrected copy of a robot
program (KRL .dat, RAPID .mod, URScript .script, FANUC .LS), its structure and comments kept
(:mod:`calib.io.programs`, :mod:`calib.compensation.program`).

Nothing is written unless every target is ok: a refused target (a frame the program does not
define) is one line and exit 2; targets the calibrated robot cannot reach on their branch are
listed (exit 3)."""
from __future__ import annotations

import sys

from calib.cli.output import EXIT_NOT_CONVERGED, EXIT_OK, PROG
from calib.errors import ParameterError

__all__ = ["run_program"]


def run_program(args, calibrated, nominal, outputs, out, vendor: str) -> int:
    """The program branch of ``calib compensate`` (see the module docstring); returns the exit code."""
    from calib.compensation.program import compensate_program
    from calib.io.urdf.controller_frame import targets_frame
    from calib.io.programs import corrected_program, read_program

    if args.convention not in (None, vendor):
        raise ParameterError(f"--convention {args.convention}: {args.targets} is a {vendor} program")
    if args.targets_frame == "meas":
        raise ParameterError(f"--targets-frame meas: a program's poses are in its controller's base frame")
    options = {"j23_factor": args.j23_factor} if vendor == "fanuc" else {}
    program = read_program(args.targets, nominal, options=options)
    for note in program.notes:
        sys.stderr.write(f"{PROG}: note: {args.targets}: {note}\n")
    frame = targets_frame(nominal, convention=None if args.targets_frame == "base" or args.targets_link else vendor,
                          link=args.targets_link)
    comp = compensate_program(calibrated, nominal, program, T_base_frame=frame.T_base_frame,
                              singular_threshold=args.singular_threshold)
    result = comp.result
    kinds = {t.kind for t in program.targets}
    sys.stdout.write(result.format() + f"\n  {len(program.targets)} targets of {args.targets} "
                     f"({', '.join(sorted(kinds))}); poses of tool frame {nominal.tool_frame}; {frame.text}\n")
    if not result.success:
        bad = result.n_targets - int(result.ok.sum())
        sys.stderr.write(f"{PROG}: {bad} of {result.n_targets} targets of {args.targets} are not ok (listed above): "
                         f"nothing written\n")
        return EXIT_NOT_CONVERGED
    text = corrected_program(program, nominal, q=comp.q, T=comp.T_out, configurations=list(comp.configurations),
                             options=options)
    outputs.stage(out, text.encode(program.encoding))
    outputs.commit()
    sys.stdout.write(f"\nwrote {out}\n")
    return EXIT_OK
