"""Closed-form inverse kinematics returning every solution branch, batched over targets.

Two families of 6R arms are solved exactly (up to 8 solutions each):

* ``"opw"`` — spherical wrist (axes 4, 5, 6 meet in one point) and parallel axes 2 ∥ 3, with axis 1
  not parallel to axis 2. This contains the ortho-parallel basis with spherical wrist of
  Brandstötter et al. (2014) — Stäubli RX160, KUKA KR, ABB IRB, Fanuc — and also non-orthogonal
  variants of it.
* ``"ur"`` — three parallel axes 2 ∥ 3 ∥ 4, axes 5 and 6 intersecting, axis 1 and axis 5 not
  parallel to axis 2 (Universal Robots UR3/5/10/16, e-series; Hawkins 2013).

How: the robot is turned into its product-of-exponentials (POE) form at ``q = 0`` in the *world*
frame — unit axis ``h_i`` and a point ``p_i`` on each joint axis plus the zero-pose TCP ``T0``:
``T(q) = e_1(q_1) ··· e_6(q_6) · T0``. This representation is convention free: DH, MDH or URDF,
base and tool frames, theta offsets and axis signs are all absorbed, so no per-vendor parameter
table (``a1, a2, b, c1..c4``, offsets, signs) has to be extracted. The structure test is geometric
(parallel / intersecting axes to ``tol``) and the extracted POE model is verified against
:func:`hykin.fk.fk` on random joints; the robot is rejected (``None``) otherwise. The joint angles
follow from the Paden–Kahan subproblems 1 (rotation of a point onto another) and 4 (rotation
giving a prescribed projection; subproblems 2 and 3 reduce to it), as in ik-geo (Elias & Wen 2022).

Branches and representation (decisions, documented):

* Branch index ``b = 4·i + 2·j + k`` with ``i`` the root of joint 1 (shoulder), ``j`` the root of the
  elbow joint (3 for ``opw``, 3 for ``ur``), ``k`` the root of the wrist (5). Root 0 is ``φ + acos``,
  root 1 is ``φ − acos`` of the underlying subproblem: labels read e.g. ``"shoulder+ elbow- wrist+"``.
* Each branch is returned **once**, in the representation nearest zero that lies within the joint
  limits (joints with a range over 2π are tried at ``q ± 2πk``); two joint vectors that differ by
  multiples of 2π count as one solution. Exhaustive numerical searches must count the same way.
* A branch is ``valid`` only if all joints are within limits, FK reproduces the target to
  ``tol_m`` / ``tol_rad`` and it is not a duplicate (modulo 2π) of an earlier valid branch (double
  roots at workspace boundaries and singularities).
* Singular cases: wrist singular (axes 4 and 6 aligned, e.g. ``q5 = 0`` on an RX160; ``ur``: axis 6
  parallel to axes 2–4) -> joint 4 (``ur``: joint 6) is set to 0 and the other wrist joint takes the
  whole rotation; shoulder singular (wrist centre on axis 1) -> joint 1 is set to 0. Exactly at a
  singularity the solutions form a continuum and only these representatives are returned; for a
  ``ur`` arm at an exact wrist singularity with the elbow stretched, ``q6 = 0`` may leave the target
  out of reach, so no branch is valid (:func:`hykin.ik.ik` then falls back to LM). Near (not at) a
  singularity the roots are computed normally; rounding decides the free angle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .fk import fk, fk_frames
from .robot import Robot

__all__ = [
    "ClosedFormError",
    "IKSolutions",
    "POEModel",
    "has_closed_form",
    "ik_closed_form",
    "mark_duplicates",
    "poe_model",
    "pose_residual",
    "run_chunked",
    "wrap_to_limits",
]

TWO_PI = 2.0 * np.pi
SP4_ATOL = np.inf  # how far beyond |cos| = 1 a subproblem-4 root is still clamped (see _sp4)


class ClosedFormError(ValueError):
    """The robot has no closed-form IK of a supported family (message says which test failed)."""


# --------------------------------------------------------------------------- POE model


@dataclass
class POEModel:
    """Product-of-exponentials model of a 6R robot at ``q = 0``, world frame.

    h: ``(6, 3)`` unit joint axes; p: ``(6, 3)`` a point on each axis (m); T0: ``(4, 4)`` TCP pose at
    ``q = 0``; family: ``"opw"``, ``"ur"`` or ``None``; wc: ``(3,)`` wrist centre (``opw``) or the
    intersection of axes 5 and 6 (``ur``), NaN otherwise; reason: why no family fits (or "").
    """

    h: np.ndarray
    p: np.ndarray
    T0: np.ndarray
    family: str | None
    wc: np.ndarray
    reason: str = ""


def _parallel(a, b, tol):
    return np.linalg.norm(np.cross(a, b)) < tol


def _line_point_lsq(h, p):
    """Point minimising the summed squared distance to lines (h_i, p_i); returns (point, max dist)."""
    A = np.zeros((3, 3))
    rhs = np.zeros(3)
    for hi, pi in zip(h, p):
        P = np.eye(3) - np.outer(hi, hi)
        A += P
        rhs += P @ pi
    x = np.linalg.lstsq(A, rhs, rcond=None)[0]
    dist = max(np.linalg.norm((np.eye(3) - np.outer(hi, hi)) @ (x - pi)) for hi, pi in zip(h, p))
    return x, dist


def poe_model(robot: Robot, tol: float = 1e-9) -> POEModel:
    """Extract the POE model of ``robot`` and classify it (``family``); cached on the robot.

    ``tol``: tolerance on sines of angles between axes (rad) and on axis distances (m, relative to
    the robot size).
    """
    key = (_geometry_bytes(robot), float(tol))
    cached = getattr(robot, "_poe_cache", None)
    if cached is not None and cached[0] == key:
        return cached[1]
    model = _poe_model(robot, tol)
    object.__setattr__(robot, "_poe_cache", (key, model))
    return model


def _geometry_bytes(robot: Robot) -> bytes:
    parts = [robot.a_m, robot.alpha_rad, robot.d_m, robot.theta_rad, robot.beta_rad, robot.origin_xyz_m,
             robot.origin_rpy_rad, robot.axis, robot.base, robot.tool, robot.lower, robot.upper]
    return (robot.convention + str(robot.joint_type)).encode() + b"".join(
        np.ascontiguousarray(p).tobytes() for p in parts)


def _poe_model(robot: Robot, tol: float) -> POEModel:
    nan3 = np.full(3, np.nan)
    if robot.dof != 6 or any(t != "revolute" for t in robot.joint_type):
        h = np.zeros((robot.dof, 3))
        return POEModel(h, h.copy(), np.eye(4), None, nan3, "closed form needs 6 revolute joints")
    fr = fk_frames(robot, np.zeros((1, 6)))
    h = fr.joint[0, :, :3, 2].copy()
    p = fr.joint[0, :, :3, 3].copy()
    T0 = fr.tcp[0].copy()
    scale = max(1.0, float(np.max(np.linalg.norm(p - p[0], axis=1))))
    ltol = tol * scale
    family, wc, reason = None, nan3, ""
    if _parallel(h[0], h[1], 1e-6):
        reason = "axis 1 is parallel to axis 2"
    elif not _parallel(h[1], h[2], tol):
        reason = "axes 2 and 3 are not parallel"
    else:
        x, dist = _line_point_lsq(h[3:], p[3:])
        par34 = _parallel(h[1], h[3], tol)
        if dist < ltol and not par34 and not _parallel(h[3], h[4], 1e-6) and not _parallel(h[4], h[5], 1e-6):
            family, wc = "opw", x
        elif par34:
            x56, d56 = _line_point_lsq(h[4:], p[4:])
            if _parallel(h[4], h[5], 1e-6) or d56 >= ltol:
                reason = "axes 2-4 parallel but axes 5 and 6 do not intersect"
            elif _parallel(h[1], h[4], 1e-6):
                reason = "axis 5 is parallel to axes 2-4"
            else:
                family, wc = "ur", x56
        else:
            reason = f"axes 4, 5, 6 do not meet in one point (miss {dist:.3g} m) and axis 4 is not parallel to 2, 3"
    model = POEModel(h, p, T0, family, wc, reason)
    if family is not None:  # numerical verification of the extracted model against FK
        rng = np.random.default_rng(0)
        q = robot.random_joints(64, rng)
        err = np.abs(_poe_fk(model, q) - fk(robot, q)).max()
        if err > 1e-9 * scale:
            model.family, model.reason = None, f"POE model disagrees with FK by {err:.3g}"
    return model


def _rot(k, th, v):
    """Rotate vectors ``v`` about unit axes ``k`` by ``th`` (Rodrigues); all broadcast, ``(..., 3)``."""
    c = np.cos(th)[..., None]
    s = np.sin(th)[..., None]
    kv = np.sum(k * v, axis=-1, keepdims=True)
    return v * c + np.cross(k, v) * s + k * kv * (1.0 - c)


def _rotmat(k, th):
    """Rotation matrices ``(..., 3, 3)`` about unit axis ``k`` (3,) by angles ``th`` (...)."""
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    c = np.cos(th)[..., None, None]
    s = np.sin(th)[..., None, None]
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def _poe_fk(m: POEModel, q):
    T = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
    for i in range(6):
        E = np.broadcast_to(np.eye(4), q.shape[:-1] + (4, 4)).copy()
        R = _rotmat(m.h[i], q[..., i])
        E[..., :3, :3] = R
        E[..., :3, 3] = m.p[i] - R @ m.p[i]
        T = T @ E
    return T @ m.T0


def has_closed_form(robot: Robot, tol: float = 1e-9) -> str | None:
    """``"opw"`` or ``"ur"`` when :func:`ik_closed_form` applies to ``robot``, else ``None``."""
    return poe_model(robot, tol).family


# --------------------------------------------------------------------------- subproblems


def _dot(a, b):
    return np.sum(a * b, axis=-1)


def _sp1(p, q, k):
    """Angle θ rotating ``p`` onto ``q`` about unit ``k`` (components ⟂ k); 0 when degenerate
    (both vectors along ``k`` to rounding: the singular cases of the module docstring)."""
    y = _dot(k, np.cross(p, q))
    x = _dot(p, q) - _dot(k, p) * _dot(k, q)
    return np.where(np.hypot(x, y) < 1e-20, 0.0, np.arctan2(y, x))


def _sp4(h, p, k, d, atol=np.inf):
    """Both roots θ of ``h · R(k, θ) p = d`` -> ``(θ+ , θ-)``, NaN where no real root.

    Cases without a real root (|d'/r| > 1: out of reach, or rounding near elbow/wrist singularities)
    are clamped to the nearest double root up to ``atol`` (default: always); the FK check and
    :func:`_refine` then decide whether the candidate is a solution. Degenerate
    cases (amplitude ~ 0, e.g. shoulder/wrist singular) give θ = 0 when the equation holds.
    """
    kp = _dot(k, p)[..., None] * k if np.ndim(k) == np.ndim(p) else _dot(k, p)[..., None] * k
    p_perp = p - kp
    A = _dot(h, p_perp)
    B = _dot(h, np.cross(k, p))
    C = d - _dot(h, kp)
    r = np.hypot(A, B)
    scale = np.maximum(np.abs(C), 1.0)
    degenerate = r < 1e-12 * scale
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = C / np.where(degenerate, 1.0, r)
    ok = np.abs(ratio) <= 1.0 + atol
    a = np.arccos(np.clip(ratio, -1.0, 1.0))
    phi = np.arctan2(B, A)
    t1 = np.where(ok, phi + a, np.nan)
    t2 = np.where(ok, phi - a, np.nan)
    deg_ok = degenerate & (np.abs(C) < 1e-9 * scale)
    t1 = np.where(degenerate, np.where(deg_ok, 0.0, np.nan), t1)
    t2 = np.where(degenerate, np.where(deg_ok, 0.0, np.nan), t2)
    return t1, t2


def _both(t1, t2, axis):
    return np.stack([t1, t2], axis=axis)


def _perp(k):
    a = np.array([1.0, 0.0, 0.0]) if abs(k[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    v = np.cross(k, a)
    return v / np.linalg.norm(v)


def _wrap(x):
    return (x + np.pi) % TWO_PI - np.pi


# --------------------------------------------------------------------------- solvers


def _solve_opw(m: POEModel, R_t, p_t):
    """All 8 candidates ``(N, 2, 2, 2, 6)`` for the spherical-wrist family (NaN = no root)."""
    h, p = m.h, m.p
    R0, P0 = m.T0[:3, :3], m.T0[:3, 3]
    W0 = m.wc
    Rd = R_t @ R0.T  # (N,3,3)
    W = p_t + Rd @ (W0 - P0)  # wrist centre of the target, (N,3)
    # q1: h2 . R1^T (W - p1) = h2 . (W0 - p1)
    t1a, t1b = _sp4(W - p[0], h[1], h[0], np.full(len(W), h[1] @ (W0 - p[0])))
    q1 = _both(t1a, t1b, 1)  # (N,2)
    Wl = p[0] + _rot(h[0], -q1, (W - p[0])[:, None, :])  # (N,2,3): wrist centre with joint 1 undone
    c = p[2] - p[1]
    u = W0 - p[2]
    D2 = _dot(Wl - p[1], Wl - p[1])
    t3a, t3b = _sp4(c, u, h[2], (D2 - c @ c - u @ u) / 2.0)
    q3 = _both(t3a, t3b, 2)  # (N,2,2)
    e3W0 = p[2] + _rot(h[2], q3, u)  # (N,2,2,3)
    q2 = _sp1(e3W0 - p[1], (Wl - p[1])[:, :, None, :], h[1])  # (N,2,2)
    # wrist: R4 R5 R6 = Rw = (R1 R2 R3)^T Rd
    R123 = _rotmat(h[0], q1)[:, :, None] @ _rotmat(h[1], q2) @ _rotmat(h[2], q3)  # (N,2,2,3,3)
    Rw = np.swapaxes(R123, -1, -2) @ Rd[:, None, None]
    v = Rw @ h[5]  # (N,2,2,3)
    t5a, t5b = _sp4(h[3], h[5], h[4], v @ h[3])
    q5 = _both(t5a, t5b, 3)  # (N,2,2,2)
    R5h6 = _rot(h[4], q5, h[5])
    q4 = _sp1(R5h6, v[:, :, :, None, :], h[3])
    x = _perp(h[5])
    Rw_x = (Rw @ x)[:, :, :, None, :]
    y = _rot(h[4], -q5, _rot(h[3], -q4, Rw_x))
    q6 = _sp1(x, y, h[5])
    sh = q5.shape
    return np.stack(
        [np.broadcast_to(q1[:, :, None, None], sh), np.broadcast_to(q2[..., None], sh),
         np.broadcast_to(q3[..., None], sh), q4, q5, q6], axis=-1,
    )


def _solve_ur(m: POEModel, R_t, p_t):
    """All 8 candidates ``(N, 2, 2, 2, 6)`` for the three-parallel-axes family (branch order i, j=q3, k=q5)."""
    h, p = m.h, m.p
    R0, P0 = m.T0[:3, :3], m.T0[:3, 3]
    N = len(p_t)
    Rd = R_t @ R0.T
    P56 = m.wc
    p6w = p_t + Rd @ (P56 - P0)  # (N,3)
    t1a, t1b = _sp4(p6w - p[0], h[1], h[0], np.full(N, h[1] @ (P56 - p[0])))
    q1 = _both(t1a, t1b, 1)  # (N,2)
    R1h2 = _rot(h[0], q1, h[1])  # (N,2,3)
    d5 = _dot(R1h2, (Rd @ h[5])[:, None, :])
    t5a, t5b = _sp4(h[1], h[5], h[4], d5)
    q5 = _both(t5a, t5b, 2)  # (N,2,2)  (index: i, k)
    # q6: R(h6, q6) (Rd^T R1 h2) = R5^T h2
    a6 = (np.swapaxes(Rd, -1, -2)[:, None] @ R1h2[..., None])[..., 0]  # (N,2,3)
    b6 = _rot(h[4], -q5, h[1])  # (N,2,2,3)
    q6 = _sp1(a6[:, :, None, :], b6, h[5])  # (N,2,2)
    # theta234 about h2: R234 = R1^T Rd R6^T R5^T
    x = _perp(h[1])
    y = _rot(h[4], -q5, x)
    y = _rot(h[5], -q6, y)
    y = (Rd[:, None, None] @ y[..., None])[..., 0]
    y = _rot(h[0], -q1[:, :, None], y)
    th = _sp1(x, y, h[1])  # (N,2,2)
    # position: e2 e3 (p4) = e1^{-1}(p_t) - R234 (Z - p4), Z = e5 e6 (P0)
    Z = p[5] + _rot(h[5], q6, P0 - p[5])
    Z = p[4] + _rot(h[4], q5, Z - p[4])  # (N,2,2,3)
    pl = p[0] + _rot(h[0], -q1, (p_t - p[0])[:, None, :])  # (N,2,3)
    W = pl[:, :, None, :] - _rot(h[1], th, Z - p[3])  # (N,2,2,3)
    c = p[2] - p[1]
    u = p[3] - p[2]
    D2 = _dot(W - p[1], W - p[1])
    t3a, t3b = _sp4(c, u, h[2], (D2 - c @ c - u @ u) / 2.0)
    q3 = _both(t3a, t3b, 2)  # (N,2,2j,2k)
    e3p4 = p[2] + _rot(h[2], q3, u)
    q2 = _sp1(e3p4 - p[1], (W - p[1])[:, :, None, :, :], h[1])
    s3, s4 = h[2] @ h[1], h[3] @ h[1]
    q4 = s4 * (th[:, :, None, :] - q2 - s3 * q3)
    sh = q3.shape
    return np.stack(
        [np.broadcast_to(q1[:, :, None, None], sh), q2, q3, q4,
         np.broadcast_to(q5[:, :, None, :], sh), np.broadcast_to(q6[:, :, None, :], sh)], axis=-1,
    )


def wrap_to_limits(q: np.ndarray, lower: np.ndarray, upper: np.ndarray, revolute: np.ndarray | None = None):
    """Representation of each revolute joint angle ``q + 2πk`` nearest zero within ``[lower, upper]``.

    Joints with no representation in the limits keep their value wrapped to ``(-π, π]`` (and so stay
    outside the limits). ``q``: ``(..., n)``; returns a new array.
    """
    q = np.asarray(q, dtype=np.float64)
    rev = np.ones(q.shape[-1], bool) if revolute is None else np.asarray(revolute, bool)
    w = _wrap(q)
    k_lo = np.ceil((lower - w) / TWO_PI - 1e-12)
    k_hi = np.floor((upper - w) / TWO_PI + 1e-12)
    k0 = np.round(-w / TWO_PI)
    k = np.clip(k0, k_lo, k_hi)
    k = np.where(k_lo <= k_hi, k, 0.0)
    out = w + TWO_PI * k
    return np.where(rev, out, q)


def pose_residual(T: np.ndarray, T_t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error (m) and rotation angle of ``R R_t^T`` (rad, accurate near 0) between pose batches."""
    pe = np.linalg.norm(T[..., :3, 3] - T_t[..., :3, 3], axis=-1)
    M = T[..., :3, :3] @ np.swapaxes(T_t[..., :3, :3], -1, -2)
    s = 0.5 * np.sqrt(
        (M[..., 2, 1] - M[..., 1, 2]) ** 2 + (M[..., 0, 2] - M[..., 2, 0]) ** 2 + (M[..., 1, 0] - M[..., 0, 1]) ** 2
    )
    c = 0.5 * (M[..., 0, 0] + M[..., 1, 1] + M[..., 2, 2] - 1.0)
    return pe, np.arctan2(s, c)


# --------------------------------------------------------------------------- public API


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


def run_chunked(kernel, args, N: int, min_chunk: int = 2000) -> None:
    """Run ``kernel(*args, start, stop)`` over ``range(N)`` in chunks on a thread pool (the kernels
    release the GIL); a single call when ``N`` is small. Threads instead of numba ``prange`` keep the
    first-call compile time short."""
    import os
    from concurrent.futures import ThreadPoolExecutor

    workers = min(os.cpu_count() or 1, max(1, N // min_chunk))
    if workers <= 1:
        kernel(*args, 0, N)
        return
    edges = np.linspace(0, N, workers + 1).astype(int)
    with ThreadPoolExecutor(workers) as ex:
        list(ex.map(lambda i: kernel(*args, int(edges[i]), int(edges[i + 1])), range(workers)))


def _labels(family: str) -> tuple[str, ...]:
    el = "elbow"
    out = []
    for b in range(8):
        i, j, k = b >> 2, (b >> 1) & 1, b & 1
        out.append(f"shoulder{'+-'[i]} {el}{'+-'[j]} wrist{'+-'[k]}")
    return tuple(out)


def _as_targets(T_world) -> tuple[np.ndarray, bool]:
    T = np.asarray(T_world, dtype=np.float64)
    single = T.ndim == 2
    T = T.reshape(1, 4, 4) if single else T
    if T.ndim != 3 or T.shape[1:] != (4, 4):
        raise ValueError(f"targets must have shape (N, 4, 4) or (4, 4), got {np.shape(T_world)}")
    if not np.all(np.isfinite(T)):
        bad = int(np.argmax(~np.all(np.isfinite(T.reshape(len(T), -1)), axis=1)))
        raise ValueError(f"target {bad} contains NaN or inf")
    return T, single


def _refine(robot: Robot, T, q, valid, pe, ae, tol_m, tol_rad, near: float = 1e-5) -> None:
    """In place: candidates within ``near`` of the target but outside tolerance (roots of
    near-tangent subproblems at elbow/wrist/shoulder singularities lose about half the digits to
    ``acos``) get a few Gauss-Newton/LM steps within the limits, then duplicates are re-marked."""
    cand = np.isfinite(q).all(-1) & ~valid & (pe < near) & (ae < near)
    if not cand.any() or not np.isfinite(tol_m) or not np.isfinite(tol_rad):
        return
    from .ik import solve_lm

    rows, cols = np.nonzero(cand)
    qs, _, _, _ = solve_lm(robot, T[rows], q[rows, cols], tol_m=min(tol_m, 1e-12), tol_rad=min(tol_rad, 1e-12),
                           max_iter=10, bounded=True)
    pe_new, ae_new = pose_residual(fk(robot, qs), T[rows])
    q[rows, cols], pe[rows, cols], ae[rows, cols] = qs, pe_new, ae_new
    ok = (pe_new <= tol_m) & (ae_new <= tol_rad) & robot.within_limits(qs, tol=0.0)
    valid[rows[ok], cols[ok]] = True
    touched = np.unique(rows[ok])
    if touched.size:
        sub = valid[touched].copy()
        # re-mark duplicates: refined slots may coincide with each other or with earlier ones
        valid[touched] = mark_duplicates(q[touched], sub)


def mark_duplicates(q: np.ndarray, valid: np.ndarray, tol: float = 1e-7,
                    revolute: np.ndarray | None = None) -> np.ndarray:
    """Return ``valid`` with slots equal (modulo 2π on revolute joints) to an earlier valid slot cleared.

    q: ``(N, K, n)``; valid: ``(N, K)``.
    """
    K = q.shape[1]
    rev = np.ones(q.shape[-1], bool) if revolute is None else revolute
    diff = q[:, :, None, :] - q[:, None, :, :]
    diff = np.where(rev, _wrap(diff), diff)
    same = np.all(np.abs(np.nan_to_num(diff, nan=np.inf)) < tol, axis=-1)  # (N,K,K)
    earlier = np.tril(np.ones((K, K), bool), -1)  # [a, b] with b < a
    dup = np.any(same & earlier & valid[:, None, :], axis=2)
    return valid & ~dup


def ik_closed_form(robot: Robot, T_world, tol_m: float = 1e-9, tol_rad: float = 1e-9,
                   structure_tol: float = 1e-9, use_numba: bool = True) -> IKSolutions:
    """All closed-form IK solutions (up to 8) of world TCP targets ``T_world`` ``(N, 4, 4)``.

    Raises :class:`ClosedFormError` when the robot is not of the ``opw`` or ``ur`` family (see
    :func:`has_closed_form`). Solutions are wrapped into the joint limits (see module docstring);
    ``valid`` marks the ones within limits whose FK reproduces the target to ``tol_m`` / ``tol_rad``.
    ``use_numba=False`` runs the vectorised numpy reference instead of the compiled kernel.
    """
    m = poe_model(robot, structure_tol)
    if m.family is None:
        raise ClosedFormError(f"robot {robot.name!r}: no closed-form IK ({m.reason})")
    T, _ = _as_targets(T_world)
    N = len(T)
    if HAVE_NUMBA and use_numba:
        from .chain import chain_of

        ch = chain_of(robot)
        q = np.empty((N, 8, 6))
        valid = np.empty((N, 8), np.bool_)
        pe = np.empty((N, 8))
        ae = np.empty((N, 8))
        fam = 0 if m.family == "opw" else 1
        xperp = _perp(m.h[5] if fam == 0 else m.h[1])
        s3, s4 = float(m.h[2] @ m.h[1]), float(m.h[3] @ m.h[1])
        args = (fam, m.h, m.p, np.ascontiguousarray(m.T0[:3, :3]), m.T0[:3, 3].copy(), m.wc, xperp, s3, s4,
                np.ascontiguousarray(ch.fixed), np.ascontiguousarray(ch.prismatic, dtype=np.bool_),
                np.ascontiguousarray(robot.lower), np.ascontiguousarray(robot.upper), np.ascontiguousarray(T),
                float(tol_m), float(tol_rad), q, valid, pe, ae)
        run_chunked(_closed_form_range, args, N, min_chunk=2000)
        _refine(robot, T, q, valid, pe, ae, tol_m, tol_rad)
        return IKSolutions(q=q, valid=valid, branch=np.arange(8), labels=_labels(m.family), pos_err_m=pe,
                           ang_err_rad=ae, family=m.family)
    R_t, p_t = T[:, :3, :3], T[:, :3, 3]
    cand = (_solve_opw if m.family == "opw" else _solve_ur)(m, R_t, p_t).reshape(N, 8, 6)
    finite = np.all(np.isfinite(cand), axis=-1)
    q = wrap_to_limits(np.where(finite[..., None], cand, 0.0), robot.lower, robot.upper)
    inlim = np.all((q >= robot.lower - 1e-12) & (q <= robot.upper + 1e-12), axis=-1)
    q = np.clip(q, robot.lower, robot.upper)
    Tq = fk(robot, q.reshape(-1, 6)).reshape(N, 8, 4, 4)
    pe, ae = pose_residual(Tq, T[:, None])
    pe = np.where(finite, pe, np.inf)
    ae = np.where(finite, ae, np.inf)
    valid = finite & inlim & (pe <= tol_m) & (ae <= tol_rad)
    valid = mark_duplicates(q, valid)
    q = np.where(finite[..., None], q, np.nan)
    _refine(robot, T, q, valid, pe, ae, tol_m, tol_rad)
    return IKSolutions(q=q, valid=valid, branch=np.arange(8), labels=_labels(m.family), pos_err_m=pe,
                       ang_err_rad=ae, family=m.family)


# --------------------------------------------------------------------------- numba kernels
# Same algebra as _solve_opw / _solve_ur, one target per iteration, with the limit wrapping, FK
# check and duplicate removal fused in (the numpy path above is the reference and the fallback).

from .fk import HAVE_NUMBA

if HAVE_NUMBA:
    import numba

    from .fk import _fk_one

    _nj = numba.njit(cache=True, nogil=True)

    @_nj
    def _v(a):  # pragma: no cover - compiled
        return (a[0], a[1], a[2])

    @_nj
    def _vdot(a, b):  # pragma: no cover - compiled
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    @_nj
    def _vcross(a, b):  # pragma: no cover - compiled
        return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])

    @_nj
    def _vsub(a, b):  # pragma: no cover - compiled
        return (a[0] - b[0], a[1] - b[1], a[2] - b[2])

    @_nj
    def _vadd(a, b):  # pragma: no cover - compiled
        return (a[0] + b[0], a[1] + b[1], a[2] + b[2])

    @_nj
    def _vrot(k, th, v):  # pragma: no cover - compiled
        c, s = np.cos(th), np.sin(th)
        kv = _vdot(k, v) * (1.0 - c)
        kx = _vcross(k, v)
        return (v[0] * c + kx[0] * s + k[0] * kv, v[1] * c + kx[1] * s + k[1] * kv, v[2] * c + kx[2] * s + k[2] * kv)

    @_nj
    def _vrot_cs(k, c, s, v):  # pragma: no cover - compiled
        kv = _vdot(k, v) * (1.0 - c)
        kx = _vcross(k, v)
        return (v[0] * c + kx[0] * s + k[0] * kv, v[1] * c + kx[1] * s + k[1] * kv, v[2] * c + kx[2] * s + k[2] * kv)

    @_nj
    def _mv(M, v):  # pragma: no cover - compiled
        return (
            M[0, 0] * v[0] + M[0, 1] * v[1] + M[0, 2] * v[2],
            M[1, 0] * v[0] + M[1, 1] * v[1] + M[1, 2] * v[2],
            M[2, 0] * v[0] + M[2, 1] * v[1] + M[2, 2] * v[2],
        )

    @_nj
    def _nsp1(p, q, k):  # pragma: no cover - compiled
        y = _vdot(k, _vcross(p, q))
        x = _vdot(p, q) - _vdot(k, p) * _vdot(k, q)
        if np.hypot(x, y) < 1e-20:
            return 0.0
        return np.arctan2(y, x)

    @_nj
    def _nsp4(h, p, k, d):  # pragma: no cover - compiled
        kp = _vdot(k, p)
        A = _vdot(h, p) - _vdot(h, k) * kp
        B = _vdot(h, _vcross(k, p))
        C = d - _vdot(h, k) * kp
        r = np.hypot(A, B)
        scale = max(abs(C), 1.0)
        if r < 1e-12 * scale:
            if abs(C) < 1e-9 * scale:
                return 0.0, 0.0, True
            return np.nan, np.nan, False
        ratio = C / r
        if abs(ratio) > 1.0 + SP4_ATOL:
            return np.nan, np.nan, False
        ratio = min(1.0, max(-1.0, ratio))
        a = np.arccos(ratio)
        phi = np.arctan2(B, A)
        return phi + a, phi - a, True

    @numba.njit(cache=True, nogil=True)
    def _opw_one(h, p, Rd, W, W0, x6, out, ok):  # pragma: no cover - compiled
        h1, h2, h3, h4, h5, h6 = _v(h[0]), _v(h[1]), _v(h[2]), _v(h[3]), _v(h[4]), _v(h[5])
        p1, p2, p3 = _v(p[0]), _v(p[1]), _v(p[2])
        a1, b1, f1 = _nsp4(_vsub(W, p1), h2, h1, _vdot(h2, _vsub(W0, p1)))
        c = _vsub(p3, p2)
        u = _vsub(W0, p3)
        cc, uu = _vdot(c, c), _vdot(u, u)
        Rdh6 = _mv(Rd, h6)
        Rdx = _mv(Rd, x6)
        for i in range(2):
            q1 = a1 if i == 0 else b1
            c1, s1 = np.cos(q1), np.sin(q1)
            Wl = _vadd(p1, _vrot_cs(h1, c1, -s1, _vsub(W, p1)))
            Wr = _vsub(Wl, p2)
            a3, b3, f3 = _nsp4(c, u, h3, (_vdot(Wr, Wr) - cc - uu) / 2.0)
            v1 = _vrot_cs(h1, c1, -s1, Rdh6)
            x1 = _vrot_cs(h1, c1, -s1, Rdx)
            for j in range(2):
                q3 = a3 if j == 0 else b3
                c3, s3_ = np.cos(q3), np.sin(q3)
                e3 = _vadd(c, _vrot_cs(h3, c3, s3_, u))
                q2 = _nsp1(e3, Wr, h2)
                c2, s2 = np.cos(q2), np.sin(q2)
                v = _vrot_cs(h3, c3, -s3_, _vrot_cs(h2, c2, -s2, v1))
                wx = _vrot_cs(h3, c3, -s3_, _vrot_cs(h2, c2, -s2, x1))
                a5, b5, f5 = _nsp4(h4, h6, h5, _vdot(v, h4))
                for k in range(2):
                    q5 = a5 if k == 0 else b5
                    c5, s5 = np.cos(q5), np.sin(q5)
                    q4 = _nsp1(_vrot_cs(h5, c5, s5, h6), v, h4)
                    y = _vrot_cs(h5, c5, -s5, _vrot(h4, -q4, wx))
                    q6 = _nsp1(x6, y, h6)
                    b = 4 * i + 2 * j + k
                    out[b, 0], out[b, 1], out[b, 2] = q1, q2, q3
                    out[b, 3], out[b, 4], out[b, 5] = q4, q5, q6
                    ok[b] = f1 and f3 and f5

    @numba.njit(cache=True, nogil=True)
    def _ur_one(h, p, Rd, p6w, pt, P56, P0, x2, s3, s4, out, ok):  # pragma: no cover - compiled
        h1, h2, h3, h4, h5, h6 = _v(h[0]), _v(h[1]), _v(h[2]), _v(h[3]), _v(h[4]), _v(h[5])
        p1, p2, p3, p4, p5, p6 = _v(p[0]), _v(p[1]), _v(p[2]), _v(p[3]), _v(p[4]), _v(p[5])
        a1, b1, f1 = _nsp4(_vsub(p6w, p1), h2, h1, _vdot(h2, _vsub(P56, p1)))
        Rdh6 = _mv(Rd, h6)
        c = _vsub(p3, p2)
        u = _vsub(p4, p3)
        cc, uu = _vdot(c, c), _vdot(u, u)
        for i in range(2):
            q1 = a1 if i == 0 else b1
            c1, s1 = np.cos(q1), np.sin(q1)
            R1h2 = _vrot_cs(h1, c1, s1, h2)
            a6v = (
                Rd[0, 0] * R1h2[0] + Rd[1, 0] * R1h2[1] + Rd[2, 0] * R1h2[2],
                Rd[0, 1] * R1h2[0] + Rd[1, 1] * R1h2[1] + Rd[2, 1] * R1h2[2],
                Rd[0, 2] * R1h2[0] + Rd[1, 2] * R1h2[1] + Rd[2, 2] * R1h2[2],
            )
            a5, b5, f5 = _nsp4(h2, h6, h5, _vdot(R1h2, Rdh6))
            pl = _vadd(p1, _vrot_cs(h1, c1, -s1, _vsub(pt, p1)))
            for k in range(2):
                q5 = a5 if k == 0 else b5
                c5, s5 = np.cos(q5), np.sin(q5)
                q6 = _nsp1(a6v, _vrot_cs(h5, c5, -s5, h2), h6)
                c6, s6 = np.cos(q6), np.sin(q6)
                y = _vrot_cs(h1, c1, -s1, _mv(Rd, _vrot_cs(h6, c6, -s6, _vrot_cs(h5, c5, -s5, x2))))
                th = _nsp1(x2, y, h2)
                Z = _vadd(p6, _vrot_cs(h6, c6, s6, _vsub(P0, p6)))
                Z = _vadd(p5, _vrot_cs(h5, c5, s5, _vsub(Z, p5)))
                W = _vsub(pl, _vrot(h2, th, _vsub(Z, p4)))
                Wr = _vsub(W, p2)
                a3, b3, f3 = _nsp4(c, u, h3, (_vdot(Wr, Wr) - cc - uu) / 2.0)
                for j in range(2):
                    q3 = a3 if j == 0 else b3
                    q2 = _nsp1(_vadd(c, _vrot(h3, q3, u)), Wr, h2)
                    q4 = s4 * (th - q2 - s3 * q3)
                    b = 4 * i + 2 * j + k
                    out[b, 0], out[b, 1], out[b, 2] = q1, q2, q3
                    out[b, 3], out[b, 4], out[b, 5] = q4, q5, q6
                    ok[b] = f1 and f5 and f3

    @numba.njit(cache=True, nogil=True)
    def _finish_one(fixed, prismatic, lower, upper, T, q, ok, tol_m, tol_rad, valid, pe, ae, Tq):  # pragma: no cover
        K, n = q.shape
        for b in range(K):
            valid[b] = False
            pe[b] = np.inf
            ae[b] = np.inf
            if not ok[b]:
                for j in range(n):
                    q[b, j] = np.nan
                continue
            inlim = True
            for j in range(n):
                w = (q[b, j] + np.pi) % TWO_PI - np.pi
                klo = np.ceil((lower[j] - w) / TWO_PI - 1e-12)
                khi = np.floor((upper[j] - w) / TWO_PI + 1e-12)
                kk = min(max(np.round(-w / TWO_PI), klo), khi) if klo <= khi else 0.0
                w = w + TWO_PI * kk
                if w < lower[j] - 1e-12 or w > upper[j] + 1e-12:
                    inlim = False
                q[b, j] = min(max(w, lower[j]), upper[j])
            _fk_one(fixed, prismatic, q[b], Tq)
            dx, dy, dz = Tq[0, 3] - T[0, 3], Tq[1, 3] - T[1, 3], Tq[2, 3] - T[2, 3]
            pe[b] = np.sqrt(dx * dx + dy * dy + dz * dz)
            # M = Rq Rt^T
            tr = 0.0
            for r in range(3):
                tr += Tq[r, 0] * T[r, 0] + Tq[r, 1] * T[r, 1] + Tq[r, 2] * T[r, 2]
            m21 = Tq[2, 0] * T[1, 0] + Tq[2, 1] * T[1, 1] + Tq[2, 2] * T[1, 2]
            m12 = Tq[1, 0] * T[2, 0] + Tq[1, 1] * T[2, 1] + Tq[1, 2] * T[2, 2]
            m02 = Tq[0, 0] * T[2, 0] + Tq[0, 1] * T[2, 1] + Tq[0, 2] * T[2, 2]
            m20 = Tq[2, 0] * T[0, 0] + Tq[2, 1] * T[0, 1] + Tq[2, 2] * T[0, 2]
            m10 = Tq[1, 0] * T[0, 0] + Tq[1, 1] * T[0, 1] + Tq[1, 2] * T[0, 2]
            m01 = Tq[0, 0] * T[1, 0] + Tq[0, 1] * T[1, 1] + Tq[0, 2] * T[1, 2]
            s = 0.5 * np.sqrt((m21 - m12) ** 2 + (m02 - m20) ** 2 + (m10 - m01) ** 2)
            ae[b] = np.arctan2(s, 0.5 * (tr - 1.0))
            if not (inlim and pe[b] <= tol_m and ae[b] <= tol_rad):
                continue
            dup = False
            for a in range(b):
                if valid[a]:
                    same = True
                    for j in range(n):
                        dd = (q[b, j] - q[a, j] + np.pi) % TWO_PI - np.pi
                        if abs(dd) >= 1e-7:
                            same = False
                            break
                    if same:
                        dup = True
                        break
            valid[b] = not dup

    @numba.njit(cache=True, nogil=True)
    def _closed_form_range(family, h, p, R0, P0, wc, xperp, s3, s4, fixed, prismatic, lower, upper, T,
                           tol_m, tol_rad, q, valid, pe, ae, start, stop):  # pragma: no cover - compiled
        for t in range(start, stop):
            Rd = np.empty((3, 3))
            for r in range(3):
                for cc in range(3):
                    Rd[r, cc] = T[t, r, 0] * R0[cc, 0] + T[t, r, 1] * R0[cc, 1] + T[t, r, 2] * R0[cc, 2]
            pt = (T[t, 0, 3], T[t, 1, 3], T[t, 2, 3])
            d = _vsub(_v(wc), _v(P0))
            X = _vadd(pt, _mv(Rd, d))
            ok = np.empty(8, np.bool_)
            if family == 0:
                _opw_one(h, p, Rd, X, _v(wc), _v(xperp), q[t], ok)
            else:
                _ur_one(h, p, Rd, X, pt, _v(wc), _v(P0), _v(xperp), s3, s4, q[t], ok)
            Tq = np.empty((4, 4))
            _finish_one(fixed, prismatic, lower, upper, T[t], q[t], ok, tol_m, tol_rad, valid[t], pe[t], ae[t], Tq)
