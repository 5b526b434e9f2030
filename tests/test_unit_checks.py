"""Issue 24: unit checks judge the spread of the data against the robot's reach, never absolute
coordinates, and ``--no-unit-check`` turns them off everywhere.

A total station 10-50 m (or a tracker kilometres) from the robot is normal and must be accepted; a
mm <-> m slip and radians <-> degrees must still be refused, in any frame."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hykin.geometry import se3
from hykin.io.dataset import DatasetError, spread_limit_m
from hykin.io.dataset_files import read_dataset
from hykin.io.plausibility import PlausibilityError
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.kinematics.robot import robot_reach_m

ROB = load_robot("ur5")


def _far(seed: int, distance_m: float):
    """Joints (rad) and positions (m) of the UR5 seen from an instrument ``distance_m`` away."""
    rng = np.random.default_rng(seed)
    q = ROB.random_joints(40, rng)
    d = rng.normal(size=3)
    F = se3.make_transform(se3.rotvec_to_matrix(rng.normal(size=3)), distance_m * d / np.linalg.norm(d))
    return q, (F @ fk(ROB, q))[:, :3, 3]


def _csv(path, q, xyz):
    n = q.shape[1]
    header = ",".join([f"q{i + 1}" for i in range(n)] + ["x", "y", "z"])
    np.savetxt(path, np.c_[q, xyz], delimiter=",", header=header, comments="", fmt="%.17g")
    return path


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 10_000), log_d=st.floats(1.0, 3.7))
def test_far_instrument_accepted_and_slips_refused(tmp_path_factory, seed, log_d):
    """10 m .. 5 km away: accepted as metres; the same numbers in mm declared m, or metres declared
    mm, are refused (with and without the robot); rad declared deg is refused."""
    tmp = tmp_path_factory.mktemp("u")
    q, xyz = _far(seed, 10.0**log_d)
    ds = read_dataset(_csv(tmp / "m.csv", q, xyz), robot=ROB)
    np.testing.assert_allclose(ds.xyz_m, xyz, rtol=1e-15)
    read_dataset(tmp / "m.csv")  # no robot: accepted too (spread, not distance)
    mm = _csv(tmp / "mm.csv", q, xyz * 1e3)
    for rob in (ROB, None):
        with pytest.raises(DatasetError, match="millimetres passed as metres"):
            read_dataset(mm, robot=rob)
    np.testing.assert_allclose(read_dataset(mm, robot=ROB, length_unit="mm").xyz_m, xyz, rtol=1e-12)
    with pytest.raises(PlausibilityError, match="metres declared --length-unit mm"):
        read_dataset(tmp / "m.csv", robot=ROB, length_unit="mm")
    with pytest.raises((PlausibilityError, DatasetError), match="radians"):
        read_dataset(tmp / "m.csv", robot=ROB, angle_unit="deg")


def test_no_unit_check_turns_every_unit_check_off(tmp_path):
    q, xyz = _far(1, 30.0)
    mm = _csv(tmp_path / "mm.csv", q, xyz * 1e3)
    ds = read_dataset(mm, robot=ROB, unit_check=False)
    assert ds.meta["unit_check"] is False
    np.testing.assert_allclose(ds.xyz_m, xyz * 1e3)
    deg = _csv(tmp_path / "deg.csv", np.degrees(q), xyz)
    with pytest.raises(DatasetError):
        read_dataset(deg, robot=ROB)  # degrees read as radians
    # (joint limits still apply with the unit checks off: the UR5's are +-2 pi)


def test_spread_limit_scales_with_the_robot():
    """A big robot may spread its positions further than a small one before it looks like mm."""
    small, big = load_robot("ur5"), load_robot("rx160")
    assert spread_limit_m(small) == pytest.approx(10 * robot_reach_m(small))
    assert spread_limit_m(big) > spread_limit_m(small)
    assert spread_limit_m(None) == 50.0


def test_cli_fit_evaluate_accept_a_total_station_30_m_away(tmp_path, capsys):
    """The reported refusal ("millimetres passed as metres", also with --no-unit-check) through the
    CLI: evaluate reads tracker-frame data 30 m away; the mm slip is refused with one line; and
    --no-unit-check lets it through to the next check."""
    from hykin.cli import main

    q, xyz = _far(2, 30.0)
    good = _csv(tmp_path / "good.csv", q, xyz)
    with pytest.raises(SystemExit) as e:
        main(["evaluate", "ur5", str(good), "--json"])
    assert e.value.code in (0, None)
    bad = _csv(tmp_path / "bad.csv", q, xyz * 1e3)
    with pytest.raises(SystemExit) as e:
        main(["evaluate", "ur5", str(bad)])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "millimetres" in err[0], err


def test_joints_beyond_2pi_inside_the_robot_limits_are_radians(tmp_path):
    """An IRB2400-like axis 6 of ±400°: 6.73 rad (385.5°) is a correct value in radians, not degrees."""
    import math

    from hykin.io.dataset import DatasetError, validate_joints
    from hykin.io.robot_file import load_robot

    rob = load_robot("abb-irb2400")
    rob = rob.copy(lower=np.r_[rob.lower[:5], -math.radians(400)], upper=np.r_[rob.upper[:5], math.radians(400)])
    q = np.zeros((3, 6))
    q[1, 5] = math.radians(385.5)
    validate_joints(q, rob)  # accepted
    q[1, 5] = 45.0  # degrees read as radians: beyond 2π and the limits
    with pytest.raises(DatasetError, match="beyond ±2π and the robot limits: likely degrees passed as radians"):
        validate_joints(q, rob)
