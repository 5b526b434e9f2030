"""Issue 24: registration that decides on evidence.

* the consistency test is a chi-square test of residuals normalised by the expected scale (checked
  against scipy and by its rejection rate on data that do fit);
* a model that predicts the registration poses worse than the nominal model with frames falls back
  to it (leave-one-pose-out), one that predicts them better is kept;
* a calibrated-only robot (a TOML robot file) is registered, through the API and the CLI;
* a series that fits neither is refused with one line; ``alpha=0`` never refuses."""

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from hykin.calibration.frames import fit_frames
from hykin.geometry import se3
from hykin.io.dataset import Dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.measure.register import register_model
from hykin.measure.register_checks import BAND_TO_SIGMA, RegistrationError, consistency_test
from hykin.measure.robot_model import RobotModel

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.model.OutOfRangeWarning")

B_TRUE = se3.make_transform(se3.rotvec_to_matrix(np.array([0.3, -1.2, 2.0])), np.array([25.0, -10.0, 0.7]))
E_TRUE = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.4, 0.1])), np.array([0.01, -0.02, 0.13]))


def _series(robot, n=150, noise_mm=0.02, noise_deg=0.002, seed=0, source="series.csv"):
    rng = np.random.default_rng(seed)
    q = robot.random_joints(n, rng)
    T = B_TRUE @ fk(robot, q) @ E_TRUE
    p = T[:, :3, 3] + rng.normal(0, noise_mm * 1e-3, (n, 3))
    R = se3.rotvec_to_matrix(rng.normal(0, np.radians(noise_deg), (n, 3))) @ T[:, :3, :3]
    return Dataset(q=q, xyz_m=p, quat_wxyz=se3.matrix_to_quat(R), source=source)


@pytest.fixture(scope="module")
def rx160():
    return load_robot("rx160")


@pytest.fixture(scope="module")
def model(exact_rx160_model):
    """Trained on exact data in the robot frame: equals the nominal robot (networks ~0; tests/conftest.py)."""
    return exact_rx160_model


def test_band_to_sigma_is_the_chi3_quantile():
    assert BAND_TO_SIGMA**2 == pytest.approx(chi2.ppf(0.95, 3), rel=1e-12)


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31), tol=st.floats(1.0, 4.0), n=st.integers(5, 40))
def test_consistency_statistic_matches_an_independent_sum(seed, tol, n):
    rng = np.random.default_rng(seed)
    sp, sa = rng.uniform(1e-5, 1e-3, n), rng.uniform(1e-5, 1e-3, n)
    T = np.tile(np.eye(4), (n, 1, 1))
    M = T.copy()
    zp, za = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)) * 0.1
    M[:, :3, 3] = zp * sp[:, None]
    M[:, :3, :3] = se3.rotvec_to_matrix(za * sa[:, None])
    t = consistency_test(M, T, sp, sa, 9, position_only=False, alpha=0.01, tolerance=tol, sigma_source="test")
    S = (np.sum(zp**2) + np.sum(za**2)) / tol**2  # residual T - M = -z sigma: same squares
    assert t.statistic == pytest.approx(S, rel=1e-9) and t.dof == 6 * n - 9
    assert t.p_value == pytest.approx(chi2.sf(S, 6 * n - 9), rel=1e-9)


def test_consistency_rejection_rate_on_data_that_fit():
    """Residuals drawn at the expected scale are refused at about the significance level."""
    rng = np.random.default_rng(0)
    n, alpha, rej = 30, 0.05, 0
    T = np.tile(np.eye(4), (n, 1, 1))
    for _ in range(400):
        M = T.copy()
        M[:, :3, 3] = rng.normal(0, 1e-4, (n, 3))
        rej += not consistency_test(M, T, np.full(n, 1e-4), np.full(n, 1.0), 0, position_only=True, alpha=alpha,
                                    tolerance=1.0, sigma_source="test").passed
    assert 0.02 < rej / 400 < 0.09


def test_good_series_registered_and_reported(model):
    new, info = register_model(model, _series(model.robot), n_poses=30)
    assert "consistency" in info.consistency and "passes" in info.consistency
    assert not info.fell_back
    assert info.rest_pos_mean_mm < 0.05


def test_wrong_robot_refused_one_line_alpha_zero_forces(model, rx160):
    ds = _series(rx160)
    T = B_TRUE @ fk(load_robot("ur10"), ds.q)  # another robot's poses for the same joints
    wrong = Dataset(q=ds.q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="wrong.csv")
    with pytest.raises(RegistrationError, match=r"^wrong\.csv: the series does not fit the model.*chi-square") as e:
        register_model(model, wrong, n_poses=30, refit="frames")  # (auto: refused for a 58 deg joint zero)
    assert "\n" not in str(e.value)
    _, info = register_model(model, wrong, n_poses=30, refit="frames", alpha=0.0)  # forced
    assert "fails" not in info.consistency


def _bent(robot, mm=3.0):
    """The robot with a link 3 mm longer and a joint zero 0.2 deg off: a wrong 'calibration'."""
    a = robot.a_m.copy()
    a[1] += mm * 1e-3
    th = robot.theta_rad.copy()
    th[2] += np.radians(0.2)
    return robot.copy(a_m=a, theta_rad=th)


def test_falls_back_to_nominal_where_the_model_is_worse(model, rx160):
    """A model whose calibrated robot is wrong on the series (and its networks ~0): the nominal model
    with frames fitted on the same poses predicts them better, so registration falls back to it and
    is never worse than nominal + frames on the rest of the series."""
    bad = copy.deepcopy(model)
    bad.robot_ = _bent(rx160)
    ds = _series(rx160, seed=3)
    forced, finfo = register_model(bad, ds, n_poses=30, alpha=0.0, check_nominal=False)
    new, info = register_model(bad, ds, n_poses=30)
    assert info.fell_back and "FALLBACK" in info.nominal_check, info.report()
    assert "passes" in info.consistency
    rest = np.setdiff1d(np.arange(len(ds)), info.used_index)
    B, E = fit_frames(fk(rx160, ds.q[info.used_index]), ds.poses()[info.used_index])
    nom = se3.pose_error(B @ fk(rx160, ds.q[rest]) @ E, ds.poses()[rest])[0].mean()
    got = se3.pose_error(new.predict(ds.q[rest]), ds.poses()[rest])[0].mean()
    old = se3.pose_error(forced.predict(ds.q[rest]), ds.poses()[rest])[0].mean()
    assert got <= nom * 1.0001 and old > 3 * nom
    assert new.unc_ is None and new.thermal_ is None
    # the input model is unchanged
    np.testing.assert_array_equal(bad.robot_.a_m, _bent(rx160).a_m)


def test_keeps_a_model_better_than_nominal(model, rx160):
    """The mirror case: the nominal robot file is the wrong one, the model's robot the right one."""
    good = copy.deepcopy(model)
    good.robot = _bent(rx160)  # nominal wrong, calibrated right
    _, info = register_model(good, _series(rx160, seed=4), n_poses=30)
    assert not info.fell_back and "kept" in info.nominal_check


def test_register_calibrated_robot_api_and_cli(rx160, tmp_path, capsys):
    """A robot file written by `calibrate` (TOML, no model) is registered: the CLI writes the robot
    with the new frames folded into base and tool, which predicts the series."""
    from hykin.cli import main
    from hykin.io.dataset_files import write_dataset
    from hykin.io.robot_toml import save_robot_toml

    cal = _bent(rx160, 1.0)
    ds = _series(cal, seed=5)
    new, info = register_model(RobotModel(cal), ds, n_poses=30)
    assert info.rest_pos_mean_mm < 0.06 and not info.fell_back
    np.testing.assert_allclose(new.to_robot().base[:3, 3], (B_TRUE @ cal.base)[:3, 3], atol=2e-4)
    rob_file, series, out = tmp_path / "cal.toml", tmp_path / "s.csv", tmp_path / "reg.toml"
    save_robot_toml(cal, rob_file)
    write_dataset(ds, series)
    with pytest.raises(SystemExit) as e:
        main(["register", str(rob_file), str(series), "-o", str(out)])
    assert e.value.code in (0, None), capsys.readouterr().err
    reg = load_robot(str(out))
    err = se3.pose_error(fk(reg, ds.q), ds.poses())[0]
    assert err.mean() < 0.06  # mm: the registered robot file predicts the series in its frame
    assert "no orientation columns" not in capsys.readouterr().err
    # a position-only series registers the tool's position; the CLI says its orientation was not
    write_dataset(Dataset(q=ds.q, xyz_m=ds.xyz_m, source="p"), tmp_path / "p.csv")
    with pytest.raises(SystemExit) as e:
        main(["register", str(rob_file), str(tmp_path / "p.csv"), "-o", str(tmp_path / "reg_p.toml")])
    assert e.value.code in (0, None)
    assert "p.csv has no orientation columns: the tool's orientation was not registered" in capsys.readouterr().err
    # a wrong robot file is refused with one line, nothing written
    bad_out = tmp_path / "bad.toml"
    save_robot_toml(load_robot("ur10"), tmp_path / "ur10.toml")
    T = B_TRUE @ fk(load_robot("ur10"), ds.q)
    write_dataset(Dataset(q=ds.q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="w"),
                  tmp_path / "w.csv")
    with pytest.raises(SystemExit) as e:
        main(["register", str(rob_file), str(tmp_path / "w.csv"), "-o", str(bad_out)])
    assert e.value.code == 2 and not bad_out.exists()
    assert len(capsys.readouterr().err.strip().splitlines()) == 1


def test_linearised_loo_matches_the_refitted_one(rx160):
    """The nominal check's leave-one-pose-out (one fit + hat matrix) against n refits."""
    from hykin.measure.register_checks import loo_errors, loo_errors_linear

    ds = _series(rx160, n=25, noise_mm=0.05, noise_deg=0.005, seed=7)
    T_model = fk(_bent(rx160, 0.5), ds.q)
    for pos_only in (False, True):
        pe, ae = loo_errors(T_model, ds.poses(), pos_only)
        pl, al = loo_errors_linear(T_model, ds.poses(), pos_only)
        np.testing.assert_allclose(pl, pe, rtol=0.02, atol=2e-7)
        if not pos_only:
            np.testing.assert_allclose(al, ae, rtol=0.05, atol=1e-7)


@pytest.mark.slow
def test_register_robot_written_as_urdf(rx160, tmp_path):
    """A registered robot file may be written as URDF (the loader reads it back with the same FK)."""
    from hykin.cli import main
    from hykin.io.dataset_files import write_dataset

    ds = _series(rx160, seed=8)
    write_dataset(ds, tmp_path / "s.csv")
    out = tmp_path / "reg.urdf"
    with pytest.raises(SystemExit) as e:
        main(["register", "rx160", str(tmp_path / "s.csv"), "-o", str(out)])
    assert e.value.code in (0, None)
    reg = load_robot(str(out))
    assert se3.pose_error(fk(reg, ds.q), ds.poses())[0].mean() < 0.06
