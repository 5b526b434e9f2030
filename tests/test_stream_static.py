"""``import stream`` on data that are no stream, or that no clock joins: static campaigns (one record per
stop), a clock offset beyond the search range, and logs that do not belong together are refused in one
line, nothing written; the truth of each simulated case is the reference."""

from __future__ import annotations

import numpy as np
import pytest

from cli_run import run
from hykin.geometry import se3
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.measure.stream_checks import MAX_STREAM_PERIOD_S, check_is_stream
from hykin.measure.streams import ClockRangeError, NotAStreamError, align_streams, estimate_clock
from shared_fixtures import sine_trajectory

B = se3.xyzrpy_to_transform([2.0, -1.0, 0.3], [0.1, -0.2, 1.0])  # robot base in the tracker frame
ROBOT = load_robot("rx160")


def _traj(seed):
    return sine_trajectory(seed)


def _stream(offset, T=12.0, seed=1, tracker_seed=None):
    """110 Hz robot log, 1 kHz tracker with ``t_tracker = t_true + offset`` (of trajectory ``tracker_seed``)."""
    t_r = np.arange(0, T, 1 / 110)
    t_t = np.arange(offset - 0.5, T + offset + 0.5, 1e-3)
    p = (B @ fk(ROBOT, _traj(seed if tracker_seed is None else tracker_seed)(t_t - offset)))[:, :3, 3]
    return t_r, _traj(seed)(t_r), t_t, p


def _write(path, t, cols, names):
    np.savetxt(path, np.column_stack([t, cols]), delimiter=",", header=",".join(["t", *names]), comments="", fmt="%.9g")


def _write_pair(tmp_path, t_r, q, t_t, p):
    r, k = tmp_path / "robot_log.csv", tmp_path / "tracker.csv"
    _write(r, t_r, q, [f"q{j + 1}" for j in range(6)])
    _write(k, t_t, p, ["x", "y", "z"])
    return r, k


def _static(n_stops, robot_rate_hz=None, seed=80):
    """A static campaign: stops 7 s apart, the tracker's point of each stop 1.2 ± 0.3 s after the robot's
    stamp; the robot log has one record per stop, or ``robot_rate_hz`` samples standing at the stops."""
    rng = np.random.default_rng(seed)
    q_stop = ROBOT.random_joints(n_stops, rng=rng)
    t_stop = 1000.0 + 7.0 * np.arange(n_stops)
    t_t = t_stop + 1.2 + rng.uniform(-0.3, 0.3, n_stops)
    p = (B @ fk(ROBOT, q_stop))[:, :3, 3]
    if robot_rate_hz is None:
        return t_stop, q_stop, t_t, p
    t_r = np.arange(t_stop[0], t_stop[-1] + 7.0, 1 / robot_rate_hz)
    return t_r, q_stop[np.searchsorted(t_stop, t_r, side="right") - 1], t_t, p


def test_check_is_stream_bounds():
    t = np.arange(0, 10, 1 / 125)
    check_is_stream(t, np.arange(0, 10, 1e-3))  # 125 Hz robot, 1 kHz tracker
    check_is_stream(np.arange(0, 10, 0.9 * MAX_STREAM_PERIOD_S), t)  # a slow logger, still a stream
    with pytest.raises(NotAStreamError) as e:
        check_is_stream(np.arange(0, 100, 1.1 * MAX_STREAM_PERIOD_S), t)
    assert e.value.which == "robot log" and not e.value.static
    assert e.value.period_robot_s == pytest.approx(1.1 * MAX_STREAM_PERIOD_S)
    check_is_stream(np.arange(0, 100, 1.1 * MAX_STREAM_PERIOD_S), t, max_gap_s=0.6)  # the option raises the bound


@pytest.mark.parametrize("robot_rate_hz, refused", [(None, "robot_log.csv"), (50, "tracker.csv")])
def test_static_campaign_is_refused_and_pointed_at_import_table(tmp_path, capsys, robot_rate_hz, refused):
    t_r, q, t_t, p = _static(12, robot_rate_hz)
    with pytest.raises(NotAStreamError):
        align_streams(t_r, q, t_t, p, None, ROBOT)
    r, k = _write_pair(tmp_path, t_r, q, t_t, p)
    out = tmp_path / "x.csv"
    code, so, se = run(["import", "stream", r, k, "--robot", "rx160", "-o", out], capsys)
    line = se.strip()
    assert code == 2 and len(line.splitlines()) == 1 and not out.exists(), se
    assert line.startswith(f"hykin: error: {tmp_path / refused}: not a stream") or f"{tmp_path / refused}: not a stream" in line
    assert "hykin import table" in line and "--max-gap" in line
    period = 7.0 if refused == "robot_log.csv" else np.median(np.diff(t_t))
    assert f"a sample every {period:.3g} s" in line
    assert ("one tracker point per robot sample" in line) == (robot_rate_hz is None)


def test_offset_at_the_edge_of_the_search_is_refused_and_found_when_widened(tmp_path, capsys):
    truth = 1.2
    t_r, q, t_t, p = _stream(truth)
    with pytest.raises(ClockRangeError) as e:
        estimate_clock(t_r, q, t_t, p, ROBOT, max_offset_s=1.0)
    assert abs(e.value.offset_s) > 1.0 - 2e-3
    c = estimate_clock(t_r, q, t_t, p, ROBOT, max_offset_s=2.0)
    assert abs(c.offset_s - truth) < 1e-4 and c.correlation > 0.99
    r, k = _write_pair(tmp_path, t_r, q, t_t, p)
    out = tmp_path / "x.csv"
    code, so, se = run(["import", "stream", r, k, "--robot", "rx160", "-o", out], capsys)
    assert code == 2 and len(se.strip().splitlines()) == 1 and "edge of the search range" in se
    assert "--max-offset" in se and not out.exists()
    code, so, se = run(["import", "stream", r, k, "--robot", "rx160", "-o", out, "--max-offset", "2"], capsys)
    assert code == 0, se
    got_ms = float(so.split("clock offset ")[1].split(" ms")[0])
    assert abs(got_ms - truth * 1e3) < 0.1


def test_logs_that_no_clock_joins_are_refused_unless_accepted(tmp_path, capsys):
    """The tracker recorded another motion: the speed profiles correlate weakly at every offset, the
    positions stay far apart: refused (before: a warning blaming the tool, and the rows written)."""
    t_r, q, t_t, p = _stream(0.05, tracker_seed=10)  # (other seeds: some peak at the edge, refused as such)
    c = estimate_clock(t_r, q, t_t, p, ROBOT)
    assert c.correlation < 0.5 and c.rms_m > 0.05
    r, k = _write_pair(tmp_path, t_r, q, t_t, p)
    out = tmp_path / "x.csv"
    code, so, se = run(["import", "stream", r, k, "--robot", "rx160", "-o", out, "--max-speed", "0"], capsys)
    assert code == 2 and len(se.strip().splitlines()) == 1 and not out.exists(), se
    assert "no clock offset joins the two files" in se and f"{c.correlation:.2f}" in se and "--max-rms-mm" in se
    code, so, se = run(["import", "stream", r, k, "--robot", "rx160", "-o", out, "--max-speed", "0",
                        "--max-rms-mm", "1e6"], capsys)
    assert code == 0 and out.exists(), se
    # the right pair of logs passes quietly
    t_r, q, t_t, p = _stream(0.05)
    r, k = _write_pair(tmp_path, t_r, q, t_t, p)
    code, so, se = run(["import", "stream", r, k, "--robot", "rx160", "-o", out, "--force"], capsys)
    assert code == 0 and "warning" not in so + se, se
    assert abs(float(so.split("clock offset ")[1].split(" ms")[0]) - 50.0) < 0.1
