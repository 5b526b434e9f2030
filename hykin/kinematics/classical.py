"""The classical part of the hybrid model: FK of the calibrated robot, with joint compliance.

Kept apart from :mod:`hykin.hybrid.model` so that code that needs only the calibrated classical
prediction (region-blocked validation, extrapolation growth, registration) does not import the model.
"""

from __future__ import annotations

import numpy as np

from .fk import fk, fk_torch
from .robot import Robot

__all__ = ["classical_fk", "classical_fk_torch"]


def classical_fk(robot: Robot, q: np.ndarray, payload_kg=None, payload_com_m=None) -> np.ndarray:
    """Classical prediction ``(N, 4, 4)``: FK of the (calibrated) robot, with joint compliance when
    the robot has finite stiffness. ``payload_kg`` / ``payload_com_m``: per-row payload
    (:func:`hykin.kinematics.compliance.gravity_torques`); default the robot's."""
    if robot.has_compliance:
        from .compliance import compliant_fk

        return compliant_fk(robot, q, payload_kg=payload_kg, payload_com_m=payload_com_m)
    return fk(robot, q)


def classical_fk_torch(robot: Robot, q, payload_kg=None, payload_com_m=None):
    """Differentiable twin of :func:`classical_fk` (float64 tensor ``(N, n)`` -> ``(N, 4, 4)``)."""
    if robot.has_compliance:
        from .compliance import compliant_fk_torch

        return compliant_fk_torch(robot, q, payload_kg=payload_kg, payload_com_m=payload_com_m)
    return fk_torch(robot, q)
