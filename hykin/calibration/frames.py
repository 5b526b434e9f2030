"""Frames of a measurement set-up: the base and tool frames that map a model's poses onto measured ones
(``T_meas ≈ B · T_model · E``), and the choice of the few poses a new series is registered from.

Used by registration (:mod:`hykin.measure.register`), the rigid-frame import (``hykin import ipa
--register``), region-blocked validation (:mod:`hykin.hybrid.region_cv`) and evaluation (the
"nominal + rigid registration" reference of :func:`hykin.evaluation.evaluate.evaluate_model`).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ..geometry.se3 import make_transform, rotation_difference_rotvec, rotvec_to_matrix

__all__ = ["fit_frames", "fit_frames_solution", "pose_from_vector6", "select_representative", "select_spread"]


def select_spread(q: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    """Indices of ``n`` rows of ``q`` spread over joint space (greedy farthest-point sampling)."""
    q = np.asarray(q, dtype=np.float64)
    N = len(q)
    if n >= N:
        return np.arange(N)
    z = (q - q.mean(0)) / np.maximum(q.std(0), 1e-12)
    rng = np.random.default_rng(seed)
    idx = [int(rng.integers(N))]
    d = np.linalg.norm(z - z[idx[0]], axis=1)
    for _ in range(n - 1):
        k = int(np.argmax(d))
        idx.append(k)
        d = np.minimum(d, np.linalg.norm(z - z[k], axis=1))
    return np.array(sorted(idx))


def select_representative(T_meas: np.ndarray, n: int, seed: int = 0, position_only: bool = False) -> np.ndarray:
    """Indices of ``n`` representative rows of measured poses ``T_meas`` ``(N, 4, 4)``: k-means
    (scipy ``kmeans2``, k-means++ start, ``seed``) on z-scored features (position; plus the 9
    rotation-matrix entries unless ``position_only``), then the pose nearest each centre. Sorted,
    unique; fewer than ``n`` only if centres share a nearest pose (then topped up by farthest-point
    sampling in the same features)."""
    from scipy.cluster.vq import kmeans2

    T_meas = np.asarray(T_meas, dtype=np.float64)
    N = len(T_meas)
    if n >= N:
        return np.arange(N)
    X = T_meas[:, :3, 3] if position_only else np.concatenate([T_meas[:, :3, 3], T_meas[:, :3, :3].reshape(N, 9)], 1)
    z = (X - X.mean(0)) / np.maximum(X.std(0), 1e-12)
    cen, _ = kmeans2(z, n, seed=seed, minit="++")
    d2 = ((z[:, None, :] - cen[None, :, :]) ** 2).sum(-1) if N * n <= 4_000_000 else None
    if d2 is not None:
        idx = set(int(i) for i in np.argmin(d2, axis=0))
    else:
        idx = {int(np.argmin(((z - c) ** 2).sum(1))) for c in cen}
    if len(idx) < n:  # top up with the poses farthest from those chosen
        d = np.min(np.linalg.norm(z[:, None, :] - z[sorted(idx)][None], axis=-1), axis=1)
        while len(idx) < n:
            k = int(np.argmax(d))
            idx.add(k)
            d = np.minimum(d, np.linalg.norm(z - z[k], axis=1))
    return np.array(sorted(idx))


def pose_from_vector6(x: np.ndarray) -> np.ndarray:
    """``(4, 4)`` pose of a 6-vector ``[rotation vector (rad, 3), translation (m, 3)]``."""
    return make_transform(rotvec_to_matrix(x[:3]), x[3:6])


def fit_frames(
    T_model: np.ndarray, T_meas: np.ndarray, position_only: bool = False, orientation_weight_m_per_rad: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares ``B, E`` with ``T_meas ≈ B · T_model · E``; returns ``(B (4,4), E (4,4))``.

    Initialisation (so large frame changes, e.g. a tool turned 120°, converge): Kabsch fit of the
    positions for B's rotation, chordal mean of ``(B R_model)ᵀ R_meas`` for E's rotation, then the
    translations of B and E by linear least squares; three rounds. With ``position_only`` only E's
    translation is fitted (its rotation is not observable from positions).
    """
    B, E, _ = fit_frames_solution(T_model, T_meas, position_only, orientation_weight_m_per_rad)
    return B, E


def fit_frames_solution(T_model, T_meas, position_only=False, orientation_weight_m_per_rad=1.0):
    """:func:`fit_frames` that also returns the scipy ``least_squares`` solution: ``(B, E, sol)``
    (``sol.x`` = ``[B rotvec, B xyz, E rotvec, E xyz]``, rad and m)."""
    from scipy.spatial.transform import Rotation

    from ..geometry.rigid import kabsch

    T_model = np.asarray(T_model, dtype=np.float64)
    T_meas = np.asarray(T_meas, dtype=np.float64)
    pm, Rm, pz, Rz = T_model[:, :3, 3], T_model[:, :3, :3], T_meas[:, :3, 3], T_meas[:, :3, :3]
    te = np.zeros(3)
    RE = np.eye(3)
    for _ in range(3):
        RB = kabsch(pm + Rm @ te, pz)[0]
        if not position_only:
            RE = Rotation.from_matrix(np.einsum("nji,kj,nkl->nil", Rm, RB, Rz)).mean().as_matrix()
        A = np.concatenate([np.broadcast_to(np.eye(3), (len(pm), 3, 3)), np.einsum("ij,njk->nik", RB, Rm)], 2)
        sol_t = np.linalg.lstsq(A.reshape(-1, 6), (pz - pm @ RB.T).ravel(), rcond=None)[0]
        tb, te = sol_t[:3], sol_t[3:]
    x0 = np.concatenate([rotation_difference_rotvec(RB, np.eye(3)), tb, rotation_difference_rotvec(RE, np.eye(3)), te])
    w = orientation_weight_m_per_rad

    def resid(x):
        B = pose_from_vector6(x[:6])
        E = pose_from_vector6(np.concatenate([np.zeros(3) if position_only else x[6:9], x[9:12]]))
        T = B @ T_model @ E
        r = [(T[:, :3, 3] - T_meas[:, :3, 3]).ravel()]
        if not position_only:
            r.append(w * rotation_difference_rotvec(T[:, :3, :3], T_meas[:, :3, :3]).ravel())
        return np.concatenate(r)

    sol = least_squares(resid, x0, method="lm" if len(T_model) * 3 >= 12 else "trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    x = sol.x
    B = pose_from_vector6(x[:6])
    E = pose_from_vector6(np.concatenate([np.zeros(3) if position_only else x[6:9], x[9:12]]))
    return B, E, sol
