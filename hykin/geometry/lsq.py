"""Shared pieces of the measurement fits (:mod:`hykin.measure.referencing`, :mod:`hykin.geometry.rigid`):
the error type, input validation of point sets and weights, and the first-order least-squares covariance.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ReferencingError", "as_points", "as_weights", "lsq_covariance"]


class ReferencingError(ValueError):
    """Degenerate or malformed input to a referencing function (too few points, collinear, ...)."""


def as_points(points, name: str, min_n: int) -> np.ndarray:
    """``points`` as a finite float64 ``(N, 3)`` array (m) with ``N >= min_n``; raises
    :class:`ReferencingError` naming ``name`` otherwise."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ReferencingError(f"{name}: expected an (N, 3) array of points in m, got shape {p.shape}")
    if p.shape[0] < min_n:
        raise ReferencingError(f"{name}: needs at least {min_n} points, got {p.shape[0]}")
    bad = ~np.isfinite(p).all(axis=1)
    if bad.any():
        raise ReferencingError(f"{name}: non-finite coordinates in row(s) {np.flatnonzero(bad)[:10].tolist()}")
    return p


def as_weights(weights, n: int, name: str) -> np.ndarray:
    """Relative weights ``(n,)`` (ones for None): finite, >= 0, not all zero; raises
    :class:`ReferencingError` naming ``name`` otherwise."""
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=np.float64).ravel()
    if w.shape != (n,):
        raise ReferencingError(f"{name}: weights must have shape ({n},), got {w.shape}")
    if not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
        raise ReferencingError(f"{name}: weights must be finite, >= 0 and not all zero")
    return w


def lsq_covariance(J: np.ndarray, r: np.ndarray, n_params: int, name: str) -> tuple[np.ndarray, float]:
    """First-order covariance ``s² (JᵀJ)⁻¹`` ``(k, k)`` of a least-squares solution and ``s²``.

    J: ``(M, k)`` residual Jacobian at the solution; r: ``(M,)`` residuals; ``s² = rᵀr / (M − n_params)``
    (0 without degrees of freedom). Assumes independent, equal-variance residuals.
    """
    dof = r.size - n_params
    s2 = float(r @ r / dof) if dof > 0 else 0.0
    JTJ = J.T @ J
    try:
        inv = np.linalg.inv(JTJ)
    except np.linalg.LinAlgError as e:  # pragma: no cover - guarded by collinearity checks
        raise ReferencingError(f"{name}: singular normal equations ({e})") from None
    return s2 * inv, s2
