"""Small helpers shared by several test modules (not a test module): free TCP ports, sweep/fleet
datasets and files."""

from __future__ import annotations

import socket

import numpy as np

from hykin.geometry.se3 import rotvec_to_matrix
from hykin.io.dataset import Dataset
from hykin.kinematics.fk import fk


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def residual_data(robot, n: int, seed: int) -> Dataset:
    """Poses with a smooth residual the classical model cannot express (so calibration leaves > 0.01 mm)."""
    q = robot.random_joints(n, seed, margin=0.1)
    T = fk(robot, q)
    T[:, :3, 3] += 2e-4 * np.stack([np.sin(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 2] + q[:, 1])], 1)
    T[:, :3, :3] = rotvec_to_matrix(1e-4 * np.stack([np.cos(q[:, 0]), np.sin(q[:, 3]), 0.5 * q[:, 1]], 1)) @ T[:, :3, :3]
    return Dataset.from_poses(q, T, orientation=True)


def write_text(path, text: str):
    """Write ``text`` (UTF-8) to ``path``; returns ``path``."""
    path.write_text(text, encoding="utf-8")
    return path
