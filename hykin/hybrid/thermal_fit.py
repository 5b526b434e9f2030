"""Thermal expansion in the hybrid model: the coefficient identified with the calibration in ``fit``
and its application to predictions and targets (:mod:`hykin.calibration.thermal` holds the physics:
one linear coefficient, positions scaled about the base origin)."""

from __future__ import annotations

import numpy as np

from ..calibration.thermal import (
    DRIFT_WARNING,
    MAX_PLAUSIBLE_PER_K,
    MIN_EFFECT_M,
    ThermalFit,
    fit_coefficient,
    scale_about,
    temperature_of,
    to_reference,
)
from ..io.payload import payload_kwargs, payload_of
from ..kinematics.classical import classical_fk
from .errors import HybridError

__all__ = ["apply_thermal", "fit_thermal", "targets_at_reference", "thermal_factor", "warn_station_temperatures"]


def fit_thermal(train, val, temp: np.ndarray, robot, calibration, recalibrate=None, rounds: int = 3,
                tolerance_per_k: float | None = None):
    """Identify the expansion coefficient (1/K) together with the calibration.

    ``train``/``val``: Datasets (``val`` may be None); ``temp``: ``(N,)`` °C of ``train``; ``robot`` /
    ``calibration``: the calibration at the measured temperatures; ``recalibrate(ds) -> (robot,
    calibration)``: calibrates on data mapped to the reference temperature (None: the model does not
    calibrate, one round); ``tolerance_per_k``: prior standard deviation of the coefficient about 0
    (default :data:`hykin.calibration.priors.DEFAULT_PRIORS` ``thermal_per_k``). Returns ``(robot,
    calibration, thermal, train, val)``: the coefficient is kept only if significant, physical
    (positive, at most 60e-6 /K) and not negligible (else ``thermal`` records why, robot, calibration
    and data are returned as given, and a significant non-physical coefficient warns once: drift of
    the instrument, :mod:`hykin.calibration.thermal`); otherwise the data are mapped to the reference
    temperature (mean of ``temp``)."""
    import warnings

    from ..calibration.priors import DEFAULT_PRIORS

    tol = DEFAULT_PRIORS["thermal_per_k"] if tolerance_per_k is None else float(tolerance_per_k)
    ref = float(temp.mean())
    dt = temp - ref
    q = np.asarray(train.q, dtype=np.float64)
    first = (robot, calibration)
    alpha, std = 0.0, float("inf")
    for _ in range(rounds):
        b = robot.base[:3, 3]
        alpha, std = fit_coefficient(train.xyz_m, classical_fk(robot, q, **payload_kwargs(payload_of(train)))[:, :3, 3],
                                     b, dt, alpha, tol)
        if recalibrate is None or abs(alpha) > 3.0 * std and not 0.0 < alpha <= MAX_PLAUSIBLE_PER_K:
            break  # not the arm's expansion (below): no recalibration on data mapped with it
        robot, calibration = recalibrate(to_reference(train, b, alpha, dt))
    rng_c = (float(temp.min()), float(temp.max()))
    # size of the effect in the data: alpha x temperature spread x reach (RMS), metres
    reach = float(np.sqrt(np.mean(np.sum((train.xyz_m - robot.base[:3, 3]) ** 2, axis=1))))
    effect_m = abs(alpha) * float(np.std(dt)) * reach
    why = None
    if abs(alpha) < 3.0 * std:
        why = "not significant (|alpha| < 3 std)"
    elif alpha <= 0.0 or alpha > MAX_PLAUSIBLE_PER_K:
        sign = "negative: no arm shrinks as it warms" if alpha <= 0 else f"beyond {MAX_PLAUSIBLE_PER_K:g} /K of any arm"
        warnings.warn(DRIFT_WARNING.format(alpha=alpha, why=sign), UserWarning, stacklevel=2)
        why = f"{sign}: drift of the instrument, not expansion of the arm"
    elif effect_m < MIN_EFFECT_M:
        why = f"negligible ({effect_m * 1e6:.2g} µm RMS in these data, below {MIN_EFFECT_M * 1e6:g} µm)"
    if why is not None:
        thermal = ThermalFit(0.0, std, ref, rng_c, f"ignored: alpha = {alpha:.3g} +- {std:.2g} /K is {why}")
        return first[0], first[1], thermal, train, val
    thermal = ThermalFit(alpha, std, ref, rng_c, f"alpha = {alpha:.4g} +- {std:.2g} /K "
                         f"({effect_m * 1e6:.2g} µm RMS in the training data)")
    b = robot.base[:3, 3]
    train = to_reference(train, b, alpha, dt)
    tv = None if val is None else temperature_of(val)
    if tv is not None:
        val = to_reference(val, b, alpha, tv - ref)
    return robot, calibration, thermal, train, val


def thermal_factor(thermal: ThermalFit | None, temperature_c, n: int) -> np.ndarray | None:
    """Scale factors ``(n,)`` for queries at ``temperature_c`` (°C, scalar or ``(n,)``); None when
    there is no thermal correction (no temperature, no or a zero coefficient)."""
    if temperature_c is None or thermal is None or thermal.coefficient_per_k == 0.0:
        return None
    t = np.asarray(temperature_c, dtype=np.float64).reshape(-1)
    if t.size not in (1, n):
        raise HybridError(f"temperature_c must be a scalar or one value per query ({n}), got {t.size} values")
    t = np.broadcast_to(t, (n,))
    if not np.isfinite(t).all():
        raise HybridError(f"temperature_c: non-finite value in row {int(np.argmax(~np.isfinite(t))) + 1}")
    return 1.0 + thermal.coefficient_per_k * (t - thermal.reference_c)


def apply_thermal(T: np.ndarray, thermal: ThermalFit | None, base_xyz_m: np.ndarray, temperature_c) -> np.ndarray:
    """Poses ``T`` ``(N, 4, 4)`` at the reference temperature -> at ``temperature_c`` (positions scaled
    about the base origin ``base_xyz_m`` ``(3,)``); ``T`` itself when there is no correction."""
    f = thermal_factor(thermal, temperature_c, len(T))
    return T if f is None else scale_about(T, base_xyz_m, f)


def targets_at_reference(T_target, temperature_c, thermal: ThermalFit | None, base_xyz_m: np.ndarray,
                         frame_pre: np.ndarray, frame_post: np.ndarray):
    """Exact inverse of the thermal scaling of a prediction (see
    :meth:`hykin.hybrid.model.HybridModel.targets_at_reference`): ``T_target`` ``(N, 4, 4)`` poses or
    ``(N, 3)`` positions (m) measured at ``temperature_c`` -> the same at the reference temperature,
    through the registration frames ``frame_pre``/``frame_post`` ``(4, 4)``."""
    T_target = np.asarray(T_target, dtype=np.float64)
    pos = T_target.shape[-2:] != (4, 4)  # positions (N, 3) / (3,), else poses (N, 4, 4) / (4, 4)
    n = T_target.size // (3 if pos else 16)
    f = thermal_factor(thermal, temperature_c, n)
    if f is None:
        return T_target
    T = np.tile(np.eye(4), (n, 1, 1)) if pos else T_target.reshape(-1, 4, 4).copy()
    if pos:
        T[:, :3, 3] = T_target.reshape(-1, 3)
    Tm = np.linalg.inv(frame_pre) @ T @ (np.eye(4) if pos else np.linalg.inv(frame_post))
    Tm = scale_about(Tm, base_xyz_m, 1.0 / f)
    out = frame_pre @ Tm @ (np.eye(4) if pos else frame_post)
    return out[:, :3, 3].reshape(T_target.shape) if pos else out.reshape(T_target.shape)


def warn_station_temperatures(thermal, train, temp: np.ndarray) -> None:
    """Warn (:class:`hykin.hybrid.errors.FitWarning`) when a kept thermal coefficient comes from data whose
    stations were measured at different temperatures (their mean temperatures apart by more than the
    spread within a station): the station frames are fitted before the coefficient, at the measured
    temperatures, and take up part of the expansion between stations, so the coefficient is biased low
    (probe report s40: 5.98e-6 /K identified for a true 12e-6 /K, stations at 20-24 and 24-28 °C; 11.9e-6
    with one station). ``train``: the data with their ``station`` column, ``temp`` ``(N,)`` °C."""
    import warnings

    from ..io.dataset import STATION_COLUMN, row_labels
    from .errors import FitWarning

    if thermal is None or not thermal.coefficient_per_k or STATION_COLUMN not in (getattr(train, "extra", None) or {}):
        return
    lab = row_labels(train, STATION_COLUMN)
    names = list(dict.fromkeys(lab.tolist()))
    if len(names) < 2:
        return
    t = np.asarray(temp, dtype=np.float64)
    means = np.array([t[lab == n].mean() for n in names])
    within = float(np.sqrt(np.mean([np.var(t[lab == n]) for n in names])))
    if np.ptp(means) <= within:
        return
    ranges = ", ".join(f"{n} {t[lab == n].min():.1f}-{t[lab == n].max():.1f} °C" for n in names)
    warnings.warn(f"the stations were measured at different temperatures ({ranges}): their frames, fitted at the "
                  f"measured temperatures, take up part of the expansion between them, so the thermal coefficient "
                  f"({thermal.coefficient_per_k * 1e6:.3g}e-6 /K) is likely biased low; measure every station over the "
                  "same temperatures, or compare a fit with --thermal off", FitWarning, stacklevel=3)
