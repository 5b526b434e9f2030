"""Inverse kinematics: closed form (all branches) and Levenberg–Marquardt.

References are independent of the solvers: plain FK (hykin.kinematics.fk.fk) with se3.pose_error for the
residuals, the joints the targets were generated from, and an exhaustive numerical search (many
random LM seeds, duplicates removed modulo 2π) for the number of branches.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hykin.geometry import se3
from hykin.io.robot_file import list_presets, load_robot
from hykin.kinematics.fk import fk
from hykin.kinematics.ik import (
    _lm_numpy,
    ik,
    ik_all_numeric,
    ik_closed_form,
)
from hykin.kinematics.ik_closed_form import ClosedFormError, has_closed_form
from hykin.kinematics.ik_solutions import (
    IKBranches,
    IKResult,
    nearest_representation,
    wrap_to_limits,
)
from hykin.kinematics.poe import poe_model
from hykin.kinematics.robot import Robot, dh_to_mdh

PRESETS = list_presets()
EXPECTED_FAMILY = {
    "rx160": "opw", "kuka-kr6-r900": "opw", "abb-irb2400": "opw",
    "ur5": "ur", "ur10": "ur", "ur10e": "ur",
    "kuka-iiwa14": None, "franka-panda": None,
}
CLOSED = [p for p in PRESETS if EXPECTED_FAMILY.get(p, has_closed_form(load_robot(p))) is not None]
ALL = PRESETS


def _robot(name):
    if name not in PRESETS:
        pytest.skip(f"preset {name} not available")
    return load_robot(name)


def _mod2pi_dist(a, b):
    return np.abs((a - b + np.pi) % (2 * np.pi) - np.pi).max(axis=-1)


def _errors(robot, q, T):
    mm, deg = se3.pose_error(fk(robot, q), T)
    return mm * 1e-3, np.radians(deg)


@pytest.mark.parametrize("name", sorted(EXPECTED_FAMILY))
def test_family_detection(name):
    r = _robot(name)
    assert has_closed_form(r) == EXPECTED_FAMILY[name]


def test_no_closed_form_when_structure_broken():
    r = _robot("rx160")
    bad = r.copy(a_m=r.a_m + np.array([0, 0, 0, 0.002, 0, 0]))  # wrist axes no longer meet
    assert has_closed_form(bad) is None
    assert "do not meet" in poe_model(bad).reason
    with pytest.raises(ClosedFormError, match="no closed-form"):
        ik_closed_form(bad, fk(bad, np.zeros(6)))
    tilt = r.copy(beta_rad=np.array([0, 1e-4, 0, 0, 0, 0]))  # axes 2, 3 not parallel any more
    assert has_closed_form(tilt) is None


@pytest.mark.parametrize("name", CLOSED)
def test_closed_form_solutions_reproduce_target_and_contain_original(name):
    r = _robot(name)
    rng = np.random.default_rng(1)
    q = r.random_joints(400, rng)
    T = fk(r, q)
    sol = ik_closed_form(r, T)
    assert sol.q.shape == (400, 8, 6) and sol.valid.shape == (400, 8) and len(sol.labels) == 8
    qv = sol.q[sol.valid]
    pe, ae = _errors(r, qv, np.repeat(T[:, None], 8, 1)[sol.valid])
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9
    assert r.within_limits(qv, tol=0.0).all()
    d = np.where(sol.valid, _mod2pi_dist(sol.q, q[:, None]), np.inf).min(axis=1)
    assert np.all(d < 1e-7), f"original joints missing for {np.sum(d >= 1e-7)} targets"
    assert np.all(sol.n_solutions >= 1) and np.all(sol.n_solutions <= 8)


@pytest.mark.parametrize("name", CLOSED)
def test_closed_form_count_equals_exhaustive_search(name):
    r = _robot(name)
    q = r.random_joints(6, np.random.default_rng(7))
    T = fk(r, q)
    cf = ik_closed_form(r, T)
    ex = ik_all_numeric(r, T, n_seeds=150, rng=3)
    np.testing.assert_array_equal(cf.n_solutions, ex.n_solutions)
    for i in range(len(T)):  # every numerical solution is one of the closed-form ones
        for qn in ex.q[i][ex.success[i]]:
            assert np.min(np.where(cf.valid[i], _mod2pi_dist(cf.q[i], qn), np.inf)) < 1e-6


@pytest.mark.parametrize("name", ["rx160", "ur10"])
def test_numpy_reference_matches_kernel(name):
    r = _robot(name)
    T = fk(r, r.random_joints(200, np.random.default_rng(2)))
    a = ik_closed_form(r, T)
    b = ik_closed_form(r, T, use_numba=False)
    np.testing.assert_array_equal(a.valid, b.valid)
    np.testing.assert_allclose(a.q[a.valid], b.q[b.valid], atol=1e-9)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    xyz=st.lists(st.floats(-1, 1), min_size=6, max_size=6),
    rpy=st.lists(st.floats(-np.pi, np.pi), min_size=6, max_size=6),
    name=st.sampled_from(["rx160", "ur5"]),
    mdh=st.booleans(),
)
def test_closed_form_any_convention_base_and_tool(xyz, rpy, name, mdh):
    r = _robot(name)
    if mdh:
        r = dh_to_mdh(r)
    r = r.copy(base=se3.xyzrpy_to_transform(np.array(xyz[:3]), np.array(rpy[:3])),
               tool=se3.xyzrpy_to_transform(0.2 * np.array(xyz[3:]), np.array(rpy[3:])))
    assert has_closed_form(r) is not None
    q = r.random_joints(20, np.random.default_rng(0))
    T = fk(r, q)
    sol = ik_closed_form(r, T)
    d = np.where(sol.valid, _mod2pi_dist(sol.q, q[:, None]), np.inf).min(axis=1)
    assert np.all(d < 1e-7)


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6))
def test_ur10_hypothesis_random_joints(u):
    r = _robot("ur10")
    q = r.lower + np.array(u) * (r.upper - r.lower)
    T = fk(r, q)[None]
    sol = ik_closed_form(r, T)
    if not sol.valid.any():  # documented limitation: exact wrist singularity with q6 := 0 out of reach
        assert abs(np.sin(q[4])) < 1e-6
        assert ik(r, T).success[0]  # the public API falls back to LM
        return
    pe, ae = _errors(r, sol.q[sol.valid], np.repeat(T, sol.valid.sum(), 0))
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9
    # at/near a wrist singularity (axis 6 ∥ axes 2-4) there is a (near) self-motion: joints are only
    # determined to ~eps / sin(q5), and exactly there q6 := 0, so q itself need not be returned
    if abs(np.sin(q[4])) > 1e-3:
        assert np.where(sol.valid[0], _mod2pi_dist(sol.q[0], q), np.inf).min() < 1e-6


def test_representation_nearest_zero_and_nearest_to():
    r = _robot("rx160")  # joints 4 and 6 span ±270°: two representations possible
    q = np.radians([[20.0, -30.0, 60.0, 250.0, 40.0, -200.0]])
    T = fk(r, q)
    sol = ik_closed_form(r, T)
    k = np.argmin(np.where(sol.valid[0], _mod2pi_dist(sol.q[0], q[0]), np.inf))
    np.testing.assert_allclose(sol.q[0, k, [3, 5]], np.radians([-110.0, 160.0]), atol=1e-9)  # nearest zero
    br = ik(r, T, all_branches=True)
    near = br.nearest_to(q[0] + 0.01, r.lower, r.upper)  # short way round: the ±2π twin within limits
    np.testing.assert_allclose(near.q[0], q[0], atol=1e-8)
    assert near.success[0] and near.label[0] == sol.labels[near.branch[0]]
    w = wrap_to_limits(np.radians([[0, 0, 0, 300.0, 0, 0]]), r.lower, r.upper)
    np.testing.assert_allclose(np.degrees(w[0, 3]), -60.0)
    n = nearest_representation(np.radians([10.0]), np.radians([200.0]), np.radians([-270.0]), np.radians([270.0]))
    np.testing.assert_allclose(np.degrees(n), [10.0])  # 370° is outside the limits


def test_wrist_singular_sets_q4_zero():
    r = _robot("rx160")
    q = np.radians([[30.0, -20.0, 70.0, 40.0, 0.0, 10.0]])  # q5 = 0: only q4 + q6 is defined
    T = fk(r, q)
    sol = ik_closed_form(r, T)
    assert sol.valid.any()
    pe, ae = _errors(r, sol.q[sol.valid], np.repeat(T, sol.valid.sum(), 0))
    assert pe.max() < 1e-9 and ae.max() < 1e-9
    sing = sol.valid[0] & (np.abs(sol.q[0, :, 4]) < 1e-6)
    assert sing.any()
    np.testing.assert_allclose(sol.q[0, sing, 3], 0.0, atol=1e-9)
    np.testing.assert_allclose(sol.q[0, sing, 5], np.radians(50.0), atol=1e-7)


@pytest.mark.parametrize("name", ALL)
def test_numerical_ik_success_rate(name):
    r = _robot(name)
    q = r.random_joints(2000, np.random.default_rng(11))
    T = fk(r, q)
    res = ik(r, T, method="numeric")
    assert isinstance(res, IKResult)
    assert res.success.mean() >= 0.999
    pe, ae = _errors(r, res.q[res.success], T[res.success])
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9
    assert r.within_limits(res.q, tol=0.0).all()
    np.testing.assert_allclose(res.pos_err_m[res.success], pe, atol=1e-12)


@pytest.mark.parametrize("name", ALL)
def test_auto_ik_nearest_to_seed(name):
    r = _robot(name)
    q = r.random_joints(200, np.random.default_rng(5), margin=0.05)
    T = fk(r, q)
    res = ik(r, T, q_seed=q + 1e-3)
    assert res.success.all()
    pe, ae = _errors(r, res.q, T)
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9
    if has_closed_form(r):  # the branch nearest the seed is the original one
        assert np.all(_mod2pi_dist(res.q, q) < 1e-6)
        assert np.all(res.branch >= 0)


@pytest.mark.parametrize("name", ["rx160", "ur5", "franka-panda"])
def test_unreachable_target_reported_failed(name):
    r = _robot(name)
    T = fk(r, np.zeros(r.dof))
    far = T.copy()
    far[:3, 3] += [10.0, 0.0, 0.0]
    res = ik(r, np.stack([T, far]), restarts=3)
    assert res.success.tolist() == [True, False]
    assert res.pos_err_m[1] > 5.0 and np.all(np.isfinite(res.q))
    assert r.within_limits(res.q, tol=0.0).all()
    br = ik(r, far, all_branches=True, n_seeds=8)
    assert isinstance(br, IKBranches) and br.n_solutions.tolist() == [0]
    if has_closed_form(r):
        assert not ik_closed_form(r, far).valid.any()
    assert not ik(r, far, position_only=True, restarts=2).success[0]


@pytest.mark.parametrize("name", ["rx160", "kuka-iiwa14"])
def test_position_only(name):
    r = _robot(name)
    q = r.random_joints(200, np.random.default_rng(4))
    T = fk(r, q)
    T_rot = T.copy()
    T_rot[:, :3, :3] = se3.rotx(0.7)[:3, :3]  # orientation must be ignored
    res = ik(r, T_rot, position_only=True)
    assert res.success.all() and np.all(res.ang_err_rad == 0.0)
    p = fk(r, res.q)[:, :3, 3]
    assert np.abs(p - T[:, :3, 3]).max() < 1e-9


def test_all_branches_redundant_robot_returns_distinct_solutions():
    r = _robot("franka-panda")
    q = r.random_joints(3, np.random.default_rng(8), margin=0.1)
    T = fk(r, q)
    br = ik(r, T, all_branches=True, n_seeds=40)
    assert np.all(br.n_solutions >= 2)
    for i in range(3):
        qs = br.q[i][br.success[i]]
        pe, ae = _errors(r, qs, np.repeat(T[i : i + 1], len(qs), 0))
        assert pe.max() <= 1e-9 and ae.max() <= 1e-9
        d = _mod2pi_dist(qs[:, None], qs[None])
        assert np.all(d[~np.eye(len(qs), dtype=bool)] > 1e-6)


def test_calibrated_robot_seeded_from_nominal_closed_form():
    nominal = _robot("rx160")
    rng = np.random.default_rng(9)
    cal = nominal.copy(
        a_m=nominal.a_m + rng.normal(0, 5e-4, 6), d_m=nominal.d_m + rng.normal(0, 5e-4, 6),
        theta_rad=nominal.theta_rad + rng.normal(0, 1e-3, 6), beta_rad=np.array([0, 1e-3, 0, 0, 0, 0]),
    )
    assert has_closed_form(cal) is None
    q = cal.random_joints(50, rng, margin=0.05)
    T = fk(cal, q)
    br = ik(cal, T, all_branches=True, seed_robot=nominal)
    nominal_count = ik_closed_form(nominal, T).n_solutions
    assert np.all(br.n_solutions >= 1)
    assert np.mean(br.n_solutions == nominal_count) > 0.9
    qs = br.q[br.success]
    pe, ae = _errors(cal, qs, np.repeat(T[:, None], 8, 1)[br.success])
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9
    d = np.where(br.success, _mod2pi_dist(br.q, q[:, None]), np.inf).min(axis=1)
    assert np.mean(d < 1e-6) >= 0.95  # a seed near a joint limit may polish onto another branch
    res = ik(cal, T, q_seed=q, seed_robot=nominal)  # one solution: the branch nearest the seed
    assert res.success.all()
    assert np.mean(_mod2pi_dist(res.q, q) < 1e-6) >= 0.95


def test_prismatic_chain():
    # a 4-dof RRPR arm (SCARA-like): prismatic joint 3 moves along z
    r = Robot(name="scara", convention="dh", a_m=[0.4, 0.3, 0.0, 0.0], alpha_rad=[0.0, np.pi, 0.0, 0.0],
              d_m=[0.3, 0.0, 0.0, 0.05], theta_rad=np.zeros(4), lower=[-2.5, -2.5, 0.0, -3.0],
              upper=[2.5, 2.5, 0.3, 3.0], joint_type=("revolute", "revolute", "prismatic", "revolute"))
    assert has_closed_form(r) is None
    q = r.random_joints(300, np.random.default_rng(3))
    T = fk(r, q)
    res = ik(r, T)
    assert res.success.mean() >= 0.99
    pe, ae = _errors(r, res.q[res.success], T[res.success])
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9


def test_numpy_lm_fallback_converges():
    r = _robot("ur5")
    q = r.random_joints(50, np.random.default_rng(6))
    T = fk(r, q)
    qs, pe, ae, it = _lm_numpy(r, T, q + 0.05, False, 1e-10, 1e-10, 50, 1e-3, r.lower, r.upper)
    assert np.all(pe < 1e-10) and np.all(ae < 1e-10)
    pe2, ae2 = _errors(r, qs, T)
    assert pe2.max() < 1e-9


def test_bad_input():
    r = _robot("rx160")
    with pytest.raises(ValueError, match="shape"):
        ik(r, np.eye(3))
    with pytest.raises(ValueError, match="NaN"):
        ik(r, np.full((4, 4), np.nan))
    with pytest.raises(ValueError, match="method"):
        ik(r, np.eye(4), method="magic")
    with pytest.raises(ValueError, match="q_seed"):
        ik(r, np.eye(4), q_seed=np.zeros(5))
    with pytest.raises(ValueError, match="closed-form"):
        ik(_robot("kuka-iiwa14"), np.eye(4), method="closed_form")


def test_all_branches_falls_back_to_lm_at_exact_ur_singularity():
    r = _robot("ur10")
    q = np.array([0.0, 0.96875 * np.pi, 0.0, 0.0, 0.0, np.pi])  # q5 = 0 and q3 = 0 (stretched)
    T = fk(r, q)[None]
    assert not ik_closed_form(r, T).valid.any()  # documented limitation of the closed form (q6 := 0)
    br = ik(r, T, all_branches=True)
    assert br.n_solutions[0] >= 1
    pe, ae = _errors(r, br.q[0][br.success[0]], np.repeat(T, br.n_solutions[0], 0))
    assert pe.max() <= 1e-9 and ae.max() <= 1e-9


def test_a_solution_a_rounding_beyond_a_limit_is_at_the_limit():
    # A UR elbow stretched at q3 = 360° (its limit): IK returns q3 = 0 + ~1e-8 (acos near 1). Its 2π
    # representation 360° + 1e-8 must count as the limit itself, not as out of range (before: the
    # representation was refused and the nearest "other" branch was 360° away, 11 mm off on the robot).
    from hykin.kinematics.ik_solutions import LIMIT_SLACK_RAD, nearest_representation

    lo, hi = np.full(6, -2 * np.pi), np.full(6, 2 * np.pi)
    q = np.array([0.1, -0.2, 3e-8, 0.3, -0.4, 0.5])
    ref = np.array([0.1, -0.2, 2 * np.pi - 1e-4, 0.3, -0.4, 0.5])
    out = nearest_representation(q, ref, lo, hi)
    assert out[2] == 2 * np.pi and np.array_equal(out[[0, 1, 3, 4, 5]], q[[0, 1, 3, 4, 5]])
    beyond = q.copy()
    beyond[2] = 10 * LIMIT_SLACK_RAD  # 2π + 1e-6 is truly outside [-2π, 2π]: the nearest fitting one is q itself
    assert nearest_representation(beyond, ref, lo, hi)[2] == beyond[2]
