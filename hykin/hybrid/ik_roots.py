"""Extra roots of hybrid IK near singularities: duplicates modulo 2π, restarts along singular
directions and from the other root of a fold (step 4 of :mod:`hykin.hybrid.ik`).

``prob`` arguments are :class:`hykin.hybrid.ik_solve.IKProblem` instances (residual, Jacobians).
"""

from __future__ import annotations

import numpy as np

__all__ = ["duplicates", "more_roots", "null_directions", "pick_new", "second_root_steps", "wrapped_diff"]

def wrapped_diff(a: np.ndarray, b: np.ndarray, rev: np.ndarray) -> np.ndarray:
    """``a - b`` with revolute joints wrapped to ``[-π, π)`` (q and q + 2π are one configuration)."""
    d = a - b
    return np.where(rev, (d + np.pi) % (2 * np.pi) - np.pi, d)


def duplicates(qm: np.ndarray, okm: np.ndarray, order: np.ndarray, rev: np.ndarray, tol: float):
    """Successful rows equal (max joint difference ``<= tol``, modulo 2π) to a better row of the same target.

    ``qm`` ``(N, B, n)``, ``okm`` ``(N, B)``, ``order`` ``(N, B)`` score (lower is kept first).
    Returns ``dup`` ``(N, B)`` bool and ``of`` ``(N, B)`` int: the column of the row each duplicate equals.
    """
    N, B = okm.shape
    perm = np.argsort(np.where(okm, order, np.inf), axis=1, kind="stable")
    qs = np.take_along_axis(qm, perm[..., None], 1)
    oks = np.take_along_axis(okm, perm, 1)
    close = np.abs(wrapped_diff(qs[:, :, None], qs[:, None], rev)).max(-1) <= tol  # (N, B, B)
    close &= oks[:, :, None] & oks[:, None]
    close &= np.tril(np.ones((B, B), dtype=bool), -1)[None]  # [j, i]: i < j
    dup_s = close.any(2)
    first = np.take_along_axis(perm, np.argmax(close, axis=2), 1)  # original column of the kept row
    dup = np.zeros((N, B), dtype=bool)
    of = np.full((N, B), -1)
    np.put_along_axis(dup, perm, dup_s, 1)
    np.put_along_axis(of, perm, np.where(dup_s, first, -1), 1)
    return dup, of


def second_root_steps(prob, q1: np.ndarray, rows: np.ndarray, t_max: float) -> np.ndarray:
    """Steps ``(k, n)`` from solutions ``q1`` towards the other root of a fold (a pair of solutions that
    merge at a singularity, e.g. elbow- and shoulder-boundary pairs of the closed form).

    Along the right singular vector ``v`` of the smallest singular value ``σ`` of the hybrid residual
    Jacobian, the residual is ``r(q1 + t v) ≈ σ u t + ½ c t²`` (``c`` by a central second difference),
    whose second root is ``t* = -2σ / (u·c)``, clipped to ``|t*| <= t_max``.
    """
    J = prob.fd_jac(q1, rows, h=1e-6)
    _, S, Vt = np.linalg.svd(J)
    v = Vt[:, -1]
    sig = S[:, -1]
    u = np.einsum("kij,kj->ki", J, v) / np.maximum(sig, 1e-300)[:, None]
    h = 1e-4
    rp, _ = prob.residual(q1 + h * v, rows)
    rm, _ = prob.residual(q1 - h * v, rows)
    r0, _ = prob.residual(q1, rows)
    c = (rp + rm - 2 * r0) / h**2
    uc = np.einsum("ki,ki->k", u, c)
    t = np.where(np.abs(uc) > 1e-300, -2 * sig / np.where(uc == 0, 1.0, uc), t_max)
    t = np.clip(t, -t_max, t_max)
    return t[:, None] * v


def null_directions(prob, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction ``(k, n)`` of the smallest singular value of the classical Jacobian at ``q`` and
    that value relative to the largest ``(k,)`` (small near a singularity)."""
    J = prob.classical_jac(q)
    _, S, Vt = np.linalg.svd(J)
    return Vt[:, -1], S[:, -1] / np.maximum(S[:, 0], 1e-300)


def pick_new(cand_q: np.ndarray, cand_ok: np.ndarray, have: list, rev: np.ndarray, tol: float) -> int:
    """Index of the first successful candidate farther than ``tol`` from every joint vector in ``have``, or -1."""
    for k in np.flatnonzero(cand_ok):
        if all(np.abs(wrapped_diff(cand_q[k], h, rev)).max() > tol for h in have):
            return int(k)
    return -1


def more_roots(prob, q0u: np.ndarray, labels_u: np.ndarray, st: list, rows: np.ndarray,
                cols: np.ndarray, N: int, B: int, rev: np.ndarray, dedupe_rad: float, sing_rel: float, run) -> None:
    """In place on ``st = [q, pe, ae, ok, box, lim, it]`` (rows ``ui`` of the solve): two searches for
    solutions the box around the classical seed cannot reach, both near singularities.

    1. Failed rows that ended within 1 mm of the target and whose seed is near a singularity
       (smallest / largest singular value of the classical Jacobian ``< sing_rel``): there the hybrid
       correction moves the joints far along the singular direction ``v`` (e.g. joints 4 and 6 at a
       wrist singularity), so restart from ``q0 + t v`` for ``t`` in ±π/8 … π.
    2. Rows that converged onto another row's solution although their seeds (or branch labels
       ``labels_u``) differ: near a fold (two
       closed-form branches close together, e.g. elbow nearly stretched) the hybrid model moves the
       fold, both seeds fall on one side and find the same root. Restart from the other root of the
       local quadratic model (:func:`second_root_steps`).

    A restart is accepted only when it succeeds and differs (``> dedupe_rad``) from every solution of
    its target, so neither search can add a duplicate; ``run(q0, rows)`` is the box solve.
    """
    q, pe, ae, ok, box, lim, it = st
    n = q.shape[1]
    lo, hi = prob.robot.lower, prob.robot.upper

    def sols_of(t):
        return [q[i] for i in np.flatnonzero(ok & (rows == t))]

    def accept(owner, res, n_per):  # few rows (near singularities only): a plain loop
        q2, p2, a2, o2, _, _, i2 = res
        for j, r0 in enumerate(owner):
            sl = slice(j * n_per, (j + 1) * n_per)
            it[r0] += int(i2[sl].sum())
            k = pick_new(q2[sl], o2[sl], sols_of(rows[r0]), rev, dedupe_rad)
            if k >= 0:
                g = j * n_per + k
                q[r0], pe[r0], ae[r0], ok[r0], box[r0], lim[r0] = q2[g], p2[g], a2[g], True, False, False

    # 1. failed rows near a singularity: restarts along the singular direction
    fi = np.flatnonzero(~ok & np.all(np.isfinite(q0u), axis=1) & (pe < 1e-3))
    if fi.size:
        v, rel = null_directions(prob, np.clip(q0u[fi], lo, hi))
        near = rel < sing_rel
        fi, v = fi[near], v[near]
        if fi.size:
            v = v / np.abs(v).max(1, keepdims=True)
            ts = np.pi * np.array([0.125, 0.25, 0.5, 0.75, 1.0, -0.125, -0.25, -0.5, -0.75])
            seeds = np.clip(q0u[fi][:, None] + ts[None, :, None] * v[:, None], lo, hi).reshape(-1, n)
            accept(fi, run(seeds, np.repeat(rows[fi], len(ts))), len(ts))
    # 2. duplicates with distinct seeds: the other root of a fold
    qm = np.full((N * B, n), np.nan)
    okm = np.zeros(N * B, dtype=bool)
    pem = np.full(N * B, np.inf)
    flat = rows * B + cols
    qm[flat], okm[flat], pem[flat] = q, ok, pe
    dup, of = duplicates(qm.reshape(N, B, n), okm.reshape(N, B), pem.reshape(N, B), rev, dedupe_rad)
    pos = np.full(N * B, -1)
    pos[flat] = np.arange(flat.size)
    d_rows = np.flatnonzero(dup.reshape(-1)[flat])  # indices into the solve rows
    if d_rows.size:
        src = pos[rows[d_rows] * B + of.reshape(-1)[flat[d_rows]]]
        # distinct seeds, or seeds of different closed-form branches (equal when both were clamped at a
        # workspace edge the hybrid model reaches); not user seeds repeated on purpose
        distinct = (np.abs(wrapped_diff(q0u[d_rows], q0u[src], rev)).max(1) > dedupe_rad) | (
            labels_u[d_rows] != labels_u[src])
        d_rows, src = d_rows[distinct], src[distinct]
    if d_rows.size:
        t_max = 0.5
        step = second_root_steps(prob, q[src], rows[src], t_max)
        mult = np.array([1.0, 1.5, 2.5, -1.0])
        seeds = np.clip(q[src][:, None] + mult[None, :, None] * step[:, None], lo, hi).reshape(-1, n)
        ok[d_rows] = False  # a duplicate: only a new, distinct root makes it a success again
        accept(d_rows, run(seeds, np.repeat(rows[d_rows], len(mult))), len(mult))
        lost = ~ok[d_rows]
        ok[d_rows[lost]] = True  # no other root: stays the duplicate it was (merged at the end)

