"""The main job end to end (quick mode) and the ONNX export of a hybrid model."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hykin.geometry.se3 import pose_error
from hykin.hybrid.model import HybridModel
from hykin.sim.presets import virtual_preset
from hykin.sim.sampling import sample
from hykin.sim.simulate import simulate


@pytest.fixture(scope="module")
def small_model():
    vr = virtual_preset("rx160-nongeo", seed=0)
    # the export and the round trip compare hykin with itself: any fitted model with compliance will do
    train = simulate(vr, sample("uniform", vr.nominal, 600, 0), noise=False, rng=1)
    return HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 4, "min_steps": 0}).fit(train, progress=False)


@pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")  # random test poses a hair outside the training range
def test_demo_quick_writes_report_and_beats_nominal(tmp_path):
    from hykin.cli.demo import run_demo

    path = run_demo(tmp_path / "demo", quick=True)
    html = path.read_text()
    assert path.name == "report.html" and html.count("data:image/png;base64,") >= 3
    # The model the demo saved is loadable and far better than the nominal robot on the demo's test set.
    from hykin.io.dataset_files import read_dataset
    from hykin.kinematics.fk import fk

    model = HybridModel.load(tmp_path / "demo" / "model.hykin")
    test = read_dataset(tmp_path / "demo" / "test.csv")
    p_nom, _ = pose_error(fk(model.nominal, test.q), test.poses())
    p_hyb, a_hyb = pose_error(model.predict(test.q), test.poses())
    assert p_nom.mean() > 1.0  # the virtual RX160 is ~1.8 mm off its nominal model
    assert p_hyb.mean() < 1e-3 and a_hyb.mean() < 1e-3  # µm-level after calibration + networks
    assert json.loads((tmp_path / "demo" / "truth.json").read_text())


@pytest.mark.slow  # the default suite exports a compliant model in tests/test_export_s39.py (ONNX Runtime at several payloads)
@pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")  # random joints fall in holes of 1,500 samples
def test_onnx_export_matches_hykin(tmp_path, small_model):
    pytest.importorskip("onnxruntime")
    from hykin.hybrid.export import export_onnx

    info = export_onnx(small_model, tmp_path / "m.onnx", n_check=500)
    assert info["max_pos_diff_mm"] < 1e-6 and info["max_ang_diff_deg"] < 1e-6
    # independent check with fresh joints, straight through ONNX Runtime
    import onnxruntime as ort

    q = small_model.nominal.random_joints(64, 5)
    q = np.clip(q, small_model.support_lower_, small_model.support_upper_)
    sess = ort.InferenceSession(str(tmp_path / "m.onnx"))
    feed = {"q": q}
    names = {i.name for i in sess.get_inputs()}
    if "payload_kg" in names:  # a model with compliance: the graph takes the payload (the file's here)
        feed["payload_kg"] = np.array([small_model.robot_.payload_kg])
    if "payload_com_m" in names:
        feed["payload_com_m"] = np.zeros((1, 3))
    T = sess.run(None, feed)[0]
    p, a = pose_error(T, small_model.predict(q))
    assert p.max() < 1e-6 and a.max() < 1e-6
    # no Mul(x, Sigmoid(x)): ONNX Runtime 1.30 fuses it into a float32-only kernel and then refuses
    # to load the float64 graph; the SiLU nets are traced as a division instead, and put back after
    import onnx
    import torch

    from hykin.hybrid.fast_nets import torch64

    g = onnx.load(str(tmp_path / "m.onnx")).graph
    sigmoid_of = {n.output[0]: n.input[0] for n in g.node if n.op_type == "Sigmoid"}
    fusable = [n.name for n in g.node if n.op_type == "Mul" and len(n.input) == 2 and any(
        sigmoid_of.get(a) == b for a, b in (n.input, n.input[::-1]))]
    assert not fusable and sum(n.op_type == "Exp" for n in g.node) >= 3  # the default nets' three SiLU layers
    assert sum(isinstance(mod, torch.nn.SiLU) for mod in torch64(small_model, small_model.net_pos_).modules()) == 3


def test_onnx_export_on_a_runtime_that_cannot_run_it_writes_nothing(tmp_path, small_model, monkeypatch):
    """ONNX Runtime before 1.29 has no float64 Cos: the export says which version it needs and leaves
    neither the file nor its temporary behind (an older file at the target stays as it was)."""
    ort = pytest.importorskip("onnxruntime")
    from hykin.hybrid.export import MIN_ORT, export_onnx

    class Refusing:
        def __init__(self, *a, **k):
            raise RuntimeError("[ONNXRuntimeError] : 9 : NOT_IMPLEMENTED : Could not find an implementation for Cos(7)")

    monkeypatch.setattr(ort, "InferenceSession", Refusing)
    import torch

    # the trace itself is checked above; here a stand-in writes the file it would have written
    monkeypatch.setattr(torch.onnx, "export", lambda model, args, f, **kw: open(f, "wb").write(b"traced"))
    (tmp_path / "old.onnx").write_bytes(b"earlier export")
    with pytest.raises(RuntimeError, match=rf"onnxruntime>={MIN_ORT}.*Nothing was written"):
        export_onnx(small_model, tmp_path / "old.onnx", n_check=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.onnx"]
    assert (tmp_path / "old.onnx").read_bytes() == b"earlier export"


def test_registered_model_roundtrip(tmp_path, small_model):
    """A model with registration frames saves and loads them (the frames change predictions)."""
    from hykin.geometry import se3

    m = small_model
    q = m.nominal.random_joints(20, 3)
    T0 = m.predict(q)
    import copy

    m2 = copy.deepcopy(m)
    m2.frame_pre_ = se3.trans(0.1, -0.2, 0.3) @ se3.rotz(0.3)
    m2.frame_post_ = se3.trans(0, 0, 0.05)
    m2.save(tmp_path / "r.hykin")
    m3 = HybridModel.load(tmp_path / "r.hykin")
    T3 = m3.predict(q)
    assert np.allclose(T3, m2.frame_pre_ @ T0 @ m2.frame_post_, atol=1e-12)
