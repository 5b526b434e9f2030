"""The report's accuracy tables, computed from an :class:`hykin.evaluation.evaluate.EvalResult` and
its dataset: statistics per model for position and orientation and per base axis, where the error
is largest (joint ranges, reach), ISO 9283 pose accuracy and repeatability, the training support,
and per-payload / per-temperature tables. Errors in mm and degrees; joints shown in degrees
(revolute) or mm (prismatic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .report import mm
from .report_figures import joint_bins

__all__ = ["Hotspot", "axis_rows", "iso_rows", "joint_hotspot", "per_payload_rows", "per_temperature_rows",
           "reach_hotspot", "support_rows"]

AXIS_HEADER = ["model", "quantity", "mean", "std", "p95 of |·|", "max of |·|", "unit"]


def _stat_row(name: str, what: str, v: np.ndarray, unit: str, signed: bool) -> list:
    a = np.abs(v)
    return [name, what, float(v.mean() if signed else a.mean()), float(v.std()), float(np.percentile(a, 95)), float(a.max()), unit]


def axis_rows(vectors: dict) -> list[list]:
    """Rows of :data:`AXIS_HEADER` per model (``vectors``: name -> ``(dp_mm (N, 3), dr_deg (N, 3) or None)``):
    position |e| and its x, y, z components, then orientation |e| and rx, ry, rz. For a component the
    mean is signed (a bias), the std its spread; for |e| the mean is of the norm."""
    rows = []
    for name, (dp, dr) in vectors.items():
        rows.append(_stat_row(name, "position |e|", np.linalg.norm(dp, axis=1), "mm", False))
        rows += [_stat_row(name, f"  {ax}", dp[:, k], "mm", True) for k, ax in enumerate("xyz")]
        if dr is not None:
            rows.append(_stat_row(name, "orientation |e|", np.linalg.norm(dr, axis=1), "deg", False))
            rows += [_stat_row(name, f"  r{ax}", dr[:, k], "deg", True) for k, ax in enumerate("xyz")]
    return rows


@dataclass
class Hotspot:
    """Where the error is largest: ``what`` (e.g. "joint 2") between ``lo`` and ``hi`` (``unit``), with
    mean error ``mean_mm`` there against ``overall_mm`` on all rows; ``n`` rows in that bin."""

    what: str
    lo: float
    hi: float
    unit: str
    mean_mm: float
    overall_mm: float
    n: int

    def words(self) -> str:
        return (f"{self.what} between {self.lo:.3g} and {self.hi:.3g} {self.unit} "
                f"(mean {mm(self.mean_mm)} there against {mm(self.overall_mm)} overall, {self.n} poses)")


def _hot(x: np.ndarray, e: np.ndarray, what: str, unit: str, n_bins: int, min_share: float) -> Hotspot | None:
    if len(x) < 2 * n_bins or np.ptp(x) <= 0:
        return None
    c, m, cnt = joint_bins(x, e, n_bins)
    ok = cnt >= max(min_share * len(x), 3)
    if not ok.any():
        return None
    k = int(np.nanargmax(np.where(ok, m, -np.inf)))
    w = (c[1] - c[0]) / 2 if len(c) > 1 else 0.0
    return Hotspot(what, float(c[k] - w), float(c[k] + w), unit, float(m[k]), float(e.mean()), int(cnt[k]))


def joint_hotspot(q: np.ndarray, err_mm: np.ndarray, revolute, n_bins: int = 6, min_share: float = 0.05) -> Hotspot | None:
    """The joint bin (``n_bins`` equal-width bins per joint, at least ``min_share`` of the rows) with the
    highest mean error relative to the mean error of all rows."""
    best = None
    for j in range(q.shape[1]):
        x = np.degrees(q[:, j]) if revolute[j] else q[:, j] * 1e3
        h = _hot(x, err_mm, f"joint {j + 1}", "deg" if revolute[j] else "mm", n_bins, min_share)
        if h is not None and (best is None or h.mean_mm > best.mean_mm):
            best = h
    return best


def reach_hotspot(xyz_m: np.ndarray, err_mm: np.ndarray, n_bins: int = 6) -> Hotspot | None:
    """The bin of horizontal reach ``sqrt(x² + y²)`` (m, base frame) with the highest mean error."""
    r = np.hypot(xyz_m[:, 0], xyz_m[:, 1])
    return _hot(r, err_mm, "horizontal reach", "m", n_bins, 0.05)


def iso_rows(data, predicted: dict) -> tuple[list[list], str]:
    """ISO 9283 AP per model and RP, when ``data`` carries a ``pose_id`` (or ``pose``) column: the poses
    whose id occurs at least twice (blank / NaN ids: ordinary test poses) must share their joints. Returns ``(rows, note)``; no rows and the reason otherwise.
    Commanded pose: each model's prediction at the pose's joints; attained: the measurement."""
    from .iso9283 import ISOError, iso9283_pose

    extra = getattr(data, "extra", None) or {}
    ids = extra.get("pose_id", extra.get("pose"))  # `hykin simulate --plan iso-cube` labels its poses in "pose"
    if ids is None:
        return [], ("not computed: the test data have no pose_id column (ISO 9283 needs each test pose "
                    "approached repeatedly, e.g. 30 cycles of the poses P1 … P5, labelled in a pose_id column).")
    ids = np.asarray(ids)
    ok = np.isfinite(ids) if ids.dtype.kind == "f" else np.ones(len(ids), bool)  # blank ids: ordinary test poses
    uniq, inv, cnt = np.unique(np.where(ok, ids, ids[ok][0] if ok.any() else 0), return_inverse=True, return_counts=True)
    sel = ok & (cnt[inv] >= 2)  # poses measured once are ordinary test poses, not ISO cycles
    if not sel.any():
        return [], "not computed: no pose_id in the test data occurs more than once (ISO 9283 needs repeated cycles)."
    T_meas = data.poses()[sel]
    rows = []
    try:
        for name, T in predicted.items():
            r = iso9283_pose(T[sel], T_meas, ids[sel], tol_m=1e-9, tol_rad=1e-9)
            for i, pid in enumerate(r.pose_ids):
                pid = int(pid) if isinstance(pid, float) and pid.is_integer() else pid
                ang = [None] * 3 if not data.has_orientation else list(map(float, r.ap_abc_deg[i]))  # position-only data
                rows.append([name, str(pid), int(r.n[i]), float(r.ap_mm[i]), *map(float, r.ap_xyz_mm[i]),
                             *ang, float(r.rp_mm[i])])
    except ISOError as e:
        return [], f"not computed: {e}"
    return rows, ("AP: distance of the mean attained position from the commanded one (the model's prediction); "
                  "AP_a/b/c: mean angle deviations about base x/y/z; RP: ISO 9283 position repeatability "
                  "l̄ + 3 S_l (a property of the robot, the same for every model).")


ISO_HEADER = ["model", "pose", "cycles", "AP_P [mm]", "AP_x", "AP_y", "AP_z", "AP_a [deg]", "AP_b", "AP_c", "RP_l [mm]"]


def support_rows(model, q: np.ndarray, revolute) -> tuple[list[list], int]:
    """Per joint the training range and the test range (deg / mm, in the networks' joint coordinates)
    and the test rows outside it; with the number of rows outside the training support as a whole
    (:meth:`HybridModel.support_distance` > 0). ``([], 0)`` for a model without a support."""
    lo, hi = getattr(model, "support_lower_", None), getattr(model, "support_upper_", None)
    if lo is None or not hasattr(model, "support_distance"):
        return [], 0
    from ..hybrid.inputs import net_coordinates

    qn = net_coordinates(np.asarray(q, float), model.wrap_centre_, model.input_mask_)
    rows = []
    for j in range(q.shape[1]):
        if not model.input_mask_[j]:
            rows.append([f"joint {j + 1}", "not a network input", None, None, None, 0])
            continue
        f, unit = (np.degrees, "deg") if revolute[j] else ((lambda v: v * 1e3), "mm")
        out = int(np.sum((qn[:, j] < lo[j]) | (qn[:, j] > hi[j])))
        rows.append([f"joint {j + 1}", unit, f(float(lo[j])), f(float(hi[j])),
                     f"{f(float(qn[:, j].min())):.4g} … {f(float(qn[:, j].max())):.4g}", out])
    n_out = int(np.sum(np.asarray(model.support_distance(q)) > 0))
    return rows, n_out


SUPPORT_HEADER = ["joint", "unit", "trained from", "trained to", "test range", "test rows outside"]


def per_payload_rows(per_payload: dict | None) -> list[list]:
    """Rows (payload kg, model, n, position mean / p95 mm, orientation mean deg) of
    :func:`hykin.io.payload.errors_per_payload`."""
    rows = []
    for kg, row in (per_payload or {}).items():
        for name, d in row.items():
            rows.append([f"{kg:g}", name, d["n"], d["pos_mean_mm"], d["pos_p95_mm"], d.get("rot_mean_deg")])
    return rows


PAYLOAD_HEADER = ["payload [kg]", "model", "n", "position mean [mm]", "position p95 [mm]", "orientation mean [deg]"]


def per_temperature_rows(temp_c, errors: dict, n_bins: int = 4) -> list[list]:
    """Rows (temperature range °C, model, n, position mean / p95 mm, orientation mean deg) over
    ``n_bins`` equal-count temperature bins; empty when the temperature does not vary."""
    if temp_c is None:
        return []
    t = np.asarray(temp_c, float)
    if np.ptp(t) <= 0:
        return []
    edges = np.unique(np.quantile(t, np.linspace(0, 1, n_bins + 1)))
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    rows = []
    dec = max(1, int(np.ceil(-np.log10(np.min(np.diff(edges))))) + 1)  # enough decimals to tell the bins apart
    for b in range(len(edges) - 1):
        sel = k == b
        if not sel.any():
            continue
        for name, (p, a) in errors.items():
            rows.append([f"{edges[b]:.{dec}f} … {edges[b + 1]:.{dec}f}", name, int(sel.sum()), float(p[sel].mean()),
                         float(np.percentile(p[sel], 95)), None if a is None else float(a[sel].mean())])
    return rows


TEMPERATURE_HEADER = ["temperature [°C]", "model", "n", "position mean [mm]", "position p95 [mm]", "orientation mean [deg]"]
