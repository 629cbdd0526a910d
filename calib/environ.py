"""The environment the process started with (:func:`starting_environ`): what the C libraries
(BLAS, malloc) read when they loaded, which later changes of ``os.environ`` do not show."""
from __future__ import annotations

#: starting_environ()'s answer, read once.
_ENVIRON: list = []


def starting_environ(environ_file: str = "/proc/self/environ") -> dict[str, str | None] | None:
    """The environment this process started (exec) with, as the kernel keeps it (later changes
    of ``os.environ`` do not show there): what the C libraries read when they loaded; a name
    given twice with different values maps to None. None where that file does not exist (not
    Linux) or cannot be read. Read once (the default file)."""
    default = environ_file == "/proc/self/environ"
    if default and _ENVIRON:
        return _ENVIRON[0]
    try:
        with open(environ_file, "rb") as f:
            entries = f.read().split(b"\0")
    except OSError:
        env = None
    else:
        env = {}
        for entry in entries:
            name, sep, value = entry.partition(b"=")
            if sep:     # (a name given twice with other values: None, neither value is sure)
                name, value = name.decode(errors="replace"), value.decode(errors="replace")
                env[name] = value if env.get(name, value) == value else None
    if default:
        _ENVIRON.append(env)
    return env
