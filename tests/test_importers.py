"""Importers of the real datasets, rigid registration and three-SMR poses (hykin.importers).

The real-data tests read ``shared/data`` next to the repository (override with the environment
variable ``HYKIN_SHARED_DATA``) and skip with a message when it is absent.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import pytest

from hykin.geometry import se3
from hykin.io.dataset import DatasetError
from hykin.kinematics.fk import fk
from hykin.measure.importers import (
    IPA_BASE_LINK_FROM_DH,
    import_ipa_series,
    import_three_smr,
    import_ur5,
    ipa_nominal_robot,
    register_rigid,
    registration_errors,
    ur5_robot_for_dataset,
)

DATA = Path(os.environ.get("HYKIN_SHARED_DATA", Path(__file__).resolve().parents[2] / "shared" / "data"))
UR5_DIR = DATA / "serial-robots-ur5" / "UR5"
IPA_DIR = DATA / "ipa-robot-accuracy"
needs_ur5 = pytest.mark.skipif(not UR5_DIR.is_dir(), reason=f"real UR5 data not found at {UR5_DIR} (set HYKIN_SHARED_DATA)")
needs_ipa = pytest.mark.skipif(not IPA_DIR.is_dir(), reason=f"real UR10 data not found at {IPA_DIR} (set HYKIN_SHARED_DATA)")


def _random_poses(n, rng, spread=1.0):
    return se3.make_transform(se3.rotvec_to_matrix(rng.normal(size=(n, 3))), rng.uniform(-spread, spread, (n, 3)))


# --------------------------------------------------------------------------- synthetic


@pytest.mark.parametrize("use_orientation", [True, False])
def test_register_rigid_recovers_frames(use_orientation):
    rng = np.random.default_rng(1)
    rob = ipa_nominal_robot()
    q = rob.random_joints(60, rng)
    T_model = fk(rob, q)
    B = se3.make_transform(se3.rotvec_to_matrix([0.3, -2.0, 1.0]), [1.5, -3.0, 0.2])  # tracker far away
    E = se3.rotz(math.pi) @ se3.make_transform(se3.rotvec_to_matrix([0.01, -0.02, 0.03]), [0.001, -0.002, -0.016])
    if not use_orientation:
        E[:3, :3] = np.eye(3)
    T_meas = B @ T_model @ E
    T_meas[:, :3, 3] += rng.normal(scale=1e-6, size=(60, 3))  # 1 µm noise
    Bf, Ef = register_rigid(T_model, T_meas, use_orientation=use_orientation)
    pos, ang = registration_errors(T_model, T_meas, Bf, Ef)
    assert pos.max() < 0.01 and ang.max() < 1e-3
    np.testing.assert_allclose(Bf, B, atol=1e-5)
    np.testing.assert_allclose(Ef, E, atol=1e-5)


def test_three_smr_import(tmp_path):
    rng = np.random.default_rng(2)
    rob = ipa_nominal_robot()
    q = rob.random_joints(25, rng)
    T = fk(rob, q)
    nest = np.array([[0.06, 0.0, 0.01], [-0.02, 0.04, 0.0], [-0.03, -0.05, 0.02]])  # m, tool frame, scalene
    P = np.einsum("nij,kj->nki", T[:, :3, :3], nest) + T[:, None, :3, 3]  # (N, 3, 3) m
    P_mm = P.reshape(-1, 9) * 1e3 + rng.normal(scale=1e-4, size=(25, 9))  # 0.1 µm noise
    header = [f"q{i}" for i in range(1, 7)] + [f"p{k}{a}" for k in (1, 2, 3) for a in "xyz"] + ["temp"]
    rows = np.hstack([np.degrees(q), P_mm, np.full((25, 1), 21.5)])
    path = tmp_path / "smr.csv"
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    ds = import_three_smr(path, nest, length_unit="mm", angle_unit="deg", robot=rob)
    assert len(ds) == 25 and ds.has_orientation and "temp" in ds.extra
    pos, ang = se3.pose_error(ds.poses(), T)
    assert pos.max() < 1e-3 and ang.max() < 1e-3
    assert ds.extra["smr_fit_rms_m"].max() < 1e-6
    # swapped reflectors no longer fit the nest: error names the row
    rows[4, 6:9], rows[4, 9:12] = rows[4, 9:12].copy(), rows[4, 6:9].copy()
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")
    with pytest.raises(DatasetError, match=r"row 5 .*do not fit the nest"):
        import_three_smr(path, nest, length_unit="mm", angle_unit="deg")
    with pytest.raises(ValueError, match="collinear"):
        import_three_smr(path, np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0.0]]), length_unit="mm", angle_unit="deg")


def test_importer_errors(tmp_path):
    p = tmp_path / "bad_ur5.csv"
    p.write_text("x_t,y_t\n1,2\n")
    with pytest.raises(DatasetError, match="missing column.*z_t"):
        import_ur5(p)
    with pytest.raises(DatasetError, match="no such series"):
        import_ipa_series(tmp_path / "Series_Z")


# --------------------------------------------------------------------------- UR5 real data


@needs_ur5
@pytest.mark.parametrize("name, rows", [("grid", 1000), ("random", 20)])
def test_ur5_import_and_nominal_reproduction(name, rows):
    ds = import_ur5(UR5_DIR / f"3D_UR5_uncalibrated_{name}_cleaned.csv")
    assert len(ds) == rows and ds.dof == 6 and not ds.has_orientation
    xt = np.stack([ds.extra[k] for k in ("x_t_m", "y_t_m", "z_t_m")], axis=1)
    err_mm = np.linalg.norm(fk(ur5_robot_for_dataset(), ds.q)[:, :3, 3] - xt, axis=1) * 1e3
    assert err_mm.max() < 0.02  # measured: mean 0.0011, max 0.0039 mm
    # data-sheet d5 = 94.65 mm is off x_t by a near-constant 0.09 mm
    err_sheet = np.linalg.norm(fk(ur5_robot_for_dataset(match_xt=False), ds.q)[:, :3, 3] - xt, axis=1) * 1e3
    assert 0.08 < err_sheet.mean() < 0.10
    # uncalibrated error = |x_dif| (published 2.566 mm on the random set)
    unc = np.linalg.norm(ds.xyz_m - xt, axis=1) * 1e3
    if name == "random":
        assert abs(unc.mean() - 2.566) < 0.005


# --------------------------------------------------------------------------- UR10 real data


def _goal_poses(ds):
    xyz = np.stack([ds.extra[k] for k in ("goal_x_m", "goal_y_m", "goal_z_m")], axis=1)
    rpy = np.stack([ds.extra[k] for k in ("goal_roll_rad", "goal_pitch_rad", "goal_yaw_rad")], axis=1)
    return se3.xyzrpy_to_transform(xyz, rpy)


@needs_ipa
def test_ipa_series_b_import_goal_and_registration():
    ds = import_ipa_series(IPA_DIR / "Series_B")
    assert len(ds) == 1495 and ds.dof == 6 and ds.has_orientation
    assert ds.meta["frame"] == "tracker"
    assert ds.extra["goal_id"].max() + 1 == 757  # distinct goal poses
    assert np.isnan(ds.extra["timestamp_s"]).all()  # mangled by a spreadsheet
    assert ds.extra["timestamp_raw"][0] == "2,02011E+13"
    assert 0.01 < np.median(ds.extra["std_x_mm"]) < 0.05
    # README fact: Goal = Rz(pi) · FK_DH(q) · Trans(0,0,0.109) · Rz(90°), median 0.09 mm
    pos, ang = se3.pose_error(_goal_poses(ds), IPA_BASE_LINK_FROM_DH @ fk(ipa_nominal_robot(), ds.q))
    assert np.median(pos) < 0.15 and np.median(ang) < 0.2
    # first row by hand: 383.76294 mm, -90.179302 deg (decimal comma)
    assert ds.xyz_m[0, 0] == pytest.approx(0.38376294, abs=1e-12)
    # rigid base + tool registration of the nominal model: ≈ 1.0 mm, ≈ 0.08 deg left
    reg = import_ipa_series(IPA_DIR / "Series_B", register_to=ipa_nominal_robot())
    assert reg.meta["frame"] == "robot base"
    assert 0.9 < reg.meta["registration_pos_mean_mm"] < 1.15
    assert 0.05 < reg.meta["registration_ang_mean_deg"] < 0.15
    pos, ang = se3.pose_error(reg.poses(), fk(ipa_nominal_robot(), reg.q))
    assert 0.9 < pos.mean() < 1.15 and ang.mean() < 0.15
    # the measurements are rigid-equivalent: same tracker-frame poses after mapping back
    back = reg.meta["T_base"] @ reg.poses() @ reg.meta["T_tool"]
    np.testing.assert_allclose(back, ds.poses(), atol=1e-9)


@needs_ipa
def test_ipa_series_a_import_goal_and_registration():
    ds = import_ipa_series(IPA_DIR / "Series_A" / "measurements_grid.csv")
    assert len(ds) == 11911
    t = ds.extra["timestamp_s"]
    assert np.isfinite(t).all()
    # 20200714163904 -> 2020-07-14T16:39:04 (clock taken as UTC)
    assert t[0] == float(np.datetime64("2020-07-14T16:39:04", "s").astype(np.int64))
    assert 50 < (t.max() - t.min()) / 3600 < 200  # "measured over ~100 h"
    assert 22.5 < ds.extra["temperature_c"].min() and ds.extra["temperature_c"].max() < 24.0
    pos, _ = se3.pose_error(_goal_poses(ds), IPA_BASE_LINK_FROM_DH @ fk(ipa_nominal_robot(), ds.q))
    assert np.median(pos) < 0.15
    idx = np.arange(0, len(ds), 4)  # a quarter of the rows keeps the test quick
    reg = import_ipa_series(IPA_DIR / "Series_A", register_to=ipa_nominal_robot(), register_idx=idx)
    assert 0.65 < reg.meta["registration_pos_mean_mm"] < 0.85  # README: ≈ 0.75 mm
    assert 0.05 < reg.meta["registration_ang_mean_deg"] < 0.15  # README: ≈ 0.1 deg


# --------------------------------------------------------------------------- fixed layouts refuse what they do not understand


def test_ur5_importer_refuses_a_seventh_joint(tmp_path):
    head = ["step_order", "x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{i}" for i in range(1, 8)]
    p = tmp_path / "seven.csv"
    p.write_text(",".join(head) + "\n" + ",".join(["0", "400", "10", "300", "1", "2", "3"] + ["10"] * 7) + "\n")
    with pytest.raises(DatasetError, match=r"column 'joint_7': a further joint.*exactly 6 joints.*hykin import table") as e:
        import_ur5(p)
    assert e.value.column == "joint_7"
    # the same file without joint_7 imports: the refusal is about the column, not the values
    p.write_text(",".join(head[:-1]) + "\n" + ",".join(["0", "400", "10", "300", "1", "2", "3"] + ["10"] * 6) + "\n")
    ds = import_ur5(p)
    assert ds.dof == 6 and ds.xyz_m[0] == pytest.approx([0.401, 0.012, 0.303], abs=1e-12)
    p.write_text(",".join(head[:-1] + ["x2"]) + "\n" + ",".join(["0", "400", "10", "300", "1", "2", "3"] + ["10"] * 6 + ["5"]) + "\n")
    with pytest.raises(DatasetError, match=r"column 'x2': not part of the serial-robots-ur5 layout"):
        import_ur5(p)


def test_ipa_importer_refuses_unknown_columns(tmp_path):
    head = (["Timestamp", "Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw"]
            + ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
            + ["measurement_temperature"] + [f"measurement_{c}" for c in ("x", "y", "z", "rx", "ry", "rz")])
    row = ["20200714163904", "0,3", "0", "1,4", "1,5", "1,5", "1,5"] + ["0,1"] * 6 + ["23,5", "2361,9", "-1368,5", "119,3", "-90,4", "-59,8", "-90,8"]
    d = tmp_path / "Series_X"
    d.mkdir()
    f = d / "measurements_x.csv"
    f.write_text(";".join(head) + "\n" + ";".join(row) + "\n")
    assert len(import_ipa_series(d)) == 1
    f.write_text(";".join(head + ["wrist_4_joint"]) + "\n" + ";".join(row + ["0,2"]) + "\n")
    with pytest.raises(DatasetError, match=r"column 'wrist_4_joint': a further joint.*hykin import table"):
        import_ipa_series(d)


@needs_ipa
def test_ipa_series_b_through_the_generic_table_importer(tmp_path):
    """The generic importer with a mapping reproduces the dedicated ipa importer on real data."""
    from hykin.measure.table_import import import_table

    mp = tmp_path / "ipa.toml"
    mp.write_text(
        'delimiter = ";"\ndecimal = ","\n'
        'joints = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]\n'
        'position = ["measurement_x", "measurement_y", "measurement_z"]\nlength_unit = "mm"\n'
        'euler = ["measurement_rx", "measurement_ry", "measurement_rz"]\neuler_convention = "XYZ"\neuler_unit = "deg"\n'
        'temperature = "measurement_temperature"\n')
    ref = import_ipa_series(IPA_DIR / "Series_B")
    ds = import_table(IPA_DIR / "Series_B" / "measurements_joint_configurations.csv", mp)
    np.testing.assert_array_equal(ds.q, ref.q)
    np.testing.assert_allclose(ds.xyz_m, ref.xyz_m, rtol=0, atol=1e-15)
    np.testing.assert_allclose(ds.quat_wxyz, ref.quat_wxyz, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ds.extra["temperature_c"], ref.extra["temperature_c"])
