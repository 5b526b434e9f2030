"""The one row schema of IK output files (``hykin ik``), for classical and hybrid IK alike.

Columns, in order: ``target`` (int, row of the target in the input), ``branch`` (str label, ``""``
when none), ``q1..qn`` (rad / m; NaN on every row that is not a solution: never made-up joints),
``success``, ``pos_err_mm``, ``ang_err_deg``, ``reason`` (``""`` on success, otherwise starting with
its category from :data:`hykin.kinematics.ik_reasons.CATEGORIES`: out of reach, joint limits,
singular, not converged), then for a model with a training support ``in_support`` (0/1) and
``support_distance``. ``success`` is written 0/1 by hybrid IK and true/false by classical IK (both
files' formats are pinned; readers accept either).
"""

from __future__ import annotations

import numpy as np

from .ik import ik
from .ik_reasons import categorise, failure_reasons
from .robot import Robot

__all__ = ["MAX_TURN_COPIES", "classical_ik_rows", "ik_rows", "turn_copies"]

#: most 2π representations per solution that ``hykin ik --all-branches`` lists (:func:`turn_copies`)
MAX_TURN_COPIES = 8


def ik_rows(target, branch, q, success, pos_err_mm, ang_err_deg, reason, *, robot: Robot | None = None,
            targets=None, position_only: bool = False, q_best: bool = True, classical_failed=None,
            in_support=None, support_distance=None, success_as_int: bool = True) -> dict[str, np.ndarray]:
    """Columns (module docstring) of ``M`` IK rows: ``target`` ``(M,)`` int, ``branch`` ``(M,)`` str, ``q``
    ``(M, n)``, ``success`` ``(M,)`` bool, ``pos_err_mm``/``ang_err_deg`` ``(M,)``, ``reason`` ``(M,)`` str
    (the solver's, for failed rows).

    Failed rows lose their joints and get a categorised reason: with ``robot`` and ``targets`` (the
    ``(N, 4, 4)`` or ``(N, 3)`` targets ``target`` indexes) by
    :func:`hykin.kinematics.ik_reasons.failure_reasons` (``q_best``: the failed rows' joints are the
    solver's best attempts, used for the singularity test; ``classical_failed`` ``(M,)`` bool: classical
    IK found no solution for the row, default all) prefixed to the solver's reason; otherwise read from
    the solver's reason (:func:`hykin.kinematics.ik_reasons.categorise`). ``in_support`` /
    ``support_distance`` ``(M,)``: the support columns (omitted when None).
    """
    ok = np.asarray(success, dtype=bool)
    q = np.array(q, dtype=np.float64, copy=True)
    reason = np.asarray(reason).astype(object).copy()
    target = np.asarray(target).astype(int)
    bad = np.flatnonzero(~ok)
    if bad.size:
        if robot is not None and targets is not None:
            tg = np.asarray(targets, dtype=np.float64)[target[bad]]
            cls = None if classical_failed is None else np.asarray(classical_failed, dtype=bool)[bad]
            cat = failure_reasons(robot, tg, bool(position_only), q_best=q[bad] if q_best else None,
                                  classical_failed=cls)
            reason[bad] = [f"{c}; {r}" if r else c for c, r in zip(cat, reason[bad])]
        else:
            reason[bad] = [categorise(str(reason[i])) for i in bad]
        q[bad] = np.nan
    cols: dict[str, np.ndarray] = {"target": target, "branch": np.asarray(branch).astype(str)}
    for j in range(q.shape[1]):
        cols[f"q{j + 1}"] = q[:, j]
    cols["success"] = ok.astype(int) if success_as_int else ok
    cols["pos_err_mm"] = np.asarray(pos_err_mm, dtype=np.float64)
    cols["ang_err_deg"] = np.asarray(ang_err_deg, dtype=np.float64)
    cols["reason"] = reason.astype(str)
    if in_support is not None:  # a failed row has no joints: not in the support, no distance to it
        cols["in_support"] = np.where(ok, np.asarray(in_support).astype(int), 0)
    if support_distance is not None:
        cols["support_distance"] = np.where(ok, np.asarray(support_distance, dtype=np.float64), np.nan)
    return cols


def turn_copies(robot: Robot, q: np.ndarray, ok: np.ndarray, max_copies: int = MAX_TURN_COPIES):
    """Every 2π representation within the limits of each solution ``q`` ``(N, K, n)`` (valid where ``ok``
    ``(N, K)``): a revolute joint whose range exceeds 2π reaches the same pose at ``q + 2πk`` (the
    robot's FK is 2π-periodic; a controller turns the axis differently). Returns ``(q (N, K·G, n), ok
    (N, K·G), src (K·G,))``: slot ``src`` of ``q`` each copy comes from, the solution itself first and
    then its copies; copies outside the limits are not ``ok``. A robot whose solutions may have more
    than ``max_copies`` representations (a UR arm: six ±360° joints, 64 per solution) is returned
    unchanged: each solution once, in its representation nearest zero."""
    q = np.asarray(q, dtype=np.float64)
    N, K, n = q.shape
    rev = np.array([t == "revolute" for t in robot.independent_joint_type])
    span = np.asarray(robot.upper, dtype=np.float64) - np.asarray(robot.lower, dtype=np.float64)
    wide = np.flatnonzero(rev & np.isfinite(span) & (span > 2 * np.pi + 1e-9))
    reps = np.floor(span[wide] / (2 * np.pi)) + 1  # most representations of one angle within the limits
    if wide.size == 0 or np.prod(reps) > max_copies:
        return q, np.asarray(ok, dtype=bool), np.arange(K)
    axes = [np.concatenate([[0.0], np.arange(1, c), -np.arange(1, c)]) for c in reps.astype(int)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, wide.size)  # (G, w), zero shift first
    shift = np.zeros((len(grid), n))
    shift[:, wide] = 2 * np.pi * grid
    qq = (q[:, :, None, :] + shift[None, None]).reshape(N, -1, n)
    inside = np.all((qq >= robot.lower) & (qq <= robot.upper), axis=-1)
    okq = np.repeat(np.asarray(ok, dtype=bool), len(grid), axis=1) & inside
    okq[:, :: len(grid)] = np.asarray(ok, dtype=bool)  # the solution itself as found
    return qq, okq, np.repeat(np.arange(K), len(grid))


def classical_ik_rows(robot: Robot, T: np.ndarray, q_current=None, position_only: bool = False) -> dict[str, np.ndarray]:
    """:func:`ik_rows` of classical IK on ``robot`` for targets ``T`` ``(N, 4, 4)`` (world, m): every
    solution branch, each in every 2π representation within the joint limits (:func:`turn_copies`: at
    most :data:`MAX_TURN_COPIES` per solution, else the one nearest zero), or with ``q_current``
    ``(N, dof)`` the one nearest it. A target without a solution gets one row (branch ``""``, its
    smallest residual over the branches, a categorised reason)."""
    br = ik(robot, T, all_branches=True, position_only=position_only)
    if q_current is not None:
        r = br.nearest_to(q_current, robot.lower, robot.upper)
        q, ok, pe, ae = r.q[:, None], r.success[:, None], r.pos_err_m[:, None], r.ang_err_rad[:, None]
        lab = np.asarray(r.label)[:, None]
    else:
        q, ok, src = turn_copies(robot, br.q, br.success)
        pe, ae, lab = br.pos_err_m[:, src], br.ang_err_rad[:, src], np.asarray(br.label, dtype=object)[:, src]
    failed = ~ok.any(axis=1)
    keep = ok.copy()
    keep[failed, 0] = True  # a failed target: one row saying why
    t, k = np.nonzero(keep)  # row-major: targets in order, their branches in slot order
    pe_best = np.where(np.isfinite(pe), pe, np.inf).min(axis=1)
    ae_best = np.where(np.isfinite(ae), ae, np.inf).min(axis=1)
    pe_best = np.where(np.isfinite(pe).any(axis=1), pe_best, np.nan)
    ae_best = np.where(np.isfinite(ae).any(axis=1), ae_best, np.nan)
    good = ok[t, k]
    return ik_rows(
        t, np.where(good, np.asarray(lab, dtype=object)[t, k], ""), np.where(good[:, None], q[t, k], np.nan), good,
        np.where(good, pe[t, k], pe_best[t]) * 1e3, np.degrees(np.where(good, ae[t, k], ae_best[t])),
        np.full(t.size, "", dtype=object), robot=robot, targets=T, position_only=position_only, q_best=False,
        success_as_int=False,
    )
