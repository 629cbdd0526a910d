"""Bounded memos of read-only values kept by key (typically a digest of array content): the one
shape of the small caches that keep a calibration from computing again what an earlier one, or an
earlier stage, computed from the same inputs."""
from __future__ import annotations


def kept(memo: dict, key, compute, size: int = 8):
    """``memo[key]``, or ``compute()`` kept there (at most ``size`` entries: the oldest dropped).
    The value should be immutable or read-only (an ndarray with its write flag cleared): callers
    share it."""
    value = memo.get(key)
    if value is None:
        value = memo[key] = compute()
        while len(memo) > size:
            memo.pop(next(iter(memo)))
    return value
