"""``hykin egm`` / ``hykin rsi`` (probe s42 AT fixes): kernel receive stamps on Python 3.11 (which lacks
the option's name), EgmRobot messages missing ``required`` fields dropped, a stray seqno's jump taken back
out of the skipped count, the newest valid cycle of a drain answered (not a garbage, truncated, stale or
reordered datagram read with it), the whole per-message path warmed before the socket is bound, and the
exit / lock lines. Handlers run on a stub compensator (command = target) unless the test needs more."""

from __future__ import annotations

import logging
import socket
import sys
import threading
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from comp_models import tiny_model_file
from test_realtime_rsi import SIGNS, _Step

from hykin.geometry import se3
from hykin.realtime import egm_pb2
from hykin.realtime.egm import EgmHandler, format_robot, parse_robot, parse_sensor
from hykin.realtime.rsi import RsiHandler
from hykin.realtime.rsi_xml import RsiConfig, format_rob, format_sen, parse_sen, read_config
from hykin.realtime import udp_bridge
from hykin.realtime.udp_bridge import arrival_time, bind_udp, run_bridge

SO_TIMESTAMPNS = getattr(udp_bridge, "SO_TIMESTAMPNS", None)

PLANNED = se3.make_transform(se3.rotvec_to_matrix(np.array([0.1, -0.2, 0.3])), np.array([0.9, -0.1, 1.2]))
JOINTS = np.array([10.0, 20, -10, 30, 40, -20])


def _stub(T, q):
    """A compensator that always succeeds and commands the target itself."""
    return _Step(q, T, True)


def _egm():
    return EgmHandler(_stub, np.eye(4), 6, np.ones(6))


def _msg(seq: int, T=PLANNED) -> bytes:
    return format_robot(seq, 4 * seq, T, JOINTS, T)


def _rsi():
    return RsiHandler(_stub, np.eye(4), 6, SIGNS, RsiConfig())


def _rob(ipoc: int) -> bytes:
    return format_rob(ipoc, [900.0, -100, 1200, 10, 20, 30], [900.0, -100, 1200, 10, 20, 30], JOINTS, RsiConfig())


# ---- A3: kernel receive stamps --------------------------------------------------------------------------

@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS is Linux's")
def test_a_socket_from_bind_udp_gets_kernel_receive_stamps():
    """Probe s42 AT: Python 3.11 does not export SO_TIMESTAMPNS, so the stamp was never enabled and every
    answer was timed from when the bridge read its datagram (late answers went uncounted)."""
    assert SO_TIMESTAMPNS == getattr(socket, "SO_TIMESTAMPNS", 35)
    with bind_udp("127.0.0.1", 0) as rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        assert rx.getsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS) == 1
        t0 = time.time()
        tx.sendto(b"x", rx.getsockname())
        data, anc, _, _ = rx.recvmsg(16, socket.CMSG_SPACE(16))
    t = arrival_time(anc)
    # (on the wall clock; no bound on when: while the kernel switches its receive stamps on, deferred, the first
    # datagrams after a socket asks for them are stamped when read)
    assert data == b"x" and t is not None and abs(t - t0) < 60


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS is Linux's")
def test_the_simulated_controller_times_answers_by_kernel_stamps():
    from hykin import load_robot
    from hykin.kinematics.fk import fk
    from hykin.realtime.simulated import SimulatedEgm

    nom = load_robot("abb-irb2400")
    q0 = np.radians(JOINTS)
    P = (se3.invert(nom.base) @ fk(nom, q0[None])[0])[None]
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as mute, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as ctrl:
        mute.bind(("127.0.0.1", 0))  # a bridge that never answers
        SimulatedEgm(nom, P, q0, mute.getsockname(), deadline_s=0.01).run(ctrl)
        assert ctrl.getsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS) == 1


# ---- A1: required fields ------------------------------------------------------------------------------

def _without(field: str, T=PLANNED) -> bytes:
    """An EgmRobot of seqno 5 with ``field`` (a dotted path) cleared."""
    m = egm_pb2.EgmRobot()
    m.ParseFromString(_msg(5, T))
    *path, name = field.split(".")
    sub = m
    for p in path:
        sub = getattr(sub, p)
    sub.ClearField(name)
    return m.SerializePartialToString()


@pytest.mark.parametrize("field", ["planned.cartesian.pos.z", "planned.cartesian.orient.u0",
                                   "feedBack.cartesian.pos.x", "mciState.state"])
def test_a_message_missing_a_required_field_is_dropped_as_malformed(field):
    """Probe s42 AT: a planned pose without z was read as z = 0, compensated and answered 1.46 m below the
    path. egm.proto marks these fields required: ABB's parser refuses such a message, and so does hykin."""
    # u0 = 0 (180 deg about x): the quaternion keeps norm 1 without it, as in the probe
    T = se3.make_transform(se3.rotvec_to_matrix(np.array([np.pi, 0, 0])), PLANNED[:3, 3])
    h = _egm()
    assert h(_msg(4, T)).kind == "ok"
    o = h(_without(field, T))
    assert o.reply is None and o.kind == "ignored:malformed" and field in h.last_reason, h.last_reason
    with pytest.raises(ValueError, match="required"):
        parse_robot(_without(field, T), 6)
    assert h(_msg(6, T)).kind == "ok"


# ---- A2: a stray's jump is not skipped cycles --------------------------------------------------------

def _skipped(h, msgs) -> int:
    """The count of skipped cycles a bridge would add up for ``msgs`` (accepted ones only)."""
    outs = [h(m) for m in msgs]
    return sum(o.skipped for o in outs if not o.kind.startswith("ignored"))


def test_a_stray_seqno_ahead_is_taken_back_out_of_the_skipped_cycles():
    """Probe s42 AT: one stray 100,000 ahead made the exit line say 'cycles skipped by the controller 100030'."""
    h = _egm()
    seqs = [5000, 5001, 105_001, 5002, 5003, 5004]  # 5002: dropped as stale (seen, not skipped)
    assert _skipped(h, [_msg(s) for s in seqs]) == 0 and h.stray_jumps == 1
    assert _skipped(h, [_msg(5010)]) == 5  # a real gap still counts
    h = _egm()  # a stray a few cycles ahead, within the restart window
    assert _skipped(h, [_msg(s) for s in (7, 8, 108, 9, 10, 11)]) == 0 and h.stray_jumps == 1
    h = _egm()  # the session's cycle 5003 lost meanwhile: that one counts
    assert _skipped(h, [_msg(s) for s in (5000, 5001, 105_001, 5002, 5004, 5005)]) == 1 and h.stray_jumps == 1


@pytest.mark.parametrize("ahead", [400, 5000])
def test_rsi_a_stray_ipoc_ahead_is_taken_back_out_of_the_skipped_cycles(ahead):
    h = _rsi()
    ipocs = [1000, 1004, 1004 + ahead, 1008, 1012, 1016]
    assert _skipped(h, [_rob(i) for i in ipocs]) == 0 and h.stray_jumps == 1
    assert _skipped(h, [_rob(1028)]) == 2  # a real gap still counts
    h = _rsi()  # the session's cycle 1012 lost meanwhile: that one counts
    assert _skipped(h, [_rob(i) for i in (1000, 1004, 1004 + ahead, 1008, 1016, 1020)]) == 1 and h.stray_jumps == 1


# ---- D1: the newest valid cycle of a drain is answered ------------------------------------------------

class _Controller:
    """Plays the controller from inside the bridge's thread: each time the handler accepts a message it
    sends the next batch of datagrams back to back (so that they all wait together when the bridge reads
    next) and lets ``pause`` s pass; after the last batch it stops the bridge. ``seqno(reply)``: the stamp
    of an answer, recorded in ``answered``."""

    def __init__(self, handler, batches, bridge_addr, seqno, pause=0.0):
        self.h, self.batches, self.addr, self.seqno, self.pause = handler, list(batches), bridge_addr, seqno, pause
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.stop, self.answered = threading.Event(), []

    def __getattr__(self, name):  # cycle_key, incremental, last_reason: the handler's
        return getattr(self.h, name)

    def send_next(self) -> None:
        if not self.batches:
            self.stop.set()
            return
        for d in self.batches.pop(0):
            self.sock.sendto(d, self.addr)

    def __call__(self, data):
        out = self.h(data)
        if not out.kind.startswith("ignored"):
            self.answered.append(self.seqno(out.reply))
            time.sleep(self.pause)
            self.send_next()
        return out


def _serve(ctrl: _Controller, rx, **kw):
    ctrl.send_next()
    guard = threading.Timer(5.0, ctrl.stop.set)  # (the old code never finished: no hang)
    guard.start()
    try:
        return run_bridge(rx, ctrl, period_s=0.004, controller=ctrl.sock.getsockname(), stop=ctrl.stop, **kw)
    finally:
        guard.cancel()
        ctrl.sock.close()


def test_a_bad_or_older_datagram_behind_the_cycle_does_not_take_its_place():
    """Probe s42 AT: a truncated copy or garbage right behind the cycle's datagram 'superseded' it: 30 of 30
    cycles went unanswered and the bridge exited on --idle-exit-s while valid messages kept coming. Now the
    newest cycle the handler accepts is answered; a reordered older one, a stale one or a far-ahead stray
    read with it is superseded, and garbage counts as malformed."""
    m = _msg
    batches = [[m(1)], [m(2), b"\xff" * 40], [m(3), m(3)[:30]], [m(5), m(4)], [m(6), m(100_006)],
               [m(7), m(2)], [m(8), b"\xff" * 40], [m(9)]]
    with bind_udp("127.0.0.1", 0) as rx:
        ctrl = _Controller(_egm(), batches, rx.getsockname(), lambda r: parse_sensor(r)[0], pause=0.08)
        st = _serve(ctrl, rx, idle_exit_s=0.3)  # 8 cycles of 0.08 s: longer than the idle limit
    assert ctrl.answered == [1, 2, 3, 5, 6, 7, 8, 9], ctrl.answered
    # (4: passed over by the bridge, which answered 5 read with it; probe AW D4: no longer counted as skipped
    # by the controller, which did send it)
    assert st.stopped == "stopped" and st.answered == 8 and st.skipped_cycles == 0 and st.passed_over == 1
    assert st.ignored["malformed"] == 3 and st.ignored["superseded"] == 3, st.ignored
    if SO_TIMESTAMPNS is not None:
        assert st.stamped == st.answered and "no kernel receive stamps" not in st.summary()


def test_rsi_answers_the_newest_valid_cycle_of_a_drain():
    r = _rob
    batches = [[r(1000)], [r(1004), b"<Rob><IPOC>1008</IPOC>"], [r(1012), r(1008)], [r(1016), b"\x00" * 9]]
    with bind_udp("127.0.0.1", 0) as rx:
        ctrl = _Controller(_rsi(), batches, rx.getsockname(), lambda b: parse_sen(b, RsiConfig())[0])
        st = _serve(ctrl, rx)
    assert ctrl.answered == [1000, 1004, 1012, 1016] and st.ignored["malformed"] == 2 and st.ignored["superseded"] == 1


def test_the_locked_controller_is_named(caplog):
    """Probe s42 AT: without --controller the bridge locked silently onto whoever sent first."""
    with bind_udp("127.0.0.1", 0) as rx:
        ctrl = _Controller(_egm(), [[_msg(1)], [_msg(2)]], rx.getsockname(), lambda r: parse_sensor(r)[0])
        port = ctrl.sock.getsockname()[1]
        ctrl.send_next()
        with caplog.at_level(logging.WARNING, logger="hykin.realtime"):
            run_bridge(rx, ctrl, period_s=0.004, stop=ctrl.stop)
        ctrl.sock.close()
    lines = [r.getMessage() for r in caplog.records if "first sender" in r.getMessage()]
    assert ctrl.answered == [1, 2] and len(lines) == 1, lines  # one line, when it locks
    assert f"127.0.0.1:{port}" in lines[0] and "--controller" in lines[0], lines


# ---- D2, D3: warm start and exit line -----------------------------------------------------------------

@pytest.mark.parametrize("cmd", ["egm", "rsi"])
def test_the_whole_message_path_runs_before_the_socket_is_bound(monkeypatch, cmd):
    """Probe s42 AT: the first answer left 130-245 ms after the banner (protobuf's import, the first FK,
    the conversions). A throwaway handler now answers synthetic messages before the socket is bound."""
    import hykin.realtime.udp_bridge as ub
    from hykin.cli import main

    cls = EgmHandler if cmd == "egm" else RsiHandler
    events = []
    call = cls.__call__
    monkeypatch.setattr(cls, "__call__", lambda self, d: (o := call(self, d), events.append(o.kind))[0])

    def bind(host, port):
        events.append("bind")
        raise OSError("not in this test")

    monkeypatch.setattr(ub, "bind_udp", bind)
    with pytest.raises(SystemExit):
        main([cmd, str(tiny_model_file()), "--listen", "127.0.0.1:18540", "--rt-priority", "0"])
    assert events == ["ok", "ok", "bind"], events


def test_the_egm_exit_line_says_whether_the_actual_pose_was_checked():
    from hykin.cli.realtime import _checked

    h = EgmHandler(_stub, np.eye(4), 6, np.ones(6), nominal_fk=lambda q: PLANNED)
    assert _checked(h, "feedBack.cartesian", "feedBack.joints") == "; feedBack.cartesian not sent: not checked"
    assert h(_msg(1)).kind == "ok" and h(_without("feedBack.cartesian")).kind == "ok"  # (seqno 5: not checked)
    line = _checked(h, "feedBack.cartesian", "feedBack.joints")
    assert line.startswith("; feedBack.cartesian checked in 1 cycles (largest gap to FK(feedBack.joints) ")


# ---- probe s42 AS (hykin rsi) ---------------------------------------------------------------------------

@pytest.mark.parametrize("ipoc", ["1004\u00b2", "\u0661\u0662\u0663", "1_004", "-4"])
def test_rsi_an_ipoc_of_other_digits_is_malformed_not_a_crash(ipoc):
    """Probe s42 AS: '<IPOC>1004²</IPOC>' passed str.isdigit(), int() raised a ValueError the handler did not
    catch, and the bridge exited (status 2); Arabic-Indic digits were read as 123."""
    h = _rsi()
    assert h(_rob(1000)).kind == "ok"
    o = h(_rob(1004).replace(b"<IPOC>1004</IPOC>", f"<IPOC>{ipoc}</IPOC>".encode()))
    assert o.reply is None and o.kind == "ignored:malformed" and "IPOC" in h.last_reason
    assert h(_rob(1008)).kind == "ok"


@pytest.mark.parametrize("value", ["1_0", "\u0661\u0660", "nan", "-inf", "1e999", "0x10", ""])
def test_rsi_a_number_not_written_in_decimal_is_malformed(value):
    """Probe s42 AS: float() took '1_0' as 10.0 (a garbled setpoint used as one)."""
    h = _rsi()
    o = h(_rob(1000).replace(b'Z="1200.000000"', f'Z="{value}"'.encode(), 1))
    assert o.kind == "ignored:malformed", (value, o.kind)


def test_a_handler_that_raises_does_not_stop_the_bridge():
    calls = []

    def handler(data):
        calls.append(data)
        if data == b"boom":
            raise RuntimeError("a bug")
        return udp_bridge.Outcome(b"ok", "ok")

    with bind_udp("127.0.0.1", 0) as rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        tx.bind(("127.0.0.1", 0))
        stop = threading.Event()
        th = threading.Thread(target=lambda: calls.append(run_bridge(rx, handler, period_s=0.004, stop=stop,
                                                                     controller=tx.getsockname())))
        th.start()
        for d in (b"boom", b"fine"):
            tx.sendto(d, rx.getsockname())
            tx.settimeout(5)
            if d == b"fine":
                assert tx.recv(16) == b"ok"
            else:
                time.sleep(0.1)
        stop.set()
        th.join(5)
    st = calls[-1]
    assert st.answered == 1 and st.ignored["handler error"] == 1 and "superseded" not in st.summary()


def test_rsi_config_sentype_with_blanks_and_relative_mode(tmp_path):
    """Probe s42 AS: <SENTYPE>My Sensor</SENTYPE> was refused (it is an attribute's value: any text), and
    <CORRMODE>RELATIVE</CORRMODE> (KUKA's name of incremental mode) was refused."""
    p = tmp_path / "cfg.xml"
    p.write_text('<ROOT><CONFIG><SENTYPE>My "Sensor" &amp; co</SENTYPE><CORRMODE>RELATIVE</CORRMODE></CONFIG></ROOT>')
    cfg = read_config(p)
    assert cfg.sen_type == 'My "Sensor" & co' and cfg.mode == "incremental"
    answer = format_sen(7, np.zeros(6), cfg)
    assert ET.fromstring(answer).get("Type") == 'My "Sensor" & co' and parse_sen(answer, cfg)[0] == 7
    assert RsiConfig(mode="Relative").mode == "incremental"
    with pytest.raises(ValueError, match="#RELATIVE"):
        RsiConfig(mode="sum")


@pytest.fixture(scope="module")
def kuka():
    from test_realtime_rsi import virtual

    return virtual("kuka-kr6-r900", 26)


@pytest.mark.parametrize("lag", [0, 1, 2])
def test_incremental_a_lost_first_answer_is_seen_through_a_rist_dead_time(kuka, lag):
    """Probe s42 AS: with RIst showing the command of one or two cycles before the last while the robot moved,
    a lost first answer (the whole correction) was never re-synchronised: the rest of the path ran
    uncorrected (3.7 mm) and the exit line said 'did not apply 0'. RIst is now compared with hykin's sum
    as of each of the last MAX_DEAD_CYCLES + 1 answers."""
    from test_realtime_rsi import _path, exact_step
    from test_realtime_s39 import Q0, _ctrl_fk

    from hykin.realtime.rsi import pose_of
    from hykin.realtime.simulated import SimulatedRsi, path_errors

    nom = kuka.nominal
    sp = _path(nom, 40, Q0)  # moving from the first cycle on
    targets = nom.base @ np.array([pose_of(p) for p in sp])
    cfg = RsiConfig(mode="incremental")
    h = RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, cfg, nominal_fk=_ctrl_fk(nom))
    sim = SimulatedRsi(nom, sp, Q0, ("127.0.0.1", 9), SIGNS, cfg=cfg)
    held, Q = np.zeros(6), []
    for k in range(len(sp)):
        q_shown = Q[k - 1 - lag] if k - 1 - lag >= 0 else Q0  # RIst: the command of `lag` cycles before the last
        out = h(sim._message(k, 1_000_000 + 4 * k, q_shown))
        if k != 0:  # the first answer is lost
            held = held + parse_sen(out.reply, cfg)[1]
        Q.append(sim._ik(pose_of(sp[k] + held), Q[-1] if Q else Q0))
    err, _ = path_errors(kuka, np.array(Q), targets)
    assert h.lost_answers == 1 and err[lag + 6:].max() < 1e-3, (h.lost_answers, err.round(4))
