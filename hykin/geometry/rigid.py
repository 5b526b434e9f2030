"""The rigid (optionally weighted, optionally scaled) fit of corresponding point sets — the one used
across hykin (referencing, raw-frame start of a calibration, stream alignment, registration).

* :func:`umeyama` — the unchecked core, batched: ``Q ≈ s R P + t`` minimising
  ``Σ w_i |Q_i − (s R P_i + t)|²`` (Umeyama 1991), ``R`` a proper rotation (never a reflection).
* :func:`nearest_rotation` — the proper rotation nearest (Frobenius) to a matrix (SVD projection).
* :func:`kabsch` / :func:`register_points` — checked single-set fits, the latter with residuals and
  first-order uncertainty (:class:`Registration`); :func:`pose_from_three_points` — batched poses of
  a tool carrying three reflectors (SMRs).

Degenerate input (too few points, collinear or coincident points) raises
:class:`~hykin.geometry.lsq.ReferencingError` in the checked functions. Float64, metres, radians.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .lsq import ReferencingError, as_points, as_weights, lsq_covariance
from .se3 import make_transform

__all__ = [
    "Registration",
    "degenerate_point_sets",
    "kabsch",
    "nearest_rotation",
    "pose_from_three_points",
    "register_points",
    "rigid_residual_jacobian",
    "umeyama",
]


def _svd_rotation(M: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(R, D, E)`` for ``M`` ``(B, 3, 3)``: ``R = U diag(E) Vᵀ`` the proper rotation nearest to ``M``,
    ``D`` ``(B, 3)`` its singular values, ``E`` ``(B, 3)`` = (1, 1, ±1) the sign fix against a reflection."""
    U, D, Vt = np.linalg.svd(M)
    sgn = np.sign(np.linalg.det(U) * np.linalg.det(Vt))
    sgn[sgn == 0] = 1.0
    E = np.ones((len(M), 3))
    E[:, 2] = sgn
    return np.einsum("bij,bj,bjk->bik", U, E, Vt), D, E


def nearest_rotation(M) -> np.ndarray:
    """The proper rotation (``det = +1``) nearest in Frobenius norm to ``M`` ``(3, 3)`` or ``(B, 3, 3)``."""
    M = np.asarray(M, dtype=np.float64)
    R, _, _ = _svd_rotation(M.reshape(-1, 3, 3))
    return R.reshape(M.shape)


def umeyama(P, Q, w=None, scale: bool = False):
    """Best rigid (or similarity) map ``Q ≈ s R P + t``, without input checks.

    P, Q: ``(N, 3)`` or batched ``(B, N, 3)`` corresponding points; w: weights ``(N,)`` / ``(B, N)``
    summing to 1 per set (None: uniform). Returns ``R`` ``([B,] 3, 3)``, ``t`` ``([B,] 3)`` and
    ``s`` ``([B])`` (ones without ``scale``). Collinear sets give an arbitrary rotation about their
    line: check with :func:`degenerate_point_sets` where that matters.
    """
    P = np.asarray(P, dtype=np.float64)
    Q = np.asarray(Q, dtype=np.float64)
    single = P.ndim == 2
    if single:
        P, Q = P[None], Q[None]
    w = np.full(P.shape[:2], 1.0 / P.shape[1]) if w is None else np.asarray(w, dtype=np.float64).reshape(P.shape[:2])
    mp = np.einsum("bn,bni->bi", w, P)
    mq = np.einsum("bn,bni->bi", w, Q)
    Pc = P - mp[:, None]
    Qc = Q - mq[:, None]
    S = np.einsum("bn,bni,bnj->bij", w, Qc, Pc)  # cross-covariance q p^T
    R, D, E = _svd_rotation(S)
    if scale:
        var_p = np.einsum("bn,bni,bni->b", w, Pc, Pc)
        s = (D * E).sum(1) / var_p
    else:
        s = np.ones(len(P))
    t = mq - s[:, None] * np.einsum("bij,bj->bi", R, mp)
    return (R[0], t[0], s[0]) if single else (R, t, s)


def degenerate_point_sets(X, w, tol: float = 1e-9) -> np.ndarray:
    """``(B,)`` mask of point sets ``X`` ``(B, N, 3)`` that are collinear or coincident under weights
    ``w`` ``(B, N)`` (second singular value of the weighted centred set below ``tol`` times the first)."""
    m = np.einsum("bn,bni->bi", w, X)
    Xc = (X - m[:, None]) * np.sqrt(w)[..., None]
    s = np.linalg.svd(Xc, compute_uv=False)
    return (s[:, 0] == 0) | (s[:, 1] < tol * s[:, 0])


def kabsch(P, Q, weights=None, scale: bool = False):
    """Best rigid (or similarity) map of points ``P`` onto ``Q``: ``Q ≈ s R P + t``.

    ``P``, ``Q``: ``(N, 3)`` corresponding points, ``N >= 3`` and not collinear; ``weights`` ``(N,)``.
    Minimises ``Σ w_i |Q_i − (s R P_i + t)|²`` (Umeyama 1991). ``R`` is always a proper rotation
    (``det = +1``): if the best orthogonal map is a reflection, the closest rotation is returned.
    Returns ``(R (3, 3), t (3,))``, or ``(R, t, s)`` with ``scale=True``.
    """
    P = as_points(P, "kabsch: P", 3)
    Q = as_points(Q, "kabsch: Q", 3)
    if P.shape != Q.shape:
        raise ReferencingError(f"kabsch: P has shape {P.shape} but Q has {Q.shape}")
    w = as_weights(weights, len(P), "kabsch")
    w = (w / w.sum())[None]
    if degenerate_point_sets(P[None], w)[0]:
        raise ReferencingError("kabsch: P points are collinear or coincident; the rotation is undefined")
    if degenerate_point_sets(Q[None], w)[0]:
        raise ReferencingError("kabsch: Q points are collinear or coincident; the rotation is undefined")
    R, t, s = umeyama(P[None], Q[None], w, scale)
    return (R[0], t[0], float(s[0])) if scale else (R[0], t[0])


def rigid_residual_jacobian(y: np.ndarray, n_params: int = 6) -> np.ndarray:
    """Jacobian ``(N, 3, n_params)`` of the residuals ``Q − (exp(δθ) y + t + δt)`` with respect to
    ``(δt (m), δθ (rad))`` (columns 0–5) at ``δ = 0``; ``y`` ``(N, 3)`` = the mapped points ``s R P``.
    Columns from 6 on are left zero for the caller's further parameters (scale, clock, ...)."""
    J = np.zeros((len(y), 3, n_params))
    J[:, :, :3] = -np.eye(3)
    # d(exp(dθ) y)/dθ = -[y]x  -> residual derivative +[y]x
    J[:, 0, 4], J[:, 0, 5] = y[:, 2], -y[:, 1]
    J[:, 1, 3], J[:, 1, 5] = -y[:, 2], y[:, 0]
    J[:, 2, 3], J[:, 2, 4] = y[:, 1], -y[:, 0]
    return J


@dataclass(frozen=True)
class Registration:
    """Result of :func:`register_points`: ``Q ≈ scale · R P + t`` with ``T = [R, t]``.

    residuals_m ``(N, 3)`` = ``Q − (s R P + t)``; rms_m = RMS point distance. cov: covariance of
    ``(δt (3, m), δθ (3, rad)[, δs])`` with ``R_true ≈ exp(δθ) R`` (θ in Q's frame); std_trans_m and
    std_rot_rad ``(3,)`` are the roots of its diagonal; scale_std is 0 without scale.
    """

    T: np.ndarray
    scale: float
    residuals_m: np.ndarray
    rms_m: float
    cov: np.ndarray
    std_trans_m: np.ndarray
    std_rot_rad: np.ndarray
    scale_std: float

    def apply(self, points) -> np.ndarray:
        """Map points ``(..., 3)`` from P's frame to Q's frame."""
        p = np.asarray(points, dtype=np.float64)
        return self.scale * p @ self.T[:3, :3].T + self.T[:3, 3]


def register_points(P, Q, weights=None, scale: bool = False) -> Registration:
    """Register ``P`` onto ``Q`` (see :func:`kabsch`) and report residuals and uncertainty.

    The covariance is ``s² (JᵀWJ)⁻¹`` with ``s²`` the weighted residual variance over ``3N − k``
    degrees of freedom (``k`` = 6 or 7), weights relative (e.g. inverse variances up to a factor).
    Needs ``N >= 3`` (N = 3 without scale leaves 3 degrees of freedom).
    """
    out = kabsch(P, Q, weights, scale)
    R, t = out[0], out[1]
    s = out[2] if scale else 1.0
    P = np.asarray(P, dtype=np.float64)
    Q = np.asarray(Q, dtype=np.float64)
    w = as_weights(weights, len(P), "register_points")
    y = s * P @ R.T
    res = Q - (y + t)
    k = 7 if scale else 6
    N = len(P)
    J = rigid_residual_jacobian(y, k)
    if scale:
        J[:, :, 6] = -(P @ R.T)
    sw = np.sqrt(w)
    Jw = (J * sw[:, None, None]).reshape(3 * N, k)
    rw = (res * sw[:, None]).ravel()
    if 3 * N > k:
        cov, _ = lsq_covariance(Jw, rw, k, "register_points")
    else:
        cov = np.zeros((k, k))
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    return Registration(T=make_transform(R, t), scale=float(s), residuals_m=res,
                        rms_m=float(np.sqrt(np.mean(np.sum(res * res, 1)))), cov=cov,
                        std_trans_m=d[:3], std_rot_rad=d[3:6], scale_std=float(d[6]) if scale else 0.0)


def pose_from_three_points(p1, p2, p3, nest, return_residual: bool = False):
    """Poses of a tool carrying three SMRs, batched.

    ``p1, p2, p3``: measured SMR positions ``(N, 3)`` (or ``(3,)``) in tracker coordinates (m);
    ``nest``: ``(3, 3)`` rows = the same three SMR positions in the tool frame (m), not collinear.
    Returns ``T`` ``(N, 4, 4)`` (tool frame -> tracker, the least-squares rigid fit of the nests onto
    the measurements), and with ``return_residual=True`` also the RMS residual per pose ``(N,)`` (m),
    which reveals a swapped or mis-measured reflector.
    """
    nest = np.asarray(nest, dtype=np.float64)
    if nest.shape != (3, 3) or not np.isfinite(nest).all():
        raise ReferencingError(f"pose_from_three_points: nest must be a finite (3, 3) array (rows = SMRs), got {nest.shape}")
    M = np.stack([np.atleast_2d(np.asarray(p, dtype=np.float64)) for p in (p1, p2, p3)], axis=1)  # (N, 3, 3)
    if M.ndim != 3 or M.shape[2] != 3:
        raise ReferencingError(f"pose_from_three_points: p1, p2, p3 must be (N, 3) arrays of equal length, got {M.shape}")
    bad = ~np.isfinite(M).all(axis=(1, 2))
    if bad.any():
        raise ReferencingError(f"pose_from_three_points: non-finite measurement in row(s) {np.flatnonzero(bad)[:10].tolist()}")
    N = len(M)
    w = np.full((N, 3), 1.0 / 3.0)
    if degenerate_point_sets(nest[None], w[:1])[0]:
        raise ReferencingError("pose_from_three_points: the three nest positions are collinear")
    deg = degenerate_point_sets(M, w)
    if deg.any():
        raise ReferencingError(f"pose_from_three_points: measured SMRs collinear in row(s) {np.flatnonzero(deg)[:10].tolist()}")
    P = np.broadcast_to(nest, (N, 3, 3))
    R, t, _ = umeyama(P, M, w)
    T = make_transform(R, t)
    if not return_residual:
        return T
    r = M - (np.einsum("bij,bnj->bni", R, P) + t[:, None])
    return T, np.sqrt(np.mean(np.sum(r * r, -1), -1))
