"""A controller that executes a Cartesian command by a local inverse kinematics from the joints it stands at.

A streaming interface (RSI, EGM, ``hykin serve``'s stream, :meth:`.compensator.Compensator.step`) and a
caller who gives the joints of each target (``q_branch``; a CSV's ``q1..qN``) know the joints the robot
stands at. Its controller solves the command (a pose of the nominal model) from there: a local solve
(LM of the nominal robot, no restarts), as controllers follow a Cartesian path. Where that is not the
compensated joints, the real robot goes elsewhere: near the wrist singularity the command hardly fixes
A4/A6, and a solve of the hybrid model may move them tens of degrees where the controller's stays near
where it is (probe s42 AQ: an offset-wrist 6R's path from A5 = 0 executed 0.65-4.4 mm off, every step
"ok"). So each command is executed as that controller would: where it lands on other joints that miss
the target, the target is solved again from the controller's joints (a fixed point: its endpoint
moves little with the command); one it still executes elsewhere fails with the reason, and one it
executes within the tolerance takes the controller's joints (where the robot will stand).
"""

from __future__ import annotations

import numpy as np

from ..geometry import se3
from .result import fail_row

__all__ = ["check_from_joints", "follow", "local_picks", "where_it_lands"]

_SAME_RAD = 1e-6  # the controller's joints this close to the compensated ones are them
#: a local solve's end is the controller's only within a local move of where it stands: from farther (given
#: joints that only hint at a branch, a home posture for every row) it depends on the solver, and is not judged
#: (probe s42 AV: from joints 100-500° away 24 of 40 targets were refused, a controller of its own landing them)
LOCAL_RAD, LOCAL_M = np.radians(20.0), 0.2
_CONVERGED = 1e-9  # m / rad: a local solve that ends above this found no solution of the command


def local_picks(nom, command: np.ndarray, D: np.ndarray | None, prev: np.ndarray) -> np.ndarray:
    """``(M, n)``: the controller's joints for ``command`` ``(M, 4, 4)`` (controller base frame, TCP ``D``
    ``(M, 4, 4)`` relative to the robot file's, None: the file's): LM of the nominal robot from ``prev``
    ``(M, n)`` within the joint limits, no restarts; NaN rows where it finds no solution."""
    from ..kinematics.ik import solve_lm

    C = np.asarray(command, dtype=np.float64)
    Tw = nom.base @ C if D is None else nom.base @ C @ se3.invert(np.asarray(D, dtype=np.float64))
    q, pe, ae, _ = solve_lm(nom, Tw, np.asarray(prev, dtype=np.float64), max_iter=200)
    bad = ~((pe <= _CONVERGED) & (ae <= _CONVERGED) & np.isfinite(q).all(1))
    q[bad] = np.nan
    return q


def _miss(model, q_k: np.ndarray, pick: np.ndarray, Tm_k: np.ndarray) -> float:
    """How far (mm) the model's robot at the controller's joints ``pick`` lands from the target ``Tm_k``
    (measurement frame): 0 where they are the compensated ``q_k``; inf where there are none."""
    from .walk_checks import landing, same_but_turned

    if not np.isfinite(pick).all():
        return np.inf
    if np.abs(pick - q_k).max() <= _SAME_RAD or same_but_turned(model.nominal, q_k[None], pick[None])[0]:
        return 0.0
    return float(landing(model, pick[None], Tm_k[None])[0][0])


def _local(nom, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``(M,)`` bool: joints ``b`` within a local move of ``a`` ``(M, n)`` (:data:`LOCAL_RAD` a revolute joint,
    :data:`LOCAL_M` a prismatic one); False where ``b`` is NaN."""
    rev = nom.revolute
    d = np.nan_to_num(np.abs(b - a), nan=np.inf)
    return ((d <= np.where(rev, LOCAL_RAD, LOCAL_M)).all(1))


def follow(model, comp, result, k: int, prev: np.ndarray, T: np.ndarray, D, Dm, Dc: np.ndarray, Tm: np.ndarray,
           tol: float, rounds: int = 6) -> tuple[float, np.ndarray]:
    """Row ``k`` of ``result`` (a :class:`.result.Compensation`, in place) executed from ``prev`` ``(n,)``:
    ``(miss mm, the controller's joints)``. Where they miss by more than ``tol`` the target is solved again
    from them (``comp``: the :class:`.compensator.Compensator`), up to ``rounds`` times. ``T``: the targets
    (``comp``'s frame), ``D``/``Dm``: their tools relative to the robot file's and the model's TCP (or None),
    ``Dc`` ``(N, 4, 4)``: ``D`` or identities, ``Tm``: the targets in the measurement frame."""
    nom = model.nominal
    pick = local_picks(nom, result.command[k][None], Dc[k][None], prev[None])[0]
    miss = _miss(model, result.q[k], pick, Tm[k])
    for _ in range(rounds if miss > tol else 0):
        if not np.isfinite(pick).all():
            break
        sl = slice(k, k + 1)
        q, cmd, ok, _, pe, ae = comp.solve(T[sl], pick[None], None if D is None else D[sl], False,
                                           D_model=None if Dm is None else Dm[sl])
        if not ok[0]:
            break
        result.q[k], result.command[k], result.pos_err_mm[k], result.ang_err_deg[k] = q[0], cmd[0], pe[0], ae[0]
        pick = local_picks(nom, cmd, Dc[k][None], prev[None])[0]
        miss = _miss(model, result.q[k], pick, Tm[k])
        if miss <= tol:
            break
    return miss, pick


def where_it_lands(nom, pick: np.ndarray, q_k: np.ndarray, miss: float) -> str:
    """How a refusal says where the controller's local solve ``pick`` goes: no solution, or its joints' distance
    from the compensated ``q_k`` and how far (mm) the model's robot lands there from the target."""
    from .walk_checks import joint_gap

    if not np.isfinite(miss):
        return "finds no solution of the command near them"
    return (f"reaches it on joints {joint_gap(nom, pick, q_k)} (largest joint difference) from the compensated ones, "
            f"landing {miss:.3g} mm from the target")


def check_from_joints(model, comp, result, T: np.ndarray, D, Dm, standing: np.ndarray) -> list:
    """Execute ``result``'s commands (in place) as a local-IK controller standing at ``standing`` ``(N, n)``
    (a step's previous joints, a batch's given joints; module docstring): every row at once, then the rows
    whose controller's joints differ (:func:`follow`). A row that still lands farther from its target than
    the model's accuracy fails with the reason; one within the tolerance takes the controller's joints; one
    between is noted (returns the notes). ``T``, ``D``, ``Dm``: as :meth:`.compensator.Compensator.solve`."""
    from ..hybrid.ik_result import model_accuracy
    from ..kinematics.ik_solutions import nearest_representation
    from .walk_checks import joint_gap, landing, same_but_turned

    N = len(T)
    rows = np.flatnonzero(result.success & np.isfinite(standing).all(1))
    if not rows.size:
        return []
    nom = model.nominal
    # joints given a turn outside the limits stand at their representation within them (as the solve takes them)
    rev = nom.revolute
    standing = np.where(rev, nearest_representation(standing, standing, comp.lower, comp.upper), standing)
    Dc = np.broadcast_to(np.eye(4), (N, 4, 4)) if D is None else np.asarray(D, dtype=np.float64)
    picks = local_picks(nom, result.command[rows], None if D is None else Dc[rows], standing[rows])
    differ = ~(np.abs(picks - result.q[rows]).max(1) <= _SAME_RAD)  # (NaN: no solution of the command there)
    # judged where the controller's solve, or the compensated joints, are a local move from where it stands
    differ &= _local(nom, standing[rows], picks) | _local(nom, standing[rows], result.q[rows])
    if not differ.any():
        return []
    Tm = comp.model_targets(T, Dm)
    acc = max(comp.tolerance_mm, model_accuracy(model)[0] or 0.0)
    tol = max(comp.tolerance_mm, 1e-3)
    noted = []
    for k in rows[differ]:
        miss, pick = follow(model, comp, result, k, standing[k], T, D, Dm, Dc, Tm, tol)
        if miss > acc:
            fail_row(result, k, f"the controller would execute it elsewhere: solving the command locally from the "
                                f"joints the robot stands at (the given joints, {joint_gap(nom, standing[k], result.q[k])} "
                                f"from the compensated ones) {where_it_lands(nom, pick, result.q[k], miss)}; near a "
                                f"singular pose (A5 = 0, a stretched elbow) the command does not fix the joints: give "
                                f"joints nearer the target or send the compensated joints (--joints)")
        elif np.isfinite(pick).all() and np.abs(pick - result.q[k]).max() > _SAME_RAD:
            # the robot will stand at the controller's joints: say so (a whole turn away: the same pose, as the
            # walk takes it), and where the model's robot lands there
            if not same_but_turned(nom, result.q[k][None], pick[None])[0]:
                pe, ae = landing(model, pick[None], Tm[k][None])
                result.pos_err_mm[k], result.ang_err_deg[k] = pe[0], ae[0]
            result.q[k] = pick
            if miss > tol:
                noted.append(f"{k} ({miss:.3g} mm)")
    if not noted:
        return []
    return [f"{len(noted)} targets (targets {', '.join(noted[:8])}{' ...' if len(noted) > 8 else ''}) are reached by "
            f"a local-IK controller from the given joints on other joints than the compensated ones: the model's "
            f"robot lands there within its accuracy ({acc:.3g} mm) of the target, by the amounts given"]
