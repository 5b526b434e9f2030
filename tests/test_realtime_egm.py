"""``hykin egm``: the EGM protobuf codec and the bridge driven by a simulated ABB controller in pose
guidance on loopback (nominal IK every cycle, a true robot with several mm of error), with a
flood from a second sender. Reference compensator and timing rules as in ``test_realtime_rsi``.
"""

from __future__ import annotations

import socket

import numpy as np
import pytest
from test_realtime_rsi import _bridge_thread, exact_step, flooded, line_arc, virtual

from hykin.geometry import se3
from hykin.kinematics.ik import ik
from hykin.realtime.egm import EgmHandler, format_robot, format_sensor, parse_robot, parse_sensor
from hykin.realtime.simulated import SimulatedEgm, path_errors


@pytest.fixture(scope="module")
def abb():
    return virtual("abb-irb2400", 27)


def _path(nom, n, q0):
    return line_arc(nom, n, q0, up=2)


def test_protobuf_round_trip():
    T = se3.make_transform(se3.rotvec_to_matrix(np.array([0.1, -0.2, 0.3])), np.array([0.9, -0.1, 1.2]))
    seq, tm, P, j = parse_robot(format_robot(7, 28, T, np.arange(6.0), T), 6)
    assert (seq, tm) == (7, 28) and np.abs(P - T).max() < 1e-12 and np.allclose(j, np.arange(6.0))
    seq, tm, S = parse_sensor(format_sensor(7, 28, T))
    assert (seq, tm) == (7, 28) and np.abs(S - T).max() < 1e-12


def test_handler_bad_input(abb):
    nom = abb.nominal
    q0 = np.radians([10.0, 20, -10, 30, 40, -20])
    P = _path(nom, 3, q0)
    h = EgmHandler(exact_step(abb), np.eye(4), 6, np.ones(6))
    msg = format_robot(10, 40, P[0], np.degrees(q0), P[0])
    o = h(msg)
    seq, tm, S = parse_sensor(o.reply)
    assert o.kind == "ok" and (seq, tm) == (10, 40) and 0.05 < se3.pose_error(S[None], P[:1])[0][0] < 20
    for bad, why in [(b"\x0a\xff\xff", "malformed"), (msg[:-7], "malformed"), (msg, "stale seqno"),
                     (format_robot(9, 36, P[0], np.degrees(q0), P[0]), "stale seqno"),
                     (format_robot(11, 44, P[0], np.degrees(q0)[:4], P[0]), "malformed")]:
        o = h(bad)
        assert o.reply is None and o.kind == f"ignored:{why}", (why, o.kind)
    far = P[1].copy()
    far[:3, 3] = [6.0, 0, 0]
    o = h(format_robot(13, 52, far, np.degrees(q0), P[0]))  # unreachable: the planned pose goes back unchanged
    assert o.kind == "failure" and o.skipped == 2 and np.abs(parse_sensor(o.reply)[2] - far).max() < 1e-12
    h.last_seq = 2**32 - 1  # seqno wraps
    assert h(format_robot(0, 56, P[0], np.degrees(q0), P[0])).kind == "ok"


def test_simulated_egm_follows_the_path_under_a_flood(abb):
    nom = abb.nominal
    q0 = np.radians([10.0, 20, -10, 30, 40, -20])
    P = _path(nom, 120, q0)
    sock, stop, th, box = _bridge_thread(EgmHandler(exact_step(abb), np.eye(4), 6, np.ones(6)))
    addr = sock.getsockname()
    ctrl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    SimulatedEgm(nom, P[:1], q0, addr, period_s=0.004, deadline_s=5.0, seq0=1).run(ctrl)  # locks the bridge onto it
    far = P[0].copy()
    far[0, 3] += 0.03
    msgs = [b"\x00" * 50, format_robot(10**6, 0, far, np.degrees(q0), far), b"\x0a" * 9000]
    run, got = flooded(addr, msgs, lambda: SimulatedEgm(nom, P, q0, addr, period_s=0.004, deadline_s=1.0, seq0=2).run(ctrl))
    ctrl.close()
    stop.set()
    th.join(5)
    assert np.isfinite(run.reply_s).all() and got == [] and box["stats"].failures == 0
    assert box["stats"].ignored["other sender"] + box["stats"].ignored["oversized"] > 0
    targets = nom.base @ P
    err, ang = path_errors(abb, run.q, targets)
    base_err, _ = path_errors(abb, ik(nom, targets, q_seed=run.q).q, targets)
    assert base_err.mean() > 0.5 and err.max() < 1e-3 and ang.max() < 1e-5


def _handler_and_message(abb):
    """An EGM handler on the ABB-like truth and ``seq -> message`` of one planned pose (a standing robot)."""
    q0 = np.radians([10.0, 20, -10, 30, 40, -20])
    P = _path(abb.nominal, 2, q0)
    return (EgmHandler(exact_step(abb), np.eye(4), 6, np.ones(6)),
            lambda seq: format_robot(seq, 4 * seq, P[0], np.degrees(q0), P[0]))


def test_a_restarted_session_is_answered_again(abb):
    h, msg = _handler_and_message(abb)
    assert h(msg(5000)).kind == "ok" and h(msg(5001)).kind == "ok"
    assert h(msg(3)).kind == "ignored:stale seqno" and h(msg(5002)).kind == "ok"  # one stray: ignored
    assert h(msg(1)).kind == "ignored:stale seqno"  # a new session's first message
    o = h(msg(2))
    assert o.kind == "ok" and o.skipped == 0 and parse_sensor(o.reply)[0] == 2
    assert h(msg(3)).kind == "ok" and h(msg(2)).kind == "ignored:stale seqno"


def test_a_stray_seqno_ahead_does_not_silence_the_session(abb):
    """Probe s41 AM: one datagram with a seqno 100 ahead left the next 100 cycles unanswered (the held pose
    put the path 47 mm off). Two messages continuing the session from before it mark it a stray."""
    h, msg = _handler_and_message(abb)
    assert h(msg(5000)).kind == "ok" and h(msg(5001)).kind == "ok"
    assert h(msg(5100)).kind == "ok"  # the stray (answered: nothing tells it from a gap yet)
    assert h(msg(5002)).kind == "ignored:stale seqno"  # one message behind alone: a late datagram?
    o = h(msg(5003))
    assert o.kind == "ok" and parse_sensor(o.reply)[0] == 5003 and h.stray_jumps == 1
    assert h(msg(5004)).kind == "ok" and h(msg(5002)).kind == "ignored:stale seqno"
    # a real gap (cycles lost) followed by the session going on is not undone
    assert h(msg(5010)).kind == "ok" and h(msg(5011)).kind == "ok" and h.stray_jumps == 1
