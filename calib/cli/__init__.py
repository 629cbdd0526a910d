"""calib.cli: the ``calib`` command, a thin layer over the Python API (see ARCHITECTURE.md).

One module per subcommand (``identifiability``, ``simulate``, ``calibrate``, ``evaluate``,
``select_poses``, ``compensate``, ``export``), each exposing ``add_parser(subparsers)`` and ``run(args) -> int``;
:mod:`calib.cli.main` assembles them (``main(argv)``, the signals, the one-line errors),
:mod:`calib.cli.output` is the one output policy, :mod:`calib.cli.args` the shared options and
:mod:`calib.cli.progress` the progress line. A new subcommand is a new module listed in
:data:`calib.cli.main.COMMAND_NAMES`.
"""
