"""calib.memo.kept: a value computed once per key, the memo bounded (oldest out first)."""
from __future__ import annotations

from calib.memo import kept


def test_kept_computes_once_per_key_and_drops_the_oldest():
    memo, calls = {}, []

    def compute(v):
        return lambda: calls.append(v) or (v,)

    assert kept(memo, "a", compute(1), size=2) == (1,)
    assert kept(memo, "a", compute(99), size=2) == (1,)        # kept: not computed again
    kept(memo, "b", compute(2), size=2)
    kept(memo, "c", compute(3), size=2)                       # "a" dropped
    assert calls == [1, 2, 3] and list(memo) == ["b", "c"]
    assert kept(memo, "a", compute(4), size=2) == (4,) and list(memo) == ["c", "a"]
