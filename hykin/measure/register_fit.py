"""The fit inside a registration (:func:`hykin.measure.register.register_model`): the residual of
``T_meas ≈ B · T_model(q; joint zeros, scale) · E`` (:class:`RegistrationProblem`), the choice of what
besides the two frames to re-fit (:func:`select_extra`: identifiable by QR, significant by
leave-one-pose-out error and t-statistics) and the parameters' standard deviations."""

from __future__ import annotations

import numpy as np

from ..calibration.frames import pose_from_vector6
from ..geometry.se3 import rotation_difference_rotvec

__all__ = ["MIN_PRESS_GAIN", "MIN_T", "RANK_TOL", "SCALE", "RegistrationProblem", "candidate_names", "loo_press",
           "parameter_stds", "robot_with", "select_extra"]


#: Scale of each kind of registration parameter for the identifiability QR (1 mm, 1 mrad, 1e-3 scale).
SCALE = {"frame_m": 1e-3, "frame_rad": 1e-3, "offset": 1e-3, "scale": 1e-3}
RANK_TOL = 0.05  # |R_kk| / ||column|| below this: redundant with the parameters before it
MIN_PRESS_GAIN = 0.03  # a parameter is kept only if it lowers the leave-one-pose-out error by >= 3 %
MIN_T = 3.0  # ... and its estimate is at least 3 standard deviations from zero


def candidate_names(model, series_has_temperature: bool) -> list[str]:
    """Joint-zero and thermal-scale candidates beyond the 12 frame parameters, in priority order. No thermal
    scale where the series carries temperatures and the model expands with them (a kept thermal coefficient):
    the temperatures say the thermal state, and a scale fitted on top of it is applied to the whole model
    (probe report s40: a third station's series re-fitted -13.9 ppm and made the other stations 0.016 ->
    0.049 mm worse)."""
    rob = model.robot_
    out = []
    if rob.convention in ("dh", "mdh"):
        out += [f"q{j + 1}.zero" for j in range(rob.dof) if rob.independent_joint_type[j] == "revolute"]
    th = getattr(model, "thermal_", None)
    if not (series_has_temperature and th is not None and getattr(th, "coefficient_per_k", 0.0)):
        out.append("thermal.scale")
    return out


def robot_with(rob, names: list[str], x: np.ndarray):
    """``rob`` with joint zero offsets (rad) and a uniform length scale (thermal state) applied."""
    if not names:
        return rob
    th = rob.theta_rad.copy()
    s = 0.0
    for nm, v in zip(names, x):
        if nm == "thermal.scale":
            s = v
        else:
            th[int(nm[1:].split(".")[0]) - 1] += v
    ch = {"theta_rad": th}
    if s != 0.0:
        f = 1.0 + s
        base, tool = rob.base.copy(), rob.tool.copy()
        base[:3, 3] *= f
        tool[:3, 3] *= f
        ch.update(a_m=rob.a_m * f, d_m=rob.d_m * f, base=base, tool=tool, origin_xyz_m=rob.origin_xyz_m * f)
    return rob.copy(**ch)


class RegistrationProblem:
    """Registration residual ``T_meas ≈ B · T_model(q; offsets, scale) · E`` on the used poses.

    The model's own correction (networks, thermal) is kept from its prediction ``T_h0`` and the
    extra parameters act through the classical chain: ``p = p_h0 + p_c(x) - p_c(0)``,
    ``R = R_c(x) R_c(0)ᵀ R_h0``."""

    def __init__(self, model, q, T_h0, T_meas, extra: list[str], position_only: bool, w: float = 1.0):
        from ..kinematics.classical import classical_fk

        self.model, self.q, self.T_h0, self.T_meas = model, q, T_h0, T_meas
        self.extra, self.pos_only, self.w = list(extra), position_only, w
        self.T_c0 = classical_fk(model.robot_, q)
        self._fk = classical_fk

    def poses(self, x: np.ndarray) -> np.ndarray:
        T = self.T_h0
        if self.extra and np.any(x[12:] != 0):
            Tc = self._fk(robot_with(self.model.robot_, self.extra, x[12:]), self.q)
            T = np.array(self.T_h0, copy=True)
            T[:, :3, 3] += Tc[:, :3, 3] - self.T_c0[:, :3, 3]
            T[:, :3, :3] = Tc[:, :3, :3] @ np.swapaxes(self.T_c0[:, :3, :3], 1, 2) @ self.T_h0[:, :3, :3]
        B = pose_from_vector6(x[:6])
        E = pose_from_vector6(np.concatenate([np.zeros(3) if self.pos_only else x[6:9], x[9:12]]))
        return B @ T @ E

    def resid(self, x: np.ndarray) -> np.ndarray:
        """``(N, 3 or 6)`` residual rows per pose (m, and w · rad)."""
        T = self.poses(x)
        r = T[:, :3, 3] - self.T_meas[:, :3, 3]
        if self.pos_only:
            return r
        return np.concatenate([r, self.w * rotation_difference_rotvec(T[:, :3, :3], self.T_meas[:, :3, :3])], 1)

    def jac(self, x: np.ndarray, h: float = 1e-7) -> np.ndarray:
        """Central-difference Jacobian ``(N, rows, P)`` of :meth:`resid` (SI units)."""
        cols = []
        for k in range(len(x)):
            e = np.zeros(len(x))
            e[k] = h
            cols.append((self.resid(x + e) - self.resid(x - e)) / (2 * h))
        return np.stack(cols, -1)


def loo_press(r: np.ndarray, J: np.ndarray) -> float:
    """Leave-one-pose-out prediction error sum of squares of the linearised fit ``J dx ≈ -r``: each
    pose's rows are left out together (``e_i = (I - H_ii)⁻¹ r_i`` of the fitted residual)."""
    N, m, P = J.shape
    A = J.reshape(N * m, P)
    sol, *_ = np.linalg.lstsq(A, -r.ravel(), rcond=None)
    rf = (r.ravel() + A @ sol).reshape(N, m)
    G = np.linalg.pinv(A.T @ A)
    H = np.einsum("nip,pq,njq->nij", J, G, J)  # (N, m, m) diagonal blocks of the hat matrix
    I = np.eye(m)
    e = np.linalg.solve(I[None] - H + 1e-12 * I[None], rf[..., None])[..., 0]
    return float((e**2).sum())


def parameter_stds(prob: RegistrationProblem, x: np.ndarray, pos_only: bool) -> dict[int, float]:
    """Standard deviation of each fitted parameter (index into ``x``; a positions-only fit has no tool
    rotation): ``sigma^2 (J^T J)^-1`` at ``x``, sigma from the residual."""
    J = prob.jac(x)
    r = prob.resid(x)
    cols = [k for k in range(len(x)) if not (pos_only and 6 <= k < 9)]
    A = J[..., cols].reshape(-1, len(cols))
    s2 = float((r**2).sum()) / max(A.shape[0] - len(cols), 1)
    return dict(zip(cols, np.sqrt(np.maximum(np.diag(np.linalg.pinv(A.T @ A)) * s2, 0.0))))


def select_extra(prob: RegistrationProblem, x0: np.ndarray, cands: list[str]) -> tuple[list[str], dict[str, str]]:
    """Which of ``cands`` to re-fit: identifiable after the frames (QR of the scaled Jacobian, priority
    order frames, joints base to tip, thermal scale) and significant (backward elimination by
    leave-one-pose-out error of the linearised fit: each kept parameter lowers it by >= 3 % and is
    >= 3 std from zero).
    Returns the chosen names and, for each candidate left out, why."""
    from ..calibration.identifiability import identifiable_columns

    why: dict[str, str] = {}
    if not cands:
        return [], why
    full = RegistrationProblem(prob.model, prob.q, prob.T_h0, prob.T_meas, cands, prob.pos_only, prob.w)
    x = np.concatenate([x0, np.zeros(len(cands))])
    r = full.resid(x)
    J = full.jac(x)
    N, m, P = J.shape
    sc = np.array([SCALE["frame_rad"]] * 3 + [SCALE["frame_m"]] * 3 + [SCALE["frame_rad"]] * 3 + [SCALE["frame_m"]] * 3
                  + [SCALE["scale" if c == "thermal.scale" else "offset"] for c in cands])
    frame_cols = [k for k in range(12) if not (prob.pos_only and 6 <= k < 9)]
    keep_cols = frame_cols + list(range(12, P))
    Js = (J * sc)[..., keep_cols].reshape(N * m, -1)
    mask, ratio = identifiable_columns(Js, RANK_TOL, 1e-6)
    ident = [c for k, c in enumerate(cands) if mask[len(frame_cols) + k]]
    for k, c in enumerate(cands):
        if c not in ident:
            why[c] = f"not identifiable from these poses (QR ratio {ratio[len(frame_cols) + k]:.3f})"
    floor = N * m * (1e-7) ** 2  # below 0.1 µm per row there is nothing left to explain

    def fit_stats(names):
        cols = frame_cols + [12 + cands.index(k) for k in names]
        A = J[..., cols].reshape(N * m, -1)
        dx, *_ = np.linalg.lstsq(A, -r.ravel(), rcond=None)
        s2 = float(((r.ravel() + A @ dx) ** 2).sum()) / max(N * m - len(cols), 1)
        std = np.sqrt(np.maximum(np.diag(np.linalg.pinv(A.T @ A)) * s2, 1e-300))
        return loo_press(r, J[..., cols]), np.abs(dx[len(frame_cols):]) / std[len(frame_cols):]

    # Backward elimination from every identifiable candidate (forward selection misses parameters
    # that only act together, e.g. opposite zero drifts of two parallel joints).
    chosen = list(ident)
    while chosen and len(frame_cols) + len(chosen) > N * m // 3:  # few poses: at most a third as many unknowns as rows
        why[chosen.pop()] = f"too few poses ({N}) to re-fit it beside the frames"
    if not chosen:
        return [], why
    press, t = fit_stats(chosen)
    while chosen:
        trials = [(fit_stats([k for k in chosen if k != c])[0], c) for c in chosen]
        pr, c = min(trials)
        weak = int(np.argmin(t))
        if pr <= press + max(MIN_PRESS_GAIN * pr, floor):
            why[c] = "not significant (leaving it out changes the leave-one-pose-out error by less than 3 %)"
        elif t[weak] < MIN_T:
            c = chosen[weak]
            why[c] = f"not significant (|estimate| {t[weak]:.1f} std < {MIN_T:g})"
        else:
            break
        chosen.remove(c)
        press, t = fit_stats(chosen)
    return [c for c in cands if c in chosen], why
