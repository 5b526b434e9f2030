"""Evaluation of a model on a measured dataset: nominal vs calibrated vs hybrid error tables and plots."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from ..geometry.se3 import pose_error, rotation_difference_rotvec
from ..io.dataset import Dataset
from ..io.payload import (
    errors_per_payload,
    format_payload_table,
    payload_kwargs,
    payload_of,
)
from ..kinematics.fk import fk
from ..kinematics.robot import Robot
from .metrics import ErrorStats, error_stats, format_table

__all__ = ["EvalResult", "evaluate_model", "evaluate_per_payload", "joint_region_rows"]


@dataclass
class EvalResult:
    """Per-model error statistics on one dataset, plus the per-sample errors for plots.

    ``stats``: ordered mapping row name -> :class:`ErrorStats` (e.g. nominal, calibrated, hybrid).
    ``errors``: row name -> ``(pos_mm (N,), ang_deg (N,) or None)``.
    ``support_distance``: ``(N,)`` distance of each sample from the training region (hybrid models).
    """

    dataset: str
    n: int
    position_only: bool
    stats: dict[str, ErrorStats]
    errors: dict[str, tuple[np.ndarray, np.ndarray | None]] = field(repr=False, default_factory=dict)
    support_distance: np.ndarray | None = field(repr=False, default=None)
    per_payload: dict | None = None  # errors_per_payload(...) when the data carry a payload_kg column
    regions: list = field(default_factory=list)  # per joint-quartile region rows (registered models), region_table
    #: row name -> ``(dp_mm (N, 3), dr_deg (N, 3) or None)``: predicted minus measured position (base x, y, z)
    #: and the rotation vector of ``R_pred R_measᵀ`` (about base x, y, z); their norms are ``errors``
    vectors: dict[str, tuple[np.ndarray, np.ndarray | None]] = field(repr=False, default_factory=dict)
    #: row name -> ``(N, 4, 4)`` predicted poses, m (for ISO 9283 and the report)
    predicted: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    def region_table(self) -> str:
        """Per joint-region mean errors (mm / deg): hybrid vs calibrated vs nominal + rigid fit (registered models)."""
        if not self.regions:
            return ""
        names = [k for k in self.regions[0] if k not in ("region", "n")]
        head = "| region | n | " + " | ".join(names) + " | hybrid / calibrated |"
        lines = [head, "|" + "---|" * (len(names) + 3)]
        for r in self.regions:
            cells = [f"{r[k][0]:.4f}" + ("" if r[k][1] is None else f" / {r[k][1]:.4f}") for k in names]
            ratio = r["hybrid"][0] / r["calibrated"][0] if "calibrated" in r and r["calibrated"][0] > 0 else float("nan")
            lines.append(f"| {r['region']} | {r['n']} | " + " | ".join(cells) + f" | {ratio:.3f} |")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        d = {
            "dataset": self.dataset,
            "n": self.n,
            "position_only": self.position_only,
            "stats": {k: v.to_dict() for k, v in self.stats.items()},
        }
        if self.support_distance is not None:
            d["outside_training_region"] = int(np.sum(self.support_distance > 0))
        if self.per_payload is not None:
            d["per_payload"] = {f"{k:g}": v for k, v in self.per_payload.items()}
        if self.regions:
            d["regions"] = self.regions
        return d

    def table(self) -> str:
        t = format_table(self.stats)
        if self.support_distance is not None:
            n_out = int(np.sum(self.support_distance > 0))
            t += f"\n{n_out} of {self.n} samples lie outside the training region (network correction faded there)."
        if self.per_payload is not None:
            t += "\nError per payload:\n" + format_payload_table(self.per_payload)
        if self.regions:
            t += ("\n\nPer joint region (registered model; mean mm / deg; nominal + rigid fit = the nominal robot with "
                  "base and tool fitted to all of these poses):\n" + self.region_table())
        return t

    def json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


def evaluate_model(model, data: Dataset) -> EvalResult:
    """Errors of the nominal, calibrated and hybrid predictions of ``model`` against ``data``.

    ``model`` is a :class:`hykin.hybrid.model.HybridModel` or a plain :class:`Robot` (nominal FK only).
    """
    T_meas = data.poses()
    pos_only = not data.has_orientation
    preds: dict[str, np.ndarray] = {}
    dist = None
    if isinstance(model, Robot):
        preds["nominal"] = fk(model, data.q)
    else:
        nominal = getattr(model, "nominal", None)
        if nominal is not None:
            # A registered model carries the frames of its measurement series; the nominal row uses them too.
            pre = getattr(model, "frame_pre_", np.eye(4))
            post = getattr(model, "frame_post_", np.eye(4))
            preds["nominal"] = pre @ fk(nominal, data.q) @ post
        from ..calibration.thermal import temperature_of

        temp = temperature_of(data)  # used by models that identified thermal expansion
        pkw = payload_kwargs(payload_of(data))  # per-row payload deflects the calibrated model
        if getattr(model, "calibration", None) is not None or getattr(model, "calibrate", False):
            preds["calibrated"] = model.predict_classical(data.q, temperature_c=temp, **pkw)
        preds["hybrid"] = model.predict(data.q, temperature_c=temp, **pkw)
        if hasattr(model, "support_distance"):
            dist = np.asarray(model.support_distance(data.q))
    stats, errors, vectors = {}, {}, {}
    for name, T in preds.items():
        stats[name] = error_stats(T, T_meas, position_only=pos_only)
        p, a = pose_error(T, T_meas)
        errors[name] = (p, None if pos_only else a)
        vectors[name] = ((T[:, :3, 3] - T_meas[:, :3, 3]) * 1e3,
                         None if pos_only else np.degrees(rotation_difference_rotvec(T[:, :3, :3], T_meas[:, :3, :3])))
    regions = []
    registered = not isinstance(model, Robot) and not (
        np.array_equal(getattr(model, "frame_pre_", np.eye(4)), np.eye(4)) and np.array_equal(getattr(model, "frame_post_", np.eye(4)), np.eye(4)))
    if registered and "nominal" in preds:
        from ..calibration.frames import fit_frames

        Tn = fk(model.nominal, data.q)
        Bn, En = fit_frames(Tn, T_meas, position_only=pos_only)
        pn, an = pose_error(Bn @ Tn @ En, T_meas)
        errors["nominal + rigid fit"] = (pn, None if pos_only else an)
        regions = joint_region_rows(data.q, {k: errors[k] for k in ("hybrid", "calibrated", "nominal + rigid fit") if k in errors})
    return EvalResult(
        dataset=data.source, n=len(data), position_only=pos_only, stats=stats, errors=errors, support_distance=dist,
        per_payload=evaluate_per_payload(errors, data), regions=regions, vectors=vectors, predicted=preds,
    )


def evaluate_per_payload(errors: dict, data: Dataset) -> dict | None:
    """Error statistics per distinct payload of ``data`` (:func:`hykin.io.payload.errors_per_payload`)
    for per-sample ``errors`` (name -> ``(pos_mm, ang_deg or None)``); None without a payload column."""
    pl = payload_of(data)
    return None if pl is None else errors_per_payload(pl[0], errors)


def joint_region_rows(q: np.ndarray, errors: dict, n_quantiles: int = 4) -> list[dict]:
    """Mean errors per joint-quantile region: for every joint j and quantile k of its values, the rows
    with q_j in that quantile; ``errors``: name -> ``(pos_mm (N,), ang_deg (N,) or None)``. Returns
    dicts ``{"region": "q3 Q2", "n": .., name: (pos mean, ang mean or None)}``, plus one for all rows."""
    q = np.asarray(q, dtype=np.float64)
    out = []
    sels = [("all", np.ones(len(q), bool))]
    for j in range(q.shape[1]):
        edges = np.quantile(q[:, j], np.linspace(0, 1, n_quantiles + 1))
        lab = np.clip(np.searchsorted(edges, q[:, j], side="right") - 1, 0, n_quantiles - 1)
        sels += [(f"q{j + 1} Q{k + 1}", lab == k) for k in range(n_quantiles)]
    for name, sel in sels:
        if not sel.any():
            continue
        row = {"region": name, "n": int(sel.sum())}
        for k, (p, a) in errors.items():
            row[k] = (float(p[sel].mean()), None if a is None else float(a[sel].mean()))
        out.append(row)
    return out
