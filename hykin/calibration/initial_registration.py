"""Closed-form start for a calibration from raw measurements: base frame and tool offset(s).

A user's measurements arrive in the tracker's frame, several metres and any rotation away from the
robot base, with a reflector whose offset on the flange is known only roughly (or not at all), and
a robot file without ``[base]``. The local Levenberg–Marquardt of :func:`hykin.calibration.calibrate.calibrate`
linearises the base rotation and cannot bridge a rotation of 90° or a base metres away, so the
calibration first finds base and tool from the nominal kinematics:

measured point ``k`` of sample ``i``: ``p_ik = R_b (f_i + F_i t_k) + b`` with the nominal flange
pose ``(F_i, f_i)`` (robot frame), the unknown base ``(R_b, b)`` and tool point offsets ``t_k``
(flange frame). With ``R_b`` fixed the model is linear in ``(b, t_1..t_K)`` (least squares, one
``3NK × (3 + 3K)`` system); with the offsets fixed ``R_b, b`` is the rigid fit of the points
``f_i + F_i t_k`` onto the measurements (:func:`hykin.geometry.rigid.kabsch`). Alternating the two
decreases the squared residual monotonically but only linearly (the blocks are coupled), so a few
alternations are followed by a joint Gauss–Newton on ``(R_b, b, t_k)``. It is started from
several tool guesses (the robot file's tool, the flange, and the file's tool mirrored) and the start
with the lowest residual is kept. For full-pose data the tool rotation then follows in closed form
from ``R_meas,i = R_b F_i R_t``: ``R_t`` is the rotation nearest to the mean of ``F_iᵀ R_bᵀ R_meas,i``
(the chordal L2 mean, SVD projection).

The nominal geometry errors (mm) only bias this start; the full calibration refines base, tool,
geometry and compliance afterwards.

**What the data cannot tell stays at the robot file.** With the tool held at (nearly) one orientation
the offsets are not excited: ``F_i t`` is then one constant vector, the same as a shift of the base,
and a fit that lets them free explains the nominal geometry's millimetres with a tool metres long
(a 0.03 deg spread turns 1 mm into 2 m). The excitation of the offsets given the base is the Schur
complement ``S`` of their block in the normal equations (independent of ``R_b``); a direction ``v`` of
``S`` (eigenvalue ``λ``) moves the points by ``τ sqrt(λ / NK)`` RMS per tolerance ``τ`` of the tool
(:mod:`hykin.calibration.priors`). Directions below ``max(floor, RMS residual of the free fit)``
(the floor, or the nominal model's error, whichever is larger: an error of that size shifts them by
more than a tolerance) are held at the robot file's tool, and the fit is repeated with only the
others free.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.rigid import kabsch, nearest_rotation
from ..geometry.se3 import rotvec_to_matrix
from ..kinematics.compliance import compliance_of, deflected_joints
from ..kinematics.fk import fk
from ..kinematics.robot import Robot

__all__ = ["InitialRegistration", "initial_registration"]

_ITER = 10  # alternations per start before the joint Gauss-Newton


@dataclass(frozen=True)
class InitialRegistration:
    """Base and tool found from nominal kinematics.

    base: ``(4, 4)`` measurement frame -> robot base (``p_meas = base @ p_robot``).
    tool: ``(4, 4)`` flange -> TCP (reflector 1); its rotation is the robot file's for
    position-only data (not observable from one point per pose).
    offsets_m: ``(K, 3)`` every reflector's offset in the flange frame (row 0 = ``tool[:3, 3]``).
    rms_m: RMS point distance (m) of the nominal robot with these frames; rms_before_m: with the
    robot file's own base and tool. starts: RMS of every start tried (m). held: number of tool-offset
    directions held at the robot file's tool (not excited: module docstring).
    """

    base: np.ndarray
    tool: np.ndarray
    offsets_m: np.ndarray
    rms_m: float
    rms_before_m: float
    starts: tuple[float, ...]
    held: int = 0


def _normal_equations(Rb: np.ndarray, F: np.ndarray, f: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normal equations ``(A (3+3K, 3+3K), rhs)`` in ``(b, t_1..t_K)`` of ``P_ik = R_b (f_i + F_i t_k) + b``."""
    N, K, _ = P.shape
    G = np.einsum("ij,njk->nik", Rb, F)  # (N, 3, 3) = R_b F_i
    r = P - (f @ Rb.T)[:, None, :]  # (N, K, 3) = p - R_b f
    n_unk = 3 + 3 * K
    A = np.zeros((n_unk, n_unk))
    rhs = np.zeros(n_unk)
    A[:3, :3] = N * K * np.eye(3)
    Gs = G.sum(0)
    rhs[:3] = r.sum((0, 1))
    for k in range(K):
        s = slice(3 + 3 * k, 6 + 3 * k)
        A[:3, s] = Gs
        A[s, :3] = Gs.T
        A[s, s] = N * np.eye(3)
        rhs[s] = np.einsum("nji,nj->i", G, r[:, k])
    return A, rhs


def _solve_linear(Rb: np.ndarray, F: np.ndarray, f: np.ndarray, P: np.ndarray, t_prior: np.ndarray | None = None,
                  basis: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """With ``R_b`` fixed: least-squares ``(b (3,), t (K, 3))`` of ``P_ik = R_b (f_i + F_i t_k) + b``, the
    offsets restricted to ``t = t_prior + basis c`` (``basis`` ``(3K, m)``) when given.

    F ``(N, 3, 3)``, f ``(N, 3)``, P ``(N, K, 3)``. Normal equations assembled in closed form
    (``(R_b F_i)ᵀ (R_b F_i) = I``), so the cost is O(N K) and no (3NK × 3+3K) matrix is built.
    """
    K = P.shape[1]
    A, rhs = _normal_equations(Rb, F, f, P)
    if basis is None:
        x = np.linalg.lstsq(A, rhs, rcond=None)[0]
        return x[:3], x[3:].reshape(K, 3)
    t0 = t_prior.reshape(-1)
    M = np.zeros((3 + 3 * K, 3 + basis.shape[1]))
    M[:3, :3] = np.eye(3)
    M[3:, 3:] = basis
    y = np.linalg.lstsq(M.T @ A @ M, M.T @ (rhs - A[:, 3:] @ t0), rcond=None)[0]
    return y[:3], (t0 + basis @ y[3:]).reshape(K, 3)


def _excited_basis(F: np.ndarray, K: int, tol_m: float, floor_m: float) -> np.ndarray:
    """``(3K, m)`` orthonormal directions of the tool offsets the data excite beyond ``floor_m`` per
    tolerance ``tol_m`` (module docstring): eigenvectors of the Schur complement of the offsets."""
    N = F.shape[0]
    A, _ = _normal_equations(np.eye(3), F, np.zeros((N, 3)), np.zeros((N, K, 3)))
    S = A[3:, 3:] - A[3:, :3] @ A[:3, 3:] / A[0, 0]
    lam, V = np.linalg.eigh(0.5 * (S + S.T))
    effect = tol_m * np.sqrt(np.clip(lam, 0, None) / (N * K))
    return V[:, effect >= floor_m]


def _rms(Rb, b, t, F, f, P) -> float:
    X = f[:, None, :] + np.einsum("nij,kj->nki", F, t)
    res = P - (X @ Rb.T + b)
    return float(np.sqrt(np.mean(np.sum(res * res, -1))))


def _gauss_newton(Rb, b, t, F, f, P, iters: int = 15, basis=None):
    """Joint Gauss-Newton on ``(R_b, b, t_k)`` (rotation as a left increment ``exp(ω) R_b``): the
    alternation's end point refined at quadratic speed (the two blocks are coupled, so alternating
    alone converges only linearly)."""
    N, K, _ = P.shape
    rms = _rms(Rb, b, t, F, f, P)
    for _ in range(iters):
        X = f[:, None, :] + np.einsum("nij,kj->nki", F, t)  # (N, K, 3)
        Y = X @ Rb.T  # R_b x
        r = (P - (Y + b)).reshape(-1, 3)  # (NK, 3)
        J = np.zeros((N, K, 3, 6 + 3 * K))
        y = Y
        # d(R_b x)/dω = -[R_b x]_x
        J[..., 0, 1], J[..., 0, 2] = y[..., 2], -y[..., 1]
        J[..., 1, 0], J[..., 1, 2] = -y[..., 2], y[..., 0]
        J[..., 2, 0], J[..., 2, 1] = y[..., 1], -y[..., 0]
        J[..., :, 3:6] = np.eye(3)
        G = np.einsum("ij,njk->nik", Rb, F)  # (N, 3, 3)
        for k in range(K):
            J[:, k, :, 6 + 3 * k: 9 + 3 * k] = G
        J = J.reshape(-1, 6 + 3 * K)
        if basis is not None:  # only the excited offset directions move
            J = np.concatenate([J[:, :6], J[:, 6:] @ basis], 1)
        dx = np.linalg.lstsq(J, r.reshape(-1), rcond=None)[0]
        Rn = rotvec_to_matrix(dx[:3]) @ Rb
        dt = dx[6:] if basis is None else basis @ dx[6:]
        bn, tn = b + dx[3:6], t + dt.reshape(K, 3)
        new = _rms(Rn, bn, tn, F, f, P)
        if not new < rms:
            break
        Rb, b, t, done = Rn, bn, tn, rms - new <= 1e-12 * max(rms, 1e-300)
        rms = new
        if done:
            break
    return Rb, b, t, rms


def _alternate(F, f, P, t0: np.ndarray, t_prior: np.ndarray | None = None, basis: np.ndarray | None = None):
    """Alternate rigid fit / linear offsets from tool offsets ``t0`` ``(K, 3)``, then Gauss-Newton;
    returns (Rb, b, t, rms). With ``basis`` ``(3K, m)``: offsets ``t_prior + basis c`` only."""
    t = t0.copy()
    if basis is not None:
        d = (t0 - t_prior).reshape(-1)
        t = t_prior + (basis @ (basis.T @ d)).reshape(t0.shape)
    Rb, b = np.eye(3), np.zeros(3)
    prev = np.inf
    for _ in range(_ITER):
        X = (f[:, None, :] + np.einsum("nij,kj->nki", F, t)).reshape(-1, 3)
        Rb, b = kabsch(X, P.reshape(-1, 3))
        b, t = _solve_linear(Rb, F, f, P, t_prior, basis)
        rms = _rms(Rb, b, t, F, f, P)
        if prev - rms <= 1e-3 * max(prev, 1e-12):
            break
        prev = rms
    return _gauss_newton(Rb, b, t, F, f, P, basis=basis)


def initial_registration(robot: Robot, q, points, rotations=None, *, tool_guesses=None, tool_tolerance_m: float = 0.1,
                         floor_m: float = 2e-4) -> InitialRegistration:
    """Base and tool offsets of ``robot`` from measurements in an unknown frame.

    q: ``(N, dof)`` joints; points: ``(N, 3)`` or ``(N, K, 3)`` measured points (m), one per
    reflector; rotations: ``(N, 3, 3)`` measured orientations (6-D devices) or None.
    tool_guesses: extra ``(3,)`` flange-frame starts for the first reflector's offset (m).
    tool_tolerance_m / floor_m: the tool's prior tolerance and the excitation floor
    (:mod:`hykin.calibration.priors`): offset directions the data do not excite stay at the file's tool.
    The robot file's base and tool are kept when they explain the data better.
    """
    q = np.asarray(q, dtype=np.float64)
    P = np.asarray(points, dtype=np.float64)
    if P.ndim == 2:
        P = P[:, None, :]
    K = P.shape[1]
    # the deflected joints under gravity (the robot file's compliance, if any): the nominal model
    q_eff = deflected_joints(robot, q) if np.any(compliance_of(robot)) else q
    flange = fk(robot.copy(base=np.eye(4), tool=np.eye(4)), q_eff)
    F, f = flange[:, :3, :3], flange[:, :3, 3]
    t_file = robot.tool[:3, 3]
    guesses = [t_file, np.zeros(3), -t_file, np.array([0.0, 0.0, 0.1]), np.array([0.0, 0.0, -0.1])]
    guesses += [np.asarray(g, dtype=np.float64) for g in (tool_guesses or [])]
    t_prior = np.tile(t_file, (K, 1))

    def fit_all(basis):
        best, rms_all = None, []
        for g in guesses:
            try:
                cand = _alternate(F, f, P, np.tile(g, (K, 1)), t_prior, basis)
            except ValueError:  # collinear flange positions: no rotation from this start
                continue
            rms_all.append(cand[3])
            if best is None or cand[3] < best[3]:
                best = cand
        return best, rms_all

    best, starts = fit_all(None)
    held = 0
    if best is not None:  # offsets the data do not excite beyond the floor (or the nominal error): the file's
        basis = _excited_basis(F, K, tool_tolerance_m, max(floor_m, best[3]))
        held = 3 * K - basis.shape[1]
        if held:
            best, starts = fit_all(basis)
    # the robot file's own frames, as a candidate too (already registered data)
    T0 = fk(robot, q_eff)
    rms_file = float(np.sqrt(np.mean(np.sum((P[:, 0] - T0[:, :3, 3]) ** 2, -1))))
    if best is None or rms_file <= best[3]:
        off = np.tile(t_file, (K, 1))
        return InitialRegistration(robot.base.copy(), robot.tool.copy(), off, rms_file, rms_file, tuple(starts), held)
    Rb, b, t, rms = best
    base = np.eye(4)
    base[:3, :3], base[:3, 3] = Rb, b
    tool = robot.tool.copy()
    tool[:3, 3] = t[0]
    if rotations is not None:
        Rm = np.asarray(rotations, dtype=np.float64)
        M = np.einsum("nji,jk,nkl->il", F, Rb.T, Rm)  # sum_i F_iᵀ R_bᵀ R_meas,i
        tool[:3, :3] = nearest_rotation(M)
    return InitialRegistration(base, tool, t, rms, rms_file, tuple(starts), held)
