"""A URDF whose branches all end in fixed frames bolted to the same link (probe s41 AI: a rail robot's
``ee_link`` and ``smr_tcp`` after ``wrist_3_link``): without ``--tip`` the longest path was taken silently
(122 mm / 120° from ``ee_link``). Such ends differ by their offsets: refused naming them."""

from __future__ import annotations

import numpy as np
import pytest

from hykin import fk, load_robot
from hykin.io.robot_file import RobotFileError

_URDF = """<robot name="r2">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="ee_link"/><link name="tool0"/><link name="smr"/>
  <link name="cam"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 0 1"/><limit lower="-3" upper="3" effort="1" velocity="1"/></joint>
  <joint name="cam_mount" type="fixed"><parent link="l1"/><child link="cam"/><origin xyz="0.1 0 0"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.5 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="ee" type="fixed"><parent link="l2"/><child link="ee_link"/><origin xyz="0.3 0 0"/></joint>
  <joint name="t0" type="fixed"><parent link="l2"/><child link="tool0"/><origin xyz="0.3 0 0" rpy="0 1.5708 0"/></joint>
  <joint name="s" type="fixed"><parent link="tool0"/><child link="smr"/><origin xyz="0 0 0.12"/></joint>
</robot>
"""


def test_fixed_frames_bolted_to_the_same_link_are_not_chosen_silently(tmp_path):
    p = tmp_path / "r2.urdf"
    p.write_text(_URDF)
    with pytest.raises(RobotFileError, match=r"several chain ends \(ee_link, smr\)"):
        load_robot(str(p))
    q = np.array([[0.3, -0.5]])
    # each named end: the frames as written (own FK: z-rotation, then a y-rotation, then the offsets)
    c, s = np.cos(q[0, 0]), np.sin(q[0, 0])
    R1 = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    c2, s2 = np.cos(q[0, 1]), np.sin(q[0, 1])
    R2 = np.array([[c2, 0, s2], [0, 1, 0], [-s2, 0, c2]])
    p2 = np.array([0, 0, 0.4]) + R1 @ np.array([0.5, 0, 0])
    ee = p2 + R1 @ R2 @ np.array([0.3, 0, 0])
    np.testing.assert_allclose(fk(load_robot(str(p), tip_link="ee_link"), q)[0, :3, 3], ee, atol=1e-12)
    Ry = np.array([[np.cos(1.5708), 0, np.sin(1.5708)], [0, 1, 0], [-np.sin(1.5708), 0, np.cos(1.5708)]])
    smr = ee + R1 @ R2 @ Ry @ np.array([0, 0, 0.12])
    np.testing.assert_allclose(fk(load_robot(str(p), tip_link="smr"), q)[0, :3, 3], smr, atol=1e-12)
