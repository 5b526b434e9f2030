"""Frames of compensation targets (:mod:`hykin.compensation.targets` explains them): ``"measurement"``,
``"base"``, ``"auto"``; and the parsing of target arrays."""

from __future__ import annotations

import numpy as np

from ..geometry import se3

__all__ = ["FRAMES", "fitted_base", "other_frame", "parse_targets", "resolve_frame", "to_model_frame"]

FRAMES = ("measurement", "base", "auto")
_AUTO_M, _AUTO_RAD = 0.05, np.radians(5.0)


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


def other_frame(frame: str) -> tuple[str, str]:
    """The resolved frame that is not ``frame`` (``"measurement"`` / ``"base"``), and its words for a
    message: targets that fail in one are usually given in the other."""
    return ("measurement", "the model's measurement frame") if frame == "base" else ("base", "the controller's base frame")


def to_model_frame(model, T: np.ndarray, frame: str) -> np.ndarray:
    """Targets ``(N, 4, 4)`` in ``frame`` -> the model's measurement frame."""
    return fitted_base(model) @ T if resolve_frame(model, frame) == "base" else T


def parse_targets(T_target) -> tuple[np.ndarray, bool]:
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
