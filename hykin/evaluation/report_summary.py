"""The written summary at the top of the report, computed from the evaluation (never canned): how
accurate the model is, how much of the nominal error it removes, where the largest errors remain,
how many test poses lie outside the training data, and which data it was trained on.
"""

from __future__ import annotations

import numpy as np

from ..hybrid.stations import in_model_frame
from .report import deg, mm
from .report_accuracy import (
    FEW_FIT_POSES,
    base_frame,
    display_name,
    distinct_poses,
    gap_words,
    joint_hotspot,
    nominal_words,
    outside_split,
    reach_hotspot,
)

__all__ = ["accuracy_sentences", "final_model", "group_sentence", "metadata_sentences", "nominal_meaningless", "support_sentence"]


def final_model(res) -> str:
    """The row the report judges: ``hybrid`` when present, else the last model of the evaluation."""
    return "hybrid" if "hybrid" in res.stats else list(res.stats)[-1]


def _pct(a: float, b: float) -> str:
    """Share of ``b`` removed when it becomes ``a``, with enough digits to tell 99.9 % from 99.999 %."""
    if not b > 0:
        return "–"
    r = 100 * (1 - a / b)
    return f"{r:.1f} %" if r < 99.9 else f"{r:.4g} %"


def nominal_meaningless(res, data) -> int | None:
    """The number of distinct test poses when the nominal row's base and tool were fitted to fewer than
    :data:`FEW_FIT_POSES` of them (its error then says little about the nominal model); else None."""
    from .evaluate import NOMINAL_FITTED

    if display_name(res, "nominal") != NOMINAL_FITTED or data is None:
        return None
    n = distinct_poses(data.q)
    return n if n < FEW_FIT_POSES else None


def accuracy_sentences(res, data, revolute, model=None, frame=None) -> list[str]:
    """Sentences on the test data: accuracy of the final model, share of the nominal error removed
    (and by the calibration alone), where the largest errors remain, poses outside the training data.
    ``frame``: the :class:`~.report_accuracy.BaseFrame` reach is measured in (default that of ``model``);
    the nominal row is named as the evaluation labels it (nominal + fitted frames for tracker-frame data)."""
    name = final_model(res)
    s = res.stats[name]
    out = []
    line = (f"On {res.n} test poses the {name} model is accurate to {mm(s.pos_mean_mm)} on average "
            f"(95 % of poses within {mm(s.pos_p95_mm)}, worst {mm(s.pos_max_mm, zeros=True)})")
    if s.ang_mean_deg is not None:
        line += f" and {deg(s.ang_mean_deg)} in orientation (95 % within {deg(s.ang_p95_deg)})"
    out.append(line + ".")
    nom = res.stats.get("nominal")
    few = nominal_meaningless(res, data) if nom is not None else None
    nom_label = display_name(res, "nominal")
    if few is not None and name != "nominal":
        out.append(f"The {nom_label} row ({nominal_words(res)}) rests on only {few} distinct test poses: a rigid fit "
                   f"of base and tool to so few poses absorbs much of the nominal model's error, so its figure "
                   f"({mm(nom.pos_mean_mm)}) is not meaningful and no share of the nominal error removed is given.")
    elif nom is not None and name != "nominal":
        what = ("the nominal model's mean position error" if nom_label == "nominal" else
                f"the mean position error of the {nom_label} row, the robot's {nominal_words(res)}")
        line = (f"It removes {_pct(s.pos_mean_mm, nom.pos_mean_mm)} of {what} "
                f"({mm(nom.pos_mean_mm)} → {mm(s.pos_mean_mm)})")
        if nom.ang_mean_deg is not None and s.ang_mean_deg is not None:
            line += f" and {_pct(s.ang_mean_deg, nom.ang_mean_deg)} of its orientation error ({deg(nom.ang_mean_deg)} → {deg(s.ang_mean_deg)})"
        cal = res.stats.get("calibrated")
        if cal is not None and name != "calibrated":
            line += f"; the calibration alone removes {_pct(cal.pos_mean_mm, nom.pos_mean_mm)} ({mm(cal.pos_mean_mm)})"
        out.append(line + ".")
    e = res.errors[name][0]
    keep = np.ones(len(e), bool)  # far-off rows (a lost beam) named, not blamed on a joint range
    if getattr(res, "outliers", None) is not None:
        keep[res.outliers.rows] = False
        out.append(res.outlier_line() + ".")
    hot = joint_hotspot(np.asarray(data.q)[keep], e[keep], revolute)
    dm = in_model_frame(model, data)
    if frame is None:
        frame = base_frame(model, dm, getattr(res, "labels", None))
    reach = reach_hotspot(np.asarray(dm.xyz_m)[keep], e[keep], frame=frame)
    if reach is not None and not frame.is_base:
        reach.what = "horizontal distance from the measurement frame's origin"
    where = [h.words() for h in (hot, reach) if h is not None and h.mean_mm > 1.2 * h.overall_mm]
    if where:
        out.append("The largest remaining errors are at " + "; and at ".join(where) + ".")
    elif hot is not None:
        out.append("The remaining error is spread evenly: no joint range or reach has a mean error above 1.2 × the overall mean.")
    groups = group_sentence(res, name)
    if groups:
        out.append(groups)
    if res.support_distance is not None:
        out.append(support_sentence(res, data, model, e))
    return out


def group_sentence(res, name: str) -> str:
    """The ``name`` model's mean position error per station and per tool, the reference labels named
    ("" when the test data name one station and one tool)."""
    per = getattr(res, "per_group", None)
    if not per:
        return ""
    parts = []
    for col, g in per.items():
        cells = ", ".join(f"{lab}{' (reference)' if lab == g['reference'] else ''} {mm(m[name]['pos_mean_mm'])} "
                          f"({m[name]['n']} poses)" for lab, m in g["labels"].items())
        parts.append(f"per {col}: {cells}")
    return f"Mean position error of the {name} model " + "; ".join(parts) + " (table below)."


def support_sentence(res, data, model, e: np.ndarray) -> str:
    """How many test poses lie outside the training support, and why: in a gap of a folded joint's
    training data (:func:`~.report_accuracy.fold_gaps`), beyond a joint's trained range, or between
    training poses; ``e``: the judged model's position errors (mm)."""
    out_rows = res.support_distance > 0
    n_out = int(out_rows.sum())
    if not n_out:
        return "All test poses lie inside the training data."
    split = outside_split(model, np.asarray(data.q), out_rows) if model is not None else None
    why = []
    if split is not None:
        ex = np.asarray(model.range_excess(np.asarray(data.q)))[split["gap"]] if split["gap"].any() else None
        gw = gap_words(model, set(np.flatnonzero((ex > 0).any(0)).tolist()) if ex is not None else set())
        for key, words in (("gap", f"in a gap of the training data ({gw})"), ("range", "beyond a joint's trained range"),
                           ("holes", "between training poses")):
            k = int(split[key].sum())
            if k:
                why.append(f"{k} {words}")
    return (f"{n_out} of {res.n} test poses lie outside the training support, mean error there "
            f"{mm(float(e[out_rows].mean()))}" + (f": {'; '.join(why)}" if why else "")
            + ". There the network correction fades out towards the calibrated model.")


def metadata_sentences(model) -> list[str]:
    """Sentences from the model's own record when there are no test data: errors on its held-out /
    validation / training rows."""
    metrics = (getattr(model, "metadata", None) or {}).get("metrics") or {}
    out = []
    labels = {"held_out": "the rows held out from network training", "val": "the validation data", "train": "the training data"}
    for key in ("held_out", "val", "train"):
        m = metrics.get(key)
        if not m:
            continue
        line = f"On {labels[key]} the hybrid model's mean position error is {mm(m.get('hybrid_pos_mean_mm', float('nan')))}"
        if "hybrid_rot_mean_deg" in m:
            line += f" and {deg(m['hybrid_rot_mean_deg'])} in orientation"
        line += f" (calibrated model alone: {mm(m.get('classical_pos_mean_mm', float('nan')))})."
        out.append(line)
        break
    out.append("No test data were given: pass a test file (hykin report MODEL TEST.csv) for accuracy tables, "
               "error maps and ISO 9283 figures.")
    return out
