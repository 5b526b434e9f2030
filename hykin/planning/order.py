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

__all__ = ["order_path", "path_travel", "travel_matrix"]


def travel_matrix(q: np.ndarray, speeds) -> np.ndarray:
    """``(N, N)`` move times (s) between the poses ``q`` ``(N, dof)`` at joint ``speeds`` ``(dof,)``."""
    q = np.asarray(q, dtype=np.float64)
    v = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (q.shape[1],))
    D = np.zeros((len(q), len(q)))
    for j in range(q.shape[1]):  # dof passes over (N, N): vectorised, bounded memory
        np.maximum(D, np.abs(q[:, None, j] - q[None, :, j]) / v[j], out=D)
    return D


def order_path(q: np.ndarray, speeds, start=None, max_passes: int = 50) -> np.ndarray:
    """Permutation ``(N,)`` of the rows of ``q`` giving a short open path (module docstring).

    ``start``: ``(dof,)`` joints the robot starts from (the first pose is the nearest to it);
    default the row nearest the centroid of ``q``."""
    q = np.asarray(q, dtype=np.float64)
    N = len(q)
    if N <= 2:
        return np.arange(N)
    D = travel_matrix(q, speeds)
    s = np.mean(q, 0) if start is None else np.asarray(start, dtype=np.float64)
    first = int(np.argmin(travel_matrix(np.vstack([s, q]), speeds)[0, 1:]))
    # nearest neighbour
    visited = np.zeros(N, bool)
    path = np.empty(N, dtype=np.int64)
    cur = first
    for i in range(N):
        path[i] = cur
        visited[cur] = True
        if i + 1 < N:
            d = np.where(visited, np.inf, D[cur])
            cur = int(np.argmin(d))
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
