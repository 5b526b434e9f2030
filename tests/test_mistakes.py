"""User mistakes: every one is refused with a non-zero exit status and ONE line naming the cause, and
nothing is written (issue #14: no silent wrong answers).

Each case drives ``hykin.cli.main`` as a user would, on a robot that is not a preset (own DH table, in
mm and degrees), and checks: exit status != 0; stderr is exactly one line ``hykin: error: ...``
containing a keyword of the cause; the output file does not exist afterwards (or, when it existed,
is byte-for-byte unchanged); every input file keeps its bytes and mtime.

Also here: unsolved IK targets get no joint values and a reason in every IK path; the CLI and the
Python API train the same model (bit-identical predictions); the model file's integrity hash.
"""

from __future__ import annotations

import csv
import json
import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest

import hykin
from hykin.cli import main
from hykin.io.dataset import Dataset
from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.io.modelfile import ModelFileError
from hykin.kinematics.fk import fk

# A 6-dof arm unlike the presets: other link lengths, joint 1 limited to ±100° (so a target behind it
# needs joints outside the limits), in mm and degrees.
ROBOT_TOML = """
name = "test-arm"
convention = "dh"
length_unit = "mm"
angle_unit = "deg"
[[joints]]
a = 120
alpha = -90
d = 480
theta = 0
min = -100
max = 100
[[joints]]
a = 700
alpha = 0
d = 0
theta = -90
min = -130
max = 130
[[joints]]
a = 40
alpha = 90
d = 0
theta = 90
min = -140
max = 140
[[joints]]
a = 0
alpha = -90
d = 560
min = -270
max = 270
[[joints]]
a = 0
alpha = 90
d = 0
min = -115
max = 115
[[joints]]
a = 0
alpha = 0
d = 90
min = -270
max = 270
[tool]
xyz = [0, 0, 60]
rpy = [0, 0, 0]
"""

N_ROWS = 60
FAST = ["--max-epochs", "3", "--min-steps", "0"]


def _read_rows(path: Path) -> tuple[list[str], list[list[str]]]:
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def _write_rows(path: Path, header, rows) -> Path:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    return path


def _scaled(src: Path, dst: Path, cols, factor: float) -> Path:
    head, rows = _read_rows(src)
    idx = [head.index(c) for c in cols]
    for r in rows:
        for i in idx:
            r[i] = repr(float(r[i]) * factor)
    return _write_rows(dst, head, rows)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Robot file, measured data (m, rad, qw..qz), joints, targets and a model fitted by the CLI."""
    d = tmp_path_factory.mktemp("mistakes")
    robot_path = d / "robot.toml"
    robot_path.write_text(ROBOT_TOML)
    robot = hykin.load_robot(robot_path)
    # the "real" robot: the nominal one with small geometric errors and another tool
    truth = robot.copy(a_m=robot.a_m + [0.4e-3, -0.3e-3, 0.2e-3, 0, 0, 0], d_m=robot.d_m + [0, 0, 0, 0.5e-3, 0, 0],
                       theta_rad=robot.theta_rad + np.radians([0.05, -0.03, 0.02, 0, 0.04, 0]))
    q = robot.random_joints(N_ROWS, rng=3, margin=0.05)
    rng = np.random.default_rng(4)
    T = fk(truth, q)
    T[:, :3, 3] += rng.normal(0, 20e-6, (N_ROWS, 3))
    data = d / "data.csv"
    write_dataset(Dataset.from_poses(q, T), data)
    joints = d / "joints.csv"
    _write_rows(joints, [f"q{j + 1}" for j in range(6)], [[repr(float(v)) for v in row] for row in q[:12]])
    poses = d / "poses.csv"
    write_dataset(Dataset.from_poses(q[:8], T[:8]), poses)
    model = d / "model.hykin"
    code, err = _run(["fit", str(robot_path), str(data), "-o", str(model), *FAST])
    assert code == 0, err
    return {"dir": d, "robot": robot_path, "data": data, "joints": joints, "poses": poses, "model": model,
            "q": q, "T": T, "robot_obj": robot}


def _run(argv) -> tuple[int, str]:
    """Run the CLI in-process; return (exit code, stderr text)."""
    import contextlib
    import io

    err = io.StringIO()
    out = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(out), warnings.catch_warnings():
        warnings.simplefilter("default")
        try:
            main([str(a) for a in argv])
            code = 0
        except SystemExit as e:
            code = 0 if e.code in (None, 0) else int(e.code) if isinstance(e.code, int) else 1
    return code, err.getvalue()


def _state(paths) -> dict:
    return {p: (p.read_bytes(), p.stat().st_mtime_ns) for p in paths if p.is_file()}


# --------------------------------------------------------------------------- bad inputs derived per case


def _robot_text(f, tmp: Path, old: str, new: str, name="typo.toml") -> Path:
    text = ROBOT_TOML.replace(old, new, 1)
    assert text != ROBOT_TOML
    p = tmp / name
    p.write_text(text)
    return p


def _edited_model(f, tmp: Path) -> Path:
    """One number of the model's metadata changed (a link length, by 0.1 mm), header rewritten."""
    raw = f["model"].read_bytes()
    n = int.from_bytes(raw[:8], "little")
    head = json.loads(raw[8 : 8 + n])
    meta = json.loads(head["__metadata__"]["hykin"])
    meta["robot"]["a_m"][1] += 1e-4
    head["__metadata__"]["hykin"] = json.dumps(meta)
    hb = json.dumps(head).encode()
    hb += b" " * (-len(hb) % 8)
    p = tmp / "edited.hykin"
    p.write_bytes(len(hb).to_bytes(8, "little") + hb + raw[8 + n :])
    return p


def _flipped_model(f, tmp: Path) -> Path:
    raw = bytearray(f["model"].read_bytes())
    n = int.from_bytes(raw[:8], "little")
    k = 8 + n + (len(raw) - 8 - n) // 3  # inside the tensor data
    raw[k] ^= 0x40  # one exponent bit of a weight
    p = tmp / "flipped.hykin"
    p.write_bytes(bytes(raw))
    return p


def _truncated_model(f, tmp: Path) -> Path:
    raw = f["model"].read_bytes()
    p = tmp / "truncated.hykin"
    p.write_bytes(raw[: len(raw) // 2])
    return p


def _scalar_last(f, tmp: Path) -> Path:
    head, rows = _read_rows(f["data"])
    i = [head.index(c) for c in ("qw", "qx", "qy", "qz")]
    for r in rows:  # x, y, z, w written under the qw, qx, qy, qz header
        w, x, y, z = (r[k] for k in i)
        r[i[0]], r[i[1]], r[i[2]], r[i[3]] = x, y, z, w
    return _write_rows(tmp / "xyzw.csv", head, rows)


def _nan_row(f, tmp: Path) -> Path:
    head, rows = _read_rows(f["data"])
    rows[7][head.index("y")] = "nan"
    return _write_rows(tmp / "nan.csv", head, rows)


def _three_rows(f, tmp: Path) -> Path:
    head, rows = _read_rows(f["data"])
    return _write_rows(tmp / "three.csv", head, rows[:3])


def _five_joints(f, tmp: Path) -> Path:
    head, rows = _read_rows(f["data"])
    k = head.index("q6")
    return _write_rows(tmp / "five.csv", head[:k] + head[k + 1 :], [r[:k] + r[k + 1 :] for r in rows])


def _deg_as_rad(f, tmp: Path) -> Path:
    return _scaled(f["data"], tmp / "deg.csv", [f"q{j}" for j in range(1, 7)], 180 / math.pi)


def _joints_rad_in_file(f, tmp: Path) -> Path:
    return f["joints"]  # radians, to be declared --angle-unit deg


def _symlink_to_data(f, tmp: Path) -> Path:
    p = tmp / "link.csv"
    p.symlink_to(f["data"])
    return p


# Each case: id, argv builder (f, tmp, out) -> list, keyword(s) in the error line, output path
# builder, extra input files to watch. "{x}" placeholders resolve from the fixture.
def _cases():
    R, D, M, J, P = "robot", "data", "model", "joints", "poses"

    def c(id_, argv, keys, out="out.csv", pre=None):
        return pytest.param(argv, keys, out, pre, id=id_)

    return [
        # --- paths
        c("fit-missing-robot", lambda f, t, o: ["fit", t / "nope.toml", f[D], "-o", o, *FAST], ["nope.toml"], "m.hykin"),
        c("fit-unknown-preset", lambda f, t, o: ["fit", "rx1600", f[D], "-o", o, *FAST], ["not a preset"], "m.hykin"),
        c("fit-missing-data", lambda f, t, o: ["fit", f[R], t / "nope.csv", "-o", o, *FAST], ["not found"], "m.hykin"),
        c("fit-missing-out-folder", lambda f, t, o: ["fit", f[R], f[D], "-o", t / "no" / "m.hykin", *FAST],
          ["does not exist"], "no/m.hykin"),
        c("fit-out-is-input", lambda f, t, o: ["fit", f[R], f[D], "-o", f[D], *FAST], ["input"], None),
        c("fit-out-symlink-to-input", lambda f, t, o: ["fit", f[R], f[D], "-o", _symlink_to_data(f, t), *FAST],
          ["input"], None),
        c("fit-existing-out", lambda f, t, o: ["fit", f[R], f[D], "-o", o, *FAST], ["--force"], "m.hykin", b"keep me"),
        c("fk-missing-model", lambda f, t, o: ["fk", t / "nope.hykin", f[J], "-o", o], ["nope.hykin"]),
        c("fk-missing-joints", lambda f, t, o: ["fk", f[M], t / "nope.csv", "-o", o], ["not found"]),
        c("fk-out-is-input", lambda f, t, o: ["fk", f[M], f[D], "-o", f[D]], ["input"], None),
        c("fk-existing-out", lambda f, t, o: ["fk", f[M], f[J], "-o", o], ["--force"], "out.csv", b"q1\n"),
        c("ik-missing-poses", lambda f, t, o: ["ik", f[M], t / "nope.csv", "-o", o], ["not found"]),
        c("ik-out-is-input", lambda f, t, o: ["ik", f[M], f[P], "-o", f[P]], ["input"], None),
        c("ik-out-folder-missing", lambda f, t, o: ["ik", f[R], f[P], "-o", t / "x" / "j.csv"], ["does not exist"],
          "x/j.csv"),
        c("evaluate-missing-model", lambda f, t, o: ["evaluate", t / "nope.hykin", f[D]], ["nope.hykin"], None),
        c("evaluate-report-is-file", lambda f, t, o: ["evaluate", f[M], f[D], "--report", f[J]], ["directory"], None),
        c("calibrate-out-folder-missing", lambda f, t, o: ["calibrate", f[R], f[D], "-o", t / "no" / "r.toml"],
          ["does not exist"], "no/r.toml"),
        c("calibrate-out-is-robot", lambda f, t, o: ["calibrate", f[R], f[D], "-o", f[R]], ["input"], None),
        c("register-out-is-model", lambda f, t, o: ["register", f[M], f[D], "-o", f[M]], ["input"], None),
        c("register-csv-as-model", lambda f, t, o: ["register", f[D], f[D], "-o", o], ["model file"], "m.hykin"),
        c("export-existing-out", lambda f, t, o: ["export", f[M], "-o", o], ["--force"], "m.onnx", b"onnx"),
        c("export-missing-model", lambda f, t, o: ["export", t / "nope.hykin", "-o", o], ["nope.hykin"], "m.onnx"),
        c("simulate-existing-out", lambda f, t, o: ["simulate", "rx160-virtual", "-n", "5", "-o", o], ["--force"],
          "out.csv", b"x\n"),
        c("simulate-unknown-preset", lambda f, t, o: ["simulate", "rx1600-virtual", "-n", "5", "-o", o], ["rx1600"]),
        c("split-out-is-input", lambda f, t, o: ["split", _copy(f[D], t / "s_train.csv"), "-o", t / "s"], ["input"],
          None),
        c("import-missing-input", lambda f, t, o: ["import", "ur5", t / "nope.csv", "-o", o], ["nope.csv"]),
        c("demo-out-folder-missing", lambda f, t, o: ["demo", "--quick", "-o", t / "no" / "demo"], ["does not exist"],
          "no/demo"),
        c("fit-out-is-directory", lambda f, t, o: ["fit", f[R], f[D], "-o", _mkdir(t / "adir"), *FAST],
          ["directory"], None),
        c("fit-missing-val", lambda f, t, o: ["fit", f[R], f[D], "--val", t / "nope.csv", "-o", o, *FAST],
          ["nope.csv"], "m.hykin"),
        c("export-out-is-model", lambda f, t, o: ["export", f[M], "-o", f[M]], ["input"], None),
        c("ik-seed-joints-wrong-rows", lambda f, t, o: ["ik", f[M], f[P], "--seed-joints", _three_rows(f, t), "-o",
                                                        o], ["expected 1 or 8"]),
        c("fit-unknown-length-unit", lambda f, t, o: ["fit", f[R], f[D], "-o", o, "--length-unit", "cm", *FAST],
          ["length_unit"], "m.hykin"),
        c("fk-joints-beyond-limits", lambda f, t, o: ["fk", f[R], _scaled(f[J], t / "lim.csv", ["q1"], 3.0), "-o", o],
          ["limits"]),
        # --- units and conventions
        c("fit-metres-declared-mm", lambda f, t, o: ["fit", f[R], f[D], "-o", o, "--length-unit", "mm", *FAST],
          ["length-unit"], "m.hykin"),
        c("fit-mm-declared-m", lambda f, t, o: ["fit", f[R], _scaled(f[D], t / "mm.csv", "xyz", 1e3), "-o", o, *FAST],
          ["millimetres"], "m.hykin"),
        c("fit-degrees-declared-rad", lambda f, t, o: ["fit", f[R], _deg_as_rad(f, t), "-o", o, *FAST], ["degrees"],
          "m.hykin"),
        c("fit-radians-declared-deg", lambda f, t, o: ["fit", f[R], f[D], "-o", o, "--angle-unit", "deg", *FAST],
          ["radians"], "m.hykin"),
        c("fit-scalar-last-quaternions", lambda f, t, o: ["fit", f[R], _scalar_last(f, t), "-o", o, *FAST],
          ["scalar-last"], "m.hykin"),
        c("register-scalar-last-quaternions", lambda f, t, o: ["register", f[M], _scalar_last(f, t), "-o", o],
          ["scalar-last"], "m.hykin"),
        c("calibrate-metres-declared-mm", lambda f, t, o: ["calibrate", f[R], f[D], "-o", o, "--length-unit", "mm"],
          ["length-unit"], "r.toml"),
        c("evaluate-metres-declared-mm", lambda f, t, o: ["evaluate", f[M], f[D], "--length-unit", "mm"],
          ["length-unit"], None),
        c("fk-radians-declared-deg", lambda f, t, o: ["fk", f[M], _joints_rad_in_file(f, t), "-o", o, "--angle-unit",
                                                      "deg"], ["radians"]),
        c("ik-metres-declared-mm", lambda f, t, o: ["ik", f[M], f[P], "-o", o, "--length-unit", "mm"], ["length-unit"]),
        c("fit-nan-row", lambda f, t, o: ["fit", f[R], _nan_row(f, t), "-o", o, *FAST], ["not finite"], "m.hykin"),
        c("fit-three-rows", lambda f, t, o: ["fit", f[R], _three_rows(f, t), "-o", o, *FAST], ["too few", "30"],
          "m.hykin"),
        c("fit-wrong-joint-count", lambda f, t, o: ["fit", f[R], _five_joints(f, t), "-o", o, *FAST], ["q6"],
          "m.hykin"),
        # --- robot files
        c("robot-lenght_unit", lambda f, t, o: ["fit", _robot_text(f, t, "length_unit", "lenght_unit"), f[D], "-o", o],
          ["lenght_unit", "did you mean 'length_unit'"], "m.hykin"),
        c("robot-angle_unt", lambda f, t, o: ["fk", _robot_text(f, t, "angle_unit", "angle_unt"), f[J], "-o", o],
          ["angle_unt", "did you mean 'angle_unit'"]),
        c("robot-tol-table", lambda f, t, o: ["fk", _robot_text(f, t, "[tool]", "[tol]"), f[J], "-o", o],
          ["unknown key 'tol'", "tool"]),
        c("robot-paylod", lambda f, t, o: ["fk", _robot_text(f, t, 'name = "test-arm"', 'name = "x"\npaylod = 5'),
                                           f[J], "-o", o], ["paylod", "payload"]),
        c("robot-missing-d", lambda f, t, o: ["fk", _robot_text(f, t, "d = 480\n", ""), f[J], "-o", o],
          ["joints[1]", "'d'"]),
        c("robot-joint-key-typo", lambda f, t, o: ["calibrate", _robot_text(f, t, "alpha = -90", "alhpa = -90"), f[D],
                                                   "-o", o], ["alhpa", "did you mean 'alpha'"], "r.toml"),
        c("robot-mm-values-declared-m", lambda f, t, o: ["fk", _robot_text(f, t, 'length_unit = "mm"',
                                                                      'length_unit = "m"'), f[J], "-o", o],
          ["length_unit = 'mm'"]),
        c("robot-tool-key-typo", lambda f, t, o: ["fk", _robot_text(f, t, "xyz = [0, 0, 60]", "xzy = [0, 0, 60]"),
                                                  f[J], "-o", o], ["xzy", "xyz"]),
        # --- model files
        c("fk-edited-model-metadata", lambda f, t, o: ["fk", _edited_model(f, t), f[J], "-o", o], ["edited"]),
        c("fk-flipped-weight-bit", lambda f, t, o: ["fk", _flipped_model(f, t), f[J], "-o", o], ["corrupt"]),
        c("export-edited-model", lambda f, t, o: ["export", _edited_model(f, t), "-o", o], ["edited"], "m.onnx"),
        c("ik-truncated-model", lambda f, t, o: ["ik", _truncated_model(f, t), f[P], "-o", o], ["model"]),
        c("fk-csv-as-model", lambda f, t, o: ["fk", f[D], f[J], "-o", o], ["not a hykin model"]),
        c("fk-model-as-joints", lambda f, t, o: ["fk", f[M], f[M], "-o", o], ["model.hykin"]),
        # --- commands added with compensation, planning and the generic importer
        c("compensate-missing-input", lambda f, t, o: ["compensate", f[M], t / "nope.csv", "-o", o], ["nope.csv"]),
        c("compensate-robot-not-model", lambda f, t, o: ["compensate", f[R], f[P], "-o", o], ["model"]),
        c("compensate-out-is-input", lambda f, t, o: ["compensate", f[M], f[P], "-o", f[P]], ["input"], None),
        c("compensate-existing-out", lambda f, t, o: ["compensate", f[M], f[P], "-o", o], ["--force"], "out.csv",
          b"x\n"),
        c("export-urdf-edited-model", lambda f, t, o: ["export-urdf", _edited_model(f, t), "-o", o], ["edited"],
          "r.urdf"),
        c("plan-out-folder-missing", lambda f, t, o: ["plan", f[R], "-n", "20", "-o", t / "no" / "p.csv"],
          ["does not exist"], "no/p.csv"),
        c("plan-out-is-robot", lambda f, t, o: ["plan", f[R], "-n", "20", "-o", f[R]], ["input"], None),
        c("import-table-missing-column", lambda f, t, o: ["import", "table", f[D], "-o", o, "--joints", "j1,j2",
                                                          "--position", "x,y,z"], ["j1"]),
        c("serve-csv-as-model", lambda f, t, o: ["serve", f[D]], ["model"], None),
    ]


def _mkdir(p: Path) -> Path:
    p.mkdir()
    return p


def _copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


@pytest.mark.parametrize("argv, keys, out, pre", _cases())
def test_mistake_is_refused(files, tmp_path, argv, keys, out, pre):
    out_path = tmp_path / (out or "unused.out")
    if pre is not None:
        out_path.write_bytes(pre)
    args = argv(files, tmp_path, out_path)
    watched = [files[k] for k in ("robot", "data", "joints", "poses", "model")]
    watched += [Path(a) for a in args if isinstance(a, Path) and a.is_file()]
    before = _state(watched)
    listing = sorted(os.listdir(tmp_path))
    code, err = _run(args)
    assert code != 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("hykin: error: "), err
    for k in keys:
        assert k in lines[0], (k, lines[0])
    assert _state(watched) == before  # inputs untouched (bytes and mtime)
    if pre is not None:
        assert out_path.read_bytes() == pre
    else:
        assert not out_path.exists()
    # nothing else written next to the inputs or outputs
    assert sorted(os.listdir(tmp_path)) == listing


def test_at_least_30_mistakes():
    assert len(_cases()) >= 30


# --------------------------------------------------------------------------- the fixes hold


def test_force_overwrites(files, tmp_path):
    out = tmp_path / "p.csv"
    out.write_text("old\n")
    code, err = _run(["fk", files["robot"], files["joints"], "-o", out, "--force"])
    assert code == 0, err
    got = read_dataset(out)
    np.testing.assert_allclose(got.xyz_m, fk(files["robot_obj"], files["q"][:12])[:, :3, 3], rtol=0, atol=1e-12)


def _ik_targets(files) -> Path:
    """8 reachable targets, one 5 m away (out of reach), one behind the robot (joint 1 limits)."""
    robot = files["robot_obj"]
    T = fk(robot, files["q"][:8])
    far = T[0].copy()
    far[:3, 3] = [5.0, 0.0, 0.5]
    behind = fk(robot, np.radians([[180.0, 10, 20, 0, 30, 0]]))[0]
    return files["dir"], np.concatenate([T, far[None], behind[None]])


@pytest.mark.parametrize("source", ["robot", "model"])
@pytest.mark.parametrize("mode", [[], ["--all-branches"], ["--position-only"], ["--all-branches", "--position-only"]])
def test_unsolved_ik_targets_get_no_joints(files, tmp_path, source, mode):
    _, T = _ik_targets(files)
    poses = tmp_path / "targets.csv"
    write_dataset(Dataset.from_poses(np.zeros((len(T), 6)), T), poses)
    out = tmp_path / "j.csv"
    code, err = _run(["ik", files[source], poses, "-o", out, *mode])
    assert code == 0, err
    head, rows = _read_rows(out)
    col = {c: [r[head.index(c)] for r in rows] for c in head}
    target = np.array(col["target"], dtype=int)
    ok = np.array(col["success"], dtype=str)
    ok = np.isin(ok, ["1", "true", "True"])
    q = np.array([[float(v) if v not in ("", "nan") else np.nan for v in col[f"q{j}"]] for j in range(1, 7)]).T
    # every unsolved row: no joints, a categorised reason
    assert np.isnan(q[~ok]).all()
    assert np.isfinite(q[ok]).all()
    cats = ("out of reach", "joint limits", "singular", "not converged")
    for r, good in zip(col["reason"], ok):
        assert (r == "") if good else r.startswith(cats), r
    # the far target is not solved, and says out of reach (position is beyond the arm either way)
    far_rows = [r for r, t in zip(col["reason"], target) if t == 8]
    assert far_rows and all(r.startswith("out of reach") for r in far_rows), far_rows
    # the reachable ones are solved
    assert set(target[ok]) >= set(range(8))
    if "--position-only" not in mode:  # orientation and position behind the base: joint 1 at 180°
        behind = [r for r, t in zip(col["reason"], target) if t == 9]
        assert behind and all(r.startswith("joint limits") for r in behind), behind


# --------------------------------------------------------------------------- one training path


def test_cli_and_api_train_the_same_model(files):
    """``hykin fit`` == ``HybridModel(robot, ...).fit(train)``: same data, options and seed give
    bit-identical predictions (the CLI no longer splits off its own validation set)."""
    robot = hykin.load_robot(files["robot"])
    ds = read_dataset(files["data"], robot=robot)
    api = hykin.HybridModel(robot, seed=0, recipe_kw={"max_epochs": 3, "min_steps": 0}).fit(ds, progress=False)
    cli = hykin.HybridModel.load(files["model"])
    q = robot.random_joints(50, rng=11, margin=0.1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        assert np.array_equal(cli.predict(q), api.predict(q))
        assert np.array_equal(cli.predict_classical(q), api.predict_classical(q))
    assert cli.metadata["n_train"] == api.metadata["n_train"] and "held_out" in cli.metadata["metrics"]


# --------------------------------------------------------------------------- model file integrity


def test_model_hash_detects_edits_and_bit_flips(files, tmp_path):
    import hashlib

    from safetensors import safe_open

    from hykin.io.modelfile import content_hash

    with safe_open(str(files["model"]), framework="pt") as f:
        md = f.metadata()
        tensors = {k: f.get_tensor(k) for k in f.keys()}  # noqa: SIM118 - safe_open is not a dict
    # independent recomputation of the documented hash: sorted tensors, then the three metadata entries
    assert len(md["content_sha256"]) == 64 and content_hash(tensors, md) == md["content_sha256"]
    h = hashlib.sha256()
    for k in ("format", "format_version", "hykin"):
        v = md[k].encode()
        h.update(k.encode() + b"\0" + len(v).to_bytes(8, "little") + v)
    for name in sorted(tensors):
        t = tensors[name].contiguous()
        head = f"{name}\0{t.dtype}\0{tuple(t.shape)}\0".encode()
        h.update(len(head).to_bytes(8, "little") + head + t.numpy().tobytes())
    assert h.hexdigest() == md["content_sha256"]
    for make in (_edited_model, _flipped_model, _truncated_model):
        with pytest.raises(ModelFileError):
            hykin.HybridModel.load(make(files, tmp_path))


def test_model_without_hash_loads_with_a_note():
    golden = Path(__file__).parent / "data" / "golden" / "model_v0.1.0.safetensors"
    with pytest.warns(hykin.UnverifiedModelWarning, match="no integrity hash"):
        hykin.HybridModel.load(golden)


# --------------------------------------------------------------------------- plausibility (API)


def test_plausibility_accepts_tracker_frame_and_refuses_slips(files):
    """Frame-independent checks: data in a far, rotated tracker frame with another tool pass; the same
    data with a unit slip or scalar-last quaternions are refused."""
    from hykin.geometry import se3
    from hykin.io.plausibility import PlausibilityError, check_dataset

    robot = files["robot_obj"]
    q, T = files["q"], files["T"]
    B = se3.xyzrpy_to_transform([4.0, -2.0, 0.7], [0.2, -0.4, 2.5])
    U = se3.xyzrpy_to_transform([0.03, 0.0, 0.11], [0.0, 0.5, 1.0])
    Tt = B @ T @ U
    check_dataset(robot, Dataset.from_poses(q, Tt))  # passes
    with pytest.raises(PlausibilityError, match="length-unit"):
        check_dataset(robot, Dataset(q=q, xyz_m=Tt[:, :3, 3] * 1e-3, quat_wxyz=None), length_unit="mm")
    _, quat = se3.transform_to_pose(Tt)
    with pytest.raises(PlausibilityError, match="scalar-last"):
        check_dataset(robot, Dataset(q=q, xyz_m=Tt[:, :3, 3], quat_wxyz=quat[:, [1, 2, 3, 0]].copy()))


def test_minimum_fit_size_is_stated(files):
    from hykin.io.plausibility import PlausibilityError, minimum_fit_rows

    robot = files["robot_obj"]
    assert minimum_fit_rows(robot, True) == 30 and minimum_fit_rows(robot, False) == 30  # 2 * 42 / 3 = 28
    ds = read_dataset(files["data"], robot=robot).subset(np.arange(29))
    with pytest.raises(PlausibilityError, match="at least 30"):
        hykin.HybridModel(robot).fit(ds, progress=False)


def test_api_fit_refuses_scalar_last_quaternions(files):
    """The Python API path checks too (HybridModel.fit on in-memory data)."""
    from hykin.io.plausibility import PlausibilityError

    ds = read_dataset(files["data"], robot=files["robot_obj"])
    bad = Dataset(q=ds.q, xyz_m=ds.xyz_m, quat_wxyz=ds.quat_wxyz[:, [1, 2, 3, 0]].copy())
    with pytest.raises(PlausibilityError, match="scalar-last"):
        hykin.HybridModel(files["robot_obj"]).fit(bad, progress=False)
