"""calib.memo: a value computed once per key, each memo bounded (oldest, or least recently used,
out first), and every memo of the package emptied by one clear()."""
from __future__ import annotations

import numpy as np

import calib
from calib.memo import MEMOS, Memo, Memos, content_digest

from conftest import BUNDLED_URDF


def test_kept_computes_once_per_key_and_drops_the_oldest():
    memo, calls = Memo("test", 2, owner=Memos()), []

    def compute(v):
        return lambda: calls.append(v) or (v,)

    assert memo.kept("a", compute(1)) == (1,)
    assert memo.kept("a", compute(99)) == (1,)        # kept: not computed again
    memo.kept("b", compute(2))
    memo.kept("c", compute(3))                       # "a" dropped
    assert calls == [1, 2, 3] and "a" not in memo and len(memo) == 2
    assert memo.kept("a", compute(4)) == (4,) and "b" not in memo


def test_a_least_recently_used_memo_keeps_what_was_asked_for():
    memo = Memo("test", 2, lru=True, owner=Memos())
    memo.put("a", 1)
    memo.put("b", 2)
    assert memo.get("a") == 1            # "a" used: "b" is now the oldest
    memo.put("c", 3)
    assert "a" in memo and "b" not in memo


def test_clear_caches_empties_every_memo_and_the_next_call_computes_the_same():
    robot = calib.load_robot(BUNDLED_URDF)
    meas = calib.simulate_measurements(robot, robot.random_configurations(40, 1), rng=2)
    first = calib.calibrate(robot, meas, cv=0)
    assert sum(len(m) for m in MEMOS) > 0
    calib.clear_caches()
    assert [m.name for m in MEMOS if len(m)] == []
    again = calib.calibrate(robot, meas, cv=0)
    np.testing.assert_array_equal(first.robot.values, again.robot.values)


def test_content_digest_tells_shape_type_and_values_apart():
    a = np.arange(6.0)
    assert content_digest(a) == content_digest(a.copy())
    assert content_digest(a) != content_digest(a.reshape(2, 3))
    assert content_digest(a) != content_digest(a.astype(np.float32))
    assert content_digest(a, None) != content_digest(a)
