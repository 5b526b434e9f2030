"""``hykin egm``: an ABB EGM peer in pose-guidance mode (UDP, protobuf ``EgmRobot`` / ``EgmSensor`` of
ABB's ``egm.proto``, compiled to :mod:`.egm_pb2`).

Per ``EgmRobot``: the planned pose (``planned.cartesian``: ``pos`` mm, ``orient`` quaternion
``u0..u3`` = w, x, y, z, in the EGM correction frame, taken as the robot's base frame) is compensated
on the branch of the feedback joints (``feedBack.joints``, deg), and the answer ``EgmSensor`` carries
the compensated pose in ``planned.cartesian`` with the robot's ``seqno`` and ``tm`` echoed and
``mtype = MSGTYPE_CORRECTION``. A pose that cannot be compensated is answered with the planned pose
itself (no correction); a message that cannot be parsed, lacks a field egm.proto marks ``required``
(as ABB's own parser refuses it), lacks the planned pose or joints, or whose
``seqno`` is not after the last answered one (modulo 2^32) is not answered; except a session started
again: two consecutive messages more than ``RESTART_BEHIND`` behind that follow each other start a
new count (:class:`hykin.realtime.udp_bridge.RestartWatch`).
"""

from __future__ import annotations

import logging

import numpy as np

from ..geometry import se3
from .udp_bridge import (MAX_MISMATCH_DEG, MAX_MISMATCH_MM, REORDER_CYCLES, GapLedger, JumpWatch, Outcome,
                         RestartWatch, check_actual_pose, check_limits, stamp_ahead)

__all__ = ["EgmHandler", "format_robot", "format_sensor", "parse_robot", "parse_sensor"]


_PB: tuple = ()
RESTART_BEHIND = 250  # seqnos behind (or ahead of) the last answered one (1 s at 4 ms) that may be a new session
_log = logging.getLogger("hykin.realtime")
_CAUSES = ("feedBack mismatch:", "unreachable setpoint:", "correction over the limit:")


def _pb():
    """``(egm_pb2, DecodeError)``, imported on first use (protobuf is loaded only by the EGM bridge)."""
    global _PB
    if not _PB:
        from google.protobuf.message import DecodeError

        from . import egm_pb2

        _PB = (egm_pb2, DecodeError)
    return _PB


def _pose(p) -> np.ndarray:
    """``EgmPose`` -> ``(4, 4)`` m."""
    o = p.orient
    q = np.array([o.u0, o.u1, o.u2, o.u3])
    n = np.linalg.norm(q)
    if not np.isfinite(q).all() or abs(n - 1) > 1e-3:
        raise ValueError(f"quaternion norm {n:.6f}, expected 1")
    xyz = np.array([p.pos.x, p.pos.y, p.pos.z]) * 1e-3
    if not np.isfinite(xyz).all():
        raise ValueError("position holds NaN or inf")
    return se3.pose_to_transform(xyz, q / n)


def _set_pose(p, T: np.ndarray) -> None:
    xyz, q = se3.transform_to_pose(T)
    p.pos.x, p.pos.y, p.pos.z = (float(v) for v in xyz * 1e3)
    p.orient.u0, p.orient.u1, p.orient.u2, p.orient.u3 = (float(v) for v in q)


def _parse(kind: str, data: bytes, complete: bool = True):
    """The message ``kind`` of ``data``; ValueError when it cannot be parsed or (``complete``) lacks a field
    egm.proto marks ``required``."""
    pb, DecodeError = _pb()
    m = getattr(pb, kind)()
    try:
        m.ParseFromString(data)
    except (DecodeError, RuntimeError) as e:
        raise ValueError(f"not an {kind} message ({e})") from None
    # proto2 parsing here does not enforce `required`: a missing field reads as 0 (probe s42 AT: a planned
    # pose without z was compensated to z = 0.5 mm and answered, 1.46 m below the path)
    if complete and not m.IsInitialized():
        raise ValueError(f"{kind} lacks required fields: {', '.join(m.FindInitializationErrors()[:6])}")
    return m


def parse_robot(data: bytes, dof: int):
    """``(seqno, tm, planned (4, 4) m, joints_deg (dof,))`` of an ``EgmRobot``; ValueError otherwise."""
    return _parse_robot(data, dof)[:4]


def _parse_robot(data: bytes, dof: int):
    """:func:`parse_robot` plus the actual pose ``feedBack.cartesian`` ``(4, 4)`` m (None without one)."""
    m = _parse("EgmRobot", data)
    if not m.HasField("header") or not m.header.HasField("seqno"):
        raise ValueError("no header.seqno")
    if not m.HasField("planned") or not m.planned.HasField("cartesian") or not m.planned.cartesian.HasField("pos") \
            or not m.planned.cartesian.HasField("orient"):
        raise ValueError("no planned.cartesian pose with pos and orient")
    j = np.array(m.feedBack.joints.joints if m.HasField("feedBack") else [], dtype=np.float64)
    if j.size < dof or not np.isfinite(j[:dof]).all():
        raise ValueError(f"feedBack.joints: {j.size} finite values, expected {dof}")
    fb = m.feedBack.cartesian if m.HasField("feedBack") and m.feedBack.HasField("cartesian") else None
    actual = _pose(fb) if fb is not None and fb.HasField("pos") and fb.HasField("orient") else None
    return m.header.seqno, m.header.tm, _pose(m.planned.cartesian), j[:dof], actual


def format_sensor(seqno: int, tm: int, T: np.ndarray) -> bytes:
    """``EgmSensor``: pose ``T`` (m) to go to, echoed ``seqno`` and ``tm``, ``MSGTYPE_CORRECTION``."""
    pb, _ = _pb()
    m = pb.EgmSensor()
    m.header.seqno, m.header.tm = int(seqno), int(tm)
    m.header.mtype = pb.EgmHeader.MSGTYPE_CORRECTION
    _set_pose(m.planned.cartesian, T)
    return m.SerializeToString()


def format_robot(seqno: int, tm: int, planned: np.ndarray, joints_deg: np.ndarray, actual: np.ndarray) -> bytes:
    """``EgmRobot`` (the simulated controller's side)."""
    pb, _ = _pb()
    m = pb.EgmRobot()
    m.header.seqno, m.header.tm = int(seqno), int(tm)
    m.header.mtype = pb.EgmHeader.MSGTYPE_DATA
    _set_pose(m.planned.cartesian, planned)
    _set_pose(m.feedBack.cartesian, actual)
    m.feedBack.joints.joints.extend(float(v) for v in joints_deg)
    m.mciState.state = pb.EgmMCIState.MCI_RUNNING
    return m.SerializeToString()


def parse_sensor(data: bytes) -> tuple[int, int, np.ndarray]:
    """``(seqno, tm, pose (4, 4) m)`` of an ``EgmSensor`` (the simulated controller's side)."""
    m = _parse("EgmSensor", data)
    if not m.planned.HasField("cartesian"):
        raise ValueError("no planned.cartesian")
    return m.header.seqno, m.header.tm, _pose(m.planned.cartesian)


class EgmHandler:
    """The per-message work of ``hykin egm`` (see :class:`hykin.realtime.rsi.RsiHandler` for ``step``,
    ``base``, ``axis_signs`` and the correction limits)."""

    def __init__(self, step, base: np.ndarray, dof: int, axis_signs, max_correction_mm: float = 50.0,
                 max_correction_deg: float = 5.0, nominal_fk=None, max_mismatch_mm: float = MAX_MISMATCH_MM,
                 max_mismatch_deg: float = MAX_MISMATCH_DEG):
        check_limits(max_correction_mm=max_correction_mm, max_correction_deg=max_correction_deg,
                     max_mismatch_mm=max_mismatch_mm, max_mismatch_deg=max_mismatch_deg)
        self.nominal_fk = nominal_fk
        self.max_mismatch = (float(max_mismatch_mm), float(max_mismatch_deg))
        self.mismatch_max = (0.0, 0.0)
        self.step, self.base, self.dof = step, np.asarray(base, dtype=np.float64), dof
        self.signs = np.asarray(axis_signs, dtype=np.float64)
        self.max_mm, self.max_deg = float(max_correction_mm), float(max_correction_deg)
        self.last_seq: int | None = None
        self.retired: int | None = None  # the last seqno answered before the latest restart
        self.restart = RestartWatch(RESTART_BEHIND, 10)
        self.strays = JumpWatch(RESTART_BEHIND, 10, modulo=2**32)  # a stray seqno ahead of the session
        self.stray_jumps = 0
        self.gaps = GapLedger(1, modulo=2**32)  # gaps counted as skipped that a late datagram may fill
        self.mismatch_checked = 0  # cycles whose feedBack.cartesian was checked against the FK of the joints
        self.last_reason = ""

    def command(self, planned: np.ndarray, joints_deg, actual=None) -> np.ndarray:
        """The compensated pose ``(4, 4)`` for one planned pose (ValueError with the reason on failure).
        ``actual``: ``feedBack.cartesian`` (4, 4), checked against the nominal FK of the joints (as RSI's RIst)."""
        q = np.radians(np.asarray(joints_deg, dtype=np.float64)) * self.signs
        if actual is not None and self.nominal_fk is not None:
            self.mismatch_checked += 1
            self.mismatch_max, why = check_actual_pose(self.nominal_fk, q, actual, self.max_mismatch, self.mismatch_max,
                                                       ("feedBack", "feedBack.cartesian", "feedBack.joints"))
            if why:
                raise ValueError(why)
        r = self.step(self.base @ planned, q)
        if not r.success:
            raise ValueError(f"unreachable setpoint: not compensated ({r.reason})")
        dp, da = se3.pose_error(r.command[None], planned[None])
        if not (dp[0] <= self.max_mm and da[0] <= self.max_deg):
            raise ValueError(f"correction over the limit: {dp[0]:.2f} mm / {da[0]:.3f} deg (--max-correction-mm "
                             f"{self.max_mm:g}, --max-correction-deg {self.max_deg:g})")
        return r.command

    def cycle_key(self, data: bytes) -> float | None:
        """How many seqnos ``data`` lies after the last answered one, for
        :func:`hykin.realtime.udp_bridge.run_bridge` to try the newest of several waiting datagrams first:
        None where no seqno can be read; ``-inf`` over ``RESTART_BEHIND`` ahead (maybe a stray: tried last)."""
        try:
            m = _parse("EgmRobot", data, complete=False)
        except ValueError:
            return None
        if not m.header.HasField("seqno"):
            return None
        if self.last_seq is None:
            return float(m.header.seqno)
        d = stamp_ahead(m.header.seqno, self.last_seq, 2**32)
        return float("-inf") if d > RESTART_BEHIND else float(d)

    def leftover(self, data: bytes) -> tuple[str, int]:
        """For the counts of :func:`hykin.realtime.udp_bridge.run_bridge` (see
        :meth:`hykin.realtime.rsi.RsiHandler.leftover`): ``("malformed", 0)`` when ``data`` is not a complete
        ``EgmRobot``, else ``("superseded", 1 when its cycle was counted as skipped, else 0)``."""
        try:
            seq = _parse_robot(data, self.dof)[0]
        except ValueError:
            return "malformed", 0
        return "superseded", self.gaps.fill(seq)

    def __call__(self, data: bytes) -> Outcome:
        try:
            seq, tm, planned, joints, actual = _parse_robot(data, self.dof)
        except ValueError as e:
            self.last_reason = str(e)
            return Outcome(None, "ignored:malformed")
        skipped = undo = 0
        if self.last_seq is not None:
            gap = (seq - self.last_seq) % 2**32
            if 2**32 - REORDER_CYCLES <= gap:
                # a few seqnos behind: a late, reordered datagram (not a sign that the answered one was a stray;
                # a cycle counted skipped is taken back out): as RSI (probe AW A3, D1)
                return Outcome(None, "ignored:stale seqno", -self.gaps.fill(seq))
            back = self.strays.returned(seq) if gap == 0 or gap >= 2**31 else None
            if back is not None:  # the session before a stray seqno ahead goes on (udp_bridge.JumpWatch)
                before, undo = back
                self.stray_jumps += 1
                _log.warning("hykin egm: a datagram with a seqno ahead of the session was a stray (the session goes "
                             "on from seqno %d)", before)
                self.last_seq, gap = before, (seq - before) % 2**32
            elif gap == 0 or gap >= 2**31:
                if not self.restart.restarted(seq, (self.last_seq - seq) % 2**32):
                    return Outcome(None, "ignored:stale seqno")
                self.retired = self.last_seq
                self.gaps.clear()
                gap = 1  # a new session: its own count
            elif gap > RESTART_BEHIND and self.retired is not None and \
                    ((seq - self.retired) % 2**32 <= RESTART_BEHIND or (seq - self.retired) % 2**32 >= 2**31):
                # far ahead, near or before the session of before a restart: maybe its stray datagram (as RSI)
                if not self.restart.restarted(seq, gap):
                    return Outcome(None, "ignored:seqno jump")
                gap = 1
            if back is None and gap > 2:  # (a return is no jump: its own gap is counted, less the undo)
                self.strays.jumped(self.last_seq, self.last_seq, gap - 1)
            elif back is None:
                self.strays.clear()
            if back is None and 1 < gap <= RESTART_BEHIND:  # (a stray's return: its jump was no gap)
                self.gaps.add(self.last_seq, gap - 1)
            elif back is not None:
                self.gaps.clear()
            skipped = gap - 1 - undo  # (a stray undone: its jump was not cycles the controller skipped)
        self.restart.clear()
        self.last_seq = seq
        try:
            T, kind, why = self.command(planned, joints, actual), "ok", ""
        except Exception as e:  # noqa: BLE001 - any internal failure: the planned pose, uncorrected
            why = str(e) if str(e).startswith(_CAUSES) else f"internal error: {type(e).__name__}: {e}"
            self.last_reason = why
            T, kind = planned, "failure"
        return Outcome(format_sensor(seq, tm, T), kind, skipped, why)
