"""The nominal row of ``hykin evaluate`` on a model fitted in the robot's base frame with the file's tool:
the robot file as written, not a rigid fit to the test poses (probe report s40: on poses within ±5° of one
pose the fit absorbed most of the geometric error, 5.63 mm shown as 0.19 mm). Data from a moved tracker are
still refused. Reference: the nominal FK against the truth's poses, computed here."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from hykin.geometry import se3
from hykin.io.dataset import Dataset
from hykin.kinematics.fk import fk


def _data(robot, q):
    xyz, quat = se3.transform_to_pose(fk(robot, q))
    return Dataset(q=q, xyz_m=xyz, quat_wxyz=quat, source="test")


@pytest.fixture(scope="module")
def base_frame_model():
    from hykin.calibration.params import apply_deviations
    from hykin.hybrid.model import HybridModel
    from hykin.io.robot_file import load_robot

    rob = load_robot("rx160")
    truth = apply_deviations(rob, {"a2": 2e-3, "a3": -1.5e-3, "d4": 1.8e-3, "theta3": 2e-3, "alpha3": -1.5e-3})
    q = rob.random_joints(150, np.random.default_rng(2), margin=0.05)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        # no calibration (seconds saved): the model's frames are the file's, as a calibration on base-frame data
        # with the file's tool leaves them (within FILE_FRAMES_MM)
        m = HybridModel(rob, seed=0, calibrate=False, recipe_kw={"max_epochs": 1}, uncertainty=False).fit(
            _data(truth, q), progress=False)
    return m, rob, truth


def test_nominal_row_on_a_small_region_is_the_file_as_written(base_frame_model):
    from hykin.evaluation.evaluate import evaluate_model

    m, rob, truth = base_frame_model
    q0 = np.radians([20.0, -30.0, 100.0, 10.0, 40.0, 15.0])
    q = q0 + np.radians(np.random.default_rng(3).uniform(-5.0, 5.0, (40, 6)))
    test = _data(truth, q)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = evaluate_model(m, test)
    want = np.linalg.norm(fk(rob, q)[:, :3, 3] - test.xyz_m, axis=1).mean() * 1e3
    assert res.labels.get("nominal", "nominal") == "nominal"
    assert res.stats["nominal"].pos_mean_mm == pytest.approx(want, rel=1e-9)
    assert want > 1.0


def test_moved_tracker_data_are_still_refused(base_frame_model):
    from hykin.evaluation.evaluate import FrameMismatchError, evaluate_model

    m, rob, truth = base_frame_model
    q = rob.random_joints(40, np.random.default_rng(4), margin=0.1)
    W = se3.trans(1.5, -0.4, 0.2) @ se3.rotz(0.6)
    xyz, quat = se3.transform_to_pose(W @ fk(truth, q))
    with pytest.raises(FrameMismatchError), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        evaluate_model(m, Dataset(q=q, xyz_m=xyz, quat_wxyz=quat, source="moved"))
