"""Compensated targets (DESIGN.md §6): what to ask a controller running its nominal model for.

For each wanted TCP pose: hybrid IK on the branch the caller means (joints near ``q_branch``) gives
the joints ``q`` at which the *real* robot (as the model knows it) reaches the pose; the nominal
model's FK of ``q`` — in the nominal robot's base frame, with the nominal tool — is the command. A
controller that runs the nominal model and solves its own IK on that branch then lands at ``q``.

Frames (``frame``):

* ``"measurement"``: targets are in the model's measurement frame (the frame of its training data).
  For a model fitted on robot-frame data this is the controller's base frame, and errors of the
  robot's base are compensated too.
* ``"base"``: targets are in the controller's base frame, placed in the measurement frame by the
  model's *fitted* base (``frame_pre · robot_.base``): the choice for models fitted on tracker-frame
  data, where the measurement frame is arbitrary. The base's own error cannot be compensated then
  (it defines the frame); the arm's, the tool's and the networks' errors are.
* ``"auto"`` (:func:`resolve_frame`): ``"base"`` when the fitted base is over 50 mm or 5° from the
  nominal base (tracker-frame data), else ``"measurement"``.

Commands are always ``inv(nominal.base) · FK_nominal(q) · tool_delta`` (controller base frame).
``tool_delta`` (``(4, 4)`` or ``(N, 4, 4)``) is the program's TCP relative to the nominal tool
(URScript ``set_tcp``): the wanted pose is then of that TCP; the model's TCP target is
``T · inv(tool_delta)`` (the correction's rotation at the TCP is taken as the model's).

An unreachable target (no hybrid solution within the joint limits, or no nominal solution on the
meant branch) gets ``success = False``, a reason and NaN command/joints — never a made-up command.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..geometry import se3
from ..kinematics.fk import fk

__all__ = ["FRAMES", "Compensation", "compensate", "fitted_base", "resolve_frame", "to_model_frame"]

FRAMES = ("measurement", "base", "auto")
_AUTO_M, _AUTO_RAD = 0.05, np.radians(5.0)


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

    def __len__(self) -> int:
        return int(self.success.shape[0])


def fitted_base(model) -> np.ndarray:
    """``(4, 4)`` the model's controller base in its measurement frame: ``frame_pre · robot_.base``."""
    return np.asarray(model.frame_pre_, dtype=np.float64) @ model.robot_.base


def resolve_frame(model, frame: str) -> str:
    """``"measurement"`` or ``"base"`` for ``frame`` in :data:`FRAMES` (module docstring)."""
    if frame not in FRAMES:
        raise ValueError(f"frame must be one of {', '.join(FRAMES)}, got {frame!r}")
    if frame != "auto":
        return frame
    D = np.linalg.inv(model.nominal.base) @ fitted_base(model)
    far = np.linalg.norm(D[:3, 3]) > _AUTO_M or np.linalg.norm(se3.matrix_to_rotvec(D[:3, :3])) > _AUTO_RAD
    return "base" if far else "measurement"


def to_model_frame(model, T: np.ndarray, frame: str) -> np.ndarray:
    """Targets ``(N, 4, 4)`` in ``frame`` -> the model's measurement frame."""
    return fitted_base(model) @ T if resolve_frame(model, frame) == "base" else T


def _targets(T_target) -> tuple[np.ndarray, bool]:
    T = np.asarray(T_target, dtype=np.float64)
    if T.ndim == 2 and T.shape[1] == 3:
        P = np.tile(np.eye(4), (len(T), 1, 1))
        P[:, :3, 3] = T
        return P, True
    if T.ndim == 2 and T.shape == (4, 4):
        T = T[None]
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"targets must have shape (N, 4, 4) or (N, 3), got {np.shape(T_target)}")
    if not np.isfinite(T).all():
        bad = int(np.flatnonzero(~np.isfinite(T.reshape(len(T), -1)).all(1))[0])
        raise ValueError(f"target {bad} contains NaN or inf")
    return T, False


def first_row_per_target(res) -> np.ndarray:
    """Row indices of a :class:`hykin.hybrid.ik_result.HybridIKResult`: one per target that has rows, its
    first successful row (else its first row), ordered by target."""
    order = np.lexsort((~res.success, res.target))
    return order[np.r_[True, res.target[order][1:] != res.target[order][:-1]]]


def compensate(model, T_target, *, q_branch=None, frame: str = "measurement", position_only: bool = False,
               tool_delta=None, branch_reason: str = "no nominal solution on the requested branch",
               **ik_kw) -> Compensation:
    """Compensated commands for targets ``T_target`` ``(N, 4, 4)`` (or ``(N, 3)`` positions), m.

    ``q_branch`` ``(N, n)`` or ``(n,)``: joints choosing the branch (current joints, or the nominal
    solution the program means); NaN rows = no branch (the target fails with ``branch_reason``).
    Default: the nominal solution nearest the previous target's (:func:`sequential_nearest`).
    ``frame``, ``tool_delta``: module docstring. Other keywords go to :func:`hykin.hybrid.ik.hybrid_ik`.
    """
    from ..hybrid.ik import hybrid_ik
    from .branches import sequential_nearest

    T, pos_in = _targets(T_target)
    pos_only = bool(position_only or pos_in)
    frame = resolve_frame(model, frame)
    nom = model.nominal
    N, n = len(T), nom.dof
    D = np.broadcast_to(np.eye(4) if tool_delta is None else np.asarray(tool_delta, dtype=np.float64), (N, 4, 4))
    Tm = to_model_frame(model, T, frame) @ se3.invert(D) if tool_delta is not None else to_model_frame(model, T, frame)
    if q_branch is None:
        branch_reason = "unreachable: the nominal robot has no solution to choose the branch from"
        T_nom = (nom.base @ T if frame == "base" else T) @ se3.invert(D)  # the target in the nominal robot's world
        qb = sequential_nearest(nom, T_nom, None) if not pos_only else np.tile(np.clip(np.zeros(n), nom.lower, nom.upper), (N, 1))
    else:
        qb = np.array(np.broadcast_to(np.asarray(q_branch, dtype=np.float64), (N, n)))
    has = np.isfinite(qb).all(1)
    q = np.full((N, n), np.nan)
    pe = np.full(N, np.nan)
    ae = np.full(N, np.nan)
    ok = np.zeros(N, dtype=bool)
    sup = np.zeros(N, dtype=bool)
    reason = np.array([branch_reason] * N, dtype=object)
    idx = np.flatnonzero(has)
    if idx.size:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # out-of-support is reported per row (in_support)
            res = hybrid_ik(model, Tm[idx, :3, 3] if pos_only else Tm[idx], all_branches=False, q_current=qb[idx],
                            nearest=True, position_only=pos_only, **ik_kw)
        first = first_row_per_target(res)
        t = idx[res.target[first]]
        q[t], pe[t], ae[t] = res.q[first], res.pos_err_mm[first], res.ang_err_deg[first]
        ok[t], sup[t] = res.success[first], res.in_support[first]
        reason[t] = np.where(res.success[first], "", res.reason[first].astype(object))
        reason[t] = np.where(res.success[first] | (reason[t] != ""), reason[t], "unreachable")
    cmd = np.full((N, 4, 4), np.nan)
    if ok.any():
        cmd[ok] = se3.invert(nom.base) @ fk(nom, q[ok]) @ D[ok]
    q[~ok] = np.nan
    # how far the command moved the target, both in the controller frame
    T_ctrl = T if frame == "base" else se3.invert(nom.base) @ T
    dpos = np.linalg.norm(cmd[:, :3, 3] - T_ctrl[:, :3, 3], axis=1) * 1e3
    dang = np.full(N, np.nan)
    if ok.any() and not pos_only:
        dang[ok] = se3.pose_error(cmd[ok], T_ctrl[ok])[1]
    return Compensation(command=cmd, q=q, success=ok, reason=reason.astype(str), pos_err_mm=pe, ang_err_deg=ae,
                        shift_mm=dpos, shift_deg=dang, in_support=sup, q_branch=qb, frame=frame)


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
