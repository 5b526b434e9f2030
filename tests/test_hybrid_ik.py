"""Hybrid IK (DESIGN.md §1.3) against a stand-in hybrid model whose correction is a known function.

The stand-in: a perturbed ("calibrated") RX160 as the classical robot plus a smooth residual of
~2 mm / ~0.1° (sums of sines of the joints). Checks are independent of the solver: FK of the returned
joints against the target, closed-form branch counts on the nominal robot, joint limits, and finite
differences for the Jacobian.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hykin.geometry import se3
from hykin.hybrid.ik import (
    HybridIKError,
    branch_count_report,
    hybrid_ik,
    hybrid_ik_from_seeds,
    ik_result_to_rows,
    wang_ik,
)
from hykin.hybrid.ik_solve import IKProblem
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk, fk_torch, jacobian
from hykin.kinematics.ik import ik_closed_form


class StandInHybrid:
    """Classical robot ``robot`` (perturbed RX160) + residual ``Δp = A0 sin(W0 q + φ0)``, ``Δr = A1 sin(W1 q + φ1)``."""

    def __init__(self, seed: int = 0, pos_mm: float = 2.0, rot_deg: float = 0.1, support=None, robot=None):
        rng = np.random.default_rng(seed)
        nom = load_robot("rx160")
        self.nominal = nom
        self.robot = robot if robot is not None else nom.copy(
            a_m=nom.a_m + rng.normal(0, 3e-4, 6), d_m=nom.d_m + rng.normal(0, 3e-4, 6),
            alpha_rad=nom.alpha_rad + rng.normal(0, 3e-4, 6), theta_rad=nom.theta_rad + rng.normal(0, 3e-4, 6),
            beta_rad=rng.normal(0, 2e-4, 6),
        )
        self.W = rng.normal(0, 1.0, (2, 6, 6))
        self.ph = rng.uniform(0, 2 * np.pi, (2, 6))
        self.A = rng.normal(0, 1, (2, 3, 6))
        self.A[0] *= pos_mm * 1e-3 / np.sqrt(6)
        self.A[1] *= np.radians(rot_deg) / np.sqrt(6)
        self.support = support

    def _corr(self, q, xp):
        cv = (lambda a: a) if xp is np else torch.as_tensor
        dp = xp.sin(q @ cv(self.W[0].T) + cv(self.ph[0])) @ cv(self.A[0].T)
        dr = xp.sin(q @ cv(self.W[1].T) + cv(self.ph[1])) @ cv(self.A[1].T)
        return dp, dr

    def predict_classical(self, q):
        return fk(self.robot, q)

    def predict(self, q):
        q = np.asarray(q, dtype=np.float64)
        T = fk(self.robot, q).copy()
        dp, dr = self._corr(q, np)
        T[:, :3, 3] += dp
        T[:, :3, :3] = se3.rotvec_to_matrix(dr) @ T[:, :3, :3]
        return T

    def predict_torch(self, q):
        T = fk_torch(self.robot, q)
        dp, dr = self._corr(q, torch)
        R = se3.so3_exp_torch(dr) @ T[:, :3, :3]
        top = torch.cat([R, (T[:, :3, 3] + dp)[:, :, None]], 2)
        bot = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=q.dtype).expand(q.shape[0], 1, 4)
        return torch.cat([top, bot], 1)

    def support_distance(self, q):
        if self.support is None:
            return np.zeros(len(q))
        lo, hi = self.support
        return np.maximum(np.maximum(lo - q, q - hi), 0.0).max(1)


@pytest.fixture(scope="module")
def model():
    return StandInHybrid()


def well_conditioned(robot, n, rng, min_sv=0.1):
    """Random joints away from singularities (smallest singular value of the Jacobian >= min_sv) with
    joints 4 and 6 in (-170°, 170°), the representation the closed form returns (nearest zero)."""
    q = robot.random_joints(20 * n, rng, margin=0.05)
    q[:, [3, 5]] = rng.uniform(-np.radians(170), np.radians(170), (len(q), 2))
    sv = np.linalg.svd(jacobian(robot, q), compute_uv=False)[:, -1]
    return q[sv >= min_sv][:n]


@pytest.fixture(scope="module")
def sample(model):
    q = well_conditioned(model.robot, 40, np.random.default_rng(7))
    T = model.predict(q)
    return q, T


@pytest.fixture(scope="module")
def solved(model, sample):
    return hybrid_ik(model, sample[1], all_branches=True)


def test_round_trip_accuracy(model, sample, solved):
    q_true, T = sample
    res = solved
    assert res.solved_targets.all()
    ok = res.success
    # independent check: hybrid FK of the returned joints against the targets
    pe, ae = se3.pose_error(model.predict(res.q[ok]), T[res.target[ok]])
    assert pe.max() <= 1e-6 and ae.max() <= 1e-5
    assert np.allclose(pe, res.pos_err_mm[ok], atol=1e-9)
    # the joints the targets were made from are among the solutions
    for t in range(len(T)):
        qs = res.q[ok & (res.target == t)]
        assert np.abs(qs - q_true[t]).max(1).min() < 1e-7


def test_all_branches_match_closed_form_count(model, sample, solved):
    _, T = sample
    n_nominal = ik_closed_form(model.nominal, T).n_solutions
    n_found = np.bincount(solved.target[solved.success], minlength=len(T))
    assert n_found.sum() == n_nominal.sum()
    assert n_found.sum() > 2 * len(T)  # several branches per target, not one
    # distinct: no two solutions of one target within 1e-6 rad
    for t in range(len(T)):
        qs = solved.q[solved.success & (solved.target == t)]
        d = np.abs(qs[:, None] - qs[None]).max(-1) + np.eye(len(qs))
        assert d.min() > 1e-6


def test_joint_limits_respected(model, sample, solved):
    ok = solved.success
    assert model.robot.within_limits(solved.q[ok]).all()


def test_solution_beyond_a_joint_limit_fails(model):
    # Limit joint 2 just below the hybrid solution: the classical seed lies inside, the answer does not.
    q_true = np.radians([[20.0, 30.0, 40.0, 10.0, 50.0, 30.0]])
    T = model.predict(q_true)
    upper = model.robot.upper.copy()
    upper[1] = q_true[0, 1] - np.radians(0.01)
    seed = q_true - 0.0  # classical start at/near the true joints, clipped into the limits by the solver
    m2 = StandInHybrid(robot=model.robot.copy(upper=upper))
    m2.W, m2.ph, m2.A = model.W, model.ph, model.A
    res = hybrid_ik_from_seeds(m2, T, seed[:, None], keep_failed=True)
    assert not res.success.any()
    assert "joint limit" in res.reason[0]
    assert res.q[0, 1] <= upper[1] + 1e-12


def test_unreachable_target_is_reported(model, sample):
    T = sample[1][:2].copy()
    T[1, :3, 3] = [5.0, 0.0, 0.5]  # 5 m away, arm reach ~2 m
    res = hybrid_ik(model, T)
    assert res.solved_targets.tolist() == [True, False]
    bad = res.target == 1
    assert bad.sum() == 1 and not res.success[bad].any()
    assert res.reason[bad][0] != ""


def test_position_only(model, sample):
    q_true, T = sample
    rng = np.random.default_rng(3)
    q_cur = q_true[:10] + rng.normal(0, 0.05, (10, 6))
    res = hybrid_ik(model, T[:10, :3, 3], q_current=q_cur, all_branches=False)
    assert res.position_only and res.success.all() and len(res) == 10
    P = model.predict(res.q)[:, :3, 3]
    assert np.linalg.norm(P - T[res.target, :3, 3], axis=1).max() * 1e3 <= 1e-6
    assert model.robot.within_limits(res.q).all()


def test_nearest_solution(model, sample, solved):
    q_true, T = sample
    rng = np.random.default_rng(5)
    q_cur = q_true + rng.normal(0, 0.01, q_true.shape)
    res = hybrid_ik(model, T, nearest=True, q_current=q_cur)
    assert len(res) == len(T) and (res.target == np.arange(len(T))).all()
    assert np.abs(res.q - q_true).max() < 1e-7
    # Nearest means nearest (probe X A2: a support rule ahead of distance flipped the wrist 183 deg from the
    # seed): with a training support that excludes the true joints of target 0, the true solution is still
    # the answer, and in_support says that it lies outside.
    lo, hi = model.robot.lower.copy(), model.robot.upper.copy()
    sols = solved.q[solved.success & (solved.target == 0)]
    alt = sols[np.abs(sols - q_true[0]).max(1) > 1e-3]
    assert len(alt) > 0
    j = int(np.argmax(np.abs(alt[0] - q_true[0])))
    # support: joint j within a small window around an alternative solution only
    lo[j], hi[j] = alt[0, j] - 1e-3, alt[0, j] + 1e-3
    m2 = StandInHybrid(robot=model.robot, support=(lo, hi))
    m2.W, m2.ph, m2.A = model.W, model.ph, model.A
    res2 = hybrid_ik(m2, T[:1], nearest=True, q_current=q_cur[:1])
    assert len(res2) == 1 and not res2.in_support[0]
    assert np.abs(res2.q[0] - q_true[0]).max() < 1e-7
    # The support breaks near-ties only (within 5 deg of joint distance): current joints on the segment
    # between the two solutions, 2 deg nearer the true one, get the in-support alternative ...
    D = np.linalg.norm(alt[0] - q_true[0])
    u = (alt[0] - q_true[0]) / D
    near = q_true[0] + u * (D - np.radians(2.0)) / 2
    d_all = np.linalg.norm(sols - near, axis=1)  # reference: every solution of the target (all branches)
    assert np.sort(d_all)[1] - d_all.min() < np.radians(5.0)  # the two nearest form a near-tie ...
    assert np.sort(d_all)[2] > d_all.min() + np.radians(5.0)  # ... and no third solution joins it
    res3 = hybrid_ik(m2, T[:1], nearest=True, q_current=near[None])
    assert res3.in_support[0] and np.abs(res3.q[0] - alt[0]).max() < 1e-6
    # ... and 8 deg nearer the true one, no longer a tie: the nearest, outside the support
    far = q_true[0] + u * (D - np.radians(8.0)) / 2
    res4 = hybrid_ik(m2, T[:1], nearest=True, q_current=far[None])
    assert not res4.in_support[0] and np.abs(res4.q[0] - q_true[0]).max() < 1e-7


def test_wang_is_worse(model, sample, solved):
    _, T = sample
    w = wang_ik(model, T)
    fin = np.isfinite(w.pos_err_mm)
    assert fin.sum() >= solved.success.sum() - 2
    ours = solved.pos_err_mm[solved.success].mean()
    theirs = w.pos_err_mm[fin].mean()
    assert theirs > 1e-4  # Wang leaves the change of the correction between q1 and q2
    assert theirs > 1e3 * max(ours, 1e-12)
    assert w.ang_err_deg[fin].mean() > 1e2 * max(solved.ang_err_deg[solved.success].mean(), 1e-12)


def test_jacobian_matches_finite_differences(model, sample):
    q, T = sample
    prob = IKProblem(model, model.robot, T[:5] @ se3.trans(0.001, 0.0, 0.0), False, 1.0)
    rows = np.arange(5)
    Ja = prob.exact_jac(q[:5], rows)
    Jn = prob.fd_jac(q[:5], rows, h=1e-6)
    assert np.abs(Ja - Jn).max() < 1e-7


def test_rows_for_csv(model, sample, solved):
    cols = ik_result_to_rows(solved)
    names = list(cols)
    assert names[:8] == ["target", "branch", "q1", "q2", "q3", "q4", "q5", "q6"]
    for c in ("success", "pos_err_mm", "ang_err_deg", "reason"):
        assert c in cols and len(cols[c]) == len(solved)


def test_bad_input(model):
    with pytest.raises(HybridIKError):
        hybrid_ik(model, np.zeros((3, 5)))
    with pytest.raises(HybridIKError):
        hybrid_ik(model, np.full((1, 4, 4), np.nan))
    with pytest.raises(HybridIKError):
        hybrid_ik(object(), np.eye(4)[None])


@pytest.mark.slow
def test_round_trip_with_a_trained_hybrid_model():
    """rx160-virtual: a small HybridModel (calibration + nets), hybrid FK -> hybrid IK -> hybrid FK."""
    from hykin.hybrid.model import HybridModel
    from hykin.sim.presets import virtual_preset
    from hykin.sim.simulate import simulate

    vr = virtual_preset("rx160-virtual")
    rng = np.random.default_rng(0)
    ds = simulate(vr, vr.nominal.random_joints(3000, rng), noise=False)
    model = HybridModel(vr.nominal, max_seconds=30).fit(ds, progress=False)
    q = well_conditioned(model.robot_, 50, rng)
    T = model.predict(q)
    res = hybrid_ik(model, T)
    assert res.solved_targets.all()
    ok = res.success
    pe, ae = se3.pose_error(model.predict(res.q[ok]), T[res.target[ok]])
    assert pe.max() <= 1e-6 and ae.max() <= 1e-5
    n_nominal = ik_closed_form(vr.nominal, T).n_solutions
    assert np.bincount(res.target[ok], minlength=len(T)).sum() == n_nominal.sum()
    w = wang_ik(model, T)
    assert np.nanmean(w.pos_err_mm) > 1e3 * pe.mean()


def _scipy_roots(model, T, seeds, tol_deg=1e-4):
    """Independent reference: distinct solutions of hybrid FK = T found by scipy's bounded
    least_squares (trust region reflective, finite-difference Jacobian) from ``seeds`` ``(S, 6)``."""
    from scipy.optimize import least_squares

    lo, hi = model.robot.lower, model.robot.upper

    def res(q):
        P = model.predict(q[None])[0]
        return np.concatenate([P[:3, 3] - T[:3, 3], se3.rotation_difference_rotvec(P[None, :3, :3], T[None, :3, :3])[0]])

    out = []
    for s in seeds:
        r = least_squares(res, np.clip(s, lo, hi), bounds=(lo, hi), xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=200)
        pe, ae = se3.pose_error(model.predict(r.x[None]), T[None])
        if pe[0] <= 1e-6 and ae[0] <= 1e-5 and all(np.abs(r.x - o).max() > np.radians(tol_deg) for o in out):
            out.append(r.x)
    return np.array(out)


@pytest.fixture(scope="module")
def singular_sample(model):
    """Targets from joints near the two singularities where the hybrid correction moves solutions far
    from the classical ones: the wrist (joint 5 ≈ 0: joints 4 and 6 move along q4 - q6 by tens of
    degrees) and the stretched elbow (joint 3 ≈ 0: a fold whose pair of solutions the correction shifts)."""
    rng = np.random.default_rng(11)
    q = well_conditioned(model.robot, 6, rng, min_sv=0.0)
    q[:3, 4] = np.radians([0.02, -0.01, 0.05])  # wrist
    q[3:, 2] = np.radians([0.05, -0.08, 0.03])  # elbow
    return q, model.predict(q)


def test_solutions_near_singularities(model, singular_sample):
    """Near the elbow fold the solver finds the generating joints and both roots of the fold (checked
    against scipy). Near the wrist singularity the correction can create extra roots (here up to 3 for
    a closed-form pair: the map is no longer 2-to-1 there); hybrid IK returns one per closed-form branch,
    so the count still equals the closed form's."""
    q_true, T = singular_sample
    res = hybrid_ik(model, T)
    ok = res.success
    assert res.solved_targets.all()
    pe, ae = se3.pose_error(model.predict(res.q[ok]), T[res.target[ok]])
    assert pe.max() <= 1e-6 and ae.max() <= 1e-5
    rep = branch_count_report(model, T, res, model.nominal)
    assert "unexplained" not in rep.kind.values(), rep.reasons
    n_nom = ik_closed_form(model.nominal, T).n_solutions
    for t in range(len(T)):
        qs = res.q[ok & (res.target == t)]
        d = np.abs((qs[:, None] - qs[None] + np.pi) % (2 * np.pi) - np.pi).max(-1) + np.eye(len(qs))
        assert d.min() > 1e-6  # distinct solutions only
        if t < 3:  # wrist
            assert len(qs) == n_nom[t] or rep.near_limit[t]
            continue
        # elbow: the generating joints and every root scipy finds across the fold
        assert np.abs(qs - q_true[t]).max(1).min() < 1e-6
        seeds = np.repeat(q_true[t][None], 13, 0)
        seeds[:, 2] += np.radians(np.linspace(-1.5, 1.5, 13))  # across the fold
        ref = _scipy_roots(model, T[t], seeds)
        assert len(ref) >= 1
        for r in ref:
            assert np.abs((qs - r + np.pi) % (2 * np.pi) - np.pi).max(1).min() < 1e-6, (t, np.degrees(r))


def test_branch_count_report_explains_every_difference(model):
    """Random joints (limits and singularities included): every count difference against the nominal
    closed form is a joint limit or a singularity / workspace edge, and away from the limits the
    counts agree except at a workspace edge."""
    q = model.robot.random_joints(120, np.random.default_rng(21))
    T = model.predict(q)
    res = hybrid_ik(model, T)
    rep = branch_count_report(model, T, res, model.nominal)
    n_nom = ik_closed_form(model.nominal, T).n_solutions
    assert np.array_equal(rep.n_closed_form, n_nom)
    assert np.array_equal(rep.n_found, np.bincount(res.target[res.success], minlength=len(T)))
    assert "unexplained" not in rep.kind.values(), rep.reasons
    edge = np.array([rep.kind.get(t) == "singularity / workspace edge" for t in range(len(T))])
    away = ~rep.near_limit & ~edge
    assert away.sum() >= 0.8 * len(T)
    assert np.array_equal(rep.n_found[away], n_nom[away])
    for t, why in rep.reasons.items():
        assert rep.differ[t] and len(why) >= 1


def test_every_branch_of_a_model_fitted_in_the_tracker_frame():
    """A model fitted on tracker data has its calibrated base metres from the nominal one (here 4.7 m
    and turned 127°) and no closed form of its own: the branches are seeded by the nominal closed form
    in the calibrated base and tool, not at the nominal base (which found 1-2 of 2-8 branches and
    ignored the nearest-joints request). Reference: an exhaustive numerical search on the calibrated
    robot."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from comp_models import ExactModel, deviate

    from hykin.kinematics.ik import ik_all_numeric

    nom = load_robot("kuka-kr6-r900")
    base = se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, np.radians(127.0)])), np.array([4.2, -2.1, 0.8]))
    truth = deviate(nom, 21)
    truth = truth.copy(base=base @ truth.base)
    m = ExactModel(nom, truth)
    q = nom.random_joints(8, 4, margin=0.1)
    T = fk(truth, q)
    res = hybrid_ik(m, T, all_branches=True)
    ref = ik_all_numeric(truth, T, n_seeds=200)
    found = np.bincount(res.target[res.success], minlength=len(T))
    assert np.array_equal(found, np.asarray(ref.n_solutions)), (found, ref.n_solutions)
    near = hybrid_ik(m, T, nearest=True, q_current=q + 0.01)
    assert np.abs(near.q - q).max() < 1e-7


def test_nearest_returns_the_current_joints_branch_of_a_fitted_model():
    """hybrid_ik(nearest=True, q_current=q) on targets the model reaches exactly at q returns q: the
    current joints seed a solution of their own (a 7-DOF arm has no finite branches to choose from: 40
    of 40 came back elsewhere), and a solution a few mrad beyond the sampled joints (fade weight ~1) is
    not traded for an in-support branch radians away (UR10: 5 of 40, up to 4.1 rad)."""
    import sys
    import warnings
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from comp_models import tiny_model_file

    from hykin.hybrid.model import HybridModel

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = HybridModel.load(tiny_model_file())
        q = m.nominal.random_joints(40, 21, margin=0.15)
        T = m.predict(q)
        res = hybrid_ik(m, T, all_branches=True, q_current=q, nearest=True)
        assert len(res) == 40 and res.success.all()
        assert np.abs(res.q - q).max() < 1e-6
        out = np.flatnonzero(m.support_distance(q) > 0)
        assert out.size  # some of these joints lie just outside the sampled ones


def test_nearest_on_a_redundant_arm_returns_the_current_joints():
    """7 DOF (no closed form, no finite set of branches): the current joints seed a solution of their
    own, so targets reached exactly at them come back there (every one came back elsewhere, ~1.7 rad)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).parent))
    from comp_models import exact

    m = exact("kuka-iiwa14", 3)
    q = m.nominal.random_joints(12, 21, margin=0.15)
    res = hybrid_ik(m, fk(m.robot_, q), all_branches=True, q_current=q, nearest=True)
    assert len(res) == 12 and res.success.all()
    assert np.abs(res.q - q).max() < 1e-6
