"""How fast the calibrated model's error grows beyond the joint ranges it was fitted on.

Split-conformal quantiles (see :meth:`hykin.hybrid.model.HybridModel.predict_uncertainty`) hold for queries
like the validation data. Outside the trained joint ranges the hybrid falls back to the calibrated
classical model, whose parameters were identified on the same ranges and so extrapolate too: on a
virtual RX160 trained on the middle half of every joint range, its mean error grows from 0.128 mm
inside to 0.211 mm outside, and an in-range band covers only 54 % of the errors there.

This module measures that growth on the training data alone, by emulating extrapolation: for every
network input joint ``j``, the calibration is refitted without the outer ``fraction`` of the range
at both ends and evaluated on the samples left out, whose distance beyond the reduced range is known. With ``r`` the ``level`` quantile of the refit's in-range errors and ``d`` the excess
in units of the reduced range, the left-out samples (pooled over splits) are binned by ``d``; the
``level`` quantile of ``error / r`` per bin is fitted by ``1 + a + k d`` (least squares, ``a, k >=
0``), so that the band ``r (1 + a + k d)`` is calibrated on emulated extrapolation the way the
in-range band is calibrated on held-out data. Several joints out of range: the largest step plus
the sum of the slopes times the excesses.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from ..geometry import se3

__all__ = ["extrapolation_growth", "fit_bands"]


def _errors(predict, ds, idx, with_rot: bool):
    T = predict(ds.q[idx])
    pe = np.linalg.norm(T[:, :3, 3] - ds.xyz_m[idx], axis=1) * 1e3
    ae = se3.pose_error(ds.poses()[idx], T)[1] if with_rot else None
    return pe, ae


def extrapolation_growth(robot, train, qn: np.ndarray, joints: np.ndarray, levels: np.ndarray, *,
                         calibrate_kw: dict | None, with_rot: bool, seed: int = 0, fraction: float = 0.2,
                         n_fit: int = 2000, n_out: int = 800, n_bins: int = 8) -> dict:
    """Growth ``k(level)`` of the calibrated model's error band per unit of range excess.

    robot: the nominal robot; train: the training Dataset; qn: ``(N, n)`` its joints in the
    coordinates the range excess is measured in (the networks' inputs); joints: ``(n,)`` bool, the
    joints that count; levels: ``(L,)`` band levels. calibrate_kw: keyword arguments of
    :func:`hykin.calibration.calibrate.calibrate` (``None``: no calibration, the nominal model is evaluated).
    Refits use at most ``n_fit`` samples and evaluate at most ``n_out`` left-out ones per split.
    Returns ``{"pos_mm": (L, n), "pos_mm_step": (L, n), "ang_deg", "ang_deg_step" (or None),
    "n_splits", "n_points"}``: per level and joint the slope ``k`` and the step ``a`` of the band
    factor ``1 + a + k d`` beyond the range (0 for joints not counted or with fewer than 50 left-out
    samples); see :func:`_fit_growth`.
    """
    from ..calibration.calibrate import CalibrationError, calibrate
    from ..kinematics.classical import classical_fk

    rng = np.random.default_rng(seed)
    n = qn.shape[1]
    keys = ("pos_mm", "ang_deg") if with_rot else ("pos_mm",)
    out = {"pos_mm": np.zeros((len(levels), n)), "ang_deg": np.zeros((len(levels), n)) if with_rot else None,
           "n_splits": 0, "n_points": 0}
    for key in keys:
        out[key + "_step"] = np.zeros((len(levels), n))
    lo, hi = qn.min(0), qn.max(0)
    span = hi - lo
    for j in np.flatnonzero(joints & (span > 1e-6)):
        # keep the middle of joint j's range (both ends cut, as when a robot is trained on a working
        # range and then used beyond it on either side), evaluate on the ends
        cut_lo, cut_hi = lo[j] + fraction * span[j], hi[j] - fraction * span[j]
        excess = np.maximum(cut_lo - qn[:, j], qn[:, j] - cut_hi) / (cut_hi - cut_lo)
        inside, outside = np.flatnonzero(excess <= 0), np.flatnonzero(excess > 0)
        if len(inside) < 50 or len(outside) < 50:
            continue
        fit_idx = rng.permutation(inside)[:n_fit]
        out_idx = rng.permutation(outside)[:n_out]
        if calibrate_kw is None:
            rob = robot
        else:
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    rob = calibrate(robot, train.subset(np.sort(fit_idx)), **calibrate_kw).robot
            except CalibrationError:
                continue
        predict = lambda q, r=rob: classical_fk(r, q)
        e_in = dict(zip(("pos_mm", "ang_deg"), _errors(predict, train, fit_idx, with_rot)))
        e_out = dict(zip(("pos_mm", "ang_deg"), _errors(predict, train, out_idx, with_rot)))
        d = excess[out_idx]
        out["n_splits"] += 1
        out["n_points"] += len(d)
        for key in keys:
            r = np.maximum(np.quantile(e_in[key], levels), 1e-300)  # (L,)
            out[key + "_step"][:, j], out[key][:, j] = _fit_growth(d, e_out[key][None, :] / r[:, None], levels, n_bins)
    return out


def _fit_growth(d: np.ndarray, z: np.ndarray, levels: np.ndarray, n_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Fit the per-bin ``level`` quantile of ``z`` (equal-count bins of ``d``) by ``1 + a + k d`` with
    ``a, k >= 0`` (least squares). Returns ``(a (L,), k (L,))``. ``a`` is the step just past the range
    edge: the in-range band is an average over the range, and the error at its edge can already be
    larger. A per-sample bound would be dominated by samples just past the cut, where ``d -> 0``."""
    order = np.argsort(d)
    bins = np.array_split(order, min(n_bins, max(1, len(d) // 25)))
    dm = np.array([d[b].mean() for b in bins])
    X = np.c_[np.ones_like(dm), dm]
    a, k = np.zeros(len(levels)), np.zeros(len(levels))
    L = len(levels)
    # (bins, L): row i's level-i quantile in each bin; one call per bin for all rows and levels, then the
    # diagonal (each entry is computed as the scalar call would: 100 levels x 8 bins were 800 calls per key)
    Y = np.stack([np.quantile(z[:, b], levels, axis=1)[np.arange(L), np.arange(L)] for b in bins]) - 1.0
    for i in range(L):
        y = Y[:, i]
        ai, ki = np.linalg.lstsq(X, y, rcond=None)[0]
        if ki < 0:  # no growth: a constant step
            ai, ki = float(y.mean()), 0.0
        if ai < 0:  # no step: a slope through (0, 0)
            ai, ki = 0.0, max(0.0, float(dm @ y / (dm @ dm)))
        a[i], k[i] = max(0.0, ai), ki
    return a, k


def _calibration_kwargs(model) -> dict:
    """The keyword arguments of :func:`hykin.calibration.calibrate.calibrate` the model was calibrated
    with (a region-blocked selection replaced by the parameter set it chose)."""
    kw = dict(model.calibrate_kw or {})
    kw.pop("select", None)
    if getattr(model, "calibration_cv_", None) is not None:
        kw.update(model.calibration_cv_.kwargs)
    # the full calibration checked these data's orientations against their positions already
    kw["max_deviation"] = {**(kw.get("max_deviation") or {}), "orientation_conflict": math.inf}
    return kw


def fit_bands(model, train, val, held_out_index, raw, record: dict) -> dict:
    """The band state ``unc`` of a just fitted ``model`` (:mod:`hykin.hybrid.bands`): quantiles of the
    hybrid and classical error norms on held-out samples (split conformal: ``val`` when given, else the
    ``held_out_index`` rows of ``train``), the calibrated model's extrapolation growth (an optional step
    of its own: on failure one warning and bands without growth, ``record`` names it) and, for a model
    with a thermal coefficient, the quantiles against the raw measurements ``raw`` (no temperature)."""
    from ..io.payload import payload_of
    from . import bands
    from .optional import optional_step

    ds, src = bands.band_source(train, val, held_out_index)
    T_c, T_h = model._predict_unframed(ds.q, payload_of(ds))
    unc = {"levels": bands.UNC_LEVELS, "n": len(ds), "source": src}
    unc.update(bands.error_quantiles(ds, T_c, T_h, with_rot=ds.has_orientation and model.net_rot_ is not None))
    # how the calibrated model's band widens beyond the trained ranges (emulated extrapolation)
    g = optional_step(
        "extrapolation growth of the uncertainty bands", record, extrapolation_growth, model.robot, train,
        model._netq(np.asarray(train.q, dtype=np.float64)), model.input_mask_, bands.UNC_LEVELS,
        calibrate_kw=_calibration_kwargs(model) if model.calibrate else None,
        with_rot="classical_ang_deg" in unc, seed=int(model.seed))
    if g is not None:
        unc.update(bands.growth_entries(g))
    th = model.thermal_
    if th is not None and th.coefficient_per_k != 0.0:
        T_c, T_h = model._predict_unframed(raw.q, payload_of(raw))
        unc.update(bands.notemp_quantiles(unc, raw, T_c, T_h))
    return unc
