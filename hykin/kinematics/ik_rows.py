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

__all__ = ["FAR_FROM_SEED_RAD", "MAX_TURN_COPIES", "TURN_COPIES_CAP", "classical_ik_rows", "expand_turn_copies",
           "far_from_seed", "far_from_seed_note", "ik_rows",
           "representations_per_solution", "turn_copies", "turn_copies_left_out", "turn_copies_note",
           "turn_copy_counts"]

#: a solution "nearest the seed" farther than this from it (any revolute joint, rad) lies on another branch
FAR_FROM_SEED_RAD = np.pi / 2


def far_from_seed(robot: Robot, q: np.ndarray, q_seed: np.ndarray) -> np.ndarray:
    """``(N,)`` bool: solutions ``q`` ``(N, dof)`` that lie more than :data:`FAR_FROM_SEED_RAD` from their
    seed joints ``q_seed`` ``(N, dof)`` on some revolute joint (False for NaN rows): the solution nearest
    the seed lies on another branch than the seed's (probe s42 AR: at a stretched elbow the seed's own
    branch missed the tolerance and the wrist came back turned 180°, without a word)."""
    rev = robot.revolute
    with np.errstate(invalid="ignore"):
        d = np.abs(np.where(rev, np.asarray(q, dtype=np.float64) - q_seed, 0.0))
        return np.nan_to_num(d, nan=0.0).max(1) > FAR_FROM_SEED_RAD


def far_from_seed_note(targets, seed: str) -> str:
    """The note for solutions far from their seed joints (:func:`far_from_seed`): ``targets`` the 0-based
    target numbers, ``seed`` what the seed joints are called ("their seed joints", "q_current")."""
    n = len(targets)
    ids = ", ".join(map(str, list(targets)[:8])) + (" ..." if n > 8 else "")
    it = "it" if n == 1 else "them"
    return (f"{n} target{'' if n == 1 else 's'} (target {ids}) {'is' if n == 1 else 'are'} solved more than 90° "
            f"(a joint) from {seed}: no solution on the branch of {seed} reaches {it} within the tolerance ({seed} "
            "far from every solution, or a stretched elbow where that branch just misses), so the nearest "
            f"solution{'' if n == 1 else 's'} {'lies' if n == 1 else 'lie'} on another branch; check before "
            f"sending {it} to the robot")


#: most 2π representations per solution that ``hykin ik --all-branches`` lists by default (:func:`expand_turn_copies`);
#: a robot whose solutions may have more lists each once and says how many it left out (:func:`turn_copies_note`)
MAX_TURN_COPIES = 8
#: the largest ``max_copies`` one may ask for: a UR arm (six ±360° joints) has 64 per solution, 512 rows per
#: target over its 8 branches; 4096 bounds the output at 32768 rows per target
TURN_COPIES_CAP = 4096


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


def _check_max_copies(max_copies: int) -> None:
    if not 1 <= int(max_copies) <= TURN_COPIES_CAP:
        raise ValueError(f"max_copies must be 1..{TURN_COPIES_CAP} (2π representations listed per solution), "
                         f"got {max_copies}")


def _wide_joints(robot: Robot) -> tuple[np.ndarray, np.ndarray]:
    """``(wide, reps)``: the independent revolute joints whose range exceeds 2π, and for each the most
    representations ``q + 2πk`` one angle can have within its limits (``floor(span / 2π) + 1``)."""
    rev = robot.revolute
    span = np.asarray(robot.upper, dtype=np.float64) - np.asarray(robot.lower, dtype=np.float64)
    wide = np.flatnonzero(rev & np.isfinite(span) & (span > 2 * np.pi + 1e-9))
    return wide, (np.floor(span[wide] / (2 * np.pi)) + 1).astype(int)


def _shifts(wide: np.ndarray, reps: np.ndarray, n: int) -> np.ndarray:
    """``(G, n)`` joint shifts (rad) ``2πk`` on the ``wide`` joints, ``|k| < reps``, the zero shift first."""
    axes = [np.concatenate([[0.0], np.arange(1, c), -np.arange(1, c)]) for c in reps]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, wide.size)
    shift = np.zeros((len(grid), n))
    shift[:, wide] = 2 * np.pi * grid
    return shift


def representations_per_solution(robot: Robot) -> int:
    """The most 2π representations one IK solution of ``robot`` can have within the joint limits: the product
    over the revolute joints with a range over 2π of ``floor(range / 2π) + 1`` (1 when there are none; two
    ±400° joints: 3 · 3 = 9; a UR arm's six ±360° joints: 3^6 = 729 at the zero pose, 2^6 = 64 elsewhere)."""
    wide, reps = _wide_joints(robot)
    return int(np.prod(reps)) if wide.size else 1


def turn_copy_counts(robot: Robot, q: np.ndarray) -> np.ndarray:
    """``(M,)`` int: the 2π representations within the joint limits of each row of ``q`` ``(M, n)`` (rad/m),
    itself included: the product over the joints with a range over 2π of the integers ``k`` with
    ``lower <= q + 2πk <= upper``; 0 for a row with a NaN (no solution)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    wide, _ = _wide_joints(robot)
    out = np.where(np.isfinite(q).all(axis=1), 1, 0)
    for j in wide:
        lo, hi = float(robot.lower[j]), float(robot.upper[j])
        with np.errstate(invalid="ignore"):
            k = np.floor((hi - q[:, j]) / (2 * np.pi) + 1e-12) - np.ceil((lo - q[:, j]) / (2 * np.pi) - 1e-12) + 1
        out = out * np.where(np.isfinite(k), np.maximum(k, 1), 0).astype(int)
    return out


def _solution_keys(robot: Robot, target: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``(M, n + 1)`` rows equal for two IK rows that are 2π representations of one solution of one target:
    the target, then the joints rounded to 1e-7, those with a range over 2π taken modulo 2π."""
    wide, _ = _wide_joints(robot)
    k = np.array(q, dtype=np.float64, copy=True)
    k[:, wide] = np.mod(k[:, wide], 2 * np.pi)
    k = np.round(k, 7)
    k[:, wide] = np.where(np.isclose(k[:, wide], 2 * np.pi, atol=1e-7), 0.0, k[:, wide]) + 0.0
    return np.column_stack([np.asarray(target, dtype=np.float64), k])


def turn_copies_left_out(robot: Robot, target, q) -> int:
    """How many 2π representations within the joint limits of the solutions listed in IK rows (``target``
    ``(M,)``, ``q`` ``(M, n)``; NaN rows are failures) the rows do not list: per solution (rows that are
    2π copies of each other count as one) its :func:`turn_copy_counts` minus the rows listing it."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    good = np.isfinite(q).all(axis=1)
    if not good.any():
        return 0
    keys = _solution_keys(robot, np.asarray(target)[good], q[good])
    _, first, listed = np.unique(keys, axis=0, return_index=True, return_counts=True)
    total = turn_copy_counts(robot, q[good][first])
    return int(np.maximum(total - listed, 0).sum())


def expand_turn_copies(robot: Robot, rows: dict, max_copies: int = MAX_TURN_COPIES) -> dict:
    """IK rows (:func:`ik_rows`' columns, e.g. hybrid IK's) with every further 2π representation within the
    limits of each solved row added after it (every other column copied: the same pose when the model is
    2π-periodic in those joints, as a hybrid model with ``periodic="wrap"`` and any robot are), unless the
    robot's :func:`representations_per_solution` exceed ``max_copies`` (then ``rows`` unchanged: each solution
    once, in its representation nearest zero). Representations already listed for the target are not repeated."""
    _check_max_copies(max_copies)
    wide, reps = _wide_joints(robot)
    if wide.size == 0 or np.prod(reps) > max_copies:
        return rows
    n = robot.dof
    Q = np.stack([np.asarray(rows[f"q{j + 1}"], dtype=np.float64) for j in range(n)], axis=1)
    tg = np.asarray(rows["target"]).astype(int)
    shift = _shifts(wide, reps, n)[1:]  # (G - 1, n): the copies, not the row itself
    good = np.isfinite(Q).all(axis=1)
    cand = Q[:, None, :] + shift[None]  # (M, G - 1, n)
    inside = good[:, None] & np.all((cand >= robot.lower) & (cand <= robot.upper), axis=-1)
    have = {(t, *np.round(qr, 9)) for t, qr in zip(tg[good], Q[good])}
    src, rep = np.nonzero(inside)
    new = np.array([(tg[i], *np.round(cand[i, g], 9)) not in have for i, g in zip(src, rep)], dtype=bool)
    src, rep = src[new], rep[new]
    order = np.argsort(np.concatenate([np.arange(len(tg)), src]), kind="stable")  # each copy after its row
    out = {}
    for c, v in rows.items():
        v = np.asarray(v)
        out[c] = np.concatenate([v, v[src]])[order]
    for j in range(n):
        out[f"q{j + 1}"] = np.concatenate([Q[:, j], cand[src, rep, j]])[order]
    return out


def turn_copies_note(robot: Robot, rows: dict, max_copies: int = MAX_TURN_COPIES, how: str | None = None) -> str:
    """One line saying how many 2π representations within the limits of the listed solutions the IK rows
    ``rows`` leave out (:func:`turn_copies_left_out`) and how to list them (``how``; default: the call with
    ``max_copies`` = :func:`representations_per_solution`), or ``""`` when none is left out."""
    n = robot.dof
    Q = np.stack([np.asarray(rows[f"q{j + 1}"], dtype=np.float64) for j in range(n)], axis=1)
    left = turn_copies_left_out(robot, rows["target"], Q)
    if left == 0:
        return ""
    wide, _ = _wide_joints(robot)
    names = ", ".join(f"q{j + 1}" for j in wide)
    per = representations_per_solution(robot)
    how = how or (f"expand_turn_copies(robot, rows, max_copies={per}) / classical_ik_rows(..., max_copies={per}) "
                  "list them")
    why = f"; a solution may have {per}, more than the {max_copies} listed per solution" if per > max_copies else ""
    return (f"note: {left} further 2π representations of the listed solutions lie within the joint limits and are not "
            f"listed ({names} turn over 360°: q ± 360° reaches the same pose{why}); {how}")


def classical_ik_rows(robot: Robot, T: np.ndarray, q_current=None, position_only: bool = False,
                      max_copies: int = MAX_TURN_COPIES) -> dict[str, np.ndarray]:
    """:func:`ik_rows` of classical IK on ``robot`` for targets ``T`` ``(N, 4, 4)`` (world, m): every
    solution branch, each in every 2π representation within the joint limits (:func:`expand_turn_copies`: when a
    solution may have at most ``max_copies`` (default :data:`MAX_TURN_COPIES`, at most
    :data:`TURN_COPIES_CAP`), else the one nearest zero: :func:`turn_copies_note` counts those left
    out), or with ``q_current`` ``(N, dof)`` the one nearest it. A target without a solution gets one row
    (branch ``""``, its smallest residual over the branches, a categorised reason)."""
    br = ik(robot, T, all_branches=True, position_only=position_only)
    if q_current is not None:
        r = br.nearest_to(q_current, robot.lower, robot.upper)
        q, ok, pe, ae = r.q[:, None], r.success[:, None], r.pos_err_m[:, None], r.ang_err_rad[:, None]
        lab = np.asarray(r.label)[:, None]
    else:
        q, ok = np.asarray(br.q, dtype=np.float64), np.asarray(br.success, dtype=bool)
        pe, ae, lab = br.pos_err_m, br.ang_err_rad, np.asarray(br.label, dtype=object)
    failed = ~ok.any(axis=1)
    keep = ok.copy()
    keep[failed, 0] = True  # a failed target: one row saying why
    t, k = np.nonzero(keep)  # row-major: targets in order, their branches in slot order
    pe_best = np.where(np.isfinite(pe), pe, np.inf).min(axis=1)
    ae_best = np.where(np.isfinite(ae), ae, np.inf).min(axis=1)
    pe_best = np.where(np.isfinite(pe).any(axis=1), pe_best, np.nan)
    ae_best = np.where(np.isfinite(ae).any(axis=1), ae_best, np.nan)
    good = ok[t, k]
    rows = ik_rows(
        t, np.where(good, np.asarray(lab, dtype=object)[t, k], ""), np.where(good[:, None], q[t, k], np.nan), good,
        np.where(good, pe[t, k], pe_best[t]) * 1e3, np.degrees(np.where(good, ae[t, k], ae_best[t])),
        np.full(t.size, "", dtype=object), robot=robot, targets=T, position_only=position_only, q_best=False,
        success_as_int=False,
    )
    return rows if q_current is not None else expand_turn_copies(robot, rows, max_copies)
