"""The UDP loop shared by the controller bridges (:mod:`.rsi`, :mod:`.egm`).

One socket, one controller. Per datagram: drop it when it is over the size limit (truncated by the
kernel), when it comes from another sender than the controller (the first sender whose message was
valid, or the address given), when a newer one of the controller is already waiting (superseded:
its cycle is over), or when the protocol handler calls it invalid or stale; else answer it at once
with the handler's reply. Counted: answered, failures (the handler could not compute
and answered a neutral message), late answers (sent more than one period after the datagram
arrived, by the kernel's receive time stamp), cycles the controller skipped (by its stamps) and
every kind of dropped datagram. After ``max_failures`` consecutive failures the loop stops
answering and returns, so that the controller's own timeout stops the robot.
"""

from __future__ import annotations

import gc
import logging
import math
import select
import socket
import struct
import time
from collections import Counter
from dataclasses import dataclass, field

import numpy as np

__all__ = ["JumpWatch", "StampRun", "MAX_MISMATCH_DEG", "MAX_MISMATCH_MM", "BridgeStats", "Outcome", "RestartWatch", "arrival_time", "bind_udp",
           "check_actual_pose", "check_limits", "parse_listen",
           "raise_priority", "run_bridge"]

_log = logging.getLogger("hykin.realtime")
_DRAIN = 256  # datagrams read at most per turn when behind


@dataclass
class Outcome:
    """What the handler made of one datagram. reply: bytes to send back (None: send nothing).
    kind: ``"ok"``, ``"failure"`` (reply is the protocol's neutral answer) or ``"ignored:<why>"``.
    skipped: cycles the controller's stamp says were skipped before this one."""

    reply: bytes | None
    kind: str
    skipped: int = 0
    reason: str = ""  # a failure's one-line cause, its category first ("correction over the limit: ...")


class StampRun:
    """Consecutive stamps (``IPOC``, ``seqno``) each following the previous by 1 to ``step`` counts: what
    confirms a restart (:class:`RestartWatch`) or a stray jump (:class:`JumpWatch`) where one message alone
    may be a stray or a late datagram. ``modulo``: stamps that wrap (EGM's 32-bit seqno)."""

    def __init__(self, step: int, confirm: int = 2, modulo: int | None = None):
        self.step, self.confirm, self.modulo = int(step), int(confirm), modulo
        self._run: list[int] = []

    def ahead(self, a: int, b: int) -> int:
        """``a - b`` (wrapped into ``[-modulo/2, modulo/2)`` for wrapping stamps)."""
        d = int(a) - int(b)
        return d if self.modulo is None else (d + self.modulo // 2) % self.modulo - self.modulo // 2

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
    off). One message behind alone stays dropped (a late, reordered datagram must not undo an answer the
    controller took). ``modulo``: stamps that wrap (EGM's 32-bit seqno)."""

    def __init__(self, window: int, step: int, confirm: int = 2, modulo: int | None = None):
        self.window = int(window)
        self._before = None
        self._run = StampRun(step, confirm, modulo)

    def jumped(self, before: int, state) -> None:
        """The message just answered jumped ahead of ``before`` (the last stamp of the session so far,
        whose ``state`` a return restores)."""
        self._before = (int(before), state)
        self._run.clear()

    def clear(self) -> None:
        """A message in order after the jump: it was real."""
        self._before = None
        self._run.clear()

    def returned(self, stamp: int):
        """For a message behind the last answered one: the state saved before the jump once ``confirm``
        consecutive such messages continue the session from before it, else None."""
        if self._before is None or not 0 < self._run.ahead(stamp, self._before[0]) <= self.window:
            self._run.clear()
            return None
        if not self._run.add(stamp):
            return None
        state = self._before[1]
        self.clear()
        return state


@dataclass
class BridgeStats:
    """Counts of one bridge run (see the module docstring); ``stopped``: why the loop ended."""

    answered: int = 0
    failures: int = 0
    late: int = 0
    skipped_cycles: int = 0
    ignored: Counter = field(default_factory=Counter)
    max_consecutive_failures: int = 0
    latency_s: list = field(default_factory=list)
    stopped: str = ""

    def summary(self) -> str:
        ign = ", ".join(f"{k} {v}" for k, v in sorted(self.ignored.items())) or "none"
        return (f"answered {self.answered} (failures answered neutrally {self.failures}), late {self.late}, "
                f"cycles skipped by the controller {self.skipped_cycles}, dropped: {ign}")


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


def bind_udp(host: str, port: int) -> socket.socket:
    """A UDP socket bound to ``(host, port)`` with kernel receive time stamps where available."""
    s = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_DGRAM)
    if hasattr(socket, "SO_TIMESTAMPNS"):
        s.setsockopt(socket.SOL_SOCKET, socket.SO_TIMESTAMPNS, 1)
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
    socket from :func:`bind_udp` (or with ``SO_TIMESTAMPNS`` set); None without one."""
    for level, kind, data in anc:
        if level == socket.SOL_SOCKET and kind == getattr(socket, "SO_TIMESTAMPNS", -1) and len(data) >= 16:
            sec, ns = struct.unpack("qq", data[:16])
            return sec + ns * 1e-9
    return None


def run_bridge(sock: socket.socket, handle, *, period_s: float, max_failures: int = 10, max_packet: int = 8192,
               controller: tuple | None = None, idle_exit_s: float = 0.0, stop=None, log_every_s: float = 10.0,
               keep_latency: bool = False, spin: bool = False) -> BridgeStats:
    """Serve datagrams on ``sock`` with ``handle(bytes) -> Outcome`` until ``stop`` (a threading.Event)
    is set, ``idle_exit_s`` passes without a valid datagram after the first one (0: never), or
    ``max_failures`` consecutive failures. ``controller``: ``(host, port)`` to accept datagrams from
    (default: the first sender of a valid one). ``keep_latency``: keep each answer's delay (s) in
    ``stats.latency_s``. ``spin``: poll the socket without sleeping (one core stays busy and warm: no
    wake-up delay and no cold caches when a datagram comes; for a core set aside for the bridge)."""
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
    try:  # Ctrl-C ends the run with its counts (the exit line), as any other stop
        while stop is None or not stop.is_set():
            if idle_exit_s and last_valid is not None and time.monotonic() - last_valid > idle_exit_s:
                st.stopped = f"no valid datagram for {idle_exit_s:g} s"
                break
            try:
                if not spin:
                    select.select([sock], [], [], 0.1)
                data, anc, flags, addr = sock.recvmsg(max_packet + 1, cmsg)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):  # nothing (or an ICMP error) to read
                continue
            # when behind, answer only the newest datagram of the controller: older cycles are over
            best = None
            for _ in range(_DRAIN):
                t_in = arrival_time(anc) or time.time()
                if len(data) > max_packet or flags & socket.MSG_TRUNC:
                    st.ignored["oversized"] += 1
                elif peer is not None and addr[:2] != tuple(peer)[:2]:
                    st.ignored["other sender"] += 1
                else:
                    if best is not None:
                        st.ignored["superseded"] += 1
                    best = (data, addr, t_in)
                    if peer is None:
                        break  # no controller yet: one datagram at a time
                try:
                    data, anc, flags, addr = sock.recvmsg(max_packet + 1, cmsg)
                except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                    break
            if best is None:
                continue
            data, addr, t_in = best
            out = handle(data)
            if out.reply is not None:
                try:
                    sock.sendto(out.reply, addr)
                except (BlockingIOError, ConnectionRefusedError):  # buffer full / nobody listening: the cycle is lost
                    st.ignored["send failed"] += 1
                delay = time.time() - t_in
                if keep_latency:
                    st.latency_s.append(delay)
                st.late += delay > period_s
                if delay > period_s and getattr(handle, "incremental", False) and not warned_late_incremental:
                    warned_late_incremental = True  # RSI drops a late answer: its sum then lacks this increment
                    _log.warning("hykin bridge: incremental mode: an answer left %.1f ms after its datagram (over the "
                                 "period): a controller that dropped it has a different sum of corrections; hykin "
                                 "re-synchronises from RIst where the message shows it (docs/realtime.md)", delay * 1e3)
            if out.kind.startswith("ignored"):
                st.ignored[out.kind.partition(":")[2] or "invalid"] += 1
                continue
            last_valid = time.monotonic()
            st.skipped_cycles += out.skipped
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
            if log_every_s and time.monotonic() - last_log > log_every_s:
                last_log = time.monotonic()
                if st.late or st.skipped_cycles or st.failures:
                    _log.warning("hykin bridge: %s", st.summary())
    except KeyboardInterrupt:
        st.stopped = "interrupted (Ctrl-C)"
    if not st.stopped:
        st.stopped = "stopped"
    return st
