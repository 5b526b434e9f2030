"""How many poses: predicted position accuracy against the number of planned poses ``N``.

Two parts, both as root-mean-square TCP position error (mm) over the working region:

* **calibration** (parameter estimation): with scaled identification rows ``J`` of the plan's
  first ``N`` poses (:mod:`hykin.planning.criteria`) and ``M_N = Σ J_iᵀ J_i``, the parameter
  covariance is ``σ² M_N⁻¹`` (``σ²`` = per-coordinate variance of what the calibration cannot
  model: tracker noise ``noise_mm`` plus unmodelled error ``unmodelled_mm / √3``; orientation rows
  of 6-D data count 1 mrad like 1 mm, the calibration's weight). Its effect at a pose ``q`` is
  ``σ² tr(J_q M_N⁻¹ J_qᵀ)``, averaged over uniform poses of the region;
* **unmodelled** error ``u`` (``unmodelled_mm``, RMS of the TCP error norm a full calibration
  leaves: transmission errors, unmodelled elasticity ...): left as is by the calibrated model.

Predicted mean error = ``0.921 × RMS`` (the mean/RMS ratio of a 3-D isotropic Gaussian error,
``√(8 / 3π)``). Calibrated model: ``0.921 √(param² + u²)``.

Hybrid: a learning curve ``h(N) = a · N^-b`` (mm), capped at the calibrated model's error. On the
benchmark robot (``benchmarks/bench_plan.py --curve``, robot seed 100, planned poses, tracker noise
10 µm) the hybrid's error hardly depended on the unmodelled level (0.028-0.034 mm at N = 1,000 for
calibrated errors 0.073-0.12 mm on three robot seeds), so the curve is absolute, not a fraction of
``u``: ``a = 0.574 mm, b = 0.421`` by default (a reference, valid for trackers and robots like that
one); with ``--for-model`` ``a`` is anchored on the model's own hybrid error at its training size.
Validation (predicted against measured on robot seeds 0 and 1, not used for the fit) is in
``docs/planning.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .criteria import IdentificationModel, scaled_rows

__all__ = ["LEARNING_A", "LEARNING_B", "MEAN_OVER_RMS", "Forecast", "forecast_accuracy"]

# Hybrid learning curve h(N) = LEARNING_A * N ** -LEARNING_B (mm), fitted by
# `benchmarks/bench_plan.py --curve --no-main --min-steps 10000` on its robot seed 100 (measured
# 0.0516, 0.0461, 0.0335, 0.0217 mm at N = 250, 500, 1000, 2000 planned poses).
LEARNING_A = 0.574
LEARNING_B = 0.421
MEAN_OVER_RMS = float(np.sqrt(8.0 / (3.0 * np.pi)))


@dataclass
class Forecast:
    """Predicted accuracy per plan size. n: ``(K,)`` sizes; param_mm: RMS position error from
    parameter uncertainty; calibrated_mm / hybrid_mm: predicted mean position error of the
    calibrated model and of the hybrid; hours: estimated measuring time (move + dwell)."""

    n: np.ndarray
    param_mm: np.ndarray
    calibrated_mm: np.ndarray
    hybrid_mm: np.ndarray
    hours: np.ndarray
    noise_mm: float
    unmodelled_mm: float
    learning: tuple[float, float]

    def table(self) -> str:
        lines = [f"{'N':>7} {'param mm':>9} {'calibrated mm':>14} {'hybrid mm':>10} {'hours':>7}"]
        for i in range(len(self.n)):
            lines.append(f"{int(self.n[i]):7d} {self.param_mm[i]:9.4f} {self.calibrated_mm[i]:14.4f} "
                         f"{self.hybrid_mm[i]:10.4f} {self.hours[i]:7.2f}")
        lines.append(f"assumptions: tracker noise {self.noise_mm:g} mm per axis, unmodelled error {self.unmodelled_mm:g} mm RMS, "
                     f"hybrid learning curve {self.learning[0]:.3g} mm N^-{self.learning[1]:.3g} (capped at the calibrated)")
        return "\n".join(lines)

    def to_rows(self) -> dict:
        return {"n": self.n, "param_mm": self.param_mm, "calibrated_mm": self.calibrated_mm,
                "hybrid_mm": self.hybrid_mm, "hours": self.hours}


def learning_curve_mm(n, a: float = LEARNING_A, b: float = LEARNING_B) -> np.ndarray:
    """Hybrid mean position error (mm) for ``n`` training poses (power law ``a n^-b``)."""
    return a * np.asarray(n, dtype=np.float64) ** (-b)


def param_rms_mm(idm: IdentificationModel, J_plan: np.ndarray, J_test: np.ndarray, ns, sigma_mm: float) -> np.ndarray:
    """``(K,)`` RMS position error (mm) from parameter uncertainty for the first ``n`` rows of
    ``J_plan`` ``(N, r, P)``, evaluated on ``J_test`` position rows ``(T, 3, P)``."""
    P = J_plan.shape[-1]
    W = np.einsum("trp,trq->pq", J_test[:, :3], J_test[:, :3]) / len(J_test)  # mean J_tᵀ J_t
    out = np.empty(len(ns))
    for k, n in enumerate(ns):
        A = J_plan[: int(n)].reshape(-1, P)
        M = A.T @ A
        try:
            Minv = np.linalg.inv(M + 1e-12 * np.trace(M) / P * np.eye(P))
        except np.linalg.LinAlgError:
            out[k] = np.inf
            continue
        out[k] = float(np.sqrt(max(sigma_mm**2 * np.trace(W @ Minv), 0.0)))
    return out


def forecast_accuracy(idm: IdentificationModel, q_nested: np.ndarray, q_test: np.ndarray, ns, *, noise_mm: float = 0.01,
                      unmodelled_mm: float = 0.15, learning: tuple[float, float] = (LEARNING_A, LEARNING_B),
                      seconds_per_pose: float = 5.0) -> Forecast:
    """Predicted accuracy (module docstring) for plan prefixes ``q_nested[:n]``, ``n`` in ``ns``.

    q_nested: ``(N, dof)`` plan in selection order (:meth:`hykin.planning.select.Plan.nested`).
    q_test: ``(T, dof)`` poses where the model will be used (uniform over the region).
    seconds_per_pose: move + settle + measure time per pose for the hours column."""
    ns = np.array(sorted({int(n) for n in ns if 1 <= int(n) <= len(q_nested)}), dtype=np.int64)
    r = idm.rows_per_pose
    ns = ns[ns * r > idm.n_params]
    if not (noise_mm >= 0 and unmodelled_mm >= 0):
        raise ValueError(f"noise and unmodelled error must be >= 0 mm, got {noise_mm}, {unmodelled_mm}")
    sigma = float(np.sqrt(noise_mm**2 + unmodelled_mm**2 / 3.0))
    Jp = scaled_rows(idm, q_nested[: int(ns.max()) if ns.size else 0])
    Jt = scaled_rows(idm, q_test)
    par = param_rms_mm(idm, Jp, Jt, ns, sigma)
    cal = MEAN_OVER_RMS * np.sqrt(par**2 + unmodelled_mm**2)
    hyb = np.minimum(cal, learning_curve_mm(ns, *learning))
    return Forecast(n=ns, param_mm=par, calibrated_mm=cal, hybrid_mm=hyb, hours=ns * seconds_per_pose / 3600.0,
                    noise_mm=float(noise_mm), unmodelled_mm=float(unmodelled_mm), learning=(float(learning[0]), float(learning[1])))
