"""Dataset files, units, validation messages, splits and hashing (hykin.dataset)."""

from __future__ import annotations

import numpy as np
import pytest

from hykin.geometry import se3
from hykin.io.dataset import (
    Dataset,
    DatasetError,
    concat,
    dataset_hash,
    split,
    validate,
)
from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.io.robot_file import load_robot


def _random_dataset(n=40, dof=6, seed=0, orientation=True, extra=True):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-3.0, 3.0, (n, dof))
    T = se3.make_transform(se3.rotvec_to_matrix(rng.normal(size=(n, 3))), rng.uniform(-1.5, 1.5, (n, 3)))
    ex = {"temperature": 20 + rng.random(n), "timestamp": np.arange(n, dtype=float)} if extra else None
    return Dataset.from_poses(q, T, extra=ex, source="synthetic", orientation=orientation)


def _write_csv(path, header, rows):
    path.write_text("\n".join([",".join(header)] + [",".join(map(str, r)) for r in rows]) + "\n")
    return path


HEADER = ["q1", "q2", "q3", "x", "y", "z", "qw", "qx", "qy", "qz"]
GOOD = [0.1, -0.2, 0.3, 0.5, 0.1, 0.4, 1.0, 0.0, 0.0, 0.0]


# --------------------------------------------------------------------------- container


def test_container_basics_and_poses():
    ds = _random_dataset(10)
    assert len(ds) == 10 and ds.dof == 6 and ds.has_orientation
    T = ds.poses()
    # quaternion -> matrix -> quaternion closes and positions are the stored ones
    np.testing.assert_allclose(T[:, :3, 3], ds.xyz_m)
    np.testing.assert_allclose(np.abs(np.sum(se3.matrix_to_quat(T[:, :3, :3]) * ds.quat_wxyz, axis=1)), 1.0, atol=1e-12)
    po = _random_dataset(5, orientation=False)
    assert not po.has_orientation
    Tp = po.poses()
    np.testing.assert_array_equal(Tp[:, :3, :3], np.broadcast_to(np.eye(3), (5, 3, 3)))
    np.testing.assert_array_equal(Tp[:, :3, 3], po.xyz_m)
    with pytest.raises(DatasetError, match="position-only"):
        po.rotations()


def test_subset_and_concat():
    ds = _random_dataset(12)
    s = ds.subset([3, 1])
    np.testing.assert_array_equal(s.q, ds.q[[3, 1]])
    np.testing.assert_array_equal(s.extra["timestamp"], [3.0, 1.0])
    m = ds.subset(ds.extra["timestamp"] < 4)
    assert len(m) == 4
    assert len(ds.subset(slice(2, 5))) == 3
    c = Dataset.concat([ds.subset(range(6)), ds.subset(range(6, 12))])
    np.testing.assert_array_equal(c.q, ds.q)
    np.testing.assert_array_equal(c.quat_wxyz, ds.quat_wxyz)
    np.testing.assert_array_equal(c.extra["temperature"], ds.extra["temperature"])
    with pytest.raises(DatasetError, match="orientation"):
        concat([ds, _random_dataset(3, orientation=False)])
    with pytest.raises(DatasetError, match="numbers of joints"):
        concat([ds, _random_dataset(3, dof=5)])
    with pytest.raises(DatasetError, match="rows"):
        Dataset(q=np.zeros((3, 6)), xyz_m=np.zeros((4, 3)))


# --------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("suffix", ["csv", "parquet"])
@pytest.mark.parametrize("units", [("m", "rad"), ("mm", "deg")])
def test_round_trip_with_units(tmp_path, suffix, units):
    if suffix == "parquet":
        pytest.importorskip("pyarrow")
    lu, au = units
    ds = _random_dataset(30)
    p = tmp_path / f"d.{suffix}"
    write_dataset(ds, p, length_unit=lu, angle_unit=au)
    back = read_dataset(p, length_unit=lu, angle_unit=au)
    exact = units == ("m", "rad")
    tol = 0 if exact else 1e-14
    np.testing.assert_allclose(back.q, ds.q, rtol=0, atol=tol * 10)
    np.testing.assert_allclose(back.xyz_m, ds.xyz_m, rtol=0, atol=tol * 10)
    np.testing.assert_array_equal(back.quat_wxyz, ds.quat_wxyz)
    np.testing.assert_array_equal(back.extra["temperature"], ds.extra["temperature"])
    assert back.source == str(p)
    if exact:
        assert dataset_hash(back) == dataset_hash(ds)


def test_file_values_are_in_declared_units(tmp_path):
    ds = _random_dataset(5, orientation=False, extra=False)
    p = tmp_path / "mm_deg.csv"
    write_dataset(ds, p, length_unit="mm", angle_unit="deg")
    raw = np.loadtxt(p, delimiter=",", skiprows=1)
    np.testing.assert_allclose(raw[:, :6], np.degrees(ds.q), rtol=1e-14)
    np.testing.assert_allclose(raw[:, 6:9], ds.xyz_m * 1e3, rtol=1e-14)
    assert p.read_text().splitlines()[0] == "q1,q2,q3,q4,q5,q6,x,y,z"
    back = read_dataset(p, length_unit="mm", angle_unit="deg")
    assert not back.has_orientation
    np.testing.assert_allclose(back.q, ds.q, atol=1e-14)


def test_parquet_remembers_units(tmp_path):
    pytest.importorskip("pyarrow")
    ds = _random_dataset(5)
    p = tmp_path / "d.parquet"
    write_dataset(ds, p, length_unit="mm", angle_unit="deg")
    with pytest.raises(DatasetError, match=r"length_unit='mm'.*'m' was declared"):
        read_dataset(p)


def test_prismatic_joint_scaled_by_length_unit(tmp_path):
    rob = load_robot("rx160")
    rob = rob.copy(joint_type=("prismatic",) + ("revolute",) * 5, lower=np.r_[0.0, rob.lower[1:]], upper=np.r_[1.0, rob.upper[1:]])
    _write_csv(tmp_path / "p.csv", ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z"],
               [[500, 10, 20, 30, 40, 50, 1000, 0, 1000]])
    ds = read_dataset(tmp_path / "p.csv", length_unit="mm", angle_unit="deg", robot=rob)
    np.testing.assert_allclose(ds.q[0], [0.5] + list(np.radians([10, 20, 30, 40, 50])))
    np.testing.assert_allclose(ds.xyz_m[0], [1.0, 0, 1.0])


def test_extra_text_column_kept(tmp_path):
    _write_csv(tmp_path / "e.csv", ["q1", "q2", "x", "y", "z", "label"], [[0.1, 0.2, 0.3, 0.4, 0.5, "a"], [0, 0, 0, 0, 0, "b"]])
    ds = read_dataset(tmp_path / "e.csv")
    assert ds.dof == 2 and list(ds.extra["label"]) == ["a", "b"]


# --------------------------------------------------------------------------- validation messages


def _expect(path, pattern_parts, **kw):
    with pytest.raises(DatasetError) as ei:
        read_dataset(path, **kw)
    msg = str(ei.value)
    for part in pattern_parts:
        assert part in msg, f"{part!r} not in {msg!r}"
    assert str(path) in msg
    return ei.value


def test_missing_columns_named(tmp_path):
    p = _write_csv(tmp_path / "m.csv", ["q1", "q2", "q3", "x", "y"], [[0, 0, 0, 0, 0]])
    e = _expect(p, ["missing column(s) z", "expected q1, q2, q3, x, y, z"])
    assert e.column == "z"
    p = _write_csv(tmp_path / "o.csv", ["q1", "x", "y", "z", "qw", "qx"], [[0, 0, 0, 0, 1, 0]])
    _expect(p, ["orientation columns incomplete", "qy, qz"])
    p = _write_csv(tmp_path / "n.csv", ["a", "b"], [[0, 0]])
    _expect(p, ["no joint columns", "expected q1..qN"])


def test_non_numeric_cell_names_row_and_column(tmp_path):
    rows = [GOOD, GOOD[:4] + ["abc"] + GOOD[5:], GOOD]
    p = _write_csv(tmp_path / "t.csv", HEADER, rows)
    e = _expect(p, ["row 2 (line 3 of the file)", "column 'y'", "'abc' is not a number"])
    assert (e.row, e.column, e.file) == (2, "y", str(p))
    rows = [GOOD, GOOD, [""] + GOOD[1:]]
    p = _write_csv(tmp_path / "empty_cell.csv", HEADER, rows)
    _expect(p, ["row 3", "column 'q1'", "(empty)"])


def test_nan_and_inf_named(tmp_path):
    p = _write_csv(tmp_path / "nan.csv", HEADER, [GOOD, GOOD[:2] + ["nan"] + GOOD[3:]])
    e = _expect(p, ["row 2", "column 'q3'", "value nan is not finite"])
    assert "np.float64" not in str(e)  # the value as written, not numpy's repr
    p = _write_csv(tmp_path / "inf.csv", HEADER, [GOOD[:9] + ["inf"]])
    _expect(p, ["row 1", "column 'qz'", "value inf is not finite"])


def test_quaternion_norm(tmp_path):
    bad = GOOD[:6] + [1.01, 0, 0, 0]
    p = _write_csv(tmp_path / "qn.csv", HEADER, [GOOD, GOOD, bad])
    _expect(p, ["row 3", "qw,qx,qy,qz", "norm is 1.01"])
    small = GOOD[:6] + [1.0004, 0, 0, 0]
    p = _write_csv(tmp_path / "qs.csv", HEADER, [small])
    ds = read_dataset(p)
    np.testing.assert_allclose(ds.quat_wxyz[0], [1, 0, 0, 0], atol=1e-15)


def test_degrees_passed_as_radians(tmp_path):
    p = _write_csv(tmp_path / "deg.csv", HEADER, [GOOD, [10, -45, 120] + GOOD[3:]])
    _expect(p, ["row 2", "column 'q1'", "likely degrees passed as radians", "angle_unit='deg'"])
    # whole-number joints within ±2π are still suspicious when they exceed π
    p = _write_csv(tmp_path / "int.csv", HEADER, [[0, 4, -5] + GOOD[3:], [1, 2, 0] + GOOD[3:]])
    _expect(p, ["column 'q3'", "whole numbers", "degrees"])
    # the same file declared in degrees is fine
    ds = read_dataset(tmp_path / "deg.csv", angle_unit="deg")
    np.testing.assert_allclose(ds.q[1], np.radians([10, -45, 120]))


def test_millimetres_passed_as_metres(tmp_path):
    p = _write_csv(tmp_path / "mm.csv", HEADER, [GOOD, GOOD[:3] + [1200, 300, 900] + GOOD[6:]])
    _expect(p, ["row 2", "column 'x,y,z'", "likely millimetres passed as metres", "length_unit='mm'"])
    ds = read_dataset(p, length_unit="mm")  # declared: accepted and scaled
    np.testing.assert_allclose(ds.xyz_m[1], [1.2, 0.3, 0.9])


def test_joint_limits_and_dof(tmp_path):
    rob = load_robot("rx160")
    h = ["q1", "q2", "q3", "q4", "q5", "q6", "x", "y", "z"]
    row = [0, 0, 0, 0, 0, 0, 1, 0, 1]
    p = _write_csv(tmp_path / "lim.csv", h, [row, row[:4] + [2.2] + row[5:]])  # q5 max is 120 deg
    _expect(p, ["row 2", "column 'q5'", "outside the limits", "126.05", "[-105, 120] deg", "rx160"], robot=rob)
    p = _write_csv(tmp_path / "dof5.csv", h[:5] + h[6:], [row[:5] + row[6:]])
    _expect(p, ["missing column(s) q6"], robot=rob)
    p = _write_csv(tmp_path / "dof7.csv", h[:6] + ["q7"] + h[6:], [row[:6] + [0] + row[6:]])
    _expect(p, ["q1..q7", "has 6 joints"], robot=rob)
    # validate() on an in-memory dataset names the description
    ds = Dataset(q=np.zeros((2, 5)), xyz_m=np.zeros((2, 3)), source="mem")
    with pytest.raises(DatasetError, match="mem: 5 joint column"):
        validate(ds, rob)


def test_empty_files_and_bad_units(tmp_path):
    (tmp_path / "empty.csv").write_text("")
    _expect(tmp_path / "empty.csv", ["empty"])
    p = _write_csv(tmp_path / "header_only.csv", HEADER, [])
    _expect(p, ["no data rows"])
    _expect(tmp_path / "nope.csv", ["file not found"])
    p = _write_csv(tmp_path / "ok.csv", HEADER, [GOOD])
    _expect(p, ["length_unit must be one of"], length_unit="cm")
    _expect(p, ["angle_unit must be one of"], angle_unit="grad")
    p = _write_csv(tmp_path / "ragged.csv", HEADER, [GOOD, GOOD[:-1]])
    _expect(p, ["row 2", "9 cells", "header has 10"])
    (tmp_path / "semi.csv").write_text("q1;x;y;z\n0;0;0;0\n")
    _expect(tmp_path / "semi.csv", ["';'-separated", "hykin import table semi.csv --suggest"])
    # with decimal commas the rows split on the commas: still named as a ';' file, not a ragged row
    (tmp_path / "eu.csv").write_text("q1 [deg];x [mm];y [mm];z [mm]\n12,5;100,25;-3,5;410,0\n")
    _expect(tmp_path / "eu.csv", ["';'-separated", "hykin import table eu.csv --suggest"])
    (tmp_path / "eu_ragged.csv").write_text("q1,x,y,z\n12,5,100,25,-3,5,410,0\n")  # a comma file: the row error
    _expect(tmp_path / "eu_ragged.csv", ["row 1", "8 cells", "header has 4"])
    (tmp_path / "tab.csv").write_text("q1\tx\ty\tz\n0\t0\t0\t0\n")
    _expect(tmp_path / "tab.csv", ["tab-separated", "name it .tsv"])
    (tmp_path / "tab.tsv").write_text("q1\tx\ty\tz\n0\t0\t0\t0\n")
    assert read_dataset(tmp_path / "tab.tsv").q.shape == (1, 1)
    # the columns in another case: refused (the format's names are lower-case), saying so
    p = _write_csv(tmp_path / "upper.csv", [h.upper() for h in HEADER], [GOOD])
    _expect(p, ["no joint columns", "column names are lower-case: the file has 'Q1' for 'q1'"])
    p = _write_csv(tmp_path / "upper_xyz.csv", [h.upper() if h in "xyz" else h for h in HEADER], [GOOD])
    _expect(p, ["missing column(s) x, y, z", "'X' for 'x'"])
    with pytest.raises(DatasetError, match="empty"):
        validate(Dataset(q=np.zeros((0, 6)), xyz_m=np.zeros((0, 3)), source="nothing"))


def test_parquet_errors_name_column(tmp_path):
    pa = pytest.importorskip("pyarrow")
    import pyarrow.parquet as pq

    t = pa.table({"q1": [0.1, None], "x": [0.0, 0.1], "y": [0.0, 0.0], "z": [0.0, 0.0]})
    pq.write_table(t, tmp_path / "null.parquet")
    _expect(tmp_path / "null.parquet", ["row 2", "column 'q1'", "null"])
    t = pa.table({"q1": ["0.1", "x1"], "x": [0.0, 0.1], "y": [0.0, 0.0], "z": [0.0, 0.0]})
    pq.write_table(t, tmp_path / "str.parquet")
    _expect(tmp_path / "str.parquet", ["row 2", "column 'q1'", "'x1' is not a number"])


# --------------------------------------------------------------------------- splits and hash


def test_split_disjoint_complete_and_reproducible():
    ds = _random_dataset(101)
    parts = split(ds, (0.8, 0.1, 0.1), seed=3)
    sizes = [len(p) for p in parts]
    assert sizes == [81, 10, 10]
    ids = np.concatenate([p.extra["timestamp"] for p in parts])
    assert np.array_equal(np.sort(ids), np.arange(101.0))  # disjoint and complete
    again = split(ds, (0.8, 0.1, 0.1), seed=3)
    assert all(np.array_equal(a.q, b.q) for a, b in zip(parts, again))
    other = split(ds, (0.8, 0.1, 0.1), seed=4)
    assert not np.array_equal(parts[1].q, other[1].q)
    with pytest.raises(DatasetError, match="sum to 1"):
        split(ds, (0.5, 0.1))


def test_grouped_split_keeps_groups_together():
    ds = _random_dataset(300)
    rng = np.random.default_rng(1)
    ds.extra["goal_id"] = rng.integers(0, 60, 300)
    parts = split(ds, (0.6, 0.2, 0.2), seed=0, group="goal_id")
    ids = np.concatenate([p.extra["timestamp"] for p in parts])
    assert np.array_equal(np.sort(ids), np.arange(300.0))
    groups = [set(p.extra["goal_id"].tolist()) for p in parts]
    assert not (groups[0] & groups[1]) and not (groups[0] & groups[2]) and not (groups[1] & groups[2])
    frac = np.array([len(p) for p in parts]) / 300
    np.testing.assert_allclose(frac, [0.6, 0.2, 0.2], atol=0.08)
    with pytest.raises(DatasetError, match="no extra column 'nope'"):
        split(ds, group="nope")


def test_hash_depends_on_poses_only():
    ds = _random_dataset(20)
    h = dataset_hash(ds)
    assert len(h) == 64 and h == dataset_hash(ds.subset(np.arange(20)))
    ds2 = ds.subset(np.arange(20))
    ds2.extra["temperature"] += 1
    assert dataset_hash(ds2) == h
    ds2.q[3, 2] += 1e-12
    assert dataset_hash(ds2) != h
    assert dataset_hash(_random_dataset(20, orientation=False)) != h


# --------------------------------------------------------------------------- joints-only / poses-only files (CLI fk, ik)


def test_read_joints_and_poses(tmp_path):
    from hykin.io.dataset_files import read_joints, read_poses

    ds = _random_dataset(8)
    p = tmp_path / "full.csv"
    write_dataset(ds, p, length_unit="mm", angle_unit="deg")
    q, extra = read_joints(p, dof=6, angle_unit="deg")
    np.testing.assert_allclose(q, ds.q, atol=1e-14)
    assert set(extra) == {"temperature", "timestamp"}  # pose columns are not extras
    T, has_rot = read_poses(p, length_unit="mm")
    assert has_rot
    np.testing.assert_allclose(T, ds.poses(), atol=1e-14)
    # joints-only file; degrees declared as radians are caught
    _write_csv(tmp_path / "j.csv", ["q1", "q2"], [[10, 20], [30, 40]])
    with pytest.raises(DatasetError, match=r"row 1 .*column 'q1'.*degrees"):
        read_joints(tmp_path / "j.csv")
    q, _ = read_joints(tmp_path / "j.csv", angle_unit="deg")
    np.testing.assert_allclose(q, np.radians([[10, 20], [30, 40]]))
    # position-only targets
    _write_csv(tmp_path / "t.csv", ["x", "y", "z"], [[0.5, 0, 0.5]])
    T, has_rot = read_poses(tmp_path / "t.csv")
    assert not has_rot and np.array_equal(T[0, :3, :3], np.eye(3)) and T[0, 0, 3] == 0.5
    with pytest.raises(DatasetError, match="missing column"):
        read_poses(tmp_path / "j.csv")
    with pytest.raises(DatasetError, match="no joint columns"):
        read_joints(tmp_path / "t.csv")


def test_further_reflectors_follow_the_length_unit(tmp_path):
    """x2,y2,z2 are lengths like x,y,z: written and read in the declared unit, metres in memory."""
    rng = np.random.default_rng(3)
    ds = Dataset(q=rng.normal(size=(6, 6)), xyz_m=rng.normal(size=(6, 3)),
                 extra={"x2": rng.normal(size=6), "y2": rng.normal(size=6), "z2": rng.normal(size=6),
                        "temperature_c": np.full(6, 21.5)})
    p = tmp_path / "mm.csv"
    write_dataset(ds, p, length_unit="mm")
    with open(p) as f:
        head = f.readline().strip().split(",")
        row = [float(v) for v in f.readline().split(",")]
    assert row[head.index("x2")] == pytest.approx(ds.extra["x2"][0] * 1e3, rel=1e-12)
    assert row[head.index("temperature_c")] == 21.5  # not a length: as is
    back = read_dataset(p, length_unit="mm")
    np.testing.assert_allclose(back.extra["y2"], ds.extra["y2"], rtol=1e-12)
    np.testing.assert_allclose(back.extra["temperature_c"], 21.5)


def test_a_file_without_header_line_is_named_so(tmp_path):
    """Probe report s40: the first row's numbers were listed as the "found" columns, nothing more."""
    p = tmp_path / "noheader.csv"
    p.write_text("\n".join(",".join(map(str, r)) for r in [[0.11, -0.2, 0.3, 0.5, 0.15, 0.4, 0.999, 0.01, 0.02, 0.03], GOOD]) + "\n")
    e = _expect(p, ["no joint columns", "the file has no header line"])
    assert "lower-case" not in str(e)
    p.write_text("\n".join(",".join(map(str, r)) for r in [[0.1, 0.1] + GOOD[2:], GOOD]) + "\n")
    _expect(p, ["appears twice in the header", "the file has no header line"])
