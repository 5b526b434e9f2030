"""``hykin import table --robot``: orientations are checked against the robot's rotations before the file
is written (probe report s40: a KUKA A,B,C export read with euler_convention "xyz" was written 120° off
with exit 0). The refusal names the Euler sequence the columns fit; several stations, each in its own
frame, are checked one by one (no wrong refusal). Data: the preset's FK turned into the file's frames
with scipy's Rotation (KUKA A,B,C = intrinsic Z,Y',X'')."""

from __future__ import annotations

import numpy as np
from cli_run import run
from scipy.spatial.transform import Rotation

from hykin.geometry import se3
from hykin.io.dataset_files import read_dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk


def _export(tmp_path, stations=False, n=60):
    rob = load_robot("kuka-kr6-r900")
    q = rob.random_joints(n, 5, margin=0.05)
    T = fk(rob, q)
    st = np.where(np.arange(n) < n // 2, "A", "B")
    if stations:  # station B: the tracker moved 3 m and turned 70°
        W = se3.trans(3.0, -1.0, 0.4) @ se3.rotz(np.radians(70.0))
        T = np.where((st == "B")[:, None, None], W @ T, T)
    abc = Rotation.from_matrix(T[:, :3, :3]).as_euler("ZYX", degrees=True)
    head = ["A1", "A2", "A3", "A4", "A5", "A6", "X", "Y", "Z", "A", "B", "C"] + (["station"] if stations else [])
    rows = [";".join(head)]
    for i in range(n):
        vals = [*np.degrees(q[i]), *(T[i, :3, 3] * 1e3), *abc[i]]
        rows.append(";".join(f"{v:.12g}" for v in vals) + (f";{st[i]}" if stations else ""))
    path = tmp_path / "export.txt"
    path.write_text("\n".join(rows) + "\n")
    return path, T


def _argv(path, out, conv, *extra):
    return ["import", "table", path, "-o", out, "--joints", "A1..A6", "--angle-unit", "deg", "--position", "X,Y,Z",
            "--length-unit", "mm", "--euler", "A,B,C", "--euler-convention", conv, "--euler-unit", "deg",
            "--delimiter", ";", "--robot", "kuka-kr6-r900", *extra]


def test_wrong_euler_convention_is_refused_naming_the_one_that_fits(tmp_path, capsys):
    path, _ = _export(tmp_path)
    out = tmp_path / "out.csv"
    code, _, err = run(_argv(path, out, "xyz", "--euler-intrinsic"), capsys)
    assert code != 0 and not out.exists()
    assert len(err.strip().splitlines()) == 1
    assert 'the same columns fit as euler_convention = "zyx", euler_extrinsic = false' in err, err
    code, _, err = run(_argv(path, out, "rpy"), capsys)  # extrinsic x,y,z with the columns in A,B,C order
    assert code != 0 and not out.exists() and 'euler_convention = "zyx"' in err
    code, _, err = run(_argv(path, out, "kuka"), capsys)
    assert code == 0, err
    ds = read_dataset(out)
    _, T = _export(tmp_path)
    ang = np.linalg.norm(Rotation.from_matrix(ds.rotations() @ np.swapaxes(T[:, :3, :3], 1, 2)).as_rotvec(), axis=1)
    assert ang.max() < 1e-9


def test_several_stations_each_in_its_own_frame_are_not_refused(tmp_path, capsys):
    path, _ = _export(tmp_path, stations=True)
    out = tmp_path / "out.csv"
    code, _, err = run(_argv(path, out, "kuka", "--keep", "station"), capsys)
    assert code == 0, err
    code, _, err = run(_argv(path, tmp_path / "o2.csv", "xyz", "--keep", "station", "--euler-intrinsic"), capsys)
    assert code != 0 and 'euler_convention = "zyx"' in err
