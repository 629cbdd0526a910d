"""calib's dataclasses with their generated methods compiled once, kept beside calib's bytecode.

calib's modules take :func:`dataclass` from here: it *is* :func:`dataclasses.dataclass`, imported
after :func:`install` has run.

Why: when a dataclass is created, :mod:`dataclasses` writes the source text of its ``__init__``,
``__repr__``, ``__eq__``, ``__hash__``, ``__setattr__`` and ``__delattr__`` and compiles it
with ``exec`` (Python 3.11: one compile per method). Python keeps a module's bytecode in
``__pycache__``, but not these: the 137 compiles of the 36 classes that ``calib calibrate``
creates took 23-24 ms of every run, a third of what calib adds to ``import pinocchio``.

How: :mod:`dataclasses` looks ``exec`` up in its own module globals before the builtins, and
:func:`install` puts :func:`_exec` there. For a text that a class of a calib module makes (the
globals dataclasses passes are that module's), it takes the code compiled from that exact text
earlier, or compiles it as ``exec`` would and keeps it; another package's class is compiled as
``exec`` would compile it there and kept nowhere, and a code object goes to the builtin as it is
(the builtin called from here would inherit this module's ``__future__`` flags: a text is always
compiled here first, by :func:`_compile`). The same text compiles to the same code:
``compile(text, "<string>", "exec", dont_inherit=True)`` is what ``exec(text)`` compiles in
dataclasses.py, which has no ``__future__`` imports, at the interpreter's optimisation level
(which names the file). The functions made from it, with the module's globals and the values
dataclasses passes, are the ones dataclasses would make. Where a later Python's dataclasses no
longer calls ``exec`` by that name, nothing changes but the time.

Where: one marshal file in calib's ``__pycache__``, named and placed by the rules of a module's
bytecode (:func:`importlib.util.cache_from_source`: the interpreter's cache tag and
optimisation level, ``PYTHONPYCACHEPREFIX``), starting with the interpreter's magic number
(another is ignored). It holds each module's texts apart, unmarshalled when that module
creates its first class. At exit, when a module's class compiled a text the file did not hold,
that module's entry is replaced by the texts its classes used in this process (all of them:
calib creates its dataclasses when a module is imported), so that an edited class leaves no
stale code behind; the file is written atomically, only where bytecode may be written
(``sys.dont_write_bytecode``, ``PYTHONDONTWRITEBYTECODE``), and a read-only installation or an
unreadable file just compiles as before. ``CALIB_DATACLASS_CACHE=0`` turns it all off.
"""
from __future__ import annotations

import builtins
import dataclasses
import marshal
import os
import sys
import types

__all__ = ["dataclass", "install", "cache_path", "ENV_OFF"]

#: The environment variable that turns the cache off (``0``).
ENV_OFF = "CALIB_DATACLASS_CACHE"
#: A module's name that makes its classes' texts cached: calib's own.
PREFIX = "calib."

_builtin_exec = builtins.exec
_file: dict | None = None           # module -> marshalled {text: code}, as read from the file
_codes: dict = {}                   # module -> {text: code}, unmarshalled on the module's first class
_used: dict = {}                    # module -> {text: code} its classes used in this process
_new: set = set()                   # modules that compiled a text the file did not hold


def cache_path() -> str:
    """The cache file's path: where :func:`importlib.util.cache_from_source` puts the bytecode of
    a module ``calib/dataclass-methods.py`` (``calib/__pycache__/dataclass-methods.cpython-311.pyc``
    without ``PYTHONPYCACHEPREFIX``, ``...opt-1.pyc`` under ``python -O``)."""
    from importlib.util import cache_from_source

    return cache_from_source(os.path.join(os.path.dirname(os.path.abspath(__file__)), "dataclass-methods.py"))


def _magic() -> bytes:
    from importlib.util import MAGIC_NUMBER

    return MAGIC_NUMBER


def _read() -> dict:
    """The file's modules and their marshalled texts; ``{}`` when it is absent, of another
    interpreter or unreadable."""
    try:
        with open(cache_path(), "rb") as f:
            blob = f.read()
        magic = _magic()
        if not blob.startswith(magic):
            return {}
        entries = marshal.loads(memoryview(blob)[len(magic):])
    except (OSError, ValueError, EOFError, TypeError):
        return {}
    if not isinstance(entries, dict):
        return {}
    return {m: b for m, b in entries.items() if isinstance(m, str) and isinstance(b, bytes)}


def _module_codes(module: str) -> dict:
    """``{text: code}`` of ``module`` (read from the file on its first class)."""
    global _file
    codes = _codes.get(module)
    if codes is None:
        if _file is None:
            _file = _read()
        codes = {}
        blob = _file.get(module)
        if blob is not None:
            try:
                loaded = marshal.loads(blob)
            except (ValueError, EOFError, TypeError):
                loaded = None
            if isinstance(loaded, dict):
                codes = {t: c for t, c in loaded.items() if isinstance(t, str) and isinstance(c, types.CodeType)}
        _codes[module] = codes
    return codes


def _compile(text: str) -> types.CodeType:
    """The code ``exec(text)`` compiles in dataclasses.py: no ``__future__`` flags inherited."""
    return compile(text, "<string>", "exec", dont_inherit=True)


def _exec(source, *args, **kwargs):
    """``exec`` as :mod:`dataclasses` calls it (``exec(text, globals, ns)``): a text from a calib
    module's class runs the code kept for that text; any other text is compiled as dataclasses'
    own ``exec`` compiles it (no ``__future__`` flags: this module's would be inherited from here),
    and anything else goes to the builtin ``exec`` as it is."""
    if type(source) is not str:
        return _builtin_exec(source, *args, **kwargs)
    globals = args[0] if args else kwargs.get("globals")
    module = globals.get("__name__") if type(globals) is dict else None
    if type(module) is not str or not module.startswith(PREFIX):
        return _builtin_exec(_compile(source), *args, **kwargs)
    codes = _module_codes(module)
    code = codes.get(source)
    if code is None:
        code = codes[source] = _compile(source)
        _new.add(module)
    _used.setdefault(module, {})[source] = code
    return _builtin_exec(code, *args, **kwargs)


def _write() -> None:
    """At exit: the file with each module that compiled a new text replaced by the texts its
    classes used here, when bytecode may be written; nothing when it cannot be."""
    if not _new or sys.dont_write_bytecode:
        return
    entries = dict(_read())          # as it is now: another process may have written it
    for module in list(_new):
        if module in _used:
            entries[module] = marshal.dumps(_used[module])
    path = cache_path()
    tmp = f"{path}.{os.getpid()}.tmp"
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
        # (as importlib writes bytecode: the mode of the package's source, a file of our own)
        mode = os.stat(__file__).st_mode & 0o666
        fd = os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, mode)
        try:
            with open(fd, "wb") as f:
                f.write(_magic() + marshal.dumps(entries))
            os.replace(tmp, path)
        except OSError:
            try:
                os.unlink(tmp)
            except OSError:
                pass
    except OSError:
        pass
    _new.clear()


def install() -> None:
    """Put :func:`_exec` in :mod:`dataclasses`' globals and have the new codes written at exit
    (once; not with ``CALIB_DATACLASS_CACHE=0``, nor where something else is there already or the
    interpreter caches no bytecode)."""
    if (os.environ.get(ENV_OFF) == "0" or "exec" in vars(dataclasses)
            or sys.implementation.cache_tag is None):       # (no bytecode cache: nowhere to keep them)
        return
    dataclasses.exec = _exec
    import atexit

    atexit.register(_write)


install()
#: :func:`dataclasses.dataclass` itself (calib's modules import it from here, so that the cache
#: is in place before their first class).
dataclass = dataclasses.dataclass
