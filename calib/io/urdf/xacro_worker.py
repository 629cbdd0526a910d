"""The child process that expands a xacro (:func:`calib.io.urdf.xacro_file.expand_xacro` runs this
file with the interpreter that runs calib): xacro is run here, not in the caller's process,
because it keeps its state in module globals (its file and macro stacks, its ``$(arg)`` table, its
list of included files), adds its unit tags (``!degrees``, ...) to PyYAML's ``SafeLoader`` for
good, and finds packages through ``ament_index_python``, which only a ROS installation has: here
its ``$(find NAME)`` is pointed at the package table the caller made
(:class:`calib.io.urdf.packages.RosPackages`), which changes nothing outside this process.

Protocol: one JSON object on stdin, ``{"file": path, "args": {name: value}, "packages": {name:
folder}}``; one JSON object on stdout, ``{"urdf": text, "files": [paths read]}`` or ``{"error":
text, "package": name or null, "file": the file being expanded or null}``. This file imports
nothing of calib (it runs as a script).
"""
import contextlib
import json
import os
import sys


def _expand(request: dict) -> dict:
    try:
        import xacro
        from xacro import substitution_args
    except ImportError as exc:
        return {"error": f"import xacro: {exc}", "package": None, "file": None, "missing": True}

    table = request["packages"]
    unknown = []

    def find(name):
        if name not in table:
            unknown.append(name)
            raise substitution_args.SubstitutionException(f"unknown package {name!r}")
        return table[name]

    substitution_args._eval_find = find          # ($(find NAME))
    substitution_args._eval_dict["find"] = find  # ($(eval find('NAME')))
    path = request["file"]
    try:
        with contextlib.redirect_stdout(sys.stderr):     # (stdout carries the answer alone)
            doc = xacro.process_file(path, mappings=dict(request["args"]), verbosity=0)
    except Exception as exc:          # xacro raises any kind (its own, XML, Python's eval): all reported
        stack = [f for f in (xacro.filestack or []) if f]
        text = " ".join(str(exc).split()) or type(exc).__name__
        return {"error": text, "package": unknown[0] if unknown else None,
                "file": stack[-1] if stack else None, "kind": type(exc).__name__}
    files = [os.path.abspath(f) for f in dict.fromkeys(xacro.all_includes)]
    return {"urdf": doc.toprettyxml(indent="  "), "files": files}     # (as xacro's command writes it)


def main() -> int:
    # run as a script, this file's folder is sys.path[0]: its neighbours are calib's modules, which
    # must not stand in for top-level ones when xacro imports its own (only then: a module that
    # imports this one keeps its sys.path)
    if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(os.path.abspath(__file__)):
        del sys.path[0]
    request = json.load(sys.stdin)
    sys.stdout.write(json.dumps(_expand(request)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
