"""What a calibration fits: joints, measured points and rotations from a dataset or arrays."""

from __future__ import annotations

import numpy as np

from ..geometry import se3
from ..kinematics.robot import Robot
from .result import CalibrationError

__all__ = ["calibration_inputs"]


def calibration_inputs(robot: Robot, data, position_only):
    """``(q (N, n) rad/m, xyz (N, 3) or (N, K, 3) m, R (N, 3, 3) or None)`` from a Dataset (or any object
    with ``q``, ``xyz_m``, ``quat_wxyz``) or a tuple ``(q, poses (N, 4, 4) | positions (N, 3))``; one-line
    :class:`CalibrationError` for shapes and non-finite rows."""
    if hasattr(data, "q") and hasattr(data, "xyz_m"):
        from ..io.reflectors import reflector_points

        q = np.asarray(data.q, dtype=np.float64)
        try:
            xyz = reflector_points(data)
        except ValueError as e:
            raise CalibrationError(str(e)) from None
        xyz = xyz[:, 0] if xyz.shape[1] == 1 else xyz
        quat = getattr(data, "quat_wxyz", None)
        R = None if quat is None else se3.quat_to_matrix(np.asarray(quat, dtype=np.float64))
    elif isinstance(data, (tuple, list)) and len(data) == 2:
        q = np.asarray(data[0], dtype=np.float64)
        P = np.asarray(data[1], dtype=np.float64)
        if P.ndim == 3 and P.shape[1:] == (4, 4):
            xyz, R = P[:, :3, 3].copy(), P[:, :3, :3].copy()
        elif P.ndim == 2 and P.shape[1] == 3 or P.ndim == 3 and P.shape[2] == 3 and P.shape[1] != 4:
            xyz, R = P, None
        else:
            raise CalibrationError(f"data: measured poses must be (N, 4, 4) or positions (N, 3), got {P.shape}")
    else:
        raise CalibrationError("data: expected a Dataset or a tuple (q (N, n), poses (N, 4, 4) | positions (N, 3))")
    if q.ndim != 2 or q.shape[1] != robot.dof:
        raise CalibrationError(f"data: joints must be (N, {robot.dof}) for robot {robot.name!r}, got {q.shape}")
    if xyz.shape[0] != q.shape[0] or xyz.shape[-1] != 3:
        raise CalibrationError(f"data: positions must be ({q.shape[0]}, 3) or ({q.shape[0]}, K, 3), got {xyz.shape}")
    for nm, arr in (("joints", q), ("positions", xyz)) + ((("orientations", R),) if R is not None else ()):
        bad = ~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)
        if bad.any():
            raise CalibrationError(f"data: row {int(np.argmax(bad)) + 1}: non-finite {nm}")
    if position_only is None:
        position_only = R is None
    if position_only:
        R = None
    elif R is None:
        raise CalibrationError("data: position_only=False but the data have no orientations")
    return np.ascontiguousarray(q), xyz, R
