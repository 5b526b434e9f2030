"""Per-row payload: gravity torques against an independent Jacobian reference, the scalar path
unchanged, calibration with several payloads, simulation, hybrid models, evaluation and the CLI."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import torch
from cli_run import run as _run

from hykin.calibration.calibrate import calibrate
from hykin.evaluation.evaluate import evaluate_model
from hykin.geometry.se3 import pose_error
from hykin.hybrid.model import HybridModel
from hykin.io.dataset import DatasetError
from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.io.payload import (
    PAYLOAD_COLUMNS,
    model_with_payload,
    payload_of,
    payload_range_of,
    robot_with_payload,
    with_payload,
)
from hykin.kinematics.compliance import compliant_fk, deflected_joints, gravity_torques
from hykin.kinematics.fk import fk
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate, true_poses


@pytest.fixture(scope="module")
def vr():
    return virtual_preset("kr-payload-virtual", seed=3)


def _payload_torque_reference(robot, q, kg, com, h=1e-6):
    """tau = m g . d p / d q by central differences of plain FK (p: payload point, world frame)."""
    g = robot.base[:3, :3] @ np.asarray(robot.gravity_base)
    out = np.zeros(q.shape)
    for j in range(q.shape[1]):
        dq = np.zeros(q.shape[1])
        dq[j] = h
        Tp, Tm = fk(robot, q + dq), fk(robot, q - dq)
        pp = (Tp[:, :3, :3] @ com[:, :, None])[..., 0] + Tp[:, :3, 3]
        pm = (Tm[:, :3, :3] @ com[:, :, None])[..., 0] + Tm[:, :3, 3]
        out[:, j] = kg * (((pp - pm) / (2 * h)) @ g)
    return out


def test_per_row_torques_match_jacobian_reference(vr):
    rob = vr.truth.copy(payload_kg=0.0)
    rng = np.random.default_rng(0)
    q = rob.random_joints(40, rng)
    kg = rng.uniform(0, 25, 40)
    com = rng.normal(0, 0.08, (40, 3))
    links_only = gravity_torques(rob, q)
    for xp_q in (q, torch.tensor(q)):  # numba kernels and the torch path
        tau = gravity_torques(rob, xp_q, payload_kg=kg, payload_com_m=com)
        tau = tau.numpy() if isinstance(tau, torch.Tensor) else tau
        ref = _payload_torque_reference(rob, q, kg, com)
        assert np.abs(tau - links_only - ref).max() < 1e-5 * max(1.0, np.abs(ref).max())


def test_scalar_payload_path_unchanged(vr):
    rob = vr.truth
    q = rob.random_joints(50, 1)
    base = deflected_joints(rob, q)
    same = deflected_joints(rob, q, payload_kg=np.full(50, rob.payload_kg))
    assert np.array_equal(base, same)  # same operations, same bits
    assert np.array_equal(compliant_fk(rob, q), compliant_fk(rob, q, payload_kg=rob.payload_kg))


def test_robot_with_payload_equals_per_row(vr):
    rob = vr.truth
    q = rob.random_joints(30, 2)
    com = np.array([0.05, -0.02, 0.12])
    per_row = deflected_joints(rob, q, payload_kg=7.5, payload_com_m=com)
    merged = deflected_joints(robot_with_payload(rob, 7.5, com), q)
    assert np.abs(per_row - merged).max() < 1e-12


def test_payload_columns_validated_with_row_and_column(vr):
    ds = simulate(vr, vr.nominal.random_joints(5, 0), payload_kg=[0, 1, 2, 3, 4], noise=False)
    assert set(ds.extra) >= {"payload_kg"}
    ds.extra["payload_kg"] = np.array([0, 1, -2, 3, 4.0])
    with pytest.raises(DatasetError, match=r"row 3, column 'payload_kg': -2.0 is not a mass"):
        payload_of(ds)
    with pytest.raises(DatasetError, match=r"row 3, column 'payload_kg'"):
        with_payload(ds, [0, 1, -2, 3, 4])
    ds.extra["payload_com_x"] = np.zeros(5)
    with pytest.raises(DatasetError, match="payload_com_y"):
        payload_of(ds)


def test_simulate_per_row_equals_per_group(vr, tmp_path):
    q = vr.nominal.random_joints(20, 4)
    kg = np.resize([0.0, 12.0], 20)
    ds = simulate(vr, q, payload_kg=kg, noise=False)
    for v in (0.0, 12.0):
        sel = kg == v
        T = true_poses(vr, q[sel], payload_kg=v)
        assert np.abs(ds.xyz_m[sel] - T[:, :3, 3]).max() < 1e-14
    write_dataset(ds, tmp_path / "d.csv")
    back = read_dataset(tmp_path / "d.csv")
    assert np.array_equal(payload_of(back)[0], kg)
    # the payload really moves the TCP (stiffness of the truth): 12 kg vs 0 kg differ by > 0.05 mm
    p, _ = pose_error(true_poses(vr, q, payload_kg=0.0), true_poses(vr, q, payload_kg=12.0))
    assert p.mean() > 0.05


def test_calibration_identifies_stiffness_with_payload_rows(vr):
    """Compliance only, noise-free, geometry exact: per-row payloads give the truth's compliance;
    ignoring them (robot payload 0) leaves a payload-dependent error."""
    truth = vr.nominal.copy(stiffness_nm_per_rad=vr.truth.stiffness_nm_per_rad)
    q = vr.nominal.random_joints(400, 5)
    kg = np.resize([0.0, 20.0], 400)
    T = compliant_fk(truth, q, payload_kg=kg)
    res = calibrate(vr.nominal, (q, T), params="c*", payload_kg=kg)
    c_true = 1.0 / truth.stiffness_nm_per_rad
    c_hat = 1.0 / res.robot.stiffness_nm_per_rad
    assert np.abs(c_hat[1:] / c_true[1:] - 1).max() < 1e-6  # joint 1 is vertical: no gravity torque, fixed
    assert res.after["pos_max_mm"] < 1e-6
    blind = calibrate(vr.nominal, (q, T), params="c*")
    assert blind.after["pos_mean_mm"] > 1e3 * res.after["pos_mean_mm"] + 1e-3


def test_hybrid_with_payload_column_save_load(vr, tmp_path):
    q = vr.nominal.random_joints(300, 6)
    tr = simulate(vr, q, payload_kg=np.resize([0.0, 12.0], 300), rng=1)
    m = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 2}, payload_input=False).fit(tr, progress=False)
    assert m.payload_range_.lower_kg == 0.0 and m.payload_range_.upper_kg == 12.0
    qt = vr.nominal.random_joints(50, 7)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        T20 = m.predict(qt, payload_kg=20.0)
        T0 = m.predict(qt, payload_kg=0.0)
        # payload-agnostic networks: the payload acts through the calibrated compliance only
        dc = m.predict_classical(qt, payload_kg=20.0)[:, :3, 3] - m.predict_classical(qt, payload_kg=0.0)[:, :3, 3]
        assert np.abs((T20[:, :3, 3] - T0[:, :3, 3]) - dc).max() < 1e-12
        assert np.abs(dc).max() > 1e-5
        # a model carrying one payload (hybrid IK path) predicts the same
        T20b = model_with_payload(m, 20.0).predict(qt)
        assert np.abs(T20b - T20).max() < 1e-12
        m.save(tmp_path / "m.hykin")
        m2 = HybridModel.load(tmp_path / "m.hykin")
        assert m2.payload_range_.to_dict() == m.payload_range_.to_dict()
        assert np.array_equal(m2.predict(qt, payload_kg=20.0), T20)
        te = simulate(vr, qt, payload_kg=np.resize([0.0, 6.0], 50), rng=2)
        res = evaluate_model(m2, te)
    assert sorted(res.per_payload) == [0.0, 6.0]
    assert res.per_payload[6.0]["hybrid"]["n"] == 25
    assert "Error per payload" in res.table() and "per_payload" in res.to_dict()
    assert payload_range_of(np.array([3.0, 1.0])).values_kg == [1.0, 3.0]




def test_cli_simulate_payloads_and_fk_payload_option(tmp_path, capsys, vr):
    data = tmp_path / "d.csv"
    code, _, err = _run(["simulate", "kr-payload-virtual", "-n", "30", "-o", str(data), "--payloads", "0,12"], capsys)
    assert code == 0, err
    ds = read_dataset(data)
    assert np.array_equal(ds.extra["payload_kg"], np.resize([0.0, 12.0], 30))
    code, _, err = _run(["simulate", "kr-payload-virtual", "-n", "5", "-o", str(tmp_path / "x.csv"), "--payloads", "0,-1"],
                        capsys)
    assert code == 2 and "--payloads" in err and not (tmp_path / "x.csv").exists()
    # fk on a model: the file's column, or --payload-kg for a file without it; both is an error
    m = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 1}).fit(ds, progress=False)
    m.save(tmp_path / "m.hykin")
    joints = tmp_path / "j.csv"
    write_dataset(ds, joints)
    code, _, err = _run(["fk", str(tmp_path / "m.hykin"), str(joints), "-o", str(tmp_path / "o.csv"), "--payload-kg", "3"],
                        capsys)
    assert code == 2 and "payload_kg" in err and not (tmp_path / "o.csv").exists()
    plain = tmp_path / "plain.csv"
    with open(plain, "w") as f:
        f.write(",".join(f"q{j + 1}" for j in range(6)) + "\n")
        f.writelines(",".join(repr(float(v)) for v in row) + "\n" for row in ds.q)
    code, _, err = _run(["fk", str(tmp_path / "m.hykin"), str(plain), "-o", str(tmp_path / "o.csv"), "--payload-kg", "12"],
                        capsys)
    assert code == 0, err
    out = read_dataset(tmp_path / "o.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = m.predict(ds.q, payload_kg=12.0)
    assert np.abs(out.xyz_m - ref[:, :3, 3]).max() < 1e-12
    assert set(PAYLOAD_COLUMNS[:1]) <= set(read_dataset(data).extra)


def test_payload_input_networks_hold_their_payload_dependence_outside_the_range(vr, tmp_path):
    """payload_input=True with rows at 0 and 12 kg: the networks take payload as an input, clamped to
    the trained range, so beyond 12 kg only the physics changes with payload; save/load keeps it."""
    q = vr.nominal.random_joints(300, 8)
    tr = simulate(vr, q, payload_kg=np.resize([0.0, 12.0], 300), rng=1)
    m = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 2}, payload_input=True).fit(tr, progress=False)
    assert m.payload_input_
    qt = vr.nominal.random_joints(20, 9)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        h = {kg: m.predict(qt, payload_kg=kg)[:, :3, 3] for kg in (3.0, 9.0, 15.0, 25.0)}
        c = {kg: m.predict_classical(qt, payload_kg=kg)[:, :3, 3] for kg in (3.0, 9.0, 15.0, 25.0)}
        assert np.abs((h[25.0] - h[15.0]) - (c[25.0] - c[15.0])).max() < 1e-12  # clamped: net part equal
        assert np.abs((h[9.0] - h[3.0]) - (c[9.0] - c[3.0])).max() > 1e-9  # inside: the net sees payload
        Tt = m.predict_torch(torch.tensor(qt), payload_kg=9.0).detach().numpy()
        assert np.abs(Tt[:, :3, 3] - h[9.0]).max() < 1e-9
        m.save(tmp_path / "m.hykin")
        m2 = HybridModel.load(tmp_path / "m.hykin")
        assert m2.payload_input_ and np.array_equal(m2.predict(qt, payload_kg=9.0)[:, :3, 3], h[9.0])
        assert np.abs(model_with_payload(m, 9.0).predict(qt)[:, :3, 3] - h[9.0]).max() < 1e-12
    single = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 1}, payload_input=True)
    single.fit(with_payload(tr, 12.0), progress=False)
    assert not single.payload_input_  # one payload: nothing to condition on


def test_warns_for_payloads_outside_the_trained_payloads(vr):
    q = vr.nominal.random_joints(200, 10)
    m = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 1}).fit(
        simulate(vr, q, payload_kg=12.0, rng=1), progress=False)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        m.predict(q[:5], payload_kg=[12.0, 12.0, 0.0, 12.0, 20.0])
    assert any("2 of 5 payloads lie outside the trained payloads [12, 12] kg" in str(w.message) for w in rec)


def test_payload_and_temperature_in_the_wrong_unit_are_refused_naming_row_and_column():
    """Grams as kg, a centre of mass in mm as m, kelvin or °F as °C: one line naming the row, the column
    and the likely unit; values a real cell sees pass."""
    from hykin.calibration.thermal import temperature_from
    from hykin.io.dataset import DatasetError
    from hykin.io.payload import payload_from_columns

    ok = payload_from_columns({"payload_kg": np.array([0.0, 1300.0]), "payload_com_x": np.array([0.0, 1.2]),
                               "payload_com_y": np.zeros(2), "payload_com_z": np.zeros(2)}, 2, "f.csv")
    assert ok[0][1] == 1300.0 and ok[1][1, 0] == 1.2
    with pytest.raises(DatasetError, match=r"f\.csv, row 2, column 'payload_kg': 20000 kg, .* look like grams"):
        payload_from_columns({"payload_kg": np.array([10.0, 20000.0])}, 2, "f.csv")
    with pytest.raises(DatasetError, match=r"row 1, columns payload_com_x, .* look like mm"):
        payload_from_columns({"payload_kg": np.array([10.0]), "payload_com_x": np.array([50.0]),
                              "payload_com_y": np.array([-30.0]), "payload_com_z": np.array([120.0])}, 1, "f.csv")
    assert temperature_from({"temperature_c": np.array([-5.0, 22.0, 55.0])}, "t.csv")[2] == 55.0
    with pytest.raises(ValueError, match=r"t\.csv: column 'temperature_c', row 2: 299\.15 °C .* look like kelvin"):
        temperature_from({"temperature_c": np.array([22.0, 299.15])}, "t.csv")
    with pytest.raises(ValueError, match=r"row 1: 91\.4 °C .* look like °F"):
        temperature_from({"temperature_c": np.array([91.4, 75.2])}, "t.csv")


def test_fk_on_a_payload_model_says_which_payload_it_assumed(capsys):
    """Probe report s40: fk on a model trained at 0 and 12 kg, joints without a payload column and no
    --payload-kg, gave 0 kg poses without a word (0.63 mm off at 12 kg)."""
    from types import SimpleNamespace

    from hykin.cli.common import note_default_payload
    from hykin.io.payload import PayloadRange

    m = SimpleNamespace(payload_range_=PayloadRange(0.0, 12.0, [0.0, 12.0]), robot_=SimpleNamespace(payload_kg=0.0))
    note_default_payload(m, None, {}, "joints.csv")
    err = capsys.readouterr().err
    assert "joints.csv has no payload_kg column" in err and "0 kg, is assumed" in err and "0-12 kg" in err
    for kg, extra in ((12.0, {}), (None, {"payload_kg": np.zeros(3)})):
        note_default_payload(m, kg, extra, "joints.csv")
        assert capsys.readouterr().err == ""
