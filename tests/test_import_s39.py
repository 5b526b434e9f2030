"""probeS: `hykin import` with users' own conventions -- time units of stream logs, quaternion / Euler column
names against the declared order, quoted CSV with decimal commas, and the one-line refusals' causes.

Expected values are written here from the files' construction (not from hykin's output)."""

from __future__ import annotations

import numpy as np
import pytest
from cli_run import run

from hykin.io.dataset import DatasetError
from hykin.io.text_table import detect_delimiter
from hykin.measure.stream_checks import NotAStreamError, check_is_stream
from hykin.measure.streams import NoOverlapError, StreamError, TimeUnitError, _ncc_offset, estimate_clock
from hykin.measure.table_import import guess_layout, import_table
from hykin.measure.table_map import TableMapError, table_map_from_dict

# --------------------------------------------------------------------------- streams: time units, overlap


def _motion(t):
    """A TCP path (m) with speed changes."""
    return np.stack([0.3 * np.sin(1.3 * t) + 0.05 * np.sin(5.1 * t), 0.2 * np.cos(0.9 * t), 0.1 * np.sin(2.2 * t)], 1)


def test_robot_time_in_ms_read_as_s_is_named_not_a_traceback():
    t_r = np.arange(0, 2.0, 0.004)  # 250 Hz robot, 2 s
    t_t = np.arange(-0.2, 2.2, 0.001)  # 1 kHz tracker
    p_r, p_t = _motion(t_r), _motion(t_t)
    # the robot's times in ms, read as s: a sample every 4 "s" over 2000 "s"; --max-gap 5 let it past the static check
    with pytest.raises(TimeUnitError) as e:
        estimate_clock(t_r * 1e3, None, t_t, p_t, p_robot=p_r, max_gap_s=5.0)
    assert e.value.which == "robot log" and e.value.unit == "ms" and e.value.factor == 1e3
    assert "every 4 s" in str(e.value) and "every 0.001 s" in str(e.value) and 'time_unit = "ms"' in str(e.value)
    with pytest.raises(TimeUnitError) as e:  # and without --max-gap: the unit, not "static data"
        check_is_stream(t_r * 1e3, t_t)
    with pytest.raises(TimeUnitError) as e:  # the tracker's time in us
        check_is_stream(t_r, t_t * 1e6)
    assert e.value.which == "tracker" and e.value.unit == "us"
    check_is_stream(np.arange(0, 10, 0.1), np.arange(0, 10, 1 / 3000))  # 10 Hz robot, 3 kHz tracker: a stream


def test_not_a_stream_names_the_time_unit_when_the_log_lasts_far_longer():
    # robot period 4 s over 116 s against a tracker at 1 ms over 2 s: not the ~1000x span of a slip, but a hint
    with pytest.raises(NotAStreamError) as e:
        check_is_stream(np.arange(0, 120, 4.0), np.arange(0, 2.0, 0.001))
    assert e.value.time_unit_hint == "ms" and 'time_unit = "ms"' in str(e.value)
    with pytest.raises(NotAStreamError) as e:  # a static campaign: same span, no time-unit hint
        check_is_stream(np.arange(0, 120, 4.0), np.arange(0, 120, 0.001))
    assert e.value.time_unit_hint is None and "time_unit" not in str(e.value)


def test_ncc_without_overlap_is_a_stream_error_not_an_index_error():
    with pytest.raises(StreamError, match="do not overlap"):
        _ncc_offset(np.zeros(0), np.zeros(0), 10.0, np.ones(50), np.ones(50), 0.0, 1e-3, 0.0, 0.1, 10.0)


def _write_stream(path, t, cols, names):
    rows = ["time," + ",".join(names)] + [f"{float(a)!r}," + ",".join(repr(float(v)) for v in r) for a, r in zip(t, cols)]
    path.write_text("\n".join(rows) + "\n")


def test_epoch_tracker_against_a_robot_log_from_zero_names_both_ranges_and_offset(tmp_path, capsys):
    t_r = np.arange(0, 2.0, 0.004)
    t_t = np.arange(-0.2, 2.2, 0.001)
    with pytest.raises(NoOverlapError) as e:
        estimate_clock(t_r, None, t_t + 1.7e9, _motion(t_t), p_robot=_motion(t_r))
    assert e.value.robot_range_s[0] == 0.0 and e.value.tracker_range_s[0] == pytest.approx(1.7e9 - 0.2)
    # through the CLI: both files, both ranges, --offset with the middles' difference (1.7e9 s)
    rob, trk = tmp_path / "robot.csv", tmp_path / "tracker.csv"
    q = np.zeros((t_r.size, 6)) + np.linspace(0, 0.5, t_r.size)[:, None]
    _write_stream(rob, t_r, q, [f"q{j}" for j in range(1, 7)])
    _write_stream(trk, t_t + 1.7e9, _motion(t_t), ["x", "y", "z"])
    out = tmp_path / "o.csv"
    code, _, se = run(["import", "stream", rob, trk, "--robot", "ur5", "--robot-time", "time", "--tracker-time", "time",
                       "-o", out], capsys)
    line = se.strip()
    assert code == 2 and len(line.splitlines()) == 1 and not out.exists(), se
    assert str(trk) in line and str(rob) in line and "--offset" in line and "1700000000.0" in line
    assert "0.000000 to 1.996000 s" in line


# --------------------------------------------------------------------------- orientation names vs order


def _pose_table(tmp_path, header, rows):
    p = tmp_path / "t.csv"
    p.write_text(",".join(header) + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    return p


def _rows_xyzw(n=4):
    rng = np.random.default_rng(3)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)  # x, y, z, w
    rows = []
    for k in range(n):
        joints = [f"{0.1 * (j + k):.3f}" for j in range(6)]
        pos = [f"{0.5 + 0.1 * k:.3f}", f"{0.2 * k:.3f}", f"{0.3 + 0.05 * k:.3f}"]
        rows.append(joints + pos + [repr(float(v)) for v in q[k]])
    return q, rows


def test_quaternion_named_xyzw_read_as_wxyz_is_refused(tmp_path):
    q, rows = _rows_xyzw()
    p = _pose_table(tmp_path, [f"q{j}" for j in range(1, 7)] + ["X", "Y", "Z", "QX", "QY", "QZ", "QW"], rows)
    base = {"joints": "q1..q6", "position": ["X", "Y", "Z"], "quaternion": ["QX", "QY", "QZ", "QW"]}
    with pytest.raises(TableMapError) as e:
        import_table(p, table_map_from_dict(base))
    msg = str(e.value)
    assert "QX,QY,QZ,QW" in msg and "--quaternion-order xyzw" in msg and "\n" not in msg
    ds = import_table(p, table_map_from_dict({**base, "quaternion_order": "xyzw"}))  # declared: read right
    want = q[:, [3, 0, 1, 2]] * np.sign(q[:, [3]])
    assert np.allclose(ds.quat_wxyz * np.sign(ds.quat_wxyz[:, [0]]), want, atol=1e-12)
    for names in (["q_w", "q_x", "q_y", "q_z"], ["qw", "qx", "qy", "qz"]):  # names in the read order: fine
        p2 = _pose_table(tmp_path, [f"q{j}" for j in range(1, 7)] + ["X", "Y", "Z", *names],
                         [r[:9] + [r[12], r[9], r[10], r[11]] for r in rows])
        import_table(p2, table_map_from_dict({**base, "quaternion": names}))
    with pytest.raises(TableMapError, match="--quaternion-order wxyz"):  # the other way round
        p3 = _pose_table(tmp_path, [f"q{j}" for j in range(1, 7)] + ["X", "Y", "Z", "qw", "qx", "qy", "qz"], rows)
        import_table(p3, table_map_from_dict({**base, "quaternion": ["qw", "qx", "qy", "qz"], "quaternion_order": "xyzw"}))


def test_euler_names_against_the_convention_are_refused(tmp_path):
    rows = [[f"{0.1 * (j + k):.3f}" for j in range(6)] + ["500", f"{10 * k}", "300", f"{5 * k}", "10", "-20"]
            for k in range(4)]
    p = _pose_table(tmp_path, [f"q{j}" for j in range(1, 7)] + ["TX", "TY", "TZ", "RZ", "RY", "RX"], rows)
    base = {"joints": "q1..q6", "position": ["TX", "TY", "TZ"], "euler": ["RZ", "RY", "RX"], "euler_unit": "deg"}
    with pytest.raises(TableMapError) as e:
        import_table(p, table_map_from_dict({**base, "euler_convention": "xyz"}))
    msg = str(e.value)
    assert "RZ,RY,RX" in msg and "'xyz'" in msg and "--euler-convention zyx" in msg and "--euler RX,RY,RZ" in msg
    import_table(p, table_map_from_dict({**base, "euler_convention": "zyx"}))  # names and convention agree
    import_table(p, table_map_from_dict({**base, "euler": ["RZ", "RY", "RX"], "euler_convention": "kuka"}))  # ZYX


# --------------------------------------------------------------------------- quoted CSV with decimal commas


def test_quoted_comma_delimited_file_with_decimal_commas(tmp_path):
    assert detect_delimiter('"A1","A2","X"', ",") == ","
    assert detect_delimiter('"-101,03","2,5"', ",") == ","
    assert detect_delimiter("A1,A2,X", ",") == ","
    assert detect_delimiter("1,5 2,5 3,5", ",") == " "  # a headerless whitespace row with decimal commas
    vals = [[-101.0289, -0.1386, 24.3596, -135.7375, -64.7816, 205.5412, 3094.3568, -868.5964, 1236.1513],
            [-116.8456, -71.0834, 107.5988, 35.1024, -24.1052, 5.4672, 2572.1564, -1213.2210, 773.6652]]
    names = ["A1", "A2", "A3", "A4", "A5", "A6", "X", "Y", "Z"]
    p = tmp_path / "quoted.csv"
    p.write_text(",".join(f'"{n}"' for n in names) + "\n"
                 + "\n".join(",".join(f'"{v!r}"'.replace(".", ",") for v in r) for r in vals) + "\n")
    g = guess_layout(p)
    assert g["delimiter"] == "," and g["decimal"] == ","
    ds = import_table(p, table_map_from_dict({"decimal": ",", "joints": "A1..A6", "angle_unit": "deg",
                                               "position": ["X", "Y", "Z"], "length_unit": "mm"}))
    assert np.allclose(ds.q, np.deg2rad(np.array(vals)[:, :6]), atol=1e-15)
    assert np.allclose(ds.xyz_m, np.array(vals)[:, 6:] * 1e-3, atol=1e-15)


def test_suggest_on_quoted_decimal_comma_file_proposes_deg_mm_and_decimal(tmp_path, capsys):
    rows = [[-101.0289, -0.1386, 24.3596, -135.7375, -64.7816, 205.5412, 3094.3568, -868.5964, 1236.1513],
            [-116.8456, -71.0834, 107.5988, 35.1024, -24.1052, 5.4672, 2572.1564, -1213.2210, 773.6652],
            [30.5, 12.0, -40.25, 80.0, 45.5, -170.0, 1500.25, 800.5, 950.75]]
    p = tmp_path / "quoted.csv"
    p.write_text('"A1","A2","A3","A4","A5","A6","X","Y","Z"\n'
                 + "\n".join(",".join(f'"{v!r}"'.replace(".", ",") for v in r) for r in rows) + "\n")
    code, so, se = run(["import", "table", p, "--suggest"], capsys)
    assert code == 0, se
    assert 'decimal = ","' in so and 'angle_unit = "deg"' in so and 'length_unit = "mm"' in so


# --------------------------------------------------------------------------- messages


def test_empty_cell_in_ur5_file_does_not_suggest_where(tmp_path, capsys):
    cols = ["x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{i}" for i in range(1, 7)]
    rows = [["400", "100", "300", "0.1", "0.2", "0.3", "10", "-20", "30", "-40", "50", "60"] for _ in range(4)]
    rows[2][11] = ""
    p = tmp_path / "ur5.csv"
    p.write_text(",".join(cols) + "\n" + "\n".join(",".join(r) for r in rows) + "\n")
    code, _, se = run(["import", "ur5", p, "-o", tmp_path / "o.csv"], capsys)
    line = se.strip()
    assert code == 2 and len(line.splitlines()) == 1, se
    assert "--where" not in line and "row 3 (line 4 of the file)" in line and "joint_6" in line


def test_units_line_with_empty_first_cells_is_named(tmp_path):
    p = tmp_path / "u.csv"
    p.write_text("J1,J2,J3,J4,J5,J6,TX,TY,TZ\n,,,,,,mm,mm,mm\n"
                 + "\n".join(",".join(["10"] * 6 + ["500", f"{100 * k}", f"{300 + k}"]) for k in range(3)) + "\n")
    m = {"joints": "J1..J6", "angle_unit": "deg", "position": ["TX", "TY", "TZ"], "length_unit": "mm"}
    with pytest.raises(DatasetError) as e:
        import_table(p, table_map_from_dict(m))
    msg = str(e.value)
    assert "units line" in msg and "drop_rows = [2]" in msg and "--drop-rows 2" in msg and "beam lost" not in msg
    ds = import_table(p, table_map_from_dict({**m, "drop_rows": [2]}))
    assert np.allclose(ds.xyz_m[:, 1:], [[0.0, 0.3], [0.1, 0.301], [0.2, 0.302]])


def test_european_thousands_separator_is_named(tmp_path):
    p = tmp_path / "k.csv"
    p.write_text("A1;A2;A3;A4;A5;A6;X;Y;Z\n" + "\n".join(
        ";".join(["-101,028905"] * 6 + ["3.094,356827", "-868,596408", "1.236,151365"]) for _ in range(3)) + "\n")
    m = {"delimiter": ";", "decimal": ",", "joints": "A1..A6", "angle_unit": "deg", "position": ["X", "Y", "Z"],
         "length_unit": "mm"}
    with pytest.raises(DatasetError) as e:
        import_table(p, table_map_from_dict(m))
    assert "thousands separator" in str(e.value) and "3094.356827" in str(e.value) and "column 'X'" in str(e.value)


def test_suggest_on_headerless_file_proposes_header_row_0(tmp_path, capsys):
    p = tmp_path / "nohdr.txt"
    p.write_text("\n".join(" ".join(f"{(k + 1) * (j - 3.5):.4f}" for j in range(9)) for k in range(5)) + "\n")
    g = guess_layout(p)
    assert g.get("header_row") == 0
    code, so, se = run(["import", "table", p, "--suggest"], capsys)
    assert code == 0 and "header_row = 0" in so, so + se
