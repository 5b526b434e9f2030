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


@pytest.mark.slow  # a full refused calibration; test_shift_found_by_a_stub_calibration covers the rule fast
@pytest.mark.parametrize("lead", [1, -1])
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


@pytest.mark.parametrize("lead", [1, -1])
def test_shift_found_by_a_stub_calibration(lead):
    """rows_out_of_step with a stand-in calibration whose residual is the noise only where each measurement
    sits with its own joints (a joint column equal to the row number tells which): the direction is named,
    and data that fit no shift give no note."""
    from types import SimpleNamespace

    from hykin.calibration.outliers import rows_out_of_step

    n = 60
    q = np.tile(np.arange(n, dtype=float)[:, None], (1, 6))
    meas = np.arange(n, dtype=float) + lead  # row i measured the pose of joints row i + lead
    ds = Dataset(q=q, xyz_m=np.c_[meas, np.zeros(n), np.zeros(n)], source="s.csv")

    def recal(d, position_only):
        assert position_only
        aligned = np.all(d.q[:, 0] == d.xyz_m[:, 0])
        return SimpleNamespace(after={"pos_rms_mm": 0.02 if aligned else 40.0})

    note = rows_out_of_step(ds, 40.0, recal)
    words = "next" if lead == 1 else "previous"
    assert f"each row's measurement belongs to the {words} row's joints" in note and "0.02 mm RMS instead of 40" in note
    assert rows_out_of_step(Dataset(q=q, xyz_m=np.c_[meas + 7, np.zeros(n), np.zeros(n)]), 40.0, recal) == ""
