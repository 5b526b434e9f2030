"""Identifiability criteria on the identification Jacobian of the calibration.

The Jacobian is :func:`hykin.calibration.jacobian.identification_jacobian` (geometry, base, tool, joint
compliance: exactly what :func:`hykin.calibration.calibrate.calibrate` estimates), scaled like the calibration
scales it (:func:`hykin.calibration.identifiability.parameter_scales`: 1 mm, 1 mrad, 1e-6 rad/N·m) and expressed in
mm of TCP displacement per typical deviation, restricted to the parameters the calibration would
estimate (:func:`hykin.calibration.priors.excitation`, the calibration's test, on a spread sample of the
candidate pool; the others it holds at the robot file's value).

Criteria of a set of poses with scaled rows ``J`` (``(N, r, P)``) and information ``M = Σ J_iᵀ J_i``:

* D-optimality: ``log det M`` (maximised by :func:`hykin.planning.select.d_optimal`);
* observability indices (Sun & Hollerbach 2008): ``O1 = (σ_1 ··· σ_P)^(1/P) / √N`` (D-type),
  ``O3 = σ_min`` (E-type) and ``O4 = σ_min² / σ_max`` (noise amplification), ``σ`` the singular
  values of the stacked ``J``;
* predicted parameter covariance ``σ² M⁻¹`` (scaled units) for :mod:`hykin.planning.forecast`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..calibration.identifiability import parameter_scales
from ..calibration.jacobian import identification_jacobian
from ..kinematics.robot import Robot

__all__ = ["IdentificationModel", "identification_model", "information", "observability", "scaled_rows"]

_MM_PER_M = 1e3
_ID_SAMPLES = 600  # spread samples for the identifiability test (as calibrate does)


@dataclass
class IdentificationModel:
    """What the calibration will estimate for a robot and a measurement kind.

    names: identifiable parameter names (calibration priority order). scales: ``(P,)`` SI typical
    deviations. position_only: rows per pose 3 (position) or 6 (pose, orientation weighted by
    ``orientation_weight_m_per_rad``). all_names: every candidate parameter; columns: indices of the
    identifiable ones among them.
    """

    robot: Robot
    names: list[str]
    scales: np.ndarray
    columns: np.ndarray
    all_names: list[str]
    position_only: bool = True
    orientation_weight_m_per_rad: float = 1.0
    compliance: bool = True

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def rows_per_pose(self) -> int:
        return 3 if self.position_only else 6


def scaled_rows(model: IdentificationModel, q) -> np.ndarray:
    """``(N, r, P)`` identification Jacobian of the identifiable parameters, scaled: TCP mm (and
    ``w ·`` mrad·m/rad) per typical deviation of each parameter."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, model.robot.dof)
    out = np.empty((len(q), model.rows_per_pose, model.n_params))
    for lo in range(0, len(q), 20_000):  # bounded memory: (chunk, 6, P_all) doubles
        _, J = identification_jacobian(model.robot, q[lo : lo + 20_000], position_only=model.position_only,
                                       orientation_weight_m_per_rad=model.orientation_weight_m_per_rad,
                                       compliance=model.compliance)
        out[lo : lo + 20_000] = J[:, :, model.columns] * (model.scales * _MM_PER_M)
    return out


def identification_model(robot: Robot, q_pool, *, position_only: bool = True, orientation_weight_m_per_rad: float = 1.0,
                         compliance: bool = True, rank_tol: float = 1e-6, negligible_tol: float = 1e-9
                         ) -> IdentificationModel:
    """Parameters the calibration would estimate from the joints ``q_pool`` ``(N, dof)``: the
    calibration's excitation test (:func:`hykin.calibration.priors.excitation`, default priors, the
    rank tolerances given) on up to 600 evenly spread rows of the pool."""
    from ..calibration.params import candidate_specs
    from ..calibration.priors import DEFAULT_PRIORS, excitation, prior_tolerances
    from ..kinematics.compliance import gravity_torques

    q_pool = np.asarray(q_pool, dtype=np.float64).reshape(-1, robot.dof)
    all_names = identification_jacobian(robot, q_pool[:1], position_only=position_only, compliance=compliance)[0]
    scales_all = parameter_scales(robot, compliance=compliance)
    full = IdentificationModel(robot, all_names, scales_all, np.arange(len(all_names)), all_names, position_only,
                               float(orientation_weight_m_per_rad), compliance)
    idx = np.unique(np.linspace(0, len(q_pool) - 1, min(len(q_pool), _ID_SAMPLES)).astype(np.int64))
    J = scaled_rows(full, q_pool[idx]) / _MM_PER_M  # (n, rows, P): m (weighted rad) per typical deviation
    tau = None
    if compliance:  # the compliance tolerance is a deflection under the pool's gravity torques (as calibrate)
        rows = np.unique(np.linspace(0, len(q_pool) - 1, min(len(q_pool), 2000)).astype(np.int64))
        tau = np.abs(gravity_torques(robot, np.ascontiguousarray(q_pool[rows]))).max(0)
    specs = candidate_specs(robot, base=True, tool=True, compliance=compliance)
    floor = np.array([DEFAULT_PRIORS["excitation_mm"] * 1e-3] * 3
                     + [float(orientation_weight_m_per_rad) * np.radians(DEFAULT_PRIORS["excitation_deg"])] * 3)
    row_floor = np.tile(floor[: J.shape[1]], len(idx))
    mask = excitation(J.reshape(-1, len(all_names)), len(idx), prior_tolerances(specs, DEFAULT_PRIORS, tau), scales_all,
                      row_floor, negligible_tol, rank_tol).excited
    cols = np.flatnonzero(mask)
    return IdentificationModel(robot, [all_names[k] for k in cols], scales_all[cols], cols, all_names, position_only,
                               float(orientation_weight_m_per_rad), compliance)


def information(J: np.ndarray) -> np.ndarray:
    """``(P, P)`` information matrix ``Σ J_iᵀ J_i`` of scaled rows ``(N, r, P)``."""
    A = J.reshape(-1, J.shape[-1])
    return A.T @ A


def observability(J: np.ndarray) -> dict:
    """Criteria of a pose set with scaled rows ``(N, r, P)`` (module docstring): ``logdet`` (of M),
    ``O1``, ``O3``, ``O4``, ``condition`` (σ_max / σ_min)."""
    N, _, P = J.shape
    s = np.linalg.svd(J.reshape(-1, P), compute_uv=False)
    if s.size < P or s[-1] <= 0:
        return {"logdet": -np.inf, "O1": 0.0, "O3": 0.0, "O4": 0.0, "condition": np.inf}
    return {
        "logdet": float(2.0 * np.sum(np.log(s))),
        "O1": float(np.exp(np.mean(np.log(s))) / np.sqrt(N)),
        "O3": float(s[-1]),
        "O4": float(s[-1] ** 2 / s[0]),
        "condition": float(s[0] / s[-1]),
    }
