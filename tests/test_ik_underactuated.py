"""IK and compensation of under-actuated arms (fewer than 6 joints): a 4-axis SCARA and a 4-axis
palletizer whose parallelogram is two ``<mimic>`` joints.

An arbitrary (measured) pose has no exact solution on such an arm: hybrid IK returns the least-squares
solution and accepts it when the error it leaves is within the model's accuracy (its held-out maximum
error). References are independent of hykin's solvers: the SCARA's DH FK and the palletizer's URDF FK
are written out here, scipy's ``least_squares`` gives the least-squares solution, and the targets come
from known joints.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from hykin.compensation import compensate
from hykin.hybrid.ik import hybrid_ik
from hykin.io.urdf import load_urdf_string
from hykin.kinematics.fk import fk
from hykin.kinematics.ik_rows import classical_ik_rows
from hykin.kinematics.robot import Robot
from hykin.io.robot_file import load_robot

ACC_MM, ACC_DEG = 0.05, 0.005  # the stand-in model's held-out maximum errors


def _dh_fk(a, alpha, d, theta, prismatic, tool, q):
    """Standard DH: ``Π Rz(θ + q) Tz(d) Tx(a) Rx(α)`` (``d + q`` for a prismatic joint), then ``tool``."""
    out = []
    for qq in np.atleast_2d(q):
        T = np.eye(4)
        for i in range(len(a)):
            th, dd = theta[i] + (0.0 if prismatic[i] else qq[i]), d[i] + (qq[i] if prismatic[i] else 0.0)
            ct, st, ca, sa = np.cos(th), np.sin(th), np.cos(alpha[i]), np.sin(alpha[i])
            T = T @ np.array([[ct, -st * ca, st * sa, a[i] * ct], [st, ct * ca, -ct * sa, a[i] * st],
                              [0, sa, ca, dd], [0, 0, 0, 1.0]])
        out.append(T @ tool)
    return np.array(out)


SCARA = dict(a=[0.4, 0.3, 0.0, 0.0], alpha=[2e-3, np.pi - 1.5e-3, 0.0, 0.0], d=[0.3, 0.0, 0.0, 0.05],
             theta=[0.0, 0.0, 0.0, 0.0], prismatic=[False, False, True, False])
TOOL = np.array([[1, 0, 0, 0.03], [0, 1, 0, 0], [0, 0, 1, 0.05], [0, 0, 0, 1.0]])


def scara_robot() -> Robot:
    """A calibrated SCARA: axes 1 and 2 tilted 0.1° (the elbow branches tilt the tool differently)."""
    return Robot(name="scara", convention="dh", a_m=SCARA["a"], alpha_rad=SCARA["alpha"], d_m=SCARA["d"],
                 theta_rad=SCARA["theta"], lower=[-2.4, -2.5, 0.0, -2 * np.pi], upper=[2.4, 2.5, 0.2, 2 * np.pi],
                 joint_type=("revolute", "revolute", "prismatic", "revolute"), tool=TOOL)


class StandIn:
    """Classical robot plus a smooth correction (``Δp`` ~0.3 mm, ``Δr`` ~0.02°, sines of the joints), with
    held-out metrics ``ACC_MM`` / ``ACC_DEG`` and the attributes the compensator reads."""

    def __init__(self, robot: Robot, ref_fk, seed: int = 0):
        rng = np.random.default_rng(seed)
        n = robot.dof
        self.robot = self.robot_ = self.nominal = robot
        self.frame_pre_ = self.frame_post_ = np.eye(4)
        self.ref_fk = ref_fk
        self.W, self.ph = rng.normal(0, 1.0, (2, n, n)), rng.uniform(0, 2 * np.pi, (2, n))
        self.A = rng.normal(0, 1, (2, 3, n)) / np.sqrt(n)
        self.A[0] *= 3e-4
        self.A[1] *= np.radians(0.02)
        self.metadata = {"metrics": {"held_out": {"hybrid_pos_mean_mm": 0.02, "hybrid_pos_max_mm": ACC_MM,
                                                  "hybrid_rot_mean_deg": 0.002, "hybrid_rot_max_deg": ACC_DEG}}}

    def _pose(self, T, q):
        q = np.atleast_2d(q)
        T = np.array(T, copy=True)
        T[:, :3, 3] += np.sin(q @ self.W[0].T + self.ph[0]) @ self.A[0].T
        T[:, :3, :3] = Rotation.from_rotvec(np.sin(q @ self.W[1].T + self.ph[1]) @ self.A[1].T).as_matrix() @ T[:, :3, :3]
        return T

    def predict(self, q):  # what hybrid IK solves with (hykin's FK)
        return self._pose(fk(self.robot, np.asarray(q, dtype=np.float64)), q)

    def reference(self, q):  # the same model on the FK written in this file
        return self._pose(self.ref_fk(q), q)


def _errors(Ta, Tb):
    dp = np.linalg.norm(Ta[:, :3, 3] - Tb[:, :3, 3], axis=1) * 1e3
    da = np.degrees(Rotation.from_matrix(Ta[:, :3, :3] @ np.swapaxes(Tb[:, :3, :3], 1, 2)).magnitude())
    return dp, da


def _wrap(d):
    return (d + np.pi) % (2 * np.pi) - np.pi


@pytest.fixture(scope="module")
def scara():
    robot = scara_robot()
    ref = lambda q: _dh_fk(SCARA["a"], SCARA["alpha"], SCARA["d"], SCARA["theta"], SCARA["prismatic"], TOOL, q)
    m = StandIn(robot, ref)
    q = np.random.default_rng(4).uniform([-2.0, 0.4, 0.02, -2.5], [2.0, 2.2, 0.18, 2.5], (6, 4))
    return m, q


def test_reference_fk_is_hykins(scara):
    m, q = scara
    np.testing.assert_allclose(m.reference(q), m.predict(q), atol=1e-12)


def test_all_branches_solve_the_models_own_poses(scara):
    """Issue: every target failed with all branches (the classical seeds of a 4-axis arm missed by the
    correction and were dropped)."""
    m, q = scara
    T = m.reference(q)
    res = hybrid_ik(m, T, all_branches=True)
    assert res.solved_targets.all()
    dp, da = _errors(m.reference(res.q[res.success]), T[res.target[res.success]])
    assert dp.max() < 1e-6 and da.max() < 1e-6
    for i in range(len(q)):  # the joints that made the pose are among the solutions
        qi = res.q[(res.target == i) & res.success]
        d = np.abs(np.where([True, True, False, True], _wrap(qi - q[i]), qi - q[i])).max(1)
        assert d.min() < 1e-7


def _tilted(m, q, deg):
    """The model's pose at ``q`` tilted by ``deg`` about the tool's x axis: off the arm's reachable poses
    (a SCARA turns its tool about the vertical only)."""
    T = m.reference(q)
    T[:, :3, :3] = T[:, :3, :3] @ Rotation.from_euler("x", deg, degrees=True).as_matrix()
    return T


def _scipy_lsq(m, T, q0):
    def r(qq):
        P = m.reference(qq)[0]
        rv = Rotation.from_matrix(P[:3, :3] @ T[:3, :3].T).as_rotvec()
        return np.concatenate([P[:3, 3] - T[:3, 3], rv])

    return least_squares(r, q0, xtol=1e-15, ftol=1e-15, gtol=1e-15).x


@pytest.mark.parametrize("all_branches", [False, True])
def test_measured_pose_is_the_least_squares_solution(scara, all_branches):
    """A measured pose the arm cannot match exactly: success within the model's accuracy, the joints
    are the least-squares solution (scipy), the reported residual is the pose error at them."""
    m, q = scara
    T = _tilted(m, q, 0.5 * ACC_DEG)
    res = hybrid_ik(m, T, all_branches=True, nearest=not all_branches, q_current=q + 0.01)
    assert res.solved_targets.all()
    for i in range(len(q)):
        k = np.flatnonzero((res.target == i) & res.success)
        d = np.abs(_wrap(res.q[k] - q[i])).max(1)
        j = k[np.argmin(d)]
        ref = _scipy_lsq(m, T[i], q[i])
        np.testing.assert_allclose(res.q[j], ref, atol=1e-7)
        dp, da = _errors(m.reference(res.q[j]), T[i][None])
        np.testing.assert_allclose([res.pos_err_mm[j], res.ang_err_deg[j]], [dp[0], da[0]], rtol=1e-6, atol=1e-9)
        assert 0.2 * ACC_DEG < da[0] <= ACC_DEG


def test_pose_missed_by_more_than_the_accuracy_fails(scara):
    m, q = scara
    T = _tilted(m, q[:2], 5 * ACC_DEG)
    res = hybrid_ik(m, T, all_branches=True, nearest=True, q_current=q[:2])
    assert not res.success.any()
    assert all("cannot match this pose" in r for r in res.reason)
    assert (res.ang_err_deg > ACC_DEG).all()
    # with the tolerance opened, the same least-squares solution is accepted
    ok = hybrid_ik(m, T, all_branches=True, nearest=True, q_current=q[:2], underactuated_deg=10 * ACC_DEG)
    assert ok.success.all()
    np.testing.assert_allclose(ok.q, np.array([_scipy_lsq(m, T[i], q[i]) for i in range(2)]), atol=1e-7)


def test_compensate_finds_the_branch_that_reaches_the_pose(scara):
    """Issue: without joint hints the walk took the elbow branch nearest the previous joints, which
    misses the model's own pose by its tilt (~0.1°)."""
    m, q = scara
    T = m.reference(q)
    c = compensate(m, T, tolerance_mm=1e-4, tolerance_deg=1e-4)
    assert c.success.all()
    dp, da = _errors(m.reference(c.q), T)
    assert dp.max() < 1e-6 and da.max() < 1e-6


PALLET = """<robot name="pallet">
  <link name="base"/><link name="l1"/><link name="l2"/><link name="l2m"/><link name="l3"/><link name="l3m"/>
  <link name="l4"/><link name="tcp"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/><origin xyz="0 0 0.5"/>
    <axis xyz="0 0 1"/><limit lower="-3.1" upper="3.1" effort="1" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="l1"/><child link="l2"/><origin xyz="0.2 0 0.1" rpy="0.001 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-0.7" upper="1.2" effort="1" velocity="1"/></joint>
  <joint name="j2m" type="revolute"><parent link="l2"/><child link="l2m"/><origin xyz="0 0 1.0"/>
    <axis xyz="0 1 0"/><limit lower="-1.2" upper="0.7" effort="1" velocity="1"/>
    <mimic joint="j2" multiplier="-1" offset="0"/></joint>
  <joint name="j3" type="revolute"><parent link="l2m"/><child link="l3"/><origin xyz="0 0 0" rpy="0 0 0.002"/>
    <axis xyz="0 1 0"/><limit lower="-1.0" upper="1.0" effort="1" velocity="1"/></joint>
  <joint name="j3m" type="revolute"><parent link="l3"/><child link="l3m"/><origin xyz="1.2 0 0"/>
    <axis xyz="0 1 0"/><limit lower="-1.0" upper="1.0" effort="1" velocity="1"/>
    <mimic joint="j3" multiplier="-1" offset="0"/></joint>
  <joint name="j4" type="revolute"><parent link="l3m"/><child link="l4"/><origin xyz="0.1 0 -0.2"/>
    <axis xyz="0 0 1"/><limit lower="-6.2832" upper="6.2832" effort="1" velocity="1"/></joint>
  <joint name="jt" type="fixed"><parent link="l4"/><child link="tcp"/><origin xyz="0.02 0 -0.1"/></joint>
</robot>"""


def _pallet_fk(q):
    """The URDF above by hand: origins, rotations about the joint axes, mimic joints = −leader."""
    def O(xyz, rpy=(0, 0, 0)):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
        T[:3, 3] = xyz
        return T

    def R(ax, v):
        T = np.eye(4)
        T[:3, :3] = Rotation.from_rotvec(v * np.asarray(ax, dtype=float)).as_matrix()
        return T

    y, z = (0, 1, 0), (0, 0, 1)
    out = []
    for q1, q2, q3, q4 in np.atleast_2d(q):
        out.append(O((0, 0, 0.5)) @ R(z, q1) @ O((0.2, 0, 0.1), (0.001, 0, 0)) @ R(y, q2) @ O((0, 0, 1.0)) @ R(y, -q2)
                   @ O((0, 0, 0), (0, 0, 0.002)) @ R(y, q3) @ O((1.2, 0, 0)) @ R(y, -q3) @ O((0.1, 0, -0.2)) @ R(z, q4)
                   @ O((0.02, 0, -0.1)))
    return np.array(out)


def test_compensate_a_palletizer_with_mimic_joints():
    """Issue: the branch walk built a per-joint mask over the chain's 6 joints (mimic ones included)
    for the 4 independent joints and crashed on broadcasting."""
    robot = load_urdf_string(PALLET, tip_link="tcp")
    assert robot.dof == 4 and len(robot.joint_type) == 6
    m = StandIn(robot, _pallet_fk, seed=1)
    q = np.random.default_rng(5).uniform([-2.5, -0.5, -0.8, -2.5], [2.5, 1.0, 0.8, 2.5], (5, 4))
    T = m.reference(q)
    np.testing.assert_allclose(m.predict(q), T, atol=1e-12)
    c = compensate(m, T)
    assert c.success.all()
    dp, da = _errors(m.reference(c.q), T)
    assert dp.max() < 1e-6 and da.max() < 1e-6
    # a measured pose (tilted about the tool's x axis: the palletizer keeps its flange level)
    Tm = T.copy()
    Tm[:, :3, :3] = Tm[:, :3, :3] @ Rotation.from_euler("x", 0.5 * ACC_DEG, degrees=True).as_matrix()
    cm = compensate(m, Tm)
    assert cm.success.all()
    np.testing.assert_allclose(np.abs(_wrap(cm.q - q)).max(), 0.0, atol=1e-4)


def test_classical_all_branches_list_every_turn_of_a_wide_joint():
    """Joint 4 of the SCARA turns ±360°: each solution also at ``q4 ∓ 2π`` where that is within the
    limits; a UR arm (six ±360° joints: 64 copies per branch) lists each branch once (documented)."""
    robot = scara_robot()
    q = np.array([[0.3, 1.1, 0.1, 0.6], [-1.0, 1.5, 0.05, -4.0]])
    T = _dh_fk(SCARA["a"], SCARA["alpha"], SCARA["d"], SCARA["theta"], SCARA["prismatic"], TOOL, q)
    rows = classical_ik_rows(robot, T)
    Q = np.stack([rows[f"q{j + 1}"] for j in range(4)], 1)
    ok = np.asarray(rows["success"], dtype=bool)
    assert ok.all()
    dp, da = _errors(_dh_fk(SCARA["a"], SCARA["alpha"], SCARA["d"], SCARA["theta"], SCARA["prismatic"], TOOL, Q),
                     T[rows["target"]])
    assert dp.max() < 1e-6 and da.max() < 1e-6
    for i in range(2):
        qi = Q[rows["target"] == i]
        assert ((qi >= robot.lower - 1e-12) & (qi <= robot.upper + 1e-12)).all()
        both = qi[np.abs(qi[:, :3] - q[i, :3]).max(1) < 1e-6, 3]  # the given branch: q4 and q4 ∓ 2π
        np.testing.assert_allclose(np.sort(both), np.sort([q[i, 3], q[i, 3] - np.sign(q[i, 3]) * 2 * np.pi]), atol=1e-7)
        assert len(np.unique(np.round(qi, 9), axis=0)) == len(qi)
    ur = load_robot("ur10")
    Tu = fk(ur, np.array([[0.3, -1.0, 1.2, -0.5, 0.7, 0.2]]))
    assert len(classical_ik_rows(ur, Tu)["target"]) == 8


def test_a_robot_file_names_an_orientation_the_arm_cannot_take():
    """Classical IK of a 4-joint robot (no model, so no accuracy to accept a least-squares solution): a
    pose whose orientation is 0.01 deg off every one the arm takes at that position fails saying so,
    and the position alone solves."""
    from hykin.geometry import se3
    from hykin.kinematics.fk import fk
    from hykin.kinematics.ik_rows import classical_ik_rows

    rob = scara_robot()
    q = np.array([[0.3, 0.5, 0.1, 0.2], [-0.4, 1.0, 0.05, -1.0]])
    T = fk(rob, q)
    T[:, :3, :3] = T[:, :3, :3] @ se3.rotvec_to_matrix(np.radians([[0.01, 0.0, 0.0]] * 2))
    rows = classical_ik_rows(rob, T, None, False)
    assert not np.any(rows["success"])
    assert all("the arm has 4 joints and takes no orientation" in r for r in rows["reason"])
    pos = classical_ik_rows(rob, T, None, True)
    ok = np.asarray(pos["success"], dtype=bool)
    assert set(np.asarray(pos["target"], dtype=int)[ok]) == {0, 1}  # every target's position is solved


def test_a_urscript_program_for_a_scara_is_compensated(scara):
    """Probe report s40: a URScript program of exactly reachable SCARA poses had 8 of 10 targets refused:
    the check that the controller's nominal IK of the written (rounded) literal gives the solved joints
    needs an exact solution, which an arm of fewer than 6 joints has only in the least-squares sense."""
    from hykin.compensation import urscript
    from hykin.compensation.programs import compensate_program
    from hykin.geometry import se3

    m, q = scara
    T = m.reference(q)
    lines = ["def prog():"]
    for P in T:
        v = se3.matrix_to_rotvec(P[:3, :3])
        lines.append("  movel(p[" + ", ".join(f"{x:.9f}" for x in (*P[:3, 3], *v)) + "], a=0.5, v=0.1)")
    res = compensate_program(m, "\n".join(lines + ["end"]) + "\n", urscript, frame="measurement")
    assert not res.failed and res.n_compensated == len(q), res.failed
