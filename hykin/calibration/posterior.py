"""Prior rows of the calibration's normal equations and the posterior it reports (used by
:mod:`hykin.calibration.calibrate`; the priors themselves are :mod:`hykin.calibration.priors`).

:func:`prior_system`: the rows ``(σ / τ_k) dev_k`` pulling each estimated parameter toward the robot
file (``dev`` = :func:`~hykin.calibration.params.deviations_between` the file and the current state)
and their derivative with respect to an LM step (1 for additive parameters; by finite differences
of :func:`~hykin.calibration.params.apply_step` for frame twists, whose deviation from the file is
not additive). :func:`reset_held`: parameters held at their prior put back at the file's value.
:func:`posterior`: covariance ``(Jᵀ Σ⁻¹ J + diag(τ⁻²))⁻¹`` of the estimated parameters, standard
deviations, correlations and the status of every parameter.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import ModelState, ParamSpec, apply_step, deviations_between

__all__ = ["ADDITIVE_GROUPS", "CORRELATED", "PriorContext", "noise_variances", "posterior", "prior_system", "prior_weight", "reset_held"]

#: groups whose deviation from the file is the sum of the steps (derivative 1)
ADDITIVE_GROUPS = ("geom", "comp", "point")
#: |posterior correlation| at which two estimated parameters are reported "correlated" (not "identified")
CORRELATED = 0.99
_FD = 1e-4  # finite-difference step, in scaled units (1e-7 m / 1e-7 rad)


@dataclass
class PriorContext:
    """The priors of one calibration: the robot file's state (prior mean), tolerances by parameter
    name (SI), the excitation floors (m, rad), the given noise (m or None) and the rank tolerances."""

    file_state: ModelState
    tol_by_name: dict
    floor_m: float
    floor_rad: float
    noise_m: float | None
    rank_tol: float
    negligible_tol: float

    def tol(self, specs) -> np.ndarray:
        return np.array([self.tol_by_name[s.name] for s in specs])


def _dev_jacobian(file_state: ModelState, state: ModelState, specs: list[ParamSpec], cols: np.ndarray,
                  rows: np.ndarray, scale: np.ndarray, dev: np.ndarray) -> np.ndarray:
    """``(len(rows), len(cols))`` d dev[rows] / d step[cols] in scaled units."""
    J = np.zeros((rows.size, cols.size))
    pos = {int(k): i for i, k in enumerate(rows)}
    for j, k in enumerate(cols):
        s = specs[k]
        if s.group in ADDITIVE_GROUPS:
            if int(k) in pos:
                J[pos[int(k)], j] = scale[k]
            continue
        mates = [i for i, r in enumerate(rows) if specs[r].group == s.group and specs[r].joint == s.joint]
        if not mates:
            continue
        delta = np.zeros(len(specs))
        delta[k] = _FD * scale[k]
        d2 = deviations_between(file_state, apply_step(state, specs, delta), specs)
        for i in mates:
            J[i, j] = (d2[rows[i]] - dev[rows[i]]) / _FD
    return J


def prior_system(file_state: ModelState, state: ModelState, specs: list[ParamSpec], act: np.ndarray,
                 weight: np.ndarray, scale: np.ndarray, jacobian: bool = True):
    """Prior rows at ``state`` for the estimated parameters ``act`` (indices).

    weight: ``(P,)`` ``σ / τ`` (0 for uninformative ones). Returns ``(r, A, g)``: the rows ``r`` ``(k,)``
    (metres, like the data residual), and (with ``jacobian``) their normal-equation terms ``A``
    ``(P, P)`` and ``g`` ``(P,)`` in scaled units, zero outside ``act`` (None, None without).
    """
    P = len(specs)
    rows = act[weight[act] > 0]
    dev = deviations_between(file_state, state, specs)
    r = weight[rows] * dev[rows]
    if not jacobian:
        return r, None, None
    A, g = np.zeros((P, P)), np.zeros(P)
    if rows.size:
        Jd = _dev_jacobian(file_state, state, specs, act, rows, scale, dev) * weight[rows][:, None]
        A[np.ix_(act, act)] = Jd.T @ Jd
        g[act] = Jd.T @ r
    return r, A, g


def reset_held(file_state: ModelState, state: ModelState, specs: list[ParamSpec], held: np.ndarray,
               scale: np.ndarray, iters: int = 3) -> ModelState:
    """``state`` with the parameters ``held`` (indices, finite tolerance) back at the robot file's value
    (Newton on their deviations; exact in one step for additive parameters)."""
    if held.size == 0:
        return state
    for _ in range(iters):
        dev = deviations_between(file_state, state, specs)
        if np.max(np.abs(dev[held] / scale[held])) < 1e-9:
            break
        J = _dev_jacobian(file_state, state, specs, held, held, scale, dev)
        try:
            step = -np.linalg.solve(J, dev[held])
        except np.linalg.LinAlgError:
            step = -np.linalg.lstsq(J, dev[held], rcond=None)[0]
        delta = np.zeros(len(specs))
        delta[held] = step * scale[held]
        state = apply_step(state, specs, delta)
    return state


def posterior(lin: dict, est: np.ndarray, tol_si: np.ndarray, scale: np.ndarray, sig2_p: float, sig2_o: float,
              names: list[str]):
    """Posterior of the estimated parameters ``est`` (indices) from the scaled normal equations ``lin``
    (``JtJ_p``, ``JtJ_o``) with residual variances ``sig2_p`` / ``sig2_o`` (m², weighted orientation
    rows) and prior tolerances ``tol_si``.

    Returns ``(std (len(est),) SI, corr (k, k), strong [(a, b, rho)] |rho| > 0.9, partners {i: [(name, rho)]}
    with |rho| >= CORRELATED)``.
    """
    k = est.size
    if k == 0:
        return np.zeros(0), np.zeros((0, 0)), [], {}
    Jp = lin["JtJ_p"][np.ix_(est, est)]
    Jo = lin["JtJ_o"][np.ix_(est, est)]
    H = Jp / max(sig2_p, 1e-300) + (Jo / max(sig2_o, 1e-300) if sig2_o > 0 else 0.0)
    with np.errstate(divide="ignore"):
        prec = np.where(np.isfinite(tol_si[est]), (scale[est] / tol_si[est]) ** 2, 0.0)
    H = H + np.diag(prec)
    D = np.sqrt(np.diag(H))
    D[D == 0] = 1.0
    cov_s = np.linalg.pinv(H / np.outer(D, D), rcond=1e-15, hermitian=True) / np.outer(D, D)
    sd_s = np.sqrt(np.clip(np.diag(cov_s), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.nan_to_num(cov_s / np.outer(sd_s, sd_s))
    strong, partners = [], {}
    for a in range(k):
        for b in range(a + 1, k):
            rho = float(corr[a, b])
            if abs(rho) > 0.9:
                strong.append((names[est[a]], names[est[b]], rho))
            if abs(rho) >= CORRELATED:
                partners.setdefault(a, []).append((names[est[b]], rho))
                partners.setdefault(b, []).append((names[est[a]], rho))
    return sd_s * scale[est], corr, strong, partners


def noise_variances(rp: np.ndarray, ro: np.ndarray | None, n_est: int, noise_m: float | None) -> tuple[float, float]:
    """Residual variances per coordinate ``(σ_p², σ_o²)`` (m², weighted orientation rows): ``noise_m²``
    for both when given, else from the residuals with ``n_est`` degrees of freedom removed."""
    if noise_m is not None:
        return noise_m ** 2, (0.0 if ro is None else noise_m ** 2)
    m_p = rp.size
    m_o = 0 if ro is None else ro.size
    m = m_p + m_o
    frac = max(m - n_est, 1) / m
    s_p = float(np.sum(rp * rp)) / max(m_p * frac, 1e-300)
    s_o = 0.0 if ro is None else float(np.sum(ro * ro)) / max(m_o * frac, 1e-300)
    return s_p, s_o


def prior_weight(tol_si: np.ndarray, sigma_m: float) -> np.ndarray:
    """``(P,)`` weights ``σ / τ`` of the prior rows (0 where uninformative)."""
    with np.errstate(divide="ignore"):
        return np.where(np.isfinite(tol_si), sigma_m / tol_si, 0.0)

