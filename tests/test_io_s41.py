"""Joint columns named with their unit (probe s41 AK): ``hykin plan`` writes ``q<i>_deg`` for a robot file in
degrees, and ``hykin fk`` refused its own plan ("missing column(s) q1..q6"), with or without
``--angle-unit deg``."""

from __future__ import annotations

import numpy as np
import pytest
from cli_run import run
from shared_fixtures import dh_robot_toml, write_text

from hykin import fk, load_robot
from hykin.io.dataset import DatasetError
from hykin.io.dataset_files import read_dataset, read_joints


def _write(path, header, rows):
    path.write_text(",".join(header) + "\n" + "".join(",".join(f"{v:.12g}" for v in r) + "\n" for r in rows))
    return path


def test_deg_named_joint_columns_are_read_in_degrees_whatever_angle_unit_says(tmp_path):
    rob = load_robot("ur10")
    q = rob.random_joints(12, 3)
    deg = _write(tmp_path / "plan.csv", [f"q{i + 1}_deg" for i in range(6)] + ["step"],
                 np.hstack([np.degrees(q), np.arange(12)[:, None]]))
    for unit in ("rad", "deg"):
        got, extra = read_joints(deg, robot=rob, angle_unit=unit)
        np.testing.assert_allclose(got, q, atol=1e-12)  # the file's degrees, by hand
        assert set(extra) == {"step"}
    # a dataset (joints and poses) too
    T = fk(rob, q)
    ds_file = _write(tmp_path / "ds.csv", [f"q{i + 1}_deg" for i in range(6)] + ["x", "y", "z"],
                     np.hstack([np.degrees(q), T[:, :3, 3]]))
    ds = read_dataset(ds_file, robot=rob)
    np.testing.assert_allclose(ds.q, q, atol=1e-12)


def test_deg_named_columns_beside_plain_angles_or_twice_are_refused(tmp_path):
    rob = load_robot("ur10")
    q = np.degrees(rob.random_joints(4, 1))
    mixed = _write(tmp_path / "mixed.csv", ["q1"] + [f"q{i + 1}_deg" for i in range(1, 6)], q)
    with pytest.raises(DatasetError, match="'q1' has no unit in its name"):
        read_joints(mixed, robot=rob)
    twice = _write(tmp_path / "twice.csv", [f"q{i + 1}" for i in range(6)] + ["q1_deg"], np.hstack([q, q[:, :1]]))
    with pytest.raises(DatasetError, match="both 'q1' and 'q1_deg'"):
        read_joints(twice, robot=rob)


def test_fk_reads_plans_own_output(tmp_path, capsys):
    """plan -> fk on a robot file in degrees (plan writes q<i>_deg): fk's poses at the plan's joints,
    the degrees converted here by hand."""
    rows = [(0.15, -90, 0.55, 0, -170, 170), (0.6, 0, 0, -90, -120, 100), (0.12, -90, 0, 0, -150, 160),
            (0, 90, 0.62, 0, -400, 400), (0, -90, 0, 0, -125, 125), (0, 0, 0.1, 0, -400, 400)]
    robot = write_text(tmp_path / "arm.toml", dh_robot_toml("arm-s41", rows))
    code, out, err = run([ "plan", robot, "-n", "12", "-o", tmp_path / "plan.csv", "--seed", "1"], capsys)
    assert code == 0, out + err
    header = (tmp_path / "plan.csv").read_text().splitlines()[0].split(",")
    assert header[:6] == [f"q{i + 1}_deg" for i in range(6)], header
    raw = np.genfromtxt(tmp_path / "plan.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    qp = np.radians(np.stack([raw[c].astype(float) for c in header[:6]], 1))
    code, out, err = run(["fk", robot, tmp_path / "plan.csv", "-o", tmp_path / "fk.csv"], capsys)
    assert code == 0, out + err
    got = np.genfromtxt(tmp_path / "fk.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    xyz = np.stack([got["x"], got["y"], got["z"]], 1).astype(float)
    np.testing.assert_allclose(xyz, fk(load_robot(robot), qp)[:, :3, 3], atol=1e-9)
