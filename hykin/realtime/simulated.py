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
from ..kinematics.ik import ik
from ..sim.simulate import true_poses
from .egm import format_robot, parse_sensor
from .rsi import pose_of
from .rsi_xml import RsiConfig, RsiMessageError, format_rob, parse_sen

__all__ = ["SimRun", "SimulatedEgm", "SimulatedRsi", "path_errors", "xyzabc_of"]


def xyzabc_of(T: np.ndarray, a_hint_deg: float = 0.0) -> np.ndarray:
    """``(6,)`` X Y Z mm, A B C deg of a ``(4, 4)`` pose (m)."""
    return np.concatenate([T[:3, 3] * 1e3, abc_from_matrix(T[:3, :3], a_hint_deg)])


@dataclass
class SimRun:
    """One simulated run of ``N`` cycles. q: ``(N, n)`` joints taken (rad). in_time: ``(N,)`` an answer
    with the cycle's stamp arrived within the period. reply_s: ``(N,)`` its delay (NaN: none).
    correction: ``(N, 6)`` commanded minus programmed pose (mm; rotation vector, rad). slipped: cycles
    the simulator itself started late."""

    q: np.ndarray
    in_time: np.ndarray
    reply_s: np.ndarray
    correction: np.ndarray
    slipped: int


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
        self.held0 = np.zeros(6)  # RSI: the correction in force at the start (incremental: the sum so far)

    def _ik(self, T_ctrl: np.ndarray, q: np.ndarray) -> np.ndarray:
        r = ik(self.nom, self.nom.base @ T_ctrl, q_seed=q)
        return r.q[0] if r.success[0] else q  # no solution: the robot stays (a real one would stop)

    def _message(self, k: int, stamp: int, q: np.ndarray) -> bytes:
        raise NotImplementedError

    def _answer(self, data: bytes, stamp: int, held):
        """The new held value from an answer for ``stamp`` (None: not an answer to this cycle)."""
        raise NotImplementedError

    def _command(self, k: int, held) -> np.ndarray:
        raise NotImplementedError

    def run(self, sock: socket.socket | None = None) -> SimRun:
        N, n = len(self.path), self.nom.dof
        own = sock is None
        sock = sock or socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        q = self.q0.copy()
        Q = np.zeros((N, n))
        in_time = np.zeros(N, bool)
        reply_s = np.full(N, np.nan)
        corr = np.zeros((N, 6))
        held = self._held0()
        slipped = 0
        t_k = time.perf_counter() + 0.01
        try:
            for k in range(N):
                if k:
                    ideal, now = t_k + self.period, time.perf_counter()
                    slipped += now > ideal + self.period / 2
                    t_k = max(ideal, now)
                while (now := time.perf_counter()) < t_k:
                    if t_k - now > 0.0015:
                        time.sleep(t_k - now - 0.001)
                stamp = self._stamp(k)
                msg = self._message(k, stamp, q)
                t_send = time.perf_counter()
                sock.sendto(msg, self.bridge)
                deadline = t_send + self.deadline
                while (left := deadline - time.perf_counter()) > 0:
                    sock.settimeout(left)
                    try:
                        data = sock.recv(65536)
                    except (socket.timeout, ConnectionRefusedError):
                        break
                    new = self._answer(data, stamp, held)
                    if new is None:
                        continue  # garbage, or a late answer to an earlier cycle
                    reply_s[k] = time.perf_counter() - t_send
                    in_time[k] = reply_s[k] <= self.period
                    held = new
                    break
                T_cmd = self._command(k, held)
                corr[k] = np.concatenate([(T_cmd[:3, 3] - self._programmed(k)[:3, 3]) * 1e3,
                                          se3.matrix_to_rotvec(T_cmd[:3, :3] @ self._programmed(k)[:3, :3].T)])
                q = self._ik(T_cmd, q)
                Q[k] = q
        finally:
            if own:
                sock.close()
        self.held_last = held  # RSI: the correction in force at the end (EGM: the last pose)
        return SimRun(q=Q, in_time=in_time, reply_s=reply_s, correction=corr, slipped=int(slipped))


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
        return self.held0.copy()

    def _stamp(self, k: int) -> int:
        return self.stamp0 + k * int(round(self.period * 1e3))

    def _programmed(self, k: int) -> np.ndarray:
        return pose_of(self.path[k])

    def _message(self, k, stamp, q):
        T_ctrl = se3.invert(self.nom.base) @ fk(self.nom, q[None])[0]
        return format_rob(stamp, self.path[k], xyzabc_of(T_ctrl, self.path[k, 3]), np.degrees(q * self.signs), self.cfg)

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
        return self.path[0]

    def _stamp(self, k: int) -> int:
        return (self.stamp0 + k) % 2**32

    def _programmed(self, k: int) -> np.ndarray:
        return self.path[k]

    def _message(self, k, stamp, q):
        T_ctrl = se3.invert(self.nom.base) @ fk(self.nom, q[None])[0]
        return format_robot(stamp, int(k * self.period * 1e3) % 2**32, self.path[k], np.degrees(q * self.signs), T_ctrl)

    def _answer(self, data, stamp, held):
        try:
            seq, _, T = parse_sensor(data)
        except ValueError:
            return None
        return T if seq == stamp else None

    def _command(self, k, held):
        return held
