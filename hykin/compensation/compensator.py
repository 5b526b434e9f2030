"""A compensator that stays warm: :class:`Compensator` loads a hybrid model's fast predictor, frames and
branch data once, then compensates one target (:meth:`Compensator.step`, warm-started from the previous
joints) or a batch (:meth:`Compensator.__call__`). :func:`hykin.compensation.compensate` and the CLI
``compensate`` run through it (one path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .targets import Compensation, compensate

__all__ = ["Compensator", "StepResult"]


@dataclass
class StepResult:
    """One compensated target. q: ``(dof,)`` joints (rad / m) the real robot needs (NaN on failure).
    command: ``(4, 4)`` pose to send (controller base frame, m; NaN on failure). success, reason
    (``""`` on success). pos_err_mm, ang_err_deg: the model's pose at ``q`` to the target."""

    q: np.ndarray
    command: np.ndarray
    success: bool
    reason: str
    pos_err_mm: float
    ang_err_deg: float


class Compensator:
    """Compensation of targets with ``model`` (a fitted :class:`hykin.HybridModel` or any model with
    ``nominal``, ``robot_``, ``predict``). ``frame``: as :func:`hykin.compensation.compensate`
    (``"measurement"``, ``"base"``, ``"auto"``); other keywords go to the hybrid IK."""

    def __init__(self, model, *, frame: str = "measurement", **ik_kw):
        from .targets import resolve_frame

        self.model = model
        self.frame = resolve_frame(model, frame)
        self.ik_kw = ik_kw
        self.dof = model.nominal.dof

    def __call__(self, targets, q_branch=None, **kw) -> Compensation:
        """Compensate targets ``(N, 4, 4)`` (or ``(N, 3)`` positions), m, in :attr:`frame`.
        ``q_branch`` ``(N, dof)`` / ``(dof,)``: joints choosing each target's branch (default: the
        walk through the targets). Returns a :class:`Compensation`."""
        return compensate(self.model, targets, q_branch=q_branch, frame=self.frame, **{**self.ik_kw, **kw})

    def step(self, target, q_prev) -> StepResult:
        """Compensate ONE target ``(4, 4)`` (m, :attr:`frame`) on the branch of ``q_prev`` ``(dof,)``
        (the previous target's joints)."""
        T = np.asarray(target, dtype=np.float64)
        if T.shape != (4, 4):
            raise ValueError(f"step: target must have shape (4, 4), got {T.shape}")
        qp = np.asarray(q_prev, dtype=np.float64).reshape(1, self.dof)
        c = self(T[None], q_branch=qp)
        return StepResult(q=c.q[0], command=c.command[0], success=bool(c.success[0]), reason=str(c.reason[0]),
                          pos_err_mm=float(c.pos_err_mm[0]), ang_err_deg=float(c.ang_err_deg[0]))
