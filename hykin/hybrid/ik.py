"""Hybrid inverse kinematics (DESIGN.md §1.3): joints that reach a target with the *hybrid* model.

Method (Ojer et al. 2024, §1.3), batched over every target × branch:

1. Classical IK on the model's calibrated classical robot (:func:`classical_robot`): closed form for all
   branches where the robot has one (:func:`hykin.ik.ik`), numerical otherwise. Each branch gives a
   seed ``q0``.
2. Bounded non-linear least squares in the box ``q0 ± δ`` (clipped to the joint limits): minimise
   the Cartesian error between the target and the hybrid pose ``T*(q)`` — position (m) and
   orientation (rotation vector ``log(R* R_targetᵀ)``, rad, weighted by ``orientation_weight_m``), or
   position only. Solver: vectorised projected Levenberg–Marquardt in float64 over all rows at once
   (no per-target Python loop). Jacobian: the classical geometric Jacobian of the calibrated robot at the
   current joints plus the correction to it (networks, compliance), measured once at the seed and
   kept — a quasi-Newton "frozen correction": the correction is ~1e-3 of the classical Jacobian and
   barely changes inside the box, so each iteration gains ~3 digits and 3–5 iterations reach
   ~1e-12 m. The correction is taken by central differences of ``model.predict`` (``jacobian_mode=
   "frozen-fd"``, default: 12 batched hybrid FK calls, the fastest), by autograd of
   ``model.predict_torch`` (``"frozen"``), or re-taken by autograd every iteration (``"exact"``).
3. Default box ``δ = 3°`` (``delta_rad``): the hybrid correction of a real arm is ~1–3 mm / 0.2°, which
   moves the joints by ~0.1–0.5°; near the wrist singularity joints 4 and 6 may need more, so a row
   that ends on the box boundary above tolerance is re-solved once in a box ``widen`` times larger,
   and otherwise reported as failed.

4. Near singularities the hybrid correction can move a solution far from its classical seed, or
   move a fold (two branches that meet, e.g. a nearly stretched elbow) so that both seeds find the
   same root. Rows that stalled under 1 mm are polished with the Jacobian re-taken every iteration;
   failed rows whose seed is near a singularity restart along its singular direction; rows that
   converged onto another branch's root restart from the other root of the local quadratic model
   (``more_roots``). A restart counts only when it is a new, distinct solution.

Solutions of one target closer than ``dedupe_rad`` (max joint difference) are merged.
:func:`branch_count_report` compares the distinct solutions per target with the closed form of the
nominal robot and explains each difference (joint limit, singularity / workspace edge, or unexplained). Failed rows
carry a reason and are never marked successful. :func:`wang_ik` is the comparison method of
Wang et al. (2019): classical IK → hybrid FK → compensated target → classical IK again.

The "model" is anything with ``robot`` (classical :class:`hykin.robot.Robot`), ``predict(q)`` →
``(N, 4, 4)`` numpy hybrid poses and, for exact Jacobians, ``predict_torch(q)`` (differentiable,
float64); ``support_distance(q)`` → ``(N,)`` (0 inside the training region) is used when present.
Units: joints rad (m for prismatic), positions m, reported errors mm and degrees.
"""

from __future__ import annotations

import contextlib
import sys
import warnings
from dataclasses import dataclass, field

import numpy as np

from ..kinematics import se3
from ..kinematics.fk import fk, jacobian
from ..kinematics.robot import Robot

__all__ = [
    "BranchCountReport",
    "HybridIKError",
    "HybridIKResult",
    "branch_count_report",
    "classical_robot",
    "classical_seeds",
    "closed_form_proxy",
    "hybrid_ik",
    "hybrid_ik_from_seeds",
    "ik_result_to_rows",
    "wang_ik",
]

DEFAULT_DELTA_RAD = float(np.radians(3.0))


class HybridIKError(ValueError):
    """Bad input to hybrid IK (shapes, non-finite targets, a model without the needed methods)."""


@dataclass
class HybridIKResult:
    """One row per solution (or per failed target), flattened over targets × branches.

    target: ``(M,)`` int, row index of the target in the input.
    branch: ``(M,)`` str, branch label (e.g. shoulder/elbow/wrist ``"LUF"``; ``"seed"`` for user seeds).
    q: ``(M, dof)`` joints (rad / m); NaN where no joints exist (no classical solution at all).
    success: ``(M,)`` bool, error within ``success_mm`` / ``success_deg`` and inside joint limits.
    pos_err_mm, ang_err_deg: ``(M,)`` achieved error of the hybrid pose ``T*(q)`` to the target (NaN
        when there are no joints; ``ang_err_deg`` is 0 for position-only targets).
    reason: ``(M,)`` str, ``""`` on success, otherwise why it failed.
    in_support: ``(M,)`` bool, joints inside the model's training support (True when the model has
        no ``support_distance``).
    support_distance: ``(M,)`` float, ``model.support_distance(q)`` (0 inside; NaN when unknown).
    iterations: ``(M,)`` int, solver iterations used.
    n_targets: number of input targets; position_only: whether orientation was ignored.
    """

    target: np.ndarray
    branch: np.ndarray
    q: np.ndarray
    success: np.ndarray
    pos_err_mm: np.ndarray
    ang_err_deg: np.ndarray
    reason: np.ndarray
    in_support: np.ndarray
    support_distance: np.ndarray
    iterations: np.ndarray
    n_targets: int
    position_only: bool = False
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return int(self.target.shape[0])

    @property
    def solved_targets(self) -> np.ndarray:
        """``(n_targets,)`` bool: the target has at least one successful solution."""
        out = np.zeros(self.n_targets, dtype=bool)
        out[self.target[self.success]] = True
        return out

    def select(self, mask: np.ndarray) -> HybridIKResult:
        """Rows where ``mask`` (bool ``(M,)`` or index array) is set."""
        kw = {k: getattr(self, k)[mask] for k in _ROW_FIELDS}
        return HybridIKResult(**kw, n_targets=self.n_targets, position_only=self.position_only, info=dict(self.info))


_ROW_FIELDS = (
    "target", "branch", "q", "success", "pos_err_mm", "ang_err_deg", "reason", "in_support",
    "support_distance", "iterations",
)


# --------------------------------------------------------------------------- inputs


def classical_robot(model) -> Robot:
    """The model's calibrated classical robot: ``model.robot_`` (a fitted :class:`hykin.hybrid.HybridModel`,
    whose ``robot`` is the nominal one) or else ``model.robot``."""
    for name in ("robot_", "robot"):
        r = getattr(model, name, None)
        if isinstance(r, Robot):
            return r
    raise HybridIKError("hybrid IK: the model must have a classical robot (`model.robot_` or `model.robot`)")


def _check_model(model) -> Robot:
    robot = classical_robot(model)
    if not callable(getattr(model, "predict", None)):
        raise HybridIKError("hybrid IK: the model must have `predict(q)` -> (N, 4, 4) poses")
    return robot


def _targets(T_target) -> tuple[np.ndarray, bool]:
    """Targets as ``(N, 4, 4)`` (positions get an identity rotation) and the position-only flag."""
    T = np.asarray(T_target, dtype=np.float64)
    if T.ndim == 1 and T.shape[0] == 3 or T.shape == (4, 4):
        T = T[None]
    if T.ndim == 2 and T.shape[1] == 3:
        pos_only = True
        T = se3.make_transform(np.broadcast_to(np.eye(3), (T.shape[0], 3, 3)), T)
    elif T.ndim == 3 and T.shape[1:] == (4, 4):
        pos_only = False
    else:
        raise HybridIKError(f"hybrid IK: targets must be (N, 4, 4) poses or (N, 3) positions, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        bad = int(np.argmax(~np.all(np.isfinite(T.reshape(T.shape[0], -1)), axis=1)))
        raise HybridIKError(f"hybrid IK: target row {bad} is not finite")
    if not pos_only:
        R = T[:, :3, :3]
        dev = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
        if np.any(dev > 1e-6):
            bad = int(np.argmax(dev > 1e-6))
            raise HybridIKError(f"hybrid IK: target row {bad} has a non-orthonormal rotation (|RRᵀ-I| = {dev[bad]:.2e})")
    return T, pos_only


# --------------------------------------------------------------------------- classical seeds


def closed_form_proxy(robot: Robot) -> Robot | None:
    """A nearby robot with a closed-form IK, to seed the branches of a calibrated robot that has none.

    Calibration leaves tiny deviations (``beta``, ``alpha`` off multiples of 90°, sub-mm ``a``/``d``
    offsets) that break the OPW/UR structure; they are snapped (``alpha`` within 0.02 rad of a multiple
    of π/2, ``beta`` to 0, DH lengths under 5 mm to 0). Returns ``None`` when even that has no closed form.
    """
    from ..kinematics.ik_closed_form import has_closed_form

    if robot.dof != 6 or robot.convention == "urdf":
        return None
    if has_closed_form(robot):
        return robot
    q90 = np.round(robot.alpha_rad / (np.pi / 2)) * (np.pi / 2)
    alpha = np.where(np.abs(robot.alpha_rad - q90) < 0.02, q90, robot.alpha_rad)
    snap = lambda x: np.where(np.abs(x) < 5e-3, 0.0, x)
    proxy = robot.copy(alpha_rad=alpha, beta_rad=np.zeros(robot.dof), a_m=snap(robot.a_m), d_m=snap(robot.d_m))
    return proxy if has_closed_form(proxy) else None


def _boundary_seeds(_ik, robot, sr, T, q, ok, pull_m):
    """Seeds for branches the classical robot cannot reach but the hybrid one may (workspace edge).

    Near a stretched elbow a ~mm correction decides whether a branch exists. For targets with a
    missing branch, the closed form is retried on the target pulled towards the robot base by each
    distance in ``pull_m``; the hybrid solve (box widened once) then decides. ``q`` ``(N, K, n)``.
    """
    miss = ~np.all(np.isfinite(q), axis=2)
    idx = np.flatnonzero(miss.any(1))
    if idx.size == 0 or q.ndim != 3:
        return q, ok
    base_p = robot.base[:3, 3]
    for d in pull_m:
        if idx.size == 0:
            break
        Tp = T[idx].copy()
        v = Tp[:, :3, 3] - base_p
        Tp[:, :3, 3] -= d * v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        br = _ik.ik(robot, Tp, all_branches=True, seed_robot=sr)
        qn, okn = np.asarray(br.q, dtype=np.float64), np.asarray(br.success, dtype=bool)
        if qn.shape[1] != q.shape[1]:
            break
        fill = miss[idx] & okn
        sub_q, sub_ok = q[idx], ok[idx]
        sub_q[fill] = qn[fill]
        sub_ok[fill] = False  # a seed, not a classical solution of the real target
        q[idx], ok[idx] = sub_q, sub_ok
        miss[idx] &= ~fill
        idx = idx[miss[idx].any(1)]
    return q, ok


def classical_seeds(robot: Robot, T: np.ndarray, *, all_branches: bool = True, q_seed=None,
                    position_only: bool = False, seed_robot: Robot | None = None,
                    pull_m: tuple[float, ...] = (1e-3, 4e-3)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Classical IK of ``robot`` (rigid) for targets ``T`` ``(N, 4, 4)``: seeds for the hybrid refinement.

    All branches come from :func:`hykin.ik.ik` with the closed form of ``seed_robot`` (default: the
    robot itself if it has one, else :func:`closed_form_proxy`) polished by LM on ``robot``; without
    any closed form, from ik's numerical multi-start search. ``q_seed`` ``(N, dof)`` / ``(N, S, dof)``
    adds one numerical solution per seed (the only ones when ``all_branches=False``). Branches with
    no classical solution are re-seeded from targets pulled ``pull_m`` towards the base (see
    :func:`_boundary_seeds`). Returns ``q0`` ``(N, B, dof)`` (NaN where a branch has no classical solution), ``branch``
    ``(N, B)`` str labels and ``ok`` ``(N, B)`` bool (the classical solver reports success).
    """
    import importlib

    _ik = importlib.import_module("hykin.kinematics.ik")

    N, n = T.shape[0], robot.dof
    outs_q, outs_b, outs_ok = [], [], []

    def _add(q, ok, lab):
        q = np.asarray(q, dtype=np.float64).reshape(N, -1, n)
        ok = np.asarray(ok, dtype=bool).reshape(N, -1)
        lab = np.asarray(lab, dtype=object).reshape(ok.shape)
        outs_q.append(q)
        outs_b.append(np.where(lab == "", "numeric", lab).astype(str))
        outs_ok.append(ok)

    if all_branches and not position_only:
        sr = seed_robot if seed_robot is not None else closed_form_proxy(robot)
        br = _ik.ik(robot, T, all_branches=True, seed_robot=sr)
        q, ok = np.array(br.q, dtype=np.float64), np.array(br.success, dtype=bool)
        if sr is not None and (~ok).any():
            # a branch just outside the joint limits (or failing the classical polish) still seeds the
            # hybrid solve: the hybrid solution may lie inside; the closed form returns it clipped
            from ..kinematics.ik import ik_closed_form

            cf = ik_closed_form(sr, T, tol_m=np.inf, tol_rad=np.inf)
            if cf.q.shape == q.shape:
                # only candidates that clipping moved a little (~1-2° beyond a limit), not far-off ones
                near = (cf.pos_err_m <= 0.02) & (cf.ang_err_rad <= 0.03)
                fill = ~ok & np.all(np.isfinite(cf.q), axis=2) & near
                q[fill] = cf.q[fill]
        if sr is not None and pull_m:
            q, ok = _boundary_seeds(_ik, robot, sr, T, q, ok, pull_m)
        _add(q, ok, br.label)
    if q_seed is not None:
        qs = np.asarray(q_seed, dtype=np.float64).reshape(N, -1, n)
        for s in range(qs.shape[1]):
            r = _ik.ik(robot, T, q_seed=qs[:, s], position_only=position_only)
            lab = np.full(N, "seed" if qs.shape[1] == 1 else f"seed{s}", dtype=object)
            _add(r.q, r.success, lab)
    if not outs_q:
        r = _ik.ik(robot, T, position_only=position_only)
        _add(r.q, r.success, np.where(np.asarray(r.label, dtype=object) == "", "numeric", r.label))
    return np.concatenate(outs_q, 1), np.concatenate(outs_b, 1), np.concatenate(outs_ok, 1)


# --------------------------------------------------------------------------- the solver


class _Problem:
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
        import torch

        pt = getattr(self.model, "predict_torch", None)
        if pt is None:
            return self._fd_jac(q, rows)
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

    def _fd_jac(self, q: np.ndarray, rows: np.ndarray, h: float = 1e-6) -> np.ndarray:
        n = q.shape[1]
        J = np.empty((q.shape[0], self.m, n))
        for j in range(n):
            e = np.zeros(n)
            e[j] = h
            rp, _ = self.residual(q + e, rows)
            rm, _ = self.residual(q - e, rows)
            J[:, :, j] = (rp - rm) / (2 * h)
        return J


def _solve_damped(J: np.ndarray, r: np.ndarray, lam: np.ndarray, frozen: np.ndarray | None = None) -> np.ndarray:
    """Batched LM step ``dq = -(JᵀJ + λ s I)⁻¹ Jᵀ r`` with ``s`` the mean diagonal of ``JᵀJ``."""
    k, m, n = J.shape
    if m < n:  # under-determined (position only): dq = -Jᵀ (J Jᵀ + λ I)⁻¹ r, the min-norm step
        A = J @ np.swapaxes(J, 1, 2)
        s = np.maximum(np.trace(A, axis1=1, axis2=2) / m, 1e-12)
        A = A + (lam * s)[:, None, None] * np.eye(m)
        y = np.linalg.solve(A, r[..., None])
        return -(np.swapaxes(J, 1, 2) @ y)[..., 0]
    A = np.swapaxes(J, 1, 2) @ J
    s = np.maximum(np.trace(A, axis1=1, axis2=2) / n, 1e-12)
    A = A + (lam * s)[:, None, None] * np.eye(n)
    if frozen is not None:  # frozen joints (zero columns): unit diagonal, so their step is exactly 0
        A = A + frozen[:, :, None] * np.eye(n)
    return -np.linalg.solve(A, (np.swapaxes(J, 1, 2) @ r[..., None]))[..., 0]


def _lm(prob: _Problem, q0: np.ndarray, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray, *,
        tol_m: float, tol_rad: float, max_iter: int, jac_mode: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Projected LM on all rows at once. Returns ``q``, residual ``r``, hybrid poses, iterations."""
    q = np.clip(q0, lo, hi)
    r, P = prob.residual(q, rows)
    cost = np.einsum("ij,ij->i", r, r)
    k = q.shape[0]
    lam = np.full(k, 1e-9)
    iters = np.zeros(k, dtype=int)
    active = np.ones(k, dtype=bool)
    D = None
    if jac_mode in ("frozen", "frozen-fd"):
        J0 = prob.exact_jac(q, rows) if jac_mode == "frozen" else prob._fd_jac(q, rows, h=1e-5)
        D = J0 - prob.classical_jac(q)
    stall = np.zeros(k, dtype=int)
    pinned = np.zeros(k, dtype=int)
    pinned_lim = np.zeros(k, dtype=int)
    lo_j, hi_j = prob.robot.lower[None], prob.robot.upper[None]

    def converged(rr):
        pe = np.linalg.norm(rr[:, :3], axis=1)
        if prob.pos_only:
            return pe <= tol_m
        return (pe <= tol_m) & (np.linalg.norm(rr[:, 3:], axis=1) / prob.w <= tol_rad)

    active &= ~converged(r)
    for it in range(max_iter):
        idx = np.flatnonzero(active)
        if idx.size == 0:
            break
        qa = q[idx]
        if D is not None and it % 6 == 5:
            # slow rows (near singularities the frozen correction is not enough): re-measure it here
            J1 = prob.exact_jac(qa, rows[idx]) if jac_mode == "frozen" else prob._fd_jac(qa, rows[idx], h=1e-5)
            D[idx] = J1 - prob.classical_jac(qa)
        if D is not None:
            J = prob.classical_jac(qa) + D[idx]
        else:
            J = prob.exact_jac(qa, rows[idx])
        dq = _solve_damped(J, r[idx], lam[idx])
        # active bounds: joints on a bound whose step points outwards are frozen and the step re-solved
        # (otherwise clipping stalls, e.g. redundant position-only solves against a joint limit)
        eps_b = 1e-12
        act = ((qa <= lo[idx] + eps_b) & (dq < 0)) | ((qa >= hi[idx] - eps_b) & (dq > 0))
        if act.any():
            ra = np.flatnonzero(act.any(1))
            Jf = J[ra] * (~act[ra])[:, None, :]
            dq[ra] = _solve_damped(Jf, r[idx[ra]], lam[idx[ra]], frozen=act[ra].astype(float)) * (~act[ra])
        q_new = np.clip(qa + dq, lo[idx], hi[idx])
        r_new, P_new = prob.residual(q_new, rows[idx])
        c_new = np.einsum("ij,ij->i", r_new, r_new)
        better = c_new < cost[idx]
        ib = idx[better]
        q[ib], r[ib], P[ib], cost[ib] = q_new[better], r_new[better], P_new[better], c_new[better]
        lam[ib] = np.maximum(lam[ib] / 10, 1e-12)
        iw = idx[~better]
        lam[iw] *= 10
        iters[idx] += 1
        # Stop rows that converged, or that cannot improve any more (λ huge or no decrease x3).
        stall[ib] = 0
        stall[iw] += 1
        # rows pinned on a box face for 3 iterations (the caller widens the box) or on a joint limit
        # for 5 (the solution lies beyond it): stop
        eps = 1e-9
        qi, loi, hii = q[idx], lo[idx], hi[idx]
        at_lo, at_hi = qi <= loi + eps, qi >= hii - eps
        box = ((at_lo & (loi > lo_j + eps)) | (at_hi & (hii < hi_j - eps))).any(1)
        lim = ((at_lo & (loi <= lo_j + eps)) | (at_hi & (hii >= hi_j - eps))).any(1)
        pinned[idx] = np.where(box, pinned[idx] + 1, 0)
        pinned_lim[idx] = np.where(lim, pinned_lim[idx] + 1, 0)
        done = converged(r[idx]) | (lam[idx] > 1e6) | (stall[idx] >= 12) | (pinned[idx] >= 3) | (pinned_lim[idx] >= 5)
        active[idx[done]] = False
    return q, r, P, iters


def _run_rows(prob: _Problem, q0: np.ndarray, rows: np.ndarray, delta: float, widen: float, *,
              tol_m: float, tol_rad: float, success_m: float, success_rad: float, max_iter: int,
              jac_mode: str):
    robot = prob.robot
    lo_j, hi_j = robot.lower[None], robot.upper[None]
    lo = np.maximum(q0 - delta, lo_j)
    hi = np.minimum(q0 + delta, hi_j)
    q, r, P, it = _lm(prob, q0, rows, lo, hi, tol_m=tol_m, tol_rad=tol_rad, max_iter=max_iter, jac_mode=jac_mode)
    pe, ae = _errs(prob, r)
    ok = (pe <= success_m) & (ae <= success_rad)
    eps = 1e-9
    at_box = ((q <= lo + eps) & (lo > lo_j + eps)) | ((q >= hi - eps) & (hi < hi_j - eps))
    retry = ~ok & at_box.any(1)
    if widen > 1 and retry.any():
        i = np.flatnonzero(retry)
        lo2 = np.maximum(q0[i] - widen * delta, lo_j)
        hi2 = np.minimum(q0[i] + widen * delta, hi_j)
        q2, r2, P2, it2 = _lm(prob, q[i], rows[i], lo2, hi2, tol_m=tol_m, tol_rad=tol_rad, max_iter=max_iter,
                              jac_mode=jac_mode)
        q[i], r[i], P[i], it[i] = q2, r2, P2, it[i] + it2
        lo[i], hi[i] = lo2, hi2
        pe, ae = _errs(prob, r)
        ok = (pe <= success_m) & (ae <= success_rad)
        at_box = ((q <= lo + eps) & (lo > lo_j + eps)) | ((q >= hi - eps) & (hi < hi_j - eps))
    at_lim = (q <= lo_j + eps) | (q >= hi_j - eps)
    return q, pe, ae, ok, at_box.any(1), at_lim.any(1), it


def _run_polished(prob: _Problem, q0: np.ndarray, rows: np.ndarray, delta: float, widen: float, *,
                  polish_iter: int = 15, **kw):
    """:func:`_run_rows`, then rows that stalled close to the target (under 1 mm, not on the box or a
    limit: the frozen correction of the Jacobian is too coarse where the networks bend strongly, e.g.
    near singularities) get up to ``polish_iter`` more iterations with the Jacobian re-taken every
    iteration (``"exact"``), in a box around where they stalled."""
    out = _run_rows(prob, q0, rows, delta, widen, **kw)
    q, pe, ae, ok, box, lim, it = out
    stalled = np.flatnonzero(~ok & ~box & ~lim & (pe < 1e-3))
    if stalled.size and kw.get("jac_mode") != "exact":
        kw2 = dict(kw, jac_mode="exact", max_iter=polish_iter)
        q2, p2, a2, o2, b2, l2, i2 = _run_rows(prob, q[stalled], rows[stalled], delta, widen, **kw2)
        better = o2 | (p2 < pe[stalled])
        sel, src = stalled[better], np.flatnonzero(better)
        q[sel], pe[sel], ae[sel], ok[sel], box[sel], lim[sel] = q2[src], p2[src], a2[src], o2[src], b2[src], l2[src]
        it[stalled] += i2
    return q, pe, ae, ok, box, lim, it


def _errs(prob: _Problem, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pe = np.linalg.norm(r[:, :3], axis=1)
    ae = np.zeros_like(pe) if prob.pos_only else np.linalg.norm(r[:, 3:], axis=1) / prob.w
    return pe, ae


@contextlib.contextmanager
def _torch_threads(n: int | None):
    """Run with ``n`` torch intra-op threads (restored afterwards); no-op for None or without torch.

    The solver evaluates the networks on modest batches many times: one thread is as fast on an idle
    machine and several times faster on a busy one (no spinning worker threads)."""
    torch = sys.modules.get("torch")
    if n is None or torch is None:
        yield
        return
    old = torch.get_num_threads()
    torch.set_num_threads(int(n))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _support(model, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    fn = getattr(model, "support_distance", None)
    dist = np.full(q.shape[0], np.nan)
    finite = np.all(np.isfinite(q), axis=1)
    if fn is None or not finite.any():
        return dist, np.ones(q.shape[0], dtype=bool)
    dist[finite] = np.asarray(fn(q[finite]), dtype=np.float64).reshape(-1)
    return dist, ~(dist > 0)


def _wrapped_diff(a: np.ndarray, b: np.ndarray, rev: np.ndarray) -> np.ndarray:
    """``a - b`` with revolute joints wrapped to ``[-π, π)`` (q and q + 2π are one configuration)."""
    d = a - b
    return np.where(rev, (d + np.pi) % (2 * np.pi) - np.pi, d)


def _duplicates(qm: np.ndarray, okm: np.ndarray, order: np.ndarray, rev: np.ndarray, tol: float):
    """Successful rows equal (max joint difference ``<= tol``, modulo 2π) to a better row of the same target.

    ``qm`` ``(N, B, n)``, ``okm`` ``(N, B)``, ``order`` ``(N, B)`` score (lower is kept first).
    Returns ``dup`` ``(N, B)`` bool and ``of`` ``(N, B)`` int: the column of the row each duplicate equals.
    """
    N, B = okm.shape
    perm = np.argsort(np.where(okm, order, np.inf), axis=1, kind="stable")
    qs = np.take_along_axis(qm, perm[..., None], 1)
    oks = np.take_along_axis(okm, perm, 1)
    close = np.abs(_wrapped_diff(qs[:, :, None], qs[:, None], rev)).max(-1) <= tol  # (N, B, B)
    close &= oks[:, :, None] & oks[:, None]
    close &= np.tril(np.ones((B, B), dtype=bool), -1)[None]  # [j, i]: i < j
    dup_s = close.any(2)
    first = np.take_along_axis(perm, np.argmax(close, axis=2), 1)  # original column of the kept row
    dup = np.zeros((N, B), dtype=bool)
    of = np.full((N, B), -1)
    np.put_along_axis(dup, perm, dup_s, 1)
    np.put_along_axis(of, perm, np.where(dup_s, first, -1), 1)
    return dup, of


def _second_root_steps(prob: _Problem, q1: np.ndarray, rows: np.ndarray, t_max: float) -> np.ndarray:
    """Steps ``(k, n)`` from solutions ``q1`` towards the other root of a fold (a pair of solutions that
    merge at a singularity, e.g. elbow- and shoulder-boundary pairs of the closed form).

    Along the right singular vector ``v`` of the smallest singular value ``σ`` of the hybrid residual
    Jacobian, the residual is ``r(q1 + t v) ≈ σ u t + ½ c t²`` (``c`` by a central second difference),
    whose second root is ``t* = -2σ / (u·c)``, clipped to ``|t*| <= t_max``.
    """
    J = prob._fd_jac(q1, rows, h=1e-6)
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


def _null_directions(prob: _Problem, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit direction ``(k, n)`` of the smallest singular value of the classical Jacobian at ``q`` and
    that value relative to the largest ``(k,)`` (small near a singularity)."""
    J = prob.classical_jac(q)
    _, S, Vt = np.linalg.svd(J)
    return Vt[:, -1], S[:, -1] / np.maximum(S[:, 0], 1e-300)


def _pick_new(cand_q: np.ndarray, cand_ok: np.ndarray, have: list, rev: np.ndarray, tol: float) -> int:
    """Index of the first successful candidate farther than ``tol`` from every joint vector in ``have``, or -1."""
    for k in np.flatnonzero(cand_ok):
        if all(np.abs(_wrapped_diff(cand_q[k], h, rev)).max() > tol for h in have):
            return int(k)
    return -1


def _more_roots(prob: _Problem, q0u: np.ndarray, labels_u: np.ndarray, st: list, rows: np.ndarray,
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
       local quadratic model (:func:`_second_root_steps`).

    A restart is accepted only when it succeeds and differs (``> dedupe_rad``) from every solution of
    its target, so neither search can add a duplicate; ``run(q0, rows)`` is the box solve.
    """
    q, pe, ae, ok, box, lim, it = st
    n = q.shape[1]
    lo, hi = prob.robot.lower, prob.robot.upper

    def sols_of(t):
        return [q[i] for i in np.flatnonzero(ok & (rows == t))]

    def accept(owner, res, n_per):  # few rows (near singularities only): a plain loop
        q2, p2, a2, o2, b2, l2, i2 = res
        for j, r0 in enumerate(owner):
            sl = slice(j * n_per, (j + 1) * n_per)
            it[r0] += int(i2[sl].sum())
            k = _pick_new(q2[sl], o2[sl], sols_of(rows[r0]), rev, dedupe_rad)
            if k >= 0:
                g = j * n_per + k
                q[r0], pe[r0], ae[r0], ok[r0], box[r0], lim[r0] = q2[g], p2[g], a2[g], True, False, False

    # 1. failed rows near a singularity: restarts along the singular direction
    fi = np.flatnonzero(~ok & np.all(np.isfinite(q0u), axis=1) & (pe < 1e-3))
    if fi.size:
        v, rel = _null_directions(prob, np.clip(q0u[fi], lo, hi))
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
    dup, of = _duplicates(qm.reshape(N, B, n), okm.reshape(N, B), pem.reshape(N, B), rev, dedupe_rad)
    pos = np.full(N * B, -1)
    pos[flat] = np.arange(flat.size)
    d_rows = np.flatnonzero(dup.reshape(-1)[flat])  # indices into the solve rows
    if d_rows.size:
        src = pos[rows[d_rows] * B + of.reshape(-1)[flat[d_rows]]]
        # distinct seeds, or seeds of different closed-form branches (equal when both were clamped at a
        # workspace edge the hybrid model reaches); not user seeds repeated on purpose
        distinct = (np.abs(_wrapped_diff(q0u[d_rows], q0u[src], rev)).max(1) > dedupe_rad) | (
            labels_u[d_rows] != labels_u[src])
        d_rows, src = d_rows[distinct], src[distinct]
    if d_rows.size:
        t_max = 0.5
        step = _second_root_steps(prob, q[src], rows[src], t_max)
        mult = np.array([1.0, 1.5, 2.5, -1.0])
        seeds = np.clip(q[src][:, None] + mult[None, :, None] * step[:, None], lo, hi).reshape(-1, n)
        ok[d_rows] = False  # a duplicate: only a new, distinct root makes it a success again
        accept(d_rows, run(seeds, np.repeat(rows[d_rows], len(mult))), len(mult))
        lost = ~ok[d_rows]
        ok[d_rows[lost]] = True  # no other root: stays the duplicate it was (merged at the end)


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
) -> HybridIKResult:
    """Hybrid refinement of given classical solutions ``q0`` ``(N, dof)`` or ``(N, B, dof)``.

    Each finite seed is refined in ``q0 ± delta_rad`` (see the module docstring); ``branch`` ``(N, B)``
    labels the seeds; seeds must be finite and at most ``delta_rad`` outside the joint limits.
    Rows per target: its distinct successful solutions; a target with none gets one failed row (its
    best attempt and the reason; NaN joints when no seed existed). ``keep_failed=True`` keeps every
    failed branch as well. ``nearest=True`` with ``q_current`` ``(N, dof)`` keeps one solution per
    target: inside the training support if any, then nearest in joint space (Euclidean).
    """
    robot = _check_model(model)
    T, pos_only_in = _targets(T_target)
    pos_only = bool(position_only or pos_only_in)
    N, n = T.shape[0], robot.dof
    q0 = np.asarray(q0, dtype=np.float64)
    if q0.ndim == 2:
        q0 = q0[:, None]
    if q0.ndim != 3 or q0.shape[0] != N or q0.shape[2] != n:
        raise HybridIKError(f"hybrid IK: seeds must have shape ({N}, B, {n}) or ({N}, {n}), got {q0.shape}")
    B = q0.shape[1]
    rev = np.array([t == "revolute" for t in robot.joint_type])
    qc = None
    if nearest:
        if q_current is None:
            raise HybridIKError("hybrid IK: nearest=True needs q_current")
        qc = np.asarray(q_current, dtype=np.float64).reshape(-1, n)
        qc = np.broadcast_to(qc, (N, n)) if qc.shape[0] == 1 else qc
        if qc.shape[0] != N:
            raise HybridIKError(f"hybrid IK: q_current must have shape ({N}, {n}) or ({n},), got {qc.shape}")
        # the hybrid model is not 2π-periodic: solve in the representation nearest the current joints
        from ..kinematics.ik import nearest_representation

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
        prob = _Problem(model, robot, T, pos_only, float(orientation_weight_m))
        rows = tgt[ui]
        with _torch_threads(torch_threads):
            qq, p_, a_, o_, box, lim, itr = _run_polished(
                prob, np.clip(flat_q0[ui], robot.lower, robot.upper), rows, float(delta_rad), float(widen),
                tol_m=tol_m, tol_rad=tol_rad, success_m=success_mm * 1e-3, success_rad=np.radians(success_deg),
                max_iter=max_iter, jac_mode=jacobian_mode,
            )
            # Rows that stalled close to the target (a local minimum of the flat cost near a
            # singularity): multi-start inside the widened box. A target with no solution yet keeps the
            # best restart; one with solutions only a restart that is a new, distinct solution.
            solved_t = np.zeros(N, dtype=bool)
            solved_t[rows[o_]] = True
            retry = ~o_ & ~box & ~lim & (p_ < 1e-3)
            if restarts > 0 and retry.any():
                ri = np.flatnonzero(retry)
                rng = np.random.default_rng(0)
                rep = np.repeat(ri, restarts)
                span = 0.5 * widen * delta_rad
                qs = np.clip(qq[rep] + rng.uniform(-span, span, (rep.size, n)), robot.lower, robot.upper)
                q2, p2, a2, o2, b2, l2, i2 = _run_rows(
                    prob, qs, rows[rep], float(delta_rad), float(widen), tol_m=tol_m, tol_rad=tol_rad,
                    success_m=success_mm * 1e-3, success_rad=np.radians(success_deg), max_iter=max_iter,
                    jac_mode=jacobian_mode,
                )
                score = np.where(o2, 0.0, p2 + np.where(np.isfinite(a2), a2, 0.0)).reshape(ri.size, restarts)
                best = np.argmin(score, axis=1)
                pick = np.arange(ri.size) * restarts + best
                better = (o2[pick] | (p2[pick] < p_[ri])) & ~solved_t[rows[ri]]
                for k in np.flatnonzero(solved_t[rows[ri]]):  # few rows: plain loop
                    sl = slice(k * restarts, (k + 1) * restarts)
                    have = [qq[i] for i in np.flatnonzero(o_ & (rows == rows[ri[k]]))]
                    j = _pick_new(q2[sl], o2[sl], have, rev, dedupe_rad)
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
            if alt_rows.size:
                wide = np.flatnonzero(rev & (robot.upper - robot.lower > 2 * np.pi))
                shifts = np.array(np.meshgrid(*([[-1.0, 0.0, 1.0]] * wide.size))).reshape(wide.size, -1).T * 2 * np.pi
                shifts = shifts[np.any(shifts != 0, axis=1)]
                if shifts.size:
                    rep = np.repeat(alt_rows, len(shifts))
                    qs = flat_q0[ui][rep].copy()
                    qs[:, wide] += np.tile(shifts, (alt_rows.size, 1))
                    inl = np.all((qs >= robot.lower - delta_rad) & (qs <= robot.upper + delta_rad), axis=1)
                    rep, qs = rep[inl], qs[inl]
                    if rep.size:
                        q2, p2, a2, o2, b2, l2, i2 = _run_rows(
                            prob, np.clip(qs, robot.lower, robot.upper), rows[rep], float(delta_rad), float(widen),
                            tol_m=tol_m, tol_rad=tol_rad, success_m=success_mm * 1e-3,
                            success_rad=np.radians(success_deg), max_iter=max_iter, jac_mode=jacobian_mode,
                        )
                        for k in np.flatnonzero(o2):  # few rows: plain loop is fine here
                            r0 = rep[k]
                            if not o_[r0]:
                                qq[r0], p_[r0], a_[r0], o_[r0], box[r0], lim[r0] = q2[k], p2[k], a2[k], True, False, False
                        np.add.at(itr, rep, i2)
            if more_roots and not pos_only and prob.m >= n:
                st = [qq, p_, a_, o_, box, lim, itr]
                run = lambda q0_, rows_: _run_polished(
                    prob, q0_, rows_, float(delta_rad), float(widen), tol_m=tol_m, tol_rad=tol_rad,
                    success_m=success_mm * 1e-3, success_rad=np.radians(success_deg), max_iter=max_iter,
                    jac_mode=jacobian_mode)
                _more_roots(prob, flat_q0[ui], labels.reshape(-1)[ui], st, rows, ui % B, N, B, rev, dedupe_rad,
                            sing_rel, run)
        q[ui], pe[ui], ae[ui], ok[ui], it[ui] = qq, p_, a_, o_, itr
        rs = np.where(
            box, f"needs more than ±{np.degrees(widen * delta_rad):.3g}° from the classical solution",
            np.where(lim, "blocked by a joint limit", "did not converge (target unreachable for the hybrid model?)"),
        )
        msg = np.array([f"{s}: residual {a * 1e3:.3g} mm / {np.degrees(b):.3g} deg" for s, a, b in zip(rs, p_, a_)],
                       dtype=object)
        reason[ui] = np.where(o_, "", msg)
    dist, ins = _support(model, q)

    # de-duplicate: drop a success that equals a better success of the same target (modulo 2π)
    okm = ok.reshape(N, B)
    qm = q.reshape(N, B, n)
    dup, _ = _duplicates(qm, okm, pe.reshape(N, B), rev, dedupe_rad)
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
        score = np.where(okm & ~dup, dj + np.where(ins_m, 0.0, 1e6), np.inf)
        pick = np.argmin(score, axis=1)
        sel = np.zeros((N, B), dtype=bool)
        sel[np.arange(N), pick] = True
        keep = np.where(has[:, None], sel, keep)
    keep_flat = keep.reshape(-1)
    res = HybridIKResult(
        target=tgt, branch=labels.reshape(-1).astype(str), q=q, success=ok, pos_err_mm=pe * 1e3,
        ang_err_deg=np.degrees(ae), reason=reason.astype(str), in_support=ins, support_distance=dist,
        iterations=it, n_targets=N, position_only=pos_only,
        info={"delta_rad": float(delta_rad), "method": "hybrid-lm", "jacobian": jacobian_mode},
    )
    return res.select(keep_flat)


def hybrid_ik(
    model,
    T_target,
    *,
    all_branches: bool = True,
    q_current=None,
    q_seed=None,
    nearest: bool = False,
    delta_rad: float = DEFAULT_DELTA_RAD,
    position_only: bool = False,
    tol_m: float = 1e-12,
    seed_robot: Robot | None = None,
    temperature_c=None,
    **kwargs,
) -> HybridIKResult:
    """Joints reaching ``T_target`` with the hybrid model: all branches by default.

    ``T_target``: ``(N, 4, 4)`` poses or ``(N, 3)`` positions (position-only) in the world frame, m.
    ``all_branches``: seed from every closed-form branch of the calibrated robot (when it has a
    closed form; otherwise numerical IK). ``q_seed`` ``(N, dof)`` / ``(N, S, dof)``: extra seeds for
    the classical IK (with ``all_branches=False``, the only seeds). ``q_current`` ``(N, dof)`` or
    ``(dof,)``: current joints; with ``nearest=True`` only the solution nearest to them is kept per
    target (inside the training support preferred); without a seed they also seed position-only IK.
    ``delta_rad``: half-width of the box around each classical solution (default 3°).
    ``seed_robot``: robot whose closed form seeds the branches (default: the calibrated robot if it has
    one, else the nominal robot — ``model.nominal`` or a HybridModel's ``model.robot`` — else
    :func:`closed_form_proxy` of the calibrated robot). ``tol_m``: stopping tolerance (and 1e-12 rad).
    ``temperature_c``: arm temperature (°C, scalar or ``(N,)``) at which the targets are to be reached,
    for a model with a thermal coefficient (:meth:`HybridModel.targets_at_reference`); errors are
    then reported at the reference temperature (they differ by ``alpha dT`` relative, ~1e-5).
    Success needs ``pos_err_mm <= success_mm`` (1e-4) and ``ang_err_deg <= success_deg`` (1e-4) and
    joints within limits. Other keywords go to :func:`hybrid_ik_from_seeds` (``widen`` = 5,
    ``orientation_weight_m`` = 1, ``success_mm``, ``success_deg``, ``max_iter`` = 60,
    ``jacobian_mode``, ``keep_failed``, ``dedupe_rad``, ``torch_threads`` = 1: torch threads while solving,
    ``restarts`` = 16: random starts in the widened box for rows that stalled near the target — local
    minima near singularities; ``more_roots`` = True, ``sing_rel`` = 0.02: the searches near
    singularities of step 4 of the module docstring).
    Returns a :class:`HybridIKResult`: per target its distinct successful solutions (one per branch;
    joints with a range over 2π in the closed form's representation, nearest zero — or nearest
    ``q_current`` with ``nearest=True``: the hybrid model is not 2π-periodic), or one failed row.
    """
    robot = _check_model(model)
    if temperature_c is not None and hasattr(model, "targets_at_reference"):
        T_target = model.targets_at_reference(T_target, temperature_c)
    T, pos_only_in = _targets(T_target)
    pos_only = bool(position_only or pos_only_in)
    N = T.shape[0]
    seeds = q_seed
    if seeds is None and q_current is not None and (pos_only or not all_branches):
        seeds = np.broadcast_to(np.asarray(q_current, dtype=np.float64).reshape(-1, robot.dof), (N, robot.dof))
    q0, labels, ok = classical_seeds(robot, T, all_branches=all_branches, q_seed=seeds, position_only=pos_only,
                                     seed_robot=_seed_robot(model, seed_robot))
    return hybrid_ik_from_seeds(
        model, T[:, :3, 3] if pos_only else T, q0, branch=labels, delta_rad=delta_rad, position_only=pos_only,
        tol_m=tol_m, q_current=q_current, nearest=nearest, **kwargs,
    )


def _seed_robot(model, seed_robot):
    from ..kinematics.ik_closed_form import has_closed_form

    if seed_robot is not None:
        return seed_robot
    cls = classical_robot(model)
    if has_closed_form(cls):
        return cls
    for name in ("nominal", "robot"):  # HybridModel: robot = nominal, robot_ = calibrated
        nom = getattr(model, name, None)
        if isinstance(nom, Robot) and nom is not cls and nom.dof == cls.dof and has_closed_form(nom):
            return nom
    return closed_form_proxy(cls)


def wang_ik(model, T_target, *, all_branches: bool = True, q_seed=None, success_mm: float = 1e-4,
            success_deg: float = 1e-4, orientation_weight_m: float = 1.0) -> HybridIKResult:
    """Comparison method of Wang et al. (2019): classical IK, hybrid FK, compensated target, classical IK.

    For each branch: ``q1`` = classical IK of the target on the calibrated robot; the hybrid model predicts
    the pose error at ``q1``, ``E = T*(q1) T̂(q1)⁻¹`` (``T̂`` the rigid classical FK that the classical IK
    inverts, so ``T̂(q1)`` = target); the compensated target is
    ``E⁻¹ T_target`` (position ``p − Δp``, rotation ``exp(−Δr) R``); ``q2`` = classical IK of it, seeded
    with ``q1``. Errors are those of ``T*(q2)`` to the target, so the result is comparable with
    :func:`hybrid_ik`. Same result type; successes use the same thresholds.
    """
    import importlib

    _ik = importlib.import_module("hykin.kinematics.ik")

    robot = _check_model(model)
    T, pos_only = _targets(T_target)
    if pos_only:
        raise HybridIKError("wang_ik: needs full (N, 4, 4) target poses")
    N, n = T.shape[0], robot.dof
    q1, labels, ok1 = classical_seeds(robot, T, all_branches=all_branches, q_seed=q_seed,
                                      seed_robot=_seed_robot(model, None))
    B = q1.shape[1]
    flat = q1.reshape(-1, n)
    fin = np.all(np.isfinite(flat), axis=1) & ok1.reshape(-1)
    tgt = np.repeat(np.arange(N), B)
    q2 = np.full_like(flat, np.nan)
    reason = np.full(N * B, "no classical solution (unreachable for this branch)", dtype=object)
    if fin.any():
        i = np.flatnonzero(fin)
        Th = fk(robot, flat[i])  # what the (rigid) classical IK inverted: Th = T at q1
        Ts = _predict(model, flat[i])
        # E = T* T̂^-1 maps classical to hybrid; compensated target Tc = E^-1 T  (p - Δp, exp(-Δr) R)
        dp = Ts[:, :3, 3] - Th[:, :3, 3]
        dR = Ts[:, :3, :3] @ np.swapaxes(Th[:, :3, :3], 1, 2)
        Tc = T[tgt[i]].copy()
        Tc[:, :3, 3] -= dp
        Tc[:, :3, :3] = np.swapaxes(dR, 1, 2) @ Tc[:, :3, :3]
        res2 = _ik.ik(robot, Tc, q_seed=flat[i])
        q2i = np.asarray(res2.q, dtype=np.float64).reshape(-1, n)
        ok2 = np.asarray(res2.success, dtype=bool).reshape(-1)
        q2[i[ok2]] = q2i[ok2]
        reason[i] = np.where(ok2, "", "classical IK of the compensated target failed")
    good = np.all(np.isfinite(q2), axis=1)
    pe = np.full(N * B, np.nan)
    ae = np.full(N * B, np.nan)
    if good.any():
        Tp = _predict(model, q2[good])
        pe[good], ae[good] = se3.pose_error(Tp, T[tgt[good]])
    okk = good & (pe <= success_mm) & (ae <= success_deg)
    reason = np.where(good & ~okk, np.array([f"error {a:.3g} mm / {b:.3g} deg" for a, b in zip(pe, ae)], dtype=object),
                      reason)
    reason[okk] = ""
    dist, ins = _support(model, q2)
    res = HybridIKResult(
        target=tgt, branch=labels.reshape(-1).astype(str), q=q2, success=okk, pos_err_mm=pe, ang_err_deg=ae,
        reason=reason.astype(str), in_support=ins, support_distance=dist, iterations=np.ones(N * B, dtype=int),
        n_targets=N, info={"method": "wang2019"},
    )
    # keep every branch that produced joints; a target with none keeps one row saying why
    keep = good.reshape(N, B).copy()
    none = ~keep.any(1)
    keep[none, 0] = True
    return res.select(keep.reshape(-1))


def _predict(model, q: np.ndarray) -> np.ndarray:
    with warnings.catch_warnings(), _torch_threads(1):
        warnings.simplefilter("ignore")
        return np.asarray(model.predict(q), dtype=np.float64).reshape(-1, 4, 4)


def ik_result_to_rows(result: HybridIKResult, robot: Robot | None = None, targets=None) -> dict[str, np.ndarray]:
    """Columns for a CSV: ``target, branch, q1..qn, success, pos_err_mm, ang_err_deg, reason``.

    Joints are rad; a row that is not a solution (``success`` 0) has **no joint values** (NaN: never
    made-up joints, whatever the path: all branches, nearest, position only) and a ``reason`` that
    starts with its category (:data:`hykin.ik_reasons.CATEGORIES`: out of reach, joint limits,
    singular, not converged). With ``robot`` (the model's calibrated robot) and ``targets`` (the
    ``(N, 4, 4)`` or ``(N, 3)`` targets given to :func:`hybrid_ik`) the category is established by
    :func:`hykin.ik_reasons.failure_reasons` (reach, IK with opened joint limits, Jacobian at the best
    attempt); otherwise it is read from the solver's reason. ``success`` is 0/1 int; ``in_support``
    (0/1) and ``support_distance`` follow ``reason``.
    """
    from ..kinematics.ik_reasons import categorise, failure_reasons

    ok = np.asarray(result.success, dtype=bool)
    q = np.array(result.q, dtype=np.float64, copy=True)
    reason = result.reason.astype(object).copy()
    bad = np.flatnonzero(~ok)
    if bad.size:
        if robot is not None and targets is not None:
            tg = np.asarray(targets, dtype=np.float64)[result.target[bad]]
            cls = np.array(["no classical solution" in str(reason[i]) or "classical solution outside" in str(reason[i])
                            for i in bad])
            cat = failure_reasons(robot, tg, bool(result.position_only), q_best=q[bad], classical_failed=cls)
            reason[bad] = [f"{c}; {r}" if r else c for c, r in zip(cat, reason[bad])]
        else:
            reason[bad] = [categorise(str(reason[i])) for i in bad]
        q[bad] = np.nan
    cols: dict[str, np.ndarray] = {"target": result.target.astype(int), "branch": result.branch.astype(str)}
    for j in range(q.shape[1]):
        cols[f"q{j + 1}"] = q[:, j]
    cols["success"] = ok.astype(int)
    cols["pos_err_mm"] = result.pos_err_mm
    cols["ang_err_deg"] = result.ang_err_deg
    cols["reason"] = reason.astype(str)
    cols["in_support"] = result.in_support.astype(int)
    cols["support_distance"] = result.support_distance
    return cols


# --------------------------------------------------------------------------- branch counts vs the closed form


@dataclass
class BranchCountReport:
    """Distinct hybrid IK solutions per target against the closed form of a (nominal) robot.

    n_found, n_closed_form: ``(N,)`` int counts; differ: ``(N,)`` bool; near_limit: ``(N,)`` bool, some
    closed-form solution (with the limits widened by ``margin_deg``) or hybrid solution lies within
    ``margin_deg`` of a joint limit — there the counts may truly differ, because a sub-degree correction
    moves a solution across the limit. reasons: ``{target: [str, ...]}`` for differing targets, one line per
    unmatched solution; kind: ``{target: "joint limit" | "singularity / workspace edge" | "unexplained"}``
    (the worst over its lines: unexplained > singularity > joint limit).
    """

    n_found: np.ndarray
    n_closed_form: np.ndarray
    differ: np.ndarray
    near_limit: np.ndarray
    reasons: dict
    kind: dict
    margin_deg: float

    def summary(self) -> str:
        """One line: totals, differing targets, and the totals over targets away from joint limits."""
        away = ~self.near_limit
        kinds = {k: sum(v == k for v in self.kind.values()) for k in ("joint limit", "singularity / workspace edge",
                                                                       "unexplained")}
        return (f"{len(self.n_found)} targets: hybrid IK {int(self.n_found.sum())} distinct solutions, closed form "
                f"{int(self.n_closed_form.sum())}; targets differing {int(self.differ.sum())} "
                f"(joint limit {kinds['joint limit']}, singularity / workspace edge "
                f"{kinds['singularity / workspace edge']}, unexplained {kinds['unexplained']}); on the "
                f"{int(away.sum())} targets with no solution within {self.margin_deg:g}° of a joint limit: "
                f"{int(self.n_found[away].sum())} vs {int(self.n_closed_form[away].sum())}, differing "
                f"{int((self.differ & away).sum())}")


def branch_count_report(model, T_target, result: HybridIKResult, robot: Robot | None = None, *,
                        margin_deg: float = 0.5, match_deg: float = 10.0, sing_rel: float = 0.02) -> BranchCountReport:
    """Compare the distinct successful solutions of ``result`` (from ``hybrid_ik(model, T_target)``, all
    branches) per target with the closed-form solutions of ``robot`` (default: the nominal robot,
    ``model.nominal`` or a HybridModel's ``model.robot``), and explain each difference.

    Solutions of one target are matched greedily (max joint difference, modulo 2π, under ``match_deg``).
    An unmatched solution is explained as *joint limit* when it lies within ``margin_deg`` of a limit, or
    its counterpart exists just beyond one (closed form with limits widened by ``margin_deg``); as
    *singularity / workspace edge* when the counterpart has no closed-form solution (out of reach) or
    the closed-form solution is near a singularity (smallest / largest singular value of its Jacobian
    ``< sing_rel``: a fold whose pair of solutions the correction removes); otherwise *unexplained*
    (a solver miss). Targets ``(N, 4, 4)``; a robot without a closed form raises ``HybridIKError``.
    """
    from ..kinematics.ik import ik_closed_form
    from ..kinematics.ik_closed_form import has_closed_form

    T, pos_only = _targets(T_target)
    if pos_only:
        raise HybridIKError("branch_count_report: needs (N, 4, 4) target poses")
    if robot is None:  # the nominal robot: `model.nominal`, else a HybridModel's `model.robot`
        robot = getattr(model, "nominal", None)
        if not isinstance(robot, Robot):
            robot = getattr(model, "robot", None)
        if not isinstance(robot, Robot):
            robot = classical_robot(model)
    if robot.dof != 6 or not has_closed_form(robot):
        raise HybridIKError(f"branch_count_report: robot {robot.name!r} has no closed-form IK")
    N = T.shape[0]
    rev = np.array([t == "revolute" for t in robot.joint_type])
    lo, hi = robot.lower, robot.upper
    m = np.radians(margin_deg)
    cf = ik_closed_form(robot, T)
    wide = ik_closed_form(robot.copy(lower=lo - np.where(rev, m, 0.0), upper=hi + np.where(rev, m, 0.0)), T)
    raw = ik_closed_form(robot, T, tol_m=np.inf, tol_rad=np.inf)
    ok = result.success & (result.target < N)
    n_found = np.bincount(result.target[ok], minlength=N)[:N]
    n_cf = cf.n_solutions

    def margin(q):  # (k, n) -> (k,) signed distance to the nearest limit (rad, < 0 outside), joint index
        d = np.minimum(q - lo, hi - q)
        return d.min(1), d.argmin(1)

    near = np.zeros(N, dtype=bool)
    wq = wide.q[wide.valid]
    wt = np.nonzero(wide.valid)[0]
    if wq.size:
        near[wt[margin(wq)[0] < m]] = True
    if ok.any():
        near[result.target[ok][margin(result.q[ok])[0] < m]] = True
    differ = n_found != n_cf
    reasons, kind = {}, {}
    rank = {"joint limit": 0, "singularity / workspace edge": 1, "unexplained": 2}
    for t in np.flatnonzero(differ):  # few targets: plain loop
        hq, hb = result.q[ok & (result.target == t)], result.branch[ok & (result.target == t)]
        nq, nb = cf.q[t][cf.valid[t]], np.array(cf.labels)[cf.valid[t]]
        if len(hq) and len(nq):
            D = np.abs(_wrapped_diff(nq[:, None], hq[None], rev)).max(-1)
        else:
            D = np.full((len(nq), len(hq)), np.inf)
        mn, mh = np.zeros(len(nq), bool), np.zeros(len(hq), bool)
        for _ in range(min(len(nq), len(hq))):
            Dm = np.where(mn[:, None] | mh[None], np.inf, D)
            i, j = np.unravel_index(np.argmin(Dm), Dm.shape)
            if Dm[i, j] > np.radians(match_deg):
                break
            mn[i], mh[j] = True, True
        lines, kinds = [], []
        for q_, lab in zip(nq[~mn], nb[~mn]):
            d, j = margin(q_[None])
            J = jacobian(robot, q_[None])[0]
            sv = np.linalg.svd(J, compute_uv=False)
            rel = sv[-1] / sv[0]
            if d[0] < m:
                kinds.append("joint limit")
                lines.append(f"closed-form solution {lab} lies {np.degrees(d[0]):.3g}° inside the limit of joint "
                             f"{j[0] + 1}; the hybrid one lies beyond it")
            elif rel < sing_rel:
                kinds.append("singularity / workspace edge")
                lines.append(f"closed-form solution {lab} is near a singularity (σmin/σmax {rel:.2g}): the hybrid "
                             f"model has no solution of this branch nearby (fold moved by the correction)")
            else:
                kinds.append("unexplained")
                lines.append(f"closed-form solution {lab} not found by hybrid IK (limit margin "
                             f"{np.degrees(d[0]):.3g}°, σmin/σmax {rel:.2g})")
        labels = list(cf.labels)
        for q_, lab in zip(hq[~mh], hb[~mh]):
            d, j = margin(q_[None])
            b = labels.index(lab) if lab in labels else -1
            wv = wide.valid[t] & ~cf.valid[t]
            beyond = wv.any() and np.abs(_wrapped_diff(wide.q[t][wv], q_, rev)).max(-1).min() < np.radians(match_deg)
            if d[0] < m or beyond:
                kinds.append("joint limit")
                lines.append(f"hybrid solution {lab} lies {np.degrees(d[0]):.3g}° inside the limit of joint {j[0] + 1}"
                             f"; the closed-form one lies beyond it")
            elif b < 0 or not np.all(np.isfinite(raw.q[t, b])):
                kinds.append("singularity / workspace edge")
                lines.append(f"hybrid solution {lab}: the closed form has no solution of this branch (out of reach)")
            elif margin(raw.q[t, b][None])[0][0] > 1e-9 and raw.pos_err_m[t, b] > 1e-6:
                # the closed form's candidate is inside the limits but misses the target: the nominal arm
                # falls short (a clamped stretched elbow / wrist), the hybrid one reaches
                kinds.append("singularity / workspace edge")
                lines.append(f"hybrid solution {lab} ({np.degrees(d[0]):.3g}° from the limits): the nominal robot "
                             f"falls short of the target by {raw.pos_err_m[t, b] * 1e3:.3g} mm in this branch "
                             f"(workspace edge)")
            elif margin(raw.q[t, b][None])[0][0] <= 1e-9:
                kinds.append("joint limit")
                lines.append(f"hybrid solution {lab} ({np.degrees(d[0]):.3g}° inside the limits): the closed-form "
                             f"solution of this branch lies beyond a limit (joint "
                             f"{margin(raw.q[t, b][None])[1][0] + 1})")
            else:
                kinds.append("unexplained")
                lines.append(f"hybrid solution {lab} has no closed-form counterpart (limit margin {np.degrees(d[0]):.3g}°)")
        if not lines:
            kinds.append("unexplained")
            lines.append("counts differ but every solution matched (duplicates within the match tolerance?)")
        reasons[int(t)] = lines
        kind[int(t)] = max(kinds, key=rank.get)
    return BranchCountReport(n_found=n_found, n_closed_form=n_cf, differ=differ, near_limit=near, reasons=reasons,
                             kind=kind, margin_deg=float(margin_deg))
