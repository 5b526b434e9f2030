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

import numpy as np

from ..compensation.krl import abc_from_matrix, matrix_from_abc
from ..geometry import se3
from .rsi_xml import RsiConfig, RsiMessageError, format_sen, parse_rob
from .udp_bridge import Outcome, RestartWatch

__all__ = ["DECIMALS", "RsiHandler", "korr_of", "pose_of"]

DECIMALS = 5  # of RKorr as written (mm, deg)
RESTART_BEHIND_MS = 1000  # an IPOC this far behind the last answered one may be a restarted controller


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
    """

    def __init__(self, step, base: np.ndarray, dof: int, axis_signs, cfg: RsiConfig, period_ms: float = 4.0,
                 max_correction_mm: float = 50.0, max_correction_deg: float = 5.0):
        self.step, self.base, self.dof, self.cfg = step, np.asarray(base, dtype=np.float64), dof, cfg
        self.signs = np.asarray(axis_signs, dtype=np.float64)
        self.period_ms = float(period_ms)
        self.max_mm, self.max_deg = float(max_correction_mm), float(max_correction_deg)
        self.last_ipoc: int | None = None
        self.restart = RestartWatch(RESTART_BEHIND_MS, int(10 * max(self.period_ms, 1.0)))
        self.sent_sum = np.zeros(6)  # incremental mode: what the controller has added up
        self.last_reason = ""

    def correction(self, setpoint, axes_deg) -> np.ndarray:
        """The absolute correction ``(6,)`` for one setpoint (ValueError with the reason on failure)."""
        q = np.radians(np.asarray(axes_deg, dtype=np.float64)) * self.signs
        r = self.step(self.base @ pose_of(setpoint), q)
        if not r.success:
            raise ValueError(f"not compensated: {r.reason}")
        k = korr_of(r.command, setpoint)
        # the limits are on the real shift and rotation (as ``hykin egm``): near B = ±90° a tiny rotation
        # has large componentwise dA, dC
        dp, da = se3.pose_error(np.asarray(r.command, dtype=np.float64)[None], pose_of(setpoint)[None])
        if not (np.isfinite(k).all() and dp[0] <= self.max_mm and da[0] <= self.max_deg):
            raise ValueError(f"correction {dp[0]:.2f} mm / {da[0]:.3f} deg over the limit "
                             f"({self.max_mm:g} mm, {self.max_deg:g} deg)")
        return k

    def __call__(self, data: bytes) -> Outcome:
        try:
            msg = parse_rob(data, self.cfg, self.dof)
        except RsiMessageError as e:
            self.last_reason = str(e)
            return Outcome(None, "ignored:malformed")
        if self.last_ipoc is not None and msg.ipoc <= self.last_ipoc:
            if not self.restart.restarted(msg.ipoc, self.last_ipoc - msg.ipoc):
                return Outcome(None, "ignored:stale IPOC")
            self.last_ipoc, self.sent_sum = None, np.zeros(6)  # a new RSI context: its own count and sum
        self.restart.clear()
        skipped = 0
        if self.last_ipoc is not None:
            skipped = max(int(round((msg.ipoc - self.last_ipoc) / self.period_ms)) - 1, 0)
        self.last_ipoc = msg.ipoc
        try:
            k = self.correction(msg.setpoint, msg.axes_deg)
            kind = "ok"
        except Exception as e:  # noqa: BLE001 - any internal failure: neutral answer, the robot goes on
            self.last_reason = f"{type(e).__name__}: {e}"
            k, kind = None, "failure"
        if self.cfg.mode == "incremental":  # the sum as the controller adds it: of the values as written
            if k is None:
                send = np.zeros(6)
            else:  # angle increments modulo 360° (the controller's sum describes the same pose)
                inc = k - self.sent_sum
                inc[3:] = np.where(np.abs(inc[3:]) > 180.0, _wrap(inc[3:]), inc[3:])
                send = np.round(inc, DECIMALS)
            self.sent_sum = self.sent_sum + send
        else:
            send = np.zeros(6) if k is None else k
        return Outcome(format_sen(msg.ipoc, send, self.cfg), kind, skipped)
