"""``hykin rsi``: a KUKA RSI Ethernet peer that corrects the setpoint every cycle with the model.

Per message (:mod:`.rsi_xml`): the setpoint ``RSol`` (controller base frame) is compensated on the
branch of the axis positions ``AIPos`` (:meth:`hykin.compensation.compensator.Compensator.step`,
warm-started from them); the answer ``RKorr`` is the command minus the setpoint, componentwise
(X Y Z mm; A B C deg, each difference wrapped to ±180°, of the command's two A B C solutions the
one nearer the setpoint's, see :func:`korr_of`): a controller that adds it to the setpoint
and runs its nominal model moves the real robot (per the model) onto the setpoint. Absolute mode
sends that correction; incremental mode sends its change since the last answer (RSI adds it up).

* A message that cannot be parsed, or whose ``IPOC`` is not after the last answered one (a repeat,
  an old or foreign message), is not answered; except a controller that restarted: two consecutive
  messages more than ``RESTART_BEHIND_MS`` behind that follow each other start a new count
  (:class:`hykin.realtime.udp_bridge.RestartWatch`; incremental mode starts its sum again).
* A setpoint that cannot be compensated (no solution, a correction over the limits: the position
  shift in mm and the rotation angle between setpoint and command in degrees, any internal
  error) is answered with a zero correction and its ``IPOC``: the robot goes on uncorrected (absolute
  mode: at the setpoint; incremental: keeping the corrections so far). After ``max_failures`` in a
  row :func:`hykin.realtime.udp_bridge.run_bridge` stops answering and RSI's timeout stops the robot.
* Cycles the controller skipped are counted from the ``IPOC`` gaps (``period_ms`` per cycle).
"""

from __future__ import annotations

import itertools
import logging

import numpy as np

from ..compensation.krl import abc_from_matrix, matrix_from_abc
from ..geometry import se3
from .rsi_xml import RsiConfig, format_sen, ipoc_of, parse_rob
from .udp_bridge import (MAX_MISMATCH_DEG, MAX_MISMATCH_MM, REORDER_CYCLES, GapLedger, JumpWatch, Outcome,
                         RestartWatch, check_actual_pose, check_limits)

__all__ = ["DECIMALS", "DEFAULT_RIST_LAG_CYCLES", "MAX_MISMATCH_DEG", "MAX_MISMATCH_MM", "RsiHandler", "korr_of", "pose_of"]

DECIMALS = 5  # of RKorr as written (mm, deg)
RESTART_BEHIND_MS = 1000  # an IPOC this far behind (or ahead of) the last answered one may be a new RSI context
RESYNC_TOL = 2e-3  # mm / deg: RIst's sum and hykin's agree within this (both written with 5-6 decimals)
#: RIst may show the command of the last cycle or of up to this many cycles before it (a dead time, e.g. a
#: servo delay of 16 ms at 4 ms): the default of ``--rist-lag-cycles``
DEFAULT_RIST_LAG_CYCLES = 4
MAX_RIST_LAG_CYCLES = 25  # the largest --rist-lag-cycles accepted (100 ms at 4 ms)
MAX_DEAD_CYCLES = DEFAULT_RIST_LAG_CYCLES  # (the name before probe AW)
#: a RIst difference must last this many cycles to be taken as answers not applied or a new context: one
#: more than the RIst lag handled, which shows an applied answer missing for at most that many cycles (probe
#: AW A2: with a confirmation of 3, a lag of 3 was taken for a lost first answer and the correction sent twice)
RESYNC_CONFIRM_CYCLES = DEFAULT_RIST_LAG_CYCLES + 1
_MAX_PENDING = 4  # answers not yet seen applied that a re-synchronisation considers (2^4 subsets)
_log = logging.getLogger("hykin.realtime")
_CAUSES = ("RIst mismatch:", "unreachable setpoint:", "correction over the limit:")  # failure reasons' categories


def pose_of(xyzabc) -> np.ndarray:
    """``(4, 4)`` pose (m) of ``X Y Z`` mm, ``A B C`` deg."""
    v = np.asarray(xyzabc, dtype=np.float64)
    return se3.make_transform(matrix_from_abc(v[3], v[4], v[5]), v[:3] * 1e-3)


def _wrap(d):
    """Angles (deg) wrapped to ``[-180, 180)``."""
    return (np.asarray(d, dtype=np.float64) + 180.0) % 360.0 - 180.0


def korr_of(command: np.ndarray, setpoint) -> np.ndarray:
    """``(6,)`` componentwise correction (mm, deg) from ``setpoint`` (X..C) to the pose ``command``
    ``(4, 4)`` (m): ``setpoint + korr`` (angles modulo 360°) describes ``command``.

    Of the command's two ``A B C`` solutions, ``(A, B, C)`` (``|B| <= 90``) and ``(A+180, 180-B,
    C+180)``, the one nearer the setpoint's (least sum of squared wrapped differences) is used: the
    same as the first wherever ``B`` is away from ±90°, and across ``B = ±90°`` the one that does not
    flip ``A`` and ``C`` by 180°. Near ``B = ±90°`` (gimbal lock) a small rotation may still need large
    ``dA``, ``dC`` (with ``A ∓ C`` nearly kept): the limits of :class:`RsiHandler` are therefore on the
    real rotation angle, not on these components."""
    sp = np.asarray(setpoint, dtype=np.float64)
    a, b, c = abc_from_matrix(command[:3, :3], sp[3])
    d = _wrap(np.array([a, b, c]) - sp[3:])
    d2 = _wrap(np.array([a + 180.0, 180.0 - b, c + 180.0]) - sp[3:])
    if float(np.sum(d2 * d2)) < float(np.sum(d * d)):
        d = d2
    return np.concatenate([command[:3, 3] * 1e3 - sp[:3], d])


class RsiHandler:
    """The per-message work of ``hykin rsi`` (an ``Outcome``-returning callable for
    :func:`hykin.realtime.udp_bridge.run_bridge`).

    step: ``(T (4, 4) in the compensator's frame, q_prev (n,) rad) -> StepResult`` (a warm
    ``Compensator.step``). base: ``(4, 4)`` maps the controller base frame into the compensator's
    target frame (the nominal base for frame ``"measurement"``, identity for ``"base"``). dof,
    axis_signs (``A = sign · q``), cfg (:class:`RsiConfig`), period_ms: the controller's cycle.
    max_correction_mm / max_correction_deg: a larger correction is treated as a failure.
    nominal_fk: ``q (n,) rad -> (4, 4)`` the nominal TCP pose in the controller's base frame (RIst's);
    when given, every message's ``RIst`` is checked against it, and one farther than
    ``max_mismatch_mm`` / ``max_mismatch_deg`` (20 mm / 2°: far above the nominal model's own error of a
    few mm) is a failure naming the likely cause (axis signs, robot file, tool or base frame).
    Incremental mode: a restarted RSI context (IPOC behind, confirmed by two messages) starts the sum
    again; a new context after an IPOC jump ahead, and an answer the controller did not apply, are seen
    in ``RIst`` and hykin's sum follows (:meth:`_resync`). rist_lag_cycles: how many cycles RIst may lag
    (the command of the last cycle or of up to that many before it); a larger lag is taken for lost
    answers (the correction sent again).
    """

    def __init__(self, step, base: np.ndarray, dof: int, axis_signs, cfg: RsiConfig, period_ms: float = 4.0,
                 max_correction_mm: float = 50.0, max_correction_deg: float = 5.0, nominal_fk=None,
                 max_mismatch_mm: float = MAX_MISMATCH_MM, max_mismatch_deg: float = MAX_MISMATCH_DEG,
                 rist_lag_cycles: int = DEFAULT_RIST_LAG_CYCLES):
        check_limits(max_correction_mm=max_correction_mm, max_correction_deg=max_correction_deg,
                     max_mismatch_mm=max_mismatch_mm, max_mismatch_deg=max_mismatch_deg, period_ms=period_ms)
        if isinstance(rist_lag_cycles, bool) or not isinstance(rist_lag_cycles, (int, np.integer)) or \
                not 0 <= rist_lag_cycles <= MAX_RIST_LAG_CYCLES:
            raise ValueError(f"--rist-lag-cycles must be a whole number 0..{MAX_RIST_LAG_CYCLES}, got {rist_lag_cycles!r}")
        self.rist_lag = int(rist_lag_cycles)
        self.step, self.base, self.dof, self.cfg = step, np.asarray(base, dtype=np.float64), dof, cfg
        self.signs = np.asarray(axis_signs, dtype=np.float64)
        self.period_ms = float(period_ms)
        self.max_mm, self.max_deg = float(max_correction_mm), float(max_correction_deg)
        self.nominal_fk = nominal_fk
        self.max_mismatch = (float(max_mismatch_mm), float(max_mismatch_deg))
        self.mismatch_max = (0.0, 0.0)  # the largest RIst - FK(AIPos) seen (mm, deg)
        self.mismatch_checked = 0
        self.last_ipoc: int | None = None
        self.restart = RestartWatch(RESTART_BEHIND_MS, int(10 * max(self.period_ms, 1.0)))
        self.sent_sum = np.zeros(6)  # incremental mode: what the controller has added up
        self._context = None  # incremental mode: [hykin's sum before an IPOC jump ahead, the jump's increment, answers since]
        self.lost_answers = 0  # incremental mode: re-synchronisations on answers RIst showed not applied
        self.new_sessions = 0
        self._retired: int | None = None  # the last IPOC answered before the latest restart
        self.strays = JumpWatch(RESTART_BEHIND_MS, int(10 * max(self.period_ms, 1.0)))  # a stray stamp ahead
        self._pending: list = []  # incremental mode: increments sent since RIst last showed the sum
        self._suspect = None  # incremental mode: (kind, difference, cycles seen, dead time) not yet taken (_resync)
        self._hist: list = []  # incremental mode: (setpoint, hykin's sum after the answer) of the last answers
        self._confirm = self.rist_lag + 1
        self.gaps = GapLedger(self.period_ms)  # gaps counted as skipped that a late datagram may fill
        self.stray_jumps = 0  # jumps ahead that were one stray datagram (undone)
        self.last_reason = ""

    @property
    def incremental(self) -> bool:
        return self.cfg.mode == "incremental"

    def check_actual(self, actual, q) -> None:
        """ValueError when the controller's actual pose ``RIst`` (X..C) is farther than the bound from
        the nominal FK of the axes ``q`` (rad, model joints): the controller's axes, robot or frames are
        not the ones hykin compensates for (:func:`hykin.realtime.udp_bridge.check_actual_pose`)."""
        if actual is None or self.nominal_fk is None:
            return
        self.mismatch_checked += 1
        self.mismatch_max, why = check_actual_pose(self.nominal_fk, q, pose_of(actual), self.max_mismatch,
                                                   self.mismatch_max, ("RIst", "RIst", "AIPos"))
        if why:
            raise ValueError(why)

    def correction(self, setpoint, axes_deg, actual=None) -> np.ndarray:
        """The absolute correction ``(6,)`` for one setpoint (ValueError with the reason on failure)."""
        q = np.radians(np.asarray(axes_deg, dtype=np.float64)) * self.signs
        self.check_actual(actual, q)
        r = self.step(self.base @ pose_of(setpoint), q)
        if not r.success:
            raise ValueError(f"unreachable setpoint: not compensated ({r.reason})")
        k = korr_of(r.command, setpoint)
        # the limits are on the real shift and rotation (as ``hykin egm``): near B = ±90° a tiny rotation
        # has large componentwise dA, dC
        dp, da = se3.pose_error(np.asarray(r.command, dtype=np.float64)[None], pose_of(setpoint)[None])
        if not (np.isfinite(k).all() and dp[0] <= self.max_mm and da[0] <= self.max_deg):
            raise ValueError(f"correction over the limit: {dp[0]:.2f} mm / {da[0]:.3f} deg (--max-correction-mm "
                             f"{self.max_mm:g}, --max-correction-deg {self.max_deg:g})")
        return k

    def _resync(self, msg, skipped: int) -> None:
        """Incremental mode: the sum the controller applied, seen in this message's ``RIst`` (the pose it
        commanded in an earlier cycle: that cycle's setpoint plus the controller's sum), against hykin's.
        ``RIst`` may show the command of the last cycle or, with a lag, of up to ``rist_lag_cycles`` cycles
        before it: it is compared with hykin's sum as of each of those answers, and one that agrees (within
        ``RESYNC_TOL``) means every answer up to it was applied (probe s42 AS: compared with the last answer
        only, a lag of one cycle on a moving path hid a lost first answer for good). Otherwise a difference
        equal to answers not yet seen applied (any of the last :data:`_MAX_PENDING` that the compared cycle
        can show) means the controller did not apply them (lost or late); within a few cycles after an IPOC
        jump of over 1 s, a difference equal to hykin's sum before the jump, seen in a cycle after it, means a
        new RSI context (its sum started at zero; probe AW A1: looked for only in the message right after the
        jump, a lagging RIst never showed it and the path ran uncorrected). hykin's sum drops that amount,
        but only once the same difference has lasted ``rist_lag_cycles + 1`` cycles: a lag of L cycles shows
        an applied answer missing for L cycles (probe AW A2: confirmed after 3, a lag of 3 took the first
        answer for lost and sent the whole correction again, 5.95 mm off). Any other difference (e.g. a
        measured ``RIst`` that lags by less than a cycle's command) leaves the sum as it is."""
        hist, ctx = self._hist, self._context
        if not hist or msg.actual is None or skipped:
            return  # (after a gap RIst is of a setpoint not seen: the answers so far stay pending)
        actual = pose_of(msg.actual)
        ds = []  # RIst's sum minus hykin's as of the answer j cycles before the last
        for j in range(min(len(hist), self.rist_lag + 1)):
            setpoint, total = hist[-1 - j]
            d = korr_of(actual, setpoint) - total
            d[3:] = _wrap(d[3:])
            if np.all(np.abs(d) <= RESYNC_TOL):  # every answer up to that one applied; the last j not shown yet
                self._pending, self._suspect = (self._pending[-j:] if j else []), None
                return
            ds.append(d)
        close = lambda d, c: bool(np.all(np.abs(np.concatenate([(d + c)[:3], _wrap((d + c)[3:])])) <= RESYNC_TOL))
        seen = None if self._suspect is None else next((j for j, d in enumerate(ds) if close(d, self._suspect[1])), None)
        if seen is not None:
            kind, c, n, _ = self._suspect
            self._suspect = (kind, c, n + 1, seen)
        else:
            cands = []
            for j in range(len(ds)):
                # the answers not yet seen applied that the command j cycles back can show: any of them may have
                # been lost or late (probe s41 AH: a first answer 1 s late, then a gap, left the whole 4.3 mm
                # correction counted but never applied)
                shown = self._pending[:max(len(self._pending) - j, 0)][-_MAX_PENDING:]
                cands += [("lost", sum(c), j) for r in range(1, len(shown) + 1) for c in itertools.combinations(shown, r)]
                if ctx is not None and j <= ctx[2]:  # the cycle compared is the jump's or later: in the new context
                    cands += [("context", ctx[0], j), ("context", ctx[0] + ctx[1], j)]
            hit = next(((kind, c, j) for kind, c, j in cands if np.any(np.abs(c) > RESYNC_TOL) and close(ds[j], c)), None)
            self._suspect = None if hit is None else (hit[0], hit[1], 1, hit[2])
        if self._suspect is None or self._suspect[2] < self._confirm:
            return
        kind, c, _, j = self._suspect
        self.sent_sum = self.sent_sum - c
        self._hist = [(setpoint, total - c) for setpoint, total in self._hist]
        self._pending, self._suspect = (self._pending[-j:] if j else []), None
        if kind == "context":
            self.new_sessions += 1
            self._context = None
            _log.warning("hykin rsi: incremental mode: RIst shows a new RSI context (its sum restarted at zero) after an "
                         "IPOC jump; hykin's sum re-synchronised")
            return
        self.lost_answers += 1
        if self.lost_answers == 1 or self.lost_answers % 100 == 0:
            _log.warning("hykin rsi: incremental mode: RIst has shown the controller's sum without answers hykin sent for "
                         "%d cycles (lost or late; or RIst lags more than --rist-lag-cycles %d); hykin's sum "
                         "re-synchronised (%d so far)", self._confirm, self.rist_lag, self.lost_answers)

    def leftover(self, data: bytes) -> tuple[str, int]:
        """For the counts of :func:`hykin.realtime.udp_bridge.run_bridge`, a datagram read with the one just
        answered and never tried: ``("malformed", 0)`` when it cannot be parsed, else ``("superseded", 1)``
        when its cycle was counted as skipped (the bridge passed over it: taken back out), else
        ``("superseded", 0)``. It is not answered and changes nothing else."""
        try:
            msg = parse_rob(data, self.cfg, self.dof)
        except ValueError:
            return "malformed", 0
        return "superseded", self.gaps.fill(msg.ipoc)

    def cycle_key(self, data: bytes) -> float | None:
        """How many ms the ``IPOC`` of ``data`` lies after the last answered one, for
        :func:`hykin.realtime.udp_bridge.run_bridge` to try the newest of several waiting datagrams first:
        None without an ``IPOC``; ``-inf`` over ``RESTART_BEHIND_MS`` ahead (maybe a stray: tried last)."""
        ipoc = ipoc_of(data)
        if ipoc is None:
            return None
        d = ipoc - (self.last_ipoc or 0)
        return float("-inf") if self.last_ipoc is not None and d > RESTART_BEHIND_MS else float(d)

    def _skipped(self, ipoc: int) -> int:
        """Cycles between the last answered ``IPOC`` and ``ipoc`` (by ``period_ms``)."""
        return max(int(round((ipoc - self.last_ipoc) / self.period_ms)) - 1, 0)

    def __call__(self, data: bytes) -> Outcome:
        try:
            msg = parse_rob(data, self.cfg, self.dof)
        except ValueError as e:  # RsiMessageError, and any other conversion error: never a crash on bad input
            self.last_reason = str(e)
            return Outcome(None, "ignored:malformed")
        new_session, jump_sum, jumped, back, undo = False, None, False, None, 0
        if self.last_ipoc is not None and 0 < self.last_ipoc - msg.ipoc <= REORDER_CYCLES * self.period_ms:
            # a few cycles behind: a late, reordered datagram, whose cycle is over. Not a sign that the answered
            # one was a stray (probe AW A3: cycles k+2, k, k+1 one by one undid k+2's applied answer and answered
            # k+1 after it); a cycle counted as skipped when the newer one came is taken back out (AW D1)
            return Outcome(None, "ignored:stale IPOC", -self.gaps.fill(msg.ipoc))
        if self.last_ipoc is not None and msg.ipoc <= self.last_ipoc:
            back = self.strays.returned(msg.ipoc)
            if back is not None:
                state, undo = back
                # the session before a jump ahead goes on: the jump was one stray datagram (a corrupted stamp),
                # whose answer the controller never took (its IPOC was not the cycle's): undo it, or an
                # incremental sum would be started again and counted twice (probe s41 AH: 4.3 mm), and the
                # session's cycles stay unanswered until their stamps pass the stray's (s41 AM: 100 cycles)
                self.last_ipoc, self.sent_sum, self._context, self._pending, self._hist = state
                self.gaps.clear()  # (the stray's jump was no gap)
                self.stray_jumps += 1
                _log.warning("hykin rsi: a datagram with IPOC ahead of the session was a stray (the session goes on "
                             "from IPOC %d): its answer is undone", state[0])
            elif not self.restart.restarted(msg.ipoc, self.last_ipoc - msg.ipoc):
                return Outcome(None, "ignored:stale IPOC")
            else:
                new_session = True
        elif self.last_ipoc is not None and msg.ipoc - self.last_ipoc > RESTART_BEHIND_MS:
            # over 1 s ahead. Within 1 s of the stamps of a session before a restart it may be a stray
            # datagram of that session: like a restart, two consecutive messages that follow each other
            # confirm it, one alone stays dropped. Otherwise answered at once (the same session, or a new
            # RSI context whose sum the next message's RIst shows: :meth:`_resync`)
            if self._retired is not None and msg.ipoc <= self._retired + RESTART_BEHIND_MS and \
                    not self.restart.restarted(msg.ipoc, msg.ipoc - self.last_ipoc):
                return Outcome(None, "ignored:IPOC jump")
            jump_sum, jumped = self.sent_sum.copy(), True
        elif self.last_ipoc is not None and msg.ipoc - self.last_ipoc <= 2 * self.period_ms:
            self.strays.clear()  # in order after a jump: the jump was real (skipped cycles, a new context)
        if back is None and self.last_ipoc is not None and msg.ipoc - self.last_ipoc > 2 * self.period_ms:
            jumped = jumped or msg.ipoc - self.last_ipoc > RESTART_BEHIND_MS
            ctx = None if self._context is None else list(self._context)
            self.strays.jumped(self.last_ipoc, (self.last_ipoc, self.sent_sum.copy(), ctx, list(self._pending),
                                                list(self._hist)),
                               0 if jumped else self._skipped(msg.ipoc))
        if new_session:  # a new RSI context: its own count and sum
            self._retired = max(self.last_ipoc, self._retired or 0)
            self.last_ipoc, self.sent_sum, self._context, self._pending, self._hist = None, np.zeros(6), None, [], []
            self.gaps.clear()
            self.new_sessions += 1
        self.restart.clear()
        skipped = 0 if self.last_ipoc is None else self._skipped(msg.ipoc)
        if skipped and not jumped and back is None:
            self.gaps.add(self.last_ipoc, skipped)
        self.last_ipoc = msg.ipoc
        if self.incremental:
            self._resync(msg, skipped)
        if jumped:  # a jump of the stamps (a new context or a stray), not cycles the controller skipped
            skipped = 0
        skipped -= undo  # a stray undone: the cycles counted for its jump were not skipped (udp_bridge.JumpWatch)
        try:
            k = self.correction(msg.setpoint, msg.axes_deg, msg.actual)
            kind, why = "ok", ""
        except Exception as e:  # noqa: BLE001 - any internal failure: neutral answer, the robot goes on
            why = str(e) if str(e).startswith(_CAUSES) else f"internal error: {type(e).__name__}: {e}"
            self.last_reason = why
            k, kind = None, "failure"
        if self.incremental:  # the sum as the controller adds it: of the values as written
            if k is None:
                send = np.zeros(6)
            else:  # angle increments modulo 360° (the controller's sum describes the same pose)
                inc = k - self.sent_sum
                inc[3:] = np.where(np.abs(inc[3:]) > 180.0, _wrap(inc[3:]), inc[3:])
                send = np.round(inc, DECIMALS)
            self.sent_sum = self.sent_sum + send
            if jump_sum is not None:  # a new context may have begun: RIst shows it within the lag (_resync)
                self._context = [jump_sum, send, 0]
            elif self._context is not None:  # looked for until a difference could have been confirmed, with margin
                self._context[2] += 1
                if self._context[2] > 2 * (self.rist_lag + 1) + 2:
                    self._context = None
            self._pending = (self._pending + [send])[-4 * _MAX_PENDING:]
            self._hist = (self._hist + [(msg.setpoint, self.sent_sum)])[-(self.rist_lag + 1):]
        else:
            send = np.zeros(6) if k is None else k
        return Outcome(format_sen(msg.ipoc, send, self.cfg), kind, skipped, why)
