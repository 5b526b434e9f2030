"""The UDP loop shared by the controller bridges (:mod:`.rsi`, :mod:`.egm`).

One socket, one controller. Per datagram: drop it when it is over the size limit (truncated by the
kernel), when it comes from another sender than the controller (the first sender whose message was
valid, or the address given), when the protocol handler calls it invalid or stale, or when a newer
cycle of the controller, read with it, is answered instead (superseded: its cycle is over); else answer
it at once with the handler's reply. Counted: answered, failures (the handler could not compute
and answered a neutral message), late answers (sent more than one period after the datagram
arrived, by the kernel's receive time stamp), cycles the controller skipped (by its stamps) and
every kind of dropped datagram (one read with the answered cycle and never tried: by what the handler's
``malformed`` says of it once the answer is sent, else "unread"). After ``max_failures`` consecutive
failures the loop stops answering and returns, so that the controller's own timeout stops the robot.
"""

from __future__ import annotations

import gc
import logging
import math
import platform
import select
import socket
import struct
import sys
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

__all__ = ["GapLedger", "JumpWatch", "REORDER_CYCLES", "StampRun", "MAX_MISMATCH_DEG", "MAX_MISMATCH_MM", "BridgeStats",
           "Outcome", "RestartWatch", "SO_TIMESTAMPNS", "arrival_time", "bind_udp", "check_actual_pose", "check_limits",
           "enable_timestamps", "parse_listen", "raise_priority", "run_bridge", "stamp_ahead"]

_log = logging.getLogger("hykin.realtime")
_DRAIN = 256  # datagrams read at most per turn when behind
_CLASSIFY = 16  # datagrams left over from a drain that are parsed (after the answer is sent) to count them right
#: a stamp at most this many cycles behind the last answered one is a late (reordered) datagram: dropped,
#: and never taken as a sign that the answered one was a stray (probe AW A3: cycles k+2, k, k+1 arriving one by
#: one had k+2's applied answer undone and k+1 answered after it)
REORDER_CYCLES = 4


def _so_timestamps() -> int | None:
    """The ``SO_TIMESTAMPNS`` socket option (= ``SCM_TIMESTAMPNS``), None where the platform has none."""
    if hasattr(socket, "SO_TIMESTAMPNS"):
        return socket.SO_TIMESTAMPNS
    # CPython 3.11 does not export the name, although Linux has had the option since 2.6.22 (probe s42 AT:
    # every answer was timed from when the bridge read its datagram, and late ones went uncounted). 35 is
    # asm-generic's value (x86, arm, riscv, powerpc, s390, mips); alpha, parisc and sparc number it otherwise
    if sys.platform.startswith("linux") and not platform.machine().lower().startswith(("alpha", "parisc", "sparc")):
        return 35
    return None


#: the socket option that makes the kernel stamp each received datagram (None: not on this platform)
SO_TIMESTAMPNS = _so_timestamps()


@dataclass
class Outcome:
    """What the handler made of one datagram. reply: bytes to send back (None: send nothing).
    kind: ``"ok"``, ``"failure"`` (reply is the protocol's neutral answer) or ``"ignored:<why>"``.
    skipped: cycles the controller's stamp says were skipped before this one."""

    reply: bytes | None
    kind: str
    skipped: int = 0  # negative: a correction of cycles counted before (a stray jump undone: JumpWatch)
    reason: str = ""  # a failure's one-line cause, its category first ("correction over the limit: ...")


def stamp_ahead(a: int, b: int, modulo: int | None = None) -> int:
    """``a - b`` in counts of a stamp (``IPOC``, ``seqno``), wrapped into ``[-modulo/2, modulo/2)`` for
    stamps that wrap (``modulo``: EGM's 2^32; None: they do not)."""
    d = int(a) - int(b)
    return d if modulo is None else (d + modulo // 2) % modulo - modulo // 2


class StampRun:
    """Consecutive stamps (``IPOC``, ``seqno``) each following the previous by 1 to ``step`` counts: what
    confirms a restart (:class:`RestartWatch`) or a stray jump (:class:`JumpWatch`) where one message alone
    may be a stray or a late datagram. ``modulo``: stamps that wrap (EGM's 32-bit seqno)."""

    def __init__(self, step: int, confirm: int = 2, modulo: int | None = None):
        self.step, self.confirm, self.modulo = int(step), int(confirm), modulo
        self._run: list[int] = []

    def ahead(self, a: int, b: int) -> int:
        """``a - b`` (:func:`stamp_ahead`)."""
        return stamp_ahead(a, b, self.modulo)

    def __len__(self) -> int:
        """Stamps of the run so far (not yet confirmed)."""
        return len(self._run)

    def add(self, stamp: int) -> bool:
        """Whether ``stamp`` completes a run of ``confirm`` (then the run starts again)."""
        if self._run and not 0 < self.ahead(stamp, self._run[-1]) <= self.step:
            self._run = []
        self._run.append(int(stamp))
        if len(self._run) < self.confirm:
            return False
        self._run = []
        return True

    def clear(self) -> None:
        self._run = []


class RestartWatch:
    """A controller that restarts (a new RSI context, an EGM session started again) counts its stamp
    (``IPOC``, ``seqno``) from a value far behind the last answered one. One such message is not enough
    (a stray old or foreign datagram): a restart is taken when ``confirm`` consecutive messages lie
    more than ``behind`` counts behind and each follows the previous by 1 to ``step`` counts."""

    def __init__(self, behind: int, step: int, confirm: int = 2):
        self.behind = int(behind)
        self._run = StampRun(step, confirm)

    def restarted(self, stamp: int, behind_by: int) -> bool:
        """Whether ``stamp``, ``behind_by`` counts behind the last answered one, confirms a restart."""
        if behind_by <= self.behind:
            self._run.clear()
            return False
        return self._run.add(stamp)

    def clear(self) -> None:
        """An in-order message was answered: no restart under way."""
        self._run.clear()


class JumpWatch:
    """A stray datagram with a stamp ahead of the session (a corrupted ``IPOC`` or ``seqno``) is answered like
    any message ahead; the session's next messages then lie behind it. Where ``confirm`` consecutive ones,
    following each other by 1 to ``step`` counts, continue the session from before the jump (at most
    ``window`` counts after its last stamp), the jump was the stray: :meth:`returned` gives the state saved
    before it (probe s41 AM: one stamp 400 ms ahead left the next 100 cycles unanswered, an EGM path 47 mm
    off), and how many cycles counted as skipped to take back (probe s42 AT: one stray 100,000 ahead left
    "cycles skipped by the controller 100030"). One message behind alone stays dropped (a late, reordered
    datagram must not undo an answer the controller took). ``modulo``: stamps that wrap (EGM's 32-bit seqno)."""

    def __init__(self, window: int, step: int, confirm: int = 2, modulo: int | None = None):
        self.window = int(window)
        self._before = None
        self._run = StampRun(step, confirm, modulo)

    def jumped(self, before: int, state, skipped: int = 0) -> None:
        """The message just answered jumped ahead of ``before`` (the last stamp of the session so far,
        whose ``state`` a return restores) and was counted with ``skipped`` cycles (what a return takes back)."""
        self._before = (int(before), state, int(skipped))
        self._run.clear()

    def clear(self) -> None:
        """A message in order after the jump: it was real."""
        self._before = None
        self._run.clear()

    def returned(self, stamp: int):
        """For a message behind the last answered one: once ``confirm`` consecutive such messages continue
        the session from before the jump, ``(state saved before it, undo)``, else None. ``undo``: cycles to
        take back from the count of skipped ones: those counted for the stray, and the messages of the run
        before this one (dropped as stale: the controller sent them). The caller counts this message's own
        gap from the restored stamp as usual and subtracts ``undo``."""
        if self._before is None or not 0 < self._run.ahead(stamp, self._before[0]) <= self.window:
            self._run.clear()
            return None
        seen = len(self._run)
        if not self._run.add(stamp):
            return None
        _, state, skipped = self._before
        self.clear()
        return state, skipped + seen


class GapLedger:
    """The last few gaps of the stamps that were counted as cycles skipped by the controller, so that a
    datagram of such a cycle that comes late (reordered, :data:`REORDER_CYCLES`), or was read with the answer
    that counted the gap, takes its cycle back out of the count, once (probe AW D1: reordering counted as
    skipped cycles; D4: cycles the bridge passed over in a burst too). Stamps in counts (``per`` counts a
    cycle: RSI's ``IPOC`` ms per period, EGM's ``seqno`` 1); ``modulo``: stamps that wrap."""

    def __init__(self, per: float = 1.0, modulo: int | None = None, keep: int = 4):
        self.per, self.modulo, self.keep = float(per), modulo, int(keep)
        self._gaps: list = []  # [stamp before the gap, cycles in it, cycles filled since]

    def add(self, before: int, cycles: int) -> None:
        """``cycles`` (> 0) skipped after the stamp ``before``."""
        if cycles > 0:
            self._gaps = (self._gaps + [[int(before), int(cycles), set()]])[-self.keep:]

    def fill(self, stamp: int) -> int:
        """1 when ``stamp`` is a cycle of a gap counted before and not filled yet (it came late), else 0."""
        for before, cycles, filled in self._gaps:
            i = int(round(stamp_ahead(stamp, before, self.modulo) / self.per))
            if 1 <= i <= cycles and i not in filled:
                filled.add(i)
                return 1
        return 0

    def clear(self) -> None:
        self._gaps = []


@dataclass
class BridgeStats:
    """Counts of one bridge run (see the module docstring); ``stopped``: why the loop ended."""

    answered: int = 0
    failures: int = 0
    late: int = 0
    stamped: int = 0  # answers timed by the kernel's receive stamp (the others: by when the datagram was read)
    skipped_cycles: int = 0  # by the gaps of the stamps, less the cycles the bridge passed over itself
    passed_over: int = 0  # cycles read in a burst and not answered because a newer one of the same drain was
    ignored: Counter = field(default_factory=Counter)
    max_consecutive_failures: int = 0
    latency_s: list = field(default_factory=list)
    stopped: str = ""

    def summary(self) -> str:
        ign = ", ".join(f"{k} {v}" for k, v in sorted(self.ignored.items()) if v) or "none"
        # without kernel stamps an answer is timed from when the bridge read its datagram: a lower bound
        how = " (timed from reading: no kernel receive stamps)" if self.answered and not self.stamped else ""
        # (the controller did send those: the bridge answered a newer cycle read with them, probe AW D4)
        over = f", cycles passed over by the bridge (a newer one answered) {self.passed_over}" if self.passed_over else ""
        return (f"answered {self.answered} (failures answered neutrally {self.failures}), late {self.late}{how}, "
                f"cycles skipped by the controller {self.skipped_cycles}{over}, dropped: {ign}")


def check_limits(**limits) -> None:
    """ValueError naming the option when a bridge limit is not a finite number above 0 (``idle_exit_s``:
    at least 0). Keywords are option names with ``_`` for ``-`` (``max_correction_mm=50.0``)."""
    for name, v in limits.items():
        opt = "--" + name.replace("_", "-")
        low_ok = (v >= 0) if name == "idle_exit_s" else (v > 0)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and low_ok):
            need = "a finite number >= 0" if name == "idle_exit_s" else "a finite number > 0"
            raise ValueError(f"{opt} must be {need}, got {v!r}")


#: the controller's actual pose this far from the nominal FK of its joints (mm, deg) is a set-up error
#: (axis signs, robot file, tool or base frame), not the nominal model's own error (a few mm at most)
MAX_MISMATCH_MM, MAX_MISMATCH_DEG = 20.0, 2.0


def check_actual_pose(nominal_fk, q: np.ndarray, actual: np.ndarray, bound: tuple[float, float],
                      worst: tuple[float, float], names: tuple[str, str, str]) -> tuple[tuple[float, float], str]:
    """The controller's actual pose ``actual`` ``(4, 4)`` against the nominal FK of its joints ``q`` (rad).
    Returns ``worst`` (largest gap so far: mm, deg) updated with this one, and ``""`` within ``bound``
    (mm, deg), else the reason, starting with ``"<names[0]> mismatch:"``. ``names``: the category, the
    actual pose's field and the joints' field as the protocol names them (RSI: ``RIst``, ``RIst``, ``AIPos``)."""
    from ..geometry import se3

    dp, da = se3.pose_error(np.asarray(nominal_fk(q), dtype=np.float64)[None], np.asarray(actual)[None])
    dp, da = float(dp[0]), float(da[0])
    worst = (max(worst[0], dp), max(worst[1], da))
    mm, deg = bound
    if dp <= mm and da <= deg:
        return worst, ""
    return worst, (f"{names[0]} mismatch: the controller's actual pose {names[1]} is {dp:.1f} mm / {da:.2f} deg from "
                   f"the nominal FK of {names[2]} (bound {mm:g} mm / {deg:g} deg, --max-mismatch-mm/-deg): the axis "
                   f"signs (--axis-signs), the robot file, or the controller's tool or base frame differ from hykin's")


def _causes(reasons: Counter, last: dict) -> str:
    """``reasons`` (failure category -> count) and the last reason of each, as one clause."""
    return "; ".join(f"{n} x {last[c]}" for c, n in reasons.most_common()) or "no reason recorded"


def parse_listen(text: str) -> tuple[str, int]:
    """``HOST:PORT`` -> ``(host, port)``; ValueError with the reason."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(f"--listen must be HOST:PORT with a port 1..65535, got {text!r}")
    return host.strip("[]"), int(port)


def enable_timestamps(sock: socket.socket) -> bool:
    """Ask the kernel to stamp each datagram ``sock`` receives (:data:`SO_TIMESTAMPNS`; read with
    :func:`arrival_time`). Whether it did: False where the platform has no such option."""
    if SO_TIMESTAMPNS is None:
        return False
    try:
        sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
    except OSError:
        return False
    return True


def bind_udp(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``(host, port)`` with kernel receive time stamps where available."""
    s = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
    enable_timestamps(s)
    s.bind((host, port))
    return s


def raise_priority(rt_priority: int) -> str:
    """Run this thread under ``SCHED_FIFO`` at ``rt_priority`` (1-99; 0: leave it as it is), so that the
    answer is not queued behind other processes. Returns one line saying what was done; never raises
    (without the right, e.g. not root and no ``rtprio`` limit / CAP_SYS_NICE, the bridge runs at normal
    priority and the line says how to grant it)."""
    import os

    if rt_priority <= 0:
        return "normal priority (--rt-priority 0)"
    if not hasattr(os, "sched_setscheduler"):
        return "normal priority (this platform has no SCHED_FIFO)"
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(min(int(rt_priority), 99)))
    except (PermissionError, OSError) as e:
        return (f"normal priority: SCHED_FIFO {rt_priority} refused ({e.strerror or e}); allow it with an rtprio limit "
                f"(/etc/security/limits.conf) or CAP_SYS_NICE, or pass --rt-priority 0 to silence this")
    return f"real-time priority (SCHED_FIFO {min(int(rt_priority), 99)})"


def arrival_time(anc) -> float | None:
    """The kernel's receive time stamp (unix s) in the ancillary data ``anc`` of ``socket.recvmsg`` on a
    socket from :func:`bind_udp` (or :func:`enable_timestamps`); None without one."""
    for level, kind, data in anc:
        if SO_TIMESTAMPNS is not None and level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(data) >= 8:
            # a struct timespec: two 64-bit fields (64-bit Linux), two 32-bit ones on a 32-bit one
            sec, ns = struct.unpack("qq", data[:16]) if len(data) >= 16 else struct.unpack("ii", data[:8])
            return sec + ns * 1e-9
    return None


def _in_order(handle, cands: list) -> list:
    """The controller's datagrams of one drain (``(data, addr, t_in, stamped)``, in arrival order) in the
    order to try them: by the handler's ``cycle_key(data)`` where it has
    one (None first: no stamp readable, the handler refuses it at once and it is counted for what it is;
    then the largest key, the newest cycle, first), else the last to arrive first."""
    key = getattr(handle, "cycle_key", None)
    if key is None or len(cands) < 2:
        return cands[::-1]
    ks = [key(c[0]) for c in cands]
    order = sorted(range(len(cands)), key=lambda i: (ks[i] is None, 0 if ks[i] is None else ks[i], i), reverse=True)
    return [cands[i] for i in order]


def _count_left(st: "BridgeStats", handle, left: list) -> None:
    """Count the datagrams of a drain never tried (a newer cycle was answered), once the answer is sent (no
    delay to it): by the handler's ``leftover(data) -> (kind, cycles)``, the dropped kind ("malformed",
    "superseded") and whether its cycle was counted skipped by the answer's gap (then it is a cycle the
    bridge passed over, not one the controller skipped: probe AW D4); "unread" beyond :data:`_CLASSIFY` of
    them or without that method (probe AW D3: a malformed one read with a valid one was counted superseded)."""
    check = getattr(handle, "leftover", None)
    for i, data in enumerate(left):
        if check is None or i >= _CLASSIFY:
            st.ignored["unread"] += 1
            continue
        try:
            kind, over = check(data)
        except Exception:  # noqa: BLE001 - counting must never stop the bridge
            kind, over = "malformed", 0
        st.ignored[kind] += 1
        st.passed_over += over
        st.skipped_cycles -= over


def run_bridge(sock: socket.socket, handle, *, period_s: float, max_failures: int = 10, max_packet: int = 8192,
               controller: tuple | None = None, idle_exit_s: float = 0.0, stop=None, log_every_s: float = 10.0,
               keep_latency: bool = False, spin: bool = False) -> BridgeStats:
    """Serve datagrams on ``sock`` with ``handle(bytes) -> Outcome`` until ``stop`` (a threading.Event)
    is set, ``idle_exit_s`` passes without a valid datagram after the first one (0: never), or
    ``max_failures`` consecutive failures. ``controller``: ``(host, port)`` to accept datagrams from
    (default: the first sender of a valid one, named in one log line). ``keep_latency``: keep each
    answer's delay (s) in ``stats.latency_s``. ``spin``: poll the socket without sleeping (one core stays
    busy and warm: no wake-up delay and no cold caches when a datagram comes; for a core set aside for
    the bridge).

    When several datagrams of the controller wait (the bridge fell behind, or a stray, truncated or
    reordered one came with the cycle's), only one is answered: the newest cycle the handler accepts.
    They are tried newest first (by the handler's optional ``cycle_key(data) -> float | None``, how far
    the datagram's stamp lies after the last answered one; else by arrival); one the handler ignores
    is counted under its reason and the one before it tried, and the ones left once one is accepted
    are counted as superseded (probe s42 AT: a truncated copy behind the cycle's datagram took its
    place, and the cycle went unanswered)."""
    st = BridgeStats()
    gc.collect()
    gc.freeze()  # the model and libraries loaded so far are never scanned again: no full-collection pause mid-run
    peer = controller
    consecutive = 0
    causes: Counter = Counter()  # of the failures in the current run of consecutive ones: category -> count
    last_cause: dict = {}
    warned_late_incremental = False
    last_valid = None
    last_log = time.monotonic()
    sock.setblocking(False)
    cmsg = socket.CMSG_SPACE(16)

    def idle() -> bool:
        """Whether no valid datagram came for ``idle_exit_s`` (checked only while none waits to be read or
        none of those read was valid: a bridge held up for a while must not exit with valid ones queued)."""
        if idle_exit_s and last_valid is not None and time.monotonic() - last_valid > idle_exit_s:
            st.stopped = f"no valid datagram for {idle_exit_s:g} s"
            return True
        return False

    try:  # Ctrl-C ends the run with its counts (the exit line), as any other stop
        while stop is None or not stop.is_set():
            try:
                if not spin:
                    select.select([sock], [], [], 0.1)
                data, anc, flags, addr = sock.recvmsg(max_packet + 1, cmsg)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):  # nothing (or an ICMP error) to read
                if idle():
                    break
                continue
            cands = []  # the controller's datagrams waiting now, in arrival order
            for _ in range(_DRAIN):
                t_in = arrival_time(anc)
                if len(data) > max_packet or flags & socket.MSG_TRUNC:
                    st.ignored["oversized"] += 1
                elif peer is not None and addr[:2] != tuple(peer)[:2]:
                    st.ignored["other sender"] += 1
                else:
                    cands.append((data, addr, t_in or time.time(), t_in is not None))
                    if peer is None:
                        break  # no controller yet: one datagram at a time
                try:
                    data, anc, flags, addr = sock.recvmsg(max_packet + 1, cmsg)
                except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                    break
            out, left = None, []
            ordered = _in_order(handle, cands)
            for n, (data, addr, t_in, stamped) in enumerate(ordered):
                try:
                    out = handle(data)
                except Exception as e:  # noqa: BLE001 - a handler's bug on some input must not stop the bridge
                    out = Outcome(None, "ignored:handler error")
                    if not st.ignored["handler error"]:
                        _log.error("hykin bridge: a datagram raised %s: %s (dropped; the bridge goes on)",
                                   type(e).__name__, e)
                if not out.kind.startswith("ignored"):
                    left = [c[0] for c in ordered[n + 1:]]  # older cycles: over (counted once the answer is sent)
                    break
                st.ignored[out.kind.partition(":")[2] or "invalid"] += 1
                st.skipped_cycles += out.skipped  # (a late datagram of a cycle counted skipped takes it back)
                out = None
            if out is None:
                if idle():
                    break
                continue
            if out.reply is not None:
                try:
                    sock.sendto(out.reply, addr)
                except (BlockingIOError, ConnectionRefusedError):  # buffer full / nobody listening: the cycle is lost
                    st.ignored["send failed"] += 1
                delay = time.time() - t_in
                if keep_latency:
                    st.latency_s.append(delay)
                st.late += delay > period_s
                st.stamped += stamped
                if delay > period_s and getattr(handle, "incremental", False) and not warned_late_incremental:
                    warned_late_incremental = True  # RSI drops a late answer: its sum then lacks this increment
                    _log.warning("hykin bridge: incremental mode: an answer left %.1f ms after its datagram (over the "
                                 "period): a controller that dropped it has a different sum of corrections; hykin "
                                 "re-synchronises from RIst where the message shows it (docs/realtime.md)", delay * 1e3)
            st.skipped_cycles += out.skipped
            _count_left(st, handle, left)
            last_valid = time.monotonic()
            st.answered += out.reply is not None
            if out.kind == "failure":
                st.failures += 1
                consecutive += 1
                why = out.reason or getattr(handle, "last_reason", "") or "unknown cause"
                cat = why.partition(":")[0]
                causes[cat] += 1
                last_cause[cat] = why
                if causes[cat] == 1 and consecutive == 1:
                    _log.warning("hykin bridge: failure answered neutrally: %s", why)
                st.max_consecutive_failures = max(st.max_consecutive_failures, consecutive)
                if consecutive >= max_failures:
                    st.stopped = f"{consecutive} consecutive failures: stopped answering; causes: {_causes(causes, last_cause)}"
                    _log.error("hykin bridge: %s (%s)", st.stopped, st.summary())
                    break
            else:
                consecutive = 0
                causes.clear()
                if peer is None:
                    peer = addr
                    # without --controller the first sender of a valid message is the controller: say which
                    # (probe s42 AT: a second sender that came first was answered 2,988 times, silently)
                    _log.warning("hykin bridge: answering %s (the first sender of a valid message) and dropping every "
                                 "other sender; to answer another, give --controller HOST:PORT",
                                 _address(addr))
            if log_every_s and time.monotonic() - last_log > log_every_s:
                last_log = time.monotonic()
                if st.late or st.skipped_cycles or st.failures:
                    _log.warning("hykin bridge: %s", st.summary())
    except KeyboardInterrupt:
        st.stopped = "interrupted (Ctrl-C)"
    if not st.stopped:
        st.stopped = "stopped"
    return st


def _address(addr) -> str:
    """``HOST:PORT`` of a socket address (``[HOST]:PORT`` for IPv6)."""
    host, port = addr[0], addr[1]
    return f"[{host}]:{port}" if ":" in str(host) else f"{host}:{port}"
