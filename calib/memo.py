"""The memos of calib: bounded tables of read-only values kept by key (typically a digest of array
content), so that a calibration does not compute again what an earlier one, or an earlier stage,
computed from the same inputs.

Every memo is a :class:`Memo` registered with the one owner :data:`MEMOS`; ``MEMOS.clear()``
(the public :func:`calib.clear_caches`) empties them all, e.g. to free their memory or to time a
cold call. Values kept must be immutable or read-only (an ndarray with its write flag cleared):
callers share them.
"""
from __future__ import annotations

from collections import OrderedDict
from hashlib import blake2b

import numpy as np

__all__ = ["Memo", "Memos", "MEMOS", "clear_caches", "content_digest"]


class Memo:
    """A bounded memo: at most ``size`` values; when full, the oldest entry is dropped (with
    ``lru``, the least recently used: a hit moves its entry to the end)."""

    def __init__(self, name: str, size: int, *, lru: bool = False, owner: "Memos | None" = None):
        self.name, self.size, self.lru = name, int(size), lru
        self._table: OrderedDict = OrderedDict()
        (MEMOS if owner is None else owner).register(self)

    def __len__(self) -> int:
        return len(self._table)

    def __contains__(self, key) -> bool:
        return key in self._table

    def get(self, key, default=None):
        """The value kept for ``key``, else ``default``."""
        if key not in self._table:
            return default
        if self.lru:
            self._table.move_to_end(key)
        return self._table[key]

    def put(self, key, value):
        """Keep ``value`` for ``key`` (the oldest dropped beyond ``size``); returns ``value``."""
        self._table[key] = value
        if self.lru:
            self._table.move_to_end(key)
        while len(self._table) > self.size:
            self._table.popitem(last=False)
        return value

    def kept(self, key, compute):
        """The value kept for ``key``, or ``compute()`` kept there."""
        value = self.get(key)
        return self.put(key, compute()) if value is None else value

    def clear(self) -> None:
        self._table.clear()


class Memos:
    """The owner of every :class:`Memo` of the process: :meth:`clear` empties them all."""

    def __init__(self) -> None:
        self._memos: list[Memo] = []

    def register(self, memo: Memo) -> None:
        self._memos.append(memo)

    def __iter__(self):
        return iter(self._memos)

    def clear(self) -> None:
        for memo in self._memos:
            memo.clear()


#: The process's memos (each module's :class:`Memo` registers here when the module loads).
MEMOS = Memos()


def clear_caches() -> None:
    """Empty every memo of calib (:data:`MEMOS`): the values kept from earlier calls (analyses,
    frame estimates, chain structures, draws) are computed again when next asked for."""
    MEMOS.clear()


def content_digest(*arrays) -> str:
    """A digest of arrays' shapes, types and values (None: a marker of its own), for memo keys
    that must not hold large data: the one place calib hashes array content."""
    h = blake2b(digest_size=20)
    for a in arrays:
        if a is None:
            h.update(b"-")
        else:
            a = np.ascontiguousarray(a)
            h.update(f"{a.shape}{a.dtype.str}".encode())
            h.update(a.tobytes())
    return h.hexdigest()
