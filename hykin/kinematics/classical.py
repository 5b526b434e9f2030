"""The classical part of the hybrid model: FK of the calibrated robot, with joint compliance.

Kept apart from :mod:`hykin.hybrid.model` so that code that needs only the calibrated classical
prediction (region-blocked validation, extrapolation growth, registration) does not import the model.
"""

from __future__ import annotations

import numpy as np

from .fk import fk, fk_torch
from .robot import Robot

__all__ = ["ClassicalModel", "classical_fk", "classical_fk_torch"]


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


class ClassicalModel:
    """A robot (file) as a model: ``predict(q)`` is :func:`classical_fk`, with the robot's joint
    compliance under ``payload_kg`` / ``payload_com_m`` (default the robot's payload). What the hybrid
    IK solver (:func:`hykin.hybrid.ik.hybrid_ik`) needs to solve a calibrated robot file with
    stiffness exactly: the rigid closed form only seeds it."""

    def __init__(self, robot: Robot, payload_kg=None, payload_com_m=None):
        self.robot = self.robot_ = self.nominal = robot
        self.payload_kg, self.payload_com_m = payload_kg, payload_com_m

    def predict(self, q, temperature_c=None) -> np.ndarray:
        """TCP poses ``(N, 4, 4)`` m of joints ``q`` ``(N, n)``; ``temperature_c`` is not modelled."""
        return classical_fk(self.robot, np.asarray(q, dtype=np.float64), self.payload_kg, self.payload_com_m)
