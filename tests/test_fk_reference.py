"""Forward kinematics, link frames and Jacobians against Pinocchio and published robot descriptions.

References, all independent of hykin's chain builder:

* a Pinocchio model built here from DH / MDH parameters with this file's own transform formulas
  (``pin.SE3`` joint placements, ``JointModelRZ`` / ``PZ``);
* Pinocchio's URDF parser on ``robot_to_urdf`` output and on the hand-written ``tests/data/test_arm.urdf``;
* published robot descriptions for the presets: ROS ``ur_description`` (UR5), ``franka_description``
  (Panda), RobotLocomotion/drake ``iiwa14`` URDF, and the OPW closed-form FK of Brandstoetter et al.
  (2014) for the KUKA KR6 R900 and ABB IRB2400 presets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pin = pytest.importorskip("pinocchio")

from hykin.io.robot_file import list_presets, load_robot
from hykin.io.urdf import load_urdf, load_urdf_string, robot_to_urdf
from hykin.kinematics.chain import chain_of
from hykin.kinematics.fk import fk, fk_frames, fk_torch, jacobian
from hykin.kinematics.robot import dh_to_mdh, mdh_to_dh
from hykin.kinematics.walk import chain_walk

DATA = Path(__file__).parent / "data"
TOL = 1e-12
N_CONFIGS = 1000
PRESETS = list_presets()


# --------------------------------------------------------------------------- independent formulas


def _rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s, 0], [0, 1, 0, 0], [-s, 0, c, 0], [0, 0, 0, 1.0]])


def _rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


def _tr(x=0.0, y=0.0, z=0.0):
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _se3(T):
    return pin.SE3(np.array(T[:3, :3]), np.array(T[:3, 3]))


def pin_model_from_dh(robot):
    """Pinocchio model of a DH/MDH robot; frames ``link_i`` (hykin link frame i) and ``tcp``."""
    model = pin.Model()
    parent, tail = 0, robot.base.copy()  # tail: transform from the previous joint frame (after q)
    links = []
    for i in range(robot.dof):
        a, al, d, th, be = (robot.a_m[i], robot.alpha_rad[i], robot.d_m[i], robot.theta_rad[i], robot.beta_rad[i])
        prism = robot.joint_type[i] == "prismatic"
        if robot.convention == "dh":  # Rz(th+q) Tz(d) Tx(a) Rx(al) Ry(be)   (q adds to d if prismatic)
            place = tail @ _rz(th) @ (_tr(z=d) if prism else np.eye(4))
            after = (np.eye(4) if prism else _tr(z=d)) @ _tr(x=a) @ _rx(al) @ _ry(be)
        else:  # mdh: Rx(al) Tx(a) Ry(be) Rz(th+q) Tz(d)
            place = tail @ _rx(al) @ _tr(x=a) @ _ry(be) @ _rz(th) @ (_tr(z=d) if prism else np.eye(4))
            after = np.eye(4) if prism else _tr(z=d)
        jm = pin.JointModelPZ() if prism else pin.JointModelRZ()
        parent = model.addJoint(parent, jm, _se3(place), f"j{i + 1}")
        model.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
        links.append(model.addFrame(pin.Frame(f"link_{i + 1}", parent, 0, _se3(after), pin.FrameType.OP_FRAME)))
        tail = after
    tcp = model.addFrame(pin.Frame("tcp", parent, 0, _se3(tail @ robot.tool), pin.FrameType.OP_FRAME))
    return model, links, tcp


def _pin_q(model, q):
    """Pinocchio configuration from joint angles (continuous joints use cos/sin pairs)."""
    out, k = [], 0
    for jm in model.joints[1:]:
        if jm.nq == 2:
            out += [np.cos(q[k]), np.sin(q[k])]
        else:
            out.append(q[k])
        k += 1
    return np.array(out)


def _pin_poses(model, frame_id, Q):
    data = model.createData()
    out = np.empty((len(Q), 4, 4))
    for k, q in enumerate(Q):
        pin.framesForwardKinematics(model, data, _pin_q(model, q))
        out[k] = data.oMf[frame_id].homogeneous
    return out


def _assert_poses(A, B, tol=TOL):
    """Position within ``tol`` m and rotation within ``tol`` rad (matrix entries bound the angle)."""
    dp = np.abs(A[..., :3, 3] - B[..., :3, 3]).max()
    dR = A[..., :3, :3] @ np.swapaxes(B[..., :3, :3], -1, -2) - np.eye(3)
    assert dp < tol, f"position differs by {dp:.3e} m"
    assert np.abs(dR).max() < tol, f"rotation differs by {np.abs(dR).max():.3e} rad"
    assert np.all(A[..., 3, :] == [0, 0, 0, 1])


# --------------------------------------------------------------------------- every preset


@pytest.mark.parametrize("name", PRESETS)
def test_preset_fk_matches_pinocchio_dh_model(name):
    robot = load_robot(name)
    model, _, tcp = pin_model_from_dh(robot)
    Q = robot.random_joints(N_CONFIGS, rng=1)
    _assert_poses(fk(robot, Q), _pin_poses(model, tcp, Q))
    # single-pose path agrees with the batched path
    np.testing.assert_array_equal(fk(robot, Q[3]), fk(robot, Q[3:4])[0])


@pytest.mark.parametrize("name", PRESETS)
def test_preset_fk_matches_pinocchio_urdf_export(name):
    robot = load_robot(name)
    text = robot_to_urdf(robot)
    model = pin.buildModelFromXML(text)
    Q = robot.random_joints(N_CONFIGS, rng=2)
    _assert_poses(fk(robot, Q), _pin_poses(model, model.getFrameId("tcp"), Q))
    back = load_urdf_string(text)  # and hykin reads its own export back
    _assert_poses(fk(back, Q), fk(robot, Q))
    np.testing.assert_allclose(back.mass_kg, robot.mass_kg)


@pytest.mark.parametrize("name", PRESETS)
def test_preset_frames_and_jacobian_match_pinocchio(name):
    robot = load_robot(name)
    model, links, tcp = pin_model_from_dh(robot)
    data = model.createData()
    Q = robot.random_joints(100, rng=3)
    fr = fk_frames(robot, Q)
    J = jacobian(robot, Q)
    for k, q in enumerate(Q):
        pin.computeJointJacobians(model, data, q)
        pin.updateFramePlacements(model, data)
        for i, fid in enumerate(links):
            _assert_poses(fr.link[k, i], data.oMf[fid].homogeneous)
        _assert_poses(fr.tcp[k], data.oMf[tcp].homogeneous)
        Jp = pin.getFrameJacobian(model, data, tcp, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(J[k], Jp, rtol=0, atol=TOL)


@pytest.mark.parametrize("name", PRESETS)
def test_preset_fk_torch_matches_fk(name):
    torch = pytest.importorskip("torch")
    robot = load_robot(name)
    Q = robot.random_joints(N_CONFIGS, rng=4)
    T = fk_torch(robot, torch.as_tensor(Q, dtype=torch.float64)).numpy()
    np.testing.assert_allclose(T, fk(robot, Q), rtol=0, atol=TOL)
    jf, lf, tcp = fk_torch(robot, torch.as_tensor(Q[:50]), frames=True)
    fr = fk_frames(robot, Q[:50])
    np.testing.assert_allclose(lf.numpy(), fr.link, rtol=0, atol=TOL)
    np.testing.assert_allclose(jf.numpy(), fr.joint, rtol=0, atol=TOL)


@pytest.mark.parametrize("name", [*PRESETS, "test_arm.urdf"])
def test_numpy_chain_walk_matches_pinocchio(name):
    """The array-namespace walk (FK's backend without numba) against the independent models; the
    URDF test arm has a prismatic joint."""
    if name.endswith(".urdf"):
        robot = load_urdf(DATA / name)
        model = pin.buildModelFromUrdf(str(DATA / name))
        tcp = model.getFrameId("tcp")
    else:
        robot = load_robot(name)
        model, _, tcp = pin_model_from_dh(robot)
    Q = robot.random_joints(200, rng=7)
    T = chain_walk(np, chain_of(robot), Q)
    _assert_poses(T, _pin_poses(model, tcp, Q))
    np.testing.assert_allclose(fk(robot, Q), T, rtol=0, atol=1e-14)  # compiled backend, same step


@pytest.mark.parametrize("name", [p for p in PRESETS if load_robot(p).convention in ("dh", "mdh")])
def test_dh_mdh_conversion_exact(name):
    robot = load_robot(name)
    conv = dh_to_mdh(robot) if robot.convention == "dh" else mdh_to_dh(robot)
    back = mdh_to_dh(conv) if robot.convention == "dh" else dh_to_mdh(conv)
    Q = robot.random_joints(N_CONFIGS, rng=5)
    _assert_poses(fk(conv, Q), fk(robot, Q))
    _assert_poses(fk(back, Q), fk(robot, Q))
    # centres of mass stay at the same place in the world
    fa, fb = fk_frames(robot, Q[:20]), fk_frames(conv, Q[:20])
    ca = np.einsum("knij,nj->kni", fa.link[..., :3, :3], robot.com_m) + fa.link[..., :3, 3]
    cb = np.einsum("knij,nj->kni", fb.link[..., :3, :3], conv.com_m) + fb.link[..., :3, 3]
    np.testing.assert_allclose(ca, cb, rtol=0, atol=TOL)


# --------------------------------------------------------------------------- hand-written URDF


def test_urdf_file_matches_pinocchio():
    path = DATA / "test_arm.urdf"
    robot = load_urdf(path)
    model = pin.buildModelFromUrdf(str(path))
    data = model.createData()
    assert robot.dof == model.nv == 6
    assert robot.joint_type == ("revolute", "revolute", "revolute", "prismatic", "revolute", "revolute")
    np.testing.assert_allclose(robot.lower, [-3.0, -2.0, -np.pi, -0.1, -2.5, -6.0])
    Q = robot.random_joints(N_CONFIGS, rng=6)
    _assert_poses(fk(robot, Q), _pin_poses(model, model.getFrameId("tcp"), Q))
    # link frame i = child link of movable joint i; Jacobian of the TCP
    child = ["link1", "link2", "link3", "link4", "link5", "link6"]
    fr, J = fk_frames(robot, Q[:100]), jacobian(robot, Q[:100])
    tcp = model.getFrameId("tcp")
    for k, q in enumerate(Q[:100]):
        qp = _pin_q(model, q)
        pin.computeJointJacobians(model, data, qp)
        pin.updateFramePlacements(model, data)
        for i, ln in enumerate(child):
            _assert_poses(fr.link[k, i], data.oMf[model.getFrameId(ln)].homogeneous)
        Jp = pin.getFrameJacobian(model, data, tcp, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        np.testing.assert_allclose(J[k], Jp, rtol=0, atol=TOL)
    # masses of fixed-attached links are merged like Pinocchio merges them into the joint body
    for i in range(6):
        inert = model.inertias[i + 1]
        assert robot.mass_kg[i] == pytest.approx(inert.mass, abs=1e-12)
        if inert.mass > 0:
            np.testing.assert_allclose(robot.com_m[i], inert.lever, rtol=0, atol=1e-12)


def test_urdf_roundtrip_through_export():
    robot = load_urdf(DATA / "test_arm.urdf")
    back = load_urdf_string(robot_to_urdf(robot))
    Q = robot.random_joints(200, rng=7)
    _assert_poses(fk(back, Q), fk(robot, Q))
    np.testing.assert_allclose(back.mass_kg, robot.mass_kg, atol=1e-12)
    np.testing.assert_allclose(back.lower, robot.lower)


# --------------------------------------------------------------------------- published descriptions


def _chain_model(joints, tool):
    """Pinocchio model from URDF-style (xyz, rpy, axis) joint origins, built with pin.SE3 directly."""
    model = pin.Model()
    parent = 0
    jm = {"y": pin.JointModelRY, "z": pin.JointModelRZ}
    for i, (xyz, rpy, ax) in enumerate(joints):
        M = pin.SE3(pin.rpy.rpyToMatrix(np.array(rpy, float)), np.array(xyz, float))
        parent = model.addJoint(parent, jm[ax](), M, f"j{i + 1}")
    M = pin.SE3(pin.rpy.rpyToMatrix(np.array(tool[1], float)), np.array(tool[0], float))
    fid = model.addFrame(pin.Frame("tool0", parent, 0, M, pin.FrameType.OP_FRAME))
    return model, fid


HP, PI = np.pi / 2, np.pi
# ROS-Industrial ur_description ur5 (CB3): shoulder_pan ... wrist_3, tool0.
UR5_URDF = [
    ((0, 0, 0.089159), (0, 0, 0), "z"), ((0, 0.13585, 0), (0, HP, 0), "y"), ((0, -0.1197, 0.425), (0, 0, 0), "y"),
    ((0, 0, 0.39225), (0, HP, 0), "y"), ((0, 0.093, 0), (0, 0, 0), "z"), ((0, 0, 0.09465), (0, 0, 0), "y"),
]
UR5_TOOL0 = ((0, 0.0823, 0), (-HP, 0, 0))
# franka_description panda_arm: joint1..joint7, flange (joint8).
PANDA_URDF = [
    ((0, 0, 0.333), (0, 0, 0), "z"), ((0, 0, 0), (-HP, 0, 0), "z"), ((0, -0.316, 0), (HP, 0, 0), "z"),
    ((0.0825, 0, 0), (HP, 0, 0), "z"), ((-0.0825, 0.384, 0), (-HP, 0, 0), "z"), ((0, 0, 0), (HP, 0, 0), "z"),
    ((0.088, 0, 0), (HP, 0, 0), "z"),
]
PANDA_FLANGE = ((0, 0, 0.107), (0, 0, 0))
# RobotLocomotion/drake iiwa_description iiwa14: iiwa_joint_1..7, then 0.045 to the flange.
IIWA_URDF = [
    ((0, 0, 0.1575), (0, 0, 0), "z"), ((0, 0, 0.2025), (HP, 0, PI), "z"), ((0, 0.2045, 0), (HP, 0, PI), "z"),
    ((0, 0, 0.2155), (HP, 0, 0), "z"), ((0, 0.1845, 0), (-HP, PI, 0), "z"), ((0, 0, 0.2155), (HP, 0, 0), "z"),
    ((0, 0.081, 0), (-HP, PI, 0), "z"),
]
IIWA_FLANGE = ((0, 0, 0.045), (0, 0, 0))


@pytest.mark.parametrize(
    "name, joints, tool, base",
    [
        # ur_description's base_link is the UR controller base turned by pi about z.
        ("ur5", UR5_URDF, UR5_TOOL0, _rz(np.pi)),
        ("franka-panda", PANDA_URDF, PANDA_FLANGE, np.eye(4)),
        ("kuka-iiwa14", IIWA_URDF, IIWA_FLANGE, np.eye(4)),
    ],
)
def test_preset_matches_published_urdf(name, joints, tool, base):
    robot = load_robot(name)
    model, fid = _chain_model(joints, tool)
    Q = robot.random_joints(N_CONFIGS, rng=8)
    _assert_poses(fk(robot, Q), base @ _pin_poses(model, fid, Q))


def opw_fk(p, q):
    """OPW closed-form FK (Brandstoetter, Angerer, Hofbaur 2014) of the flange, internal joint angles."""
    psi3 = np.arctan2(p["a2"], p["c3"])
    k = np.hypot(p["a2"], p["c3"])
    q1, q2, q3, q4, q5, q6 = q.T
    cx1 = p["c2"] * np.sin(q2) + k * np.sin(q2 + q3 + psi3) + p["a1"]
    cz1 = p["c2"] * np.cos(q2) + k * np.cos(q2 + q3 + psi3)
    c = np.stack([cx1 * np.cos(q1), cx1 * np.sin(q1), cz1 + p["c1"]], -1)
    R = np.stack([_rz(a)[:3, :3] @ _ry(b)[:3, :3] @ _rz(d)[:3, :3] @ _ry(e)[:3, :3] @ _rz(f)[:3, :3]
                  for a, b, d, e, f in zip(q1, q2 + q3, q4, q5, q6)])
    T = np.tile(np.eye(4), (len(q), 1, 1))
    T[:, :3, :3] = R
    T[:, :3, 3] = c + p["c4"] * R[:, :, 2]
    return T


@pytest.mark.parametrize(
    "name, params, sign, offset_deg",
    [
        # opw_kinematics conventions: internal = sign * controller - offset
        ("kuka-kr6-r900", dict(a1=0.025, a2=-0.035, c1=0.400, c2=0.455, c3=0.420, c4=0.080),
         [-1, 1, 1, -1, 1, -1], [0, -90, 0, 0, 0, 0]),
        ("abb-irb2400", dict(a1=0.100, a2=-0.135, c1=0.615, c2=0.705, c3=0.755, c4=0.085),
         [1, 1, 1, 1, 1, 1], [0, 0, -90, 0, 0, 0]),
    ],
)
def test_opw_presets_match_opw_closed_form(name, params, sign, offset_deg):
    robot = load_robot(name)
    Q = robot.random_joints(N_CONFIGS, rng=9)  # preset joints
    # Preset joint variables: KUKA: q = (-A1, A2, A3, -A4, A5, -A6); ABB: q = controller axes.
    ctrl = Q * (np.array(sign) if name.startswith("kuka") else 1.0)
    internal = np.array(sign) * ctrl - np.radians(offset_deg)
    _assert_poses(fk(robot, Q), opw_fk(params, internal))


def test_preset_zero_poses_published():
    """Flange positions at the zero pose quoted in manufacturer / community documentation."""
    zero = lambda n: fk(load_robot(n), np.zeros(load_robot(n).dof))[:3, 3]
    np.testing.assert_allclose(zero("ur5"), [-0.81725, -0.19145, -0.005491], atol=1e-12)
    np.testing.assert_allclose(zero("ur10"), [-1.1843, -0.256141, 0.0116], atol=1e-12)
    np.testing.assert_allclose(zero("ur10e"), [-1.18425, -0.2907, 0.06085], atol=1e-12)
    np.testing.assert_allclose(zero("franka-panda"), [0.088, 0.0, 0.926], atol=1e-12)
    np.testing.assert_allclose(zero("kuka-iiwa14"), [0.0, 0.0, 1.306], atol=1e-12)
    # ABB IRB2400 data sheet: wrist centre 855 mm forward, 1455 mm up at the zero pose.
    T = fk(load_robot("abb-irb2400"), np.zeros(6))
    np.testing.assert_allclose(T[:3, 3] - 0.085 * T[:3, 2], [0.855, 0.0, 1.455], atol=1e-12)
