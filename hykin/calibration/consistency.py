"""Orientation columns that contradict the positions: refused with the evidence of the data themselves.

A quaternion-order slip (``x,y,z,w`` written under a ``qw,qx,qy,qz`` header) or inverted rotations give
orientations that no robot file reconciles with the positions. :func:`hykin.io.plausibility.check_orientation_order`
catches most of them before the fit; on some robots (a planar arm: every axis parallel) the misread
rotations cannot be told from the relative rotations alone, and the 6-D calibration bends the geometry
to absorb them, settling at millimetres of position residual -- below the fixed ``residual_mm`` bound,
far above the tracker's noise.

The bound used here is the data's own: the same calibration run on the positions alone leaves the
residual the positions allow (measurement noise plus what the model cannot represent). Consistent
orientations add equations, not contradictions: they move the parameters by about their uncertainty,
which changes the position RMS by a few per cent (either way: the excited parameter sets differ). Measured
on the generated battery's correct 6-D campaigns (``benchmarks/bench_orientation_conflict.py``, seeds
1000-1019 of 12 families: 240 draws, none refused) the largest ratio was 1.074 (few-poses); on the
slip-xyzw planar arm it is 64. When the 6-D fit's position RMS exceeds
``orientation_conflict`` (3, ``--max-deviation orientation_conflict=R``; ``inf`` turns the check off, as
the subset calibrations of :mod:`hykin.hybrid.uncertainty` do on data the full calibration checked) times
the positions-alone RMS,
the orientations contradict the positions and the fit is refused with one line naming the file and its
``qw,qx,qy,qz`` columns. Both RMS values are compared per degree of freedom, ``RMS · sqrt(m / (m - p))``
(``m`` equations, ``p`` estimated parameters): on few poses the positions-alone fit has about as many
parameters as equations and fits the noise away (8 full poses of a 6-axis arm: 24 position equations,
~25 parameters, 0.007 mm RMS under 0.02 mm noise, where the 6-D fit leaves the noise, 0.02 mm: a
correct data set refused at 3x). With fewer than :data:`MIN_DOF` residual degrees of freedom in either
fit the positions alone say nothing of the noise and the check is skipped. The likely cause is then tested, not guessed: the calibration is repeated with
the quaternions read scalar-last, and inverted; the reading that brings the position residual back
within the bound is named.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable

import numpy as np

from .result import CalibrationError

__all__ = ["OrientationConflictError", "check_orientation_consistency"]

_CONJ = np.array([1.0, -1.0, -1.0, -1.0])


class OrientationConflictError(CalibrationError):
    """The orientation columns contradict the positions (:func:`check_orientation_consistency`)."""


def _where(data) -> str:
    src = str(getattr(data, "source", "") or "")
    return src if src and not src.startswith("hykin") else "<data>"


#: fewest residual degrees of freedom (equations - estimated parameters) for the RMS to bound the noise: with
#: 10, a fit's RMS is below 0.39x the noise with probability 1e-3 (chi-square), so a 3x bound is never
#: crossed by a correct data set by chance; with fewer the positions alone tell nothing: no check
MIN_DOF = 10


def _per_dof_rms(res) -> float | None:
    """The position RMS (mm) of ``res`` x ``sqrt(m / (m - p))`` (m equations: 3 per measured point and pose,
    3 more per pose with orientations; p: the estimated parameters, a compliance at its bound 0 not
    counted): what the residual of the true parameters would leave; None when ``m - p`` < :data:`MIN_DOF`;
    the raw RMS for a result without those counts."""
    rms = float(res.after["pos_rms_mm"])
    mask, n = getattr(res, "identifiable", None), getattr(res, "n_samples", 0)
    if mask is None or not n:
        return rms
    pts = getattr(res, "point_offsets_m", None)
    m = n * (3 * (1 if pts is None else max(len(pts), 1)) + (0 if getattr(res, "position_only", True) else 3))
    p = sum(bool(e) and st != "at bound 0" for e, st in zip(mask, getattr(res, "status", None) or [""] * len(mask)))
    return rms * math.sqrt(m / (m - p)) if m - p >= MIN_DOF else None


def _dof_text(raw: float, per: float) -> str:
    return "" if abs(per - raw) <= 1e-3 * raw else f" ({per:.3g} mm per degree of freedom)"


def check_orientation_consistency(res, data, recalibrate: Callable, ratio: float, refused=None) -> None:
    """Raise :class:`OrientationConflictError` (a CalibrationError) when ``res`` (a calibration that used
    orientations) leaves a position RMS above ``ratio`` x that of the same calibration on the positions
    alone (module docstring; both per degree of freedom, no check where either fit has fewer than
    :data:`MIN_DOF`). ``recalibrate(data, position_only) -> CalibrationResult`` repeats the
    calibration with the checks off. Sets ``res.position_only_rms_mm`` (the bound's base, mm).
    ``refused``: the CalibrationError another check raised on ``res`` (a tool metres away, a bent
    twist): it is replaced by this check's line only when a re-read of the quaternions brings the
    position residual within the bound (the evidence names the cause), else raised as it was."""
    if getattr(res, "position_only", True) or not math.isfinite(ratio):  # inf: the check is off
        if refused is not None:
            raise refused
        return
    rms = float(res.after["pos_rms_mm"])
    po = recalibrate(data, True)
    rms_po = float(po.after["pos_rms_mm"])
    res.position_only_rms_mm = rms_po
    # per degree of freedom: on few poses the positions-alone fit has about as many parameters as equations
    # and fits the noise away (8 poses: 24 equations, ~25 parameters, 0.2x the noise), where the 6-D fit
    # cannot; its raw RMS says nothing of the noise then
    per_dof, per_dof_po = _per_dof_rms(res), _per_dof_rms(po)
    if per_dof is None or per_dof_po is None or per_dof <= ratio * per_dof_po:
        if refused is not None:
            raise refused
        return
    where = _where(data)
    cause = ("check the quaternion convention (unit, scalar first, base->tool rotation) and the orientation "
             "columns' order, or drop them")
    quat = getattr(data, "quat_wxyz", None)
    if dataclasses.is_dataclass(data) and quat is not None and np.ndim(quat) == 2:
        for reading, text in ((quat[:, [3, 0, 1, 2]],
                               "quaternions look scalar-last (x,y,z,w) under the qw,qx,qy,qz header: reorder the "
                               "columns (hykin import table --quaternion-order xyzw)"),
                              (quat * _CONJ, "quaternions look inverted (tool->base rotation, or conjugated): give "
                                             "the base->tool rotation as qw,qx,qy,qz")):
            try:
                alt = recalibrate(dataclasses.replace(data, quat_wxyz=reading), False)
            except CalibrationError:
                continue
            alt_dof = _per_dof_rms(alt)
            if alt_dof is not None and alt_dof <= ratio * per_dof_po:
                cause = f"{text} (read so, they leave {alt.after['pos_rms_mm']:.3g} mm)"
                break
        else:
            if refused is not None:
                raise refused
    elif refused is not None:
        raise refused
    raise OrientationConflictError(
        f"{where}: columns qw,qx,qy,qz contradict the positions: calibrating {res.robot.name!r} with them leaves "
        f"{rms:.3g} mm RMS{_dof_text(rms, per_dof)}, with the positions alone {rms_po:.3g} mm{_dof_text(rms_po, per_dof_po)} "
        f"(bound {ratio:g}x, --max-deviation "
        f"orientation_conflict=R): {cause}")
