"""Error statistics of predicted vs measured poses (DESIGN.md §1.4 "Evaluation").

* :func:`pose_errors` — per-sample position error (mm) and orientation error (deg).
* :func:`error_stats` — mean / std / p95 / max of both, as an :class:`ErrorStats`.
* :func:`format_table` — a markdown table like Table I of Ojer et al. (rows = models).
* :func:`compare` — relative reductions (%) between two :class:`ErrorStats`.

Conventions: ``std`` is the population standard deviation (``ddof=0``, as ``numpy.std``); ``p95`` is
the 95th percentile with numpy's default linear interpolation. The orientation error is the angle of
``R_pred R_meas^T`` (:func:`hykin.geometry.se3.pose_error`).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..geometry.se3 import pose_error

__all__ = ["ErrorStats", "MetricsError", "compare", "error_stats", "format_table", "pose_errors", "stats_from_errors"]


class MetricsError(ValueError):
    """Input to a metrics function has the wrong shape or contains non-finite values."""


@dataclass(frozen=True)
class ErrorStats:
    """Summary of pose errors over ``n`` samples. Position in mm, orientation in degrees.

    Orientation fields are ``None`` for position-only data.
    """

    n: int
    pos_mean_mm: float
    pos_std_mm: float
    pos_p95_mm: float
    pos_max_mm: float
    ang_mean_deg: float | None = None
    ang_std_deg: float | None = None
    ang_p95_deg: float | None = None
    ang_max_deg: float | None = None

    @property
    def has_orientation(self) -> bool:
        return self.ang_mean_deg is not None

    def to_dict(self) -> dict:
        """Plain dict of the fields (JSON-serialisable)."""
        return asdict(self)


def _as_batch(x, name: str) -> np.ndarray:
    """Accept (N,4,4) transforms or (N,3) positions (m); return as float64 array."""
    x = np.asarray(x, dtype=np.float64)
    if x.shape == (4, 4):
        x = x[None]
    if x.ndim == 1 and x.shape == (3,):
        x = x[None]
    if not ((x.ndim == 3 and x.shape[1:] == (4, 4)) or (x.ndim == 2 and x.shape[1] == 3)):
        raise MetricsError(f"{name}: expected (N, 4, 4) transforms or (N, 3) positions in m, got shape {x.shape}")
    bad = ~np.isfinite(x.reshape(len(x), -1)).all(axis=1)
    if bad.any():
        raise MetricsError(f"{name}: non-finite values in row(s) {np.flatnonzero(bad)[:10].tolist()}")
    return x


def pose_errors(T_pred, T_meas) -> tuple[np.ndarray, np.ndarray | None]:
    """Per-sample errors: ``(pos_mm (N,), ang_deg (N,))``.

    ``T_pred`` and ``T_meas`` are ``(N, 4, 4)`` poses (m) or ``(N, 3)`` positions (m); with positions
    the angle is ``None``.
    """
    A = _as_batch(T_pred, "T_pred")
    B = _as_batch(T_meas, "T_meas")
    if A.shape[0] != B.shape[0]:
        raise MetricsError(f"T_pred has {A.shape[0]} samples but T_meas has {B.shape[0]}")
    if A.ndim == 3 and B.ndim == 3:
        return pose_error(A, B)
    pa = A[:, :3, 3] if A.ndim == 3 else A
    pb = B[:, :3, 3] if B.ndim == 3 else B
    return np.linalg.norm(pa - pb, axis=-1) * 1e3, None


def stats_from_errors(pos_mm, ang_deg=None) -> ErrorStats:
    """:class:`ErrorStats` from per-sample error arrays (mm, deg)."""
    pos = np.asarray(pos_mm, dtype=np.float64).ravel()
    if pos.size == 0:
        raise MetricsError("no samples: error statistics need at least one pose")
    if not np.isfinite(pos).all():
        raise MetricsError("position errors contain non-finite values")

    def four(x):
        return float(x.mean()), float(x.std()), float(np.percentile(x, 95)), float(x.max())

    kw = dict(zip(("pos_mean_mm", "pos_std_mm", "pos_p95_mm", "pos_max_mm"), four(pos)))
    if ang_deg is not None:
        ang = np.asarray(ang_deg, dtype=np.float64).ravel()
        if ang.shape != pos.shape:
            raise MetricsError(f"{pos.size} position errors but {ang.size} angle errors")
        if not np.isfinite(ang).all():
            raise MetricsError("angle errors contain non-finite values")
        kw.update(zip(("ang_mean_deg", "ang_std_deg", "ang_p95_deg", "ang_max_deg"), four(ang)))
    return ErrorStats(n=int(pos.size), **kw)


def error_stats(T_pred, T_meas, position_only: bool = False) -> ErrorStats:
    """Mean / std / p95 / max of position (mm) and orientation (deg) errors of ``T_pred`` vs ``T_meas``.

    ``position_only=True`` (or position arrays as input) leaves the orientation fields ``None``.
    """
    pos, ang = pose_errors(T_pred, T_meas)
    return stats_from_errors(pos, None if position_only else ang)


def _fmt(x: float | None, digits: int) -> str:
    if x is None:
        return "–"
    return f"{x:.{digits}g}" if abs(x) < 1e-3 and x != 0 else f"{x:.{digits}f}"


def format_table(rows: dict[str, ErrorStats], digits: int = 4) -> str:
    """Markdown table like the paper's Table I: one row per model.

    Columns: n, position mean ± std, p95, max (mm); orientation mean ± std, p95, max (deg).
    """
    if not rows:
        raise MetricsError("format_table needs at least one row")
    head = ["model", "n", "pos mean ± std (mm)", "pos p95 (mm)", "pos max (mm)",
            "ang mean ± std (deg)", "ang p95 (deg)", "ang max (deg)"]
    lines = []
    for name, s in rows.items():
        if not isinstance(s, ErrorStats):
            raise MetricsError(f"row {name!r}: expected ErrorStats, got {type(s).__name__}")
        ang = (f"{_fmt(s.ang_mean_deg, digits)} ± {_fmt(s.ang_std_deg, digits)}" if s.has_orientation else "–")
        lines.append([name, str(s.n), f"{_fmt(s.pos_mean_mm, digits)} ± {_fmt(s.pos_std_mm, digits)}",
                      _fmt(s.pos_p95_mm, digits), _fmt(s.pos_max_mm, digits), ang,
                      _fmt(s.ang_p95_deg, digits), _fmt(s.ang_max_deg, digits)])
    widths = [max(len(head[i]), *(len(r[i]) for r in lines)) for i in range(len(head))]
    def row(cells):
        return "| " + " | ".join(c.ljust(w) for c, w in zip(cells, widths)) + " |"
    out = [row(head), "|" + "|".join("-" * (w + 2) for w in widths) + "|"]
    out += [row(r) for r in lines]
    return "\n".join(out)


def compare(before: ErrorStats, after: ErrorStats) -> dict:
    """Reduction from ``before`` to ``after`` in percent, per statistic: ``100 (1 - after/before)``.

    Keys like ``"pos_mean_reduction_pct"``; also ``"pos_mean_ratio"`` (= before/after, the factor of
    improvement; ``inf`` when ``after`` is 0). Orientation keys only when both have orientation.
    """
    out: dict = {}
    keys = ["pos_mean", "pos_std", "pos_p95", "pos_max"]
    units = {"pos": "mm", "ang": "deg"}
    if before.has_orientation and after.has_orientation:
        keys += ["ang_mean", "ang_std", "ang_p95", "ang_max"]
    for k in keys:
        field = f"{k}_{units[k[:3]]}"
        b, a = getattr(before, field), getattr(after, field)
        if b == 0:
            out[f"{k}_reduction_pct"] = 0.0 if a == 0 else float("-inf")
        else:
            out[f"{k}_reduction_pct"] = 100.0 * (1.0 - a / b)
        out[f"{k}_ratio"] = float("inf") if a == 0 else b / a
    return out
