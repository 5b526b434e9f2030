"""A robot file (nominal or written by ``hykin calibrate``) as a model that can be registered.

:func:`hykin.measure.register.register_model` works on what a model predicts; a calibrated-only robot
has no networks, no bands and no training metadata, so :class:`RobotModel` predicts its classical
FK (compliance and payload included) through the registration frames, and :meth:`RobotModel.to_robot`
folds the registered frames and joint zeros back into a robot (``base = frame_pre · base``,
``tool = tool · frame_post``) to be written as a robot file again.
"""

from __future__ import annotations

import numpy as np

from ..kinematics.classical import classical_fk
from ..kinematics.robot import Robot

__all__ = ["RobotModel"]


class RobotModel:
    """Classical model of ``robot`` with registration frames (the attributes register_model uses)."""

    fade = False
    net_pos_ = None
    unc_ = None
    thermal_ = None

    def __init__(self, robot: Robot):
        self.robot = robot  # nominal = itself: there is nothing else to fall back to
        self.robot_ = robot.copy()
        self.frame_pre_ = np.eye(4)
        self.frame_post_ = np.eye(4)
        self.meta_: dict = {}

    def predict(self, q, temperature_c=None, payload_kg=None, payload_com_m=None) -> np.ndarray:
        """Poses ``(N, 4, 4)`` (m) of joints ``q`` ``(N, n)``: ``frame_pre · FK(q) · frame_post``
        (``temperature_c`` is ignored: a robot file has no thermal coefficient)."""
        T = classical_fk(self.robot_, np.asarray(q, dtype=np.float64), payload_kg, payload_com_m)
        return self.frame_pre_ @ T @ self.frame_post_

    predict_classical = predict

    def to_robot(self) -> Robot:
        """The registered robot: frames folded into its base and tool, joint zeros as re-fitted."""
        return self.robot_.copy(base=self.frame_pre_ @ self.robot_.base, tool=self.robot_.tool @ self.frame_post_)
