"""Measuring order: a short joint-space path through the planned poses.

Travel between two poses is the time a synchronised point-to-point joint move needs at the joint
speeds ``v`` (rad/s, m/s for prismatic joints): ``t(a, b) = max_j |a_j - b_j| / v_j`` (the slowest
joint sets the time; acceleration is left out). The path starts at ``start`` (default the pose
nearest the middle of the region), is built by nearest neighbour and then improved by 2-opt
(segment reversal while any reversal shortens it) on that metric. Open path: the robot does not
return to the start.

:func:`path_travel` reports the path length both as summed joint motion (rad, Σ_j |Δq_j|) and as
time (s, Σ t plus ``dwell_s`` per pose for settling and measuring).
"""

from __future__ import annotations

import numpy as np

__all__ = ["full_turn_joints", "nearest_turn", "order_path", "path_travel", "travel_from", "travel_matrix", "unwrap_path"]


def travel_matrix(q: np.ndarray, speeds, turns=None) -> np.ndarray:
    """``(N, N)`` move times (s) between the poses ``q`` ``(N, dof)`` at joint ``speeds`` ``(dof,)``.

    ``turns``: ``(dof,)`` bool, joints whose range spans a full turn: their move takes the shorter
    way round (the pose is the same at ``q ± 2π``; :func:`unwrap_path` picks that representation)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (q.shape[1],))
    tw = np.zeros(q.shape[1], bool) if turns is None else np.asarray(turns, bool)
    D = np.zeros((len(q), len(q)))
    for j in range(q.shape[1]):  # dof passes over (N, N): vectorised, bounded memory
        d = np.abs(q[:, None, j] - q[None, :, j])
        if tw[j]:
            d = np.mod(d, 2 * np.pi)
            d = np.minimum(d, 2 * np.pi - d)
        np.maximum(D, d / v[j], out=D)
    return D


def travel_from(q0: np.ndarray, q: np.ndarray, speeds, turns=None) -> np.ndarray:
    """``(N,)`` move times (s) from the pose ``q0`` ``(dof,)`` to each of ``q`` ``(N, dof)``: one row of
    :func:`travel_matrix` without the ``(N, N)`` matrix (a via pool of 40,000 poses needs 12 GB there)."""
    q = np.asarray(q, dtype=np.float64)
    v = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (q.shape[1],))
    tw = np.zeros(q.shape[1], bool) if turns is None else np.asarray(turns, bool)
    d = np.abs(q - np.asarray(q0, dtype=np.float64)[None])
    d = np.where(tw, np.minimum(np.mod(d, 2 * np.pi), 2 * np.pi - np.mod(d, 2 * np.pi)), d)
    return np.max(d / v, axis=1)


def full_turn_joints(lower, upper, joint_type) -> np.ndarray:
    """``(dof,)`` bool: revolute joints whose range ``[lower, upper]`` spans at least a full turn."""
    return np.array([t == "revolute" for t in joint_type]) & (np.asarray(upper) - np.asarray(lower) >= 2 * np.pi - 1e-9)


def nearest_turn(prev: np.ndarray, q: np.ndarray, lower, upper, turns) -> np.ndarray:
    """``q`` ``(K, dof)`` with each full-turn joint (``turns``) moved by a multiple of 2π, within
    ``[lower, upper]``, to the representation nearest ``prev`` ``(K, dof)``: the same poses."""
    q = np.array(q, dtype=np.float64, copy=True)
    tw = np.flatnonzero(np.asarray(turns, bool))
    if tw.size == 0:
        return q
    lo, hi = np.asarray(lower)[tw], np.asarray(upper)[tw]
    cand = q[..., None, tw] + (np.arange(-3, 4) * 2 * np.pi)[:, None]  # (K, 7, t)
    cand = np.where((cand >= lo - 1e-12) & (cand <= hi + 1e-12), cand, np.inf)
    pick = np.argmin(np.abs(cand - np.asarray(prev, dtype=np.float64)[..., None, tw]), axis=-2)  # (K, t)
    q[..., tw] = np.take_along_axis(cand, pick[..., None, :], axis=-2)[..., 0, :]
    return q


def unwrap_path(q_ordered: np.ndarray, lower, upper, turns) -> np.ndarray:
    """The poses in order, each full-turn joint moved by a multiple of 2π (within ``[lower, upper]``) to
    the representation nearest the previous pose: the same poses, reached by the shorter moves."""
    q = np.array(q_ordered, dtype=np.float64, copy=True)
    if not np.any(turns):
        return q
    for i in range(1, len(q)):  # sequential: each choice depends on the one before
        q[i] = nearest_turn(q[i - 1][None], q[i][None], lower, upper, turns)[0]
    return q


def order_path(q: np.ndarray, speeds, start=None, max_passes: int = 50, clear=None, n_near: int = 8,
               turns=None) -> np.ndarray:
    """Permutation ``(N,)`` of the rows of ``q`` giving a short open path (module docstring).

    ``start``: ``(dof,)`` joints the robot starts from (the first pose is the nearest to it);
    default the row nearest the centroid of ``q``. ``clear``: optional ``(I (K,), J (K,)) -> (K,)
    bool``, whether the move from row ``I`` to row ``J`` is free of collisions: nearest neighbour
    then takes the nearest of the ``n_near`` nearest unvisited rows whose move is clear (the nearest
    if none is), and 2-opt makes no reversal that creates a move that is not clear."""
    q = np.asarray(q, dtype=np.float64)
    N = len(q)
    if N <= 2:
        return np.arange(N)
    D = travel_matrix(q, speeds, turns)
    s = np.mean(q, 0) if start is None else np.asarray(start, dtype=np.float64)
    first = int(np.argmin(travel_from(s, q, speeds, turns)))
    cache: dict = {}

    def ok(I, J) -> np.ndarray:
        I, J = np.atleast_1d(I), np.atleast_1d(J)
        if clear is None:
            return np.ones(len(I), bool)
        todo = [k for k in range(len(I)) if (int(I[k]), int(J[k])) not in cache]
        if todo:
            res = clear(I[todo], J[todo])
            for k, r in zip(todo, res):
                cache[(int(I[k]), int(J[k]))] = cache[(int(J[k]), int(I[k]))] = bool(r)
        return np.array([cache[(int(i), int(j))] for i, j in zip(I, J)], bool)

    # nearest neighbour (the nearest clear one among the n_near nearest)
    visited = np.zeros(N, bool)
    path = np.empty(N, dtype=np.int64)
    cur = first
    for i in range(N):
        path[i] = cur
        visited[cur] = True
        if i + 1 < N:
            d = np.where(visited, np.inf, D[cur])
            near = np.argsort(d)[: min(n_near, N - i - 1)]
            if ok([cur], near[:1])[0]:  # most nearest moves are clear: check the others only when not
                cur = int(near[0])
            else:
                good = np.flatnonzero(ok(np.full(len(near) - 1, cur), near[1:]))
                cur = int(near[1 + good[0]] if good.size else near[0])
    # 2-opt on an open path with the first pose fixed: reverse path[i+1..k]
    # gain = d(a,b) + d(c,e) - d(a,c) - d(b,e), a=path[i], b=path[i+1], c=path[k], e=path[k+1] (0 past the end)
    for _ in range(max_passes):
        improved = False
        for i in range(N - 2):
            a, b = path[i], path[i + 1]
            c = path[i + 2 :]
            e_next = np.append(path[i + 3 :], -1)
            d_ce = np.where(e_next >= 0, D[c, np.maximum(e_next, 0)], 0.0)
            d_be = np.where(e_next >= 0, D[b, np.maximum(e_next, 0)], 0.0)
            gain = D[a, b] + d_ce - D[a, c] - d_be
            k = int(np.argmax(gain))
            if gain[k] > 1e-12 and clear is not None:
                e_k = e_next[k]
                new_ok = ok([a], [c[k]])[0] and (e_k < 0 or ok([b], [e_k])[0])
                if not new_ok:
                    continue
            if gain[k] > 1e-12:
                kk = i + 2 + k
                path[i + 1 : kk + 1] = path[i + 1 : kk + 1][::-1].copy()
                improved = True
        if not improved:
            break
    return path


def path_travel(q_ordered: np.ndarray, speeds, dwell_s: float = 0.0) -> dict:
    """Travel along the rows of ``q_ordered`` in order: ``joint_rad`` (Σ over moves and joints of
    |Δq|), ``move_s`` (Σ of max-norm move times), ``total_s`` (plus ``dwell_s`` per pose)."""
    q = np.asarray(q_ordered, dtype=np.float64)
    v = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (q.shape[1],))
    d = np.abs(np.diff(q, axis=0))
    move = float(np.max(d / v, axis=1).sum()) if len(d) else 0.0
    return {"joint_rad": float(d.sum()), "move_s": move, "total_s": move + dwell_s * len(q)}
