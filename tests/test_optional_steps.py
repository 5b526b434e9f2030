"""Issue 24: an optional step of ``fit`` that fails degrades with ONE warning and never loses the
fitted model (uncertainty bands and their extrapolation growth, fade calibration, thermal expansion,
region-blocked parameter selection). Each step is forced to fail (monkeypatch); the model must still
fit, predict the same poses as a model whose step did not fail, save and load."""

import warnings

import numpy as np
import pytest

import hykin.hybrid.fade as fade_mod
import hykin.hybrid.model as model_mod
import hykin.hybrid.region_cv as region_mod
import hykin.hybrid.uncertainty as unc_mod
from hykin.geometry import se3
from hykin.hybrid.model import HybridError, HybridModel
from hykin.hybrid.optional import OptionalStepWarning
from hykin.io.dataset import Dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.compliance import ComplianceError
from hykin.kinematics.fk import fk

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.model.OutOfRangeWarning")

CRASH = "robot 'column': joint deflection did not converge (last update 1.22e-10 rad)"


def _boom(*a, **k):
    raise ComplianceError(CRASH)


@pytest.fixture(scope="module")
def data():
    rob = load_robot("rx160")
    rng = np.random.default_rng(3)
    q = rob.random_joints(120, rng)
    T = fk(rob.copy(theta_rad=rob.theta_rad + np.radians([0, 0.02, -0.01, 0, 0, 0])), q)
    temp = 20.0 + rng.uniform(-3, 3, len(q))
    p = T[:, :3, 3] * (1 + 1.2e-5 * (temp - 20.0))[:, None] + rng.normal(0, 2e-5, (len(q), 3))
    ds = Dataset(q=q, xyz_m=p, quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), extra={"temperature_c": temp}, source="d")
    return rob, ds


def _fit(rob, ds, **kw):
    kw.setdefault("calibrate", "calibrate_kw" in kw)  # calibration only where the step needs it (speed)
    m = HybridModel(rob, recipe_kw={"max_epochs": 2, "min_steps": 0}, seed=0, **kw)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        m.fit(ds, progress=False)
    return m, [x for x in w if issubclass(x.category, OptionalStepWarning)]


def _kept(m, tmp_path, step):
    """The model is whole: predicts finite poses, records the skipped step, saves and loads."""
    q = m.robot.random_joints(5, np.random.default_rng(0))
    assert np.isfinite(m.predict(q)).all()
    assert step in m.meta_["optional_steps_failed"]
    p = tmp_path / "m.safetensors"
    m.save(p)
    back = HybridModel.load(p)
    np.testing.assert_allclose(back.predict(q), m.predict(q), atol=1e-12)
    assert step in back.metadata["optional_steps_failed"]
    return back


def test_band_growth_failure_keeps_bands(data, tmp_path, monkeypatch):
    rob, ds = data
    monkeypatch.setattr(unc_mod, "extrapolation_growth", _boom)
    m, w = _fit(rob, ds, thermal=False)
    assert len(w) == 1 and "extrapolation growth" in str(w[0].message) and "1.22e-10" in str(w[0].message)
    back = _kept(m, tmp_path, "extrapolation growth of the uncertainty bands")
    pos, _ = back.predict_uncertainty(rob.random_joints(3, np.random.default_rng(1)))
    assert np.all(pos > 0)  # the in-range bands are there, only the growth is missing


def test_band_failure_keeps_model(data, tmp_path, monkeypatch):
    rob, ds = data
    monkeypatch.setattr(model_mod, "fit_bands", _boom)
    m, w = _fit(rob, ds, thermal=False)
    assert len(w) == 1 and "uncertainty bands" in str(w[0].message)
    back = _kept(m, tmp_path, "uncertainty bands")
    with pytest.raises(HybridError, match="fit skipped them"):
        back.predict_uncertainty(rob.random_joints(2, np.random.default_rng(1)))


def test_uncertainty_off_skips_only_the_bands(data, tmp_path):
    """``uncertainty=False`` (the demo's learning-curve models): the same calibration and networks,
    bit for bit, as with bands; no bands, and predict_uncertainty says why, also after save/load."""
    rob, ds = data
    ref, _ = _fit(rob, ds, thermal=False, calibrate=True)
    m, w = _fit(rob, ds, thermal=False, calibrate=True, uncertainty=False)
    assert not w and ref.unc_ is not None and m.unc_ is None
    q = rob.random_joints(50, np.random.default_rng(4))
    np.testing.assert_array_equal(m.predict(q), ref.predict(q))
    np.testing.assert_array_equal(m.calibration_.values, ref.calibration_.values)
    m.save(tmp_path / "m.hykin")
    back = HybridModel.load(tmp_path / "m.hykin")
    assert back.uncertainty is False
    for mm in (m, back):
        with pytest.raises(HybridError, match="uncertainty=False"):
            mm.predict_uncertainty(q[:2])
    np.testing.assert_array_equal(back.predict(q), m.predict(q))


def test_fade_calibration_failure(data, tmp_path, monkeypatch):
    rob, ds = data
    monkeypatch.setattr(fade_mod, "calibrate_fade", _boom)
    m, w = _fit(rob, ds, thermal=False, fade_cv=2)
    assert len(w) == 1 and "fade calibration" in str(w[0].message)
    assert m.fade_calibration_ is None
    _kept(m, tmp_path, "fade calibration")


def test_thermal_failure_auto_only(data, tmp_path, monkeypatch):
    rob, ds = data
    ref, _ = _fit(rob, ds, thermal=False)
    monkeypatch.setattr(model_mod, "fit_thermal", _boom)
    m, w = _fit(rob, ds, thermal="auto")
    assert len(w) == 1 and "thermal expansion" in str(w[0].message)
    assert m.thermal_ is None
    # the calibration is the one at the measured temperatures, as with thermal off
    np.testing.assert_allclose(m.robot_.theta_rad, ref.robot_.theta_rad, atol=1e-12)
    _kept(m, tmp_path, "thermal expansion")
    with pytest.raises(ComplianceError):  # asked for explicitly: the failure is the answer
        _fit(rob, ds, thermal=True)


def test_region_cv_failure(data, tmp_path, monkeypatch):
    rob, ds = data
    monkeypatch.setattr(region_mod, "select_calibration", _boom)
    m, w = _fit(rob, ds, thermal=False, calibrate_kw={"compliance": False, "select": "region-cv"})
    assert len(w) == 1 and "region-blocked" in str(w[0].message)
    assert m.calibration_cv_ is None
    _kept(m, tmp_path, "region-blocked parameter selection")


@pytest.mark.slow
def test_cli_fit_survives_a_failing_optional_step(data, tmp_path, monkeypatch, capsys):
    """The reported crash through the CLI: exit 0, one warning line, the model written and usable."""
    from hykin.cli import main
    from hykin.io.dataset_files import write_dataset

    rob, ds = data
    train = tmp_path / "train.csv"
    write_dataset(Dataset(q=ds.q, xyz_m=ds.xyz_m, quat_wxyz=ds.quat_wxyz, source="t"), train)
    monkeypatch.setattr(model_mod, "fit_bands", _boom)
    out = tmp_path / "m.safetensors"
    with pytest.raises(SystemExit) as e, pytest.warns(OptionalStepWarning) as rec:
        main(["fit", "rx160", str(train), "-o", str(out), "--max-epochs", "2", "--min-steps", "0", "--no-calibrate"])
    assert e.value.code in (0, None)
    assert sum(issubclass(r.category, OptionalStepWarning) for r in rec) == 1
    assert out.exists()
    joints = tmp_path / "j.csv"
    write_dataset(Dataset(q=ds.q[:4], xyz_m=ds.xyz_m[:4], source="j"), joints)
    with pytest.raises(SystemExit) as e:
        main(["fk", str(out), str(joints), "-o", str(tmp_path / "p.csv")])
    assert e.value.code in (0, None)
