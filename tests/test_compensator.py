"""hykin.Compensator: one target (step) and batches run one path; reachable targets are never refused.

References: the model's own prediction at chosen joints (the targets are poses its robot reaches), a
stand-in controller = nominal IK of the command (solution nearest the joints we asked for), the hybrid
IK of hykin.hybrid.ik for the joints."""

from __future__ import annotations

import copy
import warnings

import numpy as np
import pytest
from comp_models import ExactModel, exact, tiny_model_file

import hykin
from hykin.geometry import se3
from hykin.kinematics.ik import ik


@pytest.fixture(scope="module")
def model():
    from hykin.hybrid.model import HybridModel

    return HybridModel.load(tiny_model_file())


def _predict(m, q):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return m.predict(q)


def _land(m, c, q_ref):
    """Where a controller running the nominal model lands the commands: pose error (mm, deg) to ``T``."""
    nom = m.nominal
    r = ik(nom, nom.base @ c.command, all_branches=True).nearest_to(q_ref, nom.lower, nom.upper)
    return _predict(m, np.where(r.success[:, None], r.q, np.nan))


def _hard_joints(m, rng):
    """Joints within 1° of a limit, near the wrist (q5 ~ 0) and elbow (q3 ~ 0, stretched: the workspace
    edge) singularities, and random ones."""
    nom = m.nominal
    lo, hi = nom.lower, nom.upper
    q = nom.random_joints(60, 3, margin=0.3)
    for k in range(12):  # one joint within 1 degree of a limit
        j = k % 6
        q[k, j] = (lo[j] + np.radians(rng.uniform(0.05, 1.0))) if k % 2 else (hi[j] - np.radians(rng.uniform(0.05, 1.0)))
    q[12:24, 4] = np.radians(rng.uniform(-0.5, 0.5, 12))  # wrist singularity
    q[24:36, 2] = np.radians(rng.uniform(-1.0, 1.0, 12))  # stretched elbow: workspace edge
    q[36:40, 2] = 0.0
    return q


def test_step_equals_batch_and_lands(model):
    m = model
    C = hykin.Compensator(m)
    assert C.kernel is not None  # the compiled path
    s = np.linspace(0, 1, 40)[:, None]
    q_path = np.array([0.3, -1.4, 1.5, -1.7, -1.5, 0.4]) + s * np.array([0.9, 0.4, 0.4, -0.5, 0.3, 1.0])
    T = _predict(m, q_path) @ se3.trans(0.0, 0.0, 1e-3)  # 1 mm beside the path: not the start joints
    qp, Q, cmd = q_path[0], [], []
    assert C._step_compiled(T[0], q_path[:1]) is not None  # the warm one-target path is the one timed
    assert C._step_compiled(T[0], q_path[:1] + 2 * np.pi) is None  # outside the limits: solve() decides
    for k in range(len(T)):
        r = C.step(T[k], qp)
        assert r.success and r.reason == "" and r.pos_err_mm < C.tolerance_mm
        qp = r.q
        Q.append(r.q)
        cmd.append(r.command)
    c = C(T, q_branch=np.vstack([q_path[:1], Q[:-1]]))
    assert c.success.all()
    assert np.abs(np.array(Q) - c.q).max() < 1e-9 and np.abs(np.array(cmd) - c.command).max() < 1e-9
    # the batch with the default walk finds the same joints (same branch: the path starts near zero's branch)
    p, a = se3.pose_error(_predict(m, c.q), T)
    assert p.max() < 1e-6 and a.max() < 1e-6
    # the command is the nominal FK at those joints; a nominal controller lands there
    assert np.allclose(c.command, se3.invert(m.nominal.base) @ hykin.fk(m.nominal, c.q), atol=1e-12)
    p, a = se3.pose_error(_land(m, c, c.q), T)
    assert p.max() < 1e-6


def test_hard_targets_are_compensated(model):
    m = model
    rng = np.random.default_rng(4)
    q = _hard_joints(m, rng)
    T = _predict(m, q)  # every target is reached by the model's robot within its limits
    c = hykin.Compensator(m)(T, q_branch=q)
    assert c.success.all(), list(zip(np.flatnonzero(~c.success), c.reason[~c.success]))
    p, a = se3.pose_error(_predict(m, c.q), T)
    assert p.max() < c.pos_err_mm.max() + 1e-9 and p.max() < 1e-4
    assert np.all((c.q >= m.robot_.lower - 1e-12) & (c.q <= m.robot_.upper + 1e-12))


def test_target_the_nominal_robot_cannot_reach(model):
    m = copy.deepcopy(model)
    a = m.robot_.a_m.copy()
    a[1] -= 0.004  # the real upper arm is 4 mm longer than the nominal one
    m.robot_ = m.robot_.copy(a_m=a)
    q = np.array([[0.4, -1.2, 0.0, -1.0, -1.4, 0.3], [-0.5, -0.9, 0.002, -1.9, 1.2, -0.8]])
    T = _predict(m, q)
    assert not ik(m.nominal, T, all_branches=True).success.any(1).all()  # the nominal robot cannot reach them
    c = hykin.compensate(m, T)  # no branch given: the walk falls back to the calibrated robot's solutions
    assert c.success.all(), c.reason
    assert se3.pose_error(_predict(m, c.q), T)[0].max() < 1e-6
    r = hykin.Compensator(m).step(T[1], q[1] + 0.003)  # near the stretched elbow: either side of the fold
    assert r.success and se3.pose_error(_predict(m, r.q), T[1])[0] < 1e-6


def test_failures_are_categorised_and_tolerance_from_the_model(model):
    m = model
    C = hykin.Compensator(m)
    held = m.metadata["metrics"].get("val") or m.metadata["metrics"]["held_out"]
    assert C.tolerance_mm == pytest.approx(max(1e-4, 0.5 * held["hybrid_pos_mean_mm"]))
    assert hykin.Compensator(m, tolerance_mm=0.02).tolerance_mm == 0.02
    q = np.array([[0.3, -1.4, 1.5, -1.7, -1.5, 0.4]])
    T = _predict(m, q)
    far = T.copy()
    far[0, :3, 3] = [3.0, 0.0, 0.5]  # 3 m away
    r = C.step(far[0], q[0])
    assert not r.success and r.reason.startswith("unreachable for the model: out of reach"), r.reason
    assert "frame 'base'" not in r.reason  # out of reach in either frame: no frame blamed (probe s42 AR)
    # within reach but behind a joint limit (joint 1 held to [0, 0.5] rad; the target needs 1.3 or 1.3 - pi):
    # not called out of reach
    m2 = copy.deepcopy(m)
    m2.robot_ = m2.robot_.copy(lower=np.r_[0.0, m2.robot_.lower[1:]], upper=np.r_[0.5, m2.robot_.upper[1:]])
    blocked = _predict(m, q + [1.0, 0, 0, 0, 0, 0])
    c = hykin.Compensator(m2)(np.vstack([far, blocked]), q_branch=np.vstack([[0.4, *q[0, 1:]]] * 2))
    assert not c.success.any() and "out of reach" in c.reason[0], c.reason
    assert c.reason[1].startswith("blocked by a joint limit"), c.reason  # the IK without limits reaches it
    # 1.5 m out: inside the loose reach bound (the sum of the links, ~1.7 m), beyond the arm's real reach:
    # whether the solver stopped at a limit or not, the limit is not named as the cause
    beyond = T.copy()
    beyond[0, :3, 3] = m.robot_.base[:3, 3] + [1.5, 0.0, 0.13]
    c = hykin.Compensator(m)(beyond, q_branch=q)
    assert not c.success[0] and c.reason[0].startswith("unreachable for the model") and "residual" in c.reason[0], c.reason
    assert np.isnan(r.q).all() and np.isnan(r.command).all()
    with pytest.raises(ValueError):
        C.step(np.eye(3), q[0])


def test_generic_models_run_the_same_interface():
    m = exact("ur10", 2)  # predict() only: hybrid IK of hykin.hybrid.ik underneath
    q = m.nominal.random_joints(5, 1, margin=0.2)
    T = hykin.fk(m.robot_, q)
    C = hykin.Compensator(m)
    assert C.kernel is None
    r = C.step(T[0], q[0])
    c = C(T, q_branch=q)
    assert r.success and c.success.all() and np.abs(r.q - c.q[0]).max() < 1e-9


def test_hint_a_turn_outside_the_limits(model):
    m = model
    q = np.array([0.3, -1.4, 1.5, -1.7, -1.5, 0.4])
    T = _predict(m, q[None])[0]
    hint = q + np.array([2 * np.pi, 0, 0, 0, 0, 0])  # 6.58 rad: beyond the +2π limit, the same branch
    r = hykin.Compensator(m).step(T, hint)
    assert r.success and np.abs(r.q - q).max() < 1e-6


def test_walk_candidate_is_the_nearest_representation():
    """branches.Candidates.nearest (the default walk's choice) against a brute force written here: every
    2π shift of every revolute joint within the limits, every valid solution, the nearest to the
    reference; None where no valid solution has a representation within the limits."""
    from hykin import load_robot
    from hykin.compensation.branches import Candidates, nearest_candidate

    rob = load_robot("ur10")
    rng = np.random.default_rng(5)
    N, K, n = 30, 8, rob.dof
    q = rng.uniform(-8.0, 8.0, (N, K, n))
    q[rng.random((N, K)) < 0.2, 0] = np.nan  # solutions a branch lacks
    ok = rng.random((N, K)) < 0.8
    ok[0] = False  # a target without solutions
    q[1, :, 1] = rob.upper[1] + 0.5 + np.arange(K) * 1e-3 - 2 * np.pi * 3  # beyond the limits whatever the turn
    cand = Candidates(rob, q, ok)
    for i in range(N):
        cur = rng.uniform(rob.lower, rob.upper)
        best, best_d = None, np.inf
        for k in range(K):
            if not ok[i, k] or not np.isfinite(q[i, k]).all():
                continue
            rep = np.empty(n)
            for j in range(n):
                shifts = q[i, k, j] + 2 * np.pi * np.arange(-6, 7)
                inside = shifts[(shifts >= rob.lower[j] - 1e-9) & (shifts <= rob.upper[j] + 1e-9)]
                rep[j] = inside[np.argmin(np.abs(inside - cur[j]))] if inside.size else np.nan
            d = np.linalg.norm(rep - cur)
            if np.isfinite(d) and d < best_d:
                best, best_d = rep, d
        got = cand.nearest(i, cur)
        if best is None:
            assert got is None and i in (0, 1)
        else:
            assert np.allclose(got, best, atol=1e-12)
            assert np.array_equal(nearest_candidate(rob, q[i], ok[i], cur), got)


@pytest.mark.parametrize("preset", ["ur10", "kuka-iiwa14"])
def test_compiled_walk_makes_the_same_choices_as_candidates_nearest(preset, monkeypatch):
    """sequential_nearest's compiled walk against its row-by-row Python path (Candidates.nearest), on
    targets along a path with joints near their limits, a target no branch reaches, and 2π turns."""
    from hykin import load_robot
    from hykin.compensation import branches

    if branches._walk is None:
        pytest.skip("numba missing: only the Python walk exists")
    rob = load_robot(preset)
    rng = np.random.default_rng(11)
    q = rob.random_joints(200, 3, margin=0.0)
    q[::7] = np.clip(q[::7] + rng.choice([-1, 1], (len(q[::7]), rob.dof)) * 50.0, rob.lower + 1e-8, rob.upper - 1e-8)
    T = hykin.fk(rob, q)
    T[17, :3, 3] += 50.0  # out of reach
    got = branches.sequential_nearest(rob, T, q[0])
    monkeypatch.setattr(branches, "_walk", None)
    ref = branches.sequential_nearest(rob, T, q[0])
    assert np.isnan(ref[17]).all() and np.array_equal(np.isnan(got), np.isnan(ref))
    np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("preset", ["ur10", "kr6-r900"])
def test_unpolished_walk_picks_the_same_branches(preset):
    """sequential_nearest(polish=False) (the compensator's hints: closed-form solutions as found) picks
    the branch and 2π representation of the polished walk, within the closed form's 1e-9, also at the
    wrist singularity, near the limits and for an unreachable target."""
    from hykin import load_robot
    from hykin.compensation import branches

    rob = load_robot("kuka-kr6-r900" if preset == "kr6-r900" else preset)
    rng = np.random.default_rng(5)
    s = np.linspace(0, 1, 300)[:, None]
    q = rob.random_joints(1, 2, margin=0.3) + s * rng.uniform(-2.0, 2.0, rob.dof)  # a long sweep: branch changes
    q = np.clip(q, rob.lower + 1e-6, rob.upper - 1e-6)
    q[40:45, 4] = 0.0  # wrist singularity
    T = hykin.fk(rob, q)
    T[100, :3, 3] += 10.0  # out of reach
    a = branches.sequential_nearest(rob, T, q[0])
    b = branches.sequential_nearest(rob, T, q[0], polish=False)
    assert np.array_equal(np.isnan(a), np.isnan(b)) and np.isnan(b[100]).all()
    f = np.isfinite(a).all(1)
    assert np.abs(a[f] - b[f]).max() < 1e-6
    regular = f.copy()
    regular[40:45] = False  # at the singularity the wrist angles split freely
    assert np.abs(b[regular] - q[regular]).max() < 1e-6  # the walk follows the path's own joints


def test_revolute_mask_is_per_independent_joint():
    """A URDF with <mimic> joints has more chain joints (9) than joint values (7): the compensator's
    revolute mask, used beside the limits on the hint, is per joint value."""
    from pathlib import Path

    from hykin.io.urdf import load_urdf

    rob = load_urdf(Path(__file__).parent / "data" / "construction_robot.urdf", tip_link="tcp")
    assert rob.n_chain > rob.dof
    C = hykin.Compensator(ExactModel(rob, rob))
    assert C._rev.shape == rob.lower.shape == (rob.dof,)
    assert list(C._rev) == [t == "revolute" for t in rob.independent_joint_type]


@pytest.mark.parametrize("preset,far", [("kuka-iiwa14", False), ("kuka-kr6-r900", True), ("ur10", False)])
def test_position_only_targets_the_robot_reaches_are_all_compensated(preset, far):
    """Positions ``(N, 3)`` without joints: the walk's hints are the calibrated robot's numerical
    position-only solutions (there is no closed form for positions), in its own world (a tracker-frame
    model, ``far``: base 3.6 m away). Before, every hint was the zero pose and targets far from it were
    refused as 'blocked by a joint limit: residual 400 mm'. Reference: the truth robot's positions at
    random joints; the compensated joints must put it there."""
    from comp_models import deviate

    nom = hykin.load_robot(preset)
    truth = deviate(nom, 7)
    if far:
        truth = truth.copy(base=se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, 2.1])),
                                                   np.array([3.0, -1.9, 0.7])) @ truth.base)
    m = ExactModel(nom, truth)
    q = nom.random_joints(60, 11, margin=0.15)
    P = hykin.fk(truth, q)[:, :3, 3]
    c = hykin.compensate(m, P)
    assert c.success.all(), c.reason[~c.success]
    assert np.linalg.norm(hykin.fk(truth, c.q)[:, :3, 3] - P, axis=1).max() < 1e-6


def test_position_only_targets_of_a_fitted_model_are_all_compensated():
    """The same on a fitted model file (the compiled path, whose first solve stays within ±30° of the
    hint): 2 of 120 reachable positions were refused with the zero pose as every hint."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = hykin.HybridModel.load(tiny_model_file())
        q = m.nominal.random_joints(120, 11, margin=0.15)
        P = m.predict(q)[:, :3, 3]
        c = hykin.compensate(m, P)
        assert c.success.all(), c.reason[~c.success]
        assert np.linalg.norm(m.predict(c.q)[:, :3, 3] - P, axis=1).max() * 1e3 < 1e-6
