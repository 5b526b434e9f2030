"""HybridModel: fit/predict, determinism, model file round trip (no pickle), autograd, fade."""

import json
import warnings

import numpy as np
import pytest
import torch

from hykin.geometry.se3 import rotvec_to_matrix
from hykin.hybrid.model import HybridError, HybridModel, OutOfRangeWarning
from hykin.io.dataset import Dataset
from hykin.io.modelfile import ModelFileError
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk

# the model's own out-of-range warning is expected here: the queries are random joints
pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")

TINY = {"max_epochs": 8, "batch_size": 64}


@pytest.fixture(scope="module")
def robot():
    return load_robot("rx160")


def _residual(q):
    """Known smooth residual the classical model cannot express: (dp (N,3) m, dr (N,3) rad)."""
    dp = 2e-4 * np.stack([np.sin(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 2] + q[:, 1])], 1)
    dr = 1e-4 * np.stack([np.cos(q[:, 0]), np.sin(q[:, 3]), 0.5 * q[:, 1]], 1)
    return dp, dr


def _data(robot, n, seed, orientation=True, margin=0.1):
    q = robot.random_joints(n, seed, margin=margin)
    T = fk(robot, q)
    dp, dr = _residual(q)
    T[:, :3, 3] += dp
    T[:, :3, :3] = rotvec_to_matrix(dr) @ T[:, :3, :3]
    return Dataset.from_poses(q, T, orientation=orientation)


@pytest.fixture(scope="module")
def fitted(robot):
    m = HybridModel(robot, calibrate=False, recipe_kw=TINY, seed=0)
    return m.fit(_data(robot, 400, 1), progress=False)


def test_training_reduces_error_tenfold(robot):
    train, test = _data(robot, 800, 1), _data(robot, 300, 2)
    m = HybridModel(robot, calibrate=False, recipe_kw={"max_epochs": 35, "lr": 1e-2}, seed=0).fit(train, progress=False)
    s = m.score(test)
    assert s["hybrid_pos_mean_mm"] < s["classical_pos_mean_mm"] / 10, s
    assert s["hybrid_rot_mean_deg"] < s["classical_rot_mean_deg"] / 10, s
    assert m.meta_["metrics"]["train"]["classical_pos_mean_mm"] == pytest.approx(
        np.linalg.norm(fk(robot, train.q)[:, :3, 3] - train.xyz_m, axis=1).mean() * 1e3)


def test_fit_is_deterministic(robot):
    train, test = _data(robot, 200, 3), _data(robot, 50, 4)
    a = HybridModel(robot, calibrate=False, recipe_kw=TINY, seed=5).fit(train, progress=False).predict(test.q)
    b = HybridModel(robot, calibrate=False, recipe_kw=TINY, seed=5).fit(train, progress=False).predict(test.q)
    assert np.array_equal(a, b)


def test_save_load_round_trip_without_pickle(fitted, tmp_path, robot):
    from safetensors import safe_open

    path = tmp_path / "model.hykin"
    fitted.save(path)
    with safe_open(str(path), framework="pt") as f:  # a plain safetensors file
        md = f.metadata()
        keys = list(f.keys())
    assert md["format"] == "hykin-model" and md["format_version"] == "1"
    meta = json.loads(md["hykin"])
    assert meta["config"]["arch"] == "default" and meta["training"]["data_hash"]
    assert "convention = \"dh\"" in meta["robot_toml"]
    assert any(k.startswith("pos.") for k in keys) and any(k.startswith("rot.") for k in keys)
    raw = path.read_bytes()  # safetensors layout: u64 header length, JSON header, raw tensor bytes (no pickle)
    hlen = int.from_bytes(raw[:8], "little")
    assert raw[8:9] == b"{" and json.loads(raw[8 : 8 + hlen])["__metadata__"]["format"] == "hykin-model"
    m2 = HybridModel.load(path)
    q = robot.random_joints(100, 9, margin=0.1)
    q[0, 1] = 10.0  # one far outside: fade and warning survive the round trip
    with pytest.warns(OutOfRangeWarning):
        assert np.array_equal(m2.predict(q), fitted.predict(q))
    assert np.array_equal(m2.predict(q), fitted.predict(q))
    assert np.array_equal(m2.predict_classical(q), fitted.predict_classical(q))
    assert np.array_equal(m2.support_distance(q), fitted.support_distance(q))


def test_load_rejects_other_files(tmp_path):
    from safetensors.torch import save_file

    junk = tmp_path / "junk.hykin"
    junk.write_bytes(b"\x80\x04this is not a model")
    with pytest.raises(ModelFileError, match="not a hykin model"):
        HybridModel.load(junk)
    other = tmp_path / "other.safetensors"
    save_file({"w": torch.zeros(2)}, str(other))
    with pytest.raises(ModelFileError, match="not a hykin model"):
        HybridModel.load(other)
    newer = tmp_path / "newer.safetensors"
    save_file({"w": torch.zeros(2)}, str(newer), metadata={"format": "hykin-model", "format_version": "99", "hykin": "{}"})
    with pytest.raises(ModelFileError, match="version 99"):
        HybridModel.load(newer)
    with pytest.raises(ModelFileError, match="no such"):
        HybridModel.load(tmp_path / "missing.hykin")


def test_predict_torch_matches_predict_and_finite_differences(robot):
    # compliant robot: the classical part goes through compliant_fk_torch; float64 nets for exact FD
    rc = robot.copy(stiffness_nm_per_rad=np.full(6, 2e5), payload_kg=20.0)
    m = HybridModel(rc, calibrate=False, recipe_kw={**TINY, "dtype": "float64"}, seed=0).fit(_data(rc, 300, 1), progress=False)
    q = rc.random_joints(4, 11, margin=0.15)
    qt = torch.tensor(q, requires_grad=True)
    T = m.predict_torch(qt)
    assert np.allclose(T.detach().numpy(), m.predict(q), atol=1e-13)
    # gradient of the position and of one rotation column w.r.t. q for sample 0, vs central FD
    J = torch.autograd.functional.jacobian(lambda x: m.predict_torch(x)[0, :3, :].T[[0, 3]].reshape(-1), qt)[:, 0].numpy()
    h = 1e-6
    fd = np.empty_like(J)
    for j in range(6):
        dq = np.zeros_like(q)
        dq[0, j] = h
        fd[:, j] = (m.predict(q + dq)[0, :3, :].T[[0, 3]].reshape(-1) - m.predict(q - dq)[0, :3, :].T[[0, 3]].reshape(-1)) / (2 * h)
    err = np.abs(J - fd)
    assert err.max() < 1e-6, (err.max(), np.unravel_index(err.argmax(), err.shape))


def test_fade_out_of_range_equals_classical_and_warns_once(fitted, robot):
    lo, hi = fitted.support_lower_, fitted.support_upper_
    q = lo + np.random.default_rng(3).uniform(0.3, 0.7, (5, 6)) * (hi - lo)  # well inside
    # far out (0.25 of the range beyond it; not more: revolute joints wrap onto the circle, where
    # 0.5 beyond the upper end of q2 would be near its lower end again)
    q[:3, 1] = fitted.support_upper_[1] + 0.25 * (fitted.support_upper_[1] - fitted.support_lower_[1])
    q[0, 4] = fitted.support_lower_[4] - 2.0
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        T = fitted.predict(q)
    rec = [x for x in w if issubclass(x.category, OutOfRangeWarning)]
    assert len(rec) == 1
    assert "3 of 5 queries" in str(rec[0].message) and "q2: 3" in str(rec[0].message) and "q5: 1" in str(rec[0].message)
    Tc = fitted.predict_classical(q)
    assert np.abs(T[:3] - Tc[:3]).max() < 1e-9
    assert np.abs(T[3:, :3, 3] - Tc[3:, :3, 3]).max() > 1e-6  # inside: the nets correct
    d = fitted.support_distance(q)
    assert np.all(d[:3] >= 0.15) and np.all(d[3:] < 0.1)
    assert np.allclose(fitted.fade_weight(q)[:3], 0.0) and np.allclose(fitted.fade_weight(q)[3:], 1.0)


def test_fade_is_smooth_and_partial(fitted):
    q = np.tile(fitted.support_lower_ + 0.5 * (fitted.support_upper_ - fitted.support_lower_), (3, 1))
    span = fitted.support_upper_[0] - fitted.support_lower_[0]
    q[:, 0] = fitted.support_upper_[0] + np.array([0.0, 0.05, 0.1]) * span  # 0, half, full fade width
    assert np.allclose(fitted.fade_weight(q), [1.0, 0.5, 0.0], atol=1e-9)


def test_nearest_neighbour_gap_inside_range(fitted):
    # centre of the joint box is inside the range; support_distance is >= 0 and finite
    lo, hi = fitted.support_lower_, fitted.support_upper_
    d = fitted.support_distance(((lo + hi) / 2)[None])
    assert d.shape == (1,) and np.isfinite(d).all() and d[0] >= 0
    assert np.all(fitted.support_distance(np.asarray(fitted.support_points_[:20]) * (hi - lo) + lo) == 0)


def test_position_only_data(robot):
    m = HybridModel(robot, calibrate=False, recipe_kw=TINY).fit(_data(robot, 200, 1, orientation=False), progress=False)
    assert m.net_rot_ is None
    q = robot.random_joints(10, 3, margin=0.1)
    T = m.predict(q)
    assert np.allclose(T[:, :3, :3], m.predict_classical(q)[:, :3, :3], atol=0)


def test_with_calibration_recovers_geometry(robot):
    truth = robot.copy(a_m=robot.a_m + [0, 4e-4, 0, 0, 0, 0], d_m=robot.d_m + [0, 0, 0, 3e-4, 0, 0])
    q = robot.random_joints(300, 1, margin=0.1)
    ds = Dataset.from_poses(q, fk(truth, q))
    m = HybridModel(robot, calibrate=True, recipe_kw=TINY).fit(ds, progress=False)
    assert m.robot_.a_m[1] == pytest.approx(robot.a_m[1] + 4e-4, abs=1e-8)
    assert m.meta_["metrics"]["train"]["classical_pos_mean_mm"] < 1e-5
    assert m.meta_["calibration"] is not None


def test_bad_input(fitted, robot):
    with pytest.raises(HybridError, match="shape"):
        fitted.predict(np.zeros((3, 5)))
    q = robot.random_joints(3, 1)
    q[1, 2] = np.nan
    with pytest.raises(HybridError, match="row 1"):
        fitted.predict(q)
    with pytest.raises(HybridError, match="not fitted"):
        HybridModel(robot).predict(q)
    with pytest.raises(ValueError, match="unknown architecture"):
        HybridModel(robot, arch="nope").fit(_data(robot, 50, 1), progress=False)


def test_constructor_stores_settings_and_fit_validates_them(robot):
    """scikit-learn contract: the constructor only stores (even bad settings), ``fit`` validates them
    before any work, learns the ``*_`` attributes and returns self; settings are not rewritten."""
    bad = HybridModel(robot, fade="sometimes", recipe_kw={"max_epochs": 3}, input_joints=[1, 2, 3])
    assert bad.fade == "sometimes" and bad.recipe == "default" and bad.input_joints == [1, 2, 3]
    assert not hasattr(bad, "net_pos_") and not hasattr(bad, "recipe_")
    with pytest.raises(HybridError, match="fade must be"):
        bad.fit(_data(robot, 50, 1), progress=False)
    with pytest.raises(HybridError, match="input_joints"):
        HybridModel(robot, input_joints=[0, 7]).fit(_data(robot, 50, 1), progress=False)
    m = HybridModel(robot, calibrate=False, recipe_kw=TINY, seed=0)
    assert m.fit(_data(robot, 100, 1), progress=False) is m
    assert m.recipe == "default" and m.recipe_kw == TINY and m.val_fraction is None and m.input_joints is None
    assert m.recipe_.max_epochs == TINY["max_epochs"] and m.net_pos_ is not None
    # no public attribute appears after construction except the settings; fit adds only `*_` ones
    settings = set(vars(HybridModel(robot)))
    learned = {k for k in set(vars(m)) - settings if not k.startswith("_")}  # `_x`: private caches
    assert learned and all(k.endswith("_") for k in learned), sorted(k for k in learned if not k.endswith("_"))
    assert m.fade_offset == 0.0 and m.fade_offset_ == 0.0 and np.array_equal(m.frame_pre_, np.eye(4))


def test_full_fade_uses_nearest_neighbour_gap(fitted):
    lo, hi = fitted.support_lower_, fitted.support_upper_
    q_in = np.asarray(fitted.support_points_[:10]) * (hi - lo) + lo  # training samples: gap 0
    T_range = fitted.predict(q_in)
    fitted.fade = "full"
    try:
        assert np.array_equal(fitted.predict(q_in), T_range)
        assert np.allclose(fitted.fade_weight(q_in), 1.0)
    finally:
        fitted.fade = True


def test_max_seconds_is_one_budget_for_both_networks(monkeypatch):
    """--max-minutes bounds network training as a whole: the first network gets half, the second what
    is left (here all of it, the stand-in training taking no time)."""
    from hykin.hybrid import fitting
    from hykin.hybrid.train import TrainResult, get_recipe

    got = []

    def fake(net, Xt, yt, Xv, yv, recipe, *, seed, device, max_seconds, callback):
        got.append(max_seconds)
        return TrainResult(epochs=1, best_epoch=1, best_val=0.0, final_train=0.0, seconds=0.0, stopped="done", steps=1)

    monkeypatch.setattr(fitting, "train_net", fake)
    X, y = np.zeros((8, 6)), np.zeros((8, 3))
    kw = dict(arch="default", n_in=6, in_lower=-np.ones(6), in_upper=np.ones(6), recipe=get_recipe("default"), seed=0,
              device="cpu", progress=False)
    fitting.train_networks({"pos": (y, None), "rot": (y, None)}, X, None, max_seconds=60.0, **kw)
    assert got[0] == pytest.approx(30.0, abs=1.0) and got[1] == pytest.approx(60.0, abs=1.0)
    got.clear()
    fitting.train_networks({"pos": (y, None), "rot": (None, None)}, X, None, max_seconds=60.0, **kw)  # positions only
    assert got == [pytest.approx(60.0, abs=1.0)]
