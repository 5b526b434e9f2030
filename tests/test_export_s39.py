"""What leaves hykin for a controller or ROS: the ONNX graph takes the payload (kg per row, and the
centre of mass when compliance deflects under it), checked with ONNX Runtime against the model at
several payloads; `export` / `export-urdf` refuse a wrong extension; a URDF of a compliant robot says how
far its rigid FK is from the calibrated robot (checked with an independent numpy URDF FK)."""

from __future__ import annotations

import re
import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from cli_run import run
from hykin.geometry.se3 import pose_error
from hykin.hybrid.model import HybridModel
from hykin.kinematics.compliance import compliant_fk
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")


@pytest.fixture(scope="module")
def vr():
    return virtual_preset("kr-payload-virtual", seed=3)


@pytest.fixture(scope="module")
def payload_model(vr):
    """A compliant robot trained at 0 and 15 kg (payload_kg column): payload is a network input too."""
    q = vr.nominal.random_joints(120, 1)
    train = simulate(vr, q, payload_kg=np.where(np.arange(120) % 2 == 0, 0.0, 15.0), noise=False, rng=1)
    m = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 1, "min_steps": 0}).fit(train, progress=False)
    assert m.payload_input_ and m.robot_.has_compliance
    return m


def _q(model, n, seed):
    lo, hi = np.asarray(model.support_lower_), np.asarray(model.support_upper_)
    return lo + np.random.default_rng(seed).random((n, len(lo))) * (hi - lo)


@pytest.fixture(scope="module")
def payload_onnx(payload_model, tmp_path_factory):
    pytest.importorskip("onnxruntime")
    from hykin.hybrid.export import export_onnx

    path = tmp_path_factory.mktemp("onnx") / "m.onnx"
    return path, export_onnx(payload_model, path, n_check=120)


def test_onnx_graph_takes_the_payload_and_matches_the_model_at_every_payload(payload_model, payload_onnx):
    """probeR #1: the graph took q alone and baked in the file's payload (0.44 mm off at 0 kg)."""
    import onnxruntime as ort

    m = payload_model
    path, info = payload_onnx
    assert info["inputs"] == ["q", "payload_kg", "payload_com_m"]
    assert {0.0, 15.0, m.robot_.payload_kg} <= set(info["payloads_checked_kg"]) and max(info["payloads_checked_kg"]) > 15
    sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    assert [i.name for i in sess.get_inputs()] == ["q", "payload_kg", "payload_com_m"]
    q = _q(m, 40, 7)
    com0 = np.zeros((1, 3))
    far = []
    for kg in (0.0, 15.0, 7.5, m.robot_.payload_kg, 40.0):  # trained, between, the file's, beyond
        T = sess.run(None, {"q": q, "payload_kg": np.array([kg]), "payload_com_m": com0})[0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ref = m.predict(q, payload_kg=kg)
        p, a = pose_error(T, ref)
        assert p.max() < 1e-6 and a.max() < 1e-6, kg
        far.append(pose_error(T, m.predict(q))[0].mean())  # the file's payload: all the old graph gave
    assert far[3] < 1e-6 and far[1] > 0.05 and far[4] > 0.05  # the payload matters here (mm)
    # per-row payloads and centres of mass
    kg = np.linspace(0.0, 20.0, len(q))
    com = np.random.default_rng(2).uniform(-0.15, 0.15, (len(q), 3))
    T = sess.run(None, {"q": q, "payload_kg": kg, "payload_com_m": com})[0]
    p, a = pose_error(T, m.predict(q, payload_kg=kg, payload_com_m=com))
    assert p.max() < 1e-6 and a.max() < 1e-6
    assert pose_error(T, m.predict(q, payload_kg=kg))[0].mean() > 1e-3  # the centre of mass matters too
    T1 = sess.run(None, {"q": q[:1], "payload_kg": kg[:1], "payload_com_m": com[:1]})[0]  # one row
    assert pose_error(T1, m.predict(q[:1], payload_kg=kg[:1], payload_com_m=com[:1]))[0].max() < 1e-6


def test_onnx_of_a_model_without_payload_dependence_takes_joints_alone_and_networks_only_take_kg(vr, tmp_path):
    ort = pytest.importorskip("onnxruntime")
    from hykin.hybrid.export import export_onnx, payload_inputs

    rigid = vr.nominal.copy(stiffness_nm_per_rad=np.full(vr.nominal.n_chain, np.inf))
    q = rigid.random_joints(80, 4)
    kw = dict(seed=0, recipe_kw={"max_epochs": 1, "min_steps": 0}, calibrate_kw={"compliance": False}, uncertainty=False)
    one = HybridModel(rigid, **kw).fit(simulate(vr, q, noise=False, rng=1), progress=False)
    assert not one.robot_.has_compliance and payload_inputs(one) == ()
    info = export_onnx(one, tmp_path / "one.onnx", n_check=50)
    assert info["inputs"] == ["q"] and info["payloads_checked_kg"] == []
    two = HybridModel(rigid, **kw).fit(simulate(vr, q, payload_kg=np.arange(80) % 2 * 12.0, noise=False, rng=1),
                                       progress=False)
    assert payload_inputs(two) == ("payload_kg",)
    export_onnx(two, tmp_path / "two.onnx", n_check=50)
    sess = ort.InferenceSession(str(tmp_path / "two.onnx"), providers=["CPUExecutionProvider"])
    qq = _q(two, 20, 3)
    for kg in (0.0, 12.0, 6.0):
        T = sess.run(None, {"q": qq, "payload_kg": np.full(len(qq), kg)})[0]
        assert pose_error(T, two.predict(qq, payload_kg=kg))[0].max() < 1e-6


def test_export_cli_prints_the_payload_inputs_and_refuses_a_wrong_extension(payload_model, tmp_path, monkeypatch, capsys):
    import hykin.hybrid.export as export_mod

    mp = tmp_path / "m.hykin"
    payload_model.save(mp)
    code, _, err = run(["export", mp, "-o", tmp_path / "m.txt"], capsys)
    assert code == 2 and "name the output m.onnx" in err and not (tmp_path / "m.txt").exists()
    code, _, err = run(["export-urdf", mp, "-o", tmp_path / "m.toml"], capsys)
    assert code == 2 and "name the output m.urdf" in err and not (tmp_path / "m.toml").exists()
    fake = {"max_pos_diff_mm": 1e-12, "max_ang_diff_deg": 1e-13, "n_check": 1, "inputs": ["q", "payload_kg", "payload_com_m"],
            "payload_default_kg": payload_model.robot_.payload_kg, "payloads_checked_kg": [0.0, 15.0, 19.75]}
    monkeypatch.setattr(export_mod, "export_onnx", lambda mdl, out: fake)  # the export itself: the test above
    code, o, err = run(["export", mp, "-o", tmp_path / "m.onnx"], capsys)
    assert code == 0, err
    assert "at payloads 0, 15, 19.75 kg" in o and "payload_kg ((N,) or (1,) kg)" in o and "payload_com_m" in o
    assert f"the robot file's is {payload_model.robot_.payload_kg:g} kg" in o


# --------------------------------------------------------------------------- URDF: the compliance left out


def _rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _urdf_fk(text, q, tip):
    """An independent URDF FK (numpy, serial chain root -> ``tip``): fixed-axis rpy origins, revolute
    joints about their axis, joints in chain order take the columns of ``q``."""
    root = ET.fromstring(text)
    by_child = {j.find("child").get("link"): j for j in root.findall("joint")}
    chain, ln = [], tip
    while ln in by_child:
        chain.append(by_child[ln])
        ln = by_child[ln].find("parent").get("link")
    out = np.empty((len(q), 4, 4))
    for k, qk in enumerate(q):
        T, i = np.eye(4), 0
        for j in chain[::-1]:
            o = j.find("origin")
            xyz = np.array([float(v) for v in o.get("xyz").split()])
            O = np.eye(4)
            O[:3, :3], O[:3, 3] = _rpy(*[float(v) for v in o.get("rpy").split()]), xyz
            T = T @ O
            if j.get("type") != "fixed":
                ax = np.array([float(v) for v in j.find("axis").get("xyz").split()])
                ax /= np.linalg.norm(ax)
                K = np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]], [-ax[1], ax[0], 0]])
                J = np.eye(4)
                J[:3, :3] = np.eye(3) + np.sin(qk[i]) * K + (1 - np.cos(qk[i])) * K @ K
                T, i = T @ J, i + 1
        out[k] = T
    return out


def _numbers(line):
    m = re.search(r"rigid FK is ([0-9.e+-]+) mm mean / ([0-9.e+-]+) mm max", line)
    assert m, line
    return float(m.group(1)), float(m.group(2))


def test_calibrated_urdf_of_a_compliant_robot_says_how_far_its_rigid_fk_is(vr, tmp_path, capsys):
    """probeR #6: the note said only 'a URDF cannot carry joint compliance'; now mean / max mm over
    1000 joint configurations within the limits (seed 0), at the file's payload."""
    from hykin.io.robot_toml import save_robot_toml
    from hykin.io.urdf import GAP_POSES, calibrated_robot_urdf

    rob = vr.truth.copy(payload_kg=10.0)
    assert rob.has_compliance
    text, left = calibrated_robot_urdf(rob)
    mean, mx = _numbers(left)
    q = rob.random_joints(GAP_POSES, rng=0)
    d = np.linalg.norm(_urdf_fk(text, q, "tcp")[:, :3, 3] - compliant_fk(rob, q)[:, :3, 3], axis=1) * 1e3
    assert mean == pytest.approx(d.mean(), rel=2e-3) and mx == pytest.approx(d.max(), rel=2e-3)
    assert d.mean() > 0.05 and f"{rob.payload_kg:g} kg payload" in left and left.startswith("joint compliance")
    assert calibrated_robot_urdf(rob.copy(stiffness_nm_per_rad=np.full(rob.n_chain, np.inf)))[1] == ""
    # calibrate -o X.urdf prints it (and refuses nothing here: a DH/MDH robot may be written as URDF)
    rp = tmp_path / "rob.toml"
    save_robot_toml(rob, rp)
    from hykin.io.dataset_files import write_dataset

    write_dataset(simulate(vr, rob.random_joints(120, 9), noise=False, rng=1, payload_kg=10.0), tmp_path / "d.csv")
    code, o, err = run(["calibrate", rp, tmp_path / "d.csv", "-o", tmp_path / "cal.urdf"], capsys)
    assert code == 0, err
    assert "a URDF cannot carry joint compliance (the URDF's rigid FK is" in o and "mm max" in o


def test_export_urdf_of_a_compliant_model_says_how_far_its_rigid_fk_is(payload_model, tmp_path, capsys):
    from hykin.io.urdf import GAP_POSES

    m = payload_model
    mp = tmp_path / "m.hykin"
    m.save(mp)
    code, o, err = run(["export-urdf", mp, "-o", tmp_path / "m.urdf"], capsys)
    assert code == 0, err
    mean, mx = _numbers(o)
    assert "training range" in o and "the residual networks" in o
    q = _q(m, GAP_POSES, 0)
    text = (tmp_path / "m.urdf").read_text()
    tcp = [ln.get("name") for ln in ET.fromstring(text).findall("link")][-1]
    d = np.linalg.norm(_urdf_fk(text, q, tcp)[:, :3, 3] - m.predict_classical(q)[:, :3, 3], axis=1) * 1e3
    assert mean == pytest.approx(d.mean(), rel=2e-3) and mx == pytest.approx(d.max(), rel=2e-3)
