"""Robot files: revolute joint limits written in radians under ``angle_unit = "deg"`` are refused
(probe report P), while every shipped preset and every random robot of the test battery still loads."""

from __future__ import annotations

import numpy as np
import pytest

from hykin.io.robot_file import list_presets, load_robot
from hykin.io.robot_toml import robot_from_toml_text
from hykin.kinematics.robot import RobotFileError

HEAD = 'name = "x"\nconvention = "dh"\nangle_unit = "deg"\n'


def _joint(lo, hi, a=0.3, alpha=-90, d=0.4, kind=None):
    t = f'type = "{kind}"\n' if kind else ""
    return f"[[joints]]\na = {a}\nalpha = {alpha}\nd = {d}\ntheta = 0\nmin = {lo}\nmax = {hi}\n{t}"


def test_limits_in_radians_under_degrees_are_refused():
    text = (HEAD + _joint(-2.967, 2.967) + _joint(-0.698, 1.745, alpha=0) + _joint(-6.283, 6.283, alpha=90)
            + _joint(-3.316, 3.316, alpha=-90))
    with pytest.raises(RobotFileError) as e:
        robot_from_toml_text(text, "limrad.toml")
    msg = str(e.value)
    assert "limrad.toml" in msg and "joints[3].min" in msg and "look like radians" in msg
    assert "angle_unit = 'rad'" in msg and "\n" not in msg


def test_full_turn_limits_written_as_two_pi_rounded_up_are_refused():
    with pytest.raises(RobotFileError, match="look like radians"):
        robot_from_toml_text(HEAD + _joint(-3.05, 3.05) + _joint(-6.2832, 6.2832, alpha=0) + _joint(-1.2, 2.5)
                             + _joint(-2.0, 2.0), "r.toml")


def test_limits_in_degrees_and_edge_cases_load():
    r = robot_from_toml_text(HEAD + _joint(-2.967, 2.967) + _joint(-40, 100, alpha=0) + _joint(-2, 2), "ok.toml")
    assert np.isclose(np.degrees(r.upper[1]), 100)  # one limit beyond ±2π "deg": degrees, loads
    robot_from_toml_text(HEAD + _joint(0, 0) + _joint(0, 0, alpha=0) + _joint(0, 0), "zero.toml")  # no evidence
    # fewer than 4 revolute joints (a tip/tilt/rotate stage of ±6°, ±6°, ±3°: probe report U), or a joint
    # spanning under 1 (57° if radians): not an arm's radian limits
    robot_from_toml_text(HEAD + _joint(-2.9, 2.9) + _joint(-1.7, 1.7, alpha=0), "two.toml")
    robot_from_toml_text(HEAD + _joint(-6, 6) + _joint(-6, 6, alpha=0) + _joint(-3, 3), "stage.toml")
    robot_from_toml_text(HEAD + _joint(-2.9, 2.9) + _joint(-1.7, 1.7, alpha=0) + _joint(0, 0.0625) + _joint(-2, 2),
                         "narrow.toml")
    # a prismatic joint's stroke (m) is not an angle
    robot_from_toml_text(HEAD + _joint(0, 0.5, kind="prismatic") + _joint(-2.9, 2.9, alpha=0) + _joint(-2, 2), "pris.toml")
    rad = HEAD.replace('"deg"', '"rad"')
    robot_from_toml_text(rad + _joint(-2.967, 2.967, alpha=-1.5707963) + _joint(-0.698, 1.745, alpha=0)
                         + _joint(-2, 2, alpha=0), "rad.toml")


def test_presets_and_random_robots_still_load(tmp_path):
    for name in list_presets():
        load_robot(name)
    from hykin.sim.random_robots import draw_robot

    for seed in range(30):  # both conventions, prismatic-first, makers' layouts; in degrees and in the drawn units
        kind = ("dh", "mdh")[seed % 2]
        layout = {"dof": 6, "template": True} if seed % 4 == 0 else {}
        for units in (("m", "deg"), ("mm", "deg"), None):
            rr = draw_robot(np.random.default_rng([seed, 39]), kind, units=units, prismatic=seed % 3 == 0, **layout)
            robot_from_toml_text(rr.file_text, f"random-{seed}.toml")
