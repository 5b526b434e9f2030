"""Inverse kinematics: the public API (closed form where it exists, Levenberg–Marquardt everywhere).

* :func:`ik` — one solution per target (nearest the seed) or, with ``all_branches=True``, every
  distinct solution. Robots with a closed form (:func:`~hykin.kinematics.ik_closed_form.has_closed_form`)
  are seeded from it (or from the closed form of ``seed_robot``, e.g. the nominal robot behind a
  calibrated one) and polished with LM; other robots (7 dof, prismatic joints, calibrated geometry)
  use LM from the seed and random restarts.
* :func:`ik_closed_form` — every closed-form branch (:mod:`hykin.kinematics.ik_closed_form`), with
  near-singular candidates refined by LM.
* :func:`solve_lm` — one batched LM run from given seeds (compiled per-target kernel, adaptive
  damping, joints projected onto their limits after every step).
* :func:`ik_numeric` — LM from a seed plus random restarts for the targets that failed.
* :func:`ik_all_numeric` — exhaustive numerical search: many random seeds per target, duplicates
  removed modulo 2π (the reference the closed form is tested against).

Residual: position ``p_t − p`` (m) and orientation ``log(R_t Rᵀ)`` (rad, world frame); with
``position_only=True`` only the position. ``success`` is true only where the final residual is
below ``tol_m`` and ``tol_rad`` *and* the joints are within limits; failed targets keep the best
joints found (so the caller can see how close it got) but are never reported as solved.
Redundant robots (7 dof) have infinitely many solutions: ``all_branches`` then returns the distinct
solutions found from the random seeds, a sample of the self-motion manifold.
"""

from __future__ import annotations

import numpy as np

from .chain import chain_of
from .chunks import run_chunked
from .fk import HAVE_NUMBA, fk
from .ik_closed_form import closed_form_candidates, has_closed_form
from .ik_solutions import (
    IKBranches,
    IKResult,
    IKSolutions,
    as_targets,
    mark_duplicates,
    nearest_representation,
    pose_residual,
    wrap_to_limits,
)
from .robot import Robot

__all__ = ["IKBranches", "IKResult", "ik", "ik_all_numeric", "ik_closed_form", "ik_numeric", "nearest_representation",
           "solve_lm"]


# --------------------------------------------------------------------------- LM kernel

if HAVE_NUMBA:
    import numba

    # joint axes, origins and TCP of one configuration: the chain walk's compiled backend
    from .walk import axes_one as _frames

    @numba.njit(cache=True, nogil=True)
    def _residual(T, Tt, pos_only, e):  # pragma: no cover - compiled
        """e[:3] = p_t − p; e[3:] = log(R_t Rᵀ) (world). Returns (|Δp|, angle)."""
        e[0] = Tt[0, 3] - T[0, 3]
        e[1] = Tt[1, 3] - T[1, 3]
        e[2] = Tt[2, 3] - T[2, 3]
        pe = np.sqrt(e[0] * e[0] + e[1] * e[1] + e[2] * e[2])
        if pos_only:
            return pe, 0.0
        M = np.empty((3, 3))
        for r in range(3):
            for c in range(3):
                M[r, c] = Tt[r, 0] * T[c, 0] + Tt[r, 1] * T[c, 1] + Tt[r, 2] * T[c, 2]
        vx = 0.5 * (M[2, 1] - M[1, 2])
        vy = 0.5 * (M[0, 2] - M[2, 0])
        vz = 0.5 * (M[1, 0] - M[0, 1])
        s = np.sqrt(vx * vx + vy * vy + vz * vz)
        cth = 0.5 * (M[0, 0] + M[1, 1] + M[2, 2] - 1.0)
        th = np.arctan2(s, cth)
        if cth > -0.9 or s > 1e-3:
            f = th / s if s > 1e-300 else 1.0
            e[3], e[4], e[5] = vx * f, vy * f, vz * f
        else:  # near π: axis from the symmetric part
            k = 0
            best = M[0, 0]
            for i in range(1, 3):
                if M[i, i] > best:
                    best, k = M[i, i], i
            a = np.empty(3)
            denom = np.sqrt(max((M[k, k] - cth) * (1.0 - cth), 1e-300))
            for i in range(3):
                a[i] = (0.5 * (M[i, k] + M[k, i]) - (cth if i == k else 0.0)) / denom
            nrm = np.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2])
            sgn = 1.0 if (a[0] * vx + a[1] * vy + a[2] * vz) >= 0 else -1.0
            e[3], e[4], e[5] = sgn * a[0] / nrm * th, sgn * a[1] / nrm * th, sgn * a[2] / nrm * th
        return pe, th

    @numba.njit(cache=True, nogil=True)
    def _masked_solve(A, g, lam, frozen, dq, L, rhs):  # pragma: no cover - compiled
        """Solve (A + lam I) dq = g for the free joints, frozen joints keep their dq (Cholesky,
        A holds the lower triangle). Returns False when the matrix is not positive definite."""
        n = g.shape[0]
        for a in range(n):
            if frozen[a]:
                rhs[a] = dq[a]
            else:
                s = g[a]
                for b in range(n):
                    if frozen[b]:
                        s -= (A[a, b] if b <= a else A[b, a]) * dq[b]
                rhs[a] = s
        for a in range(n):
            for b in range(a + 1):
                if frozen[a] or frozen[b]:
                    s = 1.0 if a == b else 0.0
                else:
                    s = A[a, b] + (lam if a == b else 0.0)
                for k in range(b):
                    s -= L[a, k] * L[b, k]
                if a == b:
                    if s <= 0.0:
                        return False
                    L[a, a] = np.sqrt(s)
                else:
                    L[a, b] = s / L[b, b]
        for a in range(n):
            s = rhs[a]
            for k in range(a):
                s -= L[a, k] * rhs[k]
            rhs[a] = s / L[a, a]
        for a in range(n - 1, -1, -1):
            s = rhs[a]
            for k in range(a + 1, n):
                s -= L[k, a] * dq[k]
            dq[a] = s / L[a, a]
        return True

    @numba.njit(cache=True, nogil=True)
    def normal_equations_one(J, e, m, A, g):  # pragma: no cover - compiled
        """``g = Jᵀ e`` and the lower triangle of ``A = JᵀJ`` over the first ``m`` rows; returns trace(A)."""
        n = g.shape[0]
        tr = 0.0
        for a in range(n):
            s = 0.0
            for r in range(m):
                s += J[r, a] * e[r]
            g[a] = s
            for b in range(a + 1):
                s = 0.0
                for r in range(m):
                    s += J[r, a] * J[r, b]
                A[a, b] = s
            tr += A[a, a]
        return tr

    @numba.njit(cache=True, nogil=True)
    def projected_solve(A, g, lam, q, lower, upper, frozen, dq, L, rhs):  # pragma: no cover - compiled
        """Active-set projected step ``dq`` of ``(A + lam I) dq = g`` in the box: joints whose step would
        leave it are moved onto the bound and frozen, the others re-solved (up to n passes). False when
        the damped matrix is not positive definite."""
        n = g.shape[0]
        for i in range(n):
            frozen[i] = False
        okc = True
        for _pass in range(n + 1):
            okc = _masked_solve(A, g, lam, frozen, dq, L, rhs)
            if not okc:
                break
            new = False
            for i in range(n):
                if not frozen[i]:
                    if q[i] + dq[i] > upper[i]:
                        frozen[i] = True
                        dq[i] = upper[i] - q[i]
                        new = True
                    elif q[i] + dq[i] < lower[i]:
                        frozen[i] = True
                        dq[i] = lower[i] - q[i]
                        new = True
            if not new:
                break
        return okc

    @numba.njit(cache=True, nogil=True)
    def lm_scratch(n):  # pragma: no cover - compiled
        """Scratch of one LM target with ``n`` joints (this kernel and the hybrid one of hykin.hybrid):
        ``(e, e_new (6,), J (6, n), A (n, n), g, dq, q_new (n,), L (n, n), rhs (n,), frozen (n,) bool)``."""
        return (np.empty(6), np.empty(6), np.zeros((6, n)), np.empty((n, n)), np.empty(n), np.empty(n), np.empty(n),
                np.empty((n, n)), np.empty(n), np.zeros(n, np.bool_))

    #: public name of the one-target residual (the hybrid LM kernel of hykin.hybrid uses it)
    pose_residual_one = _residual

    # The rule of hykin.kinematics.lm.lm_solve (damping="identity", active-set projection, accept on a
    # cost decrease, λ/10 floored at 1e-12 or 10 λ, stop at λ > 1e10), compiled per target: a rejected
    # step is retried with the larger λ at once (same Jacobian), so `it` counts Jacobians, not trials.
    @numba.njit(cache=True, nogil=True)
    def _lm_one(fixed, prismatic, lower, upper, Tt, q, pos_only, tol_m, tol_rad, max_iter, lam0):  # pragma: no cover
        n = q.shape[0]
        m = 3 if pos_only else 6
        z = np.empty((n, 3))
        o = np.empty((n, 3))
        T = np.empty((3, 4))
        zn = np.empty((n, 3))
        on = np.empty((n, 3))
        Tn = np.empty((3, 4))
        e, en, J, A, g, dq, qn, L, rhs, frozen = lm_scratch(n)
        for i in range(n):
            q[i] = min(max(q[i], lower[i]), upper[i])
        _frames(fixed, prismatic, q, z, o, T)
        pe, ae = _residual(T, Tt, pos_only, e)
        cost = 0.0
        for r in range(m):
            cost += e[r] * e[r]
        lam = lam0
        it = 0
        while it < max_iter:
            if pe <= tol_m and ae <= tol_rad:
                break
            it += 1
            for i in range(n):
                if prismatic[i]:
                    J[0, i], J[1, i], J[2, i] = z[i, 0], z[i, 1], z[i, 2]
                    J[3, i] = J[4, i] = J[5, i] = 0.0
                else:
                    dx, dy, dz = T[0, 3] - o[i, 0], T[1, 3] - o[i, 1], T[2, 3] - o[i, 2]
                    J[0, i] = z[i, 1] * dz - z[i, 2] * dy
                    J[1, i] = z[i, 2] * dx - z[i, 0] * dz
                    J[2, i] = z[i, 0] * dy - z[i, 1] * dx
                    J[3, i], J[4, i], J[5, i] = z[i, 0], z[i, 1], z[i, 2]
            normal_equations_one(J, e, m, A, g)
            accepted = False
            while not accepted:
                okc = projected_solve(A, g, lam, q, lower, upper, frozen, dq, L, rhs)
                if not okc:
                    lam *= 10.0
                    if lam > 1e10:
                        break
                    continue
                for i in range(n):
                    qn[i] = min(max(q[i] + dq[i], lower[i]), upper[i])
                _frames(fixed, prismatic, qn, zn, on, Tn)
                pen, aen = _residual(Tn, Tt, pos_only, en)
                costn = 0.0
                for r in range(m):
                    costn += en[r] * en[r]
                if costn < cost:
                    accepted = True
                    for i in range(n):
                        q[i] = qn[i]
                        for r in range(3):
                            z[i, r] = zn[i, r]
                            o[i, r] = on[i, r]
                    for r in range(3):
                        for c in range(4):
                            T[r, c] = Tn[r, c]
                    for r in range(6):
                        e[r] = en[r]
                    cost, pe, ae = costn, pen, aen
                    lam = max(lam * 0.1, 1e-12)
                else:
                    lam *= 10.0
                    if lam > 1e10:
                        break
            if not accepted:
                break
        return pe, ae, it

    @numba.njit(cache=True, nogil=True)
    def _lm_range(fixed, prismatic, lower, upper, Tt, q, pos_only, tol_m, tol_rad, max_iter, lam0, pe, ae, iters,
                  start, stop):  # pragma: no cover
        for k in range(start, stop):
            pe[k], ae[k], iters[k] = _lm_one(fixed, prismatic, lower, upper, Tt[k], q[k], pos_only, tol_m, tol_rad,
                                             max_iter, lam0)


def _lm_numpy(robot, T, q, pos_only, tol_m, tol_rad, max_iter, lam0, lo, hi):
    """Vectorised numpy LM (fallback without numba): :func:`hykin.kinematics.lm.lm_solve` with the
    compiled kernel's rule (identity damping from ``lam0``, stop when λ > 1e10), batched over targets.
    Residual ``p − p_t`` and ``log(R R_tᵀ)`` (the kernel's ``−e``), Jacobian the geometric one."""
    from ..geometry.se3 import matrix_to_rotvec
    from .fk import fk_frames, jacobian
    from .lm import lm_solve

    m = 3 if pos_only else 6

    def resid(qq, idx):
        fr = fk_frames(robot, qq)
        Tt = T[idx]
        r = np.concatenate([fr.tcp[:, :3, 3] - Tt[:, :3, 3],
                            -matrix_to_rotvec(Tt[:, :3, :3] @ np.swapaxes(fr.tcp[:, :3, :3], -1, -2))], -1)
        return r[:, :m], (jacobian(robot, qq, frames=fr)[:, :m],)

    def errs(r):
        return np.linalg.norm(r[:, :3], axis=1), (np.zeros(len(r)) if pos_only else np.linalg.norm(r[:, 3:], axis=1))

    def converged(r):
        pe, ae = errs(r)
        return (pe <= tol_m) & (ae <= tol_rad)

    res = lm_solve(resid, lambda qq, idx, aux, it: aux[0], q, lo, hi, converged=converged, lam0=lam0,
                   damping="identity", lam_max=1e10, max_iter=max_iter)
    pe, ae = errs(res.r)
    return res.q, pe, ae, res.iterations


def solve_lm(robot: Robot, T_world, q0, position_only: bool = False, tol_m: float = 1e-10,
             tol_rad: float = 1e-10, max_iter: int = 50, lambda0: float = 1e-3, bounded: bool = True):
    """One LM run per target from seeds ``q0`` ``(N, dof)``.

    bounded: project every step onto the joint limits; ``False`` leaves revolute joints free (the
    caller maps the result back into the limits; free iterations converge about twice as often
    from random seeds) and still clamps prismatic joints.
    Returns ``(q (N, dof), pos_err_m (N,), ang_err_rad (N,), iterations (N,))``. Stops per target when
    both residuals are below tolerance, after ``max_iter`` iterations, or when no damping improves
    the cost (local minimum / joint limit). The rule is that of :mod:`hykin.kinematics.lm` with
    ``damping="identity"`` (λ I from ``lambda0``), active-set projection, λ/10 on a decrease, 10 λ
    otherwise, stop at λ > 1e10: the compiled kernel ``_lm_one`` with numba, else :func:`hykin.kinematics.lm.lm_solve` itself.
    """
    T, _ = as_targets(T_world)
    q = np.array(np.broadcast_to(np.asarray(q0, dtype=np.float64), (len(T), robot.dof)), order="C")  # one kernel signature
    lo, hi = robot.lower, robot.upper
    if not bounded:
        rev = robot.revolute
        lo, hi = np.where(rev, -np.inf, lo), np.where(rev, np.inf, hi)
    ch = chain_of(robot)
    if not HAVE_NUMBA or ch.expand is not None:  # the kernel walks chain joints; mimic robots use numpy
        return _lm_numpy(robot, T, q, position_only, tol_m, tol_rad, max_iter, lambda0, lo, hi)
    N = len(T)
    pe, ae, it = np.empty(N), np.empty(N), np.empty(N, np.int64)
    args = (np.ascontiguousarray(ch.fixed), np.ascontiguousarray(ch.prismatic, dtype=np.bool_),
            np.ascontiguousarray(lo, dtype=np.float64), np.ascontiguousarray(hi, dtype=np.float64),
            np.ascontiguousarray(T), q, bool(position_only), float(tol_m), float(tol_rad), int(max_iter),
            float(lambda0), pe, ae, it)
    run_chunked(_lm_range, args, N, min_chunk=200)
    return q, pe, ae, it


def _attempt(robot: Robot, T, q0, position_only, tol_m, tol_rad, max_iter, lsq=None):
    """Free LM from ``q0``, result moved to its 2π-representation nearest ``q0`` within limits; where
    that is still outside the limits (another branch is needed, or a redundant robot), a bounded LM
    from the clipped joints. Returns ``(q, pe, ae, it, ok)``. ``lsq`` ``(m, rad)``: accept where LM
    stopped within these (least-squares solutions of an under-actuated arm, :func:`ik`)."""
    q, pe, ae, it = solve_lm(robot, T, q0, position_only, tol_m, tol_rad, max_iter, bounded=False)
    rev = robot.revolute
    q = np.where(rev, nearest_representation(q, q0, robot.lower, robot.upper), q)
    acc_m, acc_rad = (tol_m, tol_rad) if lsq is None else (max(tol_m, lsq[0]), max(tol_rad, lsq[1]))
    conv = (pe <= acc_m) & (ae <= acc_rad)
    inl = robot.within_limits(q, tol=0.0)
    fix = np.flatnonzero(conv & ~inl)
    if fix.size:
        q2, pe2, ae2, it2 = solve_lm(robot, T[fix], np.clip(q[fix], robot.lower, robot.upper), position_only, tol_m,
                                     tol_rad, max_iter, bounded=True)
        q[fix], pe[fix], ae[fix], it[fix] = q2, pe2, ae2, it[fix] + it2
    ok = (pe <= acc_m) & (ae <= acc_rad) & robot.within_limits(q, tol=0.0)
    bad = np.flatnonzero(~ok)
    if bad.size:  # failed rows: report the clipped joints and their true residual, never joints outside limits
        q[bad] = np.clip(q[bad], robot.lower, robot.upper)
        pe[bad], ae[bad] = _final_check(robot, T[bad], q[bad], position_only)
    return q, pe, ae, it, ok


def _final_check(robot, T, q, position_only):
    """Independent residual of the returned joints (plain FK), so success is never self-reported."""
    pe, ae = pose_residual(fk(robot, q), T)
    if position_only:
        ae = np.zeros_like(ae)
    return pe, ae


def ik_numeric(robot: Robot, T_world, q_seed=None, position_only: bool = False, tol_m: float = 1e-10,
               tol_rad: float = 1e-10, max_iter: int = 50, restarts: int = 40,
               rng: np.random.Generator | int | None = 0, lsq=None) -> IKResult:
    """LM from ``q_seed`` (default: middle of the joint limits), then up to ``restarts`` rounds of
    random seeds (uniform within limits) for the targets still failing (the later half of the rounds
    with ``4 * max_iter`` iterations). Failed targets return their best joints, clipped to the limits.
    ``lsq`` ``(m, rad)``: success within these (least-squares solutions, :func:`ik`)."""
    T, _ = as_targets(T_world)
    N, n = len(T), robot.dof
    rng = np.random.default_rng(rng)
    if q_seed is None:
        mid = 0.5 * (robot.lower + robot.upper)
        q_seed = np.where(np.isfinite(mid), mid, 0.0)
    q_seed = np.broadcast_to(np.asarray(q_seed, dtype=np.float64), (N, n))
    q, pe, ae, it, ok = _attempt(robot, T, q_seed, position_only, tol_m, tol_rad, max_iter, lsq)
    for r in range(restarts):
        bad = np.flatnonzero(~ok)
        if bad.size == 0:
            break
        # the second half of the restarts allows 4x the iterations (slow convergence near limits)
        mi = max_iter if r < restarts // 2 else 4 * max_iter
        q2, pe2, ae2, it2, ok2 = _attempt(robot, T[bad], robot.random_joints(bad.size, rng), position_only, tol_m,
                                          tol_rad, mi, lsq)
        better = ok2 | ((pe2 + ae2) < (pe[bad] + ae[bad]))
        sel = bad[better]
        q[sel], pe[sel], ae[sel], it[sel], ok[sel] = q2[better], pe2[better], ae2[better], it2[better], ok2[better]
    pe, ae = _final_check(robot, T, q, position_only)
    am, ar = (tol_m, tol_rad) if lsq is None else (max(tol_m, lsq[0]), max(tol_rad, lsq[1]))
    success = (pe <= am) & (ae <= ar) & robot.within_limits(q, tol=0.0)
    return IKResult(q=q, success=success, pos_err_m=pe, ang_err_rad=ae, branch=np.full(N, -1),
                    label=np.full(N, "", dtype=object), iterations=it)


def ik_all_numeric(robot: Robot, T_world, n_seeds: int = 200, position_only: bool = False,
                   tol_m: float = 1e-10, tol_rad: float = 1e-10, max_iter: int = 50, dedup_tol: float = 1e-6,
                   rng: np.random.Generator | int | None = 0, max_solutions: int | None = None,
                   lsq=None) -> IKBranches:
    """Exhaustive numerical search: LM from ``n_seeds`` random seeds per target, successes kept,
    duplicates (modulo 2π on revolute joints, to ``dedup_tol`` rad) removed. Counts branches the way
    :func:`ik_closed_form` does. ``lsq`` ``(m, rad)``: success within these (least-squares solutions of
    an under-actuated arm, :func:`ik`; duplicates then to ``max(dedup_tol, 1e-5)``)."""
    T, _ = as_targets(T_world)
    N, n = len(T), robot.dof
    rng = np.random.default_rng(rng)
    q0 = robot.random_joints(N * n_seeds, rng)
    TT = np.repeat(T, n_seeds, axis=0)
    q, _, _, _, ok = _attempt(robot, TT, q0, position_only, tol_m, tol_rad, max_iter, lsq)
    if lsq is not None:  # least-squares minima: LM stops where the cost stops falling, ~1e-8 apart
        dedup_tol, tol_m, tol_rad = max(dedup_tol, 1e-5), max(tol_m, lsq[0]), max(tol_rad, lsq[1])
    ok = ok.reshape(N, n_seeds)
    q = q.reshape(N, n_seeds, n)
    rev = robot.revolute
    # canonical representation (nearest zero within limits) so duplicates compare equal
    qc = np.where(rev, wrap_to_limits(q, robot.lower, robot.upper), q)
    qc = np.where(robot.within_limits(qc.reshape(-1, n), tol=0.0).reshape(N, n_seeds)[..., None], qc, q)
    uniq = mark_duplicates(qc, ok, tol=dedup_tol, revolute=rev)
    counts = uniq.sum(1)
    K = int(max(counts.max(initial=0), 1)) if max_solutions is None else max_solutions
    order = np.argsort(~uniq, axis=1, kind="stable")[:, :K]
    idx = np.arange(N)[:, None]
    qs = qc[idx, order]
    succ = uniq[idx, order]
    qs = np.where(succ[..., None], qs, np.nan)
    pe_s, ae_s = _final_check(robot, np.repeat(T, K, 0), np.nan_to_num(qs.reshape(-1, n)), position_only)
    pe_s, ae_s = pe_s.reshape(N, K), ae_s.reshape(N, K)
    succ &= (pe_s <= tol_m) & (ae_s <= tol_rad)
    return IKBranches(q=qs, success=succ, pos_err_m=np.where(succ, pe_s, np.inf), ang_err_rad=np.where(succ, ae_s, np.inf),
                      branch=np.full((N, K), -1), label=np.full((N, K), "", dtype=object))


def ik_closed_form(robot: Robot, T_world, tol_m: float = 1e-9, tol_rad: float = 1e-9,
                   structure_tol: float = 1e-9, use_numba: bool = True) -> IKSolutions:
    """All closed-form IK solutions (up to 8) of world TCP targets ``T_world`` ``(N, 4, 4)``.

    Raises :class:`~hykin.kinematics.ik_closed_form.ClosedFormError` when the robot is not of the
    ``opw`` or ``ur`` family (see :func:`has_closed_form`). Solutions are wrapped into the joint
    limits (see :mod:`hykin.kinematics.ik_closed_form`); ``valid`` marks the ones within limits whose FK
    reproduces the target to ``tol_m`` / ``tol_rad``. Candidates near singularities that miss the
    tolerance by little get a few LM steps (:func:`solve_lm`). ``use_numba=False`` runs the
    vectorised numpy reference instead of the compiled kernel.
    """
    T, _ = as_targets(T_world)
    sols = closed_form_candidates(robot, T, tol_m, tol_rad, structure_tol, use_numba)
    _refine(robot, T, sols.q, sols.valid, sols.pos_err_m, sols.ang_err_rad, tol_m, tol_rad)
    return sols


def _refine(robot: Robot, T, q, valid, pe, ae, tol_m, tol_rad, near: float = 1e-5) -> None:
    """In place: candidates within ``near`` of the target but outside tolerance (roots of
    near-tangent subproblems at elbow/wrist/shoulder singularities lose about half the digits to
    ``acos``) get a few Gauss-Newton/LM steps within the limits, then duplicates are re-marked."""
    cand = np.isfinite(q).all(-1) & ~valid & (pe < near) & (ae < near)
    if not cand.any() or not np.isfinite(tol_m) or not np.isfinite(tol_rad):
        return
    rows, cols = np.nonzero(cand)
    qs, _, _, _ = solve_lm(robot, T[rows], q[rows, cols], tol_m=min(tol_m, 1e-12), tol_rad=min(tol_rad, 1e-12),
                           max_iter=10, bounded=True)
    pe_new, ae_new = pose_residual(fk(robot, qs), T[rows])
    q[rows, cols], pe[rows, cols], ae[rows, cols] = qs, pe_new, ae_new
    ok = (pe_new <= tol_m) & (ae_new <= tol_rad) & robot.within_limits(qs, tol=0.0)
    valid[rows[ok], cols[ok]] = True
    touched = np.unique(rows[ok])
    if touched.size:
        sub = valid[touched].copy()
        # re-mark duplicates: refined slots may coincide with each other or with earlier ones
        valid[touched] = mark_duplicates(q[touched], sub)


def _polish_branches(robot: Robot, T, sols: IKSolutions, position_only, tol_m, tol_rad, max_iter,
                     same_robot: bool) -> IKBranches:
    N, K, n = sols.q.shape
    q = sols.q.reshape(-1, n).copy()
    has = np.flatnonzero(sols.valid.reshape(-1))
    pe, ae = np.full(N * K, np.inf), np.full(N * K, np.inf)
    tgt = T[has // K]
    q[has] = solve_lm(robot, tgt, q[has], position_only, tol_m, tol_rad, max_iter)[0]
    pe[has], ae[has] = _final_check(robot, tgt, q[has], position_only)
    ok = (pe <= tol_m) & (ae <= tol_rad)
    ok[has] &= robot.within_limits(q[has], tol=0.0)
    q = q.reshape(N, K, n)
    ok = ok.reshape(N, K)
    if not same_robot:  # polishing on another geometry may merge branches
        ok = mark_duplicates(q, ok, revolute=robot.revolute)
    lab = np.array(sols.labels, dtype=object)
    return IKBranches(q=np.where(ok[..., None], q, np.nan), success=ok, pos_err_m=np.where(ok, pe.reshape(N, K), np.inf),
                      ang_err_rad=np.where(ok, ae.reshape(N, K), np.inf),
                      branch=np.broadcast_to(sols.branch, (N, K)).copy(),
                      label=np.broadcast_to(lab, (N, K)).copy())


def ik(robot: Robot, T_world, q_seed=None, all_branches: bool = False, position_only: bool = False,
       method: str = "auto", seed_robot: Robot | None = None, tol_m: float = 1e-10, tol_rad: float = 1e-10,
       max_iter: int = 50, restarts: int = 40, n_seeds: int = 64,
       rng: np.random.Generator | int | None = 0, polish: bool = True,
       least_squares: tuple[float, float] | None = None) -> IKResult | IKBranches:
    """Inverse kinematics of world TCP targets ``T_world`` ``(N, 4, 4)`` (or one ``(4, 4)``).

    method: ``"auto"`` (closed form + LM polish where :func:`has_closed_form` holds for ``robot`` or
    ``seed_robot``, else numerical), ``"closed_form"`` (error when none), ``"numeric"`` (LM only).
    q_seed: ``(N, dof)`` or ``(dof,)``: numerical seed, and the joints the returned branch is nearest
    to (default: zero clipped into limits). all_branches: return an :class:`IKBranches` with every
    distinct solution (modulo 2π, each nearest zero within the limits; ``hykin ik --all-branches`` adds
    the 2π copies: :func:`hykin.kinematics.ik_rows.expand_turn_copies`); otherwise an :class:`IKResult`. position_only: 3-D residual (orientation free;
    the closed form does not apply). Unreachable targets come back with ``success = False``.
    polish: with ``all_branches`` and a robot that has its own closed form, ``False`` returns its
    solutions as found (to 1e-9 m / rad) instead of polished by LM to ``tol_m`` / ``tol_rad``: for
    branch hints that are refined afterwards anyway (the polish is most of the time of a batch).
    least_squares ``(m, rad)``: for an under-actuated robot (fewer joints than the residual has
    components: < 6 for poses, < 3 for positions) a target off the arm's reachable poses has no exact
    solution; also accept where LM stops (the least-squares solution) within these bounds. For seeds
    and branch hints that a hybrid solve refines; ignored for other robots.
    """
    T, _ = as_targets(T_world)
    N, n = len(T), robot.dof
    if method not in ("auto", "closed_form", "numeric"):
        raise ValueError(f"method must be 'auto', 'closed_form' or 'numeric', got {method!r}")
    if q_seed is not None:
        q_seed = np.asarray(q_seed, dtype=np.float64)
        if q_seed.shape not in ((n,), (N, n)):
            raise ValueError(f"q_seed must have shape ({n},) or ({N}, {n}), got {q_seed.shape}")
    cf_robot = None
    if not position_only and method != "numeric":
        if has_closed_form(robot):
            cf_robot = robot
        elif seed_robot is not None and has_closed_form(seed_robot) and seed_robot.dof == n:
            cf_robot = seed_robot
    if method == "closed_form" and cf_robot is None:
        raise ValueError(f"robot {robot.name!r}: no closed-form IK (see hykin.kinematics.ik_closed_form.has_closed_form)")

    if cf_robot is not None:
        same = cf_robot is robot
        sols = ik_closed_form(cf_robot, T, tol_m=1e-9 if same else np.inf, tol_rad=1e-9 if same else np.inf)
        lab = np.array(sols.labels, dtype=object)
        if all_branches:
            if polish or not same:  # another robot's closed form only seeds: always polished on this one
                br = _polish_branches(robot, T, sols, position_only, tol_m, tol_rad, max_iter, same)
            else:
                v = sols.valid
                br = IKBranches(q=np.where(v[..., None], sols.q, np.nan), success=v.copy(),
                                pos_err_m=np.where(v, sols.pos_err_m, np.inf), ang_err_rad=np.where(v, sols.ang_err_rad, np.inf),
                                branch=np.broadcast_to(sols.branch, v.shape).copy(),
                                label=np.broadcast_to(lab, v.shape).copy())
            none = np.flatnonzero(br.n_solutions == 0)
            if none.size:  # exact singularities the closed form misses, or unreachable: ask LM once
                sub = ik_numeric(robot, T[none], None, position_only, tol_m, tol_rad, max_iter, restarts, rng)
                got = none[sub.success]
                br.q[got, 0], br.success[got, 0] = sub.q[sub.success], True
                br.pos_err_m[got, 0], br.ang_err_rad[got, 0] = sub.pos_err_m[sub.success], sub.ang_err_rad[sub.success]
                br.branch[got, 0], br.label[got, 0] = -1, ""
            return br
        ref = np.clip(np.zeros(n), robot.lower, robot.upper) if q_seed is None else q_seed
        raw = IKBranches(q=sols.q, success=sols.valid, pos_err_m=sols.pos_err_m, ang_err_rad=sols.ang_err_rad,
                         branch=np.broadcast_to(sols.branch, (N, 8)), label=np.broadcast_to(lab, (N, 8)))
        res = raw.nearest_to(ref, robot.lower, robot.upper)
        has = np.flatnonzero(res.success)
        q, _, _, it = solve_lm(robot, T[has], res.q[has], position_only, tol_m, tol_rad, max_iter)
        res.q[has], res.iterations[has] = q, it
        res.pos_err_m[has], res.ang_err_rad[has] = _final_check(robot, T[has], q, position_only)
        res.success[has] = (res.pos_err_m[has] <= tol_m) & (res.ang_err_rad[has] <= tol_rad) & robot.within_limits(
            q, tol=0.0)
        miss = ~res.success
        if miss.any():  # closed form found nothing valid: fall back to LM with restarts
            sub = ik_numeric(robot, T[miss], None if q_seed is None else np.broadcast_to(q_seed, (N, n))[miss],
                             position_only, tol_m, tol_rad, max_iter, restarts, rng)
            for f in ("q", "success", "pos_err_m", "ang_err_rad", "branch", "label", "iterations"):
                getattr(res, f)[miss] = getattr(sub, f)
        return res
    lsq = least_squares if least_squares is not None and n < (3 if position_only else 6) else None
    if all_branches:
        return ik_all_numeric(robot, T, n_seeds=n_seeds, position_only=position_only, tol_m=tol_m, tol_rad=tol_rad,
                              max_iter=max_iter, rng=rng, lsq=lsq)
    return ik_numeric(robot, T, q_seed, position_only, tol_m, tol_rad, max_iter, restarts, rng, lsq=lsq)
