"""Simulated controllers for the bridges: they run at the real period on loopback, solve their own
nominal IK every cycle and move a simulated true robot (tests, benchmarks, trying a bridge).

:class:`SimulatedEgm` plays an ABB controller in EGM pose guidance: every ``period_s`` an
``EgmRobot`` with the programmed pose as ``planned``, its joints and nominal pose as feedback; the
pose of an ``EgmSensor`` answer with the same ``seqno`` that arrives before the next cycle is the
pose it goes to (else it holds the last one, as EGM does); its nominal IK gives the joints.

:class:`SimulatedRsi` plays a KUKA controller with RSI: every ``period_s`` it sends the programmed
setpoint ``RSol``, the nominal pose of its joints ``RIst``, its axes ``AIPos`` and ``IPOC``; an
answer that arrives before the next cycle with the same ``IPOC`` sets the correction (absolute:
replaced; incremental: added up), otherwise the last one is held. The commanded pose is the
setpoint plus the correction (componentwise, as RSI adds it); the controller's nominal IK on the
branch nearest its current joints gives the next joints, which the TRUE robot then takes. The
true TCP poses are evaluated after the run (batched) and compared with the programmed path.
"""

from __future__ import annotations

import socket
import time
from dataclasses import dataclass

import numpy as np

from ..compensation.krl import abc_from_matrix
from ..geometry import se3
from ..kinematics.fk import fk
from ..kinematics.ik import ik, solve_lm
from ..sim.simulate import true_poses
from .egm import format_robot, parse_sensor
from .rsi import pose_of
from .rsi_xml import RsiConfig, RsiMessageError, format_rob, parse_sen
from .udp_bridge import arrival_time, enable_timestamps

__all__ = ["SimRun", "SimulatedEgm", "SimulatedRsi", "path_errors", "xyzabc_of"]

_SPIN_S = 3e-4  # the last stretch before a clock tick is spun, not slept (sleep overshoots by ~0.1 ms)
_CMSG = socket.CMSG_SPACE(16)  # room for one SO_TIMESTAMPNS stamp


def xyzabc_of(T: np.ndarray, a_hint_deg: float = 0.0) -> np.ndarray:
    """``(6,)`` X Y Z mm, A B C deg of a ``(4, 4)`` pose (m)."""
    return np.concatenate([T[:3, 3] * 1e3, abc_from_matrix(T[:3, :3], a_hint_deg)])


@dataclass
class SimRun:
    """One simulated run of ``N`` cycles. q: ``(N, n)`` joints taken (rad). in_time: ``(N,)`` an answer
    with the cycle's stamp arrived within the period. reply_s: ``(N,)`` its delay (NaN: none).
    correction: ``(N, 6)`` commanded minus programmed pose (mm; rotation vector, rad). slipped: cycles
    the simulator itself started more than half a period late (its own lateness, not the bridge's).
    start_late_s: ``(N,)`` how late each cycle was sent after its clock tick (s). cpu_s: the
    simulator's own CPU time per cycle (s, this thread: message, answer, nominal IK)."""

    q: np.ndarray
    in_time: np.ndarray
    reply_s: np.ndarray
    correction: np.ndarray
    slipped: int
    start_late_s: np.ndarray | None = None
    cpu_s: float = float("nan")


def path_errors(vr, q: np.ndarray, targets_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(pos_mm (N,), ang_deg (N,))`` of the TRUE robot ``vr`` at joints ``q`` to ``targets_world``."""
    return se3.pose_error(true_poses(vr, q), targets_world)


class _Simulated:
    """The loop shared by the simulated controllers (see :class:`SimulatedRsi` for the arguments)."""

    def __init__(self, nominal, path: np.ndarray, q0: np.ndarray, bridge: tuple, axis_signs=None,
                 period_s: float = 0.004, stamp0: int = 100_000, deadline_s: float | None = None):
        self.nom, self.path = nominal, np.asarray(path, dtype=np.float64)
        self.q0, self.bridge = np.asarray(q0, dtype=np.float64), bridge
        self.signs = np.ones(nominal.dof) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
        self.period, self.stamp0 = float(period_s), int(stamp0)
        self.deadline = self.period if deadline_s is None else float(deadline_s)
        # in force at the start (a run that continues an earlier one: its held_last). RSI: the correction
        # (incremental: the sum so far), zero by default; EGM: the pose, the first programmed one by default
        self.held0 = None
        self._base = np.asarray(nominal.base, dtype=np.float64)
        self._base_inv = se3.invert(self._base)

    def _ik(self, T_ctrl: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The controller's nominal IK of ``T_ctrl`` (its base frame) from its joints ``q``: one compiled
        LM run from ``q`` (a cycle moves little: it stays on ``q``'s branch), the full IK when that does
        not converge within the limits."""
        T = self._base @ T_ctrl
        qs, pe, ae, _ = solve_lm(self.nom, T[None], q[None])
        if pe[0] <= 1e-9 and ae[0] <= 1e-9 and self.nom.within_limits(qs, tol=0.0)[0]:
            return qs[0]
        r = ik(self.nom, T, q_seed=q)
        return r.q[0] if r.success[0] else q  # no solution: the robot stays (a real one would stop)

    def _actual(self, q: np.ndarray) -> np.ndarray:
        """The nominal TCP pose ``(4, 4)`` of joints ``q`` in the controller's base frame."""
        return self._base_inv @ fk(self.nom, q)

    def _message(self, k: int, stamp: int, q: np.ndarray) -> bytes:
        raise NotImplementedError

    def _answer(self, data: bytes, stamp: int, held):
        """The new held value from an answer for ``stamp`` (None: not an answer to this cycle)."""
        raise NotImplementedError

    def _command(self, k: int, held) -> np.ndarray:
        raise NotImplementedError

    def run(self, sock: socket.socket | None = None) -> SimRun:
        """Run every cycle at its clock tick ``t0 + k period`` (absolute deadlines: sleep, then spin the
        last ``_SPIN_S``); a cycle started over half a period late re-anchors the clock (counted in
        ``slipped``), so that a late simulator never sends cycles faster than the period. An answer's
        delay is from the send to the kernel's receive stamp of the answer (where the platform has
        ``SO_TIMESTAMPNS``: Linux): what a controller on a real-time OS sees, not when this process, sharing
        the cores, got to read it; an answer that arrived after the deadline is not used."""
        N, n = len(self.path), self.nom.dof
        own = sock is None
        sock = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        enable_timestamps(sock)  # (Python 3.11 lacks the option's name: udp_bridge.SO_TIMESTAMPNS)
        q = self.q0.copy()
        Q = np.zeros((N, n))
        in_time = np.zeros(N, bool)
        reply_s = np.full(N, np.nan)
        late = np.zeros(N)
        T_cmd = np.zeros((N, 4, 4))
        held = self._held0()
        slipped = 0
        tick = time.perf_counter() + 0.01
        cpu = 0.0
        try:
            for k in range(N):
                if k:
                    tick += self.period
                    if time.perf_counter() > tick + self.period / 2:  # this cycle is over already
                        slipped += 1
                        tick = time.perf_counter()
                while (left := tick - time.perf_counter()) > 0:
                    if left > _SPIN_S:
                        time.sleep(left - _SPIN_S)
                c0 = time.thread_time()
                stamp = self._stamp(k)
                msg = self._message(k, stamp, q)
                late[k] = time.perf_counter() - tick
                t_send = time.time()  # the kernel's receive stamps are on this clock
                sock.sendto(msg, self.bridge)
                cpu += time.thread_time() - c0
                deadline = t_send + self.deadline
                while True:
                    # an answer counts by when it reached this socket (the kernel's stamp), as on a
                    # controller's real-time OS: this simulator shares the cores and may read it later;
                    # past the deadline only what already arrived is read (a zero timeout)
                    sock.settimeout(max(deadline - time.time(), 0.0))
                    try:
                        data, anc, _, _ = sock.recvmsg(65536, _CMSG)
                    except (socket.timeout, BlockingIOError, InterruptedError, ConnectionRefusedError):
                        break
                    t_got = arrival_time(anc) or time.time()
                    if t_got > deadline:
                        break  # this cycle is over: the answer is not used (RSI/EGM move on)
                    c0 = time.thread_time()
                    new = self._answer(data, stamp, held)
                    cpu += time.thread_time() - c0
                    if new is None:
                        continue  # garbage, or a late answer to an earlier cycle
                    reply_s[k] = t_got - t_send
                    in_time[k] = reply_s[k] <= self.period
                    held = new
                    break
                c0 = time.thread_time()
                T_cmd[k] = self._command(k, held)
                q = self._ik(T_cmd[k], q)
                Q[k] = q
                cpu += time.thread_time() - c0
        finally:
            if own:
                sock.close()
        self.held_last = held  # RSI: the correction in force at the end (EGM: the last pose)
        P = self._programmed_all()
        corr = np.concatenate([(T_cmd[:, :3, 3] - P[:, :3, 3]) * 1e3,
                               se3.matrix_to_rotvec(T_cmd[:, :3, :3] @ np.swapaxes(P[:, :3, :3], -1, -2))], 1)
        return SimRun(q=Q, in_time=in_time, reply_s=reply_s, correction=corr, slipped=int(slipped), start_late_s=late,
                      cpu_s=cpu / max(N, 1))


class SimulatedRsi(_Simulated):
    """A KUKA RSI controller on loopback (module docstring).

    nominal: the controller's robot model. setpoints: ``(N, 6)`` programmed TCP path (X Y Z mm,
    A B C deg, controller base frame). q0: ``(n,)`` start joints (rad). bridge: ``(host, port)``.
    axis_signs: ``A = sign · q``. cfg: :class:`RsiConfig`. period_s: the cycle [0.004]; IPOC counts
    ms from ``ipoc0``. deadline_s: how long it waits for an answer [the period, as RSI]; a longer
    wait (tests of correctness on a busy machine) delays the next cycle, it never sends cycles
    faster than the period. ``SimRun.correction``: the commanded pose minus the programmed one
    (mm, rotation vector rad).
    """

    def __init__(self, nominal, setpoints: np.ndarray, q0: np.ndarray, bridge: tuple, axis_signs=None,
                 cfg: RsiConfig | None = None, period_s: float = 0.004, ipoc0: int = 100_000, deadline_s: float | None = None):
        super().__init__(nominal, setpoints, q0, bridge, axis_signs, period_s, ipoc0, deadline_s)
        self.cfg = cfg or RsiConfig()

    def _held0(self):
        return np.zeros(6) if self.held0 is None else np.array(self.held0, dtype=np.float64)

    def _stamp(self, k: int) -> int:
        return self.stamp0 + k * int(round(self.period * 1e3))

    def _programmed_all(self) -> np.ndarray:
        return np.array([pose_of(v) for v in self.path]).reshape(-1, 4, 4)

    def _message(self, k, stamp, q):
        return format_rob(stamp, self.path[k], xyzabc_of(self._actual(q), self.path[k, 3]), np.degrees(q * self.signs),
                          self.cfg)

    def _answer(self, data, stamp, held):
        try:
            got, korr = parse_sen(data, self.cfg)
        except RsiMessageError:
            return None
        if got != stamp:
            return None
        return korr if self.cfg.mode == "absolute" else held + korr

    def _command(self, k, held):
        return pose_of(self.path[k] + held)


class SimulatedEgm(_Simulated):
    """An ABB controller in EGM pose guidance on loopback (module docstring). poses: ``(N, 4, 4)``
    programmed TCP path (m, controller base frame); ``seqno`` counts from ``seq0``, ``tm`` in ms.
    Other arguments as :class:`SimulatedRsi`."""

    def __init__(self, nominal, poses: np.ndarray, q0: np.ndarray, bridge: tuple, axis_signs=None,
                 period_s: float = 0.004, seq0: int = 1, deadline_s: float | None = None):
        super().__init__(nominal, poses, q0, bridge, axis_signs, period_s, seq0, deadline_s)

    def _held0(self):
        return self.path[0] if self.held0 is None else np.array(self.held0, dtype=np.float64)

    def _stamp(self, k: int) -> int:
        return (self.stamp0 + k) % 2**32

    def _programmed_all(self) -> np.ndarray:
        return self.path

    def _message(self, k, stamp, q):
        return format_robot(stamp, int(k * self.period * 1e3) % 2**32, self.path[k], np.degrees(q * self.signs),
                            self._actual(q))

    def _answer(self, data, stamp, held):
        try:
            seq, _, T = parse_sensor(data)
        except ValueError:
            return None
        return T if seq == stamp else None

    def _command(self, k, held):
        return held
