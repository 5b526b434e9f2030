"""``hykin rsi``: the KUKA RSI XML codec, the correction, and the bridge driven by a simulated
controller on loopback (nominal IK every cycle, a true robot with several mm of error).

The compensator of the bridge tests is a reference written here (IK of the TRUE robot, then the
nominal FK: exact compensation), so the figures check the bridge itself; the CLI test runs the real
model file and compares with the in-process handler. The simulated controller sends at the real
period (4 ms) and waits up to 1 s for an answer (correctness on a busy machine; the benchmark
``benchmarks/bench_realtime.py`` keeps RSI's own deadline).
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from comp_models import deviate, tiny_model_file
from hypothesis import given, settings
from hypothesis import strategies as st

from hykin import fk, load_robot
from hykin.compensation.krl import matrix_from_abc
from hykin.geometry import se3
from hykin.kinematics.ik import ik
from hykin.realtime.rsi import RsiHandler, korr_of, pose_of
from hykin.realtime.rsi_xml import RsiConfig, RsiConfigWarning, format_rob, format_sen, parse_rob, parse_sen, read_config
from hykin.realtime.simulated import SimulatedRsi, path_errors, xyzabc_of
from hykin.realtime.udp_bridge import bind_udp, run_bridge
from hykin.sim.simulate import VirtualRobot

ROOT = Path(__file__).resolve().parents[1]
SIGNS = np.array([-1.0, 1, 1, -1, 1, -1])


class _Step:
    def __init__(self, q, command, success, reason=""):
        self.q, self.command, self.success, self.reason = q, command, success, reason


def exact_step(vr):
    """Reference compensator: IK of the TRUE robot near q_prev, command = nominal FK there."""
    nom, truth = vr.nominal, vr.truth

    def step(T, q_prev):
        r = ik(truth, T, q_seed=q_prev, seed_robot=nom)
        if not r.success[0]:
            return _Step(np.full(nom.dof, np.nan), np.full((4, 4), np.nan), False, "unreachable")
        return _Step(r.q[0], se3.invert(nom.base) @ fk(nom, r.q[:1])[0], True)
    return step


def virtual(preset: str, seed: int) -> VirtualRobot:
    """``preset`` with our own geometric deviations: several mm of nominal error."""
    nom = load_robot(preset)
    return VirtualRobot(preset + "-test", nom, deviate(nom, seed, sigma_m=8e-4, sigma_rad=np.radians(0.1)))


@pytest.fixture(scope="module")
def kuka():
    return virtual("kuka-kr6-r900", 26)


def line_arc(nom, n: int, q0, up: int = 1) -> np.ndarray:
    """``(n, 4, 4)`` controller-frame poses around the nominal pose at q0: 50 mm along x while a 40 mm
    arch rises along axis ``up``."""
    T0 = se3.invert(nom.base) @ fk(nom, q0[None])[0]
    s = np.linspace(0, 1, n)
    P = np.repeat(T0[None], n, 0)
    P[:, 0, 3] += 0.05 * s
    P[:, up, 3] += 0.04 * np.sin(np.pi * s)
    return P


def _path(nom, n, q0):
    """:func:`line_arc` as RSI setpoints (X..C)."""
    P = line_arc(nom, n, q0)
    a0 = xyzabc_of(P[0])[3]
    return np.array([xyzabc_of(T, a0) for T in P])


def test_xml_round_trips_and_config(tmp_path):
    cfg = RsiConfig()
    sp, act, ax = np.array([500.0, -20, 700, 10, -80, 170]), np.array([501.0, -21, 701, 11, -81, 171]), np.arange(6) * 10.0
    m = parse_rob(format_rob(4711, sp, act, ax, cfg), cfg, 6)
    assert m.ipoc == 4711 and np.allclose(m.setpoint, sp) and np.allclose(m.actual, act) and np.allclose(m.axes_deg, ax)
    ipoc, k = parse_sen(format_sen(4711, np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.03]), cfg), cfg)
    assert ipoc == 4711 and np.allclose(k, [0.1, -0.2, 0.3, 0.01, -0.02, 0.03])
    p = tmp_path / "RSI_EthernetConfig.xml"
    rec = "".join(f'<ELEMENT TAG="Korr.{c}" TYPE="DOUBLE" INDX="{i + 1}" HOLDON="1" />' for i, c in enumerate("XYZABC"))
    p.write_text(f"<ROOT><CONFIG><IP_NUMBER>127.0.0.1</IP_NUMBER><PORT>49152</PORT><SENTYPE>Hykin</SENTYPE>"
                 f"<CORRMODE>INCREMENTAL</CORRMODE></CONFIG><SEND><ELEMENTS/></SEND><RECEIVE><ELEMENTS>{rec}"
                 f'<ELEMENT TAG="DiO" TYPE="LONG" INDX="7" /></ELEMENTS></RECEIVE></ROOT>')
    c = read_config(p)
    assert (c.sen_type, c.korr_tag, c.mode, c.port) == ("Hykin", "Korr", "incremental", 49152)
    assert read_config(p, "absolute").mode == "absolute"
    assert format_sen(1, np.zeros(6), c).startswith(b'<Sen Type="Hykin"><Korr X=')
    text = p.read_text()
    p.write_text(text.replace('TAG="Korr.C"', 'TAG="Foo"'))
    with pytest.raises(ValueError, match=r"RSI_EthernetConfig.xml: .*Korr lacks C"):
        read_config(p)
    # axis corrections only (AK.A1..A6): the controller would drop a Cartesian RKorr -> refused, naming the fix
    ak = "".join(f'<ELEMENT TAG="AK.A{j}" TYPE="DOUBLE" INDX="{j}" HOLDON="1" />' for j in range(1, 7))
    p.write_text(text.replace(rec, ak))
    with pytest.raises(ValueError, match=r"lists no Cartesian correction .*AK.A1.*RKorr.X"):
        read_config(p)
    # <SEND> without the setpoint: a warning naming DEF_RSol; with it and the axes: none
    p.write_text(text.replace("<SEND><ELEMENTS/>", '<SEND><ELEMENTS><ELEMENT TAG="DEF_RIst" TYPE="DOUBLE" INDX="INTERNAL" />'
                              '<ELEMENT TAG="DEF_AIPos" TYPE="DOUBLE" INDX="INTERNAL" /></ELEMENTS>'))
    with pytest.warns(RsiConfigWarning, match=r"does not list DEF_RSol:"):
        assert read_config(p).korr_tag == "Korr"
    p.write_text(p.read_text().replace('TAG="DEF_RIst"', 'TAG="DEF_RSol"'))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        read_config(p)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-170, 170), min_size=3, max_size=3), st.lists(st.floats(-3, 3), min_size=3, max_size=3),
       st.lists(st.floats(-20, 20), min_size=3, max_size=3))
def test_setpoint_plus_correction_is_the_command(abc, dabc, dxyz):
    sp = np.array([400.0, 100, 600, *abc])
    R = matrix_from_abc(*abc) @ se3.rotvec_to_matrix(np.radians(dabc))
    cmd = se3.make_transform(R, (sp[:3] + dxyz) * 1e-3)
    k = korr_of(cmd, sp)
    assert np.all(np.abs(k[3:]) <= 180)
    got = pose_of(sp + k)  # what the controller commands: componentwise sum
    assert np.abs(got[:3, 3] - cmd[:3, 3]).max() < 1e-12 and se3.pose_error(got[None], cmd[None])[1][0] < 1e-9


def test_handler_bad_input_never_gets_a_made_up_correction(kuka):
    nom = kuka.nominal
    q0 = np.radians([10.0, -80, 100, 20, 50, -30])
    sp = _path(nom, 3, q0)
    h = RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, RsiConfig())
    msg = format_rob(1000, sp[0], sp[0], np.degrees(q0 * SIGNS), RsiConfig())
    out = h(msg)
    assert out.kind == "ok"
    ipoc, k = parse_sen(out.reply, RsiConfig())
    assert ipoc == 1000 and 0.05 < np.linalg.norm(k[:3]) < 20  # several mm of correction
    for bad, why in [(b"\x00\xff garbage", "malformed"), (msg[: len(msg) // 2], "malformed"), (msg, "stale IPOC"),
                     (msg.replace(b"1000", b"996"), "stale IPOC"), (b'<!DOCTYPE x [<!ENTITY a "b">]>' + msg, "malformed"),
                     (msg.replace(b"<RSol ", b"<RXol ").replace(b"1000", b"1004"), "malformed"),
                     (msg.replace(b'A3="', b'A3="nan').replace(b"1000", b"1004"), "malformed")]:
        o = h(bad)
        assert o.reply is None and o.kind == f"ignored:{why}", (bad[:40], o.kind)
    far = sp[1].copy()
    far[:3] = [5000.0, 0, 0]  # unreachable: zero correction, IPOC echoed
    o = h(format_rob(1008, far, far, np.degrees(q0 * SIGNS), RsiConfig()))
    assert o.kind == "failure" and o.skipped == 1
    ipoc, k = parse_sen(o.reply, RsiConfig())
    assert ipoc == 1008 and not k.any()
    h2 = RsiHandler(lambda T, q: 1 / 0, np.eye(4), 6, SIGNS, RsiConfig())  # an internal error
    assert not parse_sen(h2(msg).reply, RsiConfig())[1].any() and "ZeroDivisionError" in h2.last_reason


def _bridge_thread(handler, **kw):
    sock = bind_udp("127.0.0.1", 0)
    stop = threading.Event()
    box = {}
    th = threading.Thread(target=lambda: box.setdefault("stats", run_bridge(sock, handler, period_s=0.004, stop=stop, **kw)),
                          daemon=True)
    th.start()
    return sock, stop, th, box


def flooded(addr, msgs: list, run):
    """``run()`` while a second sender floods ``addr`` with ``msgs`` in turn; ``(run's result, the
    datagrams the flooder got back)``."""
    got, stop = [], threading.Event()

    def flood():
        f = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        f.settimeout(0.001)
        k = 0
        while not stop.is_set():
            f.sendto(msgs[k % len(msgs)], addr)
            k += 1
            try:
                got.append(f.recv(65536))
            except (socket.timeout, ConnectionRefusedError):
                pass
        f.close()

    ft = threading.Thread(target=flood, daemon=True)
    ft.start()
    try:
        return run(), got
    finally:
        stop.set()
        ft.join(5)


@pytest.mark.parametrize("mode", ["absolute", "incremental"])
def test_simulated_controller_follows_the_path_through_the_bridge_under_a_flood(kuka, mode):
    nom = kuka.nominal
    q0 = np.radians([10.0, -80, 100, 20, 50, -30])
    sp = _path(nom, 120, q0)
    cfg = RsiConfig(mode=mode, korr_tag="Korr", sen_type="Cell")
    sock, stop, th, box = _bridge_thread(RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, cfg))
    addr = sock.getsockname()
    sim = SimulatedRsi(nom, sp, q0, addr, SIGNS, cfg, period_s=0.004, deadline_s=1.0, ipoc0=200_000)
    ctrl = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    # the controller's first cycle locks the bridge onto it (without --controller)
    first = SimulatedRsi(nom, sp[:1], q0, addr, SIGNS, cfg, period_s=0.004, deadline_s=5.0)
    warm = first.run(ctrl)
    if mode == "incremental":
        sim.held0 = first.held_last
    far = sp[0] + [30, 0, 0, 0, 0, 0]  # a second sender: garbage, truncated, and well-formed messages with other setpoints
    msgs = [b"\x00" * 100, b"<Rob><IPOC>99999999</IPOC>", format_rob(10**9, far, far, np.zeros(6), cfg), b"x" * 9000]
    run, got = flooded(addr, msgs, lambda: sim.run(ctrl))
    ctrl.close()
    stop.set()
    th.join(5)
    st = box["stats"]
    assert warm.reply_s[0] > 0 and np.isfinite(run.reply_s).all()  # every cycle answered, with its own IPOC
    assert got == []  # the flooder never got an answer
    assert st.ignored["other sender"] + st.ignored["oversized"] > 0 and st.failures == 0
    targets = nom.base @ np.array([pose_of(p) for p in sp])
    err, ang = path_errors(kuka, run.q, targets)
    base_err, _ = path_errors(kuka, ik(nom, targets, q_seed=run.q).q, targets)
    assert base_err.mean() > 0.5  # the robot is several tenths of a mm off without the bridge
    assert err.max() < 1e-3 and ang.max() < 1e-5  # through the bridge: on the path


def test_bridge_stops_answering_after_consecutive_failures(kuka):
    nom = kuka.nominal
    q0 = np.radians([10.0, -80, 100, 20, 50, -30])
    sp = _path(nom, 8, q0)
    sock, stop, th, box = _bridge_thread(RsiHandler(lambda T, q: 1 / 0, np.eye(4), 6, SIGNS, RsiConfig()), max_failures=3)
    run = SimulatedRsi(nom, sp, q0, sock.getsockname(), SIGNS, period_s=0.004, deadline_s=0.3).run()
    th.join(5)
    sock.close()
    assert box["stats"].stopped.startswith("3 consecutive failures")
    assert np.isfinite(run.reply_s).sum() == 3 and np.abs(run.correction).max() < 1e-9  # 3 zero answers, then silence


@pytest.mark.slow  # ~10 s: the same path runs in-process in the default suite
def test_cli_rsi_answers_as_the_in_process_handler():
    from hykin.compensation.compensator import Compensator
    from hykin.hybrid.model import HybridModel

    mp = tiny_model_file()
    m = HybridModel.load(mp)
    nom = m.nominal
    q0 = nom.random_joints(1, 4, margin=0.4)[0]
    sp = _path(nom, 4, q0)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen([sys.executable, "-m", "hykin", "rsi", str(mp), "--listen", f"127.0.0.1:{port}", "--frame",
                             "measurement", "--idle-exit-s", "2"], env={"PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])), "PATH": "/usr/bin:/bin",
                                                                       "OMP_NUM_THREADS": "1"},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    c.settimeout(0.5)
    h = RsiHandler(Compensator(m, frame="measurement").step, nom.base, 6, np.ones(6), RsiConfig())
    t0, replies = time.time(), []
    for k in range(4):
        msg = format_rob(100 + 4 * k, sp[k], sp[k], np.degrees(q0), RsiConfig())
        while True:  # until the bridge is up
            c.sendto(msg, ("127.0.0.1", port))
            try:
                replies.append(parse_sen(c.recv(65536), RsiConfig()))
                break
            except (socket.timeout, ConnectionRefusedError):
                assert proc.poll() is None and time.time() - t0 < 120, proc.communicate()[1][-500:]
    c.close()
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-500:]
    assert "answered 4" in out
    for k, (ipoc, korr) in enumerate(replies):
        ref_ipoc, ref = parse_sen(h(format_rob(100 + 4 * k, sp[k], sp[k], np.degrees(q0), RsiConfig())).reply, RsiConfig())
        assert ipoc == ref_ipoc and np.abs(korr - ref).max() < 1e-4 and np.linalg.norm(korr[:3]) > 0.01


def test_spinning_bridge_answers_like_the_sleeping_one(kuka):
    """--spin polls without select(): the same answers, and it still stops on the stop event."""
    nom = kuka.nominal
    q0 = np.radians([10.0, -80, 100, 20, 50, -30])
    sp = _path(nom, 20, q0)
    runs = []
    for spin in (False, True):
        sock, stop, th, box = _bridge_thread(RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, RsiConfig()), spin=spin)
        runs.append(SimulatedRsi(nom, sp, q0, sock.getsockname(), SIGNS, period_s=0.004, deadline_s=1.0).run())
        stop.set()
        th.join(5)
        sock.close()
        assert not th.is_alive() and box["stats"].answered == 20
    assert np.isfinite(runs[1].reply_s).all()
    np.testing.assert_allclose(runs[1].correction, runs[0].correction, atol=1e-9)


def test_raise_priority_says_what_it_did_and_never_raises(monkeypatch):
    import os

    from hykin.realtime.udp_bridge import raise_priority

    assert raise_priority(0).startswith("normal priority")
    calls = []
    monkeypatch.setattr(os, "sched_setscheduler", lambda pid, policy, param: calls.append((pid, policy, param.sched_priority)))
    assert raise_priority(30) == "real-time priority (SCHED_FIFO 30)" and calls == [(0, os.SCHED_FIFO, 30)]

    def refuse(*a):
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse)
    line = raise_priority(20)
    assert line.startswith("normal priority: SCHED_FIFO 20 refused (Operation not permitted)") and "--rt-priority 0" in line


def test_cli_rsi_refuses_an_rt_priority_out_of_range_in_one_line(tmp_path, capsys):
    from hykin.cli import main

    mp = tiny_model_file()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SystemExit) as e:
        main(["rsi", str(mp), "--listen", f"127.0.0.1:{port}", "--rt-priority", "150"])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and "--rt-priority" in err[0] and "150" in err[0]


def test_a_restarted_controller_is_answered_again(kuka):
    """A controller that restarts counts IPOC from far behind: after two consecutive such messages the
    bridge answers again; one stray old datagram, or repeats, stay unanswered."""
    nom = kuka.nominal
    q0 = np.radians([10.0, -80, 100, 20, 50, -30])
    sp = _path(nom, 2, q0)
    h = RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, RsiConfig())
    msg = lambda ipoc: format_rob(ipoc, sp[0], sp[0], np.degrees(q0 * SIGNS), RsiConfig())
    assert h(msg(900_000)).kind == "ok" and h(msg(900_004)).kind == "ok"
    assert h(msg(5_000)).kind == "ignored:stale IPOC"  # a stray old datagram ...
    assert h(msg(900_008)).kind == "ok"  # ... and the session goes on
    assert h(msg(900_004)).kind == "ignored:stale IPOC"  # a repeat
    assert h(msg(6_000)).kind == "ignored:stale IPOC"  # the restart's first message
    o = h(msg(6_004))  # its second, 4 ms later: a new count
    assert o.kind == "ok" and o.skipped == 0 and parse_sen(o.reply, RsiConfig())[0] == 6_004
    assert h(msg(6_008)).kind == "ok" and h(msg(6_004)).kind == "ignored:stale IPOC"


def _incremental_and_reference(kuka):
    """A 12-setpoint path, an incremental-mode handler and an absolute-mode one (the reference correction)
    on the KUKA-like truth, and the controller's axes (deg)."""
    q0 = np.radians([10.0, -80, 100, 20, 50, -30])
    cfg = RsiConfig(mode="incremental")
    return (_path(kuka.nominal, 12, q0), cfg, RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, cfg),
            RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, RsiConfig()), np.degrees(q0 * SIGNS))


@pytest.mark.parametrize("stray", [999_999_999, 1_000 + 400])  # far ahead; 400 ms ahead (probe s41 AM)
def test_incremental_sum_survives_a_stray_datagram_far_ahead(kuka, stray):
    """Probe s41 AH: one datagram from the controller's address with an IPOC far ahead (a corrupted stamp)
    was answered as a new RSI context; the session's next messages then counted as a restart, hykin's sum
    started again at zero and the full correction was sent a second time (4.3 mm on every later cycle).
    The session going on from before the jump now marks it a stray and undoes its answer: the sum the
    controller adds up stays the correction (checked against the absolute mode's on the same message)."""
    sp, cfg, h, ref, axes = _incremental_and_reference(kuka)
    total, prev_cmd, ipoc = np.zeros(6), sp[0], 1_000
    for k in range(12):
        msg = format_rob(ipoc, sp[k], prev_cmd, axes, cfg)
        o = h(msg)
        if k == 6:  # the first message after the stray is behind it: dropped (one alone may be a late datagram)
            assert o.kind == "ignored:stale IPOC", o
        else:
            assert o.kind == "ok", (k, o)
            got_ipoc, inc = parse_sen(o.reply, cfg)
            assert got_ipoc == ipoc
            total = total + inc  # the controller adds up the answers to its own cycles
        prev_cmd = sp[k] + total
        if k == 5:  # a stray: answered (or not), never applied by the controller (not its cycle's IPOC)
            h(format_rob(stray, sp[k], prev_cmd, axes, cfg))
        ipoc += 4
    want = parse_sen(ref(format_rob(ipoc - 4, sp[11], prev_cmd, axes, RsiConfig())).reply, RsiConfig())[1]
    np.testing.assert_allclose(total, want, atol=1e-3)
    assert h.stray_jumps == 1 and h.new_sessions == 0


def test_incremental_sum_resyncs_after_a_late_first_answer_and_a_gap(kuka):
    """Probe s41 AH: the first answer (the whole correction) reached the controller too late to be applied
    and the next cycle never reached the bridge (a gap in the stamps): hykin counted the correction as
    applied and the path stayed 4.3 mm off on every later cycle. The answers not yet seen applied in RIst
    are now all considered at the first message after the gap."""
    sp, cfg, h, ref, axes = _incremental_and_reference(kuka)
    total, prev_cmd = np.zeros(6), sp[0]
    for k in range(12):
        ipoc = 1_000 + 4 * k
        if k != 1:  # cycle 1 never reaches the bridge
            o = h(format_rob(ipoc, sp[k], prev_cmd, axes, cfg))
            assert o.kind == "ok", (k, o)
            if k != 0:  # the first answer arrives too late to be applied
                total = total + parse_sen(o.reply, cfg)[1]
        prev_cmd = sp[k] + total
    want = parse_sen(ref(format_rob(1_044, sp[11], prev_cmd, axes, RsiConfig())).reply, RsiConfig())[1]
    assert np.abs(want).max() > 1.0  # several mm of correction at stake
    np.testing.assert_allclose(total, want, atol=1e-3)
    assert h.lost_answers == 1


def test_bridge_warms_its_compensator_before_it_listens(monkeypatch):
    """Probe s41 AH: the first answer left 0.2-5 s after the start-up banner (the compiled kernels loaded on
    the first cycle). The compensator now steps once before the socket is bound."""
    import hykin.cli.realtime as cli_rt
    import hykin.realtime.udp_bridge as ub
    from hykin.compensation.compensator import Compensator

    events = []
    step = Compensator.step
    monkeypatch.setattr(Compensator, "step", lambda self, *a, **k: (events.append("step"), step(self, *a, **k))[1])

    def bind(host, port):
        events.append("bind")
        raise OSError("not in this test")

    monkeypatch.setattr(ub, "bind_udp", bind)
    with pytest.raises(Exception, match="cannot bind"):
        cli_rt._bridge_setup(str(tiny_model_file()), "127.0.0.1:49999", None, "measurement", 3, 4.0, None, None)
    assert events[:2] == ["step", "bind"], events


def test_ctrl_c_ends_the_bridge_with_its_counts():
    """Probe s41 AM: Ctrl-C printed only "hykin: interrupted", not the counts the docs promise on exit."""
    from hykin.realtime.udp_bridge import Outcome

    calls = []

    def handler(data):
        calls.append(data)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return Outcome(b"ok", "ok")

    sock = bind_udp("127.0.0.1", 0)
    with sock, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        for _ in range(2):
            tx.sendto(b"x", sock.getsockname())
        time.sleep(0.05)
        st = run_bridge(sock, handler, period_s=0.004, max_failures=3, idle_exit_s=2.0)
    assert st.stopped == "interrupted (Ctrl-C)" and len(calls) == 2
