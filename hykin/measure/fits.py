"""Geometry fits of tracker points (float64, metres and radians), each with a least-squares uncertainty.

* :func:`fit_plane` — plane through points (total least squares).
* :func:`fit_circle_3d` — circle in 3-D: plane fit, algebraic (Kåsa) circle in the plane, then a
  geometric fit (``scipy.optimize.least_squares``) of centre, normal and radius.
* :func:`axis_from_sweep` — a revolute joint's axis from the positions of a reflector (SMR) while
  that joint alone moves.

Uncertainties are first-order: ``cov = s² (JᵀJ)⁻¹`` with ``J`` the residual Jacobian at the
solution and ``s²`` the residual variance (sum of squared residuals / degrees of freedom), so they
assume independent, isotropic, equal-variance noise. Scalar ``*_std_rad`` / ``*_std_m`` values are
the root of the trace of the relevant covariance block, i.e. the RMS of the angle (or distance)
error vector one should expect.

Degenerate input (too few points, collinear points) raises :class:`~hykin.geometry.lsq.ReferencingError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from ..geometry.lsq import ReferencingError, as_points, as_weights, lsq_covariance

__all__ = ["AxisFit", "CircleFit", "PlaneFit", "axis_from_sweep", "fit_circle_3d", "fit_plane"]


# --------------------------------------------------------------------------- helpers


def _basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors ``u, v`` with ``(u, v, n)`` right-handed orthonormal."""
    n = n / np.linalg.norm(n)
    a = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _check_not_collinear(pc: np.ndarray, name: str, tol: float = 1e-9) -> None:
    s = np.linalg.svd(pc, compute_uv=False)
    if s[0] == 0 or s[1] < tol * s[0]:
        raise ReferencingError(f"{name}: points are (nearly) collinear or coincident; a plane/circle/frame is undefined")


# --------------------------------------------------------------------------- plane


@dataclass(frozen=True)
class PlaneFit:
    """Plane ``normal · (x − point) = 0``.

    normal: ``(3,)`` unit normal, sign chosen so that its largest-magnitude component is positive.
    point: ``(3,)`` weighted centroid of the points (m).
    rms_m: RMS (weighted) orthogonal distance of the points to the plane.
    normal_std_rad: RMS angular uncertainty of the normal (root of the trace of the tilt covariance).
    offset_std_m: standard deviation of the plane position along the normal at ``point``.
    cov: ``(3, 3)`` covariance of (tilt about ``-v`` i.e. toward ``u`` (rad), tilt toward ``v`` (rad),
    offset along the normal (m)), where ``basis = (u, v)``.
    """

    normal: np.ndarray
    point: np.ndarray
    rms_m: float
    normal_std_rad: float
    offset_std_m: float
    cov: np.ndarray
    basis: np.ndarray


def fit_plane(points, weights=None) -> PlaneFit:
    """Least-squares plane through ``points`` ``(N, 3)`` (m), ``N >= 3``, optional weights ``(N,)``.

    Total least squares (smallest singular vector of the weighted, centred points). Weights are
    relative (e.g. inverse variances up to a common factor); the noise level comes from the residuals.
    """
    p = as_points(points, "fit_plane", 3)
    w = as_weights(weights, len(p), "fit_plane")
    c = (w[:, None] * p).sum(0) / w.sum()
    d = p - c
    sw = np.sqrt(w)[:, None]
    _check_not_collinear(sw * d, "fit_plane")
    _, _, Vt = np.linalg.svd(sw * d, full_matrices=False)
    n = Vt[2]
    if n[np.argmax(np.abs(n))] < 0:
        n = -n
    u, v = _basis(n)
    r = d @ n
    J = np.stack([d @ u, d @ v, -np.ones(len(p))], axis=1) * sw
    cov, _ = lsq_covariance(J, r * sw[:, 0], 3, "fit_plane") if len(p) > 3 else (np.zeros((3, 3)), 0.0)
    rms = float(np.sqrt((w * r * r).sum() / w.sum()))
    return PlaneFit(n, c, rms, float(np.sqrt(cov[0, 0] + cov[1, 1])), float(np.sqrt(cov[2, 2])),
                    cov, np.stack([u, v]))


# --------------------------------------------------------------------------- circle


@dataclass(frozen=True)
class CircleFit:
    """Circle in 3-D.

    center: ``(3,)`` (m); normal: ``(3,)`` unit, right-handed with respect to the order of the points
    (the points run counter-clockwise seen from the tip of ``normal``); radius_m; rms_m: RMS of the
    geometric residuals (out-of-plane distance and radial deviation, two per point).
    center_std_m: RMS 3-D uncertainty of the centre; normal_std_rad: RMS angular uncertainty of the
    normal; radius_std_m.
    cov: ``(6, 6)`` covariance of ``(center x, y, z, tilt toward u, tilt toward v, radius)`` with
    ``basis = (u, v)`` perpendicular to ``normal``.
    """

    center: np.ndarray
    normal: np.ndarray
    radius_m: float
    rms_m: float
    center_std_m: float
    normal_std_rad: float
    radius_std_m: float
    cov: np.ndarray
    basis: np.ndarray


def _circle_residuals(x, p, n0, u0, v0):
    c, a, b, R = x[:3], x[3], x[4], x[5]
    m = n0 + a * u0 + b * v0
    nm = np.linalg.norm(m)
    n = m / nm
    d = p - c
    h = d @ n
    w = d - h[:, None] * n
    rho = np.linalg.norm(w, axis=1)
    return np.concatenate([h, rho - R]), (n, nm, d, h, w, rho)


def _circle_jac(x, p, n0, u0, v0):
    _, (n, nm, d, h, w, rho) = _circle_residuals(x, p, n0, u0, v0)
    P = (np.eye(3) - np.outer(n, n)) / nm
    dn_da, dn_db = P @ u0, P @ v0
    N = len(p)
    J = np.zeros((2 * N, 6))
    J[:N, :3] = -n
    J[:N, 3] = d @ dn_da
    J[:N, 4] = d @ dn_db
    rho_safe = np.where(rho > 0, rho, 1.0)
    J[N:, :3] = -w / rho_safe[:, None]
    J[N:, 3] = -h * J[:N, 3] / rho_safe
    J[N:, 4] = -h * J[:N, 4] / rho_safe
    J[N:, 5] = -1.0
    return J


def fit_circle_3d(points) -> CircleFit:
    """Fit a circle to ``points`` ``(N, 3)`` (m), ``N >= 4``, e.g. an SMR while one joint turns.

    Plane fit, then Kåsa's algebraic circle in the plane as a start, then the geometric fit
    minimising the out-of-plane distances and the radial deviations (``least_squares``, analytic
    Jacobian). An arc of any length works; a short arc gives large (and correctly reported)
    uncertainties.
    """
    p = as_points(points, "fit_circle_3d", 4)
    pl = fit_plane(p)
    n0 = pl.normal
    u0, v0 = pl.basis
    d = p - pl.point
    x2, y2 = d @ u0, d @ v0
    A = np.stack([x2, y2, np.ones_like(x2)], axis=1)
    bvec = -(x2**2 + y2**2)
    sol, *_ = np.linalg.lstsq(A, bvec, rcond=None)
    cx, cy = -sol[0] / 2, -sol[1] / 2
    R0 = np.sqrt(max(cx * cx + cy * cy - sol[2], 0.0))
    if not np.isfinite(R0) or R0 <= 0:
        raise ReferencingError("fit_circle_3d: points do not define a circle (zero radius)")
    c0 = pl.point + cx * u0 + cy * v0
    x0 = np.concatenate([c0, [0.0, 0.0, R0]])
    res = least_squares(lambda x: _circle_residuals(x, p, n0, u0, v0)[0], x0,
                        jac=lambda x: _circle_jac(x, p, n0, u0, v0), method="lm",
                        xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
    x = res.x
    m = n0 + x[3] * u0 + x[4] * v0
    n = m / np.linalg.norm(m)
    c = x[:3]
    # orientation from the traversal order (right-hand rule)
    dd = p - c
    turn = np.cross(dd[:-1], dd[1:]).sum(0) @ n
    if turn < 0:
        n = -n
    u, v = _basis(n)
    xf = np.concatenate([c, [0.0, 0.0, abs(x[5])]])
    r, _ = _circle_residuals(xf, p, n, u, v)
    J = _circle_jac(xf, p, n, u, v)
    cov, _ = lsq_covariance(J, r, 6, "fit_circle_3d")
    return CircleFit(
        center=c, normal=n, radius_m=float(abs(x[5])), rms_m=float(np.sqrt(np.mean(r * r))),
        center_std_m=float(np.sqrt(np.trace(cov[:3, :3]))),
        normal_std_rad=float(np.sqrt(cov[3, 3] + cov[4, 4])),
        radius_std_m=float(np.sqrt(cov[5, 5])), cov=cov, basis=np.stack([u, v]),
    )


# --------------------------------------------------------------------------- axes


@dataclass(frozen=True)
class AxisFit:
    """A revolute joint axis: the line ``point + s · direction``.

    direction: unit ``(3,)``, the positive rotation axis of the joint when the sweep points were
    given in increasing joint angle. point: the circle centre (m). std_dir_rad: RMS angular
    uncertainty of the direction; std_point_m: RMS uncertainty of the line's position perpendicular
    to it (the part of the centre's uncertainty that moves the line). rms_m: fit residual RMS.
    circle: the underlying :class:`CircleFit` (full covariance).
    """

    direction: np.ndarray
    point: np.ndarray
    std_dir_rad: float
    std_point_m: float
    rms_m: float
    radius_m: float
    circle: CircleFit


def axis_from_sweep(points) -> AxisFit:
    """Joint axis from SMR positions ``(N, 3)`` (m, N >= 4) recorded while one joint sweeps.

    Give the points in increasing joint angle: the direction then follows the joint's positive
    rotation (right-hand rule). The axis passes through the fitted circle centre along its normal.
    """
    c = fit_circle_3d(points)
    P = np.eye(3) - np.outer(c.normal, c.normal)
    std_pt = float(np.sqrt(np.trace(P @ c.cov[:3, :3] @ P)))
    return AxisFit(c.normal, c.center, c.normal_std_rad, std_pt, c.rms_m, c.radius_m, c)
