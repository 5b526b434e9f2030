"""The result of compensation (:class:`Compensation`, one row per target) and its CSV columns."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3

__all__ = ["Compensation", "command_rows", "edge_notes", "fail_row", "first_row_per_target", "merge_parts"]


@dataclass
class Compensation:
    """One row per target (``N``).

    command: ``(N, 4, 4)`` pose to send (controller base frame, m), NaN where ``success`` is False.
    q: ``(N, n)`` joints the real robot needs (rad); NaN where unreachable.
    success: ``(N,)`` bool. reason: ``(N,)`` str, ``""`` on success.
    pos_err_mm, ang_err_deg: ``(N,)`` error of the model's pose at ``q`` to the target (hybrid IK).
    shift_mm, shift_deg: ``(N,)`` how far the command is from the target (controller frame).
    in_support: ``(N,)`` bool, ``q`` inside the model's training support.
    q_branch: ``(N, n)`` joints that chose the branch. frame: the resolved frame.
    notes: what the caller should be told about targets that are compensated (texts; e.g. targets the
    controller executes on another solution within the model's accuracy).
    """

    command: np.ndarray
    q: np.ndarray
    success: np.ndarray
    reason: np.ndarray
    pos_err_mm: np.ndarray
    ang_err_deg: np.ndarray
    shift_mm: np.ndarray
    shift_deg: np.ndarray
    in_support: np.ndarray
    q_branch: np.ndarray
    frame: str
    notes: list = field(default_factory=list)

    def __len__(self) -> int:
        return int(self.success.shape[0])


def fail_row(comp: Compensation, k: int, reason: str) -> None:
    """Row ``k`` of ``comp`` fails (in place) with ``reason``: no joints, command or errors (NaN), not in the
    support; what a check after solving does to a target it refuses."""
    comp.reason[k] = reason
    comp.success[k] = False
    for name in ("q", "command", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg"):
        getattr(comp, name)[k] = np.nan
    comp.in_support[k] = False


def merge_parts(parts: list[tuple[np.ndarray, Compensation]], n_rows: int) -> Compensation:
    """One :class:`Compensation` of ``n_rows`` targets from ``parts``: ``(row indices (k,), Compensation of
    those k rows)`` covering every row once (e.g. one part per payload)."""
    first = parts[0][1]
    out = {}
    for name in ("command", "q", "success", "reason", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg",
                 "in_support", "q_branch"):
        a = getattr(first, name)
        full = np.empty((n_rows, *a.shape[1:]), dtype=a.dtype)
        for idx, c in parts:
            full[idx] = getattr(c, name)
        out[name] = full
    return Compensation(frame=first.frame, notes=[t for _, c in parts for t in c.notes], **out)


def first_row_per_target(res) -> np.ndarray:
    """Row indices of a :class:`hykin.hybrid.ik_result.HybridIKResult`: one per target that has rows, its
    first successful row (else its first row), ordered by target."""
    order = np.lexsort((~res.success, res.target))
    return order[np.r_[True, res.target[order][1:] != res.target[order][:-1]]]


def command_rows(comp: Compensation, q_names: list[str] | None = None, joints_only: bool = False) -> dict:
    """CSV columns of a :class:`Compensation`: ``target, x,y,z,qw,qx,qy,qz`` (command, m), ``q1..qN``
    (rad), ``success``, ``pos_err_mm``, ``ang_err_deg``, ``shift_mm``, ``shift_deg``, ``in_support``,
    ``status``. ``joints_only``: ``target, q1..qN, success, pos_err_mm, ang_err_deg, status``."""
    N, n = comp.q.shape
    rows: dict = {"target": np.arange(N)}
    if not joints_only:
        xyz, quat = se3.transform_to_pose(np.where(np.isfinite(comp.command), comp.command, np.eye(4)))
        quat = np.where(comp.success[:, None], quat, np.nan)
        xyz = np.where(comp.success[:, None], xyz, np.nan)
        for k, c in enumerate("xyz"):
            rows[c] = xyz[:, k]
        for k, c in enumerate(("qw", "qx", "qy", "qz")):
            rows[c] = quat[:, k]
    for j in range(n):
        rows[(q_names or [f"q{i + 1}" for i in range(n)])[j]] = comp.q[:, j]
    rows["success"] = comp.success.astype(int)
    rows["pos_err_mm"] = comp.pos_err_mm
    rows["ang_err_deg"] = comp.ang_err_deg
    if not joints_only:
        rows["shift_mm"] = comp.shift_mm
        rows["shift_deg"] = comp.shift_deg
        rows["in_support"] = comp.in_support.astype(int)
    rows["status"] = np.where(comp.success, "ok", comp.reason)
    return rows


def edge_notes(comp: Compensation, tolerance_mm: float, tolerance_deg: float, accuracy_mm: float,
               names: list | None = None) -> list:
    """``[note]`` on the targets of ``comp`` compensated beyond the tolerances (mm, deg): accepted at the model's
    reach boundary, within its accuracy ``accuracy_mm``; ``[]`` for none. ``names``: how each row is named
    (e.g. a program's lines; default ``targets`` and the row indices)."""
    rows = np.flatnonzero(comp.success & ((comp.pos_err_mm > tolerance_mm) | (comp.ang_err_deg > tolerance_deg)))
    if not rows.size:
        return []
    said = [str(k) for k in rows] if names is None else [str(names[k]) for k in rows]
    kind = "targets" if names is None else "lines"
    return [f"{rows.size} targets ({kind} {', '.join(said[:8])}{' ...' if rows.size > 8 else ''}) lie at "
            f"the model's reach boundary (a stretched elbow, the workspace edge): compensated to the nearest pose its "
            f"robot reaches, {np.nanmax(comp.pos_err_mm[rows]):.3g} mm at most from the target (pos_err_mm), beyond "
            f"the tolerance {tolerance_mm:.3g} mm but within the model's own accuracy ({accuracy_mm:.3g} mm)"]
