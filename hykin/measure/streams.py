"""Dynamic data collection: align a robot joint log with a laser-tracker stream (DESIGN.md §1.4).

The robot logs joints at its own rate and clock (e.g. 110 Hz); the tracker logs positions (and
optionally orientations) at another rate and clock (e.g. 3 kHz). The clock model is

    t_tracker = t_robot + offset_s + drift · (t_robot − t_ref_s)

(``drift`` dimensionless, e.g. 2e-5 = 20 ppm; ``t_ref_s`` = middle of the robot log).

* :func:`estimate_clock` / :func:`estimate_time_offset` — offset by normalised cross-correlation of
  the TCP speed profiles (frame-independent: the tracker frame need not be known), sub-sample by a
  parabola through the correlation peak; drift from windowed correlations. Optionally
  (``method="positions"``) refined jointly with a rigid registration by Gauss-Newton on the
  positions themselves (best with an accurate, e.g. calibrated, robot model).
* :func:`resample_tracker` — tracker positions (linear) and orientations (slerp) at query times,
  with a validity mask where the beam was lost (NaN rows or a gap longer than ``max_gap_s``).
* :func:`align_streams` — everything together: robot samples paired with tracker poses, dropping
  samples where the TCP moves faster than ``max_speed_m_s`` or the tracker has no valid data.

Refused (:mod:`hykin.measure.stream_checks`): logs that sample slower than a stream (a static
campaign, one record per stop: :class:`NotAStreamError`) and a clock offset at the edge of its
search range (:class:`ClockRangeError`).

Times in seconds, positions in metres, quaternions scalar-first ``(qw, qx, qy, qz)``.
The robot's TCP (``robot.tool``) must be the tracked point (the SMR centre) for the offset fit.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline
from scipy.ndimage import gaussian_filter1d
from scipy.signal import correlate, correlation_lags
from scipy.spatial.transform import Rotation, Slerp

from ..geometry.rigid import rigid_residual_jacobian, umeyama
from ..geometry.se3 import make_transform
from .stream_checks import (
    MIN_JOIN_CORRELATION,
    ClockRangeError,
    NoOverlapError,
    NotAStreamError,
    StreamError,
    TimeUnitError,
    check_is_stream,
    check_offset_inside,
)

__all__ = [
    "AlignedStreams",
    "ClockModel",
    "ClockRangeError",
    "MIN_JOIN_CORRELATION",
    "NoOverlapError",
    "NotAStreamError",
    "Resampled",
    "StreamError",
    "TimeUnitError",
    "align_streams",
    "estimate_clock",
    "estimate_time_offset",
    "resample_tracker",
    "tcp_speed",
]


@dataclass(frozen=True)
class ClockModel:
    """``t_tracker = t_robot + offset_s + drift · (t_robot − t_ref_s)``.

    offset_std_s / drift_std: standard deviations (scatter of windowed estimates for
    ``method="speed"``, 0 when the log is too short for two windows; first-order least squares for
    ``method="positions"``). T_tracker_base: ``(4, 4)`` rigid map of the robot model's TCP positions
    (base frame) onto the tracker's at the estimated clock; rms_m: residual RMS of that fit. coarse_offset_s: the cross-correlation estimate; n_used: samples in the fit.
    """

    offset_s: float
    drift: float = 0.0
    t_ref_s: float = 0.0
    offset_std_s: float = 0.0
    drift_std: float = 0.0
    T_tracker_base: np.ndarray | None = None
    rms_m: float = float("nan")
    n_used: int = 0
    coarse_offset_s: float = float("nan")
    correlation: float = float("nan")

    def to_tracker_time(self, t_robot) -> np.ndarray:
        """Robot timestamps -> tracker clock."""
        t = np.asarray(t_robot, dtype=np.float64)
        return t + self.offset_s + self.drift * (t - self.t_ref_s)


# --------------------------------------------------------------------------- validation


def _times(t, name: str) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64)
    if t.ndim != 1 or t.size < 2:
        raise StreamError(f"{name}: expected a 1-D array of >= 2 timestamps (s), got shape {t.shape}")
    if not np.isfinite(t).all():
        raise StreamError(f"{name}: non-finite timestamp at row {int(np.flatnonzero(~np.isfinite(t))[0])}")
    dt = np.diff(t)
    if (dt <= 0).any():
        raise StreamError(f"{name}: timestamps must be strictly increasing (row {int(np.flatnonzero(dt <= 0)[0]) + 1})")
    return t


def _rows(x, n_rows: int, n_cols: int, name: str, allow_nan: bool = False) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] != n_rows or (n_cols and x.shape[1] != n_cols):
        want = f"({n_rows}, {n_cols})" if n_cols else f"({n_rows}, n)"
        raise StreamError(f"{name}: expected shape {want}, got {x.shape}")
    if not allow_nan and not np.isfinite(x).all():
        raise StreamError(f"{name}: non-finite values at row {int(np.flatnonzero(~np.isfinite(x).all(1))[0])}")
    return x


def _robot_positions(robot, q_robot, p_robot, n: int) -> tuple[np.ndarray, np.ndarray | None]:
    if p_robot is not None:
        return _rows(p_robot, n, 3, "p_robot"), (None if q_robot is None else np.asarray(q_robot, dtype=np.float64))
    if robot is None or q_robot is None:
        raise StreamError("give either robot and q_robot (TCP positions by FK) or p_robot (TCP positions, m)")
    from ..kinematics.fk import fk

    q = _rows(q_robot, n, robot.dof, "q_robot")
    return fk(robot, q)[:, :3, 3], q


def _clean_tracker(t_tracker, p_tracker, quat=None):
    """Drop rows with NaN (beam lost); validate shapes and times."""
    t = np.asarray(t_tracker, dtype=np.float64)
    if t.ndim != 1:
        raise StreamError(f"t_tracker: expected 1-D timestamps, got shape {t.shape}")
    p = _rows(p_tracker, t.size, 3, "p_tracker", allow_nan=True)
    ok = np.isfinite(t) & np.isfinite(p).all(1)
    if quat is not None:
        qa = _rows(quat, t.size, 4, "quat_tracker", allow_nan=True)
        ok &= np.isfinite(qa).all(1)
        qa = qa[ok]
        nrm = np.linalg.norm(qa, axis=1)
        if (nrm < 1e-9).any():
            raise StreamError("quat_tracker: zero-length quaternion")
        qa = qa / nrm[:, None]
    else:
        qa = None
    if ok.sum() < 2:
        raise StreamError("tracker stream has fewer than 2 valid (finite) samples")
    return _times(t[ok], "t_tracker (valid rows)"), p[ok], qa


def _coverage(t_valid: np.ndarray, tq: np.ndarray, max_gap_s: float) -> tuple[np.ndarray, np.ndarray]:
    """Bracketing index and validity of query times against valid tracker samples."""
    idx = np.searchsorted(t_valid, tq, side="right") - 1
    inside = (idx >= 0) & (tq <= t_valid[-1])
    idx = np.clip(idx, 0, t_valid.size - 2)
    gap = t_valid[idx + 1] - t_valid[idx]
    return idx, inside & (gap <= max_gap_s)


def _interp(t_valid, p, tq, idx):
    f = ((tq - t_valid[idx]) / (t_valid[idx + 1] - t_valid[idx]))[:, None]
    return p[idx] * (1 - f) + p[idx + 1] * f


def _default_gap(t_valid: np.ndarray) -> float:
    return 3.0 * float(np.median(np.diff(t_valid)))


# --------------------------------------------------------------------------- speed


def tcp_speed(t_s, p_m) -> np.ndarray:
    """TCP speed ``(M,)`` (m/s) from positions ``(M, 3)`` at times ``(M,)`` (second-order differences)."""
    t = _times(t_s, "t_s")
    p = _rows(p_m, t.size, 3, "p_m")
    return np.linalg.norm(np.gradient(p, t, axis=0), axis=1)


def _speed_on_grid(t0, n, dt, pos_fn, valid, smooth_s):
    """Smoothed speed on a uniform grid; positions from ``pos_fn(grid)``; invalid grid points -> 0/mask."""
    g = t0 + dt * np.arange(n)
    p = pos_fn(g)
    v = np.gradient(p, dt, axis=0)
    sig = max(smooth_s / dt, 0.5)
    v = gaussian_filter1d(v, sig, axis=0, mode="nearest")
    s = np.linalg.norm(v, axis=1)
    m = valid(g).astype(np.float64)
    # distrust grid points near invalid data (the smoothing spreads gaps)
    m = (gaussian_filter1d(m, sig, mode="nearest") > 0.999).astype(np.float64)
    return s, m


def _speed_profiles(t_r, p_r, t_t, p_t, max_gap, dt, smooth_s):
    """Smoothed TCP speed of both streams on uniform grids (same step and filter)."""
    n_r = int(np.floor((t_r[-1] - t_r[0]) / dt)) + 1
    n_t = int(np.floor((t_t[-1] - t_t[0]) / dt)) + 1
    spl = CubicSpline(t_r, p_r, axis=0)
    s_r, m_r = _speed_on_grid(t_r[0], n_r, dt, spl, lambda g: np.ones(g.shape, bool), smooth_s)

    def pos_t(g):
        idx, _ = _coverage(t_t, g, np.inf)
        return _interp(t_t, p_t, g, idx)

    s_t, m_t = _speed_on_grid(t_t[0], n_t, dt, pos_t, lambda g: _coverage(t_t, g, max_gap)[1], smooth_s)
    # one common level for both: at the true lag the two centred profiles then coincide on the
    # valid support, so the normalised correlation peaks there even with masked (lost) tracker data
    mu = s_r[m_r > 0].mean()
    return (s_r - mu) * m_r, m_r, (s_t - mu) * m_t, m_t


def _ncc_offset(a, m_t, t_t0, b, m_r, t_r0, dt, center, half, min_overlap):
    """Offset (tracker − robot time) maximising the normalised cross-correlation of speed profiles
    ``a`` (tracker grid from ``t_t0``) and ``b`` (robot grid from ``t_r0``), searched in
    ``center ± half``; parabolic sub-sample refinement. Returns (offset, peak NCC)."""
    if a.size == 0 or b.size == 0 or m_t.sum() <= min_overlap or m_r.sum() <= min_overlap:
        raise NoOverlapError("robot and tracker streams do not overlap in time within the offset search range",
                             center_s=center, half_s=half)
    num = correlate(a, b, mode="full", method="fft")
    Ea = correlate(a * a, m_r, mode="full", method="fft")
    Eb = correlate(m_t, b * b, mode="full", method="fft")
    overlap = correlate(m_t, m_r, mode="full", method="fft")
    lags = correlation_lags(a.size, b.size, mode="full")
    offs = t_t0 - t_r0 + lags * dt
    keep = (np.abs(offs - center) <= half) & (overlap > min_overlap)
    if not keep.any():
        raise NoOverlapError("robot and tracker streams do not overlap in time within the offset search range",
                             center_s=center, half_s=half)
    den = np.sqrt(np.clip(Ea * Eb, 1e-300, None))
    ncc = np.where(keep, num / den, -np.inf)
    k = int(np.argmax(ncc))
    off = offs[k]
    if 0 < k < ncc.size - 1 and np.isfinite(ncc[k - 1]) and np.isfinite(ncc[k + 1]):
        y0, y1, y2 = ncc[k - 1], ncc[k], ncc[k + 1]
        den2 = y0 - 2 * y1 + y2
        if den2 < 0:
            off += 0.5 * (y0 - y2) / den2 * dt
    return float(off), float(ncc[k])


def _rigid_at(clock_fn, t_r, p_r, t_t, p_t, gap):
    tq = clock_fn(t_r)
    idx, ok = _coverage(t_t, tq, gap)
    if ok.sum() < 3:
        return None, float("nan"), 0
    pt = _interp(t_t, p_t, tq[ok], idx[ok])
    R, tr, _ = umeyama(p_r[ok], pt)
    r = pt - (p_r[ok] @ R.T + tr)
    return make_transform(R, tr), float(np.sqrt(np.mean(np.sum(r * r, 1)))), int(ok.sum())


def estimate_clock(t_robot, q_robot, t_tracker, p_tracker, robot=None, *, p_robot=None, method: str = "speed",
                   fit_drift: bool = False, max_offset_s: float = 1.0, max_gap_s: float | None = None,
                   grid_dt_s: float = 1e-3, smooth_s: float = 0.02, window_s: float = 5.0,
                   max_iter: int = 30) -> ClockModel:
    """Estimate the tracker clock relative to the robot clock (see module docstring).

    ``t_robot`` ``(M,)``, ``q_robot`` ``(M, dof)`` with ``robot`` (TCP positions by FK), or
    ``p_robot`` ``(M, 3)`` TCP positions (m, base frame) directly. ``t_tracker`` ``(K,)``,
    ``p_tracker`` ``(K, 3)`` (m, tracker frame; NaN rows = beam lost). ``max_offset_s`` bounds the
    search; ``max_gap_s`` (default 3 tracker periods) marks lost tracking.

    Always first: normalised cross-correlation of the TCP speed profiles on a ``grid_dt_s`` grid
    (both smoothed by the same Gaussian, ``smooth_s``), parabolic sub-sample peak
    (``coarse_offset_s``). Then:

    * ``method="speed"`` (default): the same correlation in windows of ``window_s`` seconds of the
      robot log (searched ±0.1 s around the global peak); with ``fit_drift`` a straight line through
      the window offsets gives offset and drift, and the scatter of the windows gives the standard
      deviations. Frame-free and robust to errors of the robot model (they scale speeds, they do not
      shift them in time).
    * ``method="positions"``: Gauss-Newton on ``p_tracker(t_robot + offset + drift τ) = R p_robot + t``
      alternating with the optimal rigid map (Kabsch). Most precise when the robot model is accurate
      (e.g. calibrated): then ~µs; with a nominal model the model errors leak into the offset
      (measured: 3.6 mm mean model error -> ~0.4 ms bias on a 20 s log, vs ~0.08 ms for "speed").

    The rigid map at the final clock (``T_tracker_base``) and its residual RMS are reported in both
    cases. The motion must change speed (a constant-speed move has no timing information).

    Raises :class:`NotAStreamError` when either log samples slower than
    ``max(stream_checks.MAX_STREAM_PERIOD_S, max_gap_s)`` (median: static data), and :class:`ClockRangeError` when
    the offset found lies within two grid steps of ``±max_offset_s`` (the range's limit, no result).
    """
    if method not in ("speed", "positions"):
        raise StreamError(f"method must be 'speed' or 'positions', got {method!r}")
    t_r = _times(t_robot, "t_robot")
    p_r, _ = _robot_positions(robot, q_robot, p_robot, t_r.size)
    t_t, p_t, _ = _clean_tracker(t_tracker, p_tracker)
    check_is_stream(t_r, t_t, max_gap_s)
    gap = _default_gap(t_t) if max_gap_s is None else float(max_gap_s)
    dt = float(grid_dt_s)
    b, m_r, a, m_t = _speed_profiles(t_r, p_r, t_t, p_t, gap, dt, smooth_s)
    try:
        coarse, corr = _ncc_offset(a, m_t, t_t[0], b, m_r, t_r[0], dt, 0.0, max_offset_s,
                                   0.1 * min(m_t.sum(), m_r.sum()))
    except NoOverlapError:
        raise NoOverlapError(
            f"robot and tracker streams do not overlap in time within the offset search range 0 ± {max_offset_s:g} s: "
            f"robot log times {t_r[0]:.6g} to {t_r[-1]:.6g} s, tracker {t_t[0]:.6g} to {t_t[-1]:.6g} s (offset about "
            f"{0.5 * (t_t[0] + t_t[-1] - t_r[0] - t_r[-1]):.6g} s?)", robot_range_s=(float(t_r[0]), float(t_r[-1])),
            tracker_range_s=(float(t_t[0]), float(t_t[-1])), center_s=0.0, half_s=float(max_offset_s)) from None
    check_offset_inside(coarse, 0.0, max_offset_s, dt)
    t_ref = 0.5 * (t_r[0] + t_r[-1])
    if method == "speed":
        K = int((t_r[-1] - t_r[0]) // window_s)
        off, drift, off_std, drift_std = coarse, 0.0, 0.0, 0.0
        if fit_drift and K < 2:
            raise StreamError(f"fit_drift needs a log of at least 2 windows of {window_s} s; the robot log lasts "
                              f"{t_r[-1] - t_r[0]:.3g} s")
        if K >= 2:
            edges = np.linspace(0, b.size, K + 1).astype(int)
            tc, ok_ = np.zeros(K), np.full(K, np.nan)
            for k in range(K):
                i0, i1 = edges[k], edges[k + 1]
                tc[k] = t_r[0] + dt * 0.5 * (i0 + i1 - 1)
                # only the tracker profile this window can reach (its span, shifted by coarse ± 0.1 s): each
                # window costs its own length, not the whole stream's
                ja = max(int(np.floor((t_r[0] + i0 * dt + coarse - 0.2 - t_t[0]) / dt)), 0)
                jb = min(int(np.ceil((t_r[0] + i1 * dt + coarse + 0.2 - t_t[0]) / dt)), a.size)
                try:  # a window mostly without beam (fast moves, dropouts) has no timing of its own: skip it
                    o_k, _ = _ncc_offset(a[ja:jb], m_t[ja:jb], t_t[0] + ja * dt, b[i0:i1], m_r[i0:i1],
                                         t_r[0] + i0 * dt, dt, coarse, 0.1, 0.25 * m_r[i0:i1].sum())
                    check_offset_inside(o_k, coarse, 0.1, dt)  # a window's range limit is no timing either
                    ok_[k] = o_k
                except StreamError:
                    pass
            good = np.isfinite(ok_)
            if fit_drift and good.sum() < 2:
                raise StreamError(f"fit_drift: only {int(good.sum())} of {K} windows of {window_s} s have enough tracker "
                                  "data to time them; record longer or with fewer beam losses")
            tc, ok_, K = tc[good], ok_[good], int(good.sum())
            if fit_drift:
                X = np.stack([np.ones(K), tc - t_ref], 1)
                sol, *_ = np.linalg.lstsq(X, ok_, rcond=None)
                off, drift = float(sol[0]), float(sol[1])
                if K > 2:
                    res = ok_ - X @ sol
                    cov = (res @ res / (K - 2)) * np.linalg.inv(X.T @ X)
                    off_std, drift_std = float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1]))
            elif K >= 2:
                off_std = float(np.std(ok_, ddof=1) / np.sqrt(K))
        clk = ClockModel(off, drift, t_ref)
        T, rms, n_used = _rigid_at(clk.to_tracker_time, t_r, p_r, t_t, p_t, gap)
        return ClockModel(off, drift, float(t_ref), off_std, drift_std, T, rms, n_used, coarse, corr)
    off, drift = coarse, 0.0
    h = max(2.0 * float(np.median(np.diff(t_t))), 1e-4)
    tau = t_r - t_ref
    for _ in range(max_iter):
        tq = t_r + off + drift * tau
        idx, ok = _coverage(t_t, tq, gap)
        _, okm = _coverage(t_t, tq - h, gap)
        _, okp = _coverage(t_t, tq + h, gap)
        ok &= okm & okp
        if ok.sum() < 10:
            raise StreamError(f"too few robot samples ({int(ok.sum())}) overlap valid tracker data at offset {off:.4f} s")
        tq_ok = tq[ok]
        pt = _interp(t_t, p_t, tq_ok, idx[ok])
        vt = (_interp(t_t, p_t, tq_ok + h, _coverage(t_t, tq_ok + h, np.inf)[0])
              - _interp(t_t, p_t, tq_ok - h, _coverage(t_t, tq_ok - h, np.inf)[0])) / (2 * h)
        R, tr, _ = umeyama(p_r[ok], pt)
        r = pt - (p_r[ok] @ R.T + tr)
        cols = [vt.ravel()] + ([(vt * tau[ok, None]).ravel()] if fit_drift else [])
        A = np.stack(cols, axis=1)
        step, *_ = np.linalg.lstsq(A, -r.ravel(), rcond=None)
        off += step[0]
        if fit_drift:
            drift += step[1]
        if abs(step[0]) < 1e-10 and (not fit_drift or abs(step[1]) < 1e-12):
            break
    # covariance of (offset[, drift]) jointly with the rigid map (rotation, translation)
    y = p_r[ok] @ R.T
    n = y.shape[0]
    k = 6 + len(cols)
    J = rigid_residual_jacobian(y, k)
    J[:, :, 6] = vt
    if fit_drift:
        J[:, :, 7] = vt * tau[ok, None]
    J = J.reshape(3 * n, k)
    rr = r.ravel()
    s2 = rr @ rr / max(rr.size - k, 1)
    try:
        cov = s2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        raise StreamError("the motion carries no timing information (singular offset fit); use a trajectory with "
                          "speed changes") from None
    return ClockModel(
        offset_s=float(off), drift=float(drift), t_ref_s=float(t_ref), offset_std_s=float(np.sqrt(cov[6, 6])),
        drift_std=float(np.sqrt(cov[7, 7])) if fit_drift else 0.0, T_tracker_base=make_transform(R, tr),
        rms_m=float(np.sqrt(np.mean(np.sum(r * r, 1)))), n_used=int(n), coarse_offset_s=coarse, correlation=corr,
    )


def estimate_time_offset(t_robot, q_robot, t_tracker, p_tracker, robot=None, **kw) -> float:
    """Offset (s) with ``t_tracker = t_robot + offset`` at the middle of the log; see :func:`estimate_clock`."""
    return estimate_clock(t_robot, q_robot, t_tracker, p_tracker, robot, **kw).offset_s


# --------------------------------------------------------------------------- resampling


@dataclass(frozen=True)
class Resampled:
    """Tracker data at query times: ``p`` ``(M, 3)``, ``quat_wxyz`` ``(M, 4)`` or None, ``valid`` ``(M,)``.

    Rows that are not valid (outside the stream or inside a tracking gap) are NaN.
    """

    p: np.ndarray
    quat_wxyz: np.ndarray | None
    valid: np.ndarray


def resample_tracker(t_query, t_tracker, p, quat=None, max_gap_s: float | None = None) -> Resampled:
    """Tracker positions (linear interpolation) and orientations (slerp) at ``t_query`` (tracker clock).

    ``p`` ``(K, 3)``; ``quat`` ``(K, 4)`` scalar-first or None; rows with NaN count as lost beam.
    A query is valid when it lies between two valid samples at most ``max_gap_s`` apart (default
    3 median tracker periods). Quaternions are returned with ``qw >= 0``.
    """
    tq = np.asarray(t_query, dtype=np.float64)
    if tq.ndim != 1 or not np.isfinite(tq).all():
        raise StreamError(f"t_query: expected finite 1-D timestamps, got shape {tq.shape}")
    t_t, p_t, q_t = _clean_tracker(t_tracker, p, quat)
    gap = _default_gap(t_t) if max_gap_s is None else float(max_gap_s)
    idx, ok = _coverage(t_t, tq, gap)
    out = np.full((tq.size, 3), np.nan)
    out[ok] = _interp(t_t, p_t, tq[ok], idx[ok])
    qo = None
    if q_t is not None:
        qo = np.full((tq.size, 4), np.nan)
        if ok.any():
            rot = Slerp(t_t, Rotation.from_quat(q_t, scalar_first=True))(tq[ok])
            qo[ok] = rot.as_quat(canonical=True, scalar_first=True)
    return Resampled(out, qo, ok)


# --------------------------------------------------------------------------- alignment


@dataclass
class AlignedStreams:
    """Robot samples paired with tracker data.

    q ``(L, dof)``, xyz_m ``(L, 3)``, quat_wxyz ``(L, 4)`` or None, t_robot_s ``(L,)``: the kept
    samples; mask ``(M,)``: which of the M robot samples were kept; info: clock, counts, frame;
    dataset: a :class:`hykin.io.dataset.Dataset` when that module is available, else None.
    """

    q: np.ndarray
    xyz_m: np.ndarray
    quat_wxyz: np.ndarray | None
    t_robot_s: np.ndarray
    mask: np.ndarray
    info: dict = field(default_factory=dict)
    dataset: object | None = None


def align_streams(t_robot, q_robot, t_tracker, p_tracker, quat_tracker=None, robot=None, *, clock=None,
                  p_robot=None, max_speed_m_s: float | None = 0.1, max_gap_s: float | None = None,
                  T_base_tracker=None, fit_drift: bool = False, **clock_kw) -> AlignedStreams:
    """Pair each robot sample with the tracker pose at the same instant; drop unusable samples.

    ``clock``: a :class:`ClockModel`, a float offset (s), or None to estimate it
    (:func:`estimate_clock`, extra keywords passed on). Samples are dropped where the TCP speed
    (from FK of the joints, or ``p_robot``) exceeds ``max_speed_m_s`` (None = keep all): a residual
    timing error ``δt`` costs ``speed · δt`` of position error, and the robot's reported joints lag
    its true motion more at speed. Samples are also dropped where the tracker has no valid data
    within ``max_gap_s``.

    ``T_base_tracker``: None keeps tracker coordinates; a ``(4, 4)`` transform (tracker -> robot
    base coordinates) is applied to positions and orientations; ``"fit"`` uses the inverse of the
    rigid map found with the clock estimate (a registration of the robot model as it is, good for a
    first look; calibration re-fits the base anyway).
    """
    t_r = _times(t_robot, "t_robot")
    p_r, q = _robot_positions(robot, q_robot, p_robot, t_r.size)
    if q is None:
        raise StreamError("align_streams needs q_robot (the joints are the dataset's inputs)")
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[0] != t_r.size:
        raise StreamError(f"q_robot: expected shape ({t_r.size}, dof), got {q.shape}")
    check_is_stream(t_r, _clean_tracker(t_tracker, p_tracker)[0], max_gap_s)
    if clock is None:
        clock = estimate_clock(t_r, q, t_tracker, p_tracker, robot, p_robot=p_robot, fit_drift=fit_drift,
                               max_gap_s=max_gap_s, **clock_kw)
    elif not isinstance(clock, ClockModel):
        clock = ClockModel(offset_s=float(clock))
    tq = clock.to_tracker_time(t_r)
    res = resample_tracker(tq, t_tracker, p_tracker, quat_tracker, max_gap_s)
    speed = tcp_speed(t_r, p_r)
    fast = np.zeros(t_r.size, bool) if max_speed_m_s is None else speed > max_speed_m_s
    mask = res.valid & ~fast
    xyz, quat = res.p[mask], None if res.quat_wxyz is None else res.quat_wxyz[mask]
    frame = "tracker"
    if isinstance(T_base_tracker, str):
        if T_base_tracker != "fit":
            raise StreamError(f"T_base_tracker must be None, a (4, 4) array or 'fit', got {T_base_tracker!r}")
        if clock.T_tracker_base is None:
            raise StreamError("T_base_tracker='fit' needs a clock from estimate_clock (it carries the rigid map)")
        from ..geometry.se3 import invert

        T_base_tracker, frame = invert(clock.T_tracker_base), "base (fit)"
    elif T_base_tracker is not None:
        frame = "base"
    if T_base_tracker is not None:
        T = np.asarray(T_base_tracker, dtype=np.float64)
        if T.shape != (4, 4):
            raise StreamError(f"T_base_tracker: expected (4, 4), got {T.shape}")
        xyz = xyz @ T[:3, :3].T + T[:3, 3]
        if quat is not None:
            Rm = T[:3, :3] @ Rotation.from_quat(quat, scalar_first=True).as_matrix()
            quat = Rotation.from_matrix(Rm).as_quat(canonical=True, scalar_first=True)
    info = dict(offset_s=clock.offset_s, drift=clock.drift, t_ref_s=clock.t_ref_s, offset_std_s=clock.offset_std_s,
                n_robot=int(t_r.size), n_kept=int(mask.sum()), n_dropped_gap=int((~res.valid).sum()),
                n_dropped_speed=int((fast & res.valid).sum()), max_speed_m_s=max_speed_m_s, frame=frame,
                clock=clock)
    out = AlignedStreams(q=q[mask], xyz_m=xyz, quat_wxyz=quat, t_robot_s=t_r[mask], mask=mask, info=info)
    try:
        from ..io.dataset import Dataset
    except ImportError:
        return out
    out.dataset = Dataset(q=out.q, xyz_m=out.xyz_m, quat_wxyz=out.quat_wxyz,
                          extra={"t_robot_s": out.t_robot_s, "tcp_speed_m_s": speed[mask]},
                          source=f"align_streams (offset {clock.offset_s:.6f} s, frame {frame})",
                          meta={"frame": frame, "time_offset_s": clock.offset_s, "clock_drift": clock.drift,
                                "max_speed_m_s": max_speed_m_s})
    return out
