"""The shared projected LM (hykin.kinematics.lm) against independent references."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import lsq_linear

from hykin.io.robot_file import load_robot
from hykin.kinematics import ik as kin_ik
from hykin.kinematics.fk import HAVE_NUMBA, fk
from hykin.kinematics.lm import damped_step, lm_solve, projected_step


@pytest.mark.parametrize("damping", ["identity", "scaled"])
def test_min_norm_form_equals_normal_equations(damping):
    """m < n: -Jᵀ(JJᵀ + λsI)⁻¹r equals -(JᵀJ + λsI)⁻¹Jᵀr (push-through identity), solved here directly."""
    rng = np.random.default_rng(0)
    J, r, lam = rng.normal(size=(5, 3, 6)), rng.normal(size=(5, 3)), np.full(5, 1e-2)
    got = damped_step(J, r, lam, damping)
    s = np.ones(5) if damping == "identity" else np.einsum("kij,kij->k", J, J) / 6
    ref = np.stack([-np.linalg.solve(J[k].T @ J[k] + lam[k] * s[k] * np.eye(6), J[k].T @ r[k]) for k in range(5)])
    assert np.abs(got - ref).max() < 1e-10


def test_projected_step_respects_box_and_frozen_joints_are_on_bounds():
    rng = np.random.default_rng(1)
    J, r = rng.normal(size=(50, 6, 6)), rng.normal(size=(50, 6))
    q = rng.uniform(-0.1, 0.1, (50, 6))
    lo, hi = np.full((50, 6), -0.2), np.full((50, 6), 0.2)
    dq = projected_step(J, r, np.full(50, 1e-6), q, lo, hi)
    assert np.all(q + dq <= hi + 1e-12) and np.all(q + dq >= lo - 1e-12)


def test_bounded_linear_least_squares_matches_scipy():
    """Linear residual r = A q - b in a box: LM reaches the bounded minimum of scipy's lsq_linear (the
    unbounded lstsq one where no bound is active; within 1e-4 of the cost where bounds are active: the active-set projection
    converges slowly along active bounds) and never leaves the box."""
    rng = np.random.default_rng(2)
    k, m, n = 40, 8, 4
    A, b = rng.normal(size=(k, m, n)), rng.normal(size=(k, m)) * 0.6
    lo, hi = -np.ones(n) * 0.5, np.ones(n) * 0.5

    def residual(q, idx):
        return np.einsum("kij,kj->ki", A[idx], q) - b[idx], ()

    res = lm_solve(residual, lambda q, idx, aux, it: A[idx], np.zeros((k, n)), lo, hi,
                   converged=lambda r: np.zeros(len(r), bool), lam0=1e-3, max_iter=200)
    ref = np.stack([lsq_linear(A[i], b[i], bounds=(lo, hi), tol=1e-14).x for i in range(k)])
    free = np.all((ref > lo + 1e-9) & (ref < hi - 1e-9), axis=1)
    assert 5 <= free.sum() < k  # both kinds of rows are tested
    ls = np.stack([np.linalg.lstsq(A[i], b[i], rcond=None)[0] for i in np.flatnonzero(free)])  # = bounded optimum
    # the cost is flat to float precision within ~1e-8 of the optimum: acceptance stops there
    assert np.abs(res.q[free] - ls).max() < 1e-7
    cost = np.einsum("ki,ki->k", res.r, res.r)
    cost_ref = ((np.einsum("kij,kj->ki", A, ref) - b) ** 2).sum(1)
    assert np.all(cost <= cost_ref * (1 + 1e-4))
    assert np.all((res.q >= lo) & (res.q <= hi))


@pytest.mark.skipif(not HAVE_NUMBA, reason="compares the compiled kernel with the numpy loop")
@pytest.mark.parametrize("position_only", [False, True])
def test_compiled_kernel_and_numpy_loop_follow_one_rule(position_only):
    """Same rule, same iterates: from seeds far enough to hit joint limits, both end on the same joints."""
    r = load_robot("rx160")
    rng = np.random.default_rng(0)
    q = r.random_joints(200, rng)
    T = fk(r, q)
    q0 = np.clip(q + rng.normal(0, 0.6, q.shape), r.lower, r.upper)
    a = kin_ik.solve_lm(r, T, q0.copy(), position_only, 1e-10, 1e-10, 200)
    b = kin_ik._lm_numpy(r, T, q0.copy(), position_only, 1e-10, 1e-10, 2000, 1e-3, r.lower, r.upper)
    same = np.abs(a[0] - b[0]).max(1) < 1e-6
    assert same.mean() >= 0.98
    conv_a = (a[1] <= 1e-10) & (a[2] <= 1e-10)
    conv_b = (b[1] <= 1e-10) & (b[2] <= 1e-10)
    assert abs(int(conv_a.sum()) - int(conv_b.sum())) <= 2
