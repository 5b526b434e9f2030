"""Gross outliers among the measured poses: rows the calibrated model cannot explain.

A lost tracker beam, a reflector seated in the wrong nest, a point given another pose's name or a row
of another station sits millimetres off where every other row fits to a fraction of a millimetre.
Least squares lets such a row pull every parameter, and the networks learn it as if it were the robot.

Test (per row, after the calibration): the row's error ``e_i`` (position: distance to the calibrated
model, the largest over the reflectors; orientation: rotation angle) against the typical error
``s = median(e) / MAXWELL_MEDIAN``, the per-coordinate σ of an isotropic Gaussian error whose
distance has that median. A row is an outlier when ``e_i > ratio · s`` and ``e_i`` exceeds a floor
(noise-free data fit to rounding; the floor keeps rounding from being called an outlier).

The default ratio 12 was chosen on clean data (``benchmarks/bench_outliers.py``, 3,000 poses each):
calibrated with hykin, the largest row of the virtual robots rx160-nongeo, ur10 and kr-payload lay
4.7–5.7 s off, of the public tracker sets ipa-robot-accuracy A / B and serial-robots-ur5 5.6 / 9.2 /
4.6 s. A Gaussian row beyond 12 s has probability ~1e-30. Ten lost beams of 1, 2 and 5 mm among 3,000
ur10-virtual poses were all found, no other row; keeping them made the calibrated held-out error
1.03x, 1.10x and 1.67x that of dropping them.

At most ``MAX_FRACTION`` of the rows are dropped (2 %): more than that is not a few bad points but a
robot file or data that do not fit, which the calibration's own checks judge; those rows are only
named, and when the rows from one row on fit ``STEP_RATIO`` (5) times worse than those before
(:func:`step_change`) the message says joints and measurements are out of step. Fewer than
``MIN_ROWS`` rows give no reliable median: no test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .jacobian import residual

__all__ = ["DEFAULT_RATIO", "OUTLIER_MODES", "Outliers", "OutlierWarning", "find_outliers", "row_errors", "rows_out_of_step", "step_change",
           "subset_rows"]

#: median of the distance of an isotropic 3-D Gaussian error, in units of its per-coordinate σ
MAXWELL_MEDIAN = 1.5382
DEFAULT_RATIO = 12.0
MAX_FRACTION = 0.02
MIN_ROWS = 20
FLOOR_M = 50e-6  # below any robot's repeatability: noise-free fits are never "outliers"
FLOOR_RAD = math.radians(0.01)  # a T-Mac orientation is good to a few 0.001°
OUTLIER_MODES = ("drop", "warn", "keep")
SHIFT_ROWS = 200  # rows_out_of_step tests the first rows only
STEP_RATIO = 5.0  # rows from some row on this many times worse than before: a row slipped in one file


class OutlierWarning(UserWarning):
    """Rows of the measured data that lie far off the calibrated model (named, with their errors)."""


@dataclass
class Outliers:
    """Rows found by :func:`find_outliers`.

    rows: ``(k,)`` 0-based data rows (row ``r`` is the file's data row ``r + 1``); pos_mm / rot_deg:
    their errors against the calibrated model (``rot_deg`` None for positions only); typical_pos_mm /
    typical_rot_deg: ``s`` of the test (per coordinate); ratio: the threshold in units of ``s``;
    n_rows: rows tested; dropped: whether the calibration left them out (else only named).
    """

    rows: np.ndarray
    pos_mm: np.ndarray
    rot_deg: np.ndarray | None
    typical_pos_mm: float
    typical_rot_deg: float | None
    ratio: float
    n_rows: int
    dropped: bool = False
    #: ``(first row, ratio)``: from that 0-based row on the rows fit ``ratio`` x worse than before
    #: (:func:`step_change`), or None
    step: tuple[int, float] | None = None

    @property
    def droppable(self) -> bool:
        """Few enough to be bad points rather than a misfit (at most ``MAX_FRACTION`` of the rows)."""
        return len(self.rows) <= max(1, int(MAX_FRACTION * self.n_rows))

    def message(self, source: str | None = None, against: str = "the calibrated model", tail: str | None = None) -> str:
        """One line: which rows (1-based data rows), how far off ``against`` which model, the likely cause and
        what was done with the option (``tail`` replaces those two)."""
        k = len(self.rows)
        shown = ", ".join(str(int(r) + 1) for r in self.rows[:12]) + (f" and {k - 12} more" if k > 12 else "")
        size = f"{self.pos_mm.min():.3g}–{self.pos_mm.max():.3g} mm" if k > 1 else f"{self.pos_mm[0]:.3g} mm"
        if self.rot_deg is not None:
            size += f", {self.rot_deg.max():.3g} deg"
        typ = f"{self.typical_pos_mm:.3g} mm" + ("" if self.typical_rot_deg is None else f" / {self.typical_rot_deg:.3g} deg")
        head = f"{source}: " if source else ""
        what = ("left out of the fit (--outliers keep uses them)" if self.dropped else
                "kept: more than 2 % of the rows, so the robot file or the data may not fit" if not self.droppable else
                "kept (--outliers warn; --outliers drop leaves them out)")
        if self.step is not None:
            return (f"{head}from data row {self.step[0] + 1} on the poses fit {self.step[1]:.3g}x worse than the rows before "
                    f"({k} of {self.n_rows} more than {self.ratio:g}x the typical error off {against}): joints "
                    f"and measurements out of step (a row missing or doubled in one of the files)? {what}")
        tail = tail or f"a lost beam, a reflector in the wrong nest or a wrong point name or station label? {what}"
        return (f"{head}{k} of {self.n_rows} poses lie more than {self.ratio:g}x the typical error ({typ} per "
                f"coordinate) off {against}: data rows {shown} ({size}); {tail}")

    def to_dict(self) -> dict:
        """JSON-able (mm, deg): ``data_rows`` 1-based as the text names them, ``index_0based`` the same rows
        counted from 0 (``evaluation.json`` says its outliers the same way: a bare "rows" was read both ways)."""
        return {"data_rows": [int(r) + 1 for r in self.rows], "index_0based": [int(r) for r in self.rows],
                "pos_mm": self.pos_mm.tolist(),
                "rot_deg": None if self.rot_deg is None else self.rot_deg.tolist(),
                "typical_pos_mm": self.typical_pos_mm, "typical_rot_deg": self.typical_rot_deg,
                "ratio": self.ratio, "n_rows": self.n_rows, "dropped": self.dropped}


def row_errors(T_model: np.ndarray, xyz: np.ndarray, R_meas: np.ndarray | None,
               pts: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
    """Per-row errors of the model poses ``T_model`` ``(N, 4, 4)`` against the measured ``xyz``
    (``(N, 3)`` or ``(N, K, 3)`` m) and ``R_meas`` ``(N, 3, 3)`` or None: position ``(N,)`` m (largest
    over the reflectors) and rotation angle ``(N,)`` rad or None."""
    rp, ro = residual(T_model, xyz, R_meas, 1.0, pts)
    n = T_model.shape[0]
    pos = np.linalg.norm(rp.reshape(n, -1, 3), axis=2).max(axis=1)
    return pos, None if ro is None else np.linalg.norm(ro, axis=1)


def _flag(e: np.ndarray, ratio: float, floor: float) -> tuple[np.ndarray, float]:
    s = float(np.median(e)) / MAXWELL_MEDIAN
    return (e > ratio * s) & (e > floor), s


def find_outliers(pos_err_m: np.ndarray, rot_err_rad: np.ndarray | None = None, ratio: float = DEFAULT_RATIO) -> Outliers | None:
    """Rows whose position (or orientation) error is more than ``ratio`` typical errors ``s`` off (module
    docstring), or None when there are none or fewer than ``MIN_ROWS`` rows."""
    pos_err_m = np.asarray(pos_err_m, dtype=np.float64)
    n = pos_err_m.shape[0]
    if n < MIN_ROWS:
        return None
    bad, s_p = _flag(pos_err_m, ratio, FLOOR_M)
    s_r = None
    if rot_err_rad is not None:
        bad_r, s_r = _flag(np.asarray(rot_err_rad, dtype=np.float64), ratio, FLOOR_RAD)
        bad |= bad_r
    if not bad.any():
        return None
    rows = np.flatnonzero(bad)
    out = Outliers(rows=rows, pos_mm=pos_err_m[rows] * 1e3,
                   rot_deg=None if rot_err_rad is None else np.degrees(np.asarray(rot_err_rad)[rows]),
                   typical_pos_mm=s_p * 1e3, typical_rot_deg=None if s_r is None else math.degrees(s_r),
                   ratio=float(ratio), n_rows=n)
    if not out.droppable:
        out.step = step_change(pos_err_m)
    return out


def step_change(e: np.ndarray, min_rows: int = 10, min_ratio: float = STEP_RATIO) -> tuple[int, float] | None:
    """``(r, ratio)`` when the rows from ``r`` on fit ``ratio`` >= ``min_ratio`` times worse (geometric mean
    of the errors ``e`` ``(N,)``) than the rows before, at the split that best separates the two (both at
    least ``min_rows``): the signature of joints and measurements out of step by a row. Else None."""
    le = np.log(np.maximum(np.asarray(e, dtype=np.float64), 1e-12))
    n = le.shape[0]
    if n < 2 * min_rows:
        return None
    c = np.cumsum(le)
    r = np.arange(min_rows, n - min_rows + 1)
    before, after = c[r - 1] / r, (c[-1] - c[r - 1]) / (n - r)
    score = (after - before) * np.sqrt(r * (n - r) / n)  # a two-sample t-like statistic on log errors
    k = int(np.argmax(score))
    ratio = float(np.exp(after[k] - before[k]))
    return (int(r[k]), ratio) if ratio >= min_ratio else None


def subset_rows(data, keep: np.ndarray, n_rows: int):
    """``data`` of :func:`hykin.calibration.calibrate.calibrate` (a Dataset or a tuple of per-row
    arrays) restricted to the rows ``keep`` (0-based indices); any other value (a per-row array of
    ``n_rows``, else unchanged) likewise."""
    if data is None:
        return None
    if hasattr(data, "subset"):
        return data.subset(keep)
    if isinstance(data, tuple):
        return tuple(subset_rows(a, keep, n_rows) for a in data)
    a = np.asarray(data)
    return a[keep] if a.ndim >= 1 and a.shape[0] == n_rows else data


def rows_out_of_step(data, rms_mm: float, recalibrate, factor: float = STEP_RATIO) -> str:
    """A refused calibration's likely cause when the whole file is out of step: the joints of one row
    belong to the measurement of the next (a row missing or doubled at the top of one file). The
    calibration is repeated on the positions with the joints shifted by one row each way
    (``recalibrate(data, position_only) -> CalibrationResult``, checks off); when one leaves ``factor``
    times less than ``rms_mm`` (the refused fit's position RMS), ``"; ..."`` naming the shift and its
    residual, else ``""``. Only for a Dataset of at least ``2 * MIN_ROWS`` rows; its first ``SHIFT_ROWS``
    rows are tested (an error path: two more calibrations, kept small)."""
    import dataclasses

    from .result import CalibrationError

    n = min(len(getattr(data, "q", ())), SHIFT_ROWS)  # the first rows tell: two calibrations stay cheap
    if not (dataclasses.is_dataclass(data) and hasattr(data, "subset")) or n < 2 * MIN_ROWS:
        return ""
    for lead, words in ((1, "each row's measurement belongs to the next row's joints"),
                        (-1, "each row's measurement belongs to the previous row's joints")):
        meas = data.subset(np.arange(n - 1) if lead == 1 else np.arange(1, n))
        shifted = dataclasses.replace(meas, q=np.asarray(data.q)[1:n] if lead == 1 else np.asarray(data.q)[:n - 1])
        try:
            rms = float(recalibrate(shifted, True).after["pos_rms_mm"])
        except (CalibrationError, ValueError):
            continue
        if factor * rms < rms_mm:
            return (f"; joints and measurements look one row out of step ({words}: shifted so, the positions leave "
                    f"{rms:.3g} mm RMS instead of {rms_mm:.3g}): a row missing or doubled at the top of one file?")
    return ""
