"""Dynamic collection end to end: a trajectory within its limits, a simulated cell's streams, and
their alignment back into a dataset (issue "From a plan to the robot and back")."""

from __future__ import annotations

import json

import numpy as np
import pytest
from cli_run import run as _run
from hypothesis import given, settings
from hypothesis import strategies as st

from hykin.measure.streams import align_streams
from hykin.planning.trajectory import min_jerk_trajectory
from hykin.sim.presets import virtual_preset
from hykin.sim.recording import record_cell


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 8), st.integers(1, 7))
def test_min_jerk_trajectory_keeps_its_limits_and_passes_the_waypoints(seed, n_wp, dof):
    rng = np.random.default_rng(seed)
    w = rng.uniform(-3, 3, (n_wp, dof))
    v = rng.uniform(0.2, 2.0, dof)
    a = rng.uniform(0.5, 5.0, dof)
    tr = min_jerk_trajectory(w, v, a)
    t = np.linspace(0, tr.duration_s, 20_001)
    q, qd = tr.at(t)
    h = t[1] - t[0]
    # speeds from the analytic derivative agree with finite differences, and stay within the limits
    assert np.allclose(np.gradient(q, h, axis=0)[1:-1], qd[1:-1], atol=1e-3 * v.max())
    assert np.all(np.abs(qd) <= v * (1 + 1e-9))
    acc = np.gradient(qd, h, axis=0)[2:-2]
    assert np.all(np.abs(acc) <= a * (1 + 1e-2) + 1e-6)
    # at rest on each waypoint, at its time
    qw, qdw = tr.at(tr.start_s)
    assert np.allclose(qw, w, atol=1e-12) and np.allclose(qdw, 0.0, atol=1e-12)
    # the path between waypoints is the straight joint move the plan checked
    mid = tr.start_s[:-1] + 0.37 * tr.segment_s
    s = (tr.at(mid)[0] - w[:-1])
    d = w[1:] - w[:-1]
    frac = np.einsum("ij,ij->i", s, d) / np.maximum(np.einsum("ij,ij->i", d, d), 1e-300)
    assert np.allclose(s, frac[:, None] * d, atol=1e-12)
    # and the segment time is the shortest one: some joint reaches its speed or acceleration limit
    peak_v = 1.875 * np.abs(d) / tr.segment_s[:, None]
    peak_a = 10 / np.sqrt(3) * np.abs(d) / tr.segment_s[:, None] ** 2
    assert np.allclose(np.max(np.maximum(peak_v / v, peak_a / a), axis=1), 1.0)


def test_streams_of_a_virtual_cell_align_back_to_their_clock():
    vr = virtual_preset("rx160-virtual")
    rng = np.random.default_rng(5)
    w = rng.uniform(vr.nominal.lower * 0.5, vr.nominal.upper * 0.5, (14, 6))
    tr = min_jerk_trajectory(w, np.radians(50), np.radians(100))
    t, q = tr.sample(250)
    rec = record_cell(vr, t, q, robot_rate_hz=125, tracker_rate_hz=1000, offset_s=0.0311, latency_s=0.0015,
                      drift=15e-6, beam_loss_speed_m_s=0.8, dropouts_per_min=3, seed=2)
    assert rec.truth["offset_s"] == 0.0326
    lost = ~np.isfinite(rec.p_tracker_m[:, 0])
    assert rec.truth["n_lost"] == lost.sum() and rec.truth["n_lost_fast"] > 0
    a = align_streams(rec.t_robot_s, rec.q_robot, rec.t_tracker_s, rec.p_tracker_m, None, vr.nominal, fit_drift=True)
    clock = a.info["clock"]
    assert abs(clock.offset_s - rec.truth["offset_s"]) < 0.2e-3
    assert abs(clock.drift - rec.truth["drift"]) < 15e-6  # a 72 s log: the drift is weakly determined
    # kept samples are the true positions at the robot's times, up to noise and the (small) clock error
    T_true = __import__("hykin.sim.simulate", fromlist=["true_poses"]).true_poses(vr, a.q)
    err = np.linalg.norm(a.xyz_m - T_true[:, :3, 3], axis=1)
    assert len(err) > 500 and np.median(err) < 0.1e-3


def test_cli_plan_trajectory_simulate_stream_import(tmp_path, capsys):
    traj, cell, out = tmp_path / "traj.csv", tmp_path / "cell", tmp_path / "streamed.csv"
    rc, o, e = _run(["plan", "rx160", "-n", "10", "--pool", "1000", "--trajectory", "--max-joint-speed", "60",
                     "--floor", "0", "-o", str(traj)], capsys)
    assert rc == 0, e
    assert (tmp_path / "traj.csv").read_text().splitlines()[0] == "t_s,q1,q2,q3,q4,q5,q6"
    rc, o, e = _run(["simulate", "rx160-virtual", "--trajectory", str(traj), "--stream", "-o", str(cell),
                     "--robot-rate", "125", "--tracker-rate", "1000"], capsys)
    assert rc == 0, e
    truth = json.loads((cell / "clock_truth.json").read_text())
    rc, o, e = _run(["import", "stream", str(cell / "robot_log.csv"), str(cell / "tracker.csv"), "--robot", "rx160",
                     "-o", str(out), "--fit-drift"], capsys)
    assert rc == 0, e
    got_ms = float(o.split("clock offset ")[1].split(" ms")[0])
    assert abs(got_ms - truth["offset_s"] * 1e3) < 0.5  # a 10-waypoint log; at scale 0.044 ms (README)
    rc, o, e = _run(["simulate", "rx160-virtual", "--stream", "-o", str(cell)], capsys)
    assert rc != 0 and "--trajectory" in e
    rc, o, e = _run(["plan", "rx160", "-n", "10", "--pool", "1000", "--trajectory", "-o", str(tmp_path / "t.src")], capsys)
    assert rc == 0, e
    src = (tmp_path / "t.src").read_text()
    assert "PTP XP10" in src and "WAIT" not in src and "$OUT" not in src  # the robot does not stop to measure


@pytest.mark.slow  # a fit of a 3,000-pose stream (9 s of the default suite's 240 s budget on 2 cores)
def test_cli_import_stream_second_pass_with_a_fitted_model_times_the_clock_on_its_positions(tmp_path, capsys):
    """Import with the robot file, fit, import again with the model file: the second clock fit uses the
    model's hybrid positions (method positions by default) and stays within 0.05 ms of the truth
    (measured: 0.0077 ms by speed, 0.024 ms by positions on a 3-epoch model of this 12-waypoint log)."""
    traj, cell = tmp_path / "traj.csv", tmp_path / "cell"
    assert _run(["plan", "rx160", "-n", "12", "--pool", "1000", "--trajectory", "--max-joint-speed", "60",
                 "--floor", "0", "--seed", "3", "-o", str(traj)], capsys)[0] == 0
    assert _run(["simulate", "rx160-virtual", "--trajectory", str(traj), "--stream", "-o", str(cell),
                 "--robot-rate", "125", "--tracker-rate", "1000"], capsys)[0] == 0
    truth_ms = json.loads((cell / "clock_truth.json").read_text())["offset_s"] * 1e3
    logs = [str(cell / "robot_log.csv"), str(cell / "tracker.csv")]
    rc, o1, e = _run(["import", "stream", *logs, "--robot", "rx160", "-o", str(tmp_path / "p1.csv"), "--max-speed", "0.3",
                      "--fit-drift"],
                     capsys)
    assert rc == 0, e
    assert "(speed;" in o1
    rc, _, e = _run(["fit", "rx160", str(tmp_path / "p1.csv"), "-o", str(tmp_path / "p1.hykin"), "--max-epochs", "3",
                     "--min-steps", "300"], capsys)
    assert rc == 0, e
    rc, o2, e = _run(["import", "stream", *logs, "--robot", str(tmp_path / "p1.hykin"), "-o", str(tmp_path / "p2.csv"),
                      "--max-speed", "0.3", "--fit-drift"], capsys)
    assert rc == 0, e
    assert "(positions, hybrid positions of the model;" in o2
    err1, err2 = (abs(float(o.split("clock offset ")[1].split(" ms")[0]) - truth_ms) for o in (o1, o2))
    assert err2 < 0.05, (err1, err2)


def test_cli_import_stream_refuses_a_robot_or_model_that_does_not_fit_in_one_line(tmp_path, capsys):
    """Another robot's file leaves its positions hundreds of mm from the tracker's after the clock fit's
    rigid map: a warning (a right file without the tool is as far off), refused with --max-rms-mm in one
    line naming the stream, the RMS and the option, nothing written; a model of another robot is refused
    by default; the right robot file passes quietly."""
    traj, cell = tmp_path / "traj.csv", tmp_path / "cell"
    assert _run(["plan", "rx160", "-n", "8", "--pool", "1000", "--trajectory", "--max-joint-speed", "60",
                 "--floor", "0", "-o", str(traj)], capsys)[0] == 0
    assert _run(["simulate", "rx160-virtual", "--trajectory", str(traj), "--stream", "-o", str(cell),
                 "--robot-rate", "125", "--tracker-rate", "1000"], capsys)[0] == 0
    logs = [str(cell / "robot_log.csv"), str(cell / "tracker.csv")]
    out = tmp_path / "s.csv"
    rc, o, e = _run(["import", "stream", *logs, "--robot", "rx160", "-o", str(out), "--max-speed", "0.3"], capsys)
    assert rc == 0, e
    rms = float(o.split("robot positions ")[1].split(" mm RMS")[0])
    assert rms < 50
    out.unlink()
    assert "warning" not in o + e
    rc, o, e = _run(["import", "stream", *logs, "--robot", "ur10", "-o", str(out), "--max-speed", "0.3"], capsys)
    assert rc == 0 and "warning: the robot file's positions stay" in o + e and "lacks the tool" in o + e and out.exists()
    out.unlink()
    rc, o, e = _run(["import", "stream", *logs, "--robot", "ur10", "-o", str(out), "--max-speed", "0.3",
                     "--max-rms-mm", "50"], capsys)
    lines = e.strip().splitlines()
    assert rc != 0 and len(lines) == 1 and "does not fit this stream" in lines[0] and "--max-rms-mm" in lines[0]
    assert "tracker.csv" in lines[0] and not out.exists()
    other = tmp_path / "ur10.hykin"  # a model of another robot (UR10, fitted on its own simulated poses)
    assert _run(["simulate", "ur10-virtual", "-n", "300", "--no-noise", "-o", str(tmp_path / "u.csv")], capsys)[0] == 0
    assert _run(["fit", "ur10", str(tmp_path / "u.csv"), "-o", str(other), "--max-epochs", "2", "--min-steps", "100"],
                capsys)[0] == 0
    rc, _, e = _run(["import", "stream", *logs, "--robot", str(other), "-o", str(out), "--max-speed", "0.3"], capsys)
    assert rc != 0 and "the model" in e and "does not fit this stream" in e and not out.exists()
    rc, _, e = _run(["import", "stream", *logs, "--robot", "rx160", "-o", str(out), "--max-speed", "0.3",
                     "--max-rms-mm", str(rms / 2)], capsys)
    assert rc != 0 and "bound" in e and not out.exists()

