"""``hykin import table / three-smr / stream``: generic column mappings round-trip to the truth.

Each layout test makes ground-truth poses with :func:`hykin.fk` on a preset, writes the file in a
tracker/robot layout with formatting code of its own (angles from rotation matrices by closed-form
formulas written here, not scipy), imports it through the CLI and compares in SI units.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from cli_run import run

from hykin.geometry import se3
from hykin.io.dataset_files import read_dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk
from hykin.measure.table_import import import_table
from hykin.measure.table_map import (
    TableMap,
    TableMapError,
    load_table_map,
    table_map_from_dict,
)


def _rot_err(R1, R2):
    return np.abs(R1 - R2).max()


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, -s], -1), np.stack([z, s, c], -1)], -2)


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    o, z = np.ones_like(a), np.zeros_like(a)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


def _fmt_comma(v):
    return f"{v:.17g}".replace(".", ",")


def _check_against(ds, q, T, tol=1e-9):
    np.testing.assert_allclose(ds.q, q, rtol=0, atol=tol)
    np.testing.assert_allclose(ds.xyz_m, T[:, :3, 3], rtol=0, atol=tol)
    if ds.has_orientation:
        assert _rot_err(ds.rotations(), T[:, :3, :3]) < tol


# --------------------------------------------------------------------------- layout 1


def _layout1(tmp_path, n=30):
    """';' + decimal comma, degrees, mm, Euler intrinsic X-Y'-Z'' in degrees, temperature, 2 metadata lines."""
    rob = load_robot("abb-irb2400").copy(tool=se3.trans(0.012, -0.02, 0.16))
    q = rob.random_joints(n, 11, margin=0.05)
    T = fk(rob, q)
    R = T[:, :3, :3]
    # R = Rx(a) Ry(b) Rz(c): closed form
    b = np.arcsin(np.clip(R[:, 0, 2], -1, 1))
    a = np.arctan2(-R[:, 1, 2], R[:, 2, 2])
    c = np.arctan2(-R[:, 0, 1], R[:, 0, 0])
    temp = 20.0 + np.arange(n) * 0.125
    head = ["Temp [C]"] + [f"Achse {j + 1}" for j in range(6)] + ["Pos X", "Pos Y", "Pos Z", "Rot X", "Rot Y", "Rot Z"]
    lines = ["Exported by TrackerSoft 4.2; operator=abc", "Date;2026-11-23", ";".join(head)]
    for i in range(n):
        vals = [temp[i], *np.degrees(q[i]), *(T[i, :3, 3] * 1000.0), *np.degrees([a[i], b[i], c[i]])]
        lines.append(";".join(_fmt_comma(v) for v in vals))
    path = tmp_path / "layout1.txt"
    path.write_text("\r\n".join(lines) + "\r\n", encoding="cp1252")
    mp = tmp_path / "layout1.toml"
    mp.write_text(
        'skip_rows = 2\ndelimiter = ";"\ndecimal = ","\n'
        'joints = "Achse *"\nangle_unit = "deg"\n'
        'position = ["Pos X", "Pos Y", "Pos Z"]\nlength_unit = "mm"\n'
        'euler = ["Rot X", "Rot Y", "Rot Z"]\neuler_convention = "xyz"\neuler_extrinsic = false\neuler_unit = "deg"\n'
        'temperature = "Temp [C]"\n')
    return rob, q, T, temp, path, mp


def test_layout1_semicolon_decimal_comma_euler_intrinsic(tmp_path, capsys):
    rob, q, T, temp, path, mp = _layout1(tmp_path)
    out = tmp_path / "out.csv"
    code, so, err = run(["import", "table", path, "-o", out, "--map", mp, "--robot", "abb-irb2400"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    _check_against(ds, q, T)
    np.testing.assert_array_equal(ds.extra["temperature_c"], temp)
    # the suggestion finds the layout (metadata lines, ';', decimal comma, degrees, mm)
    code, so, err = run(["import", "table", path, "--suggest"], capsys)
    assert code == 0, err
    from hykin.io.toml_compat import tomllib

    sug = tomllib.loads(so)
    assert sug["skip_rows"] == 2 and sug["delimiter"] == ";" and sug["decimal"] == ","
    assert sug["position"] == ["Pos X", "Pos Y", "Pos Z"] and sug["length_unit"] == "mm" and sug["angle_unit"] == "deg"
    assert sug["temperature"] == "Temp [C]" and not out.with_name("nothing").exists()


# --------------------------------------------------------------------------- layout 2


def test_layout2_seven_joints_quaternion_xyzw_tab(tmp_path, capsys):
    rob = load_robot("franka-panda")
    n = 25
    q = rob.random_joints(n, 5, margin=0.02)
    T = fk(rob, q)
    quat = se3.matrix_to_quat(T[:, :3, :3])  # wxyz
    quat *= np.where(np.arange(n) % 2 == 0, 1.0, -1.0)[:, None]  # q and -q: same rotation
    head = ["time"] + [f"joint_{j}" for j in range(1, 8)] + ["pos_x", "pos_y", "pos_z", "qx", "qy", "qz", "qw", "status"]
    rows = ["\t".join(head)]
    for i in range(n):
        vals = [0.01 * i, *q[i], *T[i, :3, 3], quat[i, 1], quat[i, 2], quat[i, 3], quat[i, 0]]
        rows.append("\t".join(repr(float(v)) for v in vals) + "\tOK")
    path = tmp_path / "panda.tsv"
    path.write_text("\n".join(rows) + "\n")
    out = tmp_path / "panda.csv"
    code, _, err = run(["import", "table", path, "-o", out, "--joints", "joint_*", "--position", "pos_x,pos_y,pos_z",
                        "--quaternion", "qx,qy,qz,qw", "--quaternion-order", "xyzw", "--time", "time", "--keep", "status",
                        "--robot", "franka-panda"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    assert ds.dof == 7
    _check_against(ds, q, T)
    np.testing.assert_allclose(ds.extra["time_s"], 0.01 * np.arange(n), atol=1e-15)
    assert list(ds.extra["status"]) == ["OK"] * n
    # the suggested mapping, passed back, gives the same dataset
    code, so, err = run(["import", "table", path, "--suggest"], capsys)
    assert code == 0, err
    mp = tmp_path / "sug.toml"
    mp.write_text(so)
    m = load_table_map(mp)
    assert m.joints == [f"joint_{j}" for j in range(1, 8)] and m.quaternion == ["qw", "qx", "qy", "qz"]
    _check_against(import_table(path, m), q, T)


# --------------------------------------------------------------------------- layout 3


def _kuka_abc(R):
    """KUKA A, B, C (deg): R = Rz(A) Ry(B) Rx(C)."""
    B = -np.arcsin(np.clip(R[:, 2, 0], -1, 1))
    A = np.arctan2(R[:, 1, 0], R[:, 0, 0])
    C = np.arctan2(R[:, 2, 1], R[:, 2, 2])
    return np.degrees(np.stack([A, B, C], 1))


def _layout3(tmp_path, n=20):
    rob = load_robot("kuka-kr6-r900")
    q = rob.random_joints(n, 3, margin=0.05)
    T = fk(rob, q)
    nest = np.array([[0.05, 0.0, 0.02], [-0.03, 0.045, 0.0], [-0.01, -0.08, 0.01]])  # m, scalene: sides 94, 100, 127 mm
    P = np.einsum("nij,kj->nki", T[:, :3, :3], nest) + T[:, None, :3, 3]  # (N, 3, 3) m
    head = [f"A{j}" for j in range(1, 7)] + ["X", "Y", "Z", "X2", "Y2", "Z2", "X3", "Y3", "Z3", "A", "B", "C"]
    rows = ["   ".join(head)]
    for i in range(n):
        vals = [*np.degrees(q[i]), *(P[i].reshape(-1) * 1000.0), *_kuka_abc(T[i:i + 1, :3, :3])[0]]
        rows.append("  ".join(f"{v:.17g}" for v in vals))
    path = tmp_path / "kuka.dat"
    path.write_text("\n".join(rows) + "\n")
    return rob, q, T, nest, P, path


def test_layout3_kuka_three_reflectors_whitespace(tmp_path, capsys):
    rob, q, T, nest, P, path = _layout3(tmp_path)
    out = tmp_path / "kuka.csv"
    code, _, err = run(["import", "table", path, "-o", out, "--joints", "A1..A6", "--angle-unit", "deg", "--position", "X,Y,Z",
                        "--point", "X2,Y2,Z2", "--point", "X3,Y3,Z3", "--length-unit", "mm", "--euler", "A,B,C",
                        "--euler-convention", "kuka", "--euler-unit", "deg"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    np.testing.assert_allclose(ds.q, q, atol=1e-9)
    np.testing.assert_allclose(ds.xyz_m, P[:, 0], atol=1e-9)
    for k in (2, 3):
        np.testing.assert_allclose(np.stack([ds.extra[f"{a}{k}"] for a in "xyz"], 1), P[:, k - 1], atol=1e-9)
    assert _rot_err(ds.rotations(), T[:, :3, :3]) < 1e-9
    # three-smr: the full TCP pose from the three reflectors and the nest (given in mm)
    out2 = tmp_path / "kuka_pose.csv"
    nest_mm = "; ".join(",".join(f"{v * 1000:.17g}" for v in r) for r in nest)
    code, so, err = run(["import", "three-smr", path, "-o", out2, "--nest", nest_mm, "--nest-unit", "mm", "--joints", "A1..A6",
                         "--angle-unit", "deg", "--position", "X,Y,Z", "--point", "X2,Y2,Z2", "--point", "X3,Y3,Z3",
                         "--length-unit", "mm", "--robot", "kuka-kr6-r900"], capsys)
    assert code == 0, err
    _check_against(read_dataset(out2), q, T)
    # swapped reflectors in one row: refused, naming row and file line
    lines = path.read_text().splitlines()
    cells = lines[5].split()
    cells[9:12], cells[12:15] = cells[12:15], cells[9:12]
    lines[5] = "  ".join(cells)
    path.write_text("\n".join(lines) + "\n")
    out3 = tmp_path / "bad.csv"
    code, _, err = run(["import", "three-smr", path, "-o", out3, "--nest", nest_mm, "--nest-unit", "mm", "--joints", "A1..A6",
                        "--angle-unit", "deg", "--position", "X,Y,Z", "--point", "X2,Y2,Z2", "--point", "X3,Y3,Z3",
                        "--length-unit", "mm"], capsys)
    assert code != 0 and len(err.strip().splitlines()) == 1 and "row 5 (line 6 of the file)" in err
    assert "do not fit the nest" in err and not out3.exists()


def test_three_smr_default_layout(tmp_path, capsys):
    """Without a mapping three-smr reads q1..qN, p1x..p3z (the import_three_smr layout), other columns kept."""
    rob = load_robot("ur10")
    q = rob.random_joints(12, 8)
    T = fk(rob, q)
    nest = np.array([[0.0, 0.05, 0.0], [0.04, -0.02, 0.01], [-0.05, -0.03, 0.0]])
    P = (np.einsum("nij,kj->nki", T[:, :3, :3], nest) + T[:, None, :3, 3]).reshape(-1, 9)
    head = [f"q{j}" for j in range(1, 7)] + [f"p{k}{a}" for k in (1, 2, 3) for a in "xyz"] + ["id"]
    body = [",".join(repr(float(v)) for v in [*q[i], *P[i]]) + f",{i}" for i in range(12)]
    path = tmp_path / "smr.csv"
    path.write_text(",".join(head) + "\n" + "\n".join(body) + "\n")
    nf = tmp_path / "nest.toml"
    nf.write_text("nest = " + str(nest.tolist()) + '\nnest_unit = "m"\n')
    out = tmp_path / "o.csv"
    code, _, err = run(["import", "three-smr", path, "-o", out, "--nest", nf], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    _check_against(ds, q, T)
    np.testing.assert_array_equal(ds.extra["id"], np.arange(12))


# --------------------------------------------------------------------------- layout 4


def _rotvec(R):
    """Axis·angle from rotation matrices (angles below π), closed form."""
    ang = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
    w = np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], 1)
    return w * (ang / (2 * np.sin(ang)))[:, None]


def test_layout4_rotvec_comments_units_row_and_filter(tmp_path, capsys):
    rob = load_robot("ur5")
    n = 20
    q = rob.random_joints(n, 4) * 0.5
    T = fk(rob, q)
    rv = _rotvec(T[:, :3, :3])
    assert (np.linalg.norm(rv, axis=1) < math.pi - 1e-3).all()
    lines = ["# UR log, TCP pose p[x,y,z,rx,ry,rz]", "base,shoulder,elbow,wrist1,wrist2,wrist3,x,y,z,rx,ry,rz,valid",
             "rad,rad,rad,rad,rad,rad,m,m,m,rad,rad,rad,-"]
    for i in range(n):
        lines.append(",".join(repr(float(v)) for v in [*q[i], *T[i, :3, 3], *rv[i]]) + ",1")
        if i % 7 == 3:  # a lost measurement: junk cells, flagged invalid
            lines.append(",".join(repr(float(v)) for v in q[i]) + ",,,,,,,0")
        if i == 10:
            lines.append("# pause")
    path = tmp_path / "ur.csv"
    path.write_text("\n".join(lines) + "\n")
    mp = tmp_path / "ur.toml"
    mp.write_text('comment = "#"\ndrop_rows = [3]\nwhere = ["valid == 1"]\n'
                  'joints = ["base", "shoulder", "elbow", "wrist1", "wrist2", "wrist3"]\n'
                  'position = ["x", "y", "z"]\nrotvec = ["rx", "ry", "rz"]\n')
    out = tmp_path / "o.parquet"
    code, _, err = run(["import", "table", path, "-o", out, "--map", mp, "--dof", "6"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    assert len(ds) == n
    _check_against(ds, q, T)


@pytest.mark.parametrize("conv, extrinsic, compose", [
    ("xyz", False, lambda a, b, c: _rx(a) @ _ry(b) @ _rz(c)),
    ("xyz", True, lambda a, b, c: _rz(c) @ _ry(b) @ _rx(a)),
    ("zyz", False, lambda a, b, c: _rz(a) @ _ry(b) @ _rz(c)),
    ("kuka", None, lambda a, b, c: _rz(a) @ _ry(b) @ _rx(c)),
    ("rpy", None, lambda a, b, c: _rz(c) @ _ry(b) @ _rx(a)),
    ("ZYX", None, lambda a, b, c: _rz(a) @ _ry(b) @ _rx(c)),
])
def test_euler_conventions(tmp_path, conv, extrinsic, compose):
    rng = np.random.default_rng(0)
    ang = rng.uniform(-3.0, 3.0, (15, 3))
    ang[:, 1] = rng.uniform(0.1, 1.4, 15)
    path = tmp_path / "e.csv"
    path.write_text("j,x,y,z,e1,e2,e3\n" + "\n".join(f"0.1,0.5,0.2,0.3,{a!r},{b!r},{c!r}" for a, b, c in ang.tolist()) + "\n")
    m = TableMap(joints=["j"], position=["x", "y", "z"], euler=["e1", "e2", "e3"], euler_convention=conv,
                 euler_extrinsic=extrinsic)
    ds = import_table(path, m)
    assert _rot_err(ds.rotations(), compose(*ang.T)) < 1e-12


# --------------------------------------------------------------------------- refusals


def _refused(capsys, argv, out, *needles):
    code, so, err = run(argv, capsys)
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    for s in needles:
        assert s in lines[0], lines[0]
    assert not out.exists()
    return lines[0]


def test_refusals(tmp_path, capsys):
    rob, q, T, temp, path, mp = _layout1(tmp_path)
    out = tmp_path / "o.csv"
    base = ["import", "table", path, "-o", out, "--map", mp]
    # missing mapped column, with did-you-mean over the header
    _refused(capsys, base + ["--position", "Pos X,Pos Y,PosZ"], out, "column 'PosZ'", "did you mean 'Pos Z'")
    # degrees declared as radians / mm declared as metres
    _refused(capsys, base + ["--angle-unit", "rad"], out, "line 4 of the file", "looks like degrees")
    _refused(capsys, base + ["--length-unit", "m"], out, "column 'Pos", "looks like millimetres")
    # joint count disagreeing with --dof
    _refused(capsys, base + ["--dof", "7"], out, "6 joint column(s)", "dof = 7")
    # unknown TOML key
    bad = tmp_path / "bad.toml"
    bad.write_text(mp.read_text() + 'lenght_unit = "mm"\n')
    _refused(capsys, ["import", "table", path, "-o", out, "--map", bad], out, "unknown mapping key 'lenght_unit'",
             "did you mean 'length_unit'")
    # decimal comma not declared
    _refused(capsys, base + ["--decimal", "."], out, "row 1 (line 4 of the file)", "decimal comma")
    # a non-numeric cell: named by row, file line and column
    lines = path.read_text(encoding="cp1252").splitlines()
    cells = lines[9].split(";")
    cells[8] = "n/a"
    lines[9] = ";".join(cells)
    path.write_text("\n".join(lines) + "\n", encoding="cp1252")
    _refused(capsys, base, out, "row 7 (line 10 of the file), column 'Pos Y'", "'n/a' is not a number")
    # no mapping at all: never import from a guess
    _refused(capsys, ["import", "table", path, "-o", out], out, "--suggest")
    # output = input
    _refused(capsys, ["import", "table", path, "-o", path, "--map", mp], out, "over the input file")


def test_refuses_seventh_joint(tmp_path, capsys):
    """A 7-joint file in the UR5 layout: `import ur5` refuses, `import table` with joints A1..A6-style
    mapping of six refuses the left-out seventh, and a 7-joint mapping imports it."""
    rob = load_robot("kuka-iiwa14")
    q = rob.random_joints(10, 1)
    T = fk(rob, q)
    head = ["step_order", "x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{j}" for j in range(1, 8)]
    body = [",".join(repr(float(v)) for v in [i, *(T[i, :3, 3] * 1e3), 0.0, 0.0, 0.0, *np.degrees(q[i])]) for i in range(10)]
    path = tmp_path / "seven.csv"
    path.write_text(",".join(head) + "\n" + "\n".join(body) + "\n")
    out = tmp_path / "o.csv"
    _refused(capsys, ["import", "ur5", path, "-o", out], out, "column 'joint_7'", "hykin import table")
    six = ["import", "table", path, "-o", out, "--joints", "joint_1,joint_2,joint_3,joint_4,joint_5,joint_6",
           "--angle-unit", "deg", "--position", "x_t,y_t,z_t", "--length-unit", "mm"]
    _refused(capsys, six, out, "column 'joint_7'", "further joint")
    _refused(capsys, six[:6] + ["joint_*"] + six[7:] + ["--robot", "ur5"], out, "7 joint column(s)", "6 joints")
    code, _, err = run(six[:6] + ["joint_*"] + six[7:] + ["--robot", "kuka-iiwa14"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    np.testing.assert_allclose(ds.q, q, atol=1e-12)
    np.testing.assert_allclose(ds.xyz_m, T[:, :3, 3], atol=1e-12)


def test_mapping_validation():
    with pytest.raises(TableMapError, match="did you mean 'quaternion'"):
        table_map_from_dict({"quaternions": ["a", "b", "c", "d"]})
    with pytest.raises(TableMapError, match="one orientation"):
        table_map_from_dict({"euler": "a,b,c", "rotvec": "d,e,f", "euler_convention": "xyz"})
    with pytest.raises(TableMapError, match="euler_convention"):
        table_map_from_dict({"euler": "a,b,c"})
    with pytest.raises(TableMapError, match="mixes cases"):
        table_map_from_dict({"euler": "a,b,c", "euler_convention": "xYz"})
    with pytest.raises(TableMapError, match="length_unit must be one of"):
        table_map_from_dict({"length_unit": "mmm"})
    with pytest.raises(TableMapError, match="needs 3 column names"):
        table_map_from_dict({"position": "x,y"})


# --------------------------------------------------------------------------- stream


def test_import_stream_cli(tmp_path, capsys):
    """110 Hz joint log + 1 kHz tracker stream (mm, tracker frame, a clock offset, a beam break)."""
    rob = load_robot("rx160")
    offset = 0.0373
    B = se3.xyzrpy_to_transform([2.0, -1.0, 0.3], [0.1, -0.2, 1.0])
    q0 = np.array([0.1, -0.3, 0.6, 0.0, 0.5, 0.0])
    A = np.array([0.5, 0.3, 0.3, 0.6, 0.4, 0.8])
    f = np.array([0.11, 0.07, 0.13, 0.17, 0.19, 0.23])

    def Q(t):
        return q0 + A * np.sin(2 * np.pi * f * np.asarray(t)[:, None] + 0.3 * np.arange(6))

    t_r = np.arange(0, 12, 1 / 110)
    t_t = np.arange(-0.5, 12.5, 1e-3)
    p = (B @ fk(rob, Q(t_t - offset)))[:, :3, 3] * 1e3
    lost = (t_t > 5.0) & (t_t < 5.05)
    rlog = tmp_path / "robot.csv"
    rlog.write_text("t," + ",".join(f"q{j}" for j in range(1, 7)) + "\n"
                    + "\n".join(",".join(repr(float(v)) for v in [t, *qq]) for t, qq in zip(t_r, Q(t_r))) + "\n")
    trk = tmp_path / "tracker.csv"
    trk.write_text("time_ms;X;Y;Z\n" + "\n".join(
        f"{float(t) * 1e3!r};" + (";;" if lo else ";".join(repr(float(v)) for v in pp)) for t, pp, lo in zip(t_t, p, lost)) + "\n")
    out = tmp_path / "aligned.csv"
    code, so, err = run(["import", "stream", rlog, trk, "-o", out, "--robot", "rx160", "--tracker-time", "time_ms",
                         "--tracker-time-unit", "ms", "--position", "X,Y,Z", "--length-unit", "mm", "--frame", "fit",
                         "--max-speed", "0.3"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    assert 0.5 * len(t_r) < len(ds) < len(t_r)
    in_gap = (ds.extra["t_robot_s"] + offset > 5.0 + 2e-3) & (ds.extra["t_robot_s"] + offset < 5.05 - 2e-3)
    assert not in_gap.any() and ((t_r + offset > 5.0 + 2e-3) & (t_r + offset < 5.05 - 2e-3)).sum() >= 4
    off_ms = float(so.split("clock offset ")[1].split(" ms")[0])
    assert abs(off_ms - offset * 1e3) < 0.1
    err_m = np.linalg.norm(ds.xyz_m - fk(rob, ds.q)[:, :3, 3], axis=1)
    assert err_m.max() < 2e-5  # linear interpolation of a 1 kHz stream + the fitted rigid map
    # the time column missing: one line
    _refused(capsys, ["import", "stream", rlog, trk, "-o", tmp_path / "x.csv", "--robot", "rx160", "--length-unit", "mm",
                      "--position", "X,Y,Z"], tmp_path / "x.csv", "column 't'", "mapped as time")


def test_headerless_iso_time_and_units_line(tmp_path, capsys):
    """No header (columns 1, 2, ...), ISO 8601 time stamps; a units line is named as the likely cause."""
    rob = load_robot("ur10e")
    q = rob.random_joints(8, 9) * 0.5
    T = fk(rob, q)
    stamps = [f"2026-11-23 04:33:{10 + i:02d}.250" for i in range(8)]
    body = ["|".join([stamps[i], *(repr(float(v)) for v in [*q[i], *T[i, :3, 3]])]) for i in range(8)]
    path = tmp_path / "nohead.txt"
    path.write_text("\n".join(body) + "\n")
    m = {"header_row": 0, "delimiter": "|", "time": "1", "joints": "2..7", "position": ["8", "9", "10"]}
    ds = import_table(path, m, rob)
    _check_against(ds, q, T)
    t0 = float(np.datetime64("2026-11-23T04:33:10.250", "ms").astype(np.int64)) * 1e-3
    np.testing.assert_allclose(ds.extra["time_s"], t0 + np.arange(8), rtol=0, atol=1e-6)
    # the same with a header and a units line under it
    path.write_text("t|a|b|c|d|e|f|x|y|z\ns|rad|rad|rad|rad|rad|rad|m|m|m\n" + "\n".join(body) + "\n")
    out = tmp_path / "o.csv"
    _refused(capsys, ["import", "table", path, "-o", out, "--joints", "a,b,c,d,e,f", "--position", "x,y,z"], out,
             "row 1 (line 2 of the file), column 'a'", "drop_rows = [2]")
    code, _, err = run(["import", "table", path, "-o", out, "--joints", "a,b,c,d,e,f", "--position", "x,y,z", "--drop-rows", "2",
                        "--time", "t"], capsys)
    assert code == 0, err
    _check_against(read_dataset(out), q, T)


_AX = {"x": _rx, "y": _ry, "z": _rz}


def _compose(seq, ang):
    """Rotation of Euler angles ``ang`` (N, 3) in scipy's sequence notation, composed here."""
    Rs = [_AX[a.lower()](ang[:, k]) for k, a in enumerate(seq)]
    return Rs[0] @ Rs[1] @ Rs[2] if seq.isupper() else Rs[2] @ Rs[1] @ Rs[0]


@pytest.mark.parametrize("seed", range(16))
def test_random_layouts_round_trip(tmp_path, seed):
    """Random layouts (delimiter, decimal, units, orientation form and convention, column order, junk
    columns, metadata and comment lines, joint count 3..9) written here and read back exactly."""
    rng = np.random.default_rng(100 + seed)
    n, dof = int(rng.integers(3, 12)), int(rng.integers(3, 10))
    delim = [",", ";", "\t", " ", "|"][seed % 5]
    decimal = "," if (delim != "," and rng.random() < 0.5) else "."
    aunit, lunit = rng.choice(["rad", "deg"]), rng.choice(["m", "mm", "cm", "in"])
    form = ["none", "wxyz", "xyzw", "euler", "rotvec"][seed % 5 if seed < 10 else int(rng.integers(0, 5))]
    q = rng.uniform(-3.0, 3.0, (n, dof))
    p = rng.uniform(-1.5, 1.5, (n, 3))
    ang = rng.uniform(-3.0, 3.0, (n, 3))
    ang[:, 1] = rng.uniform(0.2, 1.3, n)  # away from gimbal lock
    seq = "".join(rng.choice(["xyz", "zyx", "zyz", "xzx", "yxz"]))[:3]
    seq = seq.upper() if rng.random() < 0.5 else seq
    R = _compose(seq, ang)
    A, L = (180 / math.pi if aunit == "deg" else 1.0), {"m": 1.0, "mm": 1e3, "cm": 1e2, "in": 1 / 0.0254}[lunit]
    cols = {f"Joint {j + 1}" if delim != " " else f"Joint_{j + 1}": q[:, j] * A for j in range(dof)}
    cols.update({"PX": p[:, 0] * L, "PY": p[:, 1] * L, "PZ": p[:, 2] * L, "Note": np.array(["ok"] * n)})
    m = {"joints": [c for c in cols if c.startswith("Joint")], "position": ["PX", "PY", "PZ"], "angle_unit": str(aunit),
         "length_unit": str(lunit), "decimal": decimal, "delimiter": {"\t": "tab", " ": "whitespace"}.get(delim, delim)}
    if form in ("wxyz", "xyzw"):
        qw = se3.matrix_to_quat(R) * rng.choice([-1.0, 1.0], (n, 1))
        order = [0, 1, 2, 3] if form == "wxyz" else [1, 2, 3, 0]
        names = [f"Q{k}" for k in range(4)]
        cols.update({nm: qw[:, o] for nm, o in zip(names, order)})
        m.update(quaternion=names, quaternion_order=form)
    elif form == "euler":
        eu = "deg" if rng.random() < 0.5 else "rad"
        cols.update({f"E{k}": ang[:, k] * (180 / math.pi if eu == "deg" else 1.0) for k in range(3)})
        m.update(euler=["E0", "E1", "E2"], euler_convention=seq.lower(), euler_extrinsic=seq.islower(), euler_unit=eu)
    elif form == "rotvec":
        rv = _rotvec(R)
        cols.update({f"R{k}": rv[:, k] for k in range(3)})
        m.update(rotvec=["R0", "R1", "R2"])
    names = list(cols)
    order = rng.permutation(len(names))
    names = [names[i] for i in order]

    def cell(v):
        s = v if isinstance(v, str) else f"{float(v):.17g}"
        return s.replace(".", ",") if decimal == "," and not isinstance(v, str) else s

    meta = int(rng.integers(0, 3))
    lines = [f"meta line {k}" for k in range(meta)] + [delim.join(names)]
    for i in range(n):
        lines.append(delim.join(cell(cols[c][i]) for c in names))
        if rng.random() < 0.2:
            lines.append("// comment")
    path = tmp_path / "t.txt"
    path.write_text("\n".join(lines) + "\n")
    m.update(skip_rows=meta, comment="//")
    ds = import_table(path, m)
    np.testing.assert_allclose(ds.q, q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ds.xyz_m, p, rtol=0, atol=1e-12)
    assert ds.has_orientation == (form != "none")
    if form != "none":
        assert _rot_err(ds.rotations(), R) < 1e-12
    assert list(ds.extra) == []  # nothing kept unless asked


def test_a_wrong_euler_convention_is_refused_naming_the_euler_options(tmp_path, capsys):
    """KUKA A,B,C imported as rpy (roll and yaw swapped): the orientations no longer fit the robot, and
    the refusal points at the Euler options, not only at quaternion orders."""
    rob, q, T, nest, P, path = _layout3(tmp_path)
    out = tmp_path / "rpy.csv"
    code, _, err = run(["import", "table", path, "-o", out, "--joints", "A1..A6", "--angle-unit", "deg", "--position", "X,Y,Z",
                        "--length-unit", "mm", "--euler", "A,B,C", "--euler-convention", "rpy", "--euler-unit", "deg"], capsys)
    assert code == 0, err  # the import cannot know: the robot is not given
    _refused(capsys, ["calibrate", "kuka-kr6-r900", out, "-o", tmp_path / "cal.toml"], tmp_path / "cal.toml",
             "--euler-convention", "KUKA A,B,C")


def test_an_empty_cell_names_the_row_and_how_to_leave_such_rows_out(tmp_path, capsys):
    """A lost marker leaves an empty cell: refused naming row and column, with the --where that drops
    such rows; with it the other rows are imported unchanged."""
    f = tmp_path / "m.csv"
    f.write_text("J1,J2,J3,J4,J5,J6,X,Y,Z\n" + "\n".join(
        f"{10 + i},20,30,40,50,60,{100 + i},200,{'' if i == 2 else 300}" for i in range(5)) + "\n")
    args = ["import", "table", f, "--joints", "J1..J6", "--angle-unit", "deg", "--position", "X,Y,Z",
            "--length-unit", "mm", "--no-unit-check"]
    code, _, err = run([*args, "-o", tmp_path / "a.csv"], capsys)
    assert code == 2 and "row 3" in err and "column 'Z'" in err and "--where 'Z != '" in err
    code, _, err = run([*args, "-o", tmp_path / "b.csv", "--where", "Z != "], capsys)
    assert code == 0, err
    ds = read_dataset(tmp_path / "b.csv")
    assert len(ds) == 4 and np.allclose(ds.xyz_m[:, 0], [0.100, 0.101, 0.103, 0.104])
