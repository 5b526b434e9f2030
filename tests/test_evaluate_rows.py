"""Issue 24: `evaluate` rows that mean what they say. The nominal row of tracker-frame data is the
nominal robot with base and tool fitted to the poses, labelled so (not 3,571 mm of frame offset);
data in the robot's own frame keep the robot file's frames; one definition for registered models."""

import json

import numpy as np
import pytest

from hykin.calibration.frames import fit_frames
from hykin.evaluation.evaluate import NOMINAL_FITTED, ROBOT_FILE, evaluate_model
from hykin.geometry import se3
from hykin.io.dataset import Dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk

ROB = load_robot("rx160")
TRACKER = se3.make_transform(se3.rotvec_to_matrix(np.array([0.4, -0.2, 2.2])), np.array([2.8, -1.7, 0.9]))


def _data(frame, seed=0, n=200):
    rng = np.random.default_rng(seed)
    q = ROB.random_joints(n, rng)
    truth = ROB.copy(theta_rad=ROB.theta_rad + np.radians([0, 0.05, -0.04, 0.03, 0, 0]))
    T = frame @ fk(truth, q)
    T[:, :3, 3] += rng.normal(0, 2e-5, (n, 3))
    return Dataset(q=q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="d.csv")


def test_tracker_frame_nominal_row_is_fitted_and_labelled():
    ds = _data(TRACKER)
    res = evaluate_model(ROB, ds)
    assert res.labels["nominal"] == NOMINAL_FITTED
    # independent reference: the rigid fit of the nominal poses onto the data, errors averaged
    Tn = fk(ROB, ds.q)
    B, E = fit_frames(Tn, ds.poses())
    ref = np.linalg.norm((B @ Tn @ E)[:, :3, 3] - ds.xyz_m, axis=1).mean() * 1e3
    assert res.stats["nominal"].pos_mean_mm == pytest.approx(ref, rel=1e-6)
    assert res.stats["nominal"].pos_mean_mm < 5.0  # not metres of frame offset
    assert NOMINAL_FITTED in res.table() and "fitted to these poses" in res.table()
    assert json.loads(res.json())["labels"]["nominal"] == NOMINAL_FITTED
    # and the file as written, first: what fk / ik / compensate would give with it (metres off here)
    assert list(res.stats)[0] == "file" and res.labels["file"] == ROBOT_FILE
    as_written = np.linalg.norm(Tn[:, :3, 3] - ds.xyz_m, axis=1).mean() * 1e3
    assert res.stats["file"].pos_mean_mm == pytest.approx(as_written, rel=1e-12) and as_written > 1000
    assert ROBOT_FILE in res.table() and "a tool offset held at its prior" in res.table()


def test_robot_frame_nominal_row_keeps_the_robot_file_frames():
    ds = _data(np.eye(4))
    res = evaluate_model(ROB, ds)
    assert res.labels["nominal"] == "nominal" and "file" not in res.stats  # one row: the file's frames fit
    ref = np.linalg.norm(fk(ROB, ds.q)[:, :3, 3] - ds.xyz_m, axis=1).mean() * 1e3
    assert res.stats["nominal"].pos_mean_mm == pytest.approx(ref, rel=1e-12)
