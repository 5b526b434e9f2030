"""``hykin rsi`` near gimbal lock (KRL ``B = ±90°``): a small real correction is sent, not refused.

KRL ``A B C`` are Z-Y'-X'' Euler angles in degrees; the reference here is scipy's
``Rotation.from_euler("ZYX", [A, B, C], degrees=True)`` (independent of :mod:`hykin.compensation.krl`).
RSI's absolute mode adds ``RKorr`` to the setpoint componentwise; incremental mode adds up the answers.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hykin.realtime.rsi import RsiHandler, korr_of
from hykin.realtime.rsi_xml import RsiConfig, format_rob, parse_sen

B_VALUES = (85.0, 89.9, 89.99, 90.0, -90.0)
TWISTS = ([0.0, 0.05, 0.0], [0.0, 0.0, -0.05], [0.03, -0.02, 0.04], [0.0, -0.01, 0.0], [0.002, 0.001, -0.003])


def _R(abc) -> np.ndarray:
    return Rotation.from_euler("ZYX", np.asarray(abc, dtype=np.float64), degrees=True).as_matrix()


def _T(xyzabc) -> np.ndarray:
    v = np.asarray(xyzabc, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = _R(v[3:]), v[:3] * 1e-3
    return T


def _angle_deg(Ra, Rb) -> float:
    return float(np.degrees(Rotation.from_matrix(Ra @ Rb.T).magnitude()))


class _Result:
    def __init__(self, command):
        self.command, self.success, self.reason, self.q = command, True, "", np.zeros(6)


def _command(sp, twist_deg, shift_mm=(0.3, -0.2, 0.1)) -> np.ndarray:
    """The setpoint's pose turned by ``twist_deg`` (rotation vector, tool frame) and shifted (mm)."""
    T = _T(sp)
    T[:3, :3] = T[:3, :3] @ Rotation.from_rotvec(np.radians(twist_deg)).as_matrix()
    T[:3, 3] += np.asarray(shift_mm) * 1e-3
    return T


class _FixedStep:
    """A compensator that answers a preset command per call (the handler's ``step``)."""

    def __init__(self):
        self.next = None

    def __call__(self, T, q_prev):
        return _Result(self.next)


def _handler(mode: str, max_deg: float = 5.0):
    step = _FixedStep()
    cfg = RsiConfig(mode=mode)
    return RsiHandler(step, np.eye(4), 6, np.ones(6), cfg, max_correction_mm=50.0, max_correction_deg=max_deg), step, cfg


@pytest.mark.parametrize("B", B_VALUES)
@pytest.mark.parametrize("twist", TWISTS)
def test_absolute_correction_near_gimbal_lock_gives_the_command(B, twist):
    h, step, cfg = _handler("absolute")
    sp = np.array([500.0, 100.0, 300.0, 30.0, B, 170.0])
    cmd = _command(sp, twist)
    step.next = cmd
    out = h(format_rob(1000, sp, sp, np.zeros(6), cfg))
    assert out.kind == "ok", h.last_reason
    ipoc, k = parse_sen(out.reply, cfg)  # as written (5 decimals)
    assert ipoc == 1000 and np.abs(k[3:]).max() > 0 and np.abs(k).max() > 0
    got = sp + k  # what RSI commands in absolute mode
    assert np.abs(got[:3] * 1e-3 - cmd[:3, 3]).max() < 1e-8
    # rounding to 1e-5 deg per angle: the pose is met to ~2e-5 deg
    assert _angle_deg(_R(got[3:]), cmd[:3, :3]) < 3e-5
    assert _angle_deg(_R(sp[3:]), cmd[:3, :3]) == pytest.approx(np.linalg.norm(twist), rel=1e-6, abs=1e-9)


@pytest.mark.parametrize("B", B_VALUES)
def test_korr_of_is_the_command_and_crosses_b90_without_flipping(B):
    sp = np.array([500.0, 100.0, 300.0, 30.0, B, 170.0])
    for twist in TWISTS:
        cmd = _command(sp, twist)
        k = korr_of(cmd, sp)
        assert np.abs(k[3:]).max() <= 180
        assert _angle_deg(_R(sp[3:] + k[3:]), cmd[:3, :3]) < 1e-9
        # of the two Euler solutions, the componentwise-nearest one: dB stays small (no 180-B flip)
        assert abs(k[4]) <= np.linalg.norm(twist) + 1e-9


@pytest.mark.parametrize("B", (-60.0, 0.0, 45.0, 80.0))
def test_far_from_b90_the_correction_is_the_plain_difference(B):
    """Away from gimbal lock, the correction is the difference of scipy's own ZYX angles (|B| < 90)."""
    sp = np.array([400.0, -50.0, 600.0, -120.0, B, 30.0])
    for twist in TWISTS + ([1.0, -2.0, 0.5],):
        cmd = _command(sp, twist)
        ref = Rotation.from_matrix(cmd[:3, :3]).as_euler("ZYX", degrees=True)
        d = (ref - sp[3:] + 180) % 360 - 180
        k = korr_of(cmd, sp)
        assert np.abs(k[3:] - d).max() < 1e-9
        assert np.abs(k[:3] - (cmd[:3, 3] * 1e3 - sp[:3])).max() < 1e-9


def test_incremental_sum_gives_the_command_across_b90():
    h, step, cfg = _handler("incremental")
    total = np.zeros(6)
    rng = np.random.default_rng(3)
    ipoc = 100
    for B in (85.0, 89.9, 89.99, 90.0, 89.99, -90.0, -89.99, 89.999, 60.0):
        for _ in range(3):
            sp = np.array([500.0, 100.0, 300.0, 30.0 + rng.normal(), B, 170.0 + rng.normal()])
            twist = rng.normal(0, 0.05, 3)
            cmd = _command(sp, twist, rng.normal(0, 0.5, 3))
            step.next = cmd
            ipoc += 4
            out = h(format_rob(ipoc, sp, sp, np.zeros(6), cfg))
            assert out.kind == "ok", h.last_reason
            total += parse_sen(out.reply, cfg)[1]
            got = sp + total
            assert np.abs(got[:3] * 1e-3 - cmd[:3, 3]).max() < 1e-7
            assert _angle_deg(_R(got[3:]), cmd[:3, :3]) < 2e-4  # rounding of each answer adds up


@pytest.mark.parametrize("B", (0.0, 89.99, 90.0))
def test_limit_is_on_the_real_rotation_and_shift(B):
    h, step, cfg = _handler("absolute", max_deg=1.0)
    sp = np.array([500.0, 100.0, 300.0, 30.0, B, 170.0])
    step.next = _command(sp, [0.0, 0.9, 0.0])  # 0.9 deg about y: within the 1 deg limit
    out = h(format_rob(10, sp, sp, np.zeros(6), cfg))
    assert out.kind == "ok", h.last_reason
    step.next = _command(sp, [0.0, 0.8, 0.8])  # 1.13 deg: over it
    out = h(format_rob(14, sp, sp, np.zeros(6), cfg))
    assert out.kind == "failure" and "over the limit" in h.last_reason
    assert not parse_sen(out.reply, cfg)[1].any()
    step.next = _command(sp, [0.0, 0.1, 0.0], shift_mm=(40.0, 29.9, 0.0))  # 49.94 mm: within the 50 mm limit
    assert h(format_rob(18, sp, sp, np.zeros(6), cfg)).kind == "ok"
    step.next = _command(sp, [0.0, 0.1, 0.0], shift_mm=(40.0, 30.1, 0.0))  # over 50 mm
    assert h(format_rob(22, sp, sp, np.zeros(6), cfg)).kind == "failure"
