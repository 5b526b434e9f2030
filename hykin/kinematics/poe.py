"""Product-of-exponentials (POE) model of a 6R robot and its closed-form family.

The robot at ``q = 0`` in the *world* frame: unit axis ``h_i`` and a point ``p_i`` on each joint axis
plus the zero-pose TCP ``T0``, so that ``T(q) = e_1(q_1) ··· e_6(q_6) · T0``. Convention free (DH,
MDH, URDF, base and tool, offsets and axis signs are absorbed). :func:`poe_model` extracts it from
the joint frames of :func:`hykin.kinematics.fk.fk_frames`, classifies it (``"opw"``, ``"ur"`` or
``None``, see :mod:`hykin.kinematics.ik_closed_form`) and verifies it against FK on random joints.
Lengths in m, angles in rad.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fk import fk, fk_frames
from .ik_subproblems import rotmat
from .robot import Robot

__all__ = ["POEModel", "poe_fk", "poe_model"]


@dataclass
class POEModel:
    """Product-of-exponentials model of a 6R robot at ``q = 0``, world frame.

    h: ``(6, 3)`` unit joint axes; p: ``(6, 3)`` a point on each axis (m); T0: ``(4, 4)`` TCP pose at
    ``q = 0``; family: ``"opw"``, ``"ur"`` or ``None``; wc: ``(3,)`` wrist centre (``opw``) or the
    intersection of axes 5 and 6 (``ur``), NaN otherwise; reason: why no family fits (or "").
    """

    h: np.ndarray
    p: np.ndarray
    T0: np.ndarray
    family: str | None
    wc: np.ndarray
    reason: str = ""


def _parallel(a, b, tol):
    """Unit vectors ``a``, ``b`` parallel to ``tol`` (sine of the angle between them)."""
    return np.linalg.norm(np.cross(a, b)) < tol


def _line_point_lsq(h, p):
    """Point minimising the summed squared distance to lines (h_i, p_i); returns (point, max dist)."""
    A = np.zeros((3, 3))
    rhs = np.zeros(3)
    for hi, pi in zip(h, p):
        P = np.eye(3) - np.outer(hi, hi)
        A += P
        rhs += P @ pi
    x = np.linalg.lstsq(A, rhs, rcond=None)[0]
    dist = max(np.linalg.norm((np.eye(3) - np.outer(hi, hi)) @ (x - pi)) for hi, pi in zip(h, p))
    return x, dist


def poe_model(robot: Robot, tol: float = 1e-9) -> POEModel:
    """Extract the POE model of ``robot`` and classify it (``family``); cached on the robot.

    ``tol``: tolerance on sines of angles between axes (rad) and on axis distances (m, relative to
    the robot size).
    """
    key = (_geometry_bytes(robot), float(tol))
    cached = getattr(robot, "_poe_cache", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    model = _poe_model(robot, tol)
    object.__setattr__(robot, "_poe_cache", (key, model))
    return model


def _geometry_bytes(robot: Robot) -> bytes:
    parts = [robot.a_m, robot.alpha_rad, robot.d_m, robot.theta_rad, robot.beta_rad, robot.origin_xyz_m,
             robot.origin_rpy_rad, robot.axis, robot.base, robot.tool, robot.lower, robot.upper]
    return (robot.convention + str(robot.joint_type)).encode() + b"".join(
        np.ascontiguousarray(p).tobytes() for p in parts)


def _poe_model(robot: Robot, tol: float) -> POEModel:
    nan3 = np.full(3, np.nan)
    if robot.n_chain != 6 or any(t != "revolute" for t in robot.joint_type):
        h = np.zeros((robot.dof, 3))
        return POEModel(h, h.copy(), np.eye(4), None, nan3, "closed form needs 6 revolute joints (no mimic joints)")
    fr = fk_frames(robot, np.zeros((1, 6)))
    h = fr.joint[0, :, :3, 2].copy()
    p = fr.joint[0, :, :3, 3].copy()
    T0 = fr.tcp[0].copy()
    scale = max(1.0, float(np.max(np.linalg.norm(p - p[0], axis=1))))
    ltol = tol * scale
    family, wc, reason = None, nan3, ""
    if _parallel(h[0], h[1], 1e-6):
        reason = "axis 1 is parallel to axis 2"
    elif not _parallel(h[1], h[2], tol):
        reason = "axes 2 and 3 are not parallel"
    else:
        x, dist = _line_point_lsq(h[3:], p[3:])
        par34 = _parallel(h[1], h[3], tol)
        if dist < ltol and not par34 and not _parallel(h[3], h[4], 1e-6) and not _parallel(h[4], h[5], 1e-6):
            family, wc = "opw", x
        elif par34:
            x56, d56 = _line_point_lsq(h[4:], p[4:])
            if _parallel(h[4], h[5], 1e-6) or d56 >= ltol:
                reason = "axes 2-4 parallel but axes 5 and 6 do not intersect"
            elif _parallel(h[1], h[4], 1e-6):
                reason = "axis 5 is parallel to axes 2-4"
            else:
                family, wc = "ur", x56
        else:
            reason = f"axes 4, 5, 6 do not meet in one point (miss {dist:.3g} m) and axis 4 is not parallel to 2, 3"
    model = POEModel(h, p, T0, family, wc, reason)
    if family is not None:  # numerical verification of the extracted model against FK
        rng = np.random.default_rng(0)
        q = robot.random_joints(64, rng)
        err = np.abs(poe_fk(model, q) - fk(robot, q)).max()
        if err > 1e-9 * scale:
            model.family, model.reason = None, f"POE model disagrees with FK by {err:.3g}"
    return model


def poe_fk(m: POEModel, q):
    """TCP poses ``(..., 4, 4)`` of POE model ``m`` for joints ``q`` ``(..., 6)`` (rad):
    ``e_1(q_1) ··· e_6(q_6) · T0``. Only used to verify an extracted model against :func:`fk`."""
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    for i in range(6):
        E = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
        R = rotmat(m.h[i], q[..., i])
        E[..., :3, :3] = R
        E[..., :3, 3] = m.p[i] - R @ m.p[i]
        T = T @ E
    return T @ m.T0
