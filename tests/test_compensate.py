"""Compensated targets (hykin.compensation.targets, .branches), the compensate CLI on CSV, export-urdf.

References: the true robot's FK (an exact model predicts it), a stand-in controller = classical IK of
the nominal robot, closed-form quadrant / sign formulas written here, scipy-free transforms.
"""

from __future__ import annotations

import csv

import numpy as np
import pytest
from comp_models import ExactModel, deviate, exact, tiny_model_file, real_tcp

from hykin import fk, load_robot
from hykin.compensation import compensate, resolve_frame
from hykin.compensation.branches import (
    abb_confdata,
    kuka_status,
    match_abb_confdata,
    match_kuka_status,
)
from hykin.geometry import se3
from hykin.kinematics.ik import ik

# the model's own out-of-range warning is expected here: the queries are random joints
pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")


def _controller(nom, T_cmd, q_ref):
    """Stand-in controller: nominal IK of base-frame commands, solution nearest ``q_ref``."""
    r = ik(nom, nom.base @ T_cmd, all_branches=True).nearest_to(q_ref, nom.lower, nom.upper)
    return np.where(r.success[:, None], r.q, np.nan)


@pytest.mark.parametrize("preset", ["ur10", "kuka-kr6-r900"])
def test_compensated_commands_land_on_the_real_robot(preset):
    m = exact(preset, 1)
    nom = m.nominal
    q = nom.random_joints(40, 2, margin=0.15)
    T = fk(m.robot_, q)  # wanted poses the real robot can reach
    c = compensate(m, T, q_branch=q)
    assert c.success.all() and c.pos_err_mm.max() < 1e-6
    q_ctrl = _controller(nom, c.command, q)
    err = se3.pose_error(fk(m.robot_, q_ctrl), T)
    assert err[0].max() < 1e-6 and err[1].max() < 1e-6
    # without compensation the controller misses by the nominal error (several mm)
    q_unc = _controller(nom, T, q)
    ok = np.isfinite(q_unc).all(1)
    assert ok.sum() > 30 and se3.pose_error(fk(m.robot_, q_unc[ok]), T[ok])[0].mean() > 1.0
    # the command is the nominal FK of the joints, and the shift is its distance to the target
    assert np.allclose(c.command, fk(nom, c.q), atol=1e-12)
    assert np.allclose(c.shift_mm, np.linalg.norm(c.command[:, :3, 3] - T[:, :3, 3], axis=1) * 1e3)


def test_default_branch_is_the_nominal_walk_and_position_only():
    m = exact("ur10", 4)
    q = np.array([0.3, -1.6, 1.7, -1.7, -1.5, 0.4]) + np.random.default_rng(0).normal(0, 0.05, (10, 6))
    T = fk(m.robot_, q)
    c = compensate(m, T)
    assert c.success.all()
    q_ctrl = _controller(m.nominal, c.command, c.q)
    assert se3.pose_error(fk(m.robot_, q_ctrl), T)[0].max() < 1e-6
    cp = compensate(m, T[:, :3, 3], q_branch=q)
    assert cp.success.all()
    assert np.linalg.norm(fk(m.robot_, _controller(m.nominal, cp.command, cp.q))[:, :3, 3] - T[:, :3, 3], axis=1).max() < 1e-9


def test_base_frame_for_tracker_data_and_tool_delta():
    nom = load_robot("ur10")
    truth = deviate(nom, 5)
    W = se3.make_transform(se3.rotz(0.7)[:3, :3], np.array([2.0, -1.0, 0.3]))  # tracker frame: robot 2 m away
    m = ExactModel(nom, truth.copy(base=W @ truth.base))
    assert resolve_frame(m, "auto") == "base"
    q = nom.random_joints(20, 6, margin=0.15)
    T_ctrl = se3.invert(m.robot_.base) @ fk(m.robot_, q)  # wanted poses in the controller (fitted base) frame
    c = compensate(m, T_ctrl, q_branch=q, frame="auto")
    assert c.frame == "base" and c.success.all()
    real = se3.invert(m.robot_.base) @ fk(m.robot_, _controller(nom, c.command, q))
    assert se3.pose_error(real, T_ctrl)[0].max() < 1e-6
    # a TCP set in the program (URScript set_tcp): wanted poses are of that TCP
    D = se3.make_transform(se3.rotx(0.2)[:3, :3], np.array([0.0, 0.01, 0.05]))
    m2 = exact("ur10", 7)
    Tw = real_tcp(m2, fk(m2.robot_, q), D)
    c2 = compensate(m2, Tw, q_branch=q, tool_delta=D)
    q_ctrl = _controller(nom, c2.command @ se3.invert(D), q)  # controller strips its TCP before IK
    assert se3.pose_error(real_tcp(m2, fk(m2.robot_, q_ctrl), D), Tw)[0].max() < 1e-6


def test_unreachable_targets_get_no_command():
    m = exact("ur10", 1)
    q = m.nominal.random_joints(3, 1, margin=0.2)
    T = fk(m.robot_, q)
    T[1, :3, 3] = [5.0, 0.0, 0.0]  # 5 m away
    c = compensate(m, T, q_branch=q)
    assert list(c.success) == [True, False, True]
    assert np.isnan(c.command[1]).all() and np.isnan(c.q[1]).all() and c.reason[1]
    qb = q.copy()
    qb[2] = np.nan  # no branch (a program's configuration data matched nothing)
    c = compensate(m, T, q_branch=qb, branch_reason="no match")
    assert not c.success[2] and c.reason[2] == "no match"
    qb, T2 = q.copy(), T.copy()
    qb[1], T2[1] = np.nan, T[0]  # every row with a branch succeeds, one row has none
    c = compensate(m, T2, q_branch=qb, branch_reason="no match")
    assert list(c.success) == [True, False, True] and list(c.reason) == ["", "no match", ""]
    assert np.isnan(c.command[1]).all() and np.isnan(c.q[1]).all() and np.isfinite(c.command[[0, 2]]).all()
    assert np.allclose(c.command[2], compensate(m, T2[2:], q_branch=q[2:]).command[0], atol=1e-12)
    with pytest.raises(ValueError, match="NaN"):
        compensate(m, np.full((1, 4, 4), np.nan))


def test_kuka_status_and_abb_confdata_definitions():
    kr = load_robot("kuka-kr6-r900")  # q = (-A1, A2, A3, -A4, A5, -A6)
    home = np.radians([[0.0, -90, 90, 0, 0, 0]])  # KUKA HOME {A1 0, A2 -90, A3 90, A4 0, A5 0, A6 0}
    S, T = kuka_status(kr, home)
    assert S[0] == 6 and T[0] == 2  # in front, A3 >= phi, A5 <= 0; only A2 < 0
    q = kr.random_joints(200, 3, margin=0.05)
    S, T = kuka_status(kr, q)
    A = q * np.array([-1, 1, 1, -1, 1, -1])
    assert np.array_equal((S >> 2) & 1, (A[:, 4] <= 0).astype(int))
    assert np.array_equal(T, sum(((A[:, j] < 0).astype(int) << j) for j in range(6)))
    # overhead: wrist centre behind axis 1 (reach over the top) flips bit 0 only
    over = np.radians([[0.0, -90, -60, 0, 30, 0]])
    assert kuka_status(kr, over)[0][0] & 1 == 1
    # every (S, T) picks back its own joints among all nominal solutions
    qm = match_kuka_status(kr, fk(kr, q), S, T)
    assert np.nanmax(np.abs(qm - q)) < 1e-8 and not np.isnan(qm).any()
    abb = load_robot("abb-irb2400")
    qa = abb.random_joints(200, 4, margin=0.05)
    cf = abb_confdata(abb, qa)
    assert np.array_equal(cf[:, :3], np.floor(np.degrees(qa[:, [0, 3, 5]]) / 90).astype(int))
    assert np.array_equal(cf[:, 3] & 1, (qa[:, 4] < 0).astype(int))
    assert abb_confdata(abb, np.zeros((1, 6)))[0, 3] == 0  # zero pose: in front, forward, axis 5 = 0
    qm = match_abb_confdata(abb, fk(abb, qa), cf)
    assert np.nanmax(np.abs(qm - qa)) < 1e-8


# ---------------------------------------------------------------------------------------------- CLI


def _write_csv(path, cols: dict):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(list(cols))
        w.writerows(np.column_stack(list(cols.values())).tolist())


def _read_csv(path) -> list:
    with open(path) as f:
        return list(csv.DictReader(f))


def test_cli_compensate_csv_programs_and_urdf(tmp_path):
    from typer.testing import CliRunner

    from hykin.cli import app
    from hykin.hybrid.model import HybridModel
    from hykin.io.urdf import load_urdf

    mp = tiny_model_file()
    m = HybridModel.load(mp)
    nom = m.nominal
    q = nom.random_joints(6, 9, margin=0.2)
    T = m.predict(q)
    xyz, quat = se3.transform_to_pose(T)
    xyz[5] = [4.0, 0, 0]  # unreachable
    cols = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "qw": quat[:, 0], "qx": quat[:, 1], "qy": quat[:, 2], "qz": quat[:, 3]}
    cols.update({f"q{j + 1}": q[:, j] for j in range(6)})
    _write_csv(tmp_path / "t.csv", cols)
    run = CliRunner().invoke
    r = run(app, ["compensate", str(mp), str(tmp_path / "t.csv"), "-o", str(tmp_path / "c.csv")])
    assert r.exit_code == 0, r.output
    rows = _read_csv(tmp_path / "c.csv")
    assert [row["status"] == "ok" for row in rows] == [True] * 5 + [False]
    assert rows[5]["x"] == "nan" and rows[5]["q1"] == "nan"
    assert "out of reach" in rows[5]["status"] and "1 of them beyond the arm's reach" in r.output
    assert "hint:" not in r.output  # one target of six: no frame hint
    far = {k: v[5:] for k, v in cols.items()}
    _write_csv(tmp_path / "far.csv", far)
    r = run(app, ["compensate", str(mp), str(tmp_path / "far.csv"), "-o", str(tmp_path / "far_c.csv")])
    assert r.exit_code == 0 and "hint:" in r.output and "--frame base" in r.output, r.output
    cmd = np.array([[float(row[k]) for k in ("x", "y", "z")] for row in rows[:5]])
    qo = np.array([[float(row[f"q{j + 1}"]) for j in range(6)] for row in rows[:5]])
    assert np.allclose(cmd, fk(nom, qo)[:, :3, 3], atol=1e-12)
    assert se3.pose_error(m.predict(qo), T[:5])[0].max() < 1e-6  # the model reaches the targets at those joints
    # output safety: existing output, output = input
    r = run(app, ["compensate", str(mp), str(tmp_path / "t.csv"), "-o", str(tmp_path / "c.csv")])
    assert r.exit_code != 0 and "--force" in str(r.exception or r.output)
    r = run(app, ["compensate", str(mp), str(tmp_path / "t.csv"), "-o", str(tmp_path / "t.csv"), "--force"])
    assert r.exit_code != 0
    r = run(app, ["compensate", str(mp), str(tmp_path / "t.csv"), "-o", str(tmp_path / "j.csv"), "--joints"])
    assert r.exit_code == 0 and list(_read_csv(tmp_path / "j.csv")[0])[:7] == ["target"] + [f"q{j + 1}" for j in range(6)]
    # a program with an unreachable target: refused (nothing written), or kept with --skip-unreachable
    rv = se3.matrix_to_rotvec(T[:, :3, :3])
    lines = [f"movel(p[{xyz[k, 0]:.6f}, {xyz[k, 1]:.6f}, {xyz[k, 2]:.6f}, {rv[k, 0]:.6f}, {rv[k, 1]:.6f}, {rv[k, 2]:.6f}], a=1.2, v=0.25)"
             for k in range(6)]
    (tmp_path / "p.script").write_text("def p():\n" + "\n".join(lines) + "\nend\n")
    r = run(app, ["compensate", str(mp), str(tmp_path / "p.script"), "-o", str(tmp_path / "o.script")])
    assert r.exit_code != 0 and not (tmp_path / "o.script").exists()
    r = run(app, ["compensate", str(mp), str(tmp_path / "p.script"), "-o", str(tmp_path / "o.script"), "--skip-unreachable"])
    assert r.exit_code == 0, r.output
    out = (tmp_path / "o.script").read_text().splitlines()
    assert out[6] == lines[5] and all(out[k + 1] != lines[k] for k in range(5))
    # calibrated URDF: same FK as the calibrated classical model (compliance/networks cannot be carried)
    r = run(app, ["export-urdf", str(mp), "-o", str(tmp_path / "r.urdf")])
    assert r.exit_code == 0, r.output
    u = load_urdf(tmp_path / "r.urdf")
    ref = m.frame_pre_ @ fk(m.robot_.copy(stiffness_nm_per_rad=np.full(6, np.inf)), q) @ m.frame_post_
    assert np.abs(fk(u, q) - ref).max() < 1e-12
    assert np.abs(fk(u, q) - fk(nom, q)).max() > 1e-4  # the calibration is in it


def test_cli_payload_kg_compensates_for_the_load_the_robot_carries(tmp_path, capsys):
    """A model fitted at 0 and 12 kg (stiffness identified) compensates targets for the 12 kg the robot
    carries: executed by the nominal controller on the true loaded robot they land far closer than the
    same targets compensated for the robot file's payload (reference: the simulator's truth)."""
    import warnings

    from cli_run import run as run_cli

    from hykin.hybrid.model import HybridModel, OutOfRangeWarning
    from hykin.sim.presets import virtual_preset
    from hykin.sim.simulate import simulate, true_poses

    vr = virtual_preset("kr-payload-virtual", seed=2)
    nom = vr.nominal
    rng = np.random.default_rng(5)
    q = nom.random_joints(600, rng, margin=0.2)
    train = simulate(vr, q, noise=False, payload_kg=np.where(np.arange(600) % 2 == 0, 0.0, 12.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        m = HybridModel(nom, seed=0, recipe_kw={"max_epochs": 2, "min_steps": 0}).fit(train, progress=False)
    mp = tmp_path / "m.hykin"
    m.save(mp)
    q_t = nom.random_joints(40, np.random.default_rng(6), margin=0.3)
    T_t = true_poses(vr, q_t, payload_kg=np.full(40, 12.0))  # where the loaded robot should go
    xyz, quat = se3.transform_to_pose(T_t)
    tp = tmp_path / "targets.csv"
    with open(tp, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z", "qw", "qx", "qy", "qz"] + [f"q{j + 1}" for j in range(6)])
        for i in range(40):
            w.writerow([repr(float(v)) for v in (*xyz[i], *quat[i], *q_t[i])])
    errs = {}
    for name, extra in (("loaded", ["--payload-kg", "12"]), ("file", [])):
        out = tmp_path / f"{name}.csv"
        code, _, err = run_cli(["compensate", mp, tp, "-o", out, *extra], capsys)
        assert code == 0, err
        with open(out, newline="") as f:
            rows = list(csv.DictReader(f))
        ok = np.array([r["status"] == "ok" for r in rows])
        assert ok.all(), [r["status"] for r in rows if r["status"] != "ok"][:3]
        Tc = se3.pose_to_transform(np.array([[float(r[k]) for k in ("x", "y", "z")] for r in rows]),
                                   np.array([[float(r[k]) for k in ("qw", "qx", "qy", "qz")] for r in rows]))
        q_exec = _controller(nom, Tc, q_t)
        p_err = np.linalg.norm(true_poses(vr, q_exec, payload_kg=np.full(40, 12.0))[:, :3, 3] - T_t[:, :3, 3], axis=1)
        errs[name] = p_err.mean() * 1e3
    assert errs["loaded"] < 0.3 and errs["loaded"] < errs["file"] / 3, errs
    # a payload_kg column: each target compensated for the load it carries (12 kg, 0 kg alternately)
    kg = np.where(np.arange(40) % 2 == 0, 12.0, 0.0)
    T_m = true_poses(vr, q_t, payload_kg=kg)
    xyz, quat = se3.transform_to_pose(T_m)
    tm = tmp_path / "targets_kg.csv"
    with open(tm, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["x", "y", "z", "qw", "qx", "qy", "qz"] + [f"q{j + 1}" for j in range(6)] + ["payload_kg"])
        for i in range(40):
            w.writerow([repr(float(v)) for v in (*xyz[i], *quat[i], *q_t[i], kg[i])])
    code, _, err = run_cli(["compensate", mp, tm, "-o", tmp_path / "mixed.csv"], capsys)
    assert code == 0, err
    with open(tmp_path / "mixed.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    Tc = se3.pose_to_transform(np.array([[float(r[k]) for k in ("x", "y", "z")] for r in rows]),
                               np.array([[float(r[k]) for k in ("qw", "qx", "qy", "qz")] for r in rows]))
    p_err = np.linalg.norm(true_poses(vr, _controller(nom, Tc, q_t), payload_kg=kg)[:, :3, 3] - T_m[:, :3, 3], axis=1)
    assert p_err.mean() * 1e3 < 0.3 and p_err[kg == 12].mean() * 1e3 < errs["file"] / 3
    code, _, err = run_cli(["compensate", mp, tm, "-o", tmp_path / "both.csv", "--payload-kg", "12"], capsys)
    assert code == 2 and "both give the payload" in err


def test_serve_and_bridges_take_the_payload_the_robot_carries(capsys):
    """`serve`, `rsi` and `egm` take --payload-kg as `compensate` does (one helper): a bad mass is refused
    in one line before anything listens, and the model they run is the one carrying that mass (its
    prediction equals the model's under payload_kg)."""
    import warnings

    from cli_run import run as run_cli

    from hykin.cli.common import with_payload
    from hykin.hybrid.model import HybridModel

    mp = tiny_model_file()
    for cmd, bad in ((["serve", mp, "--port", "1"], "-1"), (["rsi", mp, "--listen", "127.0.0.1:1"], "nan"),
                     (["egm", mp, "--listen", "127.0.0.1:1"], "inf")):
        code, _, err = run_cli([*cmd, "--payload-kg", bad], capsys)
        assert code != 0 and "--payload-kg must be a finite mass >= 0 kg" in err, (cmd, err)
    m = HybridModel.load(mp)
    q = m.nominal.random_joints(5, 1, margin=0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        loaded = with_payload(m, 7.5)
        assert np.abs(loaded.predict(q) - m.predict(q, payload_kg=np.full(5, 7.5))).max() < 1e-12
    assert with_payload(m, None) is m


def test_shift_of_a_tracker_frame_model_is_seen_from_the_real_base():
    """A model fitted in a tracker's frame (its base metres away): the shift is the command's distance to
    the target seen from the robot's real base (the nominal model's error, mm), not the tracker's offset."""
    nom = load_robot("ur10")
    truth = deviate(nom, 5)
    B = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, 2.1])), np.array([3.0, -1.5, 0.4]))
    truth = truth.copy(base=B @ truth.base)  # calibrated in the tracker's frame
    m = ExactModel(nom, truth)
    q = nom.random_joints(20, 3, margin=0.15)
    T = m.predict(q)  # targets in the tracker's frame
    c = compensate(m, T, q_branch=q, frame="measurement")
    assert c.success.all()
    T_base = np.linalg.inv(truth.base) @ T  # the targets seen from the real base (reference)
    ref = np.linalg.norm(c.command[:, :3, 3] - T_base[:, :3, 3], axis=1) * 1e3
    assert np.allclose(c.shift_mm, ref, atol=1e-9) and c.shift_mm.max() < 50


def test_a_model_without_thermal_expansion_says_it_does_not_use_the_temperatures(tmp_path, capsys):
    from cli_run import run as run_cli

    mp = tiny_model_file()
    jp = tmp_path / "j.csv"
    jp.write_text("q1,q2,q3,q4,q5,q6,temperature_c\n0.1,-1.2,1.3,-1.4,-1.5,0.2,38\n")
    code, _, err = run_cli(["fk", mp, jp, "-o", tmp_path / "fk.csv"], capsys)
    assert code == 0 and "has a temperature column, but the model has no thermal expansion" in err
    jp.write_text("q1,q2,q3,q4,q5,q6,temperature_c\n0.1,-1.2,1.3,-1.4,-1.5,0.2,311.15\n")
    code, _, err = run_cli(["fk", mp, jp, "-o", tmp_path / "fk2.csv"], capsys)
    assert code == 2 and "look like kelvin" in err and not (tmp_path / "fk2.csv").exists()


def test_a_calibrated_tcp_far_from_the_robot_files_tool_is_named(capsys):
    """The commands are poses of the robot file's TCP: when the calibrated one is far from it (a file
    without the tool the data were measured with), the controller would be sent the wrong TCP's poses."""
    from hykin.cli.compensate import _warn_tool_mismatch

    nom = load_robot("ur10")
    far = nom.copy(tool=nom.tool @ se3.make_transform(se3.rotvec_to_matrix(np.radians([0.0, 0.0, 30.0])),
                                                      np.array([0.0, 0.05, 0.11])))
    _warn_tool_mismatch(ExactModel(nom, far))
    err = capsys.readouterr().err
    assert "the calibrated TCP is 120.8 mm / 30.00 deg from the robot file's tool" in err and "[tool]" in err
    _warn_tool_mismatch(ExactModel(nom, deviate(nom, 2)))  # a calibration's few mm: no warning
    assert "calibrated TCP" not in capsys.readouterr().err


def test_program_tool_is_fixed_to_the_real_flange_when_the_file_tool_is_a_guess():
    """Probe report s40: the robot file's [tool] guessed 30 mm short of the real one (the measured TCP);
    a second TCP given from the flange (``--tool``, ``set_tcp``) landed 30 mm off. Reference: the truth's
    flange (its chain with no tool) times that TCP."""
    nom0 = load_robot("ur10")
    tool_true = se3.trans(0.01, -0.005, 0.15)
    truth = deviate(nom0, 8).copy(tool=tool_true)
    nom = nom0.copy(tool=se3.trans(0.0, 0.0, 0.12))  # the file's guess: 30 mm short
    m = ExactModel(nom, truth)
    tcp2 = se3.trans(0.05, -0.02, 0.2) @ se3.rotx(0.1) @ se3.roty(0.2)
    q = nom.random_joints(12, 4, margin=0.2)
    want = fk(truth.copy(tool=np.eye(4)), q) @ tcp2  # the second TCP on the real flange
    c = compensate(m, want, q_branch=q, tool_delta=se3.invert(nom.tool) @ tcp2)
    assert c.success.all(), c.reason
    got = fk(truth.copy(tool=np.eye(4)), c.q) @ tcp2
    assert np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1).max() < 1e-6  # was 30 mm


def test_cli_joint_hints_in_radians_under_angle_unit_deg_are_refused(tmp_path):
    """Probe report s40: ``--angle-unit deg`` (also the unit of ``--tool``'s angles) read radian joint hints as
    degrees without a word; every target was then hinted near zero."""
    from typer.testing import CliRunner

    from hykin.cli import app
    from hykin.hybrid.model import HybridModel

    mp = tiny_model_file()
    m = HybridModel.load(mp)
    q = m.nominal.random_joints(8, 3, margin=0.2)
    xyz, quat = se3.transform_to_pose(m.predict(q))
    cols = {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "qw": quat[:, 0], "qx": quat[:, 1], "qy": quat[:, 2], "qz": quat[:, 3]}
    cols.update({f"q{j + 1}": q[:, j] for j in range(6)})
    _write_csv(tmp_path / "t.csv", cols)
    r = CliRunner().invoke(app, ["compensate", str(mp), str(tmp_path / "t.csv"), "-o", str(tmp_path / "c.csv"),
                                 "--angle-unit", "deg"])
    assert r.exit_code != 0 and "look like radians declared --angle-unit deg" in str(r.exception or r.output)
    assert not (tmp_path / "c.csv").exists()
