"""A file whose joints and measurements are one row out of step (a row missing at the top of one file)
is refused by the calibration naming that cause, tested by the data: shifted back, the positions fit
to the noise. Reference: the exact robot the data were simulated with."""

from __future__ import annotations

import numpy as np
import pytest

from hykin.calibration.calibrate import CalibrationError, calibrate
from hykin.io.dataset import Dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk


@pytest.mark.parametrize("lead", [1, pytest.param(-1, marks=pytest.mark.slow)])
def test_one_row_shift_named(lead):
    rob = load_robot("ur5")
    rng = np.random.default_rng(4)
    q = rob.random_joints(61, rng)
    xyz = fk(rob, q)[:, :3, 3] + rng.normal(0, 20e-6, (61, 3))
    if lead == 1:  # row i: joints i, measurement of pose i + 1
        ds = Dataset(q=q[:-1], xyz_m=xyz[1:], source="shift.csv")
    else:
        ds = Dataset(q=q[1:], xyz_m=xyz[:-1], source="shift.csv")
    with pytest.raises(CalibrationError) as e:
        calibrate(rob, ds)
    msg = str(e.value)
    words = "next" if lead == 1 else "previous"
    assert f"one row out of step (each row's measurement belongs to the {words} row's joints" in msg, msg
    rms = float(msg.split("the positions leave ")[1].split(" mm RMS")[0])
    assert rms < 0.05  # the noise: 20 um per coordinate is 0.035 mm RMS distance


def test_correct_file_unaffected():
    rob = load_robot("ur5")
    rng = np.random.default_rng(5)
    q = rob.random_joints(60, rng)
    ds = Dataset(q=q, xyz_m=fk(rob, q)[:, :3, 3] + rng.normal(0, 20e-6, (60, 3)), source="ok.csv")
    assert calibrate(rob, ds).after["pos_rms_mm"] < 0.05
