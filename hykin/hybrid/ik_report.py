"""Hybrid IK reporting: the rows of an ``hykin ik`` output file and the branch-count comparison with
the closed form of the nominal robot."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..kinematics.fk import jacobian
from ..kinematics.ik import ik_closed_form
from ..kinematics.ik_closed_form import has_closed_form
from ..kinematics.ik_rows import ik_rows
from ..kinematics.robot import Robot
from .ik_result import HybridIKError, HybridIKResult, classical_robot, parse_targets
from .ik_roots import wrapped_diff

__all__ = ["BranchCountReport", "branch_count_report", "ik_result_to_rows"]

def ik_result_to_rows(result: HybridIKResult, robot: Robot | None = None, targets=None) -> dict[str, np.ndarray]:
    """Columns for a CSV (the one IK row schema, :func:`hykin.kinematics.ik_rows.ik_rows`): ``target,
    branch, q1..qn, success, pos_err_mm, ang_err_deg, reason, in_support, support_distance``.

    Joints are rad; a row that is not a solution (``success`` 0) has **no joint values** (NaN: never
    made-up joints, whatever the path: all branches, nearest, position only) and a ``reason`` that
    starts with its category (:data:`hykin.kinematics.ik_reasons.CATEGORIES`: out of reach, joint
    limits, singular, not converged). With ``robot`` (the model's calibrated robot) and ``targets`` (the
    ``(N, 4, 4)`` or ``(N, 3)`` targets given to :func:`hykin.hybrid.ik.hybrid_ik`) the category is
    established by :func:`hykin.kinematics.ik_reasons.failure_reasons` (reach, IK with opened joint
    limits, Jacobian at the best attempt); otherwise it is read from the solver's reason. ``success`` is
    0/1 int; ``in_support`` (0/1) and ``support_distance`` follow ``reason``.
    """
    reason = result.reason.astype(str)
    cls = np.array(["no classical solution" in r or "classical solution outside" in r for r in reason], dtype=bool)
    return ik_rows(result.target, result.branch, result.q, result.success, result.pos_err_mm, result.ang_err_deg,
                   reason, robot=robot, targets=targets, position_only=bool(result.position_only), q_best=True,
                   classical_failed=cls, in_support=result.in_support, support_distance=result.support_distance)


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
    T, pos_only = parse_targets(T_target)
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
    rev = robot.revolute
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
            D = np.abs(wrapped_diff(nq[:, None], hq[None], rev)).max(-1)
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
            beyond = wv.any() and np.abs(wrapped_diff(wide.q[t][wv], q_, rev)).max(-1).min() < np.radians(match_deg)
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
