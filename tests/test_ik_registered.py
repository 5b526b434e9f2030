"""Hybrid IK and compensation on a registered model (a moved tracker, a new tool: ``frame_pre_`` /
``frame_post_``), and IK of a batch with an unreachable target on an arm without joints beyond a turn
(probe report s39: reachable targets reported "out of reach", a crash). Reference: the exact robot's
FK in the registered frames, computed here as ``W · fk(q) · E``."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from hykin.geometry import se3
from hykin.kinematics.fk import fk

W = se3.trans(3.1, -2.2, 0.6) @ se3.rotz(np.radians(125.0)) @ se3.rotx(np.radians(4.0))  # the moved tracker
E = se3.trans(0.035, -0.02, 0.06) @ se3.roty(np.radians(20.0))  # the new tool on the old TCP


@pytest.fixture(scope="module")
def registered(exact_rx160_model):
    m = copy.deepcopy(exact_rx160_model)
    m.frame_pre_, m.frame_post_ = W, E
    return m


def _targets(model, n=12, seed=2):
    rob = model.robot
    q = rob.random_joints(n, np.random.default_rng(seed))
    q = np.clip(q, model.support_lower_, model.support_upper_)  # inside the training support
    return q, W @ fk(rob, q) @ E


def test_hybrid_ik_on_a_registered_model_reaches_targets_in_its_frame(registered):
    from hykin.hybrid.ik import hybrid_ik

    q_true, T = _targets(registered)
    res = hybrid_ik(registered, T, all_branches=False, q_current=q_true, nearest=True)
    assert res.success.all(), res.reason
    T_got = W @ fk(registered.robot, res.q) @ E
    assert np.abs(T_got[:, :3, 3] - T[:, :3, 3]).max() < 1e-8
    assert np.abs(res.q - q_true).max() < 1e-6  # the seeded branch: the true joints


def test_all_branches_on_a_registered_model(registered):
    from hykin.hybrid.ik import hybrid_ik

    q_true, T = _targets(registered, n=4, seed=3)
    res = hybrid_ik(registered, T, all_branches=True)
    for t in range(4):
        sel = res.success & (res.target == t)
        assert sel.sum() >= 2  # an RX160 reaches these in several branches
        d = np.abs(np.angle(np.exp(1j * (res.q[sel] - q_true[t])))).max(axis=1)
        assert d.min() < 1e-6  # the true configuration is among them (modulo 2π: one representation per branch)
        T_got = W @ fk(registered.robot, res.q[sel]) @ E
        assert np.abs(T_got[:, :3, 3] - T[t, :3, 3]).max() < 1e-8


def test_compensate_on_a_registered_model(registered):
    from hykin.compensation.compensator import compensate

    q_true, T = _targets(registered, n=8, seed=4)
    c = compensate(registered, T, q_branch=q_true)
    assert c.success.all(), c.reason
    assert np.abs(c.q - q_true).max() < 1e-6


def test_ik_batch_with_an_unreachable_target_on_an_arm_within_one_turn(tmp_path):
    """kuka-iiwa14: no joint range over 2π; one target 8 m away fails alone, the other is solved."""
    from hykin.hybrid.ik import hybrid_ik
    from hykin.io.robot_file import load_robot
    from hykin.kinematics.classical import ClassicalModel

    rob = load_robot("kuka-iiwa14")
    rob = rob.copy(stiffness_nm_per_rad=np.full(rob.dof, 1e6))  # the compliant (hybrid) path, as `hykin ik` takes it
    q = rob.random_joints(1, np.random.default_rng(1)) * 0.5
    T = np.concatenate([fk(rob, q), se3.trans(8.0, 0.0, 0.5)[None]])
    for kw in ({"all_branches": True}, {"q_current": np.repeat(q, 2, axis=0), "nearest": True}):  # `hykin ik` default
        res = hybrid_ik(ClassicalModel(rob), T, **kw)
        assert res.success[res.target == 0].any() and not res.success[res.target == 1].any()
        ok = res.success & (res.target == 0)
        assert np.abs(fk(rob, res.q[ok])[:, :3, 3] - T[0, :3, 3]).max() < 1e-3  # the deflecting arm: within 1 mm


def test_a_failed_ik_row_has_no_support_distance(registered):
    """Probe report s40: an unsolved row kept the best attempt's support distance and in_support, while its
    joints are blank (docs/serve.md: null where not solved)."""
    from hykin.hybrid.ik import hybrid_ik, ik_result_to_rows

    q, T = _targets(registered, n=3, seed=5)
    T[1, :3, 3] += 8.0  # 8 m away: unreachable
    res = hybrid_ik(registered, T, all_branches=False, q_current=q, nearest=True)
    rows = ik_result_to_rows(res, robot=registered.robot_, targets=T)
    ok = np.asarray(rows["success"], dtype=bool)
    assert ok.sum() == 2 and not ok[np.asarray(rows["target"]) == 1].any()
    bad = ~ok
    assert np.isnan(rows["support_distance"][bad]).all() and (rows["in_support"][bad] == 0).all()
    assert np.isnan(rows["q1"][bad]).all() and np.isfinite(rows["support_distance"][ok]).all()
