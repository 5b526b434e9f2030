"""Safe moves between planned poses: the synchronised joint move from one pose to the next is checked
at intermediate configurations (no joint moves more than 2° / 5 mm between two checks) with every
constraint of the plan; a move that fails is replaced by a detour through a via pose (a feasible
candidate, not measured) whose two moves are clear, the quickest such detour among the
``n_try`` candidates with the shortest detour time, or by going back along the path already checked
to a pose from which the move is clear; when the planned next pose cannot be reached, the nearest
reachable one goes first. A pose that none of this reaches is tried again between every two
consecutive moves, and dropped and reported only if it fits nowhere.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SafePath", "interpolate_moves", "moves_clear", "safe_path"]


@dataclass
class SafePath:
    """The moves to execute. q: ``(M, dof)`` joints in order; measure: ``(M,)`` bool (False: a via
    pose, moved through only); dropped: indices (into the input order) of poses no safe move reaches;
    order: for each measured row of ``q``, its index in the input order (a pose that no move reached
    where it was is tried again between every two consecutive poses and goes where that is clear)."""

    q: np.ndarray
    measure: np.ndarray
    dropped: np.ndarray
    order: np.ndarray | None = None


def interpolate_moves(q_ordered: np.ndarray, step_rad: float = np.radians(2.0), step_m: float = 0.005,
                      prismatic=None) -> tuple[np.ndarray, np.ndarray]:
    """Intermediate configurations of synchronised joint moves between consecutive rows.

    Returns ``(q (M, dof), move (M,))``: configurations strictly between row i and row i+1 (no joint
    moves more than ``step_rad`` / ``step_m`` between two of them) and the index i of their move."""
    q = np.asarray(q_ordered, dtype=np.float64)
    if len(q) < 2:
        return np.zeros((0, q.shape[1])), np.zeros(0, np.int64)
    pris = np.zeros(q.shape[1], bool) if prismatic is None else np.asarray(prismatic, bool)
    step = np.where(pris, step_m, step_rad)
    d = np.diff(q, axis=0)
    k = np.maximum(np.ceil(np.max(np.abs(d) / step, axis=1)).astype(np.int64), 1)  # sub-moves per move
    move = np.repeat(np.arange(len(d)), k - 1)
    # fraction j / k for j = 1 .. k-1 of each move
    j = np.arange(len(move)) - np.repeat(np.cumsum(k - 1) - (k - 1), k - 1) + 1
    t = j / np.repeat(k, k - 1)
    return q[move] + t[:, None] * d[move], move


def moves_clear(a: np.ndarray, b: np.ndarray, ok_fn, prismatic) -> np.ndarray:
    """``(K,)`` bool: each move ``a[k] -> b[k]`` (``(K, dof)``) is clear at its intermediate configurations."""
    K = len(a)
    if K == 0:
        return np.zeros(0, bool)
    pairs = np.empty((2 * K, a.shape[1]))
    pairs[0::2], pairs[1::2] = a, b
    qi, mv = interpolate_moves(pairs, prismatic=prismatic)
    keep = mv % 2 == 0  # the moves a[k] -> b[k], not b[k] -> a[k+1]
    bad = np.zeros(K, bool)
    if keep.any():
        ok = ok_fn(qi[keep])
        np.logical_or.at(bad, mv[keep][~ok] // 2, True)
    return ~bad


def safe_path(q_ordered: np.ndarray, ok_fn, via_pool: np.ndarray, speeds, prismatic=None, n_try: int = 24,
              start=None, rep=None, n_near: int = 8) -> SafePath:
    """Make every move between consecutive rows of ``q_ordered`` clear (module docstring).

    ok_fn: ``(M, dof) -> (M,) bool`` the configurations that satisfy the plan's constraints (the
    poses themselves already do). via_pool: ``(V, dof)`` feasible configurations to detour through.
    speeds: ``(dof,)`` joint speeds (rad/s, m/s) for the detour time. start: ``(dof,)`` joints the
    robot starts from (its move to the first pose is checked too; None: not checked). rep:
    ``(prev (K, dof), q (K, dof)) -> q'``, the representation of a via pose reached from ``prev``
    (full-turn joints, :func:`hykin.planning.order.nearest_turn`); None: as given."""
    from .order import travel_from

    q = np.asarray(q_ordered, dtype=np.float64)
    v = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (q.shape[1],))
    seq = q if start is None else np.vstack([np.asarray(start, dtype=np.float64)[None], q])
    off = 0 if start is None else 1
    clear = moves_clear(seq[:-1], seq[1:], ok_fn, prismatic)
    out_q, out_m, out_i, dropped = [seq[0]], [start is None], [0 - off], []
    cur, cur_i = seq[0], 0
    rest = list(range(1, len(seq)))  # poses still to visit, in the planned order
    while rest:
        i = rest[0]
        nxt = seq[i]
        direct = clear[i - 1] if cur_i == i - 1 else moves_clear(cur[None], nxt[None], ok_fn, prismatic)[0]
        if not direct:
            # stuck on the planned next pose: the nearest of the others reachable directly goes first
            # (the planned one stays to visit later), so that one blocked move does not leave every later
            # pose a long, blocked move away from where the robot is
            R = np.array(rest[1:], dtype=np.int64)
            if R.size:
                near = R[np.argsort(np.max(np.abs(seq[R] - cur) / v, axis=1))[:n_near]]
                okn = np.flatnonzero(moves_clear(np.broadcast_to(cur, seq[near].shape), seq[near], ok_fn, prismatic))
                if okn.size:
                    k = int(near[okn[0]])
                    rest.remove(k)
                    rest.insert(0, k)
                    out_q.append(seq[k])
                    out_m.append(True)
                    out_i.append(k - off)
                    cur, cur_i = seq[k], k
                    rest.pop(0)
                    continue
        if direct:
            out_q.append(nxt)
            out_m.append(True)
            out_i.append(i - off)
            cur, cur_i = nxt, i
            rest.pop(0)
            continue
        detour = travel_from(cur, via_pool, v) + travel_from(nxt, via_pool, v)
        ranked = np.argsort(detour)
        good = np.zeros(0, np.int64)
        for lo_, hi_ in ((0, n_try), (n_try, 5 * n_try)):  # the quickest detours first, then further ones
            cand = via_pool[ranked[lo_:hi_]]
            if rep is not None and len(cand):
                cand = rep(np.broadcast_to(cur, cand.shape), cand)
            ok_a = moves_clear(np.broadcast_to(cur, cand.shape), cand, ok_fn, prismatic)
            ok_b = moves_clear(cand, np.broadcast_to(nxt, cand.shape), ok_fn, prismatic)
            good = np.flatnonzero(ok_a & ok_b)
            if good.size:
                break
        if good.size:
            out_q += [cand[good[0]], nxt]
            out_m += [False, True]
            out_i += [-1, i - off]
            cur, cur_i = nxt, i
            rest.pop(0)
            continue
        back = _backtrack(out_q, nxt, ok_fn, prismatic)
        if back is not None:  # go back along the path already checked, to where the move is clear
            out_q += [out_q[k] for k in back] + [nxt]
            out_m += [False] * len(back) + [True]
            out_i += [-1] * len(back) + [i - off]
            cur, cur_i = nxt, i
        elif len(out_q) == 1 and start is None:  # the first pose itself is trapped: start from this one
            dropped.append(0)
            out_q, out_m, out_i = [nxt], [True], [i - off]
            cur, cur_i = nxt, i
        else:
            dropped.append(i - off)
        rest.pop(0)
    still = []
    for d in dropped:  # a second chance: between any two consecutive moves, or at the end, where clear
        pos = _insertion(np.array(out_q), q[d], ok_fn, v, prismatic, rep)
        if pos is None:
            still.append(d)
            continue
        k, qd = pos
        out_q.insert(k + 1, qd)
        out_m.insert(k + 1, True)
        out_i.insert(k + 1, d)
    qs, ms, idx = np.array(out_q), np.array(out_m, bool), np.array(out_i, dtype=np.int64)
    if start is not None:
        qs, ms, idx = qs[1:], ms[1:], idx[1:]
    return SafePath(q=qs, measure=ms, dropped=np.array(still, dtype=np.int64), order=idx[ms])


def _backtrack(out_q: list, nxt: np.ndarray, ok_fn, prismatic, depth: int = 6) -> list | None:
    """Indices into ``out_q`` to move back through (the path's own poses, newest first: their moves
    were checked, so are their reverses) until ``nxt`` is reachable by a clear move; None if not
    within ``depth`` steps back."""
    k = np.arange(len(out_q) - 2, max(len(out_q) - 2 - depth, -1), -1)
    if k.size == 0:
        return None
    P = np.array([out_q[j] for j in k])
    ok = moves_clear(P, np.broadcast_to(nxt, P.shape), ok_fn, prismatic)
    if not ok.any():
        return None
    m = int(np.argmax(ok))
    return [int(j) for j in k[: m + 1]]


def _insertion(path: np.ndarray, qd: np.ndarray, ok_fn, v, prismatic, rep):
    """``(k, q')``: insert ``qd`` (as ``q'``, its representation reached from ``path[k]``) after row ``k``
    of ``path`` where both new moves are clear, at the least added travel time; None where nowhere."""
    M = len(path)
    d = np.broadcast_to(qd, path.shape)
    d = rep(path, d) if rep is not None else d.copy()
    ok = moves_clear(path, d, ok_fn, prismatic)
    if M > 1:
        ok[:-1] &= moves_clear(d[:-1], path[1:], ok_fn, prismatic)
    if not ok.any():
        return None
    t_in = np.max(np.abs(d - path) / v, axis=1)
    t_out = np.append(np.max(np.abs(path[1:] - d[:-1]) / v, axis=1), 0.0)
    t_old = np.append(np.max(np.abs(np.diff(path, axis=0)) / v, axis=1), 0.0)
    cost = np.where(ok, t_in + t_out - t_old, np.inf)
    k = int(np.argmin(cost))
    return k, d[k]
