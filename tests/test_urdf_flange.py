"""Program tools on a URDF robot are given from its flange link, not from the last moving link (probe
report s40: a maker's URDF with link_6 -> flange (115 mm) -> tool0 -> tcp; a KRL TOOL_DATA and
``compensate --tool`` given from the flange landed 115 mm off). The reference: the chain end's pose
(``fk`` with the URDF read to ``link_6``) times the flange offsets written here, times the program's tool."""

from __future__ import annotations

import numpy as np
import pytest
from comp_models import ExactModel

from hykin import fk
from hykin.compensation import krl, rapid
from hykin.compensation.programs import compensate_program
from hykin.geometry import se3
from hykin.io.urdf import load_urdf_string
from hykin.io.urdf_flange import choose_flange, flange_candidates, flange_of
from hykin.kinematics.robot import RobotFileError

_J = [("joint_a1", "base_link", "link_1", "0 0 0.45", "0 0 -1", 2.9), ("joint_a2", "link_1", "link_2", "0.26 0 0.225", "0 1 0", 2.4),
      ("joint_a3", "link_2", "link_3", "0.68 0 0", "0 1 0", 2.1), ("joint_a4", "link_3", "link_4", "0.2 0 0.035", "-1 0 0", 6.0),
      ("joint_a5", "link_4", "link_5", "0.47 0 0", "0 1 0", 2.1), ("joint_a6", "link_5", "link_6", "0 0 0", "-1 0 0", 6.0)]
FLANGE = se3.trans(0.115, 0.0, 0.0)  # link_6 -> flange (x out of the flange)
TOOL0 = se3.roty(np.pi / 2)  # flange -> tool0 (z out)


def _urdf() -> str:
    links = ["base_link"] + [j[2] for j in _J] + ["flange", "tool0", "tcp"]
    out = ['<robot name="acme">'] + [f'<link name="{n}"/>' for n in links]
    for n, p, c, xyz, ax, lim in _J:
        out.append(f'<joint name="{n}" type="revolute"><parent link="{p}"/><child link="{c}"/><origin xyz="{xyz}"/>'
                   f'<axis xyz="{ax}"/><limit lower="{-lim}" upper="{lim}" effort="1" velocity="1"/></joint>')
    out.append('<joint name="f" type="fixed"><parent link="link_6"/><child link="flange"/><origin xyz="0.115 0 0"/></joint>')
    out.append('<joint name="t0" type="fixed"><parent link="flange"/><child link="tool0"/><origin rpy="0 1.5707963267948966 0"/></joint>')
    out.append('<joint name="tc" type="fixed"><parent link="tool0"/><child link="tcp"/><origin xyz="0 0 0.18"/></joint>')
    return "\n".join(out + ["</robot>"])


@pytest.fixture(scope="module")
def setup():
    text = _urdf()
    rob = load_urdf_string(text, tip_link="tcp")
    end = load_urdf_string(text, tip_link="link_6")  # the chain end: the last moving link
    q = np.radians([[10.0, -60.0, 80.0, 20.0, 40.0, 30.0], [-25.0, -50.0, 95.0, -30.0, 55.0, -20.0]])
    return ExactModel(rob, rob), end, q


def test_candidates_and_defaults(setup):
    m, _, _ = setup
    c = flange_candidates(m.nominal)
    assert list(c) == ["link_6", "flange", "tool0", "tcp"]
    np.testing.assert_allclose(c["flange"], FLANGE, atol=1e-12)
    np.testing.assert_allclose(c["tool0"], FLANGE @ TOOL0, atol=1e-12)
    for fmt, want in (("krl", "flange"), ("csv", "flange"), ("rapid", "tool0"), ("urscript", "tool0")):
        r, note = choose_flange(m.nominal, fmt)
        assert r.urdf["flange_link"] == want and f"'{want}'" in note and "--flange" in note
    r, _ = choose_flange(m.nominal, "krl", "tool0")
    np.testing.assert_allclose(flange_of(r), FLANGE @ TOOL0, atol=1e-12)
    with pytest.raises(RobotFileError, match="link_6, flange, tool0, tcp"):
        choose_flange(m.nominal, "krl", "link_5")
    from hykin.io.robot_file import load_robot

    with pytest.raises(RobotFileError, match="not read from a URDF"):
        choose_flange(load_robot("rx160"), "krl", "flange")


def _lands(m, end, res, q, tcp_from_end):
    """The exact robot at the compensated joints puts the program TCP where the literal says."""
    assert res.n_compensated == len(q), res.failed
    got = fk(end, res.comp.q) @ tcp_from_end
    want = fk(end, q) @ tcp_from_end
    assert np.linalg.norm(got[:, :3, 3] - want[:, :3, 3], axis=1).max() < 1e-6


def test_krl_tool_data_is_given_from_the_flange_link(setup):
    m, end, q = setup
    tool = se3.make_transform(krl.matrix_from_abc(0.0, 90.0, 0.0), np.array([0.18, 0.0, 0.0]))  # {X 180, B 90}
    T = fk(end, q) @ FLANGE @ tool
    lines = []
    for P in T:
        a, b, c = krl.abc_from_matrix(P[:3, :3])
        x, y, z = P[:3, 3] * 1e3
        lines.append(f"LIN {{X {x:.6f},Y {y:.6f},Z {z:.6f},A {a:.8f},B {b:.8f},C {c:.8f}}}")
    src = "DEF t()\n$BASE = $NULLFRAME\n$TOOL = TOOL_DATA[1]\n" + "\n".join(lines) + "\nEND\n"
    res = compensate_program(m, src, krl, frame="measurement", context="TOOL_DATA[1]={X 180,Y 0,Z 0,A 0,B 90,C 0}")
    assert any("URDF link 'flange'" in n for n in res.notes)
    _lands(m, end, res, q, FLANGE @ tool)


def test_rapid_tooldata_is_given_from_tool0(setup):
    m, end, q = setup
    tool = se3.trans(0.0, 0.0, 0.2)
    T = fk(end, q) @ FLANGE @ TOOL0 @ tool
    from scipy.spatial.transform import Rotation

    from hykin.compensation.branches import abb_confdata

    conf = abb_confdata(m.nominal, q)
    body = []
    for k, P in enumerate(T):
        x, y, z, w = Rotation.from_matrix(P[:3, :3]).as_quat()
        p = P[:3, 3] * 1e3
        body.append(f"  CONST robtarget p{k}:=[[{p[0]:.6f},{p[1]:.6f},{p[2]:.6f}],[{w:.10f},{x:.10f},{y:.10f},{z:.10f}],"
                    f"[{','.join(str(int(c)) for c in conf[k])}],[9E+09,9E+09,9E+09,9E+09,9E+09,9E+09]];")
    moves = [f"    MoveL p{k}, v100, fine, tGrip\\WObj:=wobj0;" for k in range(len(T))]
    mod = ("MODULE M\n  PERS tooldata tGrip:=[TRUE,[[0,0,200],[1,0,0,0]],[1,[0,0,1],[1,0,0,0],0,0,0]];\n"
           + "\n".join(body) + "\n  PROC main()\n" + "\n".join(moves) + "\n  ENDPROC\nENDMODULE\n")
    res = compensate_program(m, mod, rapid, frame="measurement")
    assert res.n_compensated == len(q), res.failed
    got = fk(end, res.comp.q) @ FLANGE @ TOOL0 @ tool
    assert np.linalg.norm(got[:, :3, 3] - T[:, :3, 3], axis=1).max() < 1e-6


def test_several_tips_message_names_the_arm_end_links():
    """Probe report s40: a gripper's two fingers made "several tips (finger_left, finger_right)" without the
    links a user means (flange, tool0, tcp)."""
    fingers = ('<link name="fl"/><link name="fr"/>'
               '<joint name="jl" type="prismatic"><parent link="tool0"/><child link="fl"/><axis xyz="0 1 0"/>'
               '<limit lower="0" upper="0.04" effort="1" velocity="1"/></joint>'
               '<joint name="jr" type="prismatic"><parent link="tool0"/><child link="fr"/><axis xyz="0 -1 0"/>'
               '<limit lower="0" upper="0.04" effort="1" velocity="1"/></joint>')
    text = _urdf().replace("</robot>", fingers + "</robot>")
    with pytest.raises(RobotFileError, match=r"several tips \(fl, fr\).*arm's end: link_6, flange, tool0, tcp"):
        load_urdf_string(text)
    assert load_urdf_string(text, tip_link="tcp").dof == 6
