"""hykin.streams: clock offset recovery on simulated 110 Hz robot + 3 kHz tracker streams."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from hykin.geometry import se3
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.measure.streams import (
    StreamError,
    align_streams,
    estimate_clock,
    estimate_time_offset,
    resample_tracker,
    tcp_speed,
)
from shared_fixtures import sine_trajectory

B = se3.xyzrpy_to_transform([2.0, -1.0, 0.3], [0.1, -0.2, 1.0])  # robot base in tracker frame
OFFSET = 0.0373


def _traj(seed=1):
    return sine_trajectory(seed)


def _streams(T=20.0, offset=OFFSET, drift=0.0, noise=15e-6, dropouts=8, seed=1):
    """Robot clock = true time (110 Hz, 0.1 ms jitter); tracker clock t_k = t_true + offset + drift (t_true - T/2)."""
    rng = np.random.default_rng(seed)
    robot = load_robot("rx160")
    Q = _traj(seed)
    t_r = np.arange(0, T, 1 / 110) + rng.normal(0, 1e-4, int(np.ceil(T * 110)))
    t_t = np.arange(-0.5, T + 0.5, 1 / 3000)
    t_true = (t_t - offset + drift * T / 2) / (1 + drift)
    Tw = B @ fk(robot, Q(t_true))
    p = Tw[:, :3, 3] + rng.normal(0, noise, (t_t.size, 3))
    quat = se3.matrix_to_quat(Tw[:, :3, :3])
    for s in rng.uniform(0, T, dropouts):  # 50 ms beam breaks
        p[(t_t > s) & (t_t < s + 0.05)] = np.nan
    return robot, Q, t_r, t_t, p, quat


@pytest.mark.parametrize("method", ["speed", "positions"])
def test_offset_recovered(method):
    robot, Q, t_r, t_t, p, _ = _streams()
    c = estimate_clock(t_r, Q(t_r), t_t, p, robot, method=method)
    assert abs(c.offset_s - OFFSET) < 1e-4  # brief asks <= 1 ms; measured a few microseconds
    assert abs(c.coarse_offset_s - OFFSET) < 1e-4
    assert 0 < c.offset_std_s < 1e-4 and abs(c.offset_s - OFFSET) < 5 * c.offset_std_s + 2e-6
    assert 0.5 * 15e-6 * np.sqrt(3) < c.rms_m < 2 * 15e-6 * np.sqrt(3)
    np.testing.assert_allclose(c.T_tracker_base, B, atol=1e-5)
    assert estimate_time_offset(t_r, Q(t_r), t_t, p, robot, method=method) == pytest.approx(c.offset_s)


def test_p_robot_input_and_model_errors():
    """Tracker sees a robot with mm-level DH errors; the offset is estimated with the nominal model."""
    rng = np.random.default_rng(9)
    nom = load_robot("rx160")
    true = nom.copy(a_m=nom.a_m + rng.normal(0, 1e-3, 6), d_m=nom.d_m + rng.normal(0, 1e-3, 6),
                    theta_rad=nom.theta_rad + rng.normal(0, 1e-3, 6), alpha_rad=nom.alpha_rad + rng.normal(0, 1e-3, 6))
    Q = _traj(1)
    t_r = np.arange(0, 20, 1 / 110)
    t_t = np.arange(-0.5, 20.5, 1 / 3000)
    p = (B @ fk(true, Q(t_t - OFFSET)))[:, :3, 3] + rng.normal(0, 15e-6, (t_t.size, 3))
    model_err = np.linalg.norm(fk(true, Q(t_r))[:, :3, 3] - fk(nom, Q(t_r))[:, :3, 3], axis=1).mean()
    assert model_err > 2e-3
    c = estimate_clock(t_r, None, t_t, p, p_robot=fk(nom, Q(t_r))[:, :3, 3])
    assert abs(c.offset_s - OFFSET) < 1e-3


def test_negative_offset_and_drift():
    drift = 50e-6
    robot, Q, t_r, t_t, p, _ = _streams(T=60.0, offset=-0.121, drift=drift, seed=2)
    c = estimate_clock(t_r, Q(t_r), t_t, p, robot, fit_drift=True)  # 12 windows of 5 s
    assert abs(c.offset_s + 0.121) < 1e-4
    assert abs(c.drift - drift) < 5e-6 and abs(c.drift - drift) < 5 * c.drift_std
    c2 = estimate_clock(t_r, Q(t_r), t_t, p, robot, fit_drift=True, method="positions")
    assert abs(c2.offset_s + 0.121) < 1e-5 and abs(c2.drift - drift) < 1e-6
    t_q = np.array([5.0, 55.0])
    t_true_tr = t_q - 0.121 + drift * (t_q - 30.0)
    np.testing.assert_allclose(c.to_tracker_time(t_q), t_true_tr, atol=1e-4)
    with pytest.raises(StreamError, match="windows"):
        estimate_clock(t_r[:800], Q(t_r[:800]), t_t, p, robot, fit_drift=True)


def test_resample_linear_and_slerp():
    t = np.linspace(0, 1, 101)
    p = np.c_[t, 2 * t, -t] * 0.1
    axis = np.array([1.0, 2.0, 2.0]) / 3
    quat = Rotation.from_rotvec(np.outer(0.8 * t, axis)).as_quat(scalar_first=True)
    p[40:43] = np.nan  # lost beam: 3 rows -> gap of 0.04 s
    tq = np.array([0.005, 0.2531, 0.415, 0.995, 1.2])
    r = resample_tracker(tq, t, p, quat, max_gap_s=0.015)
    assert r.valid.tolist() == [True, True, False, True, False]
    np.testing.assert_allclose(r.p[r.valid], np.c_[tq, 2 * tq, -tq][r.valid] * 0.1, atol=1e-15)
    ref = Rotation.from_rotvec(np.outer(0.8 * tq[r.valid], axis)).as_quat(scalar_first=True)
    np.testing.assert_allclose(r.quat_wxyz[r.valid], ref, atol=1e-12)
    assert np.isnan(r.p[~r.valid]).all() and np.isnan(r.quat_wxyz[~r.valid]).all()
    with pytest.raises(StreamError, match="strictly increasing"):
        resample_tracker(tq, t[::-1], p)
    with pytest.raises(StreamError, match="shape"):
        resample_tracker(tq, t, p[:, :2])


def test_align_streams():
    robot, Q, t_r, t_t, p, quat = _streams(seed=3)
    a = align_streams(t_r, Q(t_r), t_t, p, quat, robot, T_base_tracker=se3.invert(B), max_speed_m_s=0.25)
    info = a.info
    assert abs(info["offset_s"] - OFFSET) < 1e-4
    speed = tcp_speed(t_r, fk(robot, Q(t_r))[:, :3, 3])
    assert not a.mask[speed > 0.25].any() and info["n_dropped_speed"] > 0 and info["n_dropped_gap"] > 0
    assert a.mask.sum() == info["n_kept"] == len(a.q) > 0.5 * len(t_r)
    Tm = fk(robot, a.q)
    # position error at kept samples: tracker noise (15 um) plus speed * timing error
    err = np.linalg.norm(a.xyz_m - Tm[:, :3, 3], axis=1)
    assert err.max() < 1e-4
    pos_mm, ang_deg = se3.pose_error(se3.pose_to_transform(a.xyz_m, a.quat_wxyz), Tm)
    assert ang_deg.max() < 1e-3
    # with a deliberately wrong 5 ms offset the errors are much larger
    b = align_streams(t_r, Q(t_r), t_t, p, None, robot, clock=OFFSET + 0.005, T_base_tracker=se3.invert(B),
                      max_speed_m_s=0.25)
    assert np.linalg.norm(b.xyz_m - fk(robot, b.q)[:, :3, 3], axis=1).mean() > 10 * err.mean()
    if a.dataset is not None:
        assert a.dataset.q.shape == a.q.shape
    with pytest.raises(StreamError):
        align_streams(t_r, Q(t_r)[:-1], t_t, p, None, robot, clock=0.0)
