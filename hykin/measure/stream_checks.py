"""Checks that a robot log and a tracker file are a stream, and that a clock fit found a result.

Used by :mod:`hykin.measure.streams` before and after the clock fit (``hykin import stream``):

* :func:`check_is_stream` — a stream samples the motion: both logs have a sample every
  :data:`MAX_STREAM_PERIOD_S` or less (median). Slower logs are static measurements (the robot stops,
  one record per stop): interpolating them across the moves between stops writes positions that
  belong to no pose, and their speed profiles carry no timing. Refused with :class:`NotAStreamError`.
* :func:`check_offset_inside` — a clock offset at the edge of its search range is the range's limit,
  not a result (the true offset lies beyond it, or the logs do not match at all): refused with
  :class:`ClockRangeError`.
* :data:`MIN_JOIN_CORRELATION` — the correlation of the two speed profiles below which their
  best offset is no join (see the constant).
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_STREAM_PERIOD_S", "MIN_JOIN_CORRELATION", "ClockRangeError", "NoOverlapError", "NotAStreamError",
           "StreamError", "TimeUnitError", "check_is_stream", "check_offset_inside", "check_time_units",
           "time_unit_slip"]

#: Slowest median sample period (s) of a stream. Streams are logged at 10 Hz-3 kHz (robot controllers:
#: KUKA RSI / ABB EGM 250 Hz, UR RTDE 125-500 Hz; trackers 100 Hz-3 kHz); a static campaign's stops are
#: seconds apart (a move, settling and the tracker's averaging take >= 1 s). 0.5 s sits between with a
#: margin of 5x to the slowest stream and 2x to the fastest stop; ``max_gap_s`` (``--max-gap``) raises it.
MAX_STREAM_PERIOD_S = 0.5

#: Smallest normalised correlation of the speed profiles at the fitted offset that is a join. Measured on a
#: simulated RX160 stream (125 Hz robot, 1 kHz tracker): the right robot file 0.99999, without its 270 mm tool
#: 0.987, the files of other robots (UR10, UR5, KR6, IRB2400) 0.82-0.86, joint columns swapped 0.73,
#: degrees read as radians 0.25, a clock offset 3 s outside the search range 0.13.
MIN_JOIN_CORRELATION = 0.5


class StreamError(ValueError):
    """Malformed stream input (shapes, non-increasing timestamps, too little valid data)."""


class NotAStreamError(StreamError):
    """The logs sample too slowly to be a stream: ``which`` ("robot log" / "tracker"), the median
    periods ``period_robot_s`` / ``period_tracker_s``, sample counts ``n_robot`` / ``n_tracker`` and the
    ``bound_s`` they were held to."""

    def __init__(self, msg: str, **info):
        super().__init__(msg)
        self.__dict__.update(info)


class ClockRangeError(StreamError):
    """The clock offset found (``offset_s``) lies at the edge of its search range (``center_s ± half_s``)."""

    def __init__(self, msg: str, offset_s: float, center_s: float, half_s: float):
        super().__init__(msg)
        self.offset_s, self.center_s, self.half_s = offset_s, center_s, half_s


class TimeUnitError(StreamError):
    """One log's time looks read in the wrong unit: ``which`` ("robot log" / "tracker") spans ``factor``
    (1e3, 1e6, 1e9) times longer and samples that much slower than the other; ``unit`` ("ms", "us", "ns")
    is its likely time unit; ``period_robot_s`` / ``period_tracker_s`` the median periods."""

    def __init__(self, msg: str, **info):
        super().__init__(msg)
        self.__dict__.update(info)


class NoOverlapError(StreamError):
    """The two logs' times do not overlap within the offset search range: ``robot_range_s`` and
    ``tracker_range_s`` (first, last time) and the search range ``center_s ± half_s``."""

    def __init__(self, msg: str, **info):
        super().__init__(msg)
        self.__dict__.update(info)


#: A log that both lasts and samples at least this many times longer than the other is read in the wrong
#: time unit (ms, us or ns taken as s): the two logs of one motion last about as long, and real rates differ
#: by at most ~300x (a 10 Hz robot log against a 3 kHz tracker) -- in the period, not in the duration.
_UNIT_SLIP_MIN_RATIO = 200.0
_UNIT_FACTORS = (("ms", 1e3), ("us", 1e6), ("ns", 1e9))


def time_unit_slip(t_robot: np.ndarray, t_tracker: np.ndarray) -> tuple[str, str, float] | None:
    """``(which, unit, factor)`` when one log (``which``: "robot log" / "tracker") both spans and samples
    :data:`_UNIT_SLIP_MIN_RATIO` or more times longer than the other -- its time is then likely in
    ``unit`` (factor 1e3 / 1e6 / 1e9 to s, the nearest to the ratio of the spans) -- else None."""
    if t_robot.size < 2 or t_tracker.size < 2:
        return None
    pr, pt = float(np.median(np.diff(t_robot))), float(np.median(np.diff(t_tracker)))
    sr, st = float(t_robot[-1] - t_robot[0]), float(t_tracker[-1] - t_tracker[0])
    if min(pr, pt, sr, st) <= 0:
        return None
    for which, p_ratio, s_ratio in (("robot log", pr / pt, sr / st), ("tracker", pt / pr, st / sr)):
        if p_ratio >= _UNIT_SLIP_MIN_RATIO and s_ratio >= _UNIT_SLIP_MIN_RATIO:
            unit, factor = min(_UNIT_FACTORS, key=lambda uf: abs(np.log10(s_ratio) - np.log10(uf[1])))
            return which, unit, factor
    return None


def check_time_units(t_robot: np.ndarray, t_tracker: np.ndarray) -> None:
    """Refuse (:class:`TimeUnitError`) logs one of which lasts and samples ~1000x (10^6x, 10^9x) longer than
    the other: its time is in ms (us, ns) read as s (see :func:`time_unit_slip`)."""
    slip = time_unit_slip(t_robot, t_tracker)
    if slip is None:
        return
    which, unit, factor = slip
    pr, pt = float(np.median(np.diff(t_robot))), float(np.median(np.diff(t_tracker)))
    sr, st = float(t_robot[-1] - t_robot[0]), float(t_tracker[-1] - t_tracker[0])
    slow, fast = ((pr, pt), (sr, st)) if which == "robot log" else ((pt, pr), (st, sr))
    other = "tracker" if which == "robot log" else "robot log"
    raise TimeUnitError(
        f"the {which} samples every {slow[0]:.3g} s, the {other} every {slow[1]:.3g} s, and lasts {fast[0]:.4g} s "
        f"against {fast[1]:.4g} s: the {which}'s time is likely in {unit} (time_unit = \"{unit}\")",
        which=which, unit=unit, factor=factor, period_robot_s=pr, period_tracker_s=pt, span_robot_s=sr,
        span_tracker_s=st)


def check_is_stream(t_robot: np.ndarray, t_tracker: np.ndarray, max_gap_s: float | None = None) -> None:
    """Refuse (:class:`NotAStreamError`) logs whose median sample period exceeds
    ``max(MAX_STREAM_PERIOD_S, max_gap_s)``; ``t_tracker`` are the valid (beam-on) tracker times."""
    check_time_units(t_robot, t_tracker)
    bound = MAX_STREAM_PERIOD_S if max_gap_s is None else max(MAX_STREAM_PERIOD_S, float(max_gap_s))
    pr, pt = float(np.median(np.diff(t_robot))), float(np.median(np.diff(t_tracker)))
    if max(pr, pt) <= bound:
        return
    which = "robot log" if pr > bound else "tracker"
    # a log sampling ~1000x slower than the other, and lasting much longer, may be a stream whose time is in ms
    # read as s (logs of one motion last about as long: a static campaign's do too)
    ratio = (pr / pt if which == "robot log" else pt / pr) if min(pr, pt) > 0 else 0.0
    sr, st = float(t_robot[-1] - t_robot[0]), float(t_tracker[-1] - t_tracker[0])
    span_ratio = (sr / st if which == "robot log" else st / sr) if min(sr, st) > 0 else 0.0
    unit = None
    if ratio >= _UNIT_SLIP_MIN_RATIO and span_ratio >= 10.0:
        unit = min(_UNIT_FACTORS, key=lambda uf: abs(np.log10(ratio) - np.log10(uf[1])))[0]
    one_each = 0.5 <= t_tracker.size / t_robot.size <= 2.0 and min(pr, pt) > bound
    what = ("one tracker point per robot sample: a static campaign (the robot stops, one measurement per stop)"
            if one_each else "static measurements (one record per stop), not a stream")
    raise NotAStreamError(
        f"not a stream: the {which} has a sample every {pr if which == 'robot log' else pt:.3g} s (median; "
        f"robot log {pr:.3g} s for {t_robot.size} samples, tracker {pt:.3g} s for {t_tracker.size} points), "
        f"{what}; a stream samples the motion every {bound:g} s or less"
        + (f" (or the {which}'s time is in {unit} read as s: time_unit = \"{unit}\")" if unit else ""),
        which=which, time_unit_hint=unit, period_robot_s=pr, period_tracker_s=pt, n_robot=int(t_robot.size), n_tracker=int(t_tracker.size),
        bound_s=bound, static=one_each)


def check_offset_inside(offset_s: float, center_s: float, half_s: float, step_s: float) -> None:
    """Refuse (:class:`ClockRangeError`) an offset within two grid steps of the edge of ``center ± half``."""
    if abs(offset_s - center_s) >= half_s - 2.0 * step_s:
        raise ClockRangeError(
            f"the clock offset found, {offset_s * 1e3:.4g} ms, lies at the edge of its search range "
            f"{center_s * 1e3:.4g} ± {half_s * 1e3:.4g} ms: that is the range's limit, not a result (the true offset "
            "lies beyond it, or the two logs do not belong together); widen the search (max_offset_s)",
            offset_s, center_s, half_s)
