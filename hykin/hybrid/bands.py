"""Split-conformal uncertainty bands of the hybrid model.

:meth:`HybridModel.predict_uncertainty`: radii of the ``level`` band (e.g. 95 %) of the
position (mm) and orientation (deg) error per query, split-conformal: empirical quantiles of the
error norms of the hybrid and of the calibrated model on held-out validation samples, blended by
``w`` = the fade of :meth:`support_distance` (``w r_hybrid + (1 - w) max(g r_classical, r_hybrid)``):
outside the training data the band becomes that of the calibrated model, widened by
``g = 1 + max_j a_j + sum_j k_j e_j`` over the joints beyond their trained range (``e_j`` the
range excess): the calibration extrapolates too. The step ``a_j`` and slope ``k_j`` are measured
in ``fit`` by refitting the calibration on the middle of each joint's range and evaluating on its
ends (:mod:`hykin.hybrid.uncertainty`; a few seconds). Cheap at query time (no ensemble), never on the
:meth:`predict` path. Coverage of the 95 % band on a virtual RX160 (rx160-nongeo) trained on the
middle half of every joint range, queried on the full range: outside the range 54 % (position)
with the in-range band alone, 90-93 % with the growth (orientation 72 % -> 90-92 %). UR10 series A
held-out 94.8 % (position) / 95.5 % (orientation); series B (new series, registered from 30 poses)
92.8 % / 94.8 %; virtual in range 94.4 % / 94.9 % (benchmarks/bench_region.py).

The band state ``unc`` is a plain dict saved in the model file: ``levels`` ``(L,)``; per prediction
(``classical``/``hybrid``) the error quantiles ``<name>_pos_mm`` / ``<name>_ang_deg`` ``(L,)`` of
held-out validation samples; the extrapolation growth of the calibrated model ``growth_<key>`` /
``step_<key>`` ``(L, n)`` (:mod:`hykin.hybrid.uncertainty`); ``notemp_*`` quantiles for queries
without a temperature (models with a thermal coefficient).
"""

from __future__ import annotations

import numpy as np

from ..geometry import se3

__all__ = ["UNC_LEVELS", "band_radii", "band_source", "error_quantiles", "growth_entries", "notemp_quantiles"]

#: band levels at which the validation error quantiles are stored (predict_uncertainty interpolates)
UNC_LEVELS = np.round(np.arange(0.5, 0.99501, 0.005), 4)


def band_source(train, val, held_out_index) -> tuple[object, str]:
    """The Dataset the bands are calibrated on and its description: ``val`` when given, else the
    ``held_out_index`` rows of ``train`` (at least 10), else ``train`` itself (in-sample)."""
    if val is not None:
        return val, "val"
    if held_out_index is not None and len(held_out_index) >= 10:
        return train.subset(np.asarray(held_out_index)), "held-out"
    return train, "train (in-sample: too few samples to hold out)"


def error_quantiles(ds, T_c: np.ndarray, T_h: np.ndarray, with_rot: bool) -> dict:
    """``{"classical_pos_mm", ["classical_ang_deg"], "hybrid_pos_mm", ["hybrid_ang_deg"]}``: the
    :data:`UNC_LEVELS` quantiles of the position (mm) / orientation (deg) error norms of the classical
    ``T_c`` and hybrid ``T_h`` poses ``(N, 4, 4)`` against ``ds``."""
    unc = {}
    for name, T in (("classical", T_c), ("hybrid", T_h)):
        pe = np.linalg.norm(T[:, :3, 3] - ds.xyz_m, axis=1) * 1e3
        unc[f"{name}_pos_mm"] = np.quantile(pe, UNC_LEVELS)
        if with_rot:
            _, ae = se3.pose_error(ds.poses(), T)
            unc[f"{name}_ang_deg"] = np.quantile(ae, UNC_LEVELS)
    return unc


def growth_entries(g: dict) -> dict:
    """Band state entries from :func:`hykin.hybrid.uncertainty.extrapolation_growth`'s result."""
    unc = {}
    for key in ("pos_mm", "ang_deg"):
        if g[key] is not None:
            unc[f"growth_{key}"], unc[f"step_{key}"] = g[key], g[key + "_step"]
    unc["growth_splits"], unc["growth_points"] = g["n_splits"], g["n_points"]
    return unc


def notemp_quantiles(unc: dict, ds_raw, T_c: np.ndarray, T_h: np.ndarray) -> dict:
    """Quantiles for queries without a temperature: predictions at the reference temperature against
    the raw measurements ``ds_raw`` (drift included); orientations are unchanged by thermal expansion."""
    out = {}
    for name, T in (("classical", T_c), ("hybrid", T_h)):
        pe = np.linalg.norm(T[:, :3, 3] - ds_raw.xyz_m, axis=1) * 1e3
        out[f"notemp_{name}_pos_mm"] = np.quantile(pe, UNC_LEVELS)
        if f"{name}_ang_deg" in unc:
            out[f"notemp_{name}_ang_deg"] = unc[f"{name}_ang_deg"]
    return out


def band_radii(unc: dict, level: float, w: np.ndarray, ex: np.ndarray, temperature_given: bool):
    """Band radii ``(pos_mm (N,), ang_deg (N,) or None)`` at ``level`` for queries with fade weight
    ``w`` ``(N,)`` and range excess ``ex`` ``(N, n)``: ``w r_hybrid + (1 - w) max(g r_classical,
    r_hybrid)``, ``g = 1 + max_j a_j + sum_j k_j e_j`` over the joints beyond their range."""
    lv = unc["levels"]
    pre = "notemp_" if not temperature_given and "notemp_hybrid_pos_mm" in unc else ""

    def band(key):
        if f"hybrid_{key}" not in unc:
            return None
        rh = float(np.interp(level, lv, unc[f"{pre}hybrid_{key}"]))
        rc = float(np.interp(level, lv, unc[f"{pre}classical_{key}"]))
        g = 1.0
        if f"growth_{key}" in unc:
            k, a = (np.array([np.interp(level, lv, c) for c in
                              np.asarray(unc[f"{name}_{key}"], dtype=np.float64).reshape(len(lv), -1).T])
                    for name in ("growth", "step"))
            g = 1.0 + np.max(np.where(ex > 0, a, 0.0), axis=1) + ex @ k
        return w * rh + (1 - w) * np.maximum(rc * g, rh)

    return band("pos_mm"), band("ang_deg")
