"""Registration of a new measurement series (hykin.register): known rigid base + tool transforms
applied to a virtual robot's data are recovered."""

import numpy as np
import pytest

from hykin.calibration.frames import fit_frames, select_representative, select_spread
from hykin.geometry import se3
from hykin.hybrid.model import HybridModel
from hykin.io.dataset import Dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.measure.register import register_model

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.model.OutOfRangeWarning")

B_TRUE = se3.make_transform(se3.rotvec_to_matrix(np.array([0.3, -1.2, 2.0])), np.array([2.5, -1.0, 0.7]))
E_TRUE = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 2.1, 0.4])), np.array([0.05, -0.02, 0.13]))


@pytest.fixture(scope="module")
def rx160():
    return load_robot("rx160")


def _series(robot, n, noise_mm=0.0, noise_deg=0.0, seed=0, position_only=False):
    rng = np.random.default_rng(seed)
    q = robot.random_joints(n, rng)
    T = B_TRUE @ fk(robot, q) @ E_TRUE
    p = T[:, :3, 3] + rng.normal(0, noise_mm * 1e-3, (n, 3))
    R = se3.rotvec_to_matrix(rng.normal(0, np.radians(noise_deg), (n, 3))) @ T[:, :3, :3]
    quat = None if position_only else se3.matrix_to_quat(R)
    return Dataset(q=q, xyz_m=p, quat_wxyz=quat, source="virtual")


_MODELS = {}


def _model(robot):
    """A model trained on exact data in the robot frame: its networks learn a zero residual (output
    scale 1e-12), so it equals the classical robot to ~1e-12 m."""
    if robot.name not in _MODELS:
        q = robot.random_joints(200, np.random.default_rng(5))
        T = fk(robot, q)
        ds = Dataset(q=q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="exact")
        _MODELS[robot.name] = HybridModel(robot, calibrate=False, recipe_kw={"max_epochs": 1}, fade=False).fit(
            ds, progress=False)
    return _MODELS[robot.name]


def test_fit_frames_recovers_large_rotations_noise_free(rx160):
    ds = _series(rx160, 30)
    B, E = fit_frames(fk(rx160, ds.q), ds.poses())
    np.testing.assert_allclose(B, B_TRUE, atol=1e-9)
    np.testing.assert_allclose(E, E_TRUE, atol=1e-9)


def test_fit_frames_position_only_recovers_base_and_tool_offset(rx160):
    ds = _series(rx160, 30, position_only=True)
    E_pos = se3.trans(*E_TRUE[:3, 3])  # only the TCP offset is observable from positions
    T_model = fk(rx160, ds.q)
    Tm = np.tile(np.eye(4), (30, 1, 1))
    Tm[:, :3, 3] = (B_TRUE @ T_model @ E_pos)[:, :3, 3]
    B, E = fit_frames(T_model, Tm, position_only=True)
    np.testing.assert_allclose(B, B_TRUE, atol=1e-9)
    np.testing.assert_allclose(E[:3, 3], E_TRUE[:3, 3], atol=1e-9)


def test_register_model_30_poses_noise_free(rx160):
    ds = _series(rx160, 300)
    new, info = register_model(_model(rx160), ds, n_poses=30)
    assert info.n_used == 30 and len(np.unique(info.used_index)) == 30
    np.testing.assert_allclose(new.frame_pre_, B_TRUE, atol=1e-9)
    np.testing.assert_allclose(new.frame_post_, E_TRUE, atol=1e-9)
    assert info.rest_pos_mean_mm < 1e-6 and info.rest_ang_mean_deg < 1e-7


def test_register_model_with_noise_30_vs_all(rx160):
    ds = _series(rx160, 600, noise_mm=0.05, noise_deg=0.005, seed=1)
    m = _model(rx160)
    r30, _ = register_model(m, ds, n_poses=30)
    rall, _ = register_model(m, ds, n_poses=len(ds))
    truth = B_TRUE @ fk(rx160, ds.q) @ E_TRUE
    e30 = se3.pose_error(r30.predict(ds.q), truth)[0].mean()
    eall = se3.pose_error(rall.predict(ds.q), truth)[0].mean()
    meas30 = se3.pose_error(r30.predict(ds.q), ds.poses())[0].mean()
    measall = se3.pose_error(rall.predict(ds.q), ds.poses())[0].mean()
    assert e30 < 0.05 and eall < 0.01  # mm from the true frames; noise 0.05 mm per axis
    assert meas30 / measall < 1.10


def test_select_representative_is_spread_and_deterministic(rx160):
    ds = _series(rx160, 500, seed=2)
    a = select_representative(ds.poses(), 30, seed=0)
    b = select_representative(ds.poses(), 30, seed=0)
    np.testing.assert_array_equal(a, b)
    assert len(a) == 30 and len(np.unique(a)) == 30 and a.max() < 500
    np.testing.assert_array_equal(select_representative(ds.poses(), 600), np.arange(500))
    assert len(select_spread(ds.q, 30)) == 30


def test_register_rejects_bad_input(rx160):
    ds = _series(rx160, 10)
    with pytest.raises(ValueError):
        register_model(_model(rx160), ds, n_poses=2)
    with pytest.raises(ValueError):
        register_model(_model(rx160), ds, select="nope")


def test_registered_model_fades_with_the_nearest_neighbour_gap(rx160):
    import copy

    m = copy.deepcopy(_model(rx160))
    m.fade = True
    new, _ = register_model(m, _series(rx160, 100), n_poses=30)
    assert new.fade == "full" and m.fade is True  # the original model is untouched
    m.fade = "range"
    assert register_model(m, _series(rx160, 100), n_poses=30)[0].fade == "range"


def test_register_model_returns_a_new_model_and_leaves_the_input_unchanged(rx160):
    """Registration is not fitting the given model: the input model's predictions, frames, fade and
    calibrated robot are bit-identical afterwards, also when joint zero offsets are re-fitted."""
    import copy

    m = copy.deepcopy(_model(rx160))
    m.fade = True
    q = rx160.random_joints(200, np.random.default_rng(11)) * 1.2  # partly outside the trained range
    before = m.predict(q), m.predict_classical(q), m.fade_weight(q)
    rob_before = copy.deepcopy(m.robot_)
    # a series whose joint 2 zero is off by 0.5 mrad: the copy re-fits it into its calibrated robot
    shifted = rx160.copy(theta_rad=rx160.theta_rad + np.r_[0.0, 5e-4, 0.0, 0.0, 0.0, 0.0])
    qs = rx160.random_joints(300, np.random.default_rng(12))
    T = B_TRUE @ fk(shifted, qs) @ E_TRUE
    series = Dataset(q=qs, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="shifted")
    new, info = register_model(m, series, n_poses=40)
    assert new is not m and new.robot_ is not m.robot_
    assert any(p.name.startswith("q2") for p in info.parameters)  # the copy's robot was changed
    for a, b in zip(before, (m.predict(q), m.predict_classical(q), m.fade_weight(q))):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(m.frame_pre_, np.eye(4))
    np.testing.assert_array_equal(m.frame_post_, np.eye(4))
    assert m.fade is True and new.fade == "full"
    np.testing.assert_array_equal(m.robot_.theta_rad, rob_before.theta_rad)
    assert not np.allclose(new.robot_.theta_rad, rob_before.theta_rad)
