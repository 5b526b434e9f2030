"""URDF robots as makers ship them (issue #24): <mimic> joints, several tips, dead-end branches,
prismatic / continuous / fixed joints, joint columns by URDF name, calibrated URDF written back.

The robot is ``tests/data/construction_robot.urdf``: a lifting column whose one actuated prismatic
joint drives two mimic stages (multipliers 0.8 and 0.5, offsets), a 6R arm with a continuous wrist,
a TCP tip and a pan-mounted camera tip, and a laser frame bolted to a link (a dead end).
References: a chain walk over the raw XML written here, Pinocchio (its URDF parser honours
``<mimic>`` with ``mimic=True``), finite differences.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from hykin.calibration.jacobian import identification_jacobian
from hykin.calibration.params import apply_deviations, parameter_names
from hykin.geometry import se3
from hykin.io.dataset_files import read_dataset
from hykin.io.dataset import DatasetError
from hykin.io.modelfile import robot_from_json_dict, robot_to_dict
from hykin.io.urdf import calibrated_robot_urdf, load_urdf, load_urdf_string, robot_to_urdf
from hykin.kinematics.fk import fk, fk_torch, jacobian
from hykin.kinematics.ik import ik
from hykin.kinematics.robot import RobotFileError

DATA = Path(__file__).parent / "data"
URDF = DATA / "construction_robot.urdf"
INDEP = ("column_lift", "a1", "a2", "a3", "a4", "a5", "a6")


@pytest.fixture(scope="module")
def robot():
    return load_urdf(URDF, tip_link="tcp")


# --------------------------------------------------------------------------- reference walk (raw XML)


def _ref_fk(xml: str, tip: str, values: dict[str, float]) -> np.ndarray:
    """TCP pose from the URDF text alone: origin · motion per joint from the root to ``tip``; a mimic
    joint's value is multiplier · leader + offset (URDF spec)."""
    root = ET.fromstring(xml)
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    by_name = {j.get("name"): j for j in root.findall("joint")}
    path, ln = [], tip
    while ln in joints:
        path.append(joints[ln])
        ln = joints[ln].find("parent").get("link")
    T = np.eye(4)
    for j in reversed(path):
        o = j.find("origin")
        xyz = [float(v) for v in o.get("xyz", "0 0 0").split()] if o is not None else [0.0] * 3
        rpy = [float(v) for v in o.get("rpy", "0 0 0").split()] if o is not None else [0.0] * 3
        O = np.eye(4)
        O[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()  # URDF rpy: fixed-axis roll, pitch, yaw
        O[:3, 3] = xyz
        T = T @ O
        if j.get("type") == "fixed":
            continue
        v = _ref_value(by_name, values, j.get("name"))
        ax = np.array([float(a) for a in j.find("axis").get("xyz").split()])
        ax /= np.linalg.norm(ax)
        M = np.eye(4)
        if j.get("type") == "prismatic":
            M[:3, 3] = v * ax
        else:
            M[:3, :3] = Rotation.from_rotvec(v * ax).as_matrix()
        T = T @ M
    return T


def _ref_value(by_name: dict, values: dict, name: str) -> float:
    """A joint's value: its own, or (mimic, also of a mimic) multiplier · leader's value + offset."""
    m = by_name[name].find("mimic")
    if m is None:
        return values[name]
    return float(m.get("multiplier", 1)) * _ref_value(by_name, values, m.get("joint")) + float(m.get("offset", 0))


def test_mimic_robot_has_independent_joints_only(robot):
    assert robot.dof == 7 and robot.n_chain == 9
    assert robot.independent_joint_names == INDEP
    assert robot.independent_joint_type == ("prismatic",) + ("revolute",) * 6
    np.testing.assert_allclose(robot.mimic[1:3], [[0, 0.8, 0.02], [0, 0.5, -0.01]])
    assert robot.lower.shape == (7,) and robot.upper[-1] == pytest.approx(np.pi)  # a6: continuous


def test_fk_matches_reference_walk_and_pinocchio(robot):
    q = robot.random_joints(20, rng=1)
    T = fk(robot, q)
    xml = URDF.read_text()
    for k in range(len(q)):
        ref = _ref_fk(xml, "tcp", dict(zip(INDEP, q[k])))
        np.testing.assert_allclose(T[k], ref, atol=1e-13)
    np.testing.assert_allclose(fk(robot, q[3]), T[3], atol=1e-15)  # single-pose path
    pin = pytest.importorskip("pinocchio")
    m = pin.buildModelFromXML(xml, True)
    d = m.createData()
    fid = m.getFrameId("tcp")
    for k in range(len(q)):
        qp = pin.neutral(m)
        for nm, v in zip(INDEP, q[k]):
            i = m.joints[m.getJointId(nm)].idx_q
            if nm == "a6":  # continuous: (cos, sin)
                qp[i], qp[i + 1] = np.cos(v), np.sin(v)
            else:
                qp[i] = v
        pin.framesForwardKinematics(m, d, qp)
        np.testing.assert_allclose(d.oMf[fid].homogeneous, T[k], atol=1e-13)


def test_torch_fk_and_jacobian_chain_rule(robot):
    torch = pytest.importorskip("torch")
    q = robot.random_joints(6, rng=2)
    qt = torch.tensor(q, requires_grad=True)
    Tt = fk_torch(robot, qt)
    np.testing.assert_allclose(Tt.detach().numpy(), fk(robot, q), atol=1e-14)
    J = jacobian(robot, q)
    assert J.shape == (6, 6, 7)
    # position rows: autograd of the torch walk; and central differences of the numpy FK
    g = torch.autograd.grad(Tt[:, 0, 3].sum(), qt)[0].numpy()
    np.testing.assert_allclose(J[:, 0, :], g, atol=1e-12)
    h = 1e-6
    for j in range(7):
        dq = np.zeros(7)
        dq[j] = h
        fd = (fk(robot, q + dq)[:, :3, 3] - fk(robot, q - dq)[:, :3, 3]) / (2 * h)
        np.testing.assert_allclose(J[:, :3, j], fd, atol=1e-8)


def test_identification_jacobian_of_mimic_origins_against_differences(robot):
    q = robot.random_joints(8, rng=4)
    names, J = identification_jacobian(robot, q, position_only=True, compliance=False)
    h = 1e-7
    for name in ("o2.x", "o2.rz", "o3.z", "o3.ry", "o1.z", "o5.rx"):  # o2, o3: the mimic stages
        k = names.index(name)
        fd = (fk(apply_deviations(robot, {name: h}), q)[:, :3, 3] - fk(apply_deviations(robot, {name: -h}), q)[:, :3, 3]) / (2 * h)
        np.testing.assert_allclose(J[:, :, k], fd, atol=1e-7, err_msg=name)
    assert len(names) == 12 + 9 * 6  # base, tool, one twist per chain joint origin (mimic ones included)


def test_ik_through_mimic_joints(robot):
    q = robot.random_joints(4, rng=3, margin=0.1)
    T = fk(robot, q)
    res = ik(robot, T, q_seed=q + 0.05)
    assert res.success.all()
    np.testing.assert_allclose(fk(robot, res.q), T, atol=1e-9)


# --------------------------------------------------------------------------- tips and branches


def test_several_tips_refused_in_one_line_and_dead_end_ignored():
    with pytest.raises(RobotFileError) as e:
        load_urdf(URDF)
    msg = str(e.value)
    assert "\n" not in msg and "camera_link" in msg and "tcp" in msg and "--tip" in msg
    assert "laser_frame" not in msg  # a dead-end branch of fixed joints is no tip
    cam = load_urdf(URDF, tip_link="camera_link")
    assert cam.dof == 2 and cam.n_chain == 4  # the column (1 + 2 mimic) and the camera pan
    sub = load_urdf(URDF, base_link="arm_mount", tip_link="tcp")
    assert sub.dof == 6 and sub.mimic is None


def test_mimic_leader_off_chain_refused():
    xml = URDF.read_text()
    with pytest.raises(RobotFileError, match="column_stage2.*not on the chain"):
        load_urdf_string(xml, base_link="column_1", tip_link="tcp", where="c.urdf")
    bad = xml.replace('<mimic joint="column_lift" multiplier="0.5"', '<mimic joint="nope" multiplier="0.5"')
    with pytest.raises(RobotFileError, match="nope"):
        load_urdf_string(bad, tip_link="tcp")


# --------------------------------------------------------------------------- files


def _calibrated(robot, seed=0):
    rng = np.random.default_rng(seed)
    dev = {n: rng.normal(0, 1e-3) for n in parameter_names(robot, compliance=False)}
    return apply_deviations(robot, dev).copy(base=se3.xyzrpy_to_transform([12.0, -30.0, 1.5], [0.01, -0.02, 0.7]))


def test_calibrated_urdf_round_trip(robot):
    cal = _calibrated(robot)
    text, left = calibrated_robot_urdf(cal)
    assert left == ""
    back = load_urdf_string(text, tip_link="tcp")
    q = robot.random_joints(200, rng=5)
    assert np.abs(fk(back, q)[:, :3, 3] - fk(cal, q)[:, :3, 3]).max() < 1e-12
    assert np.abs(fk(back, q)[:, :3, :3] - fk(cal, q)[:, :3, :3]).max() < 1e-12
    assert text.count("<mimic") == 2 and "camera_pan" in text and "laser_mount" in text
    np.testing.assert_array_equal(back.mimic, robot.mimic)
    soft = cal.copy(stiffness_nm_per_rad=np.full(9, 1e6))
    assert calibrated_robot_urdf(soft)[1].startswith("joint compliance (the URDF's rigid FK is")
    # a chain that ends in a movable joint: the calibrated tool goes to a new link <tip>_tcp
    arm = load_urdf(URDF, base_link="arm_mount", tip_link="a_link6")
    arm_cal = arm.copy(tool=se3.xyzrpy_to_transform([0.01, 0.02, 0.15], [0.1, 0.0, 0.0]))
    back = load_urdf_string(calibrated_robot_urdf(arm_cal)[0], base_link="arm_mount", tip_link="a_link6_tcp")
    qa = arm.random_joints(20, rng=5)
    np.testing.assert_allclose(fk(back, qa), fk(arm_cal, qa), atol=1e-12)


def test_generic_urdf_export_keeps_mimic(robot):
    back = load_urdf_string(robot_to_urdf(robot))
    q = robot.random_joints(50, rng=6)
    np.testing.assert_allclose(fk(back, q), fk(robot, q), atol=1e-12)
    assert back.dof == 7


def test_model_file_codec_keeps_mimic_names_and_urdf(robot):
    back = robot_from_json_dict(robot_to_dict(robot))
    np.testing.assert_array_equal(back.mimic, robot.mimic)
    assert back.joint_names == robot.joint_names and back.urdf == robot.urdf
    q = robot.random_joints(10, rng=7)
    np.testing.assert_array_equal(fk(back, q), fk(robot, q))
    from hykin.io.robot_file import load_robot

    assert "mimic" not in robot_to_dict(load_robot("ur10"))  # files of other robots unchanged


def _write_csv(path, header, rows):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in rows) + "\n")


def test_joint_columns_by_urdf_name(robot, tmp_path):
    q = robot.random_joints(30, rng=8)
    xyz = fk(robot, q)[:, :3, 3]
    _write_csv(tmp_path / "q.csv", [f"q{i + 1}" for i in range(7)] + ["x", "y", "z"], np.hstack([q, xyz]))
    perm = [3, 0, 6, 1, 2, 5, 4]  # any column order
    _write_csv(tmp_path / "n.csv", [INDEP[i] for i in perm] + ["x", "y", "z"], np.hstack([q[:, perm], xyz]))
    a = read_dataset(tmp_path / "q.csv", robot=robot)
    b = read_dataset(tmp_path / "n.csv", robot=robot)
    np.testing.assert_array_equal(a.q, b.q)
    assert not b.extra
    # a ROS-style log with the mimic joints' values too: checked against <mimic>, then redundant
    mim = np.stack([0.8 * q[:, 0] + 0.02, 0.5 * q[:, 0] - 0.01], 1)
    _write_csv(tmp_path / "m.csv", list(INDEP) + ["column_stage2", "column_stage3", "x", "y", "z"], np.hstack([q, mim, xyz]))
    np.testing.assert_array_equal(read_dataset(tmp_path / "m.csv", robot=robot).q, a.q)
    mim[5, 1] += 0.01
    _write_csv(tmp_path / "w.csv", list(INDEP) + ["column_stage2", "column_stage3", "x", "y", "z"], np.hstack([q, mim, xyz]))
    with pytest.raises(DatasetError, match="row 6.*column_stage3"):
        read_dataset(tmp_path / "w.csv", robot=robot)
    typo = ["colum_lift"] + list(INDEP[1:]) + ["x", "y", "z"]
    _write_csv(tmp_path / "t.csv", typo, np.hstack([q, xyz]))
    with pytest.raises(DatasetError) as e:
        read_dataset(tmp_path / "t.csv", robot=robot)
    msg = str(e.value)
    assert "\n" not in msg and "'colum_lift'" in msg and "column_lift, a1, a2" in msg


# --------------------------------------------------------------------------- generated chains (Hypothesis)


@st.composite
def _mimic_chains(draw):
    """URDF text of a random serial chain: 2-7 movable joints (revolute / prismatic / continuous),
    fixed joints between some of them, random origins and axes, and mimic joints (of any joint,
    before or after their leader, mimic of a mimic) with random multipliers and offsets."""
    n = draw(st.integers(2, 7))
    f = st.floats(-1.0, 1.0, allow_nan=False)
    kinds = [draw(st.sampled_from(["revolute", "prismatic", "continuous"])) for _ in range(n)]
    lead = [None] * n
    for i in range(n):
        if draw(st.booleans()) and draw(st.booleans()):  # about a quarter are mimic joints
            lead[i] = draw(st.integers(0, n - 1).filter(lambda k, i=i: k != i))
    for i in range(n):  # break cycles: follow leaders; a cycle makes its first joint independent
        seen, k = {i}, lead[i]
        while k is not None and k not in seen:
            seen.add(k)
            k = lead[k]
        if k is not None:
            lead[i] = None
    links = ['<link name="l0"/>']
    joints, parent = [], "l0"
    for i in range(n):
        if draw(st.booleans()):
            links.append(f'<link name="f{i}"/>')
            joints.append(f'<joint name="fix{i}" type="fixed"><parent link="{parent}"/><child link="f{i}"/>'
                          f'<origin xyz="{draw(f)} {draw(f)} {draw(f)}" rpy="{draw(f)} {draw(f)} {draw(f)}"/></joint>')
            parent = f"f{i}"
        ax = [draw(f) for _ in range(3)]
        if np.linalg.norm(ax) < 0.1:
            ax = [0.0, 0.0, 1.0]
        lim = "" if kinds[i] == "continuous" else '<limit lower="-1.5" upper="1.5"/>'
        mim = "" if lead[i] is None else \
            f'<mimic joint="j{lead[i]}" multiplier="{draw(st.floats(-2, 2))}" offset="{draw(st.floats(-0.5, 0.5))}"/>'
        links.append(f'<link name="l{i + 1}"/>')
        joints.append(f'<joint name="j{i}" type="{kinds[i]}"><parent link="{parent}"/><child link="l{i + 1}"/>'
                      f'<origin xyz="{draw(f)} {draw(f)} {draw(f)}" rpy="{draw(f)} {draw(f)} {draw(f)}"/>'
                      f'<axis xyz="{ax[0]} {ax[1]} {ax[2]}"/>{lim}{mim}</joint>')
        parent = f"l{i + 1}"
    return f'<robot name="gen">{"".join(links)}{"".join(joints)}</robot>', f"l{n}"


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(_mimic_chains(), st.integers(0, 2**31 - 1))
def test_generated_mimic_chains_against_reference(chain, seed):
    xml, tip = chain
    r = load_urdf_string(xml)
    names = r.independent_joint_names
    q = r.random_joints(4, rng=seed)
    T = fk(r, q)
    for k in range(len(q)):
        np.testing.assert_allclose(T[k], _ref_fk(xml, tip, dict(zip(names, q[k]))), atol=1e-12)
    h = 1e-6
    J = jacobian(r, q)
    for j in range(r.dof):
        dq = np.zeros(r.dof)
        dq[j] = h
        fd = (fk(r, q + dq)[:, :3, 3] - fk(r, q - dq)[:, :3, 3]) / (2 * h)
        np.testing.assert_allclose(J[:, :3, j], fd, atol=1e-7)
    back = load_urdf_string(calibrated_robot_urdf(r)[0])  # the maker's file written back unchanged in FK
    np.testing.assert_allclose(fk(back, q), T, atol=1e-12)


def test_compiled_hybrid_fk_is_not_used_for_mimic_chains(robot):
    """The compiled small-batch hybrid FK walks independent joints only: a robot with <mimic> joints takes
    the numpy path (found by the battery: a 40-row evaluation of a mimic model was metres off, the
    112-row one right)."""
    from types import SimpleNamespace

    from hykin.hybrid.fast_fk import kernel_of

    model = SimpleNamespace(fade=True, net_pos_=object(), robot_=robot)
    assert model.robot_.n_chain > model.robot_.dof
    assert kernel_of(model) is None
