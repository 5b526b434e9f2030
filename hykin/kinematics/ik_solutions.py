"""IK targets and solutions: target parsing, pose residuals, joint-angle bookkeeping, result containers.

Shared by the closed-form solver (:mod:`hykin.kinematics.ik_closed_form`) and the numerical one
(:mod:`hykin.kinematics.ik`). Joints in rad (revolute) or m (prismatic), positions in m, float64.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "TWO_PI",
    "IKBranches",
    "IKResult",
    "IKSolutions",
    "as_targets",
    "mark_duplicates",
    "nearest_representation",
    "pose_residual",
    "wrap_angle",
    "wrap_to_limits",
]

TWO_PI = 2.0 * np.pi


def as_targets(T_world) -> tuple[np.ndarray, bool]:
    """Validated world TCP targets: ``(T (N, 4, 4) float64, single)``; ``single`` when one ``(4, 4)``
    was given. Raises ``ValueError`` on another shape or on NaN/inf entries."""
    T = np.asarray(T_world, dtype=np.float64)
    single = T.ndim == 2
    T = T.reshape(1, 4, 4) if single else T
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"targets must have shape (N, 4, 4) or (4, 4), got {np.shape(T_world)}")
    if not np.all(np.isfinite(T)):
        bad = int(np.argmax(~np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)))
        raise ValueError(f"target {bad} contains NaN or inf")
    return T, single


def pose_residual(T: np.ndarray, T_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error (m) and rotation angle of ``R R_t^T`` (rad, accurate near 0) between pose batches."""
    pe = np.linalg.norm(T[..., :3, 3] - T_t[..., :3, 3], axis=-1)
    M = T[..., :3, :3] @ np.swapaxes(T_t[..., :3, :3], -1, -2)
    s = 0.5 * np.sqrt(
        (M[..., 2, 1] - M[..., 1, 2]) ** 2 + (M[..., 0, 2] - M[..., 2, 0]) ** 2 + (M[..., 1, 0] - M[..., 0, 1]) ** 2
    )
    c = 0.5 * (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1.0)
    return pe, np.arctan2(s, c)


def wrap_angle(x):
    """Angles (rad) wrapped to ``[-π, π)``, elementwise."""
    return (x + np.pi) % TWO_PI - np.pi


def wrap_to_limits(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, revolute: np.ndarray | None = None):
    """Representation of each revolute joint angle ``q + 2πk`` nearest zero within ``[lower, upper]``.

    Joints with no representation in the limits keep their value wrapped to ``(-π, π]`` (and so stay
    outside the limits). ``q``: ``(..., n)``; returns a new array.
    """
    q = np.asarray(q, dtype=np.float64)
    rev = np.ones(q.shape[-1], bool) if revolute is None else np.asarray(revolute, bool)
    w = wrap_angle(q)
    k_lo = np.ceil((lower - w) / TWO_PI - 1e-12)
    k_hi = np.floor((upper - w) / TWO_PI + 1e-12)
    k0 = np.round(-w / TWO_PI)
    k = np.clip(k0, k_lo, k_hi)
    k = np.where(k_lo <= k_hi, k, 0.0)
    out = w + TWO_PI * k
    return np.where(rev, out, q)


#: rad: a solution this close beyond a joint limit counts as at the limit (and is clipped onto it). A
#: solution AT a limit comes back from IK a rounding beyond it, and at a singular limit (a UR elbow
#: stretched at q3 = ±360°: acos near 1) that rounding is ~1e-8 rad; 1e-7 rad moves the TCP < 0.2 µm.
LIMIT_SLACK_RAD = 1e-7


def representation_range(q, lower, upper) -> tuple[np.ndarray, np.ndarray]:
    """``(k_lo, k_hi)``: the multiples ``k`` of 2π for which ``q + 2πk`` lies within ``[lower, upper]``
    widened by :data:`LIMIT_SLACK_RAD`; ``k_lo > k_hi`` where none does."""
    return (np.ceil((lower - LIMIT_SLACK_RAD - q) / TWO_PI), np.floor((upper + LIMIT_SLACK_RAD - q) / TWO_PI))


def nearest_representation(q, q_ref, lower, upper):
    """Each revolute angle of ``q`` moved by multiples of 2π to be nearest ``q_ref`` within limits
    (clipped onto a limit it passes by at most :data:`LIMIT_SLACK_RAD`); unchanged where none fits."""
    q = np.asarray(q, dtype=np.float64)
    k_lo, k_hi = representation_range(q, lower, upper)
    fits = k_lo <= k_hi
    k = np.clip(np.round((q_ref - q) / TWO_PI), k_lo, k_hi)
    out = q + TWO_PI * np.nan_to_num(np.where(fits, k, 0.0))
    return np.where(fits, np.clip(out, lower, upper), out)


def mark_duplicates(q: np.ndarray, valid: np.ndarray, tol: float = 1e-7,
                    revolute: np.ndarray | None = None) -> np.ndarray:
    """Return ``valid`` with slots equal (modulo 2π on revolute joints) to an earlier valid slot cleared.

    q: ``(N, K, n)``; valid: ``(N, K)``.
    """
    K = q.shape[1]
    rev = np.ones(q.shape[-1], bool) if revolute is None else revolute
    diff = q[:, :, None, :] - q[:, None, :, :]
    diff = np.where(rev, wrap_angle(diff), diff)
    same = np.all(np.abs(np.nan_to_num(diff, nan=np.inf)) < tol, axis=-1)  # (N,K,K)
    earlier = np.tril(np.ones((K, K), bool), -1)  # [a, b] with b < a
    dup = np.any(same & earlier & valid[:, None, :], axis=2)
    return valid & ~dup


# --------------------------------------------------------------------------- result containers


@dataclass
class IKSolutions:
    """All closed-form IK branches of a batch of targets.

    q: ``(N, 8, 6)`` joints (rad; only meaningful where ``valid``, NaN where a subproblem was
    degenerate); valid: ``(N, 8)`` bool (within limits,
    reproduces the target, not a duplicate); branch: ``(8,)`` int branch ids 0..7; labels: ``(8,)``
    strings; pos_err_m, ang_err_rad: ``(N, 8)`` FK residuals (inf where no candidate); family: the
    solver used.
    """

    q: np.ndarray
    valid: np.ndarray
    branch: np.ndarray
    labels: tuple[str, ...]
    pos_err_m: np.ndarray
    ang_err_rad: np.ndarray
    family: str

    @property
    def n_solutions(self) -> np.ndarray:
        """``(N,)`` number of valid solutions per target."""
        return self.valid.sum(axis=1)


@dataclass
class IKResult:
    """One IK solution per target.

    q: ``(N, dof)`` joints (rad / m); success: ``(N,)``; pos_err_m, ang_err_rad: ``(N,)`` residuals of
    ``q`` (``ang_err_rad`` is 0 for position-only solves); branch: ``(N,)`` closed-form branch id
    (0..7) or -1; label: ``(N,)`` branch label strings ("" when none); iterations: ``(N,)`` LM iterations
    of the last attempt (0 when the closed form was already within tolerance).
    """

    q: np.ndarray
    success: np.ndarray
    pos_err_m: np.ndarray
    ang_err_rad: np.ndarray
    branch: np.ndarray
    label: np.ndarray
    iterations: np.ndarray

    @property
    def success_rate(self) -> float:
        return float(np.mean(self.success)) if self.success.size else 0.0


@dataclass
class IKBranches:
    """Every distinct solution of each target, padded to ``K`` slots.

    q: ``(N, K, dof)`` (NaN in empty slots); success: ``(N, K)``; pos_err_m, ang_err_rad: ``(N, K)``;
    branch: ``(N, K)`` closed-form branch ids or -1; label: ``(N, K)`` strings.
    """

    q: np.ndarray
    success: np.ndarray
    pos_err_m: np.ndarray
    ang_err_rad: np.ndarray
    branch: np.ndarray
    label: np.ndarray

    @property
    def n_solutions(self) -> np.ndarray:
        """``(N,)`` number of solutions per target (0 = unreachable)."""
        return self.success.sum(axis=1)

    def nearest_to(self, q_current, lower=None, upper=None) -> IKResult:
        """The solution nearest ``q_current`` ``(N, dof)`` or ``(dof,)`` (Euclidean, joint space).

        With ``lower``/``upper`` given, each solution's 2π-equivalent representations within those
        limits are considered too (so a ±270° joint goes the short way round).
        """
        N, _, n = self.q.shape
        qc = np.broadcast_to(np.asarray(q_current, dtype=np.float64), (N, n))
        q = self.q
        if lower is not None and upper is not None:
            q = nearest_representation(q, qc[:, None, :], lower, upper)
        d = np.linalg.norm(np.nan_to_num(q - qc[:, None, :], nan=np.inf), axis=-1)
        d = np.where(self.success, d, np.inf)
        k = np.argmin(d, axis=1)
        idx = np.arange(N)
        return IKResult(
            q=q[idx, k].copy(), success=self.success[idx, k].copy(), pos_err_m=self.pos_err_m[idx, k].copy(),
            ang_err_rad=self.ang_err_rad[idx, k].copy(), branch=np.array(self.branch[idx, k]),
            label=np.array(self.label[idx, k], dtype=object), iterations=np.zeros(N, np.int64),
        )
