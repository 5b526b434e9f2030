"""Levenberg–Marquardt in hykin: the one damping rule (:func:`next_lambda`) and steps, and the one
batched, box-projected loop of the inverse kinematics (:func:`lm_solve`).

The calibration (:mod:`hykin.calibration.calibrate`) solves one problem in tens of parameters whose
Jacobian is accumulated in chunks over thousands of rows: its relinearising loop takes
:func:`normal_equations_step` on those normal equations and updates λ with :func:`next_lambda`.

Rows ``k`` are independent least-squares problems ``min_q |r_k(q)|²`` subject to
``lo_k <= q <= hi_k`` (joint limits, or a box around a seed). The caller gives the residual and its
Jacobian as callbacks over a batch of rows; :func:`lm_solve` runs every row at once (numpy float64,
no per-row Python loop). The rule, shared by every IK solver of the package:

* **step** (:func:`damped_step`): ``dq = -(JᵀJ + λ s I)⁻¹ Jᵀ r`` with ``s = 1`` (``damping="identity"``,
  classical IK) or ``s`` = the mean diagonal of ``JᵀJ`` (``damping="scaled"``, hybrid IK: λ then is
  relative, whatever the units of the residual). For ``m < n`` (position only, redundant arms) the
  same step is taken in its min-norm form ``-Jᵀ (J Jᵀ + λ s I)⁻¹ r`` (equal by the push-through identity).
* **projection** (:func:`projected_step`): active set — joints whose step would leave the box are
  moved onto the bound and frozen there, the free joints are re-solved with those moves fixed (up to
  ``n`` passes); the new point is clipped into the box.
* **acceptance**: a step is accepted iff the cost ``|r|²`` strictly decreases; then
  ``λ ← max(λ/10, 1e-12)``, otherwise ``λ ← 10 λ`` and the point is kept.
* **stop** per row: ``converged(r)``, ``λ > lam_max``, ``max_iter`` trials, ``max_rejects``
  consecutive rejected steps, or the caller's ``stop`` hook.

The compiled per-target kernel of :mod:`hykin.kinematics.ik` (``_lm_one``, numba) implements the
same rule with ``damping="identity"`` and ``lam_max = 1e10``; it retries a rejected step with the
larger λ at once (the Jacobian at the unchanged point is the same) and counts one iteration per
Jacobian, where this loop counts every trial — the iterates are the same, the iteration counts differ.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

__all__ = ["LAMBDA_MIN", "LMResult", "damped_step", "lm_solve", "next_lambda", "normal_equations_step", "projected_step"]

LAMBDA_MIN = 1e-12


def next_lambda(lam, accepted):
    """The damping after a trial step, the rule of every LM loop in hykin (IK here, the calibration
    in :mod:`hykin.calibration.calibrate`): accepted -> ``max(λ/10, 1e-12)``, rejected -> ``10 λ``.
    ``lam``, ``accepted``: scalars or arrays of one shape (elementwise)."""
    return np.where(accepted, np.maximum(np.asarray(lam, dtype=np.float64) / 10, LAMBDA_MIN), np.asarray(lam) * 10.0)


def normal_equations_step(A: np.ndarray, g: np.ndarray, lam: float) -> np.ndarray:
    """Marquardt step ``(n,)`` from normal equations ``A = JᵀJ`` ``(n, n)``, ``g = Jᵀr`` ``(n,)``:
    ``-(D⁻¹ A D⁻¹ + λ I)⁻¹ D⁻¹ g / D`` with ``D = sqrt(diag A)`` (Jacobi scaling: λ is relative for
    every parameter whatever its unit; zero diagonals count as 1). Least squares when the damped
    system is numerically singular. For problems whose Jacobian is accumulated in chunks (the
    calibration: thousands of rows, tens of parameters)."""
    import scipy.linalg

    D = np.sqrt(np.diag(A))
    D[D == 0] = 1.0
    M = A / np.outer(D, D) + lam * np.eye(len(g))
    try:
        return -scipy.linalg.solve(M, g / D, assume_a="pos", check_finite=False) / D
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        return -np.linalg.lstsq(M, g / D, rcond=None)[0] / D


def damped_step(J: np.ndarray, r: np.ndarray, lam: np.ndarray, damping: str = "identity",
                frozen: np.ndarray | None = None, dq_frozen: np.ndarray | None = None) -> np.ndarray:
    """Batched damped Gauss–Newton step ``(k, n)`` for Jacobians ``J`` ``(k, m, n)`` of residuals ``r`` ``(k, m)``.

    ``lam`` ``(k,)``: damping; ``damping``: ``"identity"`` (``λ I``) or ``"scaled"`` (``λ s I``, ``s`` the
    mean diagonal of ``JᵀJ`` over the free joints). ``frozen`` ``(k, n)`` bool: joints whose step is fixed
    to ``dq_frozen`` ``(k, n)``; the free joints minimise the linear model with those moves made.
    """
    k, m, n = J.shape
    if frozen is None:
        fz = np.zeros((k, n))
        rr = r
    else:
        fz = frozen.astype(np.float64)
        rr = r + np.einsum("kij,kj->ki", J, fz * dq_frozen)
    Jf = J * (1.0 - fz)[:, None, :]
    JfT = np.swapaxes(Jf, 1, 2)
    if m < n:  # min-norm form: the same step for the same λ s (push-through identity)
        A = Jf @ JfT
        s = _scale(A, n, damping)
        y = np.linalg.solve(A + (lam * s)[:, None, None] * np.eye(m), rr[..., None])
        dq = -(JfT @ y)[..., 0]
    else:
        A = JfT @ Jf
        s = _scale(A, n, damping)
        # frozen joints: zero columns plus a unit diagonal, so the system stays regular and their step 0
        A = A + (lam * s)[:, None, None] * np.eye(n) + fz[:, :, None] * np.eye(n)
        dq = -np.linalg.solve(A, (JfT @ rr[..., None]))[..., 0]
    if frozen is None:
        return dq
    return np.where(frozen, dq_frozen, dq)


def _scale(A: np.ndarray, n: int, damping: str) -> np.ndarray:
    """``s`` ``(k,)`` of the damping ``λ s I``: 1, or trace(JᵀJ) / n (= trace(J Jᵀ) / n)."""
    if damping == "identity":
        return np.ones(A.shape[0])
    if damping == "scaled":
        return np.maximum(np.trace(A, axis1=1, axis2=2) / n, 1e-12)
    raise ValueError(f"damping must be 'identity' or 'scaled', got {damping!r}")


def projected_step(J: np.ndarray, r: np.ndarray, lam: np.ndarray, q: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                   damping: str = "identity") -> np.ndarray:
    """:func:`damped_step` kept inside the box ``[lo, hi]`` ``(k, n)`` by an active set: joints whose step
    leaves the box go onto the bound and are frozen, the others are re-solved (up to ``n`` passes)."""
    n = q.shape[1]
    dq = damped_step(J, r, lam, damping)
    frozen = np.zeros(q.shape, dtype=bool)
    dqf = np.zeros(q.shape)
    for _ in range(n):
        over = ~frozen & (q + dq > hi)
        under = ~frozen & (q + dq < lo)
        new = over | under
        rows = np.flatnonzero(new.any(1))
        if rows.size == 0:
            break
        dqf[rows] = np.where(over[rows], hi[rows] - q[rows], np.where(under[rows], lo[rows] - q[rows], dqf[rows]))
        frozen[rows] |= new[rows]
        dq[rows] = damped_step(J[rows], r[rows], lam[rows], damping, frozen[rows], dqf[rows])
    return dq


@dataclass
class LMResult:
    """Final state of :func:`lm_solve`: ``q`` ``(k, n)``, residual ``r`` ``(k, m)``, the residual callback's
    per-row ``aux`` at ``q`` (tuple of arrays with leading dimension ``k``), ``iterations`` ``(k,)`` trials
    and ``lam`` ``(k,)`` final damping."""

    q: np.ndarray
    r: np.ndarray
    aux: tuple
    iterations: np.ndarray
    lam: np.ndarray


def lm_solve(
    residual: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, tuple]],
    jacobian: Callable[[np.ndarray, np.ndarray, tuple, int], np.ndarray],
    q0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    converged: Callable[[np.ndarray], np.ndarray],
    lam0: float,
    damping: str = "identity",
    lam_max: float = 1e10,
    max_iter: int = 50,
    max_rejects: int | None = None,
    stop: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray] | None = None,
) -> LMResult:
    """Projected LM (module docstring) on rows ``q0`` ``(k, n)`` in boxes ``lo``/``hi`` (``(n,)`` or ``(k, n)``).

    ``residual(q, idx)`` → ``(r (j, m), aux)`` for joints ``q`` ``(j, n)`` of rows ``idx`` ``(j,)``; ``aux`` a
    tuple of per-row arrays (e.g. poses, a Jacobian) handed back to ``jacobian(q, idx, aux, it)`` →
    ``J`` ``(j, m, n)`` = ∂r/∂q at ``q`` (``it``: the iteration). ``converged(r)`` → ``(j,)`` bool.
    ``stop(q, idx, accepted)`` → ``(j,)`` bool: an extra per-row stop after each trial.
    """
    k = q0.shape[0]
    lo = np.broadcast_to(np.asarray(lo, dtype=np.float64), q0.shape)
    hi = np.broadcast_to(np.asarray(hi, dtype=np.float64), q0.shape)
    q = np.clip(q0, lo, hi)
    r, aux = residual(q, np.arange(k))
    aux = tuple(np.array(a, copy=True) for a in aux)
    cost = np.einsum("ij,ij->i", r, r)
    lam = np.full(k, float(lam0))
    iters = np.zeros(k, dtype=int)
    rejects = np.zeros(k, dtype=int)
    active = ~np.asarray(converged(r), dtype=bool)
    for it in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        qa = q[idx]
        J = jacobian(qa, idx, tuple(a[idx] for a in aux), it)
        dq = projected_step(J, r[idx], lam[idx], qa, lo[idx], hi[idx], damping)
        q_new = np.clip(qa + dq, lo[idx], hi[idx])
        r_new, aux_new = residual(q_new, idx)
        c_new = np.einsum("ij,ij->i", r_new, r_new)
        better = c_new < cost[idx]
        ib = idx[better]
        q[ib], r[ib], cost[ib] = q_new[better], r_new[better], c_new[better]
        for a, b in zip(aux, aux_new):
            a[ib] = b[better]
        lam[idx] = next_lambda(lam[idx], better)
        iters[idx] += 1
        rejects[ib] = 0
        rejects[idx[~better]] += 1
        done = np.asarray(converged(r[idx]), dtype=bool) | (lam[idx] > lam_max)
        if max_rejects is not None:
            done |= rejects[idx] >= max_rejects
        if stop is not None:
            done |= np.asarray(stop(q[idx], idx, better), dtype=bool)
        active[idx[done]] = False
    return LMResult(q=q, r=r, aux=aux, iterations=iters, lam=lam)
