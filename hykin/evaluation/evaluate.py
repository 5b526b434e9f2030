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

__all__ = ["NOMINAL_FITTED", "ROBOT_FILE", "EvalResult", "FrameMismatchError", "check_model_frame", "distinct_poses",
           "evaluate_model", "evaluate_per_payload", "joint_region_rows", "nominal_row", "with_fitted_frames"]


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
    #: test rows far off the last row's model (:func:`hykin.calibration.outliers.find_outliers`): named,
    #: counted in the figures; ``outliers_of``: that row's name
    outliers: object | None = None
    outliers_of: str = ""
    #: ISO 9283 per pose (set by the report: ``{"columns": [...], "rows": [[...]], "note": str}``), or None
    iso9283: dict | None = None
    #: errors per station / per tool (:func:`hykin.evaluation.per_group.group_stats`) when the test data name more
    #: than one; None otherwise
    per_group: dict | None = None
    #: the ``pose_id`` cell of each outlier row (test data with that column), else None
    outlier_pose_ids: list | None = None

    def outlier_line(self) -> str:
        """One line naming the test rows far off the model, with the figures without them ("" if none)."""
        o = self.outliers
        if o is None:
            return ""
        keep = np.ones(self.n, bool)
        keep[o.rows] = False
        p = self.errors[self.outliers_of][0][keep]
        name = self.labels.get(self.outliers_of, self.outliers_of)
        return o.message(self.dataset, against=f"the {name} model",
                         tail=(f"a lost beam, a reflector in the wrong nest or a wrong point name? They are counted in the "
                               f"figures above; without them the {name} row is {p.mean():.4g} mm mean, {p.max():.4g} mm max"))

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
        if self.per_group is not None:
            d.update({f"per_{col}": g for col, g in self.per_group.items()})
        if self.outliers is not None:
            d["outliers"] = self.outliers_dict()
        if self.iso9283 is not None:
            d["iso9283"] = self.iso9283
        return d

    def outliers_dict(self) -> dict:
        """The outliers for JSON, numbered as the text names them: ``data_rows`` are 1-based data rows (the
        header not counted: a CSV's line is the data row + 1), ``index_0based`` the same rows as indices
        into the data, ``pose_id`` their pose ids (data with that column); errors in mm / deg."""
        o = self.outliers.to_dict()  # data_rows / index_0based numbered as below
        d = {"model": self.outliers_of, "data_rows": o.pop("data_rows"), "index_0based": o.pop("index_0based")}
        if self.outlier_pose_ids is not None:
            d["pose_id"] = list(self.outlier_pose_ids)
        return {**d, **o, "numbering": "data_rows: 1-based data rows as in the text (CSV line = data row + 1); "
                                       "index_0based: the same rows counted from 0"}

    def table(self) -> str:
        t = format_table({self.labels.get(k, k): v for k, v in self.stats.items()})
        t += "\nstd: population standard deviation (ddof = 0); p95: 95th percentile (linear interpolation)."
        if self.labels.get("nominal") == NOMINAL_FITTED:
            t += f"\n{NOMINAL_FITTED}: the nominal robot with base and tool frames fitted to these poses (rigid fit)."
        if "file" in self.stats:
            t += (f"\n{ROBOT_FILE}: the robot file with its own base and tool, as fk, ik and compensate use it; more than "
                  f"{FRAME_FIT_FACTOR:g}x the error with fitted frames: the data are in another frame or with another tool "
                  f"than the file's, or the file's base or tool is wrong (e.g. a tool offset held at its prior).")
        if self.support_distance is not None:
            n_out = int(np.sum(self.support_distance > 0))
            t += f"\n{n_out} of {self.n} samples lie outside the training region (network correction faded there)."
        if self.outliers is not None:
            t += "\n" + self.outlier_line()
        if self.per_group is not None:
            from .per_group import group_table, reference_words

            ref = reference_words(self.per_group)
            t += (f"\nError per {' and per '.join(self.per_group)} (each row in its own station's and tool's frame"
                  f"{'; ' + ref if ref else ''}):\n" + group_table(self.per_group, self.labels))
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
#: test data of at least this many distinct poses (joints rounded to 1e-3 rad) are checked to be in the
#: model's frame (:func:`check_model_frame`)
FRAME_CHECK_POSES = 20
#: ... and only a model error above this (mm) and above this many times the model's own held-out mean
#: error counts as another frame (a moved tracker: metres; another tool: centimetres)
FRAME_CHECK_MIN_MM = 1.0
FRAME_CHECK_OWN_FACTOR = 5.0
_FIT_ROWS = 2000  # at most this many evenly spread rows fit the nominal row's frames


def nominal_row(nominal: Robot, q: np.ndarray, T_meas: np.ndarray, position_only: bool,
                always_fit: bool = False, payload: dict | None = None) -> tuple[np.ndarray, str]:
    """The nominal row of an evaluation: poses ``(N, 4, 4)`` and label. One definition: the nominal
    robot with the robot file's base and tool (label ``"nominal"``) when those frames fit the data, else
    (data in a tracker's frame, another tool, ``always_fit`` for a registered model) the nominal robot
    with base and tool fitted to these poses by a rigid fit (label :data:`NOMINAL_FITTED`). A robot
    file with joint stiffness deflects under ``payload`` (:func:`hykin.io.payload.payload_kwargs` of
    the data; default its own payload): a calibrated robot file is evaluated as it predicts."""
    T = classical_fk(nominal, q, **(payload or {}))
    if len(T) < 4:
        return T, "nominal"
    T_fit = with_fitted_frames(T, T_meas, position_only)
    if always_fit:
        return T_fit, NOMINAL_FITTED
    return (T_fit, NOMINAL_FITTED) if _mean_mm(T, T_meas) > FRAME_FIT_FACTOR * _mean_mm(T_fit, T_meas) else (T, "nominal")


#: the model's fitted base / TCP within this of the robot file's (mm, deg): the file's frames are the model's
#: (what a calibration moves a surveyed base or a measured tool by); farther, the nominal row's frames are
#: fitted to the data as before (a tracker's frame; a file whose base or tool is centimetres off)
FILE_FRAMES_MM, FILE_FRAMES_DEG = 5.0, 0.5


def file_frames_fit_model(model) -> bool:
    """Whether a fitted model's base (``frame_pre_ · robot_.base``) and TCP (``robot_.tool · frame_post_``) lie
    within :data:`FILE_FRAMES_MM` / :data:`FILE_FRAMES_DEG` of its robot file's base and tool: its data were
    taken in the robot's base frame with the file's tool, so data in the model's frame are in the file's."""
    from ..geometry.se3 import invert
    from ..hybrid.ik_result import model_tcp_shift

    nom, rob = getattr(model, "nominal", None), getattr(model, "robot_", None)
    if not isinstance(nom, Robot) or not isinstance(rob, Robot):
        return False
    base = invert(nom.base) @ np.asarray(getattr(model, "frame_pre_", np.eye(4))) @ rob.base  # fitted base vs file's
    mm, deg = pose_error(np.stack([base, model_tcp_shift(model)]), np.eye(4)[None].repeat(2, axis=0))
    return bool((mm <= FILE_FRAMES_MM).all() and (deg <= FILE_FRAMES_DEG).all())


def with_fitted_frames(T: np.ndarray, T_meas: np.ndarray, position_only: bool) -> np.ndarray:
    """Predicted poses ``T`` ``(N, 4, 4)`` with base and tool fitted to the measured ``T_meas`` by a rigid
    fit (at most :data:`_FIT_ROWS` evenly spread rows fit them): ``B · T · E``."""
    from ..calibration.frames import fit_frames

    sel = np.unique(np.linspace(0, len(T) - 1, min(len(T), _FIT_ROWS)).astype(np.int64))
    B, E = fit_frames(T[sel], T_meas[sel], position_only=position_only)
    return B @ T @ E


def distinct_poses(q: np.ndarray, tol: float = 1e-6) -> int:
    """The number of distinct joint configurations among the rows of ``q`` (rounded to ``tol``)."""
    q = np.asarray(q, float)
    return int(len(np.unique(np.round(q / tol), axis=0))) if len(q) else 0


def _own_mm(model) -> float | None:
    """The model's own mean position error (mm) on the rows held out from its training, else on its
    validation data, from its metadata; None when it has none."""
    metrics = (getattr(model, "metadata", None) or {}).get("metrics") or {}
    for key in ("held_out", "val"):
        v = (metrics.get(key) or {}).get("hybrid_pos_mean_mm")
        if v is not None and np.isfinite(v):
            return float(v)
    return None


def _mean_mm(T: np.ndarray, T_meas: np.ndarray) -> float:
    return float(np.linalg.norm(T[:, :3, 3] - T_meas[:, :3, 3], axis=1).mean() * 1e3)


class FrameMismatchError(ValueError):
    """Test data not in the model's frame (:func:`check_model_frame`)."""


def check_model_frame(data: Dataset, T_model: np.ndarray, T_meas: np.ndarray, position_only: bool,
                      nominal_mm: float | None, own_mm: float | None = None) -> None:
    """Refuse (:class:`FrameMismatchError`, one line) test data that are not in the model's frame (a moved tracker,
    another tool): the model's poses ``T_model`` are worse than the nominal robot's (mean ``nominal_mm``,
    its frames fitted where needed) and more than :data:`FRAME_FIT_FACTOR` times worse than with base
    and tool fitted to the data. Both are needed: a good model in its own frame beats the nominal
    robot, and a frame error is what a rigid fit removes. And the model's error must exceed
    :data:`FRAME_CHECK_MIN_MM` and :data:`FRAME_CHECK_OWN_FACTOR` times its own held-out mean error
    ``own_mm`` (mm, from its metadata): over a small joint region the nominal robot with fitted frames is
    a few 0.1 mm off, so a model fitted without calibration, or weakly trained, is worse than it there
    without any frame being wrong (measured: 0.465 mm against 0.168 mm on 30 poses within ±5°). Data of
    fewer than :data:`FRAME_CHECK_POSES` distinct poses are not tested (the fit's 12 parameters absorb
    too much there)."""
    if len(T_meas) < 4 or distinct_poses(data.q, tol=1e-3) < FRAME_CHECK_POSES:
        return
    e_model = _mean_mm(T_model, T_meas)
    if nominal_mm is not None and e_model <= nominal_mm:
        return
    if e_model <= max(FRAME_CHECK_MIN_MM, FRAME_CHECK_OWN_FACTOR * (own_mm or 0.0)):
        return  # within the model's own accuracy (or a millimetre): a weak model, or a small region, not a frame
    e_fit = _mean_mm(with_fitted_frames(T_model, T_meas, position_only), T_meas)
    if e_model <= FRAME_FIT_FACTOR * e_fit:
        return
    nom = "" if nominal_mm is None else f", the nominal robot {nominal_mm:.4g} mm"
    raise FrameMismatchError(
        f"{data.source or '<dataset>'}: the poses are not in the model's frame (a moved tracker, another tool, or the "
        f"model's base or tool is wrong): the hybrid model is {e_model:.4g} mm off them, {e_fit:.4g} mm with base and tool "
        f"fitted to them{nom}; register the model to a series measured in this frame first (hykin register MODEL "
        f"SERIES -o MODEL2; docs/registration.md) and evaluate MODEL2")


def evaluate_model(model, data: Dataset, *, fit_frames: bool = False) -> EvalResult:
    """Errors of the nominal, calibrated and hybrid predictions of ``model`` against ``data``.

    ``model`` is a :class:`hykin.hybrid.model.HybridModel` or a plain :class:`Robot` (nominal FK only).
    The nominal row (:func:`nominal_row`) is labelled ``"nominal + fitted frames"`` where its frames
    were fitted to the data (tracker-frame data, registered models); its key stays ``"nominal"``.
    A model fitted on several stations / tools compares each row in its own station's and tool's frame
    (the data are mapped into the model's frame, :func:`hykin.hybrid.stations.in_model_frame`); data
    of several stations for a model of one frame are refused (DatasetError).
    Data in another frame than the model's are refused (:func:`check_model_frame`) unless
    ``fit_frames``: then the calibrated and hybrid rows, like the nominal one, have base and tool fitted
    to the data (labels ``"... + fitted frames"``; 12 parameters fitted to the test poses flatter them).
    """
    from ..hybrid.stations import in_model_frame
    from .per_group import group_labels

    groups = group_labels(model, data)  # station / tool labels per row (the mapped data have none)
    raw = data  # its pose_id column names the outliers
    data = in_model_frame(model, data)  # several stations / tools: each row in its own frame
    T_meas = data.poses()
    pos_only = not data.has_orientation
    preds: dict[str, np.ndarray] = {}
    labels: dict[str, str] = {}
    dist = nom_check_mm = None
    registered = not isinstance(model, Robot) and not (
        np.array_equal(getattr(model, "frame_pre_", np.eye(4)), np.eye(4)) and np.array_equal(getattr(model, "frame_post_", np.eye(4)), np.eye(4)))
    pkw = payload_kwargs(payload_of(data))  # per-row payload deflects the calibrated model (and compliant files)
    if isinstance(model, Robot):
        preds["nominal"], labels["nominal"] = nominal_row(model, data.q, T_meas, pos_only, always_fit=fit_frames,
                                                          payload=pkw)
        if labels["nominal"] == NOMINAL_FITTED:  # the file as written first: its own frames may be what is wrong
            preds = {"file": classical_fk(model, data.q, **pkw), **preds}
            labels["file"] = ROBOT_FILE
    else:
        nominal = getattr(model, "nominal", None)
        if nominal is not None and not (registered or fit_frames) and file_frames_fit_model(model):
            # the model's frames are the file's (robot-frame data, the file's tool): the data, checked to be in
            # the model's frame below, are in the file's; a rigid fit to them would flatter the nominal row
            # (on a small joint region it absorbs most of the geometric error: 5.6 mm shown as 0.19 mm)
            preds["nominal"], labels["nominal"] = classical_fk(nominal, data.q, **pkw), "nominal"
            # the frame check compares with the nominal robot as nominal_row places it (fitted frames for data
            # in another frame): data from a moved tracker must still be told apart
            nom_check_mm = _mean_mm(nominal_row(nominal, data.q, T_meas, pos_only, payload=pkw)[0], T_meas)
        elif nominal is not None:
            # a registered model's frames belong to it: the nominal row fits its own (one definition)
            preds["nominal"], labels["nominal"] = nominal_row(nominal, data.q, T_meas, pos_only, always_fit=registered or fit_frames,
                                                              payload=pkw)
        from ..calibration.thermal import temperature_of

        temp = temperature_of(data)  # used by models that identified thermal expansion
        if getattr(model, "calibration", None) is not None or getattr(model, "calibrate", False):
            preds["calibrated"] = model.predict_classical(data.q, temperature_c=temp, **pkw)
        preds["hybrid"] = model.predict(data.q, temperature_c=temp, **pkw)
        if fit_frames:
            for k in ("calibrated", "hybrid"):
                if k in preds:
                    preds[k] = with_fitted_frames(preds[k], T_meas, pos_only)
                    labels[k] = f"{k} + fitted frames"
        else:
            if nom_check_mm is None and "nominal" in preds:
                nom_check_mm = _mean_mm(preds["nominal"], T_meas)
            check_model_frame(data, preds["hybrid"], T_meas, pos_only, nom_check_mm, own_mm=_own_mm(model))
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
    from ..calibration.outliers import find_outliers

    last = list(errors)[-1]  # the hybrid model (a robot file: its last row)
    p_mm, a_deg = errors[last]
    found = find_outliers(p_mm * 1e-3, None if a_deg is None else np.radians(a_deg))
    from .per_group import group_stats

    return EvalResult(
        dataset=data.source, n=len(data), position_only=pos_only, stats=stats, errors=errors, support_distance=dist,
        per_payload=evaluate_per_payload(errors, data), regions=regions, labels=labels, vectors=vectors, predicted=preds,
        outliers=found, outliers_of=last if found is not None else "",
        per_group=group_stats(errors, groups) if groups else None,
        outlier_pose_ids=None if found is None else _pose_ids(raw, found.rows),
    )


def _pose_ids(data, rows) -> list | None:
    """The ``pose_id`` cell of each of ``rows`` (0-based) as text ("" for a blank cell), or None without
    that column."""
    ids = (getattr(data, "extra", None) or {}).get("pose_id")
    if ids is None:
        return None
    out = []
    for v in np.asarray(ids)[np.asarray(rows, dtype=np.int64)]:  # the few outlier rows only
        if isinstance(v, (float, np.floating)):
            v = "" if not np.isfinite(v) else int(v) if float(v).is_integer() else float(v)
        v = str(v).strip()
        out.append("" if v.lower() == "nan" else v)
    return out


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
