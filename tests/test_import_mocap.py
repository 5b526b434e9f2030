"""Motion-capture exports through `hykin import table`: OptiTrack Motive's multi-line header (X,Y,Z
repeated per rigid body / marker, an empty name), Vicon's group line and units line, headerless reads
with skip_rows, frame counters beside headerless joints, rotation vs translation names (RX/TX, Leica
Q0..QZ). Every check is against the values written into the generated file."""

import math

import numpy as np
import pytest
from cli_run import run
from scipy.spatial.transform import Rotation

from hykin.io.dataset_files import read_dataset
from hykin.io.toml_compat import tomllib
from hykin.measure.table_import import import_table
from hykin.measure.table_map import TableMapError, suggest_map

N = 12


def _poses(seed=0):
    rng = np.random.default_rng(seed)
    q_deg = rng.uniform(-170, 170, (N, 6))
    pos_mm = rng.uniform(-400, 400, (N, 3)) + [2700.0, -1900.0, 1500.0]
    rot = Rotation.random(N, random_state=seed)
    return q_deg, pos_mm, rot


def _motive(path, shifted=True):
    """A Motive 1.23 CSV: metadata, blank line, Type/Name/ID/Rotation group lines (``shifted``: one
    extra leading empty cell, as some exporters write), then ``Frame,Time,X,Y,Z,W,X,Y,Z,,X,Y,Z,J1..J6``."""
    q, p, rot = _poses()
    quat = rot.as_quat()  # xyzw
    marker = p + [45.0, 0.0, 10.0]
    lead = ",," if shifted else ","
    groups = ["Rigid Body"] * 8 + ["Marker"] * 3 + ["Robot"] * 6
    lines = ["Format Version,1.23,Take Name,t,Rotation Type,Quaternion,Length Units,Millimeters", "",
             lead + "Type," + ",".join(groups),
             lead + "Name," + ",".join(["Tool"] * 8 + ["Tool:Marker1"] * 3 + [f"Joint{j}" for j in range(1, 7)]),
             lead + "ID," + ",".join(["1"] * 8 + ["1:1"] * 3 + [""] * 6),
             lead + "," + ",".join(["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"] + ["Position"] * 3 + ["Angle"] * 6),
             "Frame,Time (Seconds)," + ",".join(["X", "Y", "Z", "W", "X", "Y", "Z", ""] + ["X", "Y", "Z"]
                                                + [f"J{j}" for j in range(1, 7)])]
    for i in range(N):
        vals = [*quat[i], *p[i], 0.00015, *marker[i], *q[i]]
        lines.append(f"{17 + 240 * i},{(17 + 240 * i) / 120:.6f}," + ",".join(repr(float(v)) for v in vals))
    path.write_text("\n".join(lines) + "\n")
    return q, p, rot, marker


def _check(ds, q_deg, p_mm, rot):
    np.testing.assert_allclose(ds.q, np.radians(q_deg), rtol=0, atol=1e-12)
    np.testing.assert_allclose(ds.xyz_m, p_mm * 1e-3, rtol=0, atol=1e-12)
    err = (Rotation.from_quat(ds.quat_wxyz, scalar_first=True).inv() * rot).magnitude()
    assert err.max() < 1e-9


def _import_with(suggested: str, path, tmp_path, capsys):
    """``hykin import table PATH --map`` with the suggested map text as it was written: the Dataset."""
    mp = tmp_path / "m.toml"
    mp.write_text(suggested)
    out = tmp_path / "o.csv"
    code, _, err = run(["import", "table", path, "-o", out, "--map", mp], capsys)
    assert code == 0, err
    return read_dataset(out)


@pytest.mark.parametrize("shifted", [True, False])
def test_motive_suggest_then_import(tmp_path, capsys, shifted):
    path = tmp_path / "take.csv"
    q, p, rot, marker = _motive(path, shifted)
    code, so, err = run(["import", "table", path, "--suggest"], capsys)
    assert code == 0, err
    sug = tomllib.loads(so)
    assert sug["skip_rows"] == 6 and sug["group_rows"] == [4, 6]
    assert sug["position"] == ["Tool Position X", "Tool Position Y", "Tool Position Z"]
    assert sug["quaternion"] == ["Tool Rotation W", "Tool Rotation X", "Tool Rotation Y", "Tool Rotation Z"]
    assert sug["joints"] == [f"J{j}" for j in range(1, 7)] and sug["angle_unit"] == "deg" and sug["length_unit"] == "mm"
    assert "points" not in sug and "Tool:Marker1 Position X" in so  # markers offered, commented out
    _check(_import_with(so, path, tmp_path, capsys), q, p, rot)
    # the empty name (Mean Marker Error) and the markers are readable by their joined names
    ds = import_table(path, dict(sug, keep=["Tool Mean Marker Error"],
                                 points=[[f"Tool:Marker1 Position {a}" for a in "XYZ"]]))
    np.testing.assert_array_equal(ds.extra["Tool Mean Marker Error"], 0.00015)
    np.testing.assert_allclose(ds.extra["x2"], marker[:, 0] * 1e-3, atol=1e-12)


def test_repeated_names_without_group_lines_refused_with_the_way_out(tmp_path):
    path = tmp_path / "t.csv"
    path.write_text("J,X,Y,Z,X,Y,Z\n" + "0.5,1,2,3,4,5,6\n" * 3)
    with pytest.raises(Exception) as e:
        import_table(path, {"joints": ["J"], "position": ["X", "Y", "Z"]})
    msg = str(e.value)
    assert "\n" not in msg and "column 'X': appears twice" in msg and "group_rows" in msg and "header_row = 0" in msg
    # the way out: no header, columns 1..6
    ds = import_table(path, {"header_row": 0, "skip_rows": 1, "joints": ["1"], "position": ["5", "6", "7"],
                             "check_units": False})
    np.testing.assert_array_equal(ds.xyz_m, [[4.0, 5.0, 6.0]] * 3)


def test_motive_headerless_skip_rows_and_frame_counter(tmp_path, capsys):
    """header_row = 0 with skip_rows: the width is the data's; the frame counter and time beside the
    numbered columns are not further joints, and no ignore list is needed."""
    path = tmp_path / "take.csv"
    q, p, rot, _ = _motive(path)
    m = {"header_row": 0, "skip_rows": 7, "joints": [str(k) for k in range(14, 20)], "angle_unit": "deg",
         "position": ["7", "8", "9"], "length_unit": "mm", "quaternion": ["3", "4", "5", "6"], "quaternion_order": "xyzw",
         "time": "2"}
    ds = import_table(path, m)
    _check(ds, q, p, rot)
    np.testing.assert_allclose(ds.extra["time_s"], (17 + 240 * np.arange(N)) / 120, atol=1e-6)
    # the same with drop_rows in place of skip_rows (the metadata and group lines dropped)
    ds = import_table(path, {**{k: v for k, v in m.items() if k != "skip_rows"}, "drop_rows": [1, 3, 4, 5, 6, 7]})
    _check(ds, q, p, rot)
    # the suggestion reads the same layout
    code, so, err = run(["import", "table", path, "--suggest", "--skip-rows", "7", "--header-row", "0"], capsys)
    assert code == 0, err
    sug = tomllib.loads(so)
    assert sug["header_row"] == 0 and sug["skip_rows"] == 7


def test_headerless_further_joint_still_refused(tmp_path):
    """A seventh joint column next to six mapped headerless joints is still refused."""
    rng = np.random.default_rng(3)
    q = rng.uniform(-3, 3, (15, 7))
    path = tmp_path / "q.csv"
    np.savetxt(path, np.c_[np.arange(15), q, rng.uniform(0.2, 0.9, (15, 3))], delimiter=",", fmt="%.10g")
    m = {"header_row": 0, "joints": [str(k) for k in range(2, 8)], "position": ["9", "10", "11"]}
    with pytest.raises(Exception, match=r"column '8': looks like a further joint.*vary like theirs"):
        import_table(path, m)
    ds = import_table(path, {**m, "joints": [str(k) for k in range(2, 9)]})
    np.testing.assert_allclose(ds.q, q, atol=1e-9)


def _vicon(path):
    q, p, rot = _poses(1)
    rv = rot.as_rotvec(degrees=True)
    lines = ["Segments", "100", ",,UR5Tool:Tool,,,,,,Robot:Joints,,,,,",
             "Frame,Sub Frame,RX,RY,RZ,TX,TY,TZ,J1,J2,J3,J4,J5,J6", ",,deg,deg,deg,mm,mm,mm,deg,deg,deg,deg,deg,deg"]
    for i in range(N):
        lines.append(f"{1 + 200 * i},0," + ",".join(repr(float(v)) for v in [*rv[i], *p[i], *q[i]]))
    path.write_text("\n".join(lines) + "\n")
    return q, p, rot


def test_vicon_suggest_finds_header_units_line_and_rotvec(tmp_path, capsys):
    path = tmp_path / "vicon.csv"
    q, p, rot = _vicon(path)
    code, so, err = run(["import", "table", path, "--suggest"], capsys)
    assert code == 0, err
    sug = tomllib.loads(so)
    assert sug["skip_rows"] == 3 and sug["drop_rows"] == [5]
    assert sug["position"] == ["TX", "TY", "TZ"] and sug["rotvec"] == ["RX", "RY", "RZ"] and "points" not in sug
    assert sug["rotvec_unit"] == "deg" and sug["angle_unit"] == "deg" and sug["length_unit"] == "mm"
    assert "from the units line" in so
    _check(_import_with(so, path, tmp_path, capsys), q, p, rot)
    # the swapped mapping is refused naming the swap
    with pytest.raises(TableMapError, match=r"'TX', 'TY', 'TZ'.*swapped.*position = RX, RY, RZ"):
        import_table(path, {"skip_rows": 3, "drop_rows": [5], "joints": "J1..J6", "angle_unit": "deg",
                            "position": ["RX", "RY", "RZ"], "length_unit": "mm", "points": [["TX", "TY", "TZ"]]})


def test_quaternion_names_are_not_reflectors():
    """Leica SA Q0,QX,QY,QZ (scalar first) and q0..q3 with unit norm are a quaternion, not a reflector."""
    head = [f"J{j}" for j in range(1, 7)] + ["X", "Y", "Z", "Q0", "QX", "QY", "QZ"]
    row = ["0.1"] * 6 + ["1000", "2000", "300", "0.5", "0.5", "0.5", "0.5"]
    sug = tomllib.loads(suggest_map(head, [row]))
    assert sug["quaternion"] == ["Q0", "QX", "QY", "QZ"] and sug["quaternion_order"] == "wxyz" and "points" not in sug
    head2 = [f"A{j}" for j in range(1, 7)] + ["x", "y", "z", "q0", "q1", "q2", "q3"]
    c = math.cos(0.3)
    sug = tomllib.loads(suggest_map(head2, [["0.1"] * 6 + ["1", "2", "3", repr(c), repr(math.sin(0.3)), "0", "0"]]))
    assert sug["quaternion"] == ["q0", "q1", "q2", "q3"] and sug["joints"] == [f"A{j}" for j in range(1, 7)]
    # RX/TX names: T is the translation whatever the order
    sug = tomllib.loads(suggest_map(["RX", "RY", "RZ", "TX", "TY", "TZ", "J1", "J2"]))
    assert sug["position"] == ["TX", "TY", "TZ"] and "points" not in sug
