"""The walk of a redundant arm (more than 6 joints, full poses) through a list of targets without joints.

A 7-joint arm reaches a pose on a one-parameter family of joints (its self-motion), and its controller
resolves the redundancy itself, typically by a local inverse kinematics from the joints it stands at.
The discrete branches of the nominal IK (:func:`.branches.sequential_nearest`) do not describe that: a
hint picked among sampled branches can lie on another arm angle than the controller reaches from the
previous joints (probe s41 AI: an iiwa-like cobot and a 6R on a rail, 75 and 46 of 100 smooth-path
targets refused, the others executed 1.7-2.9 mm off).

So a redundant arm walks locally: each target is solved from the compensated joints of the one before
(the first from the discrete walk's hint), the solution moved along the self-motion to the nearest of
them (:mod:`hykin.hybrid.self_motion`, in the compensator), as a controller moving through the list
would. :func:`check_local` then executes each command as such a controller: a local nominal IK (LM, no
restarts) from the previous compensated joints. Where that lands on other joints whose pose misses the
target by more than the model's accuracy, the target fails with the reason; within it, it is noted.
"""

from __future__ import annotations

import numpy as np

from .result import fail_row

__all__ = ["check_local", "local_hints"]



def local_hints(comp, T: np.ndarray, first: np.ndarray, D, Dm, pos_only: bool, branch_reason) -> np.ndarray:
    """``(N, n)`` hints: row 0 ``first[0]`` (the discrete walk's: how the robot gets to the first target,
    a joint move, is not in the list), each next row the compensated joints of the last target solved
    (targets ``T`` ``(N, 4, 4)`` in ``comp``'s frame; ``D``/``Dm``: :meth:`.compensator.Compensator.solve`'s)."""
    N = len(T)
    qb = np.array(first, dtype=np.float64, copy=True)
    prev = qb[0]
    for k in range(N):
        if not np.isfinite(prev).all():
            prev = qb[k]
        qb[k] = prev
        sl = slice(k, k + 1)
        q, _, ok, _, _, _ = comp.solve(T[sl], prev[None], None if D is None else D[sl], pos_only, branch_reason,
                                       D_model=None if Dm is None else Dm[sl])
        if ok[0]:
            prev = q[0]
    return qb


#: a redundant arm's target farther than this from the joints before (a revolute joint, rad) is not sent
#: without joints: a local solve's end on the self-motion after such a move depends on the solver
FAR_STEP_RAD = np.radians(20.0)


def check_local(model, comp, result, T: np.ndarray, D, Dm, rounds: int = 6) -> list:
    """Execute ``result``'s commands (a :class:`.result.Compensation`, in place) as a local-IK controller
    from the previous sent target's joints (the first target is reached some other way, a joint move: not
    checked; module docstring); returns the notes.
    Where the controller's joints are not the compensated ones and miss, the target is solved again from
    them, up to ``rounds`` times (the controller's endpoint moves little with the command: a fixed point).
    ``D``/``Dm``: the targets' tools relative to the robot file's and the model's TCP (or None)."""
    from ..hybrid.ik_result import model_accuracy
    from .local_controller import follow, where_it_lands

    nom = model.nominal
    Dc = np.broadcast_to(np.eye(4), (len(T), 4, 4)) if D is None else D
    Tm = comp.model_targets(T, Dm)
    acc = max(comp.tolerance_mm, model_accuracy(model)[0] or 0.0)
    tol = max(comp.tolerance_mm, 1e-3)
    rev = nom.revolute
    q_first = result.q.copy()  # the walk's joints before this check
    prev, noted = None, []
    for k in range(len(T)):
        if not result.success[k]:
            continue  # not sent: the robot stays where it was
        if prev is None:
            prev = result.q[k]
            continue
        before = q_first[:k][np.isfinite(q_first[:k]).all(1)]  # the list's previous target, sent or not
        step = np.abs(np.where(rev, q_first[k] - before[-1], 0.0)).max() if len(before) else 0.0
        if step > FAR_STEP_RAD:  # where a local solve ends after such a move depends on the solver
            fail_row(result, k, f"the controller would execute it elsewhere on this redundant arm: it lies "
                             f"{np.degrees(step):.0f}° (a joint) from the target before, and where a controller's "
                             f"local solve ends on the self-motion after such a move depends on its solver (one "
                             f"least-norm solver landed 2-5 mm off, probe s41); give the joints (q1..qN) or send "
                             f"them (--joints)")
            continue
        miss, pick = follow(model, comp, result, k, prev, T, D, Dm, Dc, Tm, tol, rounds)
        if miss > acc:
            fail_row(result, k, f"the controller would execute it elsewhere on this redundant arm: solving the command "
                             f"locally from the joints before it {where_it_lands(nom, pick, result.q[k], miss)}; give "
                             "the joints (q1..qN) or send them (--joints)")
            continue
        if miss > tol:
            noted.append(f"{k} ({miss:.3g} mm)")
        prev = result.q[k]
    if not noted:
        return []
    return [f"{len(noted)} targets (targets {', '.join(noted[:8])}{' ...' if len(noted) > 8 else ''}) are reached by "
            f"a local-IK controller on other joints of the redundant arm than the compensated ones: the model's "
            f"robot lands there within its accuracy ({acc:.3g} mm) of the target, by the amounts given"]
