"""``hykin plan`` refuses impossible trackers and boxes up front, in one line (probe report P):
a tracker in millimetres under --length-unit m, inside the robot's body or inside a keep-out box; a
box beyond the reach; too few candidates (names --pool); messages in the user's units."""

from __future__ import annotations

import math

import numpy as np
import pytest
from cli_run import run as _run
from shared_fixtures import dh_robot_toml

from hykin.io.robot_toml import load_robot_toml, robot_from_toml_text
from hykin.planning import Constraints, PlanningError, feasible, parse_region
from hykin.planning.bodies import body_segments
from hykin.planning.select import candidate_pool

# the tester's 6R (DH, degrees), base at (1.0, 0.5, 0.2) m turned 30° about z
ROBOT = dh_robot_toml("probe-6r", [(0.18, -90, 0.45, 0, -170, 170), (0.62, 0, 0, -90, -40, 100), (0.10, -90, 0, 0, -150, 70),
                                    (0, 90, 0.66, 0, -360, 360), (0, -90, 0, 0, -120, 120), (0, 0, 0.11, 0, -360, 360)], """
[tool]
xyz = [0.03, 0.0, 0.14]
rpy = [0, 0, 0]

[base]
xyz = [1.0, 0.5, 0.2]
rpy = [0, 0, 30]
""")


def load_robot_toml_text(text):
    """The robot of ``text`` (TOML), named like a file in errors."""
    return robot_from_toml_text(text, "probe-6r.toml")


@pytest.fixture
def robot_file(tmp_path):
    p = tmp_path / "robot.toml"
    p.write_text(ROBOT)
    return p


def _plan(robot_file, tmp_path, capsys, *extra):
    out = tmp_path / "plan.csv"
    code, so, se = _run(["plan", str(robot_file), "-n", "12", "-o", str(out), "--pool", "512", *extra], capsys)
    return code, so, se, out


def _one_line_refusal(code, se, out):
    assert code == 2, se
    assert se.strip().count("\n") == 0, se
    assert not out.exists()


def test_tracker_in_mm_under_metres_is_refused_naming_the_option(robot_file, tmp_path, capsys):
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--tracker", "3500,1500,1000")
    _one_line_refusal(code, se, out)
    assert "--max-tracker-distance-m" in se and "--length-unit mm" in se and "from the robot base" in se


def test_tracker_distance_bound_can_be_lifted(robot_file, tmp_path, capsys):
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--tracker", "150,1.5,1", "--max-incidence", "60",
                             "--no-body-check", "--max-tracker-distance-m", "1000")
    assert code == 0, se
    assert out.exists()


def test_tracker_distance_api_bound():
    from hykin.planning.constraints import MAX_TRACKER_DISTANCE_M

    rob = load_robot_toml_text(ROBOT)
    assert MAX_TRACKER_DISTANCE_M == 100.0
    far = np.array([1.0, 0.5, 0.2]) + [MAX_TRACKER_DISTANCE_M + 1.0, 0.0, 0.0]
    with pytest.raises(PlanningError, match="farther than the 100 m"):
        Constraints(tracker_m=far, body=False).check(rob)
    Constraints(tracker_m=far, body=False, max_tracker_distance_m=math.inf).check(rob)  # lifted
    near = np.array([1.0, 0.5, 0.2]) + [MAX_TRACKER_DISTANCE_M - 1.0, 0.0, 0.0]
    Constraints(tracker_m=near, body=False).check(rob)


def test_tracker_inside_the_base_column_is_refused(robot_file, tmp_path, capsys):
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--tracker", "1.0,0.5,0.4")
    _one_line_refusal(code, se, out)
    assert "inside the robot's base column" in se and "0.169 m" in se


def test_tracker_clear_of_the_body_in_every_feasible_pose():
    """A tracker where the upper arm passes in some poses: no feasible pose has it inside the body
    (reference: distance from the tracker to densely sampled capsule segments)."""
    rob = load_robot_toml_text(ROBOT)
    base = rob.base[:3, 3]
    tracker = base + np.array([0.0, 0.0, 0.45 + 0.3])  # above the shoulder, within the upper arm's sweep
    c = Constraints(tracker_m=tracker, max_incidence_deg=90.0).check(rob)
    q = rob.random_joints(1500, np.random.default_rng(5))
    ok = feasible(rob, q, c)
    seg, body = body_segments(rob, q)
    t = np.linspace(0.0, 1.0, 200)[:, None]
    pts = seg[:, :, 0, None] + t * (seg[:, :, 1, None] - seg[:, :, 0, None])  # (N, S, 200, 3)
    d = np.linalg.norm(pts - tracker, axis=-1).min(axis=2)  # (N, S)
    inside = np.zeros(len(q), bool)
    for b, r in enumerate(c.bodies.radii_m):
        inside |= d[:, body == b].min(axis=1) < r - 1e-3
    assert inside.sum() > 20  # the test is meaningful: the arm does reach the tracker
    assert not np.any(ok & inside)
    assert ok.sum() > 50


def test_tracker_inside_a_keep_out_box_is_refused_before_sampling(robot_file, tmp_path, capsys):
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--tracker", "3.5,1.5,1",
                             "--keep-out", "0,0,0,0.1,0.1,0.1", "--keep-out", "3.4,1.4,0.9,3.6,1.6,1.1")
    _one_line_refusal(code, se, out)
    assert "the tracker lies inside keep-out box 2" in se
    assert "candidate" not in se  # refused up front, not after drawing candidates


def test_box_beyond_reach_is_refused_with_distances(robot_file, tmp_path, capsys):
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--box", "10,10,10,11,11,11")
    _one_line_refusal(code, se, out)
    assert "nearest point is 16.35 m from the robot base" in se and "reach of 2.118 m" in se
    assert "candidate" not in se


def test_box_within_reach_is_not_refused_up_front():
    rob = load_robot_toml_text(ROBOT)
    c = Constraints(box_m=np.array([[1.5, 0.0, 0.0], [2.5, 1.0, 1.0]]), body=False).check(rob)
    assert c.box_m is not None


def test_too_few_candidates_names_pool():
    rob = load_robot_toml_text(ROBOT)
    c = Constraints(tracker_m=np.array([3.5, 1.5, 1.0]), max_incidence_deg=30.0, body=False).check(rob)
    with pytest.raises(PlanningError, match=r"only [1-9]\d* of 256 .*--pool \d+") as e:
        candidate_pool(rob, c, 3000, pool=256, max_pool=256)
    assert "\n" not in str(e.value)
    c = Constraints(tracker_m=np.array([3.5, 1.5, 1.0]), max_incidence_deg=1.0, body=False).check(rob)
    with pytest.raises(PlanningError, match=r"only 0 of 256 .*--pool"):
        candidate_pool(rob, c, 3000, pool=256, max_pool=256)


def test_region_out_of_limits_in_degrees_is_reported_in_degrees(robot_file, tmp_path, capsys):
    rob = load_robot_toml_text(ROBOT)
    with pytest.raises(PlanningError, match=r"joint 1 range \[-200, 200\] deg exceeds the joint limits \[-170, 170\] deg"):
        parse_region(rob, "-200:200,:,:,:,:,:")
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--region", "-200:200,:,:,:,:,:")
    _one_line_refusal(code, se, out)
    assert "[-170, 170] deg" in se and "2.967" not in se


def test_zero_reflector_axis_message_has_plain_numbers(robot_file, tmp_path, capsys):
    code, _, se, out = _plan(robot_file, tmp_path, capsys, "--reflector-axis", "0,0,0")
    _one_line_refusal(code, se, out)
    assert "array(" not in se and "got 0, 0, 0" in se


def test_robot_file_fixture_loads(robot_file):
    assert load_robot_toml(robot_file).dof == 6
