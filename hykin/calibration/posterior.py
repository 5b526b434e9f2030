"""Prior rows of the calibration's normal equations and the posterior it reports (used by
:mod:`hykin.calibration.calibrate`; the priors themselves are :mod:`hykin.calibration.priors`).

:func:`prior_system`: the rows ``(σ / τ_k) dev_k`` pulling each estimated parameter toward the robot
file (``dev`` = :func:`~hykin.calibration.params.deviations_between` the file and the current state)
and their derivative with respect to an LM step (1 for additive parameters; by finite differences
of :func:`~hykin.calibration.params.apply_step` for frame twists, whose deviation from the file is
not additive). :func:`reset_held`: parameters held at their prior put back at the file's value.
:func:`posterior`: standard deviations of the estimated parameters from the "consider" covariance
``A_e⁻¹ + K Σ_h Kᵀ`` (``A_e = J_eᵀ Σ⁻¹ J_e + diag(τ_e⁻²)``; the held parameters' tolerances ``Σ_h``
carried through the fit by ``K = A_e⁻¹ J_eᵀ Σ⁻¹ J_h``), their correlations, and the partners that
make a parameter "correlated" (an estimated one, or a held one whose tolerance dominates its std).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from .params import ModelState, ParamSpec, apply_step, deviations_between

__all__ = ["ADDITIVE_GROUPS", "CORRELATED", "GAUGE", "UNDETERMINED", "PriorContext", "noise_variances", "posterior",
           "posterior_parts", "prior_system", "prior_weight", "reset_held", "statuses"]

#: groups whose deviation from the file is the sum of the steps (derivative 1)
ADDITIVE_GROUPS = ("geom", "comp", "point")
#: |posterior correlation| at which two estimated parameters are reported "correlated" (not "identified")
CORRELATED = 0.99
#: a held parameter whose data column the estimated frames (base, tool, stations) reproduce but for this
#: fraction of its norm is a convention of those frames (``theta1`` against ``base.rz``, ``d6`` against
#: ``tool.z``), left out of the consider covariance
GAUGE = 1e-4
#: an estimate whose posterior std reaches this fraction of its tolerance (or, uninformative, of its kind's
#: reference scale) is "undetermined", never "identified": the data hardly narrow it (std >= tol / 2: the
#: data bring at most 3x the prior's information)
UNDETERMINED = 0.5
#: frame parameters' names (base, tool, further stations and tools, further reflectors' offsets)
_FRAME = re.compile(r"(base|tool|station\[|tool\[|p\d+\.)")
_COMPLIANCE = re.compile(r"c\d+")  # compliance parameters' names (hykin.calibration.params.candidate_specs)
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
    #: per name, the scale (SI) against which a std makes an estimate "undetermined" (:func:`statuses`):
    #: the tolerance where finite, else :func:`hykin.calibration.priors.label_scales`; None: the tolerances
    label_by_name: dict | None = None

    def tol(self, specs) -> np.ndarray:
        return np.array([self.tol_by_name[s.name] for s in specs])

    def label_scale(self, specs) -> np.ndarray:
        by = self.label_by_name or self.tol_by_name
        return np.array([by.get(s.name, self.tol_by_name[s.name]) for s in specs])


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


def _info(lin: dict, rows: np.ndarray, cols: np.ndarray, sig2_p: float, sig2_o: float) -> np.ndarray:
    """Data information ``Jᵀ Σ⁻¹ J`` (scaled units) between the parameters ``rows`` and ``cols``."""
    H = lin["JtJ_p"][np.ix_(rows, cols)] / max(sig2_p, 1e-300)
    if sig2_o > 0:
        H = H + lin["JtJ_o"][np.ix_(rows, cols)] / sig2_o
    return H


def _gauge(H_ee: np.ndarray, H_eh: np.ndarray, d_hh: np.ndarray) -> np.ndarray:
    """``(h,)`` bool: held columns that the estimated columns ``e`` reproduce exactly in the data (the
    unexplained part of the column below :data:`GAUGE` of its norm, or a zero column)."""
    if H_ee.shape[0] == 0:
        return d_hh <= 0
    D = np.sqrt(np.diag(H_ee))
    D[D == 0] = 1.0
    inv = np.linalg.pinv(H_ee / np.outer(D, D), rcond=1e-12, hermitian=True) / np.outer(D, D)
    explained = np.einsum("ij,ik,kj->j", H_eh, inv, H_eh)
    with np.errstate(invalid="ignore", divide="ignore"):
        frac = np.where(d_hh > 0, 1.0 - explained / d_hh, 0.0)
    return ~(frac > GAUGE ** 2)


def posterior(lin: dict, est: np.ndarray, tol_si: np.ndarray, scale: np.ndarray, sig2_p: float, sig2_o: float,
              names: list[str], held: np.ndarray | None = None, bound: np.ndarray | None = None):
    """Posterior of the estimated parameters ``est`` (indices) from the scaled normal equations ``lin``
    (``JtJ_p``, ``JtJ_o`` over all parameters) with residual variances ``sig2_p`` / ``sig2_o`` (m²,
    weighted orientation rows) and prior tolerances ``tol_si``.

    Covariance ``A_e⁻¹ + K Σ_h Kᵀ`` ("consider" covariance): ``A_e = J_eᵀ W J_e + diag(τ_e⁻²)`` the
    estimated block (prior rows included) and, for the parameters ``held`` at the robot file (indices;
    None: every parameter outside ``est`` and ``bound`` with a finite tolerance), ``K = A_e⁻¹ J_eᵀ W J_h``
    how their error moves the estimate and ``Σ_h = diag(τ_h²)`` their prior. A held parameter that the
    estimated frames alone (base, tool, further stations and tools, reflector offsets) reproduce
    exactly in the data (:func:`_gauge`: ``d1``/``theta1`` against ``base.z``/``base.rz``, the last
    joint's parameters against the tool) is left out: the frames are expressed for its robot-file value,
    a convention, not an error. One that joint parameters reproduce exactly (``d3`` against ``d2`` for
    parallel axes) is kept: ``d2`` alone is then not known better than ``d3``'s tolerance (its status
    says "correlated with d3"). ``bound``: parameters held at a bound
    (a compliance at 0) with what the data say of them: marginalised (estimated for the covariance with
    their prior, then left out) instead of taken at their whole tolerance; None: every compliance
    (``c1`` ...) outside ``est`` (one held at 0 because the data pushed it below is told by the data,
    its whole tolerance would swamp every estimate; an unexcited one moves the data too little to matter).

    Returns ``(std (len(est),) SI, corr (k, k), strong [(a, b, rho)] |rho| > 0.9, partners {i: [(name, rho)]}
    with |rho| >= CORRELATED)``. ``std`` includes the held parameters' term; ``corr`` and ``strong`` are
    those of ``A_e⁻¹`` (what the data tell about the estimated parameters among themselves); ``partners``
    also names held parameters whose posterior correlation ``-(K Σ_h)_ij / (std_i τ_j)`` with an estimated
    one reaches :data:`CORRELATED` (at least 98 % of its variance is that held parameter's: the data tell
    their combination, the robot file's value of the held one the split). :func:`posterior_parts` also
    gives the standard deviations without the held parameters' term.
    """
    sd, corr, strong, partners, _ = posterior_parts(lin, est, tol_si, scale, sig2_p, sig2_o, names, held, bound)
    return sd, corr, strong, partners


def posterior_parts(lin: dict, est: np.ndarray, tol_si: np.ndarray, scale: np.ndarray, sig2_p: float,
                    sig2_o: float, names: list[str], held: np.ndarray | None = None, bound: np.ndarray | None = None):
    """:func:`posterior` and, last, ``sd_data`` ``(len(est),)`` SI: the standard deviations without the
    held parameters' term (``sd / sd_data`` large: the estimate is limited by what is held, not by the data)."""
    k = est.size
    if k == 0:
        return np.zeros(0), np.zeros((0, 0)), [], {}, np.zeros(0)
    est = np.asarray(est, dtype=np.int64)
    if bound is None:  # compliances outside est: at their bound 0, or not excited (see posterior())
        bound = np.array([i for i, n in enumerate(names) if _COMPLIANCE.fullmatch(n)], dtype=np.int64)
    bound = np.setdiff1d(np.asarray(bound, dtype=np.int64), est)
    if held is None:
        held = np.setdiff1d(np.flatnonzero(np.isfinite(tol_si)), np.concatenate([est, bound]))
    held = np.asarray(held, dtype=np.int64)
    held = held[np.isfinite(tol_si[held]) & (tol_si[held] > 0)]
    ext = np.concatenate([est, bound])  # estimated for the covariance; the bound ones are marginalised
    H_data = _info(lin, ext, ext, sig2_p, sig2_o)
    with np.errstate(divide="ignore"):
        prec = np.where(np.isfinite(tol_si[ext]), (scale[ext] / tol_si[ext]) ** 2, 0.0)
    H = H_data + np.diag(prec)
    D = np.sqrt(np.diag(H))
    D[D == 0] = 1.0
    cov_x = np.linalg.pinv(H / np.outer(D, D), rcond=1e-15, hermitian=True) / np.outer(D, D)
    cov_d = cov_x[:k, :k]  # the data's (and the estimated priors') term
    sd_d = np.sqrt(np.clip(np.diag(cov_d), 0, None))
    var = np.diag(cov_d).copy()
    cross = np.zeros((k, 0))  # scaled cov(estimate error, held parameter's error)
    if held.size:
        H_eh = _info(lin, ext, held, sig2_p, sig2_o)
        d_hh = np.diag(_info(lin, held, held, sig2_p, sig2_o))
        fr = np.flatnonzero([_FRAME.match(names[i]) is not None for i in ext])  # frames: a convention
        live = ~_gauge(H_data[np.ix_(fr, fr)], H_eh[fr], d_hh)
        held = held[live]
        if held.size:
            K = (cov_x @ H_eh[:, live])[:k]
            cross = K * (tol_si[held] / scale[held]) ** 2
            var = var + np.einsum("ij,ij->i", cross, K)
    sd_s = np.sqrt(np.clip(var, 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = np.nan_to_num(cov_d / np.outer(sd_d, sd_d))
        # posterior correlation of an estimated parameter's true value with a held one's
        rho_h = np.nan_to_num(-cross / np.outer(sd_s, tol_si[held] / scale[held]))
    strong, partners = [], {}
    for a in range(k):
        for b in range(a + 1, k):
            rho = float(corr[a, b])
            if abs(rho) > 0.9:
                strong.append((names[est[a]], names[est[b]], rho))
            if abs(rho) >= CORRELATED:
                partners.setdefault(a, []).append((names[est[b]], rho))
                partners.setdefault(b, []).append((names[est[a]], rho))
        share = rho_h[a] ** 2  # the fraction of the variance each held parameter brings
        # dominated by held parameters together (d3 between held d2 and d4: half each) or by one alone
        big = np.flatnonzero(share >= 0.05) if share.sum() >= CORRELATED ** 2 else np.flatnonzero(np.abs(rho_h[a]) >= CORRELATED)
        for j in big:
            partners.setdefault(a, []).append((names[held[j]], float(rho_h[a, j])))
    return sd_s * scale[est], corr, strong, partners, sd_d * scale[est]


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



def statuses(mask: np.ndarray, at_bound: np.ndarray, est: np.ndarray, sd: np.ndarray, partners: dict,
             tol_si: np.ndarray, label_scale: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """``(std (P,) SI, status [P])`` of a calibration: ``mask`` estimated, ``at_bound`` (a compliance held
    at 0), ``est`` the estimated indices with posterior std ``sd`` and ``partners`` (:func:`posterior`).
    Held: the prior's std (nan where uninformative or at a bound), "held at prior" / "at bound 0";
    estimated: "correlated" (with partners), else "undetermined" where ``sd`` reaches
    :data:`UNDETERMINED` of ``label_scale`` (the tolerance, or an uninformative kind's reference scale:
    a tool offset ± 1.4 m is not "identified"), else "identified"."""
    std = np.where(np.isfinite(tol_si), tol_si, np.nan)
    std[at_bound] = np.nan
    std[est] = sd
    status = ["held at prior" if not m else "at bound 0" if b else "identified" for m, b in zip(mask, at_bound)]
    for i in partners:
        status[est[i]] = "correlated"
    with np.errstate(invalid="ignore"):
        weak = est[(sd >= UNDETERMINED * label_scale[est]) & (sd > 0)]
    for k in weak:
        if status[k] == "identified":
            status[k] = "undetermined"
    return std, status
