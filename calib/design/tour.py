"""The order a robot visits the poses of a plan in, and the moves between them.

Travel
------
A joint move (KRL PTP, RAPID MoveAbsJ, URScript movej) is synchronous: every joint arrives
together, so a move takes about ``max_j |dq_j| / v_j`` at the joints' velocity limits ``v_j``
(the URDF's, acceleration ignored). That is the cost of a move (seconds) and the travel of a
path is its sum. A revolute joint whose range holds a full turn or more reaches an angle and the
same angle plus or minus 2 pi: it turns the short way (:func:`unwrapped`), within its limits.

Order
-----
An open path (or a closed one from and back to a home configuration) through all poses:
nearest-neighbour paths from every start (from home only, with a home), then 2-opt and or-opt
improvements until none shortens the path (a local optimum of the travelling-salesman problem;
50 poses take milliseconds). A random order of the same poses travels several times as far.

Moves
-----
:func:`connect` checks each straight joint move with the collision model and, where it collides,
finds intermediate configurations among the known collision-free ones (a lazy roadmap: shortest
paths through them, their moves checked, the blocked ones removed).
"""
from __future__ import annotations

import math

import numpy as np

from calib.errors import DataError

__all__ = ["Travel", "move_times", "unwrapped", "order_poses", "path_travel", "connect", "random_travel", "route"]

#: The lazy roadmap of a blocked move: its configurations, the neighbours each is joined to, and
#: the shortest paths tried.
ROADMAP_NODES = 400
ROADMAP_NEIGHBOURS = 12
ROADMAP_ROUNDS = 40
#: Re-orderings tried when a move finds no waypoints (the move's pair then forbidden), and the
#: cost (seconds) standing for a forbidden move in the order.
REORDERS = 4
FORBIDDEN = 1e6
#: A velocity limit used when the URDF gives none (rad/s, m/s).
DEFAULT_SPEED = 1.0


class Travel:
    """The travel metric of a robot: ``speeds`` (n,) joint velocity limits (rad/s, m/s),
    ``wrap`` (n,) bool the joints that turn the short way, ``lower``/``upper`` (n,) their
    limits (the plan's, inside the URDF's by the joint margin)."""

    def __init__(self, speeds: np.ndarray, wrap: np.ndarray, lower: np.ndarray, upper: np.ndarray):
        speeds = np.asarray(speeds, float)
        self.speeds = np.where(np.isfinite(speeds) & (speeds > 0), speeds, DEFAULT_SPEED)
        self.wrap = np.asarray(wrap, bool)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)

    def delta(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """B - A (..., n), the wrapping joints' difference taken the short way (in [-pi, pi))."""
        d = np.asarray(B, float) - np.asarray(A, float)
        d[..., self.wrap] = (d[..., self.wrap] + math.pi) % (2 * math.pi) - math.pi
        return d

    def times(self, A: np.ndarray, B: np.ndarray) -> np.ndarray:
        """Seconds of the joint moves A -> B (..., n), the short way."""
        return np.max(np.abs(self.delta(A, B)) / self.speeds, axis=-1)

    def nearest(self, prev: np.ndarray, q: np.ndarray) -> np.ndarray:
        """q's representative reached from prev the short way, within the limits (a wrapping
        joint the long way round when the short way would leave them)."""
        out = prev + self.delta(prev, q)
        hi, lo = out > self.upper, out < self.lower
        out[self.wrap & hi] -= 2 * math.pi
        out[self.wrap & lo] += 2 * math.pi
        out[~self.wrap] = np.asarray(q, float)[~self.wrap]
        return out


def move_times(travel: Travel, Q: np.ndarray) -> np.ndarray:
    """(N, N) seconds of the moves between configurations Q (N, n)."""
    return travel.times(Q[:, None, :], Q[None, :, :])


def unwrapped(travel: Travel, path: np.ndarray, *, fixed_first: bool = False, fixed_last: bool = False) -> np.ndarray:
    """The configurations of ``path`` (m, n) with each wrapping joint's angles chosen among their
    representatives within the limits (angle + 2 pi k) so that the joint's total turning
    ``sum |dq|`` is least (dynamic programming over the path, joint by joint); ``fixed_first``,
    ``fixed_last``: the first or last configuration stays as given (a home configuration)."""
    out = np.array(path, float)
    m = len(out)
    if m < 2:
        return out
    for j in np.flatnonzero(travel.wrap):
        lo, hi = travel.lower[j], travel.upper[j]
        reps = []
        for k, a in enumerate(out[:, j]):
            if (fixed_first and k == 0) or (fixed_last and k == m - 1):
                reps.append(np.array([a]))
                continue
            base = a - 2 * math.pi * math.floor((a - lo) / (2 * math.pi))
            r = base + 2 * math.pi * np.arange(0, int((hi - base) // (2 * math.pi)) + 1)
            reps.append(r[(r >= lo - 1e-12) & (r <= hi + 1e-12)] if len(r) else np.array([a]))
        cost = np.zeros(len(reps[0]))
        back = []
        for k in range(1, m):
            step = cost[:, None] + np.abs(reps[k][None, :] - reps[k - 1][:, None])
            back.append(np.argmin(step, axis=0))
            cost = step.min(axis=0)
        i = int(np.argmin(cost))
        for k in range(m - 1, -1, -1):
            out[k, j] = reps[k][i]
            if k:
                i = int(back[k - 1][i])
    return out


def path_travel(travel: Travel, path: np.ndarray) -> float:
    """Seconds of the moves along ``path`` (m, n), as the configurations are given."""
    path = np.asarray(path, float)
    if len(path) < 2:
        return 0.0
    return float(np.sum(np.max(np.abs(np.diff(path, axis=0)) / travel.speeds, axis=1)))


def _length(order: list[int], D: np.ndarray, closed: bool) -> float:
    s = sum(D[a, b] for a, b in zip(order[:-1], order[1:]))
    return s + (D[order[-1], order[0]] if closed else 0.0)


def _nearest_neighbour(D: np.ndarray, start: int) -> list[int]:
    n = len(D)
    seen = np.zeros(n, bool)
    seen[start] = True
    order = [start]
    for _ in range(n - 1):
        d = np.where(seen, np.inf, D[order[-1]])
        nxt = int(np.argmin(d))
        order.append(nxt)
        seen[nxt] = True
    return order


def _two_opt(order: list[int], D: np.ndarray, closed: bool) -> bool:
    """One sweep of 2-opt (reverse order[i..j], the best j for each i); the first node stays
    first. True if improved."""
    n = len(order)
    improved = False
    for i in range(1, n - 1):
        o = np.array(order)
        a, b = o[i - 1], o[i]
        c = o[i + 1:]
        d = np.concatenate([o[i + 2:], [o[0]] if closed else [-1]])
        has = d >= 0
        dd = np.maximum(d, 0)
        delta = D[a, c] - D[a, b] + np.where(has, D[b, dd] - D[c, dd], 0.0)
        k = int(np.argmin(delta))
        if delta[k] < -1e-12:
            j = i + 1 + k
            order[i:j + 1] = order[i:j + 1][::-1]
            improved = True
    return improved


def _or_opt(order: list[int], D: np.ndarray, closed: bool) -> bool:
    """One sweep of or-opt: a run of 1 to 3 nodes moved elsewhere, either way round (the first
    node stays first). True if improved. Each move is scored by the edges it changes."""
    improved = False
    for size in (1, 2, 3):
        i = 1
        while i + size <= len(order):
            run = order[i:i + size]
            rest = order[:i] + order[i + size:]
            p = order[i - 1]
            nxt = order[i + size] if i + size < len(order) else (order[0] if closed else None)
            gain = D[p, run[0]] + (D[run[-1], nxt] - D[p, nxt] if nxt is not None else 0.0)
            # insert between rest[k - 1] and rest[k] (k = len(rest): at the end)
            x = np.array(rest)
            y = np.array(rest[1:] + ([rest[0]] if closed else [-1]))
            best, where = gain - 1e-12, None
            for seq in (run, run[::-1]):
                cost = D[x, seq[0]] + np.where(y >= 0, D[seq[-1], np.maximum(y, 0)] - D[x, np.maximum(y, 0)], 0.0)
                k = int(np.argmin(cost))
                if cost[k] < best:
                    best, where = cost[k], rest[:k + 1] + list(seq) + rest[k + 1:]
            if where is not None and where != order:
                order[:] = where
                improved = True
            i += 1
    return improved


def order_poses(D: np.ndarray, *, home: bool = False, max_sweeps: int = 50, starts: int = 6) -> list[int]:
    """The visiting order of the nodes of a move-time matrix D (N, N): with ``home``, node 0 is
    the home configuration (first, and the path returns to it), else an open path from any
    node. Nearest-neighbour paths from every start, the ``starts`` shortest of them improved by
    2-opt and or-opt until no sweep shortens them (module docstring)."""
    D = np.asarray(D, float)
    n = len(D)
    if n <= 2:
        return list(range(n))
    tours = [_nearest_neighbour(D, s) for s in ([0] if home else range(n))]
    tours.sort(key=lambda o: _length(o, D, home))
    best, best_len = None, math.inf
    for order in tours[:starts]:
        for _ in range(max_sweeps):
            if not (_two_opt(order, D, home) | _or_opt(order, D, home)):
                break
        length = _length(order, D, home)
        if length < best_len:
            best, best_len = list(order), length
    return best


def random_travel(travel: Travel, Q: np.ndarray, rng, home: np.ndarray | None = None, draws: int = 20) -> float:
    """The mean travel (seconds) of ``draws`` random orders of the poses Q (N, n) (from and back
    to ``home`` when given), each move the short way."""
    out = []
    for _ in range(draws):
        path = Q[rng.permutation(len(Q))]
        if home is not None:
            path = np.vstack([home, path, home])
        out.append(path_travel(travel, unwrapped(travel, path, fixed_first=home is not None,
                                                 fixed_last=home is not None)))
    return float(np.mean(out))


def connect(model, travel: Travel, a: np.ndarray, b: np.ndarray, free_pool: np.ndarray) -> list | None:
    """The waypoints of a collision-free move a -> b (both (n,), b reached from a the short way
    already): [] when the straight move is free, else configurations of ``free_pool`` (M, n:
    collision-free ones) with every move between them free, or None when none is found.
    ``model`` is the collision model (:class:`calib.design.collision.CollisionModel`).

    A lazy roadmap: :data:`ROADMAP_NODES` pool configurations (each the representative nearest
    a), half those with the least travel a -> v -> b, half spread over the rest of the pool (the
    ways round an obstacle), joined to their :data:`ROADMAP_NEIGHBOURS` nearest by travel time; the shortest path from a to b is found (Dijkstra), its moves
    checked, the blocked ones removed, until a path's moves are all free; then the waypoints
    a single free move can skip are dropped (:func:`_shortcut`)."""
    if model.move_free(a, b):
        return []
    if len(free_pool) == 0:
        return None
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import dijkstra

    V = np.array([travel.nearest(a, v) for v in free_pool])
    cost = travel.times(a[None], V) + travel.times(V, b[None])
    ranked = np.argsort(cost)
    # the nearest half by travel, the other half spread over the pool (ways round an obstacle)
    near_half = ranked[:ROADMAP_NODES // 2]
    rest = ranked[ROADMAP_NODES // 2:]
    spread = rest[np.linspace(0, len(rest) - 1, min(len(rest), ROADMAP_NODES - len(near_half))).astype(int)] \
        if len(rest) else rest
    V = V[np.concatenate([near_half, spread])]
    nodes = np.vstack([a, b, V])
    D = np.max(np.abs(nodes[:, None, :] - nodes[None, :, :]) / travel.speeds, axis=2)
    k = min(ROADMAP_NEIGHBOURS, len(nodes) - 1)
    near = np.argsort(D, axis=1)[:, 1:k + 1]
    W = np.zeros_like(D)
    rows = np.repeat(np.arange(len(nodes)), k)
    W[rows, near.ravel()] = D[rows, near.ravel()]
    W = np.maximum(W, W.T)
    W[0, 1] = W[1, 0] = 0.0                    # (the straight move is blocked)
    known: dict = {}
    for _ in range(ROADMAP_ROUNDS):
        _, prev = dijkstra(csr_matrix(W), indices=0, return_predecessors=True)
        if prev[1] < 0:
            return None
        path = [1]
        while path[-1] != 0:
            path.append(int(prev[path[-1]]))
        path.reverse()
        blocked = False
        for u, v in zip(path[:-1], path[1:]):
            key = (min(u, v), max(u, v))
            if key not in known:
                known[key] = model.move_free(nodes[u], nodes[v])
            if not known[key]:
                W[u, v] = W[v, u] = 0.0
                blocked = True
        if not blocked:
            return [nodes[i] for i in _shortcut(model, nodes, path, known)]
    return None


def _shortcut(model, nodes: np.ndarray, path: list[int], known: dict) -> list[int]:
    """The waypoints of a free roadmap path with the detours cut: from each kept node, the
    farthest later node reached by one free move (``known``: moves already checked)."""
    keep, i = [], 0
    while i < len(path) - 1:
        for j in range(len(path) - 1, i, -1):
            key = (min(path[i], path[j]), max(path[i], path[j]))
            if key not in known:
                known[key] = model.move_free(nodes[path[i]], nodes[path[j]])
            if known[key]:
                break
        if j < len(path) - 1:
            keep.append(path[j])
        i = j
    return keep


def route(collision, travel: Travel, Q: np.ndarray, home, free_pool: np.ndarray):
    """(path, names, measured, order): the poses Q in visiting order with the waypoints of the
    moves that need them (:mod:`calib.design.tour`); ``order`` the poses' indices into Q in
    visiting order. A move no waypoint frees is forbidden and the poses ordered again (at most
    :data:`REORDERS` times). Poses are named ``P01`` ... in visiting order, waypoints after the
    pose they leave (``P03_via1``), the home ``home`` and, at the end, ``home_end``. ``collision``: the collision model."""
    n = len(Q)
    offset = 0 if home is None else 1
    nodes = Q if home is None else np.vstack([home, Q])
    D = move_times(travel, nodes)
    width = max(2, len(str(n)))
    known: dict = {}
    for _ in range(REORDERS + 1):
        order = order_poses(D, home=home is not None)
        ids = list(order) + ([0] if home is not None else [])
        seq = unwrapped(travel, nodes[ids], fixed_first=home is not None, fixed_last=home is not None)
        labels, number = [], 0
        for at, i in enumerate(ids):
            if home is not None and i == 0:
                labels.append("home" if at == 0 else "home_end")
            else:
                number += 1
                labels.append(f"P{number:0{width}d}")
        entries = [(seq[0], labels[0], not labels[0].startswith("home"))]
        blocked = []
        for k in range(1, len(seq)):
            key = (seq[k - 1].tobytes(), seq[k].tobytes())
            if key not in known:
                known[key] = connect(collision, travel, seq[k - 1], seq[k], free_pool)
            vias = known[key]
            if vias is None:
                blocked.append((ids[k - 1], ids[k]))
                continue
            entries += [(v, f"{labels[k - 1]}_via{j + 1}", False) for j, v in enumerate(vias)]
            entries.append((seq[k], labels[k], not labels[k].startswith("home")))
        if not blocked:
            break
        for i, j in blocked:
            D[i, j] = D[j, i] = FORBIDDEN
    else:
        raise DataError(f"no collision-free move was found between some of the poses after {REORDERS} "
                        f"re-orderings: lower the clearances, or draw more candidates")
    path = np.array([e[0] for e in entries])
    names = [e[1] for e in entries]
    measured = np.array([e[2] for e in entries], bool)
    return path, names, measured, np.array([i - offset for i in ids if home is None or i != 0], int)
