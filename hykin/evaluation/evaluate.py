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
from ..kinematics.classical import classical_fk
from ..kinematics.robot import Robot
from .metrics import ErrorStats, error_stats, format_table

__all__ = ["NOMINAL_FITTED", "ROBOT_FILE", "EvalResult", "evaluate_model", "evaluate_per_payload", "joint_region_rows",
           "nominal_row"]


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
    labels: dict = field(default_factory=dict)  # row name -> label in the table (e.g. "nominal + fitted frames")
    #: row name -> ``(dp_mm (N, 3), dr_deg (N, 3) or None)``: predicted minus measured position (base x, y, z)
    #: and the rotation vector of ``R_pred R_measᵀ`` (about base x, y, z); their norms are ``errors``
    vectors: dict[str, tuple[np.ndarray, np.ndarray | None]] = field(repr=False, default_factory=dict)
    #: row name -> ``(N, 4, 4)`` predicted poses, m (for ISO 9283 and the report)
    predicted: dict[str, np.ndarray] = field(repr=False, default_factory=dict)

    def region_table(self) -> str:
        """Per joint-region mean errors (mm / deg): hybrid vs calibrated vs nominal + fitted frames (registered models)."""
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
        if self.labels:
            d["labels"] = dict(self.labels)
        return d

    def table(self) -> str:
        t = format_table({self.labels.get(k, k): v for k, v in self.stats.items()})
        if self.labels.get("nominal") == NOMINAL_FITTED:
            t += f"\n{NOMINAL_FITTED}: the nominal robot with base and tool frames fitted to these poses (rigid fit)."
        if "file" in self.stats:
            t += (f"\n{ROBOT_FILE}: the robot file with its own base and tool, as fk, ik and compensate use it; more than "
                  f"{FRAME_FIT_FACTOR:g}x the error with fitted frames: the data are in another frame or with another tool "
                  f"than the file's, or the file's base or tool is wrong (e.g. a tool offset held at its prior).")
        if self.support_distance is not None:
            n_out = int(np.sum(self.support_distance > 0))
            t += f"\n{n_out} of {self.n} samples lie outside the training region (network correction faded there)."
        if self.per_payload is not None:
            t += "\nError per payload:\n" + format_payload_table(self.per_payload)
        if self.regions:
            t += ("\n\nPer joint region (registered model; mean mm / deg; the nominal row of the table above):\n"
                  + self.region_table())
        return t

    def json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)


NOMINAL_FITTED = "nominal + fitted frames"
ROBOT_FILE = "robot file as written"
#: the robot file's frames are kept for the nominal row unless fitting base and tool to the data
#: lowers its mean position error by more than this factor (data in another frame, another tool)
FRAME_FIT_FACTOR = 2.0
_FIT_ROWS = 2000  # at most this many evenly spread rows fit the nominal row's frames


def nominal_row(nominal: Robot, q: np.ndarray, T_meas: np.ndarray, position_only: bool,
                always_fit: bool = False, payload: dict | None = None) -> tuple[np.ndarray, str]:
    """The nominal row of an evaluation: poses ``(N, 4, 4)`` and label. One definition: the nominal
    robot with the robot file's base and tool (label ``"nominal"``) when those frames fit the data, else
    (data in a tracker's frame, another tool, ``always_fit`` for a registered model) the nominal robot
    with base and tool fitted to these poses by a rigid fit (label :data:`NOMINAL_FITTED`). A robot
    file with joint stiffness deflects under ``payload`` (:func:`hykin.io.payload.payload_kwargs` of
    the data; default its own payload): a calibrated robot file is evaluated as it predicts."""
    from ..calibration.frames import fit_frames

    T = classical_fk(nominal, q, **(payload or {}))
    if len(T) < 4:
        return T, "nominal"
    sel = np.unique(np.linspace(0, len(T) - 1, min(len(T), _FIT_ROWS)).astype(np.int64))
    B, E = fit_frames(T[sel], T_meas[sel], position_only=position_only)
    T_fit = B @ T @ E
    if always_fit:
        return T_fit, NOMINAL_FITTED
    e_file = np.linalg.norm(T[:, :3, 3] - T_meas[:, :3, 3], axis=1).mean()
    e_fit = np.linalg.norm(T_fit[:, :3, 3] - T_meas[:, :3, 3], axis=1).mean()
    return (T_fit, NOMINAL_FITTED) if e_file > FRAME_FIT_FACTOR * e_fit else (T, "nominal")


def evaluate_model(model, data: Dataset) -> EvalResult:
    """Errors of the nominal, calibrated and hybrid predictions of ``model`` against ``data``.

    ``model`` is a :class:`hykin.hybrid.model.HybridModel` or a plain :class:`Robot` (nominal FK only).
    The nominal row (:func:`nominal_row`) is labelled ``"nominal + fitted frames"`` where its frames
    were fitted to the data (tracker-frame data, registered models); its key stays ``"nominal"``.
    A model fitted on several stations / tools compares each row in its own station's and tool's frame
    (the data are mapped into the model's frame, :func:`hykin.hybrid.stations.in_model_frame`).
    """
    if getattr(model, "station_frames_", None) is not None:  # several stations / tools: each row's own frame
        from ..hybrid.stations import in_model_frame

        data = in_model_frame(model, data)
    T_meas = data.poses()
    pos_only = not data.has_orientation
    preds: dict[str, np.ndarray] = {}
    labels: dict[str, str] = {}
    dist = None
    registered = not isinstance(model, Robot) and not (
        np.array_equal(getattr(model, "frame_pre_", np.eye(4)), np.eye(4)) and np.array_equal(getattr(model, "frame_post_", np.eye(4)), np.eye(4)))
    pkw = payload_kwargs(payload_of(data))  # per-row payload deflects the calibrated model (and compliant files)
    if isinstance(model, Robot):
        preds["nominal"], labels["nominal"] = nominal_row(model, data.q, T_meas, pos_only, payload=pkw)
        if labels["nominal"] == NOMINAL_FITTED:  # the file as written first: its own frames may be what is wrong
            preds = {"file": classical_fk(model, data.q, **pkw), **preds}
            labels["file"] = ROBOT_FILE
    else:
        nominal = getattr(model, "nominal", None)
        if nominal is not None:
            # a registered model's frames belong to it: the nominal row fits its own (one definition)
            preds["nominal"], labels["nominal"] = nominal_row(nominal, data.q, T_meas, pos_only, always_fit=registered,
                                                              payload=pkw)
        from ..calibration.thermal import temperature_of

        temp = temperature_of(data)  # used by models that identified thermal expansion
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
    if registered and "nominal" in preds:
        regions = joint_region_rows(data.q, {labels.get(k, k): errors[k] for k in ("hybrid", "calibrated", "nominal")
                                             if k in errors})
    return EvalResult(
        dataset=data.source, n=len(data), position_only=pos_only, stats=stats, errors=errors, support_distance=dist,
        per_payload=evaluate_per_payload(errors, data), regions=regions, labels=labels, vectors=vectors, predicted=preds,
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
