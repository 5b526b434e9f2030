"""Calibration coverage notes found by probes AK and W (session 41), each against a truth of our own.

Robot, FK (numpy DH, not hykin's walk), truth and noisy tracker data come from ``test_calibration_s40``.

* AK-A: joint 6 never moved: exit 0, fine in the campaign, off elsewhere, and nothing said so. Now a
  warning names the joint and its angle (and the calibrated file carries it as a comment).
* AK-D6: the tool at one orientation: the tool offset cannot be told from the base; now one warning says
  so with the rotation spread, and names the fixes.
* AK-D2: mirrored positions (two swapped columns) were refused blaming ``d4``; now the refusal says
  the positions look mirrored and, with right-handed orientations, which columns.
* W-D1: a joint zero 90° off was refused as "deviates −9.955°" (where the prior stopped the fit); now
  the quarter turn is named with its amount, and a deviation the fit stopped at is worded so.
"""

from __future__ import annotations

import math
import re
import warnings

import numpy as np
import pytest

from hykin.calibration.calibrate import CalibrationError, calibrate
from hykin.calibration.coverage import joint_range_warnings, rotation_spread_deg, tool_orientation_warning
from hykin.io.dataset import Dataset
from hykin.io.dataset_files import write_dataset
from hykin.io.robot_toml import load_robot_toml, robot_to_toml_string
from hykin.kinematics.fk import fk

from cli_run import run
from test_calibration_s40 import NOMINAL, dh_fk, measured, one_orientation_joints, robot_of, spread_joints, truth_of


def _calibrate(robot, data, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return calibrate(robot, data, compliance=False, **kw)


def _pos_err_mm(robot, g, q) -> np.ndarray:
    """Per-row distance (mm) of the calibrated ``robot``'s TCP from our truth ``g`` at joints ``q``."""
    return np.linalg.norm(fk(robot, q)[:, :3, 3] - dh_fk(g, q)[:, :3, 3], axis=1) * 1e3


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles (deg) of ``Ra_i^T Rb_i`` (our own: arccos of (trace - 1) / 2)."""
    c = (np.einsum("nij,nij->n", Ra, Rb) - 1) / 2
    return np.degrees(np.arccos(np.clip(c, -1, 1)))


# --------------------------------------------------------------------------- AK-A: a joint never moved


@pytest.fixture(scope="module")
def j6_fixed():
    g = truth_of(11)
    q = spread_joints(300, 12)
    q[:, 5] = 0.3
    return g, q, _calibrate(robot_of(NOMINAL), measured(g, q, 13))


def test_joint_never_moved_is_warned_with_its_angle(j6_fixed):
    """q6 = 0.3 rad in every row: exactly one warning, naming joint 6 and q6 = 17.19° (0.3 rad in
    degrees, ours); the claim holds against our truth: in the campaign the calibrated robot is within
    0.05 mm, at q6 + 90° it is more than 5x worse (old code: no warning at all)."""
    g, q, res = j6_fixed
    assert len(res.coverage) == 1, res.coverage
    w = res.coverage[0]
    assert w.startswith("joint 6 never moved in the data (range 0°, q6 = 17.19°)") and "the tool" in w
    assert f"{math.degrees(0.3):.4g}" == "17.19"
    inside = _pos_err_mm(res.robot, g, q)
    q_out = q.copy()
    q_out[:, 5] += math.pi / 2
    outside = _pos_err_mm(res.robot, g, q_out)
    assert inside.max() < 0.05 and outside.mean() > 5 * inside.mean(), (inside.mean(), outside.mean())


def test_full_range_campaign_warns_nothing():
    """Every joint spread over its range, tool at many orientations: no coverage warning."""
    g = truth_of(14)
    q = spread_joints(200, 15)
    res = _calibrate(robot_of(NOMINAL), measured(g, q, 16))
    assert res.coverage == []


def test_joint_range_is_wrapped_and_small_ranges_named():
    """q4 at ±(π - 0.01) is one 1.146° range (wrapped, ours: 0.02 rad), q2 moved 3°: both named with their
    ranges; q1 over 60° is not."""
    rng = np.random.default_rng(0)
    q = np.zeros((50, 6))
    q[:, 0] = rng.uniform(-0.5, 0.5, 50) * math.radians(120)
    q[:, 1] = np.linspace(0.0, math.radians(3.0), 50)
    q[:, 3] = np.where(np.arange(50) % 2, math.pi - 0.01, -math.pi + 0.01)
    q[:, [2, 4, 5]] = rng.uniform(-1, 1, (50, 3))
    ws = joint_range_warnings(robot_of(NOMINAL), q)
    assert [w.split(" in the data")[0] for w in ws] == ["joint 2 moved only 3°", "joint 4 moved only 1.15°"]
    assert f"{math.degrees(0.02):.3g}" == "1.15"
    assert "q2 = 0° to 3°" in ws[0]


def test_calibrated_file_carries_the_warning_as_a_comment(j6_fixed, tmp_path, capsys):
    """The CLI prints the warning (exit 0) and writes it on top of the robot file as a TOML comment; the
    file still reads back to the same robot (FK equal to 1e-9 m)."""
    g, q, _ = j6_fixed
    rob = tmp_path / "nominal.toml"
    rob.write_text(robot_to_toml_string(robot_of(NOMINAL)), encoding="utf-8")
    data = tmp_path / "j6.csv"
    write_dataset(measured(g, q, 13), data)
    out = tmp_path / "cal.toml"
    code, stdout, err = run(["calibrate", rob, data, "-o", out, "--no-compliance"], capsys)
    assert code == 0, err
    assert re.search(r"warning: joint 6 never moved in the data \(range 0°, q6 = 17\.19°\)", stdout + err)
    text = out.read_text(encoding="utf-8")
    assert text.startswith("# hykin calibrate warning: joint 6 never moved")
    cal = load_robot_toml(out)
    np.testing.assert_allclose(fk(cal, q[:20]), fk(_calibrate(robot_of(NOMINAL), measured(g, q, 13)).robot, q[:20]),
                               atol=1e-9)


# --------------------------------------------------------------------------- AK-D6: tool at one orientation


def test_tool_at_one_orientation_is_warned_with_its_spread():
    """The flange at one orientation: one warning that the tool offset was not observable, with a
    rotation spread within 0.2° of our truth's (~0, from our FK) and the two fixes; against our truth
    the calibrated robot is within 0.1 mm in the campaign and more than 1 mm off at other orientations."""
    g = truth_of(2)
    q = one_orientation_joints(g, 90, 3)
    res = _calibrate(robot_of(NOMINAL), measured(g, q, 4))
    tw = [w for w in res.coverage if "tool offset" in w]
    assert len(tw) == 1, res.coverage
    m = re.search(r"the tool was held at one orientation \(rotation spread ([\d.e+-]+)°\)", tw[0])
    R = dh_fk(g, q)[:, :3, :3]
    ours = _angle_deg(np.broadcast_to(R[0], R.shape), R).max()
    assert m and abs(float(m.group(1)) - ours) < 0.2, (tw[0], ours)
    assert "several orientations" in tw[0] and "--prior tool_mm" in tw[0]
    assert _pos_err_mm(res.robot, g, q).max() < 0.1
    q_out = spread_joints(100, 5)
    assert _pos_err_mm(res.robot, g, q_out).mean() > 1.0
    assert tool_orientation_warning(res, q, tool_prior_given=True) is None  # a stated tool prior: held on purpose


def test_rotation_spread_against_our_angles():
    """Rotations about z by 0..10° around a mean: the largest angle from the chordal mean is 5° (ours)."""
    t = np.radians(np.linspace(-5, 5, 11))
    R = np.zeros((11, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = np.cos(t), -np.sin(t), np.sin(t), np.cos(t), 1
    assert rotation_spread_deg(R) == pytest.approx(5.0, abs=1e-9)


# --------------------------------------------------------------------------- AK-D2: mirrored positions


@pytest.fixture(scope="module")
def campaign():
    g = truth_of(21)
    q = spread_joints(250, 22)
    return g, q, measured(g, q, 23)


@pytest.mark.parametrize("cols,name", [((1, 0, 2), "x and y swapped"), ((0, 2, 1), "y and z swapped")])
def test_swapped_position_columns_are_named_mirrored(campaign, cols, name):
    """Two position columns swapped, orientations right: refused (as before) saying the positions look
    mirrored and which columns; the mirrored RMS it quotes is no more than our own reflection-allowed
    rigid fit of the file's FK (the tool free can only lower it), the as-given RMS 5x more."""
    g, q, ds = campaign
    bad = Dataset(q=q, xyz_m=ds.xyz_m[:, list(cols)], quat_wxyz=ds.quat_wxyz, source="<s41>")
    with pytest.raises(CalibrationError, match=rf"look mirrored \(a left-handed frame or a column mistake: {name}\?\)") as e:
        _calibrate(robot_of(NOMINAL), bad)
    mir, given = (float(v) for v in re.search(r"fit them to ([\d.e+]+) mm RMS mirrored against ([\d.e+]+) mm", str(e.value)).groups())
    P = dh_fk(NOMINAL, q)[:, :3, 3]
    A, B = P - P.mean(0), bad.xyz_m - bad.xyz_m.mean(0)
    U, _, Vt = np.linalg.svd(A.T @ B)
    ours = np.sqrt(np.mean(np.sum((A @ U @ Vt - B) ** 2, 1))) * 1e3  # orthogonal (reflection allowed) fit
    assert mir <= ours * 1.001 + 1e-3 and given > 5 * mir, (mir, ours, given)


def test_negated_column_position_only_is_mirrored_unnamed(campaign):
    """Position-only data with z negated: mirrored, columns not named (no orientations to tell)."""
    g, q, ds = campaign
    bad = Dataset(q=q, xyz_m=ds.xyz_m * [1, 1, -1], quat_wxyz=None, source="<s41>")
    with pytest.raises(CalibrationError, match=r"look mirrored .*two of x, y, z swapped or one negated\?"):
        _calibrate(robot_of(NOMINAL), bad)


# --------------------------------------------------------------------------- W-D1: a joint zero a quarter turn off


def test_joint_zero_quarter_turn_off_names_the_turn(campaign):
    """The file's theta3 is 90° off our truth (position-only data): refused naming joint 3's zero a
    quarter turn off with theta3 -90° (ours: the truth minus the file), not a few degrees; the
    stopped deviation is worded as stopped, with the residual it left."""
    g, q, _ = campaign
    ds = measured(g, q, 24, orientation=False)
    wrong = {**NOMINAL, "theta": NOMINAL["theta"] + np.radians([0, 0, 90, 0, 0, 0])}
    turn = round(math.degrees(g["theta"][2] - wrong["theta"][2]))
    with pytest.raises(CalibrationError, match=rf"joint 3's zero looks a quarter turn off: with theta3 {turn:+d}° ") as e:
        _calibrate(robot_of(wrong), ds)
    msg = str(e.value)
    assert turn == -90
    if "fitted as given: joint" in msg and " went to " in msg:
        assert "the fit stopped there still leaving" in msg and "possibly far more" in msg


def test_the_coverage_warning_is_kept_in_the_calibration_metadata(j6_fixed):
    """A model keeps what its calibration warned about (`fit` prints it; the metadata hold it)."""
    _, _, res = j6_fixed
    d = res.to_dict()
    assert d["coverage"] == res.coverage and d["coverage"][0].startswith("joint 6 never moved")


def test_an_arm_whose_axes_are_all_parallel_is_not_told_to_tilt_its_tool(tmp_path):
    """Probe s41 AP: a SCARA (every axis parallel) was warned that its tool offset was not observable and
    told to measure at several tool orientations, which it cannot take (its file was right everywhere)."""
    from hykin.calibration.coverage import _axes_parallel

    p = tmp_path / "scara.toml"
    p.write_text('''name = "scara-s41"\nconvention = "dh"\nlength_unit = "m"\nangle_unit = "deg"
[[joints]]\na = 0.35\nalpha = 0\nd = 0.4\ntheta = 0\nmin = -150\nmax = 150
[[joints]]\na = 0.3\nalpha = 180\nd = 0\ntheta = 0\nmin = -140\nmax = 140
[[joints]]\na = 0\nalpha = 0\nd = 0\ntheta = 0\nmin = 0\nmax = 0.3\ntype = "prismatic"
[[joints]]\na = 0\nalpha = 0\nd = 0.05\ntheta = 0\nmin = -360\nmax = 360
''')
    scara = load_robot_toml(p)
    q = np.array([[0.3, -0.4, 0.1, 1.0]])
    assert _axes_parallel(scara, q)
    assert not _axes_parallel(robot_of(NOMINAL), spread_joints(2, 1))
    tilted = scara.copy(alpha_rad=np.radians([0.2, 180.1, 0.0, 0.0]))  # a calibration's tilt stays "parallel"
    assert _axes_parallel(tilted, q)
