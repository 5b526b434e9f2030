"""Standard deviations of a calibration with held parameters (the "consider" covariance of
:func:`hykin.calibration.posterior.posterior`).

References are independent of hykin: a linear model ``y = J_e x_e + J_h x_h + noise`` written here,
its estimate (the MAP with ``x_h`` held at 0) in closed form and a Monte-Carlo over draws of the noise,
of the held parameters from their priors and of the estimated ones from theirs; the joint Gaussian
posterior inverted here; the known truth of a simulated robot."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from hykin.calibration.calibrate import calibrate
from hykin.calibration.params import apply_deviations
from hykin.calibration.posterior import posterior, posterior_parts
from hykin.kinematics.fk import fk

SCALE = 1e-3  # hykin's scaled units: the columns are d residual / (1e-3 SI)


def _lin(Jp, Jo=None):
    """hykin's normal-equation dict from SI Jacobians (position rows, orientation rows)."""
    P = Jp.shape[1]
    Js = Jp * SCALE
    out = {"JtJ_p": Js.T @ Js, "JtJ_o": np.zeros((P, P))}
    if Jo is not None:
        Jos = Jo * SCALE
        out["JtJ_o"] = Jos.T @ Jos
    return out


def _problem(seed=0, m_p=60, m_o=30):
    """Columns: e0..e3 estimated (e0 uninformative), h4 held and partly absorbed by the estimated ones,
    h5 held and exactly a combination of e1, e2 (a joint parameter absorbs it), h6 held, a zero column."""
    rng = np.random.default_rng(seed)
    Jp = rng.normal(0, 1, (m_p, 7))
    Jo = rng.normal(0, 1, (m_o, 7))
    for J in (Jp, Jo):
        J[:, 4] = 0.8 * J[:, 1] - 0.5 * J[:, 3] + 0.15 * J[:, 4]  # mostly explained, not exactly
        J[:, 5] = 0.7 * J[:, 1] + 0.3 * J[:, 2]  # exactly explained
        J[:, 6] = 0.0
    tol = np.array([np.inf, 0.02, 0.05, 0.03, 0.04, 0.05, 0.5])
    return Jp, Jo, tol


def test_consider_covariance_matches_monte_carlo_over_noise_and_held_parameters():
    Jp, Jo, tol = _problem()
    sp, so = 0.01, 0.004  # noise of position and orientation rows (SI)
    est, held = np.arange(4), np.array([4, 5, 6])
    names = [f"e{i}" for i in range(4)] + ["h4", "h5", "h6"]
    # the estimator (MAP, x_h held at 0), in closed form
    W = np.concatenate([np.full(Jp.shape[0], sp ** -2), np.full(Jo.shape[0], so ** -2)])
    J = np.vstack([Jp, Jo])
    prec = np.where(np.isfinite(tol[est]), tol[est] ** -2.0, 0.0)
    A = J[:, est].T @ (W[:, None] * J[:, est]) + np.diag(prec)
    rng = np.random.default_rng(1)
    M = 40_000
    x = rng.normal(0, 1, (M, 7)) * np.where(np.isfinite(tol), tol, 1.0)  # truth drawn from the priors
    noise = rng.normal(0, 1, (M, J.shape[0])) * np.sqrt(1 / W)
    y = x @ J.T + noise
    xhat = np.linalg.solve(A, ((y * W) @ J[:, est]).T).T
    err = xhat - x[:, est]
    mc_sd = err.std(0)
    sd, corr, strong, partners, sd_data = posterior_parts(_lin(Jp, Jo), est, tol, np.full(7, SCALE), sp ** 2, so ** 2, names)
    # the data-only term alone says far less than the estimates actually scatter
    assert np.all(mc_sd / sd_data > 1.5)
    # the exactly absorbed h5 counts: an estimated joint parameter absorbing it is not known better than it
    np.testing.assert_allclose(sd, mc_sd, rtol=0.02)
    # posterior correlation of the estimated parameters' true values with the held ones: -corr(error, x_h)
    for a, lst in partners.items():
        for other, rho in lst:
            if other.startswith("h"):
                h = int(other[1:])
                mc_rho = -np.corrcoef(err[:, a], x[:, h])[0, 1]
                assert rho == pytest.approx(mc_rho, abs=0.01)  # Monte-Carlo error (1 - rho²) / sqrt(M) ~ 0.002
    assert any(o == "h5" for lst in partners.values() for o, _ in lst)  # e1/e2 dominated by h5: "correlated"
    # the 4-tuple API gives the same std
    np.testing.assert_allclose(posterior(_lin(Jp, Jo), est, tol, np.full(7, SCALE), sp ** 2, so ** 2, names)[0], sd)


def test_frame_conventions_are_left_out_and_bound_parameters_are_marginalised():
    rng = np.random.default_rng(2)
    m = 80
    Jp = rng.normal(0, 1, (m, 6))
    Jp[:, 4] = 2.0 * Jp[:, 0]  # "d1": exactly the base's column
    tol = np.array([np.inf, 0.05, 0.05, 0.05, 0.005, 0.2])
    names = ["base.z", "a2", "d4", "theta3", "d1", "c2"]
    s2 = 1e-4
    est = np.array([0, 1, 2, 3])
    lin = _lin(Jp)
    # d1 against base.z: a convention of the base frame, not an error (base.z unchanged)
    sd, _, _, partners, sd_data = posterior_parts(lin, est, tol, np.full(6, SCALE), s2, 0.0, names, held=np.array([4]))
    np.testing.assert_allclose(sd, sd_data, rtol=1e-9)
    assert not partners
    # "c2" at its bound: marginal of the joint Gaussian posterior over est + c2, inverted here
    ext = np.array([0, 1, 2, 3, 5])
    H = Jp[:, ext].T @ Jp[:, ext] / s2 + np.diag(np.where(np.isfinite(tol[ext]), tol[ext] ** -2.0, 0.0))
    ref = np.sqrt(np.diag(np.linalg.inv(H)))[:4]
    sd_b = posterior_parts(lin, est, tol, np.full(6, SCALE), s2, 0.0, names, held=np.zeros(0, int), bound=np.array([5]))[0]
    np.testing.assert_allclose(sd_b, ref, rtol=1e-6)
    # default: a compliance (c<k>) outside est is marginalised, not taken at its whole tolerance
    sd_d = posterior_parts(lin, est, tol, np.full(6, SCALE), s2, 0.0, names)[0]
    np.testing.assert_allclose(sd_d, ref, rtol=1e-6)


def _irb(rng, n):
    from hykin.io.robot_file import load_robot

    nom = load_robot("abb-irb2400")
    return nom, nom.random_joints(n, rng)


def test_position_only_calibration_std_covers_a_held_parameter_error():
    """IRB 2400, positions only, base known: alpha5 (0.3 deg off in the truth) and theta5 are held and
    d5 absorbs them; the reported std of every estimated parameter covers its true deviation."""
    rng = np.random.default_rng(3)
    nom, q = _irb(rng, 50)
    dev = {"alpha5": math.radians(0.3), "a2": 3e-4, "theta3": 5e-4, "d4": -2e-4}
    truth = apply_deviations(nom, dev)
    y = fk(truth, q)[:, :3, 3] + rng.normal(0, 1e-5, (len(q), 3))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = calibrate(nom, (q, y), compliance=False, base=False, checks=False, outliers="keep", max_iter=20)
    assert "alpha5" in res.held_names
    z = {n: (v - dev.get(n, 0.0)) / s for n, v, s, m in zip(res.names, res.values, res.std, res.identifiable) if m}
    assert max(abs(v) for v in z.values()) < 3, z
    i = res.names.index("d5")
    assert abs(res.values[i]) > 1e-4  # d5 really moved (0.45 mm: what alpha5 held at 0 left it) ...
    assert res.status[i] == "correlated" and any(a == "alpha5" for a, _ in res.correlated_with[i])  # ... not "identified"
    text = res.report()
    assert "held at prior)" in text and "as written to the robot file" in text
