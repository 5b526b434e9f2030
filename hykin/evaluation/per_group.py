"""Accuracy per station and per tool: test data with a ``station`` or ``tool`` column of more than one
label (a laser tracker moved between set-ups, several reflector mounts) get their error statistics
per label, so that one badly registered station or one tool whose frame is off shows in the figures
instead of hiding in the mean over all rows.

Errors are the evaluation's per-row errors (mm, deg), each row in its own station's and tool's frame
(:func:`hykin.hybrid.stations.in_model_frame`); the reference station / tool is the model's first
(its robot base and TCP), named in the tables.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GROUP_HEADER", "group_labels", "group_rows", "group_stats", "group_table", "reference_words"]

#: the report's table columns (position mm, orientation deg)
GROUP_HEADER = ["group", "label", "model", "n", "position mean [mm]", "position p95 [mm]", "position max [mm]",
                "orientation mean [deg]"]


def group_labels(model, data) -> dict[str, dict]:
    """Per label column of ``data`` (``"station"``, ``"tool"``) with more than one label:
    ``{"labels": (N,) str per row, "reference": the model's reference label or None}``. Empty dict
    when the data have no such column or one label only (one frame: nothing to break down)."""
    from ..io.dataset import STATION_COLUMN, TOOL_COLUMN, row_labels

    if data is None or not getattr(data, "extra", None):
        return {}
    fr = getattr(model, "station_frames_", None)
    refs = {STATION_COLUMN: None if fr is None else str(fr.station_labels[0]),
            TOOL_COLUMN: None if fr is None else str(fr.tool_labels[0])}
    out = {}
    for col in (STATION_COLUMN, TOOL_COLUMN):
        lab = row_labels(data, col)
        if lab is not None and len(np.unique(lab)) > 1:
            out[col] = {"labels": lab, "reference": refs[col]}
    return out


def _ordered(labels: np.ndarray, reference: str | None) -> list[str]:
    """The distinct labels, the reference first, then in order of first appearance."""
    _, first = np.unique(labels, return_index=True)
    seen = [str(labels[i]) for i in np.sort(first)]
    return ([reference] if reference in seen else []) + [s for s in seen if s != reference]


def group_stats(errors: dict, groups: dict) -> dict:
    """Error statistics per label: ``{column: {"reference": str | None, "labels": {label: {model: {"n",
    "pos_mean_mm", "pos_p95_mm", "pos_max_mm", "ang_mean_deg" (None for positions only)}}}}}``.
    ``errors``: model -> ``(pos_mm (N,), ang_deg (N,) or None)``; ``groups``: :func:`group_labels`.
    p95: numpy's linear-interpolation percentile, as in the overall table."""
    out = {}
    for col, g in groups.items():
        per = {}
        for lab in _ordered(g["labels"], g["reference"]):
            sel = g["labels"] == lab
            per[lab] = {name: _subset_stats(p[sel], None if a is None else a[sel]) for name, (p, a) in errors.items()}
        out[col] = {"reference": g["reference"], "labels": per}
    return out


def _subset_stats(pos_mm: np.ndarray, ang_deg: np.ndarray | None) -> dict:
    """The table's figures of one label's rows, from the evaluation's own statistics
    (:func:`.metrics.stats_from_errors`)."""
    from .metrics import stats_from_errors

    st = stats_from_errors(pos_mm, ang_deg)
    return {"n": st.n, "pos_mean_mm": st.pos_mean_mm, "pos_p95_mm": st.pos_p95_mm, "pos_max_mm": st.pos_max_mm,
            "ang_mean_deg": st.ang_mean_deg}


def group_rows(stats: dict, labels: dict | None = None) -> list[list]:
    """Rows of :data:`GROUP_HEADER` from :func:`group_stats` (the reference label marked "(reference)");
    ``labels``: model key -> the name shown."""
    rows = []
    for col, g in stats.items():
        for lab, models in g["labels"].items():
            shown = f"{lab} (reference)" if lab == g["reference"] else lab
            for name, s in models.items():
                rows.append([col, shown, (labels or {}).get(name, name), s["n"], s["pos_mean_mm"], s["pos_p95_mm"],
                             s["pos_max_mm"], s["ang_mean_deg"]])
    return rows


def group_table(stats: dict, labels: dict | None = None) -> str:
    """The per-station / per-tool figures as a markdown table for the terminal (mm, deg)."""
    f = lambda v: "–" if v is None else f"{v:.4g}"
    lines = ["| " + " | ".join(GROUP_HEADER) + " |", "|" + "---|" * len(GROUP_HEADER)]
    for r in group_rows(stats, labels):
        lines.append("| " + " | ".join([r[0], r[1], r[2], str(r[3]), *map(f, r[4:])]) + " |")
    return "\n".join(lines)


def reference_words(stats: dict) -> str:
    """"reference station T1, reference tool smrA" for the columns that name one ("" if none)."""
    return ", ".join(f"reference {col} {g['reference']}" for col, g in stats.items() if g["reference"] is not None)
