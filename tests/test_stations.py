"""Several stations / tools in one dataset (issue 24; hykin.calibration.stations, hybrid.stations).

Virtual data of our own: a 6R DH arm (not a preset), a true robot with geometric deviations, simulated
by hykin.sim in its base frame, then measured from two stations 5 m apart and turned (the measured
pose is ``B_s · T``). The true frames are known, so a fit "given the true frames by hand" is the same
data transformed into the robot base by the test itself.
"""

from __future__ import annotations

import numpy as np
import pytest

from hykin.calibration.calibrate import CalibrationError, calibrate
from hykin.calibration.stations import StationFrames, row_groups, to_reference
from hykin.geometry import se3
from hykin.io.dataset import Dataset, DatasetError, row_labels
from hykin.kinematics.robot import Robot
from hykin.sim.simulate import VirtualRobot, geometric_deviation, simulate

D2R = np.pi / 180


def arm6() -> Robot:
    return Robot(name="arm6-stations", convention="dh",
                 a_m=[0.12, 0.55, 0.10, 0.0, 0.0, 0.0], alpha_rad=np.array([-90, 0, -90, 90, -90, 0]) * D2R,
                 d_m=[0.45, 0.0, 0.0, 0.50, 0.0, 0.09], theta_rad=[0, -np.pi / 2, 0, 0, 0, 0],
                 lower=np.array([-170, -120, -150, -180, -120, -350]) * D2R,
                 upper=np.array([170, 120, 150, 180, 120, 350]) * D2R, tool=se3.trans(0.01, 0.02, 0.12))


#: station frames (station -> robot base): 5 m apart and turned (A by 40° about z, B by ~138° and tilted)
STATIONS = {
    "A": se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, 0.7])), np.array([2.0, 0.0, 0.5])),
    "B": se3.make_transform(se3.rotvec_to_matrix(np.array([0.05, -0.03, 2.4])), np.array([-1.0, 4.0, 0.7])),
}


def campaign(n=300, seed=0, orientation=True, noise_m=20e-6, tools=None):
    """(nominal, data with a station column, the same data in the robot base frame, station of each row).
    ``tools``: ``{label: flange -> TCP}`` alternating over the rows (a ``tool`` column) or None."""
    rng = np.random.default_rng(seed)
    nom = arm6()
    truth = geometric_deviation(nom, rng, 0.5e-3, 0.5e-3, 0, 0).copy(base=np.eye(4))
    q = nom.random_joints(n, rng)
    extra = {}
    if tools is None:
        vr = VirtualRobot("v", nom, truth, noise_position_m=noise_m, noise_orientation_rad=noise_m / 0.5)
        T = simulate(vr, q, rng=rng).poses()
    else:
        labels = list(tools)
        which = np.arange(n) % len(labels)
        T = np.empty((n, 4, 4))
        for k, lab in enumerate(labels):
            vr = VirtualRobot("v", nom, truth.copy(tool=tools[lab]), noise_position_m=noise_m, noise_orientation_rad=noise_m / 0.5)
            T[which == k] = simulate(vr, q[which == k], rng=rng).poses()
        extra["tool"] = np.array(labels)[which]
    st = np.where(np.arange(n) % 5 < 3, "A", "B")  # A: 60 % of the rows (the reference)
    Tm = np.stack([STATIONS[s] for s in st]) @ T
    data = Dataset.from_poses(q, Tm, extra={"station": st, **extra}, orientation=orientation, source="two-stations.csv")
    base = Dataset.from_poses(q, T, extra=dict(extra), orientation=orientation, source="base-frame.csv")
    return nom, data, base, st


def relative(fr: StationFrames, a: str, b: str) -> np.ndarray:
    """``B_b · B_a⁻¹``: station a's frame -> station b's frame (free of the base/DH gauge)."""
    return fr.base_of(b) @ np.linalg.inv(fr.base_of(a))


@pytest.mark.parametrize("orientation", [False, True])
def test_bundle_matches_true_frames_by_hand(orientation):
    nom, data, base, _ = campaign(orientation=orientation)
    res = calibrate(nom, data)
    ref = calibrate(nom, base)  # the same rows, transformed into the robot base with the true frames
    fr = res.station_frames
    assert fr.station_labels == ("A", "B")  # reference: the station with the most rows
    assert res.after["pos_rms_mm"] <= 1.2 * ref.after["pos_rms_mm"]
    true_rel = STATIONS["B"] @ np.linalg.inv(STATIONS["A"])
    pe, ae = se3.pose_error(relative(fr, "A", "B")[None], true_rel[None])
    assert pe[0] < 0.1 and ae[0] < 0.005  # mm, deg
    assert np.allclose(fr.station_bases[0], res.robot.base)
    assert {f"station[B].{f}" for f in ("x", "y", "z", "rx", "ry", "rz")} <= set(res.identified_names)
    # the data mapped into the reference frame by the fitted frames agree with the model of the robot
    T = to_reference(data, fr).poses()
    from hykin.kinematics.classical import classical_fk

    err = np.linalg.norm(T[:, :3, 3] - classical_fk(res.robot, data.q)[:, :3, 3], axis=1)
    assert np.sqrt(np.mean(err**2)) * 1e3 == pytest.approx(res.after["pos_rms_mm"], rel=1e-3)


def test_one_row_station_refused():
    nom, data, _, st = campaign(n=200, orientation=False)
    lab = st.copy()
    lab[7] = "C"
    d = Dataset(q=data.q, xyz_m=data.xyz_m, extra={"station": lab}, source="one-row.csv")
    with pytest.raises(CalibrationError) as e:
        calibrate(nom, d)
    msg = str(e.value)
    assert "\n" not in msg and "station 'C' has 1 row" in msg and "at least 3" in msg and "one-row.csv" in msg
    # 6-D rows: one row fixes the frame exactly (no redundancy); two are needed
    d6 = Dataset(q=data.q, xyz_m=data.xyz_m, quat_wxyz=campaign(n=200)[1].quat_wxyz, extra={"station": lab})
    with pytest.raises(CalibrationError, match="station 'C' has 1 row; .* at least 2 6-D rows"):
        calibrate(nom, d6)


def test_collinear_station_refused_and_three_spread_points_accepted():
    nom, data, _, st = campaign(n=200, orientation=False)
    g = row_groups(Dataset(q=data.q, xyz_m=data.xyz_m, extra={"station": st}), len(st))
    from hykin.calibration.stations import check_groups

    xyz = data.xyz_m.copy()
    lab = st.copy()
    lab[:3] = "C"
    xyz[:3] = np.array([1.0, 2.0, 0.5]) + np.outer([0.0, 0.3, 0.7], [1.0, 0.5, 0.0])  # three points on a line
    g = row_groups(Dataset(q=data.q, xyz_m=xyz, extra={"station": lab}, source="line.csv"), len(lab))
    with pytest.raises(CalibrationError, match="station 'C' has 3 rows but its points lie on a line"):
        check_groups(g, xyz, position_only=True)
    xyz[2] += [0.0, 0.0, 0.2]  # off the line: a frame is fixed
    check_groups(g, xyz, position_only=True)


def test_wrong_station_detected():
    """Half of station B's rows labelled A (their frames swapped): no robot explains that; refused."""
    nom, data, _, st = campaign(n=150, orientation=False)
    lab = st.copy()
    b_rows = np.flatnonzero(st == "B")
    lab[b_rows[::2]] = "A"
    with pytest.raises(CalibrationError, match="wrong station/tool label on some rows \\(RMS per station: A .* mm, B .* mm\\)"):
        calibrate(nom, Dataset(q=data.q, xyz_m=data.xyz_m, extra={"station": lab}, source="swapped.csv"))


@pytest.mark.parametrize("orientation", [False, True])
def test_tool_column_two_tools(orientation):
    tools = {"T1": se3.trans(0.01, 0.02, 0.12), "T2": se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.3, 0.0])),
                                                                          np.array([0.06, -0.03, 0.18]))}
    nom, data, base, _ = campaign(n=300, orientation=orientation, tools=tools)
    res = calibrate(nom, data)
    fr = res.station_frames
    assert set(fr.tool_labels) == {"T1", "T2"} and np.allclose(fr.tool_frames[0], res.robot.tool)
    E = dict(zip(fr.tool_labels, fr.tool_frames))
    rel, true_rel = np.linalg.inv(E["T1"]) @ E["T2"], np.linalg.inv(tools["T1"]) @ tools["T2"]
    assert np.linalg.norm(rel[:3, 3] - true_rel[:3, 3]) * 1e3 < 0.1  # mm
    if orientation:
        assert se3.pose_error(rel[None], true_rel[None])[1][0] < 0.01  # deg
    assert res.after["pos_rms_mm"] < 0.06  # noise 20 µm per axis: 35 µm RMS
    # one tool with one row is refused like a station
    lab = data.extra["tool"].copy()
    lab[5] = "T3"
    d = Dataset(q=data.q, xyz_m=data.xyz_m, quat_wxyz=data.quat_wxyz, extra={"station": data.extra["station"], "tool": lab})
    with pytest.raises(CalibrationError, match="tool 'T3' has 1 row"):
        calibrate(nom, d)


def test_labels_any_type_and_reference_choice():
    ds = Dataset(q=np.zeros((5, 1)), xyz_m=np.zeros((5, 3)), extra={"station": np.array([2.0, 1.0, 1.0, 2.0, 1.0])})
    assert row_labels(ds, "station").tolist() == ["2", "1", "1", "2", "1"]
    g = row_groups(ds, 5)
    assert g.station_labels == ("1", "2") and g.station.tolist() == [1, 0, 0, 1, 0]  # most rows first
    tie = Dataset(q=np.zeros((4, 1)), xyz_m=np.zeros((4, 3)), extra={"station": np.array(["east", "west", "west", "east"])})
    assert row_groups(tie, 4).station_labels == ("east", "west")  # tie: the first to appear
    one = Dataset(q=np.zeros((2, 1)), xyz_m=np.zeros((2, 3)), extra={"station": np.array(["x", "x"])})
    assert row_groups(one, 2) is None  # one station: the plain case
    bad = Dataset(q=np.zeros((2, 1)), xyz_m=np.zeros((2, 3)), extra={"station": np.array(["x", " "])}, source="f.csv")
    with pytest.raises(DatasetError, match="f.csv, row 2 .*column 'station': empty station label"):
        row_labels(bad, "station")


def test_station_column_read_from_csv_and_parquet(tmp_path):
    from hykin.io.dataset_files import read_dataset, write_dataset

    _, data, _, st = campaign(n=20, orientation=False)
    for suffix in ("csv", "parquet"):
        p = tmp_path / f"d.{suffix}"
        write_dataset(data, p)
        back = read_dataset(p)
        assert row_labels(back, "station").tolist() == st.tolist()


def test_to_reference_unknown_station_names_row():
    _, data, _, st = campaign(n=20, orientation=True)
    fr = StationFrames(("A", "B"), np.stack([STATIONS["A"], STATIONS["B"]]), ("-",), np.eye(4)[None])
    lab = st.copy()
    lab[4] = "Z"
    d = Dataset(q=data.q, xyz_m=data.xyz_m, quat_wxyz=data.quat_wxyz, extra={"station": lab}, source="t.csv")
    with pytest.raises(DatasetError, match="t.csv, row 5 .*column 'station': station 'Z' is not in the model"):
        to_reference(d, fr)
    # known stations: every row lands in station A's frame (checked against the frames by hand)
    T = to_reference(data, fr).poses()
    Tb = np.stack([np.linalg.inv(STATIONS[s]) for s in st]) @ data.poses()  # robot base frame
    assert np.allclose(T, STATIONS["A"] @ Tb, atol=1e-12)


@pytest.mark.slow
def test_cli_fit_stations_vs_true_frames_by_hand_and_model_file(tmp_path, capsys):
    """``hykin fit`` on two-station data (no station option: the column is enough) against the same fit
    on the data transformed by hand into the robot base with the true frames; held-out error within
    1.2x. Then the model file keeps the frames: evaluate per row's station, fk --station, register of
    a series from a new station C."""
    import json

    from cli_run import run

    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset_files import read_dataset, write_dataset
    from hykin.io.robot_toml import save_robot_toml

    nom, data, base, st = campaign(n=700, orientation=False, seed=3)
    save_robot_toml(nom, tmp_path / "arm.toml")
    tr, te = np.arange(500), np.arange(500, 700)
    for name, d in (("train", data.subset(tr)), ("test", data.subset(te)), ("train_hand", base.subset(tr)),
                    ("test_hand", base.subset(te))):
        write_dataset(d, tmp_path / f"{name}.csv")
    budget = ["--max-minutes", "0.3"]  # the same budget for both fits (a test-time limit, not a station option)
    err = {}
    for tag, tr_f, te_f in (("bundle", "train", "test"), ("hand", "train_hand", "test_hand")):
        code, out, _ = run(["fit", tmp_path / "arm.toml", tmp_path / f"{tr_f}.csv", "-o", tmp_path / f"{tag}.hykin", *budget], capsys)
        assert code == 0, out
        code, out, _ = run(["evaluate", tmp_path / f"{tag}.hykin", tmp_path / f"{te_f}.csv", "--json"], capsys)
        assert code == 0
        err[tag] = json.loads(out)
    h_b, h_h = (err[k]["stats"]["hybrid"]["pos_mean_mm"] for k in ("bundle", "hand"))
    assert h_b <= 1.2 * h_h, (h_b, h_h)
    m = HybridModel.load(tmp_path / "bundle.hykin")
    assert m.station_frames_.station_labels == ("A", "B")
    true_rel = STATIONS["B"] @ np.linalg.inv(STATIONS["A"])
    assert se3.pose_error(relative(m.station_frames_, "A", "B")[None], true_rel[None])[0][0] < 0.1
    # fk in station B's frame reproduces station B's measured test rows
    write_dataset(Dataset(q=data.q[te], xyz_m=np.zeros((len(te), 3))), tmp_path / "joints.csv")
    code, out, _ = run(["fk", tmp_path / "bundle.hykin", tmp_path / "joints.csv", "-o", tmp_path / "fkB.csv", "--station", "B"], capsys)
    assert code == 0 and "(frame of station 'B')" in out
    fkB = read_dataset(tmp_path / "fkB.csv")
    rows_b = st[te] == "B"
    assert np.mean(np.linalg.norm(fkB.xyz_m[rows_b] - data.xyz_m[te][rows_b], axis=1)) * 1e3 < 2 * h_b + 0.02
    # ik of station B's measured positions, by option and by the targets' station column (probe report s40:
    # ik had neither; every target in B's frame was "out of reach"): the model's pose in B's frame at the
    # returned joints is the target
    from hykin.hybrid.stations import station_transform

    kb = te[rows_b][:8]
    write_dataset(Dataset(q=data.q[kb], xyz_m=data.xyz_m[kb]), tmp_path / "tB.csv")
    write_dataset(Dataset(q=data.q[kb], xyz_m=data.xyz_m[kb], extra={"station": st[kb]}), tmp_path / "tBcol.csv")
    L, _ = station_transform(m, "B")
    for argv in (["--station", "B"], []):
        src = tmp_path / ("tB.csv" if argv else "tBcol.csv")
        code, out, errout = run(["ik", tmp_path / "bundle.hykin", src, "-o", tmp_path / "ikB.csv", "--force",
                                 "--seed-joints", src, *argv], capsys)  # seeds: the measured joints
        assert code == 0 and "(8 solved, 0 failed)" in out, (out, errout)
        q_ik = np.loadtxt(tmp_path / "ikB.csv", delimiter=",", skiprows=1, usecols=range(2, 8))  # q1..q6
        got = (L @ m.predict(q_ik))[:, :3, 3]
        assert np.abs(got - data.xyz_m[kb]).max() < 1e-6
    code, _, errout = run(["fk", tmp_path / "bundle.hykin", tmp_path / "joints.csv", "-o", tmp_path / "fkC.csv", "--station", "C"], capsys)
    assert code != 0 and "station 'C' is not in the model (its stations: A, B)" in errout
    assert not (tmp_path / "fkC.csv").exists()
    # a series from a new station C: register fits its frame; fk --station C then reproduces it
    C = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.02, -1.2])), np.array([3.0, -2.5, 0.3]))
    Tb = base.poses()[te]
    series = Dataset.from_poses(data.q[te], C @ Tb, extra={"station": np.array(["C"] * len(te))}, orientation=False)
    write_dataset(series, tmp_path / "seriesC.csv")
    code, out, errout = run(["register", tmp_path / "bundle.hykin", tmp_path / "seriesC.csv", "-o", tmp_path / "reg.hykin"], capsys)
    assert code == 0, errout
    code, out, _ = run(["fk", tmp_path / "reg.hykin", tmp_path / "joints.csv", "-o", tmp_path / "fkC.csv", "--station", "C"], capsys)
    assert code == 0
    fkC = read_dataset(tmp_path / "fkC.csv")
    assert np.mean(np.linalg.norm(fkC.xyz_m - series.xyz_m, axis=1)) * 1e3 < 2 * h_b + 0.05
    code, out, _ = run(["evaluate", tmp_path / "reg.hykin", tmp_path / "seriesC.csv", "--json"], capsys)
    assert code == 0


def test_plausibility_checks_each_station_and_tool_on_its_own_rows():
    """6-D rows of two turned stations and two tools: no single frame rotation fits them all, each
    station's own rows do (the data checks of fit / read_dataset must not refuse a correct campaign)."""
    from hykin.io.plausibility import PlausibilityError, check_dataset

    tools = {"T1": se3.trans(0.0, 0.0, 0.1), "T2": se3.make_transform(se3.rotvec_to_matrix(np.array([1.2, 0.0, 0.0])),
                                                                       np.array([0.0, 0.05, 0.1]))}
    nom, data, _, _ = campaign(n=120, orientation=True, tools=tools)
    check_dataset(nom, data)
    one = Dataset(q=data.q, xyz_m=data.xyz_m, quat_wxyz=data.quat_wxyz)  # the labels dropped: one frame cannot fit
    with pytest.raises(PlausibilityError, match="orientations do not match"):
        check_dataset(nom, one)


def test_no_calibrate_fits_only_the_further_stations_frames():
    """``fit --no-calibrate``: the robot file stays as is (its base = the reference station's frame);
    the other stations' frames are still fitted, from the nominal model (so to within its errors)."""
    from hykin.hybrid.model import HybridModel
    from hykin.hybrid.stations import fit_station_frames

    nom, data, base, st = campaign(n=200, orientation=False)
    Tm = np.where((st == "A")[:, None, None], base.poses(), STATIONS["B"] @ base.poses())  # A = the robot base
    d = Dataset.from_poses(data.q, Tm, extra={"station": st}, orientation=False)
    fr = fit_station_frames(HybridModel(nom, calibrate=False), d)
    assert np.array_equal(fr.station_bases[0], nom.base)
    pe, ae = se3.pose_error(relative(fr, "A", "B")[None], STATIONS["B"][None])
    assert pe[0] < 3.0 and ae[0] < 0.2  # mm, deg: the nominal geometry is ~1 mm off


def test_cli_calibrate_refuses_one_row_station_in_one_line(tmp_path, capsys):
    from cli_run import run

    from hykin.io.dataset_files import write_dataset
    from hykin.io.robot_toml import save_robot_toml

    nom, data, _, st = campaign(n=120, orientation=False)
    lab = st.astype("<U8")
    lab[-1] = "north"
    write_dataset(Dataset(q=data.q, xyz_m=data.xyz_m, extra={"station": lab}), tmp_path / "d.csv")
    save_robot_toml(nom, tmp_path / "arm.toml")
    code, _, err = run(["calibrate", tmp_path / "arm.toml", tmp_path / "d.csv", "-o", tmp_path / "cal.toml"], capsys)
    assert code != 0 and not (tmp_path / "cal.toml").exists()
    line = err.strip()
    assert "\n" not in line and "station 'north' has 1 row" in line and "d.csv" in line


def test_station_frames_dict_round_trip():
    """What the model file's header holds (JSON) gives back the same frames, bit for bit."""
    import json

    fr = StationFrames(("A", "B", "7"), np.stack([STATIONS["A"], STATIONS["B"], np.eye(4)]), ("T1", "T2"),
                       np.stack([se3.trans(0, 0, 0.1), se3.trans(0.05, 0, 0.1)]))
    back = StationFrames.from_dict(json.loads(json.dumps(fr.to_dict())))
    assert back.station_labels == fr.station_labels and back.tool_labels == fr.tool_labels
    assert np.array_equal(back.station_bases, fr.station_bases) and np.array_equal(back.tool_frames, fr.tool_frames)


def test_registration_adds_station_and_tool_frames():
    """A registration ``T_meas = pre · T_model · post`` of a series from new station C with new tool T9:
    the frames recorded map that series back onto the model (to_reference), the registration frames
    they took over become identity, and a series with two stations is refused in one line."""
    from hykin.calibration.stations import add_frames, series_labels

    robot = arm6().copy(base=STATIONS["A"])
    fr = StationFrames(("A", "B"), np.stack([STATIONS["A"], STATIONS["B"]]), ("T1",), robot.tool[None])
    pre = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.1, 1.0])), np.array([3.0, -1.0, 0.2]))
    post = se3.make_transform(se3.rotvec_to_matrix(np.array([0.2, 0.0, 0.0])), np.array([0.01, 0.0, 0.03]))
    q = robot.random_joints(10, 1)
    from hykin.kinematics.fk import fk

    T_model = fk(robot, q)
    n = len(q)
    series = Dataset.from_poses(q, pre @ T_model @ post, extra={"station": np.array(["C"] * n), "tool": np.array(["T9"] * n)})
    labels = series_labels(series)
    assert labels == ("C", "T9")
    fr2, pre2, post2 = add_frames(fr, labels, pre, post, robot)
    assert fr2.station_labels == ("A", "B", "C") and fr2.tool_labels == ("T1", "T9")
    assert np.array_equal(pre2, np.eye(4)) and np.array_equal(post2, np.eye(4))
    assert np.allclose(to_reference(series, fr2).poses(), T_model, atol=1e-12)
    assert fr.station_labels == ("A", "B")  # the input frames are not changed
    two = Dataset(q=q, xyz_m=np.zeros((n, 3)), extra={"station": np.array(["C", "D"] * (n // 2))}, source="s.csv")
    with pytest.raises(DatasetError, match="s.csv: the series has 2 stations \\(C, D\\); a registration fits one station frame"):
        series_labels(two)


def test_ik_targets_of_another_station_and_tool_are_mapped_into_the_model_frame():
    """``hykin ik --station/--tool`` and the targets' ``station``/``tool`` columns (probe report s40: ik had
    neither; targets in station S2's frame were "out of reach"). Reference: ``fk --station --tool``'s map
    ``L · T · Rt`` inverted; a robot file refuses them."""
    from types import SimpleNamespace

    from hykin.calibration.stations import StationFrames
    from hykin.cli.common import CLIError
    from hykin.cli.query import _targets_in_model_frame
    from hykin.hybrid.stations import station_transform

    B0, B1 = se3.trans(0.1, 0.2, 0.0), se3.trans(3.0, -1.0, 0.5) @ se3.rotz(0.7)
    E0, E1 = se3.trans(0.0, 0.0, 0.1), se3.trans(0.02, 0.0, 0.12) @ se3.rotx(0.3)
    m = SimpleNamespace(station_frames_=StationFrames(("S1", "S2"), np.stack([B0, B1]), ("A", "B"), np.stack([E0, E1])))
    rng = np.random.default_rng(0)
    T_model = se3.xyzrpy_to_transform(rng.uniform(-1, 1, (6, 3)), rng.uniform(-1, 1, (6, 3)))
    L, Rt = station_transform(m, "S2", "B")
    T_file = L @ T_model @ Rt  # what fk --station S2 --tool B writes for those model poses
    got = _targets_in_model_frame(m, T_file, True, {}, "S2", "B", "m.hykin", "t.csv")
    np.testing.assert_allclose(got, T_model, atol=1e-12)
    cols = {"station": np.array(["S2"] * 3 + ["S1"] * 3), "tool": np.array(["B"] * 6)}
    L1, Rt1 = station_transform(m, "S1", "B")
    mixed = np.concatenate([T_file[:3], (L1 @ T_model @ Rt1)[3:]])
    np.testing.assert_allclose(_targets_in_model_frame(m, mixed, True, cols, None, None, "m", "t"), T_model, atol=1e-12)
    with pytest.raises(CLIError, match="need their orientations"):
        _targets_in_model_frame(m, T_file, False, {}, None, "B", "m", "t.csv")
    with pytest.raises(CLIError, match="is a robot"):
        _targets_in_model_frame(None, T_file, True, cols, None, None, "arm.toml", "t.csv")


def test_two_stations_in_one_frame_name_stations_as_a_cause():
    """Probe report s40: two tracker stations' rows without a station column were refused naming the
    quaternion convention, the joint order and the robot file, never the stations."""
    from hykin.io.plausibility import PlausibilityError, check_orientation_order

    nom, data, base, st = campaign(n=120, seed=5)
    with pytest.raises(PlausibilityError, match="several tracker stations or tools"):
        check_orientation_order(nom, data.q, data.quat_wxyz, where="mixed.csv")
