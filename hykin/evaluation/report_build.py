"""THE report builder: one self-contained HTML report from one model and optional test data.
``hykin report``, ``hykin evaluate --report`` and ``hykin demo`` all call :func:`build_report`
(the demo appends its comparison with the paper to the returned :class:`Report`).

Sections, in reading order: summary in words; model card and data; accuracy per model (position,
orientation, per base axis) with error distributions; where the error is (against each joint, in
the workspace, per joint region); ISO 9283; training support; per payload and per temperature;
calibration (table and correlation heatmap); inverse-kinematics timings.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..hybrid.stations import in_model_frame
from . import report_accuracy as acc
from .evaluate import evaluate_model
from .report import Report, mm
from .report_calibration import HEADER as CAL_HEADER
from .report_calibration import TEXT_COLS as CAL_TEXT
from .report_calibration import calibration_rows, calibration_summary
from .report_card import DATA_HEADER, card_rows, data_rows
from .report_figures import (
    correlation_figure,
    distributions_figure,
    error_histograms,
    joint_error_figure,
    spatial_error_figure,
)
from .report_ik import HEADER as IK_HEADER
from .report_ik import time_hybrid_ik
from .report_summary import accuracy_sentences, final_model, metadata_sentences, nominal_meaningless

__all__ = ["build_report", "evaluation_report", "write_report"]


def _revolute(robot) -> np.ndarray:
    jt = getattr(robot, "joint_type", None) or ("revolute",) * robot.dof
    return np.array([t == "revolute" for t in jt], bool)


def _calibration(model) -> dict | None:
    cal = getattr(model, "calibration", None)
    if cal is not None:
        return cal.to_dict()
    return ((getattr(model, "metadata", None) or {}).get("calibration")) or None


def build_report(model, test=None, *, model_path=None, test_path=None, title: str | None = None,
                 res=None, ik_targets: int = 20, seed: int = 0, intro: list[str] | None = None) -> tuple[Report, object]:
    """The report of ``model`` (a fitted :class:`hykin.hybrid.model.HybridModel` or a :class:`Robot`),
    evaluated on ``test`` (a Dataset, optional; ``res``: its :func:`evaluate_model` result when already
    computed). ``ik_targets``: targets for the warm IK timing (0: none). ``intro``: paragraphs placed
    after the summary (what the data are). Returns ``(report, res)``."""
    robot = getattr(model, "nominal", None) or model
    rev = _revolute(robot)
    if test is not None and res is None:
        res = evaluate_model(model, test)
    name = Path(str(model_path)).name if model_path else robot.name
    rep = Report(title or f"hykin report: {name}")
    rep.subtitle = f"robot {robot.name}" + (f"; test data {Path(str(test_path or test.source)).name} ({len(test)} poses)" if test is not None else "")
    cal = _calibration(model)
    cal_rows = calibration_rows(cal, robot, getattr(model, "robot_", None)) if cal else []

    frame = acc.base_frame(model, in_model_frame(model, test), res.labels) if res is not None else None
    summary = accuracy_sentences(res, test, rev, model, frame) if res is not None else metadata_sentences(model)
    nom_fit = _nominal_fitted(res)
    if cal:
        summary += calibration_summary(cal, cal_rows, nom_fit)[:2]
    meta = getattr(model, "metadata", None) or {}
    if meta:
        summary.append(f"Trained on {meta.get('n_total', '?')} measured poses (seed {meta.get('seed', '?')}); "
                       "the model card below lists the files and their hashes.")
    rep.summary(summary)
    for p in intro or []:
        rep.text(p)

    rep.heading("Model card")
    rep.table(["item", "value"], card_rows(model, model_path), text_cols=2)
    drows = data_rows(model, test, test_path)
    if drows:
        rep.table(DATA_HEADER, drows, "Data", text_cols=2)

    if res is not None:
        _accuracy_sections(rep, model, test, res, rev, frame)
    if cal:
        _calibration_section(rep, cal, cal_rows, nom_fit)
    if ik_targets and hasattr(model, "predict_classical"):
        _ik_section(rep, model, test, ik_targets, seed)
    return rep, res


def _accuracy_sections(rep: Report, model, test, res, rev, frame: acc.BaseFrame | None = None) -> None:
    names = list(res.vectors)
    labels = {k: acc.display_name(res, k) for k in names}
    tm = in_model_frame(model, test)  # the rows in the frame the model predicts in
    if frame is None:
        frame = acc.base_frame(model, tm, res.labels)
    nom = labels.get("nominal", "nominal")
    rep.heading("Accuracy on the test data")
    axes = ("x, y, z in the robot's base frame (" + frame.words + ")" if frame.is_base
            else "x, y, z in the measurement frame: no robot base is known")
    rep.note(f"{nom}: the robot's {acc.nominal_words(res)}; calibrated: the calibrated classical model; hybrid: calibrated "
             "model plus the learned residual networks. Errors are predicted minus measured. For |e| the mean is of the "
             f"error's length; for a component ({axes}; rx, ry, rz rotations about them) the "
             "mean is signed (a bias) and the std its spread. std: the population standard deviation (ddof = 0); p95: "
             "the 95th percentile (linear interpolation).")
    few = nominal_meaningless(res, test)
    if few is not None:
        rep.note(f"The {nom} row is not meaningful here: its base and tool were fitted to only {few} distinct test poses, "
                 "a fit that absorbs much of the nominal model's error.")
    rep.table(acc.AXIS_HEADER, acc.axis_rows(res.vectors, frame, labels), text_cols=2)
    _per_group_table(rep, res, labels)
    last = final_model(res)
    rep.figure(distributions_figure({labels[k]: res.errors[k] for k in names}),
               f"Error distributions on the test data, {', '.join(labels[k] for k in names)} (log scale).")

    rep.heading("Where the error is")
    keep, left_out = _without_outliers(res)  # a lost beam is named, not drawn as a joint range's error
    rep.figure(joint_error_figure(np.asarray(test.q)[keep], {labels[k]: res.errors[k][0][keep] for k in names}, rev),
               f"Position error against each joint: lines are mean errors per joint bin, dots the {last} model's test "
               f"poses.{left_out}")
    rep.figure(spatial_error_figure(frame.points(tm.xyz_m)[keep], res.errors[last][0][keep], last),
               f"Test positions ({frame.name}{', ' + frame.words if frame.is_base else ''}) seen from above (x–y) "
               f"and from the sides, coloured by the {last} model's position error.{left_out}")
    if res.regions:
        rep.note("Per joint quartile (registered model; mean mm): nominal + rigid fit is the nominal robot with base and "
                 "tool fitted to all of these poses.")
        keys = [k for k in res.regions[0] if k not in ("region", "n")]
        rep.table(["region", "n", *keys], [[r["region"], r["n"], *(r[k][0] for k in keys)] for r in res.regions])

    rep.heading("ISO 9283 pose accuracy and repeatability")
    rows, note = acc.iso_rows(tm, res.predicted, frame, labels)
    res.iso9283 = {"columns": list(acc.ISO_HEADER), "rows": rows, "note": note}  # evaluation.json too
    if rows:
        rep.table(acc.ISO_HEADER, rows, text_cols=2)
    rep.note(note)

    srows, n_out = acc.support_rows(model, test.q, rev)
    if srows:
        rep.heading("Training support")
        rep.table(acc.SUPPORT_HEADER, srows, text_cols=2)
        rep.note(f"{n_out} of {res.n} test poses lie outside the training support (outside a joint's trained range, or "
                 "in a gap between training poses); the network correction fades to the calibrated model there. "
                 + acc.support_note(model))
    prow = acc.per_payload_rows(res.per_payload, labels)
    from ..calibration.thermal import temperature_of

    trow = acc.per_temperature_rows(temperature_of(test), res.errors, labels=labels)
    if prow or trow:
        rep.heading("Per payload and temperature")
        if prow:
            rep.table(acc.PAYLOAD_HEADER, prow, text_cols=2)
        if trow:
            rep.table(acc.TEMPERATURE_HEADER, trow, text_cols=2)
    else:
        rep.note("The test data carry no payload_kg or temperature_c column: no per-payload or per-temperature tables.")


def _without_outliers(res) -> tuple[np.ndarray, str]:
    """``(keep (N,) bool, caption sentence)``: the rows the where-is-the-error figures show, all but the
    test rows named as outliers (the summary's hotspots leave them out too); the sentence names them."""
    keep = np.ones(res.n, bool)
    o = getattr(res, "outliers", None)
    if o is None:
        return keep, ""
    keep[o.rows] = False
    k = len(o.rows)
    shown = ", ".join(str(int(r) + 1) for r in o.rows[:12]) + (f" and {k - 12} more" if k > 12 else "")
    return keep, (f" The {k} test row{'s' if k > 1 else ''} named as outlier{'s' if k > 1 else ''} (data row"
                  f"{'s' if k > 1 else ''} {shown}, {mm(float(o.pos_mm.max()), zeros=True)} max) {'are' if k > 1 else 'is'} left out "
                  "here; the tables above count them.")


def _per_group_table(rep: Report, res, labels: dict) -> None:
    """The accuracy per station and per tool (test data naming more than one), the reference named."""
    if not getattr(res, "per_group", None):
        return
    from .per_group import GROUP_HEADER, group_rows, reference_words

    ref = reference_words(res.per_group)
    rep.table(GROUP_HEADER, group_rows(res.per_group, labels), text_cols=3,
              caption=f"Accuracy per {' and per '.join(res.per_group)}: each row in its own station's and tool's "
                      f"frame{' (' + ref + ': the robot base and TCP of the model)' if ref else ''}.")


def _nominal_fitted(res) -> tuple[float, str] | None:
    """``(mean mm, where)`` of the evaluation's nominal row when its base and tool were fitted to the test poses
    (the robot's own error, as the accuracy table shows it), else None."""
    from .evaluate import NOMINAL_FITTED

    if res is None or "nominal" not in res.stats or acc.display_name(res, "nominal") != NOMINAL_FITTED:
        return None
    return res.stats["nominal"].pos_mean_mm, "on the test data, as in the accuracy table"


def _calibration_section(rep: Report, cal: dict, rows, nom_fit: tuple[float, str] | None = None) -> None:
    rep.heading("Calibration")
    rep.bullets(calibration_summary(cal, rows, nom_fit))
    rep.note("Deviation = identified − nominal; for base and tool, the correction along the nominal frame's own axes (the "
             "notes give identified − nominal where the two differ). Further stations' and tools' frames "
             "(station[..], tool[..]) have no robot-file value: their identified value is the frame itself (station → "
             "robot base, flange → TCP) and they have no deviation. Posterior std: "
             "the standard deviation of the identified value (residual noise and prior); prior std: the tolerance the "
             "calibration assumed for the robot file's value (blank: uninformative). Status (docs/calibration-priors.md): "
             "identified; correlated with the named parameters (|ρ| ≥ 0.99: the data tell their combination, the priors "
             "the split; a partner held at prior keeps the robot file's value, so this parameter takes the whole "
             "combination); held at prior (greyed: these poses do not excite it, so it keeps the robot file's value and "
             "its posterior std is the prior's); at bound 0 (a compliance held rigid). Base/tool rx, ry, rz: rotation vector.")
    rep.table(CAL_HEADER, [r.cells() for r in rows], text_cols=CAL_TEXT, digits=6, row_classes=["held" if r.held else "" for r in rows])
    names, corr = cal.get("correlation_names") or [], np.asarray(cal.get("correlation") or [])
    if len(names) >= 2 and corr.shape == (len(names), len(names)):
        rep.figure(correlation_figure(names, corr),
                   "Correlation of the identified parameters (red +1, blue −1): strongly correlated pairs are hard "
                   "to tell apart from these poses. Parameters held at prior are not shown; a partner named in the "
                   "table's status that is missing here is one of them.")


def _ik_section(rep: Report, model, test, n: int, seed: int) -> None:
    if test is not None:
        q = np.asarray(test.q)[: int(n)]
    else:
        q = model.nominal.random_joints(int(n), seed)
        lo, hi = getattr(model, "support_lower_", None), getattr(model, "support_upper_", None)
        if lo is not None and np.all(getattr(model, "input_mask_", True)) and not np.isfinite(getattr(model, "wrap_centre_", [np.nan])).any():
            q = np.clip(q, lo, hi)
    t = time_hybrid_ik(model, q)
    if t is None:
        return
    rep.heading("Inverse kinematics timing")
    rep.table(IK_HEADER, t.rows(), text_cols={0, 5})
    rep.note(f"Warm figures: one untimed call first (imports, compiled kernels), then the best of 2 calls on {t.n_targets} "
             "targets (the model's own poses at test joints), divided by the number of targets, on this machine while "
             "it wrote the report. Hybrid IK is vectorised over the targets of a call: on batches of thousands the cost "
             "per target is much lower, on a handful it is dominated by fixed per-call work. A first, cold call costs more.")


def write_report(rep: Report, out_dir, res=None) -> Path:
    """Write ``out_dir/report.html`` (and ``out_dir/evaluation.json`` with ``res``); returns the HTML path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if res is not None:
        (out / "evaluation.json").write_text(res.json(), encoding="utf-8")
    return rep.write(out / "report.html")


def evaluation_report(res, out_dir: str | Path, title: str | None = None, *, model=None, data=None,
                      model_path=None, test_path=None, ik_targets: int = 20) -> Path:
    """Write ``out_dir/report.html`` (the report of :func:`build_report`)
    and ``out_dir/evaluation.json``. ``model`` and ``data``: the model and test Dataset ``res`` was
    computed from (without them only the error tables and distributions of ``res`` are shown)."""
    if model is None or data is None:
        rep = Report(title or "hykin evaluation")
        rep.text(f"Dataset: {res.dataset} ({res.n} samples{', position only' if res.position_only else ''}).")
        names = list(res.errors)
        b, a = res.errors[names[0]], res.errors[names[-1]]
        rep.figure(error_histograms(b[0], a[0], b[1], a[1], labels=(names[0], names[-1])),
                   caption=f"Error distributions, {names[0]} vs {names[-1]}.")
        return write_report(rep, out_dir, res)
    rep, _ = build_report(model, data, model_path=model_path, test_path=test_path, title=title, res=res, ik_targets=ik_targets)
    return write_report(rep, out_dir, res)
