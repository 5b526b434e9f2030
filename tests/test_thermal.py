"""Thermal expansion: identified from a temperature column, applied in predict / evaluate / fk / IK."""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
import pytest

from hykin.calibration.thermal import (
    fit_coefficient,
    scale_about,
    temperature_of,
    to_reference,
)
from hykin.geometry import se3
from hykin.hybrid.model import HybridError, HybridModel, OutOfRangeWarning
from hykin.io.dataset import Dataset
from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.kinematics.fk import fk
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate, true_poses

FAST = {"max_epochs": 15}


@pytest.fixture(scope="module")
def session():
    vr = virtual_preset("rx160-nongeo")
    q = vr.nominal.random_joints(3000, np.random.default_rng(3))
    temp = 20.0 + 6.0 * (1 - np.exp(-np.arange(len(q)) / 1000.0))  # warm-up over the session
    return vr, q, simulate(vr, q, noise=True, rng=3, temperature=temp)  # kept as column temperature_c


@pytest.fixture(scope="module")
def model(session):
    vr, _, ds = session
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        return HybridModel(vr.nominal, recipe_kw=FAST, seed=0).fit(ds, progress=False)


def test_scaling_is_exact_for_uniform_expansion():
    """Scaling every length of the chain by s scales the TCP position about the base origin by s."""
    from hykin.io.robot_file import load_robot

    rob = load_robot("rx160").copy(base=se3.xyzrpy_to_transform(np.array([[0.3, -0.2, 0.1]]), np.array([[0.1, 0.2, -0.3]]))[0],
                                   tool=se3.xyzrpy_to_transform(np.array([[0.01, 0.02, 0.15]]), np.zeros((1, 3)))[0])
    s = 1.0 + 3e-4
    tool = rob.tool.copy()
    tool[:3, 3] *= s
    big = rob.copy(a_m=rob.a_m * s, d_m=rob.d_m * s, tool=tool)
    q = rob.random_joints(200, 1)
    T = scale_about(fk(rob, q), rob.base[:3, 3], np.full(200, s))
    assert np.abs(T - fk(big, q)).max() < 1e-13


def test_fit_coefficient_recovers_alpha_noise_free():
    rng = np.random.default_rng(0)
    b = np.array([0.1, -0.2, 0.3])
    p_ref = rng.normal(size=(500, 3))
    dt = rng.uniform(-3, 3, 500)
    meas = b + (1 + 1.7e-5 * dt)[:, None] * (p_ref - b)
    a, sd = fit_coefficient(meas, p_ref, b, dt, 0.0)
    assert abs(a - 1.7e-5) < 1e-15 and sd < 1e-12
    ds = Dataset(q=np.zeros((500, 1)), xyz_m=meas)
    assert np.abs(to_reference(ds, b, a, dt).xyz_m - p_ref).max() < 1e-14


def test_alpha_recovered_and_applied(session, model):
    vr, q, ds = session
    th = model.thermal_
    assert th is not None and th.coefficient_per_k != 0.0, th
    assert abs(th.coefficient_per_k - vr.thermal.coefficient_per_k) < 0.05 * vr.thermal.coefficient_per_k, th
    assert th.range_c[0] <= th.reference_c <= th.range_c[1]
    # new configurations at the session's hottest temperature: the modelled change of pose from the
    # reference temperature is the true one (the simulator's thermal drift)
    q2 = vr.nominal.random_joints(1000, np.random.default_rng(4))
    hot = np.full(len(q2), th.range_c[1])
    d_true = true_poses(vr, q2, temperature_c=hot)[:, :3, 3] - true_poses(vr, q2, temperature_c=np.full(len(q2), th.reference_c))[:, :3, 3]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        T_ref = model.predict(q2)
        d_model = model.predict(q2, temperature_c=hot)[:, :3, 3] - T_ref[:, :3, 3]
    size = np.linalg.norm(d_true, axis=1)
    assert size.mean() > 0.015e-3  # tens of µm: worth modelling
    assert np.linalg.norm(d_model - d_true, axis=1).mean() < 0.1 * size.mean()
    # the correction is the expansion itself: alpha * dT * |p - b|
    expected = th.coefficient_per_k * (hot - th.reference_c) * np.linalg.norm(T_ref[:, :3, 3] - model.robot_.base[:3, 3], axis=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        moved = np.linalg.norm(model.predict(q2, temperature_c=hot)[:, :3, 3] - T_ref[:, :3, 3], axis=1)
    assert np.allclose(moved, expected, rtol=1e-9, atol=1e-15)


def test_targets_at_reference_inverts_predict(session, model):
    vr, q, ds = session
    import copy

    reg = copy.deepcopy(model)
    reg.frame_pre_ = se3.xyzrpy_to_transform(np.array([[0.5, 0.1, -0.2]]), np.array([[0.01, -0.02, 0.3]]))[0]
    reg.frame_post_ = se3.xyzrpy_to_transform(np.array([[0.0, 0.0, 0.02]]), np.array([[0.05, 0.0, 0.0]]))[0]
    t = np.linspace(18, 30, 50)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        T_hot = reg.predict(q[:50], temperature_c=t)
        T_ref = reg.predict(q[:50])
    back = reg.targets_at_reference(T_hot, t)
    assert np.abs(back - T_ref).max() < 1e-12
    p_back = reg.targets_at_reference(T_hot[:, :3, 3], t)
    assert np.abs(p_back - T_ref[:, :3, 3]).max() < 3e-6  # alpha dT |frame_post offset| = 1e-4 * 2 cm
    assert reg.targets_at_reference(T_hot, None) is not None and np.array_equal(reg.targets_at_reference(T_hot, None), T_hot)
    # one pose (4, 4) / one position (3,): the same as the first row of the batch
    assert np.abs(reg.targets_at_reference(T_hot[0], t[0]) - back[0]).max() < 1e-15
    assert np.abs(reg.targets_at_reference(T_hot[0, :3, 3], t[0]) - p_back[0]).max() < 1e-15


def test_save_load_keeps_thermal(model, session, tmp_path):
    vr, q, ds = session
    model.save(tmp_path / "m.hykin")
    m2 = HybridModel.load(tmp_path / "m.hykin")
    assert m2.thermal_ == model.thermal_
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        assert np.array_equal(m2.predict(q[:20], temperature_c=25.0), model.predict(q[:20], temperature_c=25.0))


@pytest.mark.slow  # ~7 s on 2 cores: in the slow suite to keep the default suite under 4 minutes
def test_unrelated_temperature_is_ignored_and_required_column_checked():
    """No expansion in the data: a noisy temperature column must not produce a coefficient."""
    vr = dataclasses.replace(virtual_preset("rx160-nongeo"), thermal=None)
    q = vr.nominal.random_joints(1500, np.random.default_rng(5))
    ds = simulate(vr, q, noise=True, rng=5)
    ds = dataclasses.replace(ds, extra={"temperature_c": np.random.default_rng(6).uniform(20, 24, len(q))})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        m = HybridModel(vr.nominal, recipe_kw=FAST).fit(ds, progress=False)
    assert m.thermal_ is not None and m.thermal_.coefficient_per_k == 0.0 and "ignored" in m.thermal_.note
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        assert np.array_equal(m.predict(q[:10], temperature_c=40.0), m.predict(q[:10]))
    plain = dataclasses.replace(ds, extra={})
    with pytest.raises(HybridError, match="temperature"):
        HybridModel(vr.nominal, recipe_kw=FAST, thermal=True).fit(plain, progress=False)
    bad = dataclasses.replace(ds, extra={"temperature_c": np.r_[np.nan, np.full(len(q) - 1, 21.0)]})
    with pytest.raises(ValueError, match="temperature_c', row 1"):
        temperature_of(bad)


def test_cli_fk_and_evaluate_use_the_temperature_column(model, session, tmp_path):
    from typer.testing import CliRunner

    from hykin.cli import app

    vr, q, ds = session
    path = tmp_path / "m.hykin"
    model.save(path)
    sub = ds.subset(np.arange(200))
    write_dataset(sub, tmp_path / "j.csv")
    r = CliRunner().invoke(app, ["fk", str(path), str(tmp_path / "j.csv"), "-o", str(tmp_path / "p.csv")])
    assert r.exit_code == 0, r.output
    out = read_dataset(tmp_path / "p.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        T = model.predict(sub.q, temperature_c=temperature_of(sub))
    assert np.abs(out.xyz_m - T[:, :3, 3]).max() < 1e-9
    write_dataset(Dataset(q=sub.q, xyz_m=sub.xyz_m, quat_wxyz=sub.quat_wxyz), tmp_path / "j2.csv")
    r = CliRunner().invoke(app, ["fk", str(path), str(tmp_path / "j2.csv"), "-o", str(tmp_path / "p2.csv")])
    assert r.exit_code == 0 and "temperature_c column" in " ".join(r.output.split()), r.output
    r = CliRunner().invoke(app, ["evaluate", str(path), str(tmp_path / "j.csv"), "--json"])
    assert r.exit_code == 0, r.output


def test_hybrid_ik_reaches_targets_at_temperature(model, session):
    from hykin.hybrid.ik import hybrid_ik

    vr, q, ds = session
    q0 = q[:20]
    t = np.full(20, model.thermal_.range_c[1] + 2.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        T_hot = model.predict(q0, temperature_c=t)
        res = hybrid_ik(model, T_hot, all_branches=False, q_current=q0, nearest=True, temperature_c=t)
        assert res.success.all()
        p, a = se3.pose_error(model.predict(res.q, temperature_c=t[res.target]), T_hot[res.target])
    assert p.max() < 1e-6 and a.max() < 1e-6
    assert np.abs(res.q - q0[res.target]).max() < 1e-6


def test_bands_with_and_without_temperature_cover(session, model):
    vr, q, ds = session
    assert "notemp_hybrid_pos_mm" in model.unc_
    th = model.thermal_
    q2 = vr.nominal.random_joints(1500, np.random.default_rng(8))
    t2 = np.random.default_rng(9).uniform(*th.range_c, len(q2))
    meas = simulate(vr, q2, noise=True, rng=8, temperature=t2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        for t in (t2, None):
            p, _ = se3.pose_error(model.predict(q2, temperature_c=t), meas.poses())
            b, _ = model.predict_uncertainty(q2, 0.95, temperature_c=t)
            assert 0.88 <= np.mean(p <= b) <= 0.995, (t is None, np.mean(p <= b))
        b_t, _ = model.predict_uncertainty(q2, 0.95, temperature_c=t2)
        b_n, _ = model.predict_uncertainty(q2, 0.95)
    assert b_n.mean() >= b_t.mean()  # without the temperature the drift is part of the band


def test_cli_compensate_reads_the_targets_temperature(model, session, tmp_path, capsys):
    """CSV targets with a temperature_c column are compensated at that temperature: executed by the
    nominal controller on the true robot at 21 °C they land on the targets (truth: the simulator)."""
    import csv

    from cli_run import run as run_cli

    from hykin.kinematics.ik import ik

    vr, _, _ = session
    nom = vr.nominal
    q = nom.random_joints(20, np.random.default_rng(8), margin=0.3)
    temp = np.full(20, 21.0)
    T = true_poses(vr, q, temperature_c=temp)
    xyz, quat = se3.transform_to_pose(T)
    mp, tp, out = tmp_path / "m.hykin", tmp_path / "t.csv", tmp_path / "c.csv"
    model.save(mp)
    with open(tp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z", "qw", "qx", "qy", "qz"] + [f"q{j + 1}" for j in range(6)] + ["temperature_c"])
        for i in range(20):
            w.writerow([repr(float(v)) for v in (*xyz[i], *quat[i], *q[i], temp[i])])
    code, _, err = run_cli(["compensate", mp, tp, "-o", out, "--joints"], capsys)
    assert code == 0, err
    with open(out, newline="") as f:
        qc = np.array([[float(r[f"q{j + 1}"]) for j in range(6)] for r in csv.DictReader(f)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        at_t = model.predict(qc, temperature_c=temp)  # the model at the targets' temperature (its own predict)
        at_ref = model.predict(qc)  # ... and at its reference
    err_t = np.linalg.norm(at_t[:, :3, 3] - T[:, :3, 3], axis=1) * 1e3
    err_ref = np.linalg.norm(at_ref[:, :3, 3] - T[:, :3, 3], axis=1) * 1e3
    assert err_t.max() < 1e-3 and err_ref.mean() > 0.01, (err_t.max(), err_ref.mean())
    # and on the true robot at that temperature the joints land within the model's accuracy
    land = np.linalg.norm(true_poses(vr, qc, temperature_c=temp)[:, :3, 3] - T[:, :3, 3], axis=1) * 1e3
    assert land.mean() < 0.2
    # joints at temperatures the model never saw: a warning with the count
    jp = tmp_path / "j.csv"
    jp.write_text("q1,q2,q3,q4,q5,q6,temperature_c\n" + "".join(
        ",".join(repr(float(v)) for v in q[i]) + f",{t}\n" for i, t in zip(range(3), (22.0, 40.0, 41.0))))
    code, _, err = run_cli(["fk", mp, jp, "-o", tmp_path / "fk.csv"], capsys)
    lo, hi = model.thermal_.range_c
    assert code == 0 and f"2 of 3 rows of {jp} lie outside the temperatures the model was trained on ({lo:.2f}-{hi:.2f}" in err


def test_stations_at_different_temperatures_warn_that_the_coefficient_is_biased():
    """Probe report s40: stations measured at 20-24 and 24-28 °C gave 5.98e-6 /K for a true 12e-6 /K
    without a word. A kept coefficient from such data warns; stations over the same temperatures do not."""
    import warnings
    from types import SimpleNamespace

    from hykin.hybrid.errors import FitWarning
    from hykin.hybrid.thermal_fit import warn_station_temperatures
    from hykin.io.dataset import Dataset

    rng = np.random.default_rng(0)
    n = 200
    st = np.where(np.arange(n) < n // 2, "S1", "S2")
    ds = Dataset(q=np.zeros((n, 6)), xyz_m=np.zeros((n, 3)), extra={"station": st})
    th = SimpleNamespace(coefficient_per_k=6e-6)
    apart = np.where(st == "S1", rng.uniform(20, 24, n), rng.uniform(24, 28, n))
    with pytest.warns(FitWarning, match=r"S1 20\.0-24\.0 °C, S2 24\.0-28\.0 °C.*biased low"):
        warn_station_temperatures(th, ds, apart)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_station_temperatures(th, ds, rng.uniform(20, 28, n))  # the same temperatures: no warning
        warn_station_temperatures(SimpleNamespace(coefficient_per_k=0.0), ds, apart)  # no coefficient kept
