"""Redundant arms: the solution nearest the caller's joints along the self-motion.

A 7-joint arm reaching a full pose (or any arm of more than 3 joints reaching a position) has a
manifold of solutions. An LM started at the caller's joints (the compensator's branch hint, hybrid IK's
``q_current``) stops at *a* solution; its
min-norm steps make that one near the hint, but not the nearest, and near a singular configuration
(an iiwa's joint 2 near 0, where axes 1 and 3 align) it can lie 10–30° farther than the nearest. A
program that gives joints means the nearest (its arm angle), so :func:`toward_hint` moves every solved
row along the self-motion: the step ``N (hint − q)`` with ``N = I − J⁺J`` the null-space projector of
the calibrated robot's task Jacobian, then the same hybrid solve from there, kept only where it still
reaches the target and the joints are nearer the hint; halved steps where not, until nothing improves.

The calibrated robot's Jacobian only proposes the step: the hybrid model's own solve decides where it
lands, so the result is a solution of the hybrid model to the same tolerance as before.
"""

from __future__ import annotations

import numpy as np

from ..kinematics.fk import fk_frames, jacobian

__all__ = ["is_redundant", "toward_hint"]

MAX_ROUNDS = 12  # null-space steps (each followed by a hybrid solve) per call
MIN_GAIN_RAD = 1e-7  # a step must bring the joints this much nearer the hint (Euclidean, rad) to count
_RCOND = 1e-6


def is_redundant(dof: int, position_only: bool) -> bool:
    """Whether an arm of ``dof`` joints has a self-motion reaching a full pose (``position_only`` False:
    more than 6 joints) or a position (more than 3)."""
    return dof > (3 if position_only else 6)


def _task_jacobian(robot, post: np.ndarray, q: np.ndarray, position_only: bool) -> np.ndarray:
    """``(M, m, n)``: the Jacobian of the measured point (position only, ``m = 3``: the point
    ``fk(q) @ post`` moves with ``v + ω × (p' − p)``) or of the TCP pose (``m = 6``; a constant frame
    before or after the chain maps its velocities by an invertible matrix: the same null space)."""
    fr = fk_frames(robot, q)
    J = jacobian(robot, q, frames=fr)
    if not position_only:
        return J
    r = fr.tcp[:, :3, :3] @ post[:3, 3]  # p' - p, (M, 3)
    Jv, Jw = J[:, :3], J[:, 3:]
    return Jv - np.cross(r[:, :, None], Jw, axis=1)  # v' = v + ω × r = v − r × ω


def toward_hint(solve_rows, accept, robot, post, q, pe, ae, hint, lo, hi, rows, position_only: bool) -> None:
    """Move the solved ``rows`` of ``q`` ``(N, n)`` (in place, with their errors ``pe``/``ae``, m/rad)
    along the self-motion toward ``hint`` ``(N, n)`` (module docstring). ``solve_rows(idx, q0)`` ->
    ``(q, pe, ae)``: the caller's hybrid solve of its rows ``idx`` from ``q0`` ``(M, n)`` within the joint
    limits; ``accept(pe, ae)`` -> bool ``(M,)``: the caller's success tolerance. ``lo``/``hi`` ``(n,)``:
    the joint limits. ``post`` ``(4, 4)``: the model's frame after the chain (the measured point's offset)."""
    i = np.asarray(rows, dtype=np.int64)
    if not i.size:
        return
    n = q.shape[1]
    alpha = np.ones(i.size)
    eye = np.eye(n)
    for _ in range(MAX_ROUNDS):
        J = _task_jacobian(robot, post, q[i], position_only)
        Nsp = eye - np.linalg.pinv(J, rcond=_RCOND) @ J
        d_old = np.linalg.norm(q[i] - hint[i], axis=1)
        step = (Nsp @ (hint[i] - q[i])[:, :, None])[:, :, 0]
        q0 = np.clip(q[i] + alpha[:, None] * step, lo, hi)
        q2, p2, a2 = solve_rows(i, q0)
        d_new = np.linalg.norm(q2 - hint[i], axis=1)
        # still a solution (no worse than before, within the tolerance) and nearer the hint
        good = (accept(p2, a2) & (p2 <= np.maximum(pe[i], 1e-9)) & (a2 <= np.maximum(ae[i], 1e-9))
                & (d_new < d_old - MIN_GAIN_RAD))
        j = i[good]
        q[j], pe[j], ae[j] = q2[good], p2[good], a2[good]
        small = np.linalg.norm(alpha[:, None] * step, axis=1) < MIN_GAIN_RAD
        # a refused step is halved (twice at most); a row whose step vanished is done
        alpha = np.where(good, 1.0, alpha * 0.5)
        keep = ~small & (alpha >= 0.25)
        i, alpha = i[keep], alpha[keep]
        if not i.size:
            return
