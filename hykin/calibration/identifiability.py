"""Identifiability: which calibration parameters the data can tell apart.

The identification Jacobian, each column scaled by its parameter's typical deviation (1 mm, 1 mrad,
1e-6 rad/N·m: :func:`hykin.calibration.params.scale_of`) and in priority order, is factorised by QR;
a column whose ``|R_kk|`` is a negligible fraction of its norm is explained by the columns before it.
"""

from __future__ import annotations

import numpy as np

from ..kinematics.robot import Robot
from .params import candidate_specs, scale_of

__all__ = ["identifiable_columns", "parameter_scales"]


def _identifiable(J_s: np.ndarray, rank_tol: float, negligible_tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Mask of identifiable columns of the scaled Jacobian (priority order) and the ratios |R_kk|/‖col‖."""
    norms = np.linalg.norm(J_s, axis=0)
    if J_s.shape[0] == 0 or not np.any(norms > 0):
        return np.zeros(J_s.shape[1], bool), np.zeros(J_s.shape[1])
    import torch

    R = torch.linalg.qr(torch.from_numpy(np.ascontiguousarray(J_s)), mode="r")[1].numpy()
    m = min(R.shape)
    rkk = np.zeros(J_s.shape[1])
    rkk[:m] = np.abs(np.diag(R[:m, :m]))
    ratio = np.where(norms > 0, rkk / np.where(norms > 0, norms, 1.0), 0.0)
    mask = (ratio > rank_tol) & (norms > negligible_tol * norms.max())
    return mask, ratio


def parameter_scales(robot: Robot, *, base: bool = True, tool: bool = True, compliance: bool = True) -> np.ndarray:
    """``(P,)`` typical deviation of each candidate parameter (:func:`parameter_names` order): the
    scaling :func:`calibrate` applies to the identification Jacobian (1 mm, 1 mrad, 1e-6 rad/N·m)."""
    return np.array([scale_of(s) for s in candidate_specs(robot, base=base, tool=tool, compliance=compliance)])


def identifiable_columns(J_scaled: np.ndarray, rank_tol: float = 1e-6, negligible_tol: float = 1e-9):
    """Identifiability test of :func:`calibrate` on a scaled Jacobian ``(rows, P)`` whose columns are
    in priority order: ``(mask (P,) bool, ratio |R_kk| / ‖column‖ (P,))``."""
    return _identifiable(np.asarray(J_scaled, dtype=np.float64), rank_tol, negligible_tol)
