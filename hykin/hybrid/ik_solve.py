"""Hybrid IK solver: residual and Jacobians of the hybrid pose error (:class:`IKProblem`), the box
solve around each classical seed (projected LM of :mod:`hykin.kinematics.lm`), restarts, and
:func:`hybrid_ik_from_seeds`. Method: :mod:`hykin.hybrid.ik`."""

from __future__ import annotations

import warnings

import numpy as np

from ..geometry import se3
from ..kinematics.fk import jacobian
from ..kinematics.ik import nearest_representation
from ..kinematics.lm import lm_solve
from ..kinematics.robot import Robot
from .ik_result import (
    DEFAULT_DELTA_RAD,
    HybridIKError,
    HybridIKResult,
    check_model,
    model_accuracy,
    parse_targets,
    support_of,
    underactuated,
)
from .ik_result import torch_threads as torch_threads_ctx
from .ik_roots import duplicates, pick_new
from .ik_roots import more_roots as search_more_roots
from .self_motion import is_redundant, toward_hint

__all__ = ["IKProblem", "accept_least_squares", "box_lm", "controllable_error", "errors_of", "hybrid_ik_from_seeds", "run_polished", "run_rows"]

class IKProblem:
    """Residuals and Jacobians of rows (targets repeated per branch), numpy float64."""

    def __init__(self, model, robot: Robot, T: np.ndarray, pos_only: bool, w_rot: float):
        self.model, self.robot, self.T, self.pos_only, self.w = model, robot, T, pos_only, w_rot
        self.m = 3 if pos_only else 6

    def residual(self, q: np.ndarray, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``r`` ``(k, m)`` and hybrid poses ``(k, 4, 4)`` for joints ``q`` ``(k, dof)`` of ``rows``."""
        with warnings.catch_warnings():  # out-of-range warnings: reported per row as in_support instead
            warnings.simplefilter("ignore")
            P = np.asarray(self.model.predict(q), dtype=np.float64).reshape(-1, 4, 4)
        Tt = self.T[rows]
        r_p = P[:, :3, 3] - Tt[:, :3, 3]
        if self.pos_only:
            return r_p, P
        r_r = se3.rotation_difference_rotvec(P[:, :3, :3], Tt[:, :3, :3])
        return np.concatenate([r_p, self.w * r_r], 1), P

    def classical_jac(self, q: np.ndarray) -> np.ndarray:
        J = jacobian(self.robot, q)
        if self.pos_only:
            return J[:, :3]
        J = J.copy()
        J[:, 3:] *= self.w
        return J

    def exact_jac(self, q: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """Exact Jacobian ``(k, m, dof)`` of the residual by autograd of ``predict_torch``."""
        pt = getattr(self.model, "predict_torch", None)
        if pt is None:
            return self.fd_jac(q, rows)
        import torch
        qt = torch.tensor(q, dtype=torch.float64, requires_grad=True)
        Tt = torch.as_tensor(self.T[rows], dtype=torch.float64)
        P = pt(qt).to(torch.float64)
        r_p = P[:, :3, 3] - Tt[:, :3, 3]
        if self.pos_only:
            r = r_p
        else:
            r_r = se3.so3_log_torch(P[:, :3, :3] @ Tt[:, :3, :3].transpose(1, 2))
            r = torch.cat([r_p, self.w * r_r], 1)
        # Rows are independent (eval-mode model), so d(sum_rows r_k)/dq gives row-wise gradients.
        cols = []
        for k in range(self.m):
            (g,) = torch.autograd.grad(r[:, k].sum(), qt, retain_graph=k < self.m - 1)
            cols.append(g)
        return torch.stack(cols, 1).detach().numpy()

    def fd_jac(self, q: np.ndarray, rows: np.ndarray, h: float = 1e-6) -> np.ndarray:
        """Jacobian ``(k, m, dof)`` of the residual by central differences of ``model.predict`` (step ``h``)."""
        n = q.shape[1]
        J = np.empty((q.shape[0], self.m, n))
        for j in range(n):
            e = np.zeros(n)
            e[j] = h
            rp, _ = self.residual(q + e, rows)
            rm, _ = self.residual(q - e, rows)
            J[:, :, j] = (rp - rm) / (2 * h)
        return J


def box_lm(prob: IKProblem, q0: np.ndarray, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray, *,
           tol_m: float, tol_rad: float, max_iter: int, jac_mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Projected LM (:func:`hykin.kinematics.lm.lm_solve`, scaled damping from λ = 1e-9) on all rows at
    once in the boxes ``lo``/``hi`` ``(k, n)``. Returns ``q``, residual ``r``, hybrid poses, iterations.

    Jacobian: classical Jacobian plus a correction measured at the seed ("frozen", "frozen-fd") and
    re-measured every 6th iteration (slow rows near singularities), or autograd every iteration
    ("exact"). Extra stops: 12 rejected steps in a row, 3 iterations pinned on a box face (the caller
    widens the box) or 5 on a joint limit (the solution lies beyond it)."""
    k = q0.shape[0]
    D = None
    if jac_mode in ("frozen", "frozen-fd"):
        qc = np.clip(q0, lo, hi)
        J0 = prob.exact_jac(qc, rows) if jac_mode == "frozen" else prob.fd_jac(qc, rows, h=1e-5)
        D = J0 - prob.classical_jac(qc)

    def jac(qa, idx, aux, it):
        if D is None:
            return prob.exact_jac(qa, rows[idx])
        if it % 6 == 5:
            J1 = prob.exact_jac(qa, rows[idx]) if jac_mode == "frozen" else prob.fd_jac(qa, rows[idx], h=1e-5)
            D[idx] = J1 - prob.classical_jac(qa)
        return prob.classical_jac(qa) + D[idx]

    def converged(rr):
        pe, ae = errors_of(prob, rr)
        return (pe <= tol_m) & (ae <= tol_rad)

    pinned = np.zeros(k, dtype=int)
    pinned_lim = np.zeros(k, dtype=int)
    lo_j, hi_j = prob.robot.lower[None], prob.robot.upper[None]

    def pinned_stop(qi, idx, accepted):
        eps = 1e-9
        loi, hii = lo[idx], hi[idx]
        at_lo, at_hi = qi <= loi + eps, qi >= hii - eps
        box = ((at_lo & (loi > lo_j + eps)) | (at_hi & (hii < hi_j - eps))).any(1)
        lim = ((at_lo & (loi <= lo_j + eps)) | (at_hi & (hii >= hi_j - eps))).any(1)
        pinned[idx] = np.where(box, pinned[idx] + 1, 0)
        pinned_lim[idx] = np.where(lim, pinned_lim[idx] + 1, 0)
        return (pinned[idx] >= 3) | (pinned_lim[idx] >= 5)

    def residual(q, idx):
        r, P = prob.residual(q, rows[idx])
        return r, (P,)

    res = lm_solve(residual, jac, q0, lo, hi,
                   converged=converged, lam0=1e-9, damping="scaled", lam_max=1e6, max_iter=max_iter,
                   max_rejects=12, stop=pinned_stop)
    return res.q, res.r, res.aux[0], res.iterations


def controllable_error(prob: IKProblem, q: np.ndarray, rows: np.ndarray, r: np.ndarray,
                       max_step_rad: float = np.inf) -> tuple[np.ndarray, np.ndarray]:
    """``(m, rad)`` ``(k,)``: the part of the residual ``r`` ``(k, m)`` at ``q`` that the joints can still
    reduce: its projection onto the hybrid Jacobian's (central differences) left singular vectors, of those
    whose component a joint step of at most ``max_step_rad`` removes (a full arm at its reach boundary,
    the stretched elbow, has one the joints cannot: it would take tens of radians). Zero at a least-squares
    solution; what is left (``r`` minus it) the arm cannot control."""
    U, S, _ = np.linalg.svd(prob.fd_jac(q, rows), full_matrices=False)
    c = np.einsum("kji,kj->ki", U, r)
    with np.errstate(invalid="ignore"):  # inf · 0: a direction the joints do not move at all
        keep = np.abs(c) <= max_step_rad * S
    return errors_of(prob, np.einsum("kij,kj->ki", U, np.where(keep, c, 0.0)))


def stationary(prob: IKProblem, q: np.ndarray, rows: np.ndarray, success_m: float, success_rad: float,
               max_step_rad: float = np.inf) -> np.ndarray:
    """``(k,)`` bool: ``q`` is a least-squares solution of its row (:func:`controllable_error` within
    ``success_m`` / ``success_rad``): the joints cannot reduce the error any further (by a step of at most
    ``max_step_rad``)."""
    if not len(q):
        return np.zeros(0, dtype=bool)
    r, _ = prob.residual(q, rows)
    cp, ca = controllable_error(prob, q, rows, r, max_step_rad)
    return (cp <= success_m) & (ca <= success_rad)


def lsq_ok(prob: IKProblem, q, rows, r, ok, lim, success_m, success_rad, lsq) -> np.ndarray:
    """``ok`` plus the rows of an under-actuated arm (``lsq`` ``(m, rad)`` set, else ``ok`` itself) at a
    least-squares solution (:func:`controllable_error` within ``success_m`` / ``success_rad``, not on a
    joint limit) whose residual is within ``lsq``: the model's accuracy (:func:`hykin.hybrid.ik_result.model_accuracy`)."""
    if lsq is None:
        return ok

    def at_least_squares(cand):
        cp, ca = controllable_error(prob, q[cand], rows[cand], r[cand])
        return (cp <= success_m) & (ca <= success_rad)

    return accept_least_squares(ok, lim, *errors_of(prob, r), lsq, at_least_squares)


def accept_least_squares(ok, lim, pe_m, ae_rad, lsq, at_least_squares) -> np.ndarray:
    """``ok`` ``(n,)`` plus the rows not on a joint limit (``lim``) whose errors ``pe_m`` / ``ae_rad`` are
    within the model's accuracy ``lsq`` ``(m, rad)`` and that ``at_least_squares(rows)`` (``(k,)`` bool)
    finds at a least-squares solution. The one acceptance rule of under-actuated arms, for
    :func:`lsq_ok` and the compensator (which has the errors but not the residuals)."""
    cand = np.flatnonzero(~ok & ~lim & (pe_m <= lsq[0]) & (ae_rad <= lsq[1]))
    if not cand.size:
        return ok
    ok = ok.copy()
    ok[cand] = at_least_squares(cand)
    return ok


def run_rows(prob: IKProblem, q0: np.ndarray, rows: np.ndarray, delta: float, widen: float, *,
              tol_m: float, tol_rad: float, success_m: float, success_rad: float, max_iter: int,
              jac_mode: str, lsq=None):
    """Box solve (:func:`box_lm`) of ``rows`` from ``q0`` in ``q0 ± delta``, rows pinned on the box
    re-solved once in a box ``widen`` times larger. ``lsq`` ``(m, rad)``: an under-actuated arm's
    least-squares acceptance (:func:`lsq_ok`). Returns ``(q, pe_m, ae_rad, ok, on_box, at_limit, iterations)``."""
    robot = prob.robot
    lo_j, hi_j = robot.lower[None], robot.upper[None]
    lo = np.maximum(q0 - delta, lo_j)
    hi = np.minimum(q0 + delta, hi_j)
    q, r, P, it = box_lm(prob, q0, rows, lo, hi, tol_m=tol_m, tol_rad=tol_rad, max_iter=max_iter, jac_mode=jac_mode)
    pe, ae = errors_of(prob, r)
    ok = (pe <= success_m) & (ae <= success_rad)
    eps = 1e-9
    at_box = ((q <= lo + eps) & (lo > lo_j + eps)) | ((q >= hi - eps) & (hi < hi_j - eps))
    retry = ~ok & at_box.any(1)
    if widen > 1 and retry.any():
        i = np.flatnonzero(retry)
        lo2 = np.maximum(q0[i] - widen * delta, lo_j)
        hi2 = np.minimum(q0[i] + widen * delta, hi_j)
        q2, r2, P2, it2 = box_lm(prob, q[i], rows[i], lo2, hi2, tol_m=tol_m, tol_rad=tol_rad, max_iter=max_iter,
                              jac_mode=jac_mode)
        q[i], r[i], P[i], it[i] = q2, r2, P2, it[i] + it2
        lo[i], hi[i] = lo2, hi2
        pe, ae = errors_of(prob, r)
        ok = (pe <= success_m) & (ae <= success_rad)
        at_box = ((q <= lo + eps) & (lo > lo_j + eps)) | ((q >= hi - eps) & (hi < hi_j - eps))
    at_lim = ((q <= lo_j + eps) | (q >= hi_j - eps)).any(1)
    ok = lsq_ok(prob, q, rows, r, ok, at_lim | at_box.any(1), success_m, success_rad, lsq)
    return q, pe, ae, ok, at_box.any(1), at_lim, it


def run_polished(prob: IKProblem, q0: np.ndarray, rows: np.ndarray, delta: float, widen: float, *,
                  polish_iter: int = 15, **kw):
    """:func:`run_rows`, then rows that stalled close to the target (under 1 mm, not on the box or a
    limit: the frozen correction of the Jacobian is too coarse where the networks bend strongly, e.g.
    near singularities) get up to ``polish_iter`` more iterations with the Jacobian re-taken every
    iteration (``"exact"``), in a box around where they stalled."""
    out = run_rows(prob, q0, rows, delta, widen, **kw)
    q, pe, ae, ok, box, lim, it = out
    stalled = np.flatnonzero(~ok & ~box & ~lim & (pe < 1e-3))
    if stalled.size and kw.get("jac_mode") != "exact":
        kw2 = dict(kw, jac_mode="exact", max_iter=polish_iter)
        q2, p2, a2, o2, b2, l2, i2 = run_rows(prob, q[stalled], rows[stalled], delta, widen, **kw2)
        better = o2 | (p2 < pe[stalled])
        sel, src = stalled[better], np.flatnonzero(better)
        q[sel], pe[sel], ae[sel], ok[sel], box[sel], lim[sel] = q2[src], p2[src], a2[src], o2[src], b2[src], l2[src]
        it[stalled] += i2
    return q, pe, ae, ok, box, lim, it


def _nearest_on_self_motion(prob: IKProblem, q, pe, ae, hint, rows, tgt, kw: dict, success_mm, success_deg) -> None:
    """:func:`hykin.hybrid.self_motion.toward_hint` on the solved ``rows`` (flat seed rows of target
    ``tgt[rows]``; ``q``, ``pe``/``ae`` m/rad updated in place) with :func:`run_rows` within the joint limits."""
    robot = prob.robot
    span = float(np.max(robot.upper - robot.lower))  # a box as wide as the limits: the limits bound it
    s_m, s_rad = success_mm * 1e-3, np.radians(success_deg)

    def solve_rows(idx, q0):
        q2, p2, a2, _, _, _, _ = run_rows(prob, q0, tgt[idx], span, 1.0, success_m=s_m, success_rad=s_rad, **kw)
        return q2, p2, a2

    # prob.robot holds the model's frames (predicting_robot): its TCP is the measured point
    toward_hint(solve_rows, lambda p, a: (p <= s_m) & (a <= s_rad), robot, np.eye(4), q, pe, ae, hint, robot.lower,
                robot.upper, rows, prob.pos_only)


def errors_of(prob: IKProblem, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pe = np.linalg.norm(r[:, :3], axis=1)
    ae = np.zeros_like(pe) if prob.pos_only else np.linalg.norm(r[:, 3:], axis=1) / prob.w
    return pe, ae


# nearest=True keeps the solution nearest the current joints. Only among near-ties (joint distance within
# _NEAR_TIE_RAD of the nearest) does it prefer one whose network correction applies at least _USABLE_FADE
# (fade weight): 5 deg of joint motion is no branch change, and there the networks' solution is the better
# answer. A support rule ahead of distance sent probe X's arm 183 deg (a wrist flip) from its seed when
# the solution 2.9 deg away lay just outside a restricted training range; in_support says which it is.
_USABLE_FADE = 0.5
_NEAR_TIE_RAD = np.radians(5.0)


def hybrid_ik_from_seeds(
    model,
    T_target,
    q0,
    *,
    branch=None,
    delta_rad: float = DEFAULT_DELTA_RAD,
    widen: float = 5.0,
    position_only: bool = False,
    orientation_weight_m: float = 1.0,
    tol_m: float = 1e-12,
    tol_rad: float = 1e-12,
    success_mm: float = 1e-4,
    success_deg: float = 1e-4,
    max_iter: int = 60,
    jacobian_mode: str = "frozen-fd",
    dedupe_rad: float = 1e-6,
    keep_failed: bool = False,
    q_current=None,
    nearest: bool = False,
    torch_threads: int | None = 1,
    restarts: int = 16,
    more_roots: bool = True,
    sing_rel: float = 0.02,
    underactuated_mm: float | None = None,
    underactuated_deg: float | None = None,
) -> HybridIKResult:
    """Hybrid refinement of given classical solutions ``q0`` ``(N, dof)`` or ``(N, B, dof)``.

    Each finite seed is refined in ``q0 ± delta_rad`` (see the module docstring); ``branch`` ``(N, B)``
    labels the seeds; seeds must be finite and at most ``delta_rad`` outside the joint limits.
    Rows per target: its distinct successful solutions; a target with none gets one failed row (its
    best attempt and the reason; NaN joints when no seed existed). ``keep_failed=True`` keeps every
    failed branch as well. ``nearest=True`` with ``q_current`` ``(N, dof)`` keeps one solution per
    target: the nearest in joint space (Euclidean); among solutions within 5° (``_NEAR_TIE_RAD``) of that
    distance, one inside the training support (or where the network correction still applies at least
    half: fade weight >= 0.5) is preferred. ``in_support`` tells whether the kept one is inside.

    Under-actuated arms (fewer than 6 joints, full poses; :func:`hykin.hybrid.ik_result.underactuated`)
    cannot match all six components of an arbitrary (e.g. measured) pose: the answer is the
    least-squares solution. A row succeeds there when the joints can reduce the error no further (its
    controllable part, :func:`controllable_error`, within ``success_mm`` / ``success_deg``) and the
    error left is within ``underactuated_mm`` / ``underactuated_deg`` (default: the model's own
    accuracy, :func:`hykin.hybrid.ik_result.model_accuracy`: its held-out maximum error; without
    metrics, ``success_mm`` / ``success_deg``: exact poses only). The residual is reported as for
    any row.
    """
    robot = check_model(model)
    T, pos_only_in = parse_targets(T_target)
    pos_only = bool(position_only or pos_only_in)
    N, n = T.shape[0], robot.dof
    q0 = np.asarray(q0, dtype=np.float64)
    if q0.ndim == 2:
        q0 = q0[:, None]
    if q0.ndim != 3 or q0.shape[0] != N or q0.shape[2] != n:
        raise HybridIKError(f"hybrid IK: seeds must have shape ({N}, B, {n}) or ({N}, {n}), got {q0.shape}")
    B = q0.shape[1]
    rev = robot.revolute
    qc = None
    if nearest:
        if q_current is None:
            raise HybridIKError("hybrid IK: nearest=True needs q_current")
        qc = np.asarray(q_current, dtype=np.float64).reshape(-1, n)
        qc = np.broadcast_to(qc, (N, n)) if qc.shape[0] == 1 else qc
        if qc.shape[0] != N:
            raise HybridIKError(f"hybrid IK: q_current must have shape ({N}, {n}) or ({n},), got {qc.shape}")
        # the hybrid model is not 2π-periodic: solve in the representation nearest the current joints
        q0 = np.where(rev, nearest_representation(q0, qc[:, None], robot.lower, robot.upper), q0)
    labels = np.full((N, B), "seed", dtype=object) if branch is None else np.asarray(branch, dtype=object).reshape(N, B)
    finite = np.all(np.isfinite(q0), axis=2)
    # a seed up to delta outside the limits is still a start (the hybrid solution may lie inside)
    inlim = np.all((q0 >= robot.lower - delta_rad) & (q0 <= robot.upper + delta_rad), axis=2) & finite
    usable = finite & inlim
    if delta_rad <= 0:
        raise HybridIKError(f"hybrid IK: delta_rad must be > 0, got {delta_rad}")
    if jacobian_mode not in ("frozen-fd", "frozen", "exact"):
        raise HybridIKError(f"hybrid IK: jacobian_mode must be 'frozen-fd', 'frozen' or 'exact', got {jacobian_mode!r}")

    lsq = None
    if underactuated(robot, pos_only):
        acc_mm, acc_deg = model_accuracy(model)
        acc_mm = acc_mm if underactuated_mm is None else underactuated_mm
        acc_deg = acc_deg if underactuated_deg is None else underactuated_deg
        lsq = (max(success_mm, acc_mm or 0.0) * 1e-3, np.radians(max(success_deg, acc_deg or 0.0)))
    tgt = np.repeat(np.arange(N), B)
    flat_q0 = q0.reshape(N * B, n)
    use = usable.reshape(-1)
    M = N * B
    q = np.full((M, n), np.nan)
    pe = np.full(M, np.nan)
    ae = np.full(M, np.nan)
    ok = np.zeros(M, dtype=bool)
    it = np.zeros(M, dtype=int)
    reason = np.full(M, "", dtype=object)
    reason[~finite.reshape(-1)] = "no classical solution (unreachable for this branch)"
    reason[finite.reshape(-1) & ~inlim.reshape(-1)] = "classical solution outside joint limits"
    ui = np.flatnonzero(use)
    if ui.size:
        prob = IKProblem(model, robot, T, pos_only, float(orientation_weight_m))
        rows = tgt[ui]
        with torch_threads_ctx(torch_threads):
            qq, p_, a_, o_, box, lim, itr = run_polished(
                prob, np.clip(flat_q0[ui], robot.lower, robot.upper), rows, float(delta_rad), float(widen),
                tol_m=tol_m, tol_rad=tol_rad, success_m=success_mm * 1e-3, success_rad=np.radians(success_deg),
                max_iter=max_iter, jac_mode=jacobian_mode, lsq=lsq,
            )
            # Rows that stalled close to the target (a local minimum of the flat cost near a
            # singularity): multi-start inside the widened box. A target with no solution yet keeps the
            # best restart; one with solutions only a restart that is a new, distinct solution.
            solved_t = np.zeros(N, dtype=bool)
            solved_t[rows[o_]] = True
            retry = ~o_ & ~box & ~lim & (p_ < 1e-3)
            if lsq is not None and retry.any():  # an under-actuated arm's least-squares solution: no other nearby
                ri = np.flatnonzero(retry)
                retry[ri[stationary(prob, qq[ri], rows[ri], success_mm * 1e-3, np.radians(success_deg))]] = False
            if restarts > 0 and retry.any():
                ri = np.flatnonzero(retry)
                rng = np.random.default_rng(0)
                rep = np.repeat(ri, restarts)
                span = 0.5 * widen * delta_rad
                qs = np.clip(qq[rep] + rng.uniform(-span, span, (rep.size, n)), robot.lower, robot.upper)
                q2, p2, a2, o2, b2, l2, i2 = run_rows(
                    prob, qs, rows[rep], float(delta_rad), float(widen), tol_m=tol_m, tol_rad=tol_rad,
                    success_m=success_mm * 1e-3, success_rad=np.radians(success_deg), max_iter=max_iter,
                    jac_mode=jacobian_mode, lsq=lsq,
                )
                score = np.where(o2, 0.0, p2 + np.where(np.isfinite(a2), a2, 0.0)).reshape(ri.size, restarts)
                best = np.argmin(score, axis=1)
                pick = np.arange(ri.size) * restarts + best
                better = (o2[pick] | (p2[pick] < p_[ri])) & ~solved_t[rows[ri]]
                for k in np.flatnonzero(solved_t[rows[ri]]):  # few rows: plain loop
                    sl = slice(k * restarts, (k + 1) * restarts)
                    have = [qq[i] for i in np.flatnonzero(o_ & (rows == rows[ri[k]]))]
                    j = pick_new(q2[sl], o2[sl], have, rev, dedupe_rad)
                    if j >= 0:
                        pick[k], better[k] = k * restarts + j, True
                sel, src = ri[better], pick[better]
                qq[sel], p_[sel], a_[sel], o_[sel], box[sel], lim[sel] = q2[src], p2[src], a2[src], o2[src], b2[src], l2[src]
                itr[ri] += i2.reshape(ri.size, restarts).sum(1)
            # Still unsolved: the other 2π representations of joints with a range over 2π. The hybrid
            # model is not 2π-periodic, so q ± 2π is another configuration (e.g. at a stretched elbow a
            # target can be reachable in one representation only).
            solved_t[:] = False
            solved_t[rows[o_]] = True
            alt_rows = np.flatnonzero(~o_ & ~solved_t[rows])
            wide = np.flatnonzero(rev & (robot.upper - robot.lower > 2 * np.pi))
            if alt_rows.size and wide.size:  # (no joint with a range over 2π: no other representation)
                shifts = np.array(np.meshgrid(*([[-1.0, 0.0, 1.0]] * wide.size))).reshape(wide.size, -1).T * 2 * np.pi
                shifts = shifts[np.any(shifts != 0, axis=1)]
                if shifts.size:
                    rep = np.repeat(alt_rows, len(shifts))
                    qs = flat_q0[ui][rep].copy()
                    qs[:, wide] += np.tile(shifts, (alt_rows.size, 1))
                    inl = np.all((qs >= robot.lower - delta_rad) & (qs <= robot.upper + delta_rad), axis=1)
                    rep, qs = rep[inl], qs[inl]
                    if rep.size:
                        q2, p2, a2, o2, b2, l2, i2 = run_rows(
                            prob, np.clip(qs, robot.lower, robot.upper), rows[rep], float(delta_rad), float(widen),
                            tol_m=tol_m, tol_rad=tol_rad, success_m=success_mm * 1e-3,
                            success_rad=np.radians(success_deg), max_iter=max_iter, jac_mode=jacobian_mode, lsq=lsq,
                        )
                        for k in np.flatnonzero(o2):  # few rows: plain loop is fine here
                            r0 = rep[k]
                            if not o_[r0]:
                                qq[r0], p_[r0], a_[r0], o_[r0], box[r0], lim[r0] = q2[k], p2[k], a2[k], True, False, False
                        np.add.at(itr, rep, i2)
            if more_roots and not pos_only and prob.m >= n:
                st = [qq, p_, a_, o_, box, lim, itr]
                run = lambda q0_, rows_: run_polished(
                    prob, q0_, rows_, float(delta_rad), float(widen), tol_m=tol_m, tol_rad=tol_rad,
                    success_m=success_mm * 1e-3, success_rad=np.radians(success_deg), max_iter=max_iter,
                    jac_mode=jacobian_mode, lsq=lsq)
                search_more_roots(prob, flat_q0[ui], labels.reshape(-1)[ui], st, rows, ui % B, N, B, rev, dedupe_rad,
                            sing_rel, run)
        q[ui], pe[ui], ae[ui], ok[ui], it[ui] = qq, p_, a_, o_, itr
        rs = np.where(
            box, f"needs more than ±{np.degrees(widen * delta_rad):.3g}° from the classical solution",
            np.where(lim, "blocked by a joint limit", "did not converge (target unreachable for the hybrid model?)"),
        )
        if lsq is not None:  # at a least-squares solution that misses by more than the model's accuracy
            f = np.flatnonzero(~o_ & ~box & ~lim)
            if f.size:
                stat = stationary(prob, qq[f], rows[f], success_mm * 1e-3, np.radians(success_deg))
                rs = rs.astype(object)
                rs[f[stat]] = (f"the arm ({n} joints) cannot match this pose: its least-squares solution misses by more "
                               f"than the model's accuracy ({lsq[0] * 1e3:.3g} mm / {np.degrees(lsq[1]):.3g} deg)")
        msg = np.array([f"{s}: residual {a * 1e3:.3g} mm / {np.degrees(b):.3g} deg" for s, a, b in zip(rs, p_, a_)],
                       dtype=object)
        reason[ui] = np.where(o_, "", msg)
    dist, ins = support_of(model, q)

    # de-duplicate: drop a success that equals a better success of the same target (modulo 2π)
    okm = ok.reshape(N, B)
    qm = q.reshape(N, B, n)
    dup, _ = duplicates(qm, okm, pe.reshape(N, B), rev, dedupe_rad)
    keep = okm & ~dup
    has = okm.any(1)
    if keep_failed:
        keep |= ~okm
    else:
        # a target with no success keeps its best attempt (lowest position error, seeds first)
        score = np.where(np.isfinite(pe.reshape(N, B)), pe.reshape(N, B), np.inf)
        best = np.argmin(score, axis=1)
        none = np.flatnonzero(~has)
        keep[none, best[none]] = True
    if nearest:
        dj = np.linalg.norm(qm - qc[:, None], axis=2)
        ins_m = ins.reshape(N, B)
        fw = getattr(model, "fade_weight", None)
        if fw is not None:  # just outside the sampled joints the correction still applies: no branch change
            ins_m = ins_m | (np.asarray(fw(np.nan_to_num(q)), dtype=np.float64).reshape(N, B) >= _USABLE_FADE)
        dj = np.where(okm & ~dup, dj, np.inf)
        tie = dj <= dj.min(1, keepdims=True) + _NEAR_TIE_RAD  # nearest first; the support breaks near-ties only
        score = np.where(tie, dj + np.where(ins_m, 0.0, 1e6), np.inf)
        pick = np.argmin(score, axis=1)
        sel = np.zeros((N, B), dtype=bool)
        sel[np.arange(N), pick] = True
        keep = np.where(has[:, None], sel, keep)
        if ui.size and is_redundant(n, pos_only):  # the kept solution: the one nearest q_current on its self-motion
            _nearest_on_self_motion(prob, q, pe, ae, np.repeat(qc, B, axis=0), np.flatnonzero(sel.reshape(-1) & ok),
                                    tgt, dict(tol_m=tol_m, tol_rad=tol_rad, max_iter=max_iter, jac_mode=jacobian_mode),
                                    success_mm, success_deg)
            dist, ins = support_of(model, q)
    keep_flat = keep.reshape(-1)
    res = HybridIKResult(
        target=tgt, branch=labels.reshape(-1).astype(str), q=q, success=ok, pos_err_mm=pe * 1e3,
        ang_err_deg=np.degrees(ae), reason=reason.astype(str), in_support=ins, support_distance=dist,
        iterations=it, n_targets=N, position_only=pos_only,
        info={"delta_rad": float(delta_rad), "method": "hybrid-lm", "jacobian": jacobian_mode},
    )
    return res.select(keep_flat)

