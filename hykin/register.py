"""Registration of a new measurement series to an existing hybrid model.

When the tracker is moved or the tool is changed, the robot's own error model (calibrated joints,
compliance, residual networks) stays valid; only the rigid frames around it change. A new series
is registered by fitting two rigid transforms, ``T_meas ≈ B · T_model(q) · E`` (B: measurement
frame -> old world frame, E: old TCP -> new TCP), from a few of its poses, without retraining.

Which poses: :func:`select_representative` (default of :func:`register_model`) clusters the
series' measured poses (k-means on z-scored position and rotation-matrix columns) and takes the
pose nearest each centre: spread over the workspace but typical, not extreme. Measured on UR10
series B against a model trained on series A (benchmarks/bench_real.py), 30 poses chosen this way
leave 3-8 % more mean position error than a registration from all 1495 poses (4 seeds), against
15-24 % for farthest-point sampling in joint space (:func:`select_spread`, which picks the extreme
configurations where the model is least accurate) and 3-10 % for random choice.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .dataset import Dataset
from .se3 import make_transform, pose_error, rotation_difference_rotvec, rotvec_to_matrix

__all__ = ["RegistrationInfo", "fit_frames", "select_spread", "select_representative", "register_model"]


@dataclass
class RegistrationInfo:
    """What a registration did and how well: errors on the poses used and on the rest of the series."""

    n_used: int
    n_total: int
    frame_pre: np.ndarray
    frame_post: np.ndarray
    used_pos_mean_mm: float
    used_ang_mean_deg: float | None
    rest_pos_mean_mm: float | None
    rest_ang_mean_deg: float | None
    used_index: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, int))
    converged: bool = True  # least-squares solver reached a tolerance (scipy status > 0)
    message: str = ""  # solver message
    nfev: int = 0  # residual evaluations
    n_fade_swapped: int = 0  # selected poses in the model's fade zone (0 < w < 1) replaced by trusted neighbours

    def summary(self) -> str:
        ang = lambda v: "" if v is None else f", {v:.4f} deg"  # noqa: E731
        s = (
            f"registered from {self.n_used} of {self.n_total} poses: "
            f"{self.used_pos_mean_mm:.4f} mm{ang(self.used_ang_mean_deg)} mean on those poses"
        )
        if self.rest_pos_mean_mm is not None:
            s += f"; {self.rest_pos_mean_mm:.4f} mm{ang(self.rest_ang_mean_deg)} mean on the other {self.n_total - self.n_used}"
        if self.n_fade_swapped:
            s += f" ({self.n_fade_swapped} selected poses in the fade zone of the network correction replaced by their nearest validated neighbours)"
        if not self.converged:
            s += f" (WARNING: solver did not converge: {self.message})"
        return s


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


def _pose6(x: np.ndarray) -> np.ndarray:
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
    B, E, _ = _fit_frames(T_model, T_meas, position_only, orientation_weight_m_per_rad)
    return B, E


def _fit_frames(T_model, T_meas, position_only=False, orientation_weight_m_per_rad=1.0):
    """Worker of :func:`fit_frames`; also returns the scipy solution."""
    from scipy.spatial.transform import Rotation

    from .referencing import kabsch

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
        B = _pose6(x[:6])
        E = _pose6(np.concatenate([np.zeros(3) if position_only else x[6:9], x[9:12]]))
        T = B @ T_model @ E
        r = [(T[:, :3, 3] - T_meas[:, :3, 3]).ravel()]
        if not position_only:
            r.append(w * rotation_difference_rotvec(T[:, :3, :3], T_meas[:, :3, :3]).ravel())
        return np.concatenate(r)

    sol = least_squares(resid, x0, method="lm" if len(T_model) * 3 >= 12 else "trf", xtol=1e-15, ftol=1e-15, gtol=1e-15)
    x = sol.x
    B = _pose6(x[:6])
    E = _pose6(np.concatenate([np.zeros(3) if position_only else x[6:9], x[9:12]]))
    return B, E, sol


def _avoid_fade_zone(model, q: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, int]:
    """Replace the selected rows ``idx`` that lie in ``model``'s fade zone (0 < w < 1) by the nearest
    (joint space) unselected rows outside it; returns ``(idx, number replaced)``."""
    if getattr(model, "fade", False) is False or not hasattr(model, "fade_weight"):
        return idx, 0
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wf = np.asarray(model.fade_weight(q))
    ok = (wf == 0.0) | (wf == 1.0)
    bad = idx[~ok[idx]]
    free = np.setdiff1d(np.flatnonzero(ok), idx)
    if bad.size == 0 or free.size < bad.size:
        return idx, 0
    keep = list(idx[ok[idx]])
    for b in bad:
        j = int(np.argmin(np.linalg.norm(q[free] - q[b], axis=1)))
        keep.append(int(free[j]))
        free = np.delete(free, j)
    return np.sort(np.asarray(keep, dtype=np.int64)), int(bad.size)


def register_model(model, series: Dataset, n_poses: int = 30, seed: int = 0, select: str = "representative"):
    """Register ``series`` to ``model`` from ``n_poses`` poses; returns ``(new_model, info)``.

    ``select``: ``"representative"`` (:func:`select_representative` on the measured poses, default)
    or ``"spread"`` (:func:`select_spread`, farthest-point in joint space).

    The returned model is a copy whose ``frame_pre``/``frame_post`` carry the new frames; the
    networks and calibrated parameters are untouched. Poses are chosen where the model is validated:
    inside the networks' training support (fade weight 1) or beyond the fade (weight 0, the calibrated
    model); a selected pose in between, where the correction is only partly applied and unvalidated,
    is replaced by its nearest validated neighbour in joint space (on UR10 series B, two such poses
    among 30 made the orientation error 9 % worse than calibration alone in one joint region).
    The registered model fades its correction with the nearest-neighbour gap too (``fade="full"``,
    unless the model's fade was off or ``"range"``): a new series samples the joint box differently
    from the training one, and on UR10 series B (random poses, model trained on series A's grid) 35
    poses inside the pairwise grids but far from every training pose were 11 % (position) / 20 %
    (orientation) worse than calibration alone with the default fade. ``info`` reports the error on the poses used
    and on the rest of the series (an honest check of the registration).
    """
    if n_poses < 3:
        raise ValueError(f"register: need at least 3 poses, got {n_poses}")
    if len(series) < 3:
        raise ValueError(f"{series.source}: a series needs at least 3 poses to register, got {len(series)}")
    pos_only = not series.has_orientation
    if select not in ("representative", "spread"):
        raise ValueError(f"register: select must be 'representative' or 'spread', got {select!r}")
    if select == "spread":
        idx = select_spread(series.q, n_poses, seed)
    else:
        idx = select_representative(series.poses(), n_poses, seed, position_only=pos_only)
    new = copy.deepcopy(model)
    new.frame_pre = np.eye(4)
    new.frame_post = np.eye(4)
    if getattr(new, "fade", False) in (True, "support"):
        new.fade = "full"
    idx, n_swapped = _avoid_fade_zone(new, series.q, idx)
    from .thermal import temperature_of

    from .payload import payload_kwargs, payload_of

    T_model = new.predict(series.q, temperature_c=temperature_of(series), **payload_kwargs(payload_of(series)))
    T_meas = series.poses()
    B, E, sol = _fit_frames(T_model[idx], T_meas[idx], position_only=pos_only)
    new.frame_pre, new.frame_post = B, E
    T_reg = B @ T_model @ E
    p, a = pose_error(T_reg, T_meas)
    rest = np.setdiff1d(np.arange(len(series)), idx)
    info = RegistrationInfo(
        n_used=len(idx),
        n_total=len(series),
        frame_pre=B,
        frame_post=E,
        used_pos_mean_mm=float(p[idx].mean()),
        used_ang_mean_deg=None if pos_only else float(a[idx].mean()),
        rest_pos_mean_mm=float(p[rest].mean()) if len(rest) else None,
        rest_ang_mean_deg=None if pos_only or not len(rest) else float(a[rest].mean()),
        used_index=idx,
        converged=bool(sol.status > 0),
        message=str(sol.message),
        nfev=int(sol.nfev),
        n_fade_swapped=n_swapped,
    )
    return new, info
