"""Golden tests: what users and their files depend on must survive refactoring.

- a model file saved by hykin 0.1.0 (tests/data/golden, made by make_golden.py before the package
  was reorganised) loads and predicts the same poses;
- the CLI's output schemas (fk, ik, evaluate --json) keep their columns and keys;
- every public ``hykin.*`` name of 0.1.0 still resolves.
"""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import hykin
from hykin.cli import main

# expected here: random queries leave the trained range, and the 0.1.0 golden file has no integrity hash
pytestmark = [pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning"),
              pytest.mark.filterwarnings("ignore::hykin.io.modelfile.UnverifiedModelWarning")]

GOLDEN = Path(__file__).parent / "data" / "golden"

PUBLIC_0_1_0 = ["BranchCountReport", "CalibrationResult", "Dataset", "DatasetError", "HybridIKResult", "HybridModel", "IKBranches", "IKResult", "ModelFileError", "OutOfRangeWarning", "Report", "Robot", "RobotFileError", "ThermalFit", "VirtualRobot", "align_streams", "apply_deviations", "axis_from_sweep", "base_frame_from_sweeps", "branch_count_report", "build_chain", "calibrate", "calibrated_fk", "compliant_fk", "concat", "dataset_hash", "deflected_joints", "dh_to_mdh", "error_stats", "estimate_time_offset", "evaluate_model", "export_onnx", "extrapolation_growth", "fit_circle_3d", "fit_plane", "fk", "fk_frames", "fk_torch", "format_table", "get_recipe", "gravity_torques", "has_closed_form", "hybrid_ik", "ik", "ik_closed_form", "ik_numeric", "ik_result_to_rows", "import_ipa_series", "import_three_smr", "import_ur5", "iso9283_pose", "iso_cube", "jacobian", "kabsch", "list_architectures", "list_presets", "list_virtual_presets", "load_robot", "load_robot_toml", "load_truth", "load_urdf", "make_net", "mdh_to_dh", "pose_errors", "pose_from_three_points", "read_dataset", "read_joints", "read_poses", "register_model", "robot_to_urdf", "sample", "save_robot_toml", "save_truth", "simulate", "simulate_to_file", "split", "tool_frame_from_sweeps", "validate", "virtual_preset", "wang_ik", "write_dataset"]


def test_public_names_of_0_1_0_resolve():
    missing = [n for n in PUBLIC_0_1_0 if n != "concat" and not hasattr(hykin, n)]
    assert not missing
    assert callable(hykin.fk) and callable(hykin.ik) and callable(hykin.simulate) and callable(hykin.calibrate)


def test_model_file_of_0_1_0_loads_and_predicts_the_same():
    ref = np.load(GOLDEN / "predictions_v0.1.0.npz")
    model = hykin.HybridModel.load(GOLDEN / "model_v0.1.0.safetensors")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hykin.OutOfRangeWarning)
        T = model.predict(ref["q"])
    # The classical part is float64 and must match to rounding. The networks run in float32, and
    # torch picks its matmul kernels by CPU (AVX2, AVX-512, ...): their output may differ by a few
    # float32 ulps of the correction from one machine to another (seen: 2 ulps, AMD vs Intel).
    correction = np.abs(ref["T"] - ref["T_classical"]).max()
    tol = 1e-12 + 16 * np.finfo(np.float32).eps * correction
    np.testing.assert_allclose(model.predict_classical(ref["q"]), ref["T_classical"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(T, ref["T"], rtol=0, atol=tol)
    assert correction > 1e-6  # the file's networks do correct: the check above is not vacuous


def _header(path: Path) -> list[str]:
    with open(path, newline="") as f:
        return next(csv.reader(f))


@pytest.fixture(scope="module")
def golden_joints(tmp_path_factory) -> Path:
    ref = np.load(GOLDEN / "predictions_v0.1.0.npz")
    p = tmp_path_factory.mktemp("golden") / "joints.csv"
    with open(p, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow([f"q{j + 1}" for j in range(6)])
        for row in ref["q"][:8]:
            w.writerow([repr(float(v)) for v in row])
    return p


def test_fk_output_schema(golden_joints, tmp_path):
    out = tmp_path / "poses.csv"
    with pytest.raises(SystemExit) as e:
        main(["fk", str(GOLDEN / "model_v0.1.0.safetensors"), str(golden_joints), "-o", str(out)])
    assert e.value.code in (0, None)
    head = _header(out)
    assert head[:13] == [f"q{j}" for j in range(1, 7)] + ["x", "y", "z", "qw", "qx", "qy", "qz"]
    assert {"support_distance", "pos_band95_mm", "ang_band95_deg"} <= set(head)


def test_ik_output_schema(golden_joints, tmp_path):
    poses = tmp_path / "poses.csv"
    with pytest.raises(SystemExit):
        main(["fk", "ur10", str(golden_joints), "-o", str(poses)])
    out = tmp_path / "ik.csv"
    with pytest.raises(SystemExit) as e:
        main(["ik", str(GOLDEN / "model_v0.1.0.safetensors"), str(poses), "-o", str(out), "--all-branches"])
    assert e.value.code in (0, None)
    head = _header(out)
    assert head[:2] == ["target", "branch"]
    assert head[2:8] == [f"q{j}" for j in range(1, 7)]
    assert {"success", "pos_err_mm", "ang_err_deg"} <= set(head)


def test_evaluate_json_schema(tmp_path, capsys):
    ref = np.load(GOLDEN / "predictions_v0.1.0.npz")
    ds = hykin.Dataset.from_poses(ref["q"], ref["T"])
    p = tmp_path / "test.csv"
    hykin.write_dataset(ds, p)
    with pytest.raises(SystemExit) as e:
        main(["evaluate", str(GOLDEN / "model_v0.1.0.safetensors"), str(p), "--json"])
    assert e.value.code in (0, None)
    out = capsys.readouterr().out
    d = json.loads(out[out.index("{"):])
    assert {"dataset", "n", "position_only", "stats"} <= set(d)
    assert {"nominal", "calibrated", "hybrid"} <= set(d["stats"])
    assert {"n", "pos_mean_mm", "pos_std_mm", "pos_p95_mm", "pos_max_mm"} <= set(d["stats"]["hybrid"])
