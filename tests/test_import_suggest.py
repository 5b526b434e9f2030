"""Issue 24: `import table --suggest` never maps uncertainty, sensor or index/time columns as
positions, further reflectors or joints; a further reflector is accepted at import only at a
plausible, constant lever arm from the first (a 3 µm "second reflector" is refused with one line)."""

import numpy as np
import pytest
from hykin.io.toml_compat import tomllib
from hypothesis import given, settings
from hypothesis import strategies as st

from hykin.measure.table_import import import_table
from hykin.measure.table_map import TableMapError, never_position, suggest_map

DECOYS = ["U95 {a}", "U95_{a}", "u95{a}", "Unc {a}", "unc_{a}", "Uncertainty {a}", "std_{a}", "Sigma{a}", "err_{a}",
          "acc_{a}", "Acc{A}", "accel_{a}", "Accelerometer {A}", "gyro_{a}", "Gyro{A}", "IMU_{a}", "temp_{a}",
          "force_{a}", "Torque {A}", "vel_{a}", "Index {A}", "idx_{a}", "time_{a}", "Sample {A}", "RMS {A}"]
REAL = ["{A}", "Pos {A}", "pos_{a}", "TCP_{A}", "Meas {A}", "{a}_m", "{A} [mm]"]


def _triple(fmt):
    return [fmt.format(a=a, A=a.upper()) for a in "xyz"]


@pytest.mark.parametrize("fmt", DECOYS)
def test_decoy_names_are_never_positions(fmt):
    assert all(never_position(c) for c in _triple(fmt))


@pytest.mark.parametrize("fmt", REAL)
def test_real_names_are_positions(fmt):
    assert not any(never_position(c) for c in _triple(fmt))


@settings(max_examples=60, deadline=None)
@given(real=st.sampled_from(REAL), decoys=st.lists(st.sampled_from(DECOYS), min_size=1, max_size=4, unique=True),
       order=st.randoms(use_true_random=False), joints=st.sampled_from(["A{i}", "J{i}", "q{i}", "joint_{i}"]))
def test_suggest_maps_only_the_real_triple(real, decoys, order, joints):
    header = [joints.format(i=i) for i in range(1, 7)]
    cols = [_triple(real)] + [_triple(d) for d in decoys]
    order.shuffle(cols)
    header += [c for t in cols for c in t] + ["Index", "Time"]
    doc = tomllib.loads(suggest_map(header))
    assert doc["position"] == _triple(real)
    assert "points" not in doc
    assert doc["joints"] == [joints.format(i=i) for i in range(1, 7)]


def _table(path, lever_m, extra_noise_m=0.0, n=40, seed=0):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-1, 1, (n, 6))
    p = rng.uniform(-0.8, 0.8, (n, 3)) + [1.0, 0.0, 0.5]
    d = rng.normal(size=(n, 3))
    p2 = p + lever_m * d / np.linalg.norm(d, axis=1, keepdims=True) + rng.normal(0, extra_noise_m, (n, 3))
    head = "J1,J2,J3,J4,J5,J6,X,Y,Z,X2,Y2,Z2"
    np.savetxt(path, np.c_[q, p, p2], delimiter=",", header=head, comments="", fmt="%.12g")
    return path


MAP = {"joints": ["J1", "J2", "J3", "J4", "J5", "J6"], "position": ["X", "Y", "Z"], "points": [["X2", "Y2", "Z2"]]}


def test_plausible_second_reflector_imported(tmp_path):
    ds = import_table(_table(tmp_path / "t.csv", 0.12), MAP)
    lever = np.linalg.norm(np.c_[ds.extra["x2"], ds.extra["y2"], ds.extra["z2"]] - ds.xyz_m, axis=1)
    np.testing.assert_allclose(lever, 0.12, rtol=1e-9)


@pytest.mark.parametrize("lever_m, noise_m, why", [
    (3e-6, 0.0, "outside the lever arm"),   # the reported 3 µm "second reflector" (an uncertainty column)
    (5.0, 0.0, "outside the lever arm"),    # 5 m: not on the same tool (or mm read as m)
    (0.1, 0.02, "changes its distance"),    # not rigid: 20 mm noise on a 100 mm lever arm
])
def test_implausible_second_reflector_refused_at_import(tmp_path, lever_m, noise_m, why):
    with pytest.raises(TableMapError) as e:
        import_table(_table(tmp_path / "t.csv", lever_m, noise_m), MAP)
    msg = str(e.value)
    assert "\n" not in msg and "'X2', 'Y2', 'Z2'" in msg and why in msg
    # the limit is an option
    if lever_m > 1:
        import_table(_table(tmp_path / "t.csv", lever_m, noise_m), dict(MAP, lever_arm_m=[0.003, 10.0]))


@pytest.mark.parametrize("offset_m", [60.0, 2500.0])
def test_import_far_instrument_by_spread_not_coordinates(tmp_path, offset_m):
    """A total station / tracker far from the robot: coordinates of tens of metres or kilometres are
    metres (judged by the spread, not the distance from the origin); the same table in mm declared m
    is refused, and declared mm it is read."""
    rng = np.random.default_rng(1)
    q = rng.uniform(-1, 1, (30, 6))
    p = rng.uniform(-0.8, 0.8, (30, 3)) + offset_m
    head = "J1,J2,J3,J4,J5,J6,X,Y,Z"
    m = {"joints": ["J1", "J2", "J3", "J4", "J5", "J6"], "position": ["X", "Y", "Z"]}
    np.savetxt(tmp_path / "m.csv", np.c_[q, p], delimiter=",", header=head, comments="", fmt="%.17g")
    np.testing.assert_allclose(import_table(tmp_path / "m.csv", m).xyz_m, p, rtol=1e-12)
    np.savetxt(tmp_path / "mm.csv", np.c_[q, p * 1e3], delimiter=",", header=head, comments="", fmt="%.17g")
    with pytest.raises(Exception, match="looks like millimetres"):
        import_table(tmp_path / "mm.csv", m)
    np.testing.assert_allclose(import_table(tmp_path / "mm.csv", dict(m, length_unit="mm")).xyz_m, p, rtol=1e-12)


def test_suggest_keeps_station_tool_pose_and_load_and_import_names_what_it_left_out(tmp_path, capsys):
    """Probe report s40: --suggest left out a tracker export's Station, Tool and Load columns, and the import
    dropped them without a word (every row then in one frame). Now --suggest keeps the labels and maps the
    load; an import that leaves columns out names them."""
    from cli_run import run

    header = ["Pt", "Station", "Tool", "Load [kg]", "J1", "J2", "J3", "J4", "J5", "J6", "X", "Y", "Z"]
    text = suggest_map(header, [["P1", "S1", "A", "12", "1", "2", "3", "4", "5", "6", "1000", "200", "300"]])
    m = tomllib.loads("\n".join(line for line in text.splitlines() if not line.startswith("#")))
    assert m["keep"] == {"Pt": "pose_id", "Station": "station", "Tool": "tool"}
    assert m["payload"] == "Load [kg]"
    rows = [",".join(header)] + [f"P{i},S{1 + i % 2},A,0,{0.1 * i},0.2,0.3,0.4,0.5,0.6,1,0.2,0.3" for i in range(6)]
    (tmp_path / "t.csv").write_text("\n".join(rows) + "\n")
    code, out, err = run(["import", "table", tmp_path / "t.csv", "-o", tmp_path / "o.csv", "--joints", "J1..J6",
                          "--position", "X,Y,Z", "--no-unit-check"], capsys)
    assert code == 0, err
    assert "columns not mapped, left out: Pt, Station, Tool, Load [kg]" in err
