"""The command line on a maker's URDF (issue #24): ``--tip``/``--base``, calibrate writing URDF,
``fit`` end to end on a construction robot with mimic joints (data simulated here from a perturbed
copy of ``tests/data/construction_robot.urdf``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cli_run import run
from hykin.calibration.params import apply_deviations, parameter_names
from hykin.geometry import se3
from hykin.io.urdf import load_urdf
from hykin.kinematics.fk import fk

URDF = Path(__file__).parent / "data" / "construction_robot.urdf"


def _truth(seed: int = 0, base=None):
    nom = load_urdf(URDF, tip_link="tcp")
    rng = np.random.default_rng(seed)
    dev = {n: rng.normal(0, 5e-4) for n in parameter_names(nom, base=False, tool=False, compliance=False)}
    truth = apply_deviations(nom, dev)
    truth = truth.copy(tool=truth.tool @ se3.xyzrpy_to_transform([0.002, -0.003, 0.004], [0, 0, 0]))
    if base is not None:
        truth = truth.copy(base=base)
    return nom, truth


def _bump_m(q):
    """A smooth error no joint-origin calibration can model (what the networks learn), ~1 mm."""
    return 1e-3 * np.stack([np.sin(q[:, 1]) * np.cos(q[:, 2]), np.sin(q[:, 3] + q[:, 0]), 0.5 * np.cos(q[:, 4]) * q[:, 0]], 1)


def _write(path, nom, truth, n, seed, bump=False, noise_m=2e-5):
    rng = np.random.default_rng(seed)
    q = nom.random_joints(n, rng=rng, margin=0.05)
    xyz = fk(truth, q)[:, :3, 3] + rng.normal(0, noise_m, (n, 3)) + (_bump_m(q) if bump else 0.0)
    names = list(nom.independent_joint_names)
    lines = [",".join(names + ["x", "y", "z"])]
    lines += [",".join(repr(float(v)) for v in row) for row in np.hstack([q, xyz])]
    path.write_text("\n".join(lines) + "\n")
    return q


@pytest.mark.slow  # ~10 s: the same path runs in-process in the default suite
def test_calibrate_urdf_with_tip_writes_urdf(tmp_path, capsys):
    nom, truth = _truth(0)
    _write(tmp_path / "d.csv", nom, truth, 400, 1)
    out = tmp_path / "cal.urdf"
    code, so, se = run(["calibrate", URDF, tmp_path / "d.csv", "--tip", "tcp", "--no-compliance", "-o", out], capsys)
    assert code == 0, se
    assert f"calibrated robot written to {out}" in so
    cal = load_urdf(out, tip_link="tcp")  # the maker's file: two tips kept, so the tip is named again
    assert cal.dof == 7 and cal.n_chain == 9 and out.read_text().count("<mimic") == 2
    q = nom.random_joints(300, rng=9)
    err = lambda r: np.linalg.norm(fk(r, q)[:, :3, 3] - fk(truth, q)[:, :3, 3], axis=1).mean()
    assert err(nom) > 2e-3 and err(cal) < 0.05e-3, (err(nom), err(cal))


@pytest.mark.parametrize(
    "argv, words",
    [
        (["calibrate", URDF, "D", "-o", "O.urdf"], ["several tips", "camera_link", "tcp", "--tip"]),
        (["calibrate", "ur10", "D", "--tip", "tool0", "-o", "O.toml"], ["ur10", "--tip", "URDF"]),
        (["calibrate", URDF, "D", "--tip", "tcp", "-o", "O.toml"], ["URDF robot is written as URDF", "o.urdf"]),
        (["calibrate", URDF, "D", "--tip", "nope", "-o", "O.urdf"], ["tip_link 'nope'"]),
        (["fk", URDF, "D", "--base", "arm_mount", "-o", "O.csv"], ["several tips"]),
    ],
)
def test_robot_link_mistakes_one_line(tmp_path, capsys, argv, words):
    nom, truth = _truth(0)
    _write(tmp_path / "d.csv", nom, truth, 20, 1)
    sub = {"D": str(tmp_path / "d.csv"), "O.urdf": str(tmp_path / "o.urdf"), "O.toml": str(tmp_path / "o.toml"),
           "O.csv": str(tmp_path / "o.csv")}
    code, so, se = run([sub.get(str(a), a) for a in argv], capsys)
    assert code == 2
    line = se.strip()
    assert "\n" not in line, line
    for w in words:
        assert w in line, (w, line)
    assert not any(Path(v).exists() for k, v in sub.items() if k != "D")


@pytest.mark.slow
def test_fit_urdf_tip_end_to_end(tmp_path, capsys):
    """``hykin fit ROBOT.urdf --tip tcp`` on positions-only data in a tracker frame, held-out error of
    nominal + fitted frames / calibrated / hybrid; then ``export-urdf``."""
    from hykin.calibration.calibrate import calibrate
    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset_files import read_dataset

    base = se3.xyzrpy_to_transform([3.2, 2.4, 1.5], [0.0, 0.0, 0.7])  # < 10 m: see the test below
    nom, truth = _truth(3, base)
    _write(tmp_path / "train.csv", nom, truth, 2000, 4, bump=True, noise_m=5e-5)
    _write(tmp_path / "test.csv", nom, truth, 500, 5, bump=True, noise_m=5e-5)
    m = tmp_path / "m.hykin"
    code, so, se = run(["fit", URDF, tmp_path / "train.csv", "--tip", "tcp", "-o", m, "--max-minutes", "1"], capsys)
    assert code == 0, se
    model = HybridModel.load(m)
    assert model.robot_.urdf["tip_link"] == "tcp" and model.robot_.dof == 7
    te = read_dataset(tmp_path / "test.csv", robot=model.robot_)
    tr = read_dataset(tmp_path / "train.csv", robot=nom)
    frames = calibrate(nom, tr, params=["base.*", "tool.x", "tool.y", "tool.z"], compliance=False).robot
    err = lambda T: np.linalg.norm(T[:, :3, 3] - te.xyz_m, axis=1).mean() * 1e3
    e_frames, e_cal, e_hyb = err(fk(frames, te.q)), err(model.predict_classical(te.q)), err(model.predict(te.q))
    print(f"held-out mean mm: nominal+frames {e_frames:.3f}, calibrated {e_cal:.3f}, hybrid {e_hyb:.3f}")
    assert e_hyb < 0.5 * e_cal and e_cal < 0.5 * e_frames
    code, so, se = run(["export-urdf", m, "-o", tmp_path / "c.urdf"], capsys)
    assert code == 0, se
    assert load_urdf(tmp_path / "c.urdf", tip_link="tcp").dof == 7


@pytest.mark.slow
@pytest.mark.xfail(reason="positions over 10 m are refused as 'mm passed as m' (issue #24; helper misc24 fixes it)",
                   strict=False)
def test_calibrate_urdf_far_from_instrument(tmp_path, capsys):
    """A total station 25 m away: must be accepted (blocked today by the 10 m unit check)."""
    base = se3.xyzrpy_to_transform([20.0, 15.0, 1.5], [0.0, 0.0, 0.7])
    nom, truth = _truth(3, base)
    _write(tmp_path / "d.csv", nom, truth, 600, 6)
    code, so, se = run(["calibrate", URDF, tmp_path / "d.csv", "--tip", "tcp", "--no-compliance", "-o",
                        tmp_path / "c.urdf"], capsys)
    assert code == 0, se


def test_register_a_multi_tip_urdf_with_tip(tmp_path, capsys):
    """``hykin register`` of a URDF robot with several tips (probe report s40: refused asking for --tip,
    which register did not have). The series is the truth seen from a moved tracker; the registered
    robot file must put the TCP there (reference: the truth's FK in that frame)."""
    nom, truth = _truth(3)
    W = se3.trans(2.0, -1.0, 0.3) @ se3.rotz(0.4)
    moved = truth.copy(base=W @ truth.base)
    q = _write(tmp_path / "s.csv", nom, moved, 60, 4, noise_m=0.0)
    code, _, se = run(["register", URDF, tmp_path / "s.csv", "-o", tmp_path / "r.urdf", "--poses", "30"], capsys)
    assert code != 0 and "several tips" in se and "--tip" in se
    out = tmp_path / "r.urdf"
    code, so, se = run(["register", URDF, tmp_path / "s.csv", "-o", out, "--tip", "tcp", "--poses", "30"], capsys)
    assert code == 0, se
    reg = load_urdf(out, tip_link="tcp")
    q2 = nom.random_joints(50, rng=11)
    err = np.linalg.norm(fk(reg, q2)[:, :3, 3] - fk(moved, q2)[:, :3, 3], axis=1).max()
    # the frames are registered; the arm keeps the file's geometry (0.5 mm deviations of the truth stay)
    assert err < 5e-3 and np.linalg.norm(fk(nom, q2)[:, :3, 3] - fk(moved, q2)[:, :3, 3], axis=1).min() > 0.5
