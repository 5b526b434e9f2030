"""Robot files: TOML round trips, units, presets, URDF loading and the errors that name file and field."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hykin.geometry import se3
from hykin.io.robot_file import list_presets, load_robot
from hykin.io.robot_toml import load_robot_toml, robot_to_toml_string, save_robot_toml
from hykin.io.urdf import load_urdf, load_urdf_string, robot_to_urdf
from hykin.kinematics.fk import fk, fk_frames
from hykin.kinematics.robot import Robot, RobotFileError

DATA = Path(__file__).parent / "data"


# --------------------------------------------------------------------------- round trips


@st.composite
def dh_robots(draw):
    n = draw(st.integers(1, 7))
    conv = draw(st.sampled_from(["dh", "mdh"]))
    length = st.floats(-1.5, 1.5, allow_nan=False)
    angle = st.floats(-math.pi, math.pi, allow_nan=False)
    prism = draw(st.lists(st.booleans(), min_size=n, max_size=n))
    lo = np.array(draw(st.lists(st.floats(-3, 0), min_size=n, max_size=n)))
    hi = lo + np.array(draw(st.lists(st.floats(0.01, 3), min_size=n, max_size=n)))
    arr = lambda s: np.array(draw(st.lists(s, min_size=n, max_size=n)))
    frame = lambda: se3.xyzrpy_to_transform(
        np.array(draw(st.lists(length, min_size=3, max_size=3))), np.array(draw(st.lists(angle, min_size=3, max_size=3)))
    )
    return Robot(
        name="random", convention=conv, a_m=arr(length), alpha_rad=arr(angle), d_m=arr(length), theta_rad=arr(angle),
        beta_rad=arr(st.floats(-0.1, 0.1)), lower=lo, upper=hi,
        joint_type=tuple("prismatic" if p else "revolute" for p in prism),
        mass_kg=arr(st.floats(0.0, 50.0)), com_m=np.array(draw(st.lists(st.lists(length, min_size=3, max_size=3), min_size=n, max_size=n))),
        stiffness_nm_per_rad=arr(st.one_of(st.just(math.inf), st.floats(1e3, 1e7))),
        base=frame(), tool=frame(), payload_kg=draw(st.floats(0, 20)),
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(robot=dh_robots(), seed=st.integers(0, 2**31))
def test_toml_round_trip_same_fk(tmp_path_factory, robot, seed):
    path = tmp_path_factory.mktemp("rt") / "r.toml"
    save_robot_toml(robot, path)
    back = load_robot_toml(path)
    assert back.convention == robot.convention and back.joint_type == robot.joint_type
    Q = robot.random_joints(50, rng=seed)
    np.testing.assert_allclose(fk(back, Q), fk(robot, Q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(back.lower, robot.lower, atol=1e-12)
    np.testing.assert_allclose(back.upper, robot.upper, atol=1e-12)
    np.testing.assert_allclose(back.mass_kg, robot.mass_kg)
    np.testing.assert_allclose(back.com_m[robot.mass_kg > 0], robot.com_m[robot.mass_kg > 0])
    np.testing.assert_array_equal(back.stiffness_nm_per_rad, robot.stiffness_nm_per_rad)
    assert back.payload_kg == pytest.approx(robot.payload_kg)


@pytest.mark.parametrize("name", list_presets())
def test_presets_load_and_round_trip(tmp_path, name):
    robot = load_robot(name)
    assert robot.source, "every preset documents where its numbers come from"
    assert np.all(robot.lower < robot.upper)
    save_robot_toml(robot, tmp_path / "p.toml")
    back = load_robot(tmp_path / "p.toml")
    Q = robot.random_joints(100, rng=0)
    np.testing.assert_allclose(fk(back, Q), fk(robot, Q), rtol=0, atol=1e-12)
    assert back.source == robot.source


def test_preset_dofs_and_masses():
    dof = {n: load_robot(n).dof for n in list_presets()}
    assert dof["kuka-iiwa14"] == dof["franka-panda"] == 7
    assert all(dof[n] == 6 for n in ("ur5", "ur10", "ur10e", "kuka-kr6-r900", "abb-irb2400"))
    np.testing.assert_allclose(load_robot("ur5").mass_kg, [3.7, 8.393, 2.275, 1.219, 1.219, 0.1879])
    np.testing.assert_allclose(load_robot("ur10").mass_kg, [7.1, 12.7, 4.27, 2.0, 2.0, 0.365])
    np.testing.assert_allclose(load_robot("ur10e").mass_kg, [7.369, 13.051, 3.989, 2.1, 1.98, 0.615])
    np.testing.assert_allclose(np.degrees(load_robot("ur5").upper), 360)
    np.testing.assert_allclose(np.degrees(load_robot("kuka-iiwa14").upper), [170, 120, 170, 120, 170, 120, 175])


# --------------------------------------------------------------------------- units


MM_DEG = """
name = "two"
convention = "dh"
length_unit = "mm"
angle_unit = "deg"
[[joints]]
a = 150
alpha = -90
d = 550
theta = 10
min = -160
max = 160
mass = 3
com = [10, 20, 30]
[[joints]]
type = "prismatic"
a = 825
alpha = 0
d = 100
min = -50
max = 250
[tool]
xyz = [0, 0, 110]
rpy = [0, 90, 0]
[base]
xyz = [1000, 0, 0]
rpy = [0, 0, 45]
"""

M_RAD = f"""
name = "two"
convention = "dh"
length_unit = "m"
angle_unit = "rad"
[[joints]]
a = 0.15
alpha = {-math.pi / 2!r}
d = 0.55
theta = {math.radians(10)!r}
min = {math.radians(-160)!r}
max = {math.radians(160)!r}
mass = 3
com = [0.01, 0.02, 0.03]
[[joints]]
type = "prismatic"
a = 0.825
alpha = 0
d = 0.1
min = -0.05
max = 0.25
[tool]
xyz = [0, 0, 0.11]
rpy = [0, {math.pi / 2!r}, 0]
[base]
xyz = [1.0, 0, 0]
rpy = [0, 0, {math.pi / 4!r}]
"""


def test_units_mm_deg_equal_m_rad(tmp_path):
    (tmp_path / "a.toml").write_text(MM_DEG)
    (tmp_path / "b.toml").write_text(M_RAD)
    a, b = load_robot(tmp_path / "a.toml"), load_robot(tmp_path / "b.toml")
    for f in ("a_m", "alpha_rad", "d_m", "theta_rad", "lower", "upper", "com_m", "base", "tool"):
        np.testing.assert_allclose(getattr(a, f), getattr(b, f), rtol=1e-14, atol=1e-15, err_msg=f)
    # prismatic limits are lengths: -50 mm .. 250 mm
    np.testing.assert_allclose([a.lower[1], a.upper[1]], [-0.05, 0.25])
    Q = a.random_joints(20, rng=1)
    np.testing.assert_allclose(fk(a, Q), fk(b, Q), atol=1e-14)
    # closed form at q = 0 for the two-joint arm: base · Rz(10°)Tz(.55)Tx(.15)Rx(-90°) · Tz(.1)Tx(.825) · tool
    T = b.base @ se3.rotz(math.radians(10)) @ se3.trans(0, 0, 0.55) @ se3.trans(0.15) @ se3.rotx(-math.pi / 2)
    T = T @ se3.trans(0, 0, 0.1) @ se3.trans(0.825) @ b.tool
    np.testing.assert_allclose(fk(a, np.zeros(2)), T, atol=1e-14)


# --------------------------------------------------------------------------- errors


def _write(tmp_path, text, name="bad.toml"):
    p = tmp_path / name
    p.write_text(text)
    return p


GOOD_JOINT = "[[joints]]\na = 0.1\nalpha = 0\nd = 0.2\ntheta = 0\nmin = -90\nmax = 90\n"
HEAD = 'name = "x"\nconvention = "dh"\nangle_unit = "deg"\n'


@pytest.mark.parametrize(
    "text, must_contain",
    [
        (HEAD + "[[joints]]\na = 0.1\nmax = 90\n", ["joints[1]", "min"]),
        (HEAD + GOOD_JOINT + "[[joints]]\na = 0.1\nmin = -1\n", ["joints[2]", "max"]),
        ('name = "x"\nconvention = "xyz"\n' + GOOD_JOINT, ["convention", "xyz"]),
        (HEAD + GOOD_JOINT.replace("d = 0.2", 'd = "long"'), ["joints[1].d", "number"]),
        (HEAD + GOOD_JOINT + "colour = 3\n", ["joints[1]", "colour"]),
        (HEAD + GOOD_JOINT + "[tool]\nxyz = [0, 0]\n", ["[tool].xyz", "3"]),
        (HEAD + GOOD_JOINT + "[tool]\nrot = [0, 0, 0]\n", ["[tool]", "rot"]),
        (HEAD + GOOD_JOINT.replace("min = -90", "min = 100"), ["joints[1]", "min = 100 is above max = 90"]),
        (HEAD + GOOD_JOINT + "mass = -1\n", ["joints[1].mass"]),
        (HEAD + GOOD_JOINT + "stiffness = 0\n", ["joints[1].stiffness"]),
        (HEAD.replace('angle_unit = "deg"', 'angle_unit = "grad"') + GOOD_JOINT, ["angle_unit", "grad"]),
        ('name = "x"\n' + GOOD_JOINT, ["convention"]),
        (HEAD, ["joints"]),
        (HEAD + "[[joints\n", ["invalid TOML"]),
    ],
)
def test_errors_name_file_and_field(tmp_path, text, must_contain):
    p = _write(tmp_path, text)
    with pytest.raises(RobotFileError) as e:
        load_robot_toml(p)
    msg = str(e.value)
    assert isinstance(e.value, ValueError)
    # the message names the file (except the dataclass-level check, which names the robot)
    assert "bad.toml" in msg or "'x'" in msg
    for s in must_contain:
        assert s in msg, (s, msg)


def test_missing_file_and_unknown_preset(tmp_path):
    with pytest.raises(RobotFileError, match="not found"):
        load_robot_toml(tmp_path / "nope.toml")
    with pytest.raises(RobotFileError, match="not a preset"):
        load_robot("no-such-robot")


def test_urdf_robot_cannot_be_saved_as_toml():
    with pytest.raises(RobotFileError, match="only DH/MDH"):
        robot_to_toml_string(load_urdf(DATA / "test_arm.urdf"))


# --------------------------------------------------------------------------- URDF loading


def test_load_robot_dispatches_urdf():
    r = load_robot(DATA / "test_arm.urdf")
    assert r.convention == "urdf" and r.dof == 6
    assert "j1" in r.source and "tcp" in r.source


def test_urdf_base_and_tip_links():
    full = load_urdf(DATA / "test_arm.urdf")
    sub = load_urdf(DATA / "test_arm.urdf", base_link="link2_cover", tip_link="link5")
    assert sub.dof == 3 and sub.joint_type == ("revolute", "prismatic", "revolute")
    q = full.random_joints(30, rng=0)
    fr = fk_frames(full, q)
    # sub-chain pose = inverse(frame of link2_cover) · frame of link5 in the full chain
    cover = fr.link[:, 1] @ se3.xyzrpy_to_transform([0.3, 0.02, -0.01], [0.3, 0, -0.2])
    np.testing.assert_allclose(fk(sub, q[:, 2:5]), se3.invert(cover) @ fr.link[:, 4], atol=1e-12)
    # the camera branch is not part of the default chain; naming it as the tip gives a 3-joint robot
    cam = load_urdf(DATA / "test_arm.urdf", tip_link="camera")
    assert cam.dof == 3


def test_urdf_fixed_joint_masses_merged():
    r = load_urdf(DATA / "test_arm.urdf")
    # link2 (3 kg at (0.2, 0, 0.03)) + link2_cover (1 kg at (0.05, 0.01, 0) in its own frame)
    Tc = se3.xyzrpy_to_transform([0.3, 0.02, -0.01], [0.3, 0, -0.2])
    c_cover = (Tc @ np.array([0.05, 0.01, 0.0, 1.0]))[:3]
    assert r.mass_kg[1] == pytest.approx(4.0)
    np.testing.assert_allclose(r.com_m[1], (3 * np.array([0.2, 0, 0.03]) + c_cover) / 4, atol=1e-15)
    np.testing.assert_allclose(r.mass_kg, [4.5, 4.0, 2.0, 0.0, 0.5, 0.0])


URDF_OK = """<robot name="r"><link name="a"/><link name="b"/>
<joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
<limit lower="-1" upper="1" effort="1" velocity="1"/></joint></robot>"""


@pytest.mark.parametrize(
    "text, must_contain",
    [
        ("<robot", ["invalid XML"]),
        ("<robo/>", ["<robot>"]),
        (URDF_OK.replace('<limit lower="-1" upper="1" effort="1" velocity="1"/>', ""), ["joint 'j'", "<limit"]),
        (URDF_OK.replace('lower="-1"', 'lower="abc"'), ["joint 'j'", "lower"]),
        (URDF_OK.replace('xyz="0 0 1"', 'xyz="0 0"'), ["joint 'j'", "axis"]),
        (URDF_OK.replace('xyz="0 0 1"', 'xyz="0 0 0"'), ["joint 'j'", "non-zero"]),
        (URDF_OK.replace('type="revolute"', 'type="floating"'), ["joint 'j'", "floating"]),
        (URDF_OK.replace('<child link="b"/>', '<child link="c"/>'), ["joint 'j'", "'c'"]),
        (URDF_OK.replace('lower="-1"', 'lower="2"'), ["joint 'j'", "lower > upper"]),
        (URDF_OK.replace('type="revolute"', 'type="fixed"'), ["no movable joint"]),
    ],
)
def test_urdf_errors_name_file_and_element(tmp_path, text, must_contain):
    p = _write(tmp_path, text, "bad.urdf")
    with pytest.raises(RobotFileError) as e:
        load_urdf(p)
    msg = str(e.value)
    assert "bad.urdf" in msg
    for s in must_contain:
        assert s in msg, (s, msg)


def test_urdf_bad_links_named():
    with pytest.raises(RobotFileError, match="tip_link 'zz'"):
        load_urdf(DATA / "test_arm.urdf", tip_link="zz")
    with pytest.raises(RobotFileError, match="not below"):
        load_urdf(DATA / "test_arm.urdf", base_link="link3", tip_link="link2")
    two_tips = URDF_OK.replace("</robot>", '<link name="c"/><joint name="k" type="revolute"><parent link="a"/>'
                               '<child link="c"/><limit lower="-1" upper="1"/></joint></robot>')
    with pytest.raises(RobotFileError, match="name tip_link"):
        load_urdf_string(two_tips, where="two.urdf")


def test_export_then_load_keeps_limits_and_mass():
    r = load_robot("ur10")
    back = load_urdf_string(robot_to_urdf(r))
    np.testing.assert_allclose(back.lower, r.lower)
    np.testing.assert_allclose(back.mass_kg, r.mass_kg)
    # COM at the same world point (frames differ: URDF link frame = joint frame here)
    q = r.random_joints(10, rng=0)
    fa, fb = fk_frames(r, q), fk_frames(back, q)
    ca = np.einsum("knij,nj->kni", fa.link[..., :3, :3], r.com_m) + fa.link[..., :3, 3]
    cb = np.einsum("knij,nj->kni", fb.link[..., :3, :3], back.com_m) + fb.link[..., :3, 3]
    np.testing.assert_allclose(ca, cb, atol=1e-12)


# --------------------------------------------------------------------------- FK cache rule


def test_chain_cache_follows_geometry_changes():
    r = load_robot("ur5")
    q = r.random_joints(1, rng=0)[0]
    T0 = fk(r, q)
    r.d_m = r.d_m + np.array([0.01, 0, 0, 0, 0, 0])  # new array: new chain
    np.testing.assert_allclose(fk(r, q)[:3, 3] - T0[:3, 3], [0, 0, 0.01], atol=1e-15)
    with pytest.raises(ValueError):  # in-place edits of a cached robot's geometry are refused
        r.a_m[1] += 0.1
    c = r.copy(a_m=r.a_m * 2)  # copies are independent and writeable
    c.theta_rad[0] = 0.3
    assert not np.allclose(fk(c, q), fk(r, q))


_SIX = """name = "own"
convention = "dh"
length_unit = "mm"
angle_unit = "{au}"
{top}
[[joints]]
a = 150
alpha = {alpha}
d = 450
theta = {theta}
min = {lo}
max = {hi}
[[joints]]
a = 600
alpha = 0
d = 0
min = -1.5
max = 1.5
[tool]
xyz = [0, 0, 100]
rpy = {rpy}
"""


def _own(au="deg", alpha=-90, theta=0, lo=-170, hi=170, rpy="[0, 0, 0]", top=""):
    from hykin.io.robot_toml import robot_from_toml_text

    return robot_from_toml_text(_SIX.format(au=au, alpha=alpha, theta=theta, lo=lo, hi=hi, rpy=rpy, top=top), "own.toml")


def test_robot_file_values_in_the_wrong_angle_unit_are_refused_naming_the_key():
    from hykin.io.robot_file import RobotFileError

    r = _own(theta=45, lo=-400, hi=400, rpy="[0, 90, 180]")  # correct degree values, a ±400° axis
    assert r.upper[0] == pytest.approx(np.radians(400)) and r.theta_rad[0] == pytest.approx(np.pi / 4)
    r = _own(au="rad", alpha=-1.5707963, lo=-6.98, hi=6.98)  # the same in radians
    assert r.upper[0] == pytest.approx(6.98)
    for kw, msg in [(dict(theta=-1.5707963), r"joints\[1\]\.theta: -1\.5707963 deg is -π/2 .* a radian value"),
                    (dict(rpy="[0, 0, 3.14159265]"), r"\[tool\]\.rpy: 3\.1415927 deg is π"),
                    (dict(au="rad", alpha=-1.5708, lo=-170, hi=170), r"joints\[1\]: a joint limit of 170 rad .* look like degrees"),
                    (dict(lo=160, hi=-100), r"joints\[1\]: min = 160 is above max = -100"),
                    (dict(top="payload = -5"), r"payload = -5: must be a mass >= 0")]:
        with pytest.raises(RobotFileError, match=msg):
            _own(**kw)


def test_robot_file_limits_in_radians_under_degrees_and_a_payload_in_grams_are_refused():
    from hykin.io.robot_file import RobotFileError

    with pytest.raises(RobotFileError, match=r"joints\[1\]\.min: -3\.14159 deg is -π .* a radian value"):
        _own(lo=-3.14159, hi=3.14159)
    with pytest.raises(RobotFileError, match=r"payload = 5000 kg, more than any serial robot carries"):
        _own(top="payload = 5000")
    assert _own(lo=-180, hi=180, top="payload = 2300").payload_kg == 2300


def test_cli_prismatic_joint_columns_follow_length_unit(tmp_path, capsys):
    """Probe report s40: ``fk`` had no --length-unit and ``ik --seed-joints`` / ``compensate`` hints read a
    prismatic column in metres whatever --length-unit said (a rail hint of 1.0 mm taken as 1.0 m).
    Reference: the robot's FK of the joints in SI."""
    from cli_run import run

    (tmp_path / "r.toml").write_text(M_RAD)
    rob = load_robot(tmp_path / "r.toml")
    Q = rob.random_joints(6, rng=2)
    rows = ["q1,q2"] + [f"{float(q[0])!r},{float(q[1]) * 1e3!r}" for q in Q]  # the prismatic joint in mm
    (tmp_path / "j.csv").write_text("\n".join(rows) + "\n")
    code, _, err = run(["fk", tmp_path / "r.toml", tmp_path / "j.csv", "-o", tmp_path / "p.csv", "--length-unit", "mm"], capsys)
    assert code == 0, err
    got = np.loadtxt(tmp_path / "p.csv", delimiter=",", skiprows=1, usecols=(2, 3, 4))
    np.testing.assert_allclose(got, fk(rob, Q)[:, :3, 3], atol=1e-12)
    code, _, err = run(["fk", tmp_path / "r.toml", tmp_path / "j.csv", "-o", tmp_path / "p2.csv"], capsys)
    assert code != 0 and "outside the limits" in err  # mm read as m: 100 m of a 0.25 m axis
