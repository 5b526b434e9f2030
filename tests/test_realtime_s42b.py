"""``hykin rsi`` / ``hykin egm`` (probe AW fixes): incremental mode with a RIst that lags 3-4 cycles does not
take the lag for a lost answer (the correction was sent twice); a new RSI context after an IPOC jump ahead is
seen through a lagging RIst; cycles reordered k+2, k, k+1 do not undo k+2's applied answer and are never
answered out of order; the counts (reordering is not skipped cycles; a malformed datagram read with a valid
one is malformed; cycles the bridge passed over in a burst are not "skipped by the controller").

The controller is driven cycle by cycle (no sockets) where the figures are path errors, judged on the TRUE
robot; socket tests assert counts only, not timing."""

from __future__ import annotations

import socket

import numpy as np
import pytest
from test_realtime_rsi import SIGNS, _path, exact_step, virtual
from test_realtime_s39 import Q0, _ctrl_fk
from test_realtime_s42 import _Controller, _egm, _msg, _rob, _rsi, _serve, _without

from hykin.realtime.egm import parse_sensor
from hykin.realtime.rsi import DEFAULT_RIST_LAG_CYCLES, RsiHandler, pose_of
from hykin.realtime.rsi_xml import RsiConfig, parse_sen
from hykin.realtime.simulated import SimulatedRsi, path_errors
from hykin.realtime.udp_bridge import bind_udp

INC = RsiConfig(mode="incremental")


@pytest.fixture(scope="module")
def kuka():
    return virtual("kuka-kr6-r900", 26)


def _drive(kuka, sp, h, lag, stamps, lost=(), restart=None):
    """A KUKA controller in incremental mode, cycle by cycle: RIst is the nominal pose it commanded ``lag``
    cycles before the last; the answers of cycles in ``lost`` are not applied; at cycle ``restart`` its sum
    starts again at zero (a new RSI context). Returns the joints per cycle."""
    sim = SimulatedRsi(kuka.nominal, sp, Q0, ("127.0.0.1", 9), SIGNS, cfg=INC)
    held, Q = np.zeros(6), []
    for k in range(len(sp)):
        if k == restart:
            held = np.zeros(6)
        q_shown = Q[k - 1 - lag] if k - 1 - lag >= 0 else Q0
        out = h(sim._message(k, stamps[k], q_shown))
        if out.reply is not None and k not in lost:
            held = held + parse_sen(out.reply, INC)[1]
        Q.append(sim._ik(pose_of(sp[k] + held), Q[-1] if Q else Q0))
    return np.array(Q)


def _handler(kuka, **kw):
    return RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, INC, nominal_fk=_ctrl_fk(kuka.nominal), **kw)


def _targets(kuka, sp):
    return kuka.nominal.base @ np.array([pose_of(p) for p in sp])


# ---- A2: a lagging RIst is not a lost answer ------------------------------------------------------------

@pytest.mark.parametrize("still", [0, 6])
@pytest.mark.parametrize("lag", [3, 4])
def test_a_rist_lag_of_3_or_4_cycles_does_not_double_the_correction(kuka, lag, still):
    """Probe AW A2: with RIst lagging 3 (or 4) cycles and no answer lost, the lag was taken for a lost first
    answer after RESYNC_CONFIRM_CYCLES = 3 and the whole correction was sent again: 5.95 mm off for the rest of
    the path. A difference must now last rist_lag_cycles + 1 cycles (default 4 + 1)."""
    nom = kuka.nominal
    sp = np.vstack([np.repeat(_path(nom, 30, Q0)[:1], still, 0), _path(nom, 30, Q0)]) if still else _path(nom, 30, Q0)
    h = _handler(kuka)
    Q = _drive(kuka, sp, h, lag, 1_000_000 + 4 * np.arange(len(sp)))
    err, _ = path_errors(kuka, Q, _targets(kuka, sp))
    assert h.lost_answers == 0 and err.max() < 1e-3, (h.lost_answers, err.round(4))


@pytest.mark.parametrize("lag", [0, 3])
def test_a_lost_first_answer_is_still_resynchronised_with_a_lag(kuka, lag):
    """What a lost answer costs now: RIst shows it missing from cycle lag + 1 on; it is taken after
    rist_lag_cycles + 1 such cycles, and the path is on again from then."""
    nom = kuka.nominal
    sp = _path(nom, 40, Q0)
    h = _handler(kuka)
    Q = _drive(kuka, sp, h, lag, 1_000_000 + 4 * np.arange(len(sp)), lost=(0,))
    err, _ = path_errors(kuka, Q, _targets(kuka, sp))
    back = lag + DEFAULT_RIST_LAG_CYCLES + 1  # the first cycle answered with the correction again
    assert h.lost_answers == 1 and err[back:].max() < 1e-3 and err[0] > 1.0, (h.lost_answers, err.round(4))


def test_a_smaller_lag_bound_takes_a_lost_answer_sooner(kuka):
    nom = kuka.nominal
    sp = _path(nom, 20, Q0)
    h = _handler(kuka, rist_lag_cycles=1)
    Q = _drive(kuka, sp, h, 0, 1_000_000 + 4 * np.arange(len(sp)), lost=(0,))
    err, _ = path_errors(kuka, Q, _targets(kuka, sp))
    assert h.lost_answers == 1 and err[2:].max() < 1e-3, err.round(4)


@pytest.mark.parametrize("bad", [-1, 26, 2.5, True])
def test_the_lag_bound_is_checked(kuka, bad):
    with pytest.raises(ValueError, match="--rist-lag-cycles"):
        _handler(kuka, rist_lag_cycles=bad)


def test_cli_refuses_a_lag_bound_out_of_range_in_one_line(capsys):
    from hykin.cli import main

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    with pytest.raises(SystemExit) as e:
        main(["rsi", "no-model-loaded-before-the-check.hykin", "--listen", f"127.0.0.1:{port}", "--rt-priority", "0",
              "--rist-lag-cycles", "40"])
    err = capsys.readouterr().err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and "--rist-lag-cycles" in err[0]


# ---- A1: a new RSI context after a jump ahead, seen through a lagging RIst ------------------------------

@pytest.mark.parametrize("lag,still", [(0, False), (1, False), (2, False), (1, True), (4, False)])
def test_a_new_context_after_a_jump_ahead_is_seen_through_a_rist_lag(kuka, lag, still):
    """Probe AW A1: a new RSI context (the controller's sum at zero again) after an IPOC jump of 20 s ahead
    was looked for only in the message right after the jump; with RIst lagging 1-2 cycles it never showed
    there, and the rest of the path ran uncorrected (5.8 mm, 'new RSI contexts 0')."""
    nom = kuka.nominal
    p = _path(nom, 30, Q0)
    sp = np.vstack([p[:15], np.repeat(p[15:16], 15, 0)]) if still else p
    r = 12  # the new context's first cycle
    stamps = 1_000_000 + 4 * np.arange(len(sp)) + np.where(np.arange(len(sp)) >= r, 20_000, 0)
    h = _handler(kuka)
    Q = _drive(kuka, sp, h, lag, stamps, restart=r)
    err, _ = path_errors(kuka, Q, _targets(kuka, sp))
    back = r + lag + DEFAULT_RIST_LAG_CYCLES + 1
    assert h.new_sessions == 1 and h.lost_answers == 0, (h.new_sessions, h.lost_answers)
    assert err[:r].max() < 1e-3 and err[back:].max() < 1e-3, err.round(4)


def test_a_jump_ahead_in_the_same_context_keeps_the_sum(kuka):
    """A jump of the stamps over 1 s with the controller's sum kept (no new context) changes nothing."""
    nom = kuka.nominal
    sp = _path(nom, 30, Q0)
    stamps = 1_000_000 + 4 * np.arange(len(sp)) + np.where(np.arange(len(sp)) >= 12, 20_000, 0)
    h = _handler(kuka)
    Q = _drive(kuka, sp, h, 2, stamps)
    err, _ = path_errors(kuka, Q, _targets(kuka, sp))
    assert h.new_sessions == 0 and h.lost_answers == 0 and err.max() < 1e-3


# ---- A3 / D1: reordered cycles ---------------------------------------------------------------------------

def test_rsi_reordered_cycles_are_not_a_stray_and_never_answered_out_of_order(kuka):
    """Probe AW A3: cycles k+2, k, k+1 arriving one by one: k+2 was answered, then taken for a stray when k+1
    followed k (incremental: its applied answer undone) and k+1 answered after k+2; each event counted 2
    cycles 'skipped by the controller' (D1). The late ones are dropped now, and their cycles taken back out."""
    sp = _path(kuka.nominal, 12, Q0)
    h = RsiHandler(exact_step(kuka), np.eye(4), 6, SIGNS, INC)
    sim = SimulatedRsi(kuka.nominal, sp, Q0, ("127.0.0.1", 9), SIGNS, cfg=INC)
    order = [0, 1, 2, 3, 6, 4, 5, 7, 10, 8, 9, 11]
    answered, skipped = [], 0
    for k in order:
        out = h(sim._message(k, 1000 + 4 * k, Q0))
        skipped += out.skipped
        if out.reply is not None:
            answered.append(parse_sen(out.reply, INC)[0])
            sum_after = h.sent_sum.copy()
        else:
            assert out.kind == "ignored:stale IPOC" and np.array_equal(h.sent_sum, sum_after)  # nothing undone
    assert answered == [1000 + 4 * k for k in (0, 1, 2, 3, 6, 7, 10, 11)]
    assert h.stray_jumps == 0 and skipped == 0


def test_egm_reordered_cycles_are_not_a_stray_and_never_answered_out_of_order():
    h = _egm()
    answered, skipped = [], 0
    for s in (1, 2, 3, 6, 4, 5, 7, 10, 8, 9, 11):
        out = h(_msg(s))
        skipped += out.skipped
        if out.reply is not None:
            answered.append(parse_sensor(out.reply)[0])
    assert answered == [1, 2, 3, 6, 7, 10, 11] and h.stray_jumps == 0 and skipped == 0
    assert sum(h(_msg(s)).skipped for s in (14, 12, 12, 13)) == 0  # a duplicate late one takes back nothing more


def test_a_real_gap_still_counts_and_a_far_stray_is_still_undone():
    h = _rsi()
    outs = [h(_rob(i)) for i in (1000, 1004, 1016, 1020)]  # 1008, 1012 never came
    assert sum(o.skipped for o in outs) == 2
    outs = [h(_rob(i)) for i in (1024, 1024 + 400, 1028, 1032, 1036)]  # a stray 400 ms ahead
    assert h.stray_jumps == 1 and sum(o.skipped for o in outs if o.reply is not None) == 0


def test_the_bridge_counts_a_late_reordered_datagram_back_out_of_the_skipped_cycles():
    """The bridge adds the (negative) skipped cycles of a dropped late datagram too."""
    import threading

    from hykin.realtime.udp_bridge import run_bridge

    with bind_udp("127.0.0.1", 0) as rx, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx:
        tx.bind(("127.0.0.1", 0))
        stop, box = threading.Event(), {}
        th = threading.Thread(target=lambda: box.update(st=run_bridge(rx, _rsi(), period_s=0.004, stop=stop,
                                                                      controller=tx.getsockname())))
        th.start()
        try:
            for i in (1000, 1004, 1016, 1008, 1012, 1020):
                tx.sendto(_rob(i), rx.getsockname())
                tx.recvfrom(4096) if i not in (1008, 1012) else None  # (wait for the answer where one comes)
            tx.sendto(_rob(1024), rx.getsockname())
            tx.recvfrom(4096)
        finally:
            stop.set()
            th.join(5)
    st = box["st"]
    # (1008 and 1012 are dropped as stale, alone or, read with 1020, superseded: the controller skipped nothing)
    assert st.answered == 5 and st.skipped_cycles == 0, st


# ---- D3 / D4: counts of a drain ----------------------------------------------------------------------------

def test_a_malformed_datagram_read_with_a_valid_one_is_counted_malformed():
    """Probe AW D3: an EgmRobot missing pos.z, read in the same drain as the valid datagram of its seqno (and
    never tried: the valid one was answered first), was counted 'superseded'."""
    bad = _without("planned.cartesian.pos.z")  # seqno 5
    batches = [[_msg(3)], [_msg(4)], [bad, _msg(5)], [_msg(6), _msg(5)], [_msg(7)]]
    with bind_udp("127.0.0.1", 0) as rx:
        ctrl = _Controller(_egm(), batches, rx.getsockname(), lambda r: parse_sensor(r)[0])
        st = _serve(ctrl, rx)
    assert ctrl.answered == [3, 4, 5, 6, 7], ctrl.answered
    assert st.ignored["malformed"] == 1 and st.ignored["superseded"] == 1, st.ignored


def test_cycles_passed_over_in_a_burst_are_not_skipped_by_the_controller():
    """Probe AW D4: cycles the bridge read in a burst and passed over (it answered the newest) were counted
    'cycles skipped by the controller'."""
    r = _rob
    batches = [[r(1000)], [r(1004), r(1008), r(1012)], [r(1024)]]  # 1016, 1020: never sent
    with bind_udp("127.0.0.1", 0) as rx:
        ctrl = _Controller(_rsi(), batches, rx.getsockname(), lambda b: parse_sen(b, RsiConfig())[0])
        st = _serve(ctrl, rx)
    assert ctrl.answered == [1000, 1012, 1024], ctrl.answered
    assert st.skipped_cycles == 2 and st.passed_over == 2 and st.ignored["superseded"] == 2, st
    assert "cycles skipped by the controller 2, cycles passed over by the bridge (a newer one answered) 2" in st.summary()
