"""Hybrid IK of one target, compiled: Levenberg–Marquardt on the hybrid pose of
:mod:`hykin.hybrid.fast_fk`, started from given joints (a warm start: the previous target's joints, or
a branch's seed), in a box (joint limits, or a box around the seed).

The rule is the one of :mod:`hykin.kinematics.lm` (``damping="scaled"``: ``(JᵀJ + λ s I) dq = Jᵀ e``
with ``s`` the mean diagonal of ``JᵀJ``; active-set projection onto the box; a step is accepted iff the
cost decreases, then ``λ ← max(λ/10, 1e-12)``, else ``λ ← 10 λ``; stop at convergence, ``λ > lam_max`` or
``max_iter`` Jacobians), compiled per target like the classical kernel of :mod:`hykin.kinematics.ik`
(same normal equations and projected solve, :func:`hykin.kinematics.ik.projected_solve`, and residual,
:func:`hykin.kinematics.ik.pose_residual_one`: position ``p_t − p`` (m) and ``log(R_t Rᵀ)`` (rad, times
``w_rot`` m)).

Jacobian: the "frozen correction" of :mod:`hykin.hybrid.ik`: the rigid geometric Jacobian of the
calibrated chain at the current joints (mapped through the registration frame), plus — with
``fd=True`` — the difference to the hybrid residual's central-difference Jacobian, measured at the start
and every 6th iteration. The classical part alone is within ~1e-3 of the hybrid one (the correction and
the compliance are small), so each step gains ~3 digits and 3–5 steps reach 1e-12 m from a warm start;
``fd=True`` is for starts far from the solution or near singularities. After each accepted step below
1e-4 rad the correction also gets Broyden's rank-one update (the secant of that step), so that a model
whose networks or compliance tilt the Jacobian more than ~1e-3 still converges superlinearly (measured
on a UR-like model with soft joints, 1,200 targets at limits and singularities from the true joints:
6,100 -> 8,000-9,400 targets/s; the smooth path's iterations unchanged).
"""

from __future__ import annotations

import numpy as np

from ..kinematics.chunks import run_chunked
from ..kinematics.fk import HAVE_NUMBA

__all__ = ["solve", "solve_packed_rows"]

_BROYDEN_MAX_STEP2 = 1e-8  # squared joint step (rad^2) up to which solve_one makes Broyden's update

if HAVE_NUMBA:
    import numba

    from ..kinematics.ik import lm_scratch, normal_equations_one, pose_residual_one, projected_solve
    from ..kinematics.walk import axes_one
    from .fast_fk import hybrid_one, unpack

    @numba.njit(cache=True, nogil=True)
    def _residual(P, q, Tt, pos_only, w_rot, T, ex, e):  # pragma: no cover - compiled
        """Hybrid pose of ``q`` into ``T`` and residual into ``e``; returns (|Δp| m, angle rad, cost)."""
        # framed_out = P[40] (the model's own ``framed``) is the same as True here, and a runtime bool: a
        # literal True would compile hybrid_one a second time (~3 s) beside fast_fk's batch kernel
        hybrid_one(P, q, T, ex, P[40])
        pe, ae = pose_residual_one(T, Tt, pos_only, e)
        m = 3 if pos_only else 6
        cost = 0.0
        for r in range(m):
            if r >= 3:
                e[r] *= w_rot
            cost += e[r] * e[r]
        return pe, ae, cost

    @numba.njit(cache=True, nogil=True)
    def _classical_jac(P, q, T, pos_only, w_rot, J, z, o, T3):  # pragma: no cover - compiled
        """Geometric Jacobian ``J`` (m, n) of the rigid calibrated chain at ``q``, about the hybrid TCP
        ``T[:3, 3]``, in the (registration) frame of ``T``."""
        fixed, prism = P[0], P[1]
        framed, pre = P[40], P[41]
        n = q.shape[0]
        axes_one(fixed, prism, q, z, o, T3)
        for i in range(n):
            zx, zy, zz = z[i, 0], z[i, 1], z[i, 2]
            ox, oy, oz = o[i, 0], o[i, 1], o[i, 2]
            if framed:
                zx, zy, zz = (pre[0, 0] * zx + pre[0, 1] * zy + pre[0, 2] * zz, pre[1, 0] * zx + pre[1, 1] * zy
                              + pre[1, 2] * zz, pre[2, 0] * zx + pre[2, 1] * zy + pre[2, 2] * zz)
                ox, oy, oz = (pre[0, 0] * ox + pre[0, 1] * oy + pre[0, 2] * oz + pre[0, 3], pre[1, 0] * ox
                              + pre[1, 1] * oy + pre[1, 2] * oz + pre[1, 3], pre[2, 0] * ox + pre[2, 1] * oy
                              + pre[2, 2] * oz + pre[2, 3])
            if prism[i]:
                J[0, i], J[1, i], J[2, i] = zx, zy, zz
                if not pos_only:
                    J[3, i] = J[4, i] = J[5, i] = 0.0
            else:
                dx, dy, dz = T[0, 3] - ox, T[1, 3] - oy, T[2, 3] - oz
                J[0, i] = zy * dz - zz * dy
                J[1, i] = zz * dx - zx * dz
                J[2, i] = zx * dy - zy * dx
                if not pos_only:
                    J[3, i], J[4, i], J[5, i] = w_rot * zx, w_rot * zy, w_rot * zz

    @numba.njit(cache=True, nogil=True)
    def _fd_correction(P, q, Tt, pos_only, w_rot, J, D, T, ex, z, o, T3):  # pragma: no cover - compiled
        """``D`` = central-difference Jacobian of the hybrid pose (−∂e/∂q) minus the classical ``J``."""
        n = q.shape[0]
        m = 3 if pos_only else 6
        h = 1e-6
        qh = q.copy()
        ep = np.empty(6)
        em = np.empty(6)
        Th = np.empty((4, 4))
        for i in range(n):
            qh[i] = q[i] + h
            _residual(P, qh, Tt, pos_only, w_rot, Th, ex, ep)
            qh[i] = q[i] - h
            _residual(P, qh, Tt, pos_only, w_rot, Th, ex, em)
            qh[i] = q[i]
            for r in range(m):
                D[r, i] = -(ep[r] - em[r]) / (2 * h) - J[r, i]

    @numba.njit(cache=True, nogil=True)
    def solve_one(P, Tt, q, lo, hi, pos_only, w_rot, tol_m, tol_rad, max_iter, lam0, lam_max, fd):  # pragma: no cover
        """LM from ``q`` (n,) (solved in place, clipped into ``[lo, hi]``) to the target ``Tt`` (4, 4).
        Returns ``(pos_err_m, ang_err_rad, jacobians)``."""
        n = q.shape[0]
        m = 3 if pos_only else 6
        T = np.empty((4, 4))
        Tn = np.empty((4, 4))
        ex = np.empty(n)
        e, en, J, A, g, dq, qn, L, rhs, frozen = lm_scratch(n)
        D = np.zeros((6, n))
        z = np.empty((n, 3))
        o = np.empty((n, 3))
        T3 = np.empty((3, 4))
        for i in range(n):
            q[i] = min(max(q[i], lo[i]), hi[i])
        pe, ae, cost = _residual(P, q, Tt, pos_only, w_rot, T, ex, e)
        lam = lam0
        it = 0
        while it < max_iter:
            if pe <= tol_m and ae <= tol_rad:
                break
            _classical_jac(P, q, T, pos_only, w_rot, J, z, o, T3)
            if fd and it % 6 == 0:
                _fd_correction(P, q, Tt, pos_only, w_rot, J, D, Tn, ex, z, o, T3)
                _classical_jac(P, q, T, pos_only, w_rot, J, z, o, T3)  # z, o were scratch
            for r in range(m):
                for i in range(n):
                    J[r, i] += D[r, i]
            it += 1
            scale = max(normal_equations_one(J, e, m, A, g) / n, 1e-12)
            accepted = False
            while not accepted:
                okc = projected_solve(A, g, lam * scale, q, lo, hi, frozen, dq, L, rhs)
                if not okc:
                    lam *= 10.0
                    if lam > lam_max:
                        break
                    continue
                for i in range(n):
                    qn[i] = min(max(q[i] + dq[i], lo[i]), hi[i])
                pen, aen, costn = _residual(P, qn, Tt, pos_only, w_rot, Tn, ex, en)
                if costn < cost:
                    accepted = True
                    # Broyden's update of the correction D after a small step s: afterwards (J + D_new) s =
                    # -(e_new - e), so the Jacobian learns what the rigid chain misses (the networks' and the
                    # compliance's slopes). After a large step the secant's own error (~|s| times the
                    # curvature) exceeds that mismatch, so it is skipped (measured: a 1e-3 rad first step
                    # updated this way cost the smooth path its 2-iteration convergence)
                    ss = 0.0
                    for i in range(n):
                        s_i = qn[i] - q[i]
                        dq[i] = s_i
                        ss += s_i * s_i
                    if 0.0 < ss <= _BROYDEN_MAX_STEP2:
                        for r in range(m):
                            js = 0.0
                            for i in range(n):
                                js += J[r, i] * dq[i]
                            u = (e[r] - en[r] - js) / ss
                            for i in range(n):
                                D[r, i] += u * dq[i]
                    for i in range(n):
                        q[i] = qn[i]
                    for r in range(4):
                        for c in range(4):
                            T[r, c] = Tn[r, c]
                    for r in range(6):
                        e[r] = en[r]
                    cost, pe, ae = costn, pen, aen
                    lam = max(lam * 0.1, 1e-12)
                else:
                    lam *= 10.0
                    if lam > lam_max:
                        break
            if not accepted:
                break
        return pe, ae, it

    @numba.njit(cache=True, nogil=True)
    def _solve_range(P, Tt, q, lo, hi, pos_only, w_rot, tol_m, tol_rad, max_iter, lam0, lam_max, fd, pe, ae, its,
                     k0, k1):  # pragma: no cover - compiled
        for k in range(k0, k1):
            pe[k], ae[k], its[k] = solve_one(P, Tt[k], q[k], lo[k], hi[k], pos_only, w_rot, tol_m, tol_rad, max_iter,
                                             lam0, lam_max, fd[k])

    @numba.njit(cache=True, nogil=True)
    def _solve_packed(F, G, B, Tt, q, lo, hi, pos_only, w_rot, tol_m, tol_rad, max_iter, lam0, lam_max, fd, pe, ae,
                      its, k0, k1):  # pragma: no cover - compiled
        _solve_range(unpack(F, G, B), Tt, q, lo, hi, pos_only, w_rot, tol_m, tol_rad, max_iter, lam0, lam_max, fd, pe,
                     ae, its, k0, k1)


_TOL, _MAX_ITER, _LAM0, _LAM_MAX = 1e-12, 40, 1e-9, 1e6  # solve's defaults (m and rad; iterations; damping)


def _writable(a, shape: tuple, dtype) -> np.ndarray:
    """``a`` when it is a writable C-contiguous array of ``shape`` and ``dtype``, else such a copy of its
    broadcast to ``shape``."""
    if type(a) is np.ndarray and a.shape == shape and a.dtype == dtype and a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(np.broadcast_to(np.asarray(a, dtype=dtype), shape), dtype=dtype, order="C")


def solve(kernel, T_target: np.ndarray, q0: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, position_only: bool = False,
          w_rot: float = 1.0, tol_m: float = _TOL, tol_rad: float = _TOL, max_iter: int = _MAX_ITER, lam0: float = _LAM0,
          lam_max: float = _LAM_MAX, fd=False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Hybrid IK of targets ``T_target`` ``(N, 4, 4)`` (the model's framed world, m) from ``q0`` ``(N, n)``
    in boxes ``lo``/``hi`` ``(N, n)``. ``fd``: bool or ``(N,)`` (module docstring).
    Returns ``(q (N, n), pos_err_m (N,), ang_err_rad (N,), iterations (N,))``."""
    N = len(q0)
    q = np.array(q0, dtype=np.float64, order="C", copy=True)
    Tt = np.ascontiguousarray(T_target, dtype=np.float64)
    # writable C arrays always (a read-only broadcast view would compile the kernel a second time); the
    # kernel only reads lo, hi and fd, so arrays already of that kind are passed as they are
    lo, hi = _writable(lo, q.shape, np.float64), _writable(hi, q.shape, np.float64)
    fdv = np.full(N, fd, dtype=np.bool_) if isinstance(fd, (bool, np.bool_)) else _writable(fd, (N,), np.bool_)
    pe, ae, its = np.empty(N), np.empty(N), np.empty(N, dtype=np.int64)
    args = (*kernel.args, Tt, q, lo, hi, bool(position_only), float(w_rot), float(tol_m), float(tol_rad), int(max_iter),
            float(lam0), float(lam_max), fdv, pe, ae, its)
    if N >= 128:  # threads over the one serial kernel (no parallel compile: numba's prange cost ~13 s)
        run_chunked(_solve_packed, args, N, min_chunk=64)
    else:
        _solve_packed(*args, 0, N)
    return q, pe, ae, its


def solve_packed_rows(kernel, T_target: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """:func:`solve` with its defaults (no finite differences) for a few rows, on arrays the caller made:
    ``T_target`` ``(N, 4, 4)``, ``q`` ``(N, n)`` (solved in place), ``lo``/``hi`` ``(N, n)``, all C-contiguous
    writable float64 (what :func:`solve` passes; no copies or checks here: the warm one-target path).
    Returns ``(pos_err_m (N,), ang_err_rad (N,))``."""
    N = len(q)
    pe, ae = np.empty(N), np.empty(N)
    _solve_packed(*kernel.args, T_target, q, lo, hi, False, 1.0, _TOL, _TOL, _MAX_ITER, _LAM0, _LAM_MAX, np.zeros(N, dtype=np.bool_),
                  pe, ae, np.empty(N, dtype=np.int64), 0, N)
    return pe, ae
