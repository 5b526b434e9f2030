"""Parametric calibration: the "calibrated classical model" (DESIGN.md §1.4).

Identifies, from measured TCP poses (or positions), deviations of

* the geometry: per joint ``a, alpha, d, theta`` (DH / MDH) plus Hayati's ``beta`` where two
  consecutive axes are near-parallel (``|sin alpha| < 0.2``), or a small 6-D twist on every URDF
  joint origin (``o3.x`` ... ``o3.rz``);
* the base frame (world/measurement -> robot base) and the tool frame (flange -> TCP), each as a
  small 6-D twist applied on the right: ``T <- T · E(v, w)`` with ``E = [exp(w), v]``;
* joint compliance ``c_i = 1 / k_i`` (rad/N·m), the joints deflecting under the gravity torques of
  the link masses and payload (:mod:`hykin.kinematics.compliance`): ``q_eff = q + c * tau(q_eff)``;

by Levenberg–Marquardt over all samples. The Jacobian is analytic and vectorised: every parameter is
an elementary twist (a rotation about, or a translation along, a known axis of a known frame of the
chain), so its column is ``[u x (p_tcp - p0); u]`` or ``[u; 0]`` evaluated at the deflected joints;
a compliance column is the joint's own column times its gravity torque (the small coupling
``c dtau/dq`` is left out of the Jacobian, not out of the residual: the fixed point is exact).
Each iteration relinearises at the current estimate (the deviations are composed into the robot),
so the Jacobian is always the exact derivative at zero deviation.

Residual per sample: ``p_meas - p_model`` (m) for every measured point and, for full-pose data,
``w · log(R_meas R_model^T)`` (rad × ``w`` m/rad, the orientation weight). Data with several
reflectors per pose (``x2,y2,z2`` ... columns, :mod:`hykin.io.reflectors`) are fitted as what they are:
points on one tool body, the first at the TCP, each further one with its own unknown offset
``p2.x, p2.y, p2.z`` ... (TCP frame) identified with everything else. The orientation weight is
chosen from the data by default (``"auto"``): a first fit at ``w = 1 m/rad`` gives the residual
standard deviations per coordinate, and the fit is repeated at ``w = σ_pos / σ_rot`` so that each
kind of row counts by its noise (a fixed 1 m/rad over-weights orientations that come from reflectors
0.1 m apart by 10×: measured, the held-out error of every reflector doubled, benchmarks/bench_reflectors.py).

Priors (:mod:`hykin.calibration.priors`): every candidate parameter starts at the robot file's value
with a tolerance per kind (length, angle, joint zero, base, tool, compliance; the base is
uninformative by default: a tracker's frame comes from the data). A parameter the data do not excite
beyond a model-error floor is **held at its prior** (the robot file's value, posterior std = its
tolerance), e.g. the tool offset measured with the tool at one orientation, a joint never moved,
``theta1`` against the base; the others are the maximum a posteriori: prior rows ``(σ/τ) δ`` added to
the normal equations of the one LM (:func:`hykin.kinematics.lm.normal_equations_step`), ``σ`` the
residual noise per coordinate (re-estimated at the solution) or ``noise_m``.

Raw data (a tracker's frame, unknown tool, robot file without ``[base]``) run in stages:

1. closed-form base and tool offset(s) from the nominal kinematics
   (:func:`hykin.calibration.initial_registration.initial_registration`: linear in the offsets for a fixed base
   rotation, Kabsch for the rotation, a few alternations, joint Gauss–Newton; several tool
   guesses; offset directions the data do not excite stay at the file's tool), kept where it
   explains the data better than the robot file's own frames;
2. MAP LM on base and tool (and reflector offsets) only, from that start;
3. excitation decided at this estimate, MAP LM on everything excited;
4. excitation re-checked at the solution; a further pass when the excited set changed, when the
   orientation weight was re-estimated, or when the iteration cap stopped a still-falling cost;
5. if the fit is still implausible, a restart from the robot file's own frames; the best is kept;
6. refusals (:mod:`hykin.calibration.checks`): not converged, an estimated parameter beyond its
   tolerances, or a residual no correct robot file leaves -> :class:`CalibrationError`, one line that
   says what to check (robot file, units, tool, joint order).

Several stations / tools (a ``station`` / ``tool`` column, :mod:`hykin.calibration.stations`): every
further station's and tool's frame is one more 6-D group (``station[B].x`` ..., ``tool[T2].x`` ...)
fitted in the same LM (a bundle); the reference station's frame is ``base``, the reference tool's ``tool``.

Excitation: the identification Jacobian (evenly spread samples) scaled by the tolerances, each row
by its floor, factorised by a greedy column-pivoted QR (rank-revealing) after the uninformative
columns: ``|R_kk| / sqrt(N)`` is the RMS effect of a one-tolerance change that no other parameter
explains (:func:`hykin.calibration.priors.excitation`). Reported per parameter (:class:`CalibrationResult`):
identified, correlated (|posterior correlation| >= 0.99 with named others), held at prior, at bound 0.
Standard deviations come from the posterior covariance ``(Jᵀ Σ⁻¹ J + diag(τ⁻²))⁻¹`` with separate
residual variances for position and orientation rows, plus what the parameters held at prior may be
off by, carried through the fit (the "consider" covariance, :func:`hykin.calibration.posterior.posterior`).
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable

import numpy as np

from ..io.payload import payload_kwargs
from ..kinematics.compliance import (
    ComplianceError,
    compliance_of,
    compliant_fk,
    gravity_torques,
)
from ..kinematics.fk import fk
from ..kinematics.lm import next_lambda, normal_equations_step
from ..kinematics.robot import Robot
from .jacobian import (
    effective_joints,
    framed,
    identification_jacobian,
    linearize,
    model_poses,
    residual,
)
from .params import (
    TWIST,
    ModelState,
    ParamSpec,
    apply_deviations,
    apply_step,
    candidate_specs,
    deviations_between,
    parameter_names,
    scale_of,
    select_specs,
)
from .posterior import PriorContext, noise_variances, posterior, prior_system, prior_weight, reset_held, statuses
from .priors import (PRECISE_NOTE, excitation, label_scales, precise_data_note, prior_tolerances, residual_floors,
                     resolve_priors, uninformative_note)
from .result import (
    CalibrationError,
    CalibrationResult,
    orientation_weight_from_sigmas,
    residual_stats,
)
from .identifiability import identifiable_columns, parameter_scales
from .coverage import coverage_warnings, data_mistake_note
from .inputs import calibration_inputs
from .outliers import DEFAULT_RATIO, OUTLIER_MODES, OutlierWarning, find_outliers, row_errors, rows_out_of_step, subset_rows
from .stations import check_groups, frame_starts, reference_rows, row_groups, station_rms

__all__ = [
    "CalibrationError",
    "CalibrationResult",
    "apply_deviations",
    "calibrate",
    "calibrated_fk",
    "identifiable_columns",
    "identification_jacobian",
    "parameter_names",
    "parameter_scales",
]

_ID_SAMPLES = 600  # samples (evenly spread) used for the identifiability QR
_COARSE_SAMPLES = 20_000  # larger data sets first converge on this many evenly spread samples
#: relative cost decrease per iteration below which an LM stopped by its iteration cap counts as
#: converged (a flat valley, e.g. compliances creeping to their bound 0: 1e-5 of the cost is
#: ~5e-6 of the RMS residual, far below anything that matters); above it the cost is still falling
_STALLED_REL = 1e-5
#: smallest residual σ (m per coordinate) weighting the prior rows (noise-free data: the data decide)
_SIGMA_FLOOR_M = 1e-9


# --------------------------------------------------------------------------- LM step


def _lm_step(lin: dict, act: np.ndarray, lam: float, is_comp: np.ndarray, c: np.ndarray, comp_joint: np.ndarray):
    """Damped Gauss-Newton step (scaled units) on the free parameters, prior rows included.

    Compliance is bounded below by 0: a compliance at its bound whose step points below it is held
    (active-set), then the system is solved again. Returns (free indices, step) or (.., None).
    """
    free = act.copy()
    A_all = lin["JtJ_p"] + lin["JtJ_o"] + lin["A_prior"]
    g_all = lin["Jtr"] + lin["g_prior"]
    while free.size:
        step = normal_equations_step(A_all[np.ix_(free, free)], g_all[free], lam)
        held = is_comp[free] & (c[comp_joint[free]] <= 0) & (step < 0)
        if not held.any():
            return free, step
        free = free[~held]
    return free, None


def _moves(lin: dict, act: np.ndarray, sigma_m: float) -> bool:
    """Whether the Gauss-Newton step of the normal equations ``lin`` (prior rows included) moves any
    parameter of ``act`` by more than 1e-3 of its posterior standard deviation (``sigma_m`` noise)."""
    A = (lin["JtJ_p"] + lin["JtJ_o"] + lin["A_prior"])[np.ix_(act, act)]
    g = (lin["Jtr"] + lin["g_prior"])[act]
    step = normal_equations_step(A, g, 0.0)
    D = np.sqrt(np.diag(A))
    D[D == 0] = 1.0
    sd = sigma_m * np.sqrt(np.clip(np.diag(np.linalg.pinv(A / np.outer(D, D), hermitian=True)), 0, None)) / D
    return bool(np.any(np.abs(step) > 1e-3 * sd))


# --------------------------------------------------------------------------- main entry


def _calibrate_pass(robot: Robot, q, xyz, R_meas, specs: list[ParamSpec], w: float, max_iter: int, tol: float,
                    progress, pri: PriorContext, pts0: np.ndarray | None = None, pl=None, groups=None, frames0=None):
    """One excitation test at ``robot``, the held parameters put back at the robot file, one MAP LM
    on the excited ones (:mod:`hykin.calibration.priors`), the excitation re-tested at the solution.

    pl: per-row payload ``(kg (N,), com (N, 3) | None)`` deflecting the joints, or None (the robot's).
    groups / frames0: the rows' stations and tools and the start of their frames
    (:mod:`hykin.calibration.stations`), or None.
    Returns ``(result, rel, changed)``: the result (deviations relative to ``robot``), the relative
    cost decrease of the last accepted iteration (large when the iteration cap stopped a still-falling
    cost) and whether the excited set differs at the solution.
    """
    t0 = time.perf_counter()
    N = q.shape[0]
    last = {"rel": 0.0}
    P = len(specs)
    scale = np.array([scale_of(s) for s in specs])
    tol_si = pri.tol(specs)
    state0 = ModelState(robot=robot.copy(), c=compliance_of(robot), pts=np.zeros((xyz.shape[1], 3)) if pts0 is None else pts0,
                        frames=None if frames0 is None else frames0.synced(robot))
    rows_per = 3 * xyz.shape[1] + (0 if R_meas is None else 3)
    from ..io.plausibility import check_calibration_size

    check_calibration_size(N, P, rows_per)  # fewer equations than unknowns would fit the noise exactly
    is_comp = np.array([sp.group == "comp" for sp in specs])
    comp_joint = np.array([sp.joint for sp in specs])
    names = [s.name for s in specs]
    prior = {"act": np.zeros(0, np.int64), "weight": np.zeros(P)}

    def cost_of(st: ModelState, qd, xyzd, Rd, pld, gd=None):
        q_eff = effective_joints(st, qd, pld)
        rp, ro = residual(framed(st, fk(st.robot, q_eff), gd), xyzd, Rd, w, st.pts)
        rpr = prior_system(pri.file_state, st, specs, prior["act"], prior["weight"], scale, jacobian=False)[0]
        cost = 0.5 * (float(np.sum(rp * rp)) + (0.0 if ro is None else float(np.sum(ro * ro))) + float(rpr @ rpr))
        return cost, rp, ro, q_eff

    def lin_at(st, q_eff, xyzd, Rd, id_rows, pld, gd=None):
        lin = linearize(st, specs, scale, q_eff, xyzd, Rd, w, keep_rows=id_rows, payload=pld, groups=gd)
        _, lin["A_prior"], lin["g_prior"] = prior_system(pri.file_state, st, specs, prior["act"], prior["weight"], scale)
        return lin

    def sigma_of(rp, ro):
        return max(math.sqrt(noise_variances(rp, ro, prior["act"].size, pri.noise_m)[0]), _SIGMA_FLOOR_M)

    def run_lm(state, qd, xyzd, Rd, act, max_it, id_rows=None, pld=None, gd=None):
        """Relinearising MAP LM on the samples ``qd``; returns (state, rp, ro, lin, it, converged, message).
        The prior rows are weighted by the residual σ per coordinate (or the given noise); when σ at the
        solution differs from the σ used by more than 10 %, the LM goes on with the new weights (so the
        end point is the MAP at the σ of its own residual, whatever the path)."""
        prior["act"] = act
        cost, rp, ro, q_eff = cost_of(state, qd, xyzd, Rd, pld, gd)
        sig = sigma_of(rp, ro)
        prior["weight"] = prior_weight(tol_si, sig)
        cost, rp, ro, q_eff = cost_of(state, qd, xyzd, Rd, pld, gd)
        lin = lin_at(state, q_eff, xyzd, Rd, id_rows, pld, gd)
        lam, reweights = 1e-6, 0
        converged, message, it = False, "maximum number of iterations reached", 0
        if act.size == 0:
            return state, rp, ro, lin, 0, True, "no excited parameter"
        while it < max_it:
            it += 1
            accepted = False
            for _ in range(12):
                free, step_s = _lm_step(lin, act, lam, is_comp, state.c, comp_joint)
                if step_s is None or np.max(np.abs(step_s)) < 1e-10:  # < 1e-13 m / rad: nothing left
                    converged, message = True, "step below 1e-13"
                    break
                delta = np.zeros(P)
                delta[free] = step_s * scale[free]
                trial = apply_step(state, specs, delta)
                try:
                    new_cost, new_rp, new_ro, new_q_eff = cost_of(trial, qd, xyzd, Rd, pld, gd)
                except ComplianceError:  # the step made the joints too soft for an equilibrium: reject it
                    new_cost = math.inf
                accepted = new_cost < cost
                lam = float(next_lambda(lam, accepted))
                if accepted:
                    break
            if accepted:
                rel = (cost - new_cost) / max(cost, 1e-300)
                last["rel"] = rel
                state, cost, q_eff, rp, ro = trial, new_cost, new_q_eff, new_rp, new_ro
                if progress is not None:
                    progress(it, cost)
                lin = lin_at(state, q_eff, xyzd, Rd, id_rows, pld, gd)
                if rel <= tol:
                    converged, message = True, f"relative cost decrease {rel:.2g} <= tol"
            elif not converged:
                converged, message = True, "no further decrease of the cost"
            if converged:
                s_new = sigma_of(rp, ro)
                if pri.noise_m is not None or abs(s_new / sig - 1) <= 0.1 or reweights >= 8:
                    break
                reweights += 1
                sig = s_new  # re-weight the prior rows (same data linearization) ...
                prior["weight"] = prior_weight(tol_si, sig)
                cost, rp, ro, q_eff = cost_of(state, qd, xyzd, Rd, pld, gd)
                _, lin["A_prior"], lin["g_prior"] = prior_system(pri.file_state, state, specs, act, prior["weight"], scale)
                if not _moves(lin, act, sig):
                    break
                converged, lam = False, 1e-6  # ... and go on where the new weights move the MAP
        return state, rp, ro, lin, it, converged, message

    def excited_at(lin):
        row_floor = np.where(lin["J_id_rot"], w * pri.floor_rad, pri.floor_m)
        return excitation(lin["J_id"], id_rows.size, tol_si, scale, row_floor, pri.negligible_tol, pri.rank_tol)

    # excitation at the start, on evenly spread samples
    id_rows = np.unique(np.linspace(0, N - 1, min(N, _ID_SAMPLES)).astype(np.int64))
    sub = lambda a, idx: None if a is None else a[idx]
    sub_pl = lambda idx: None if pl is None else (pl[0][idx], sub(pl[1], idx))
    sub_g = lambda idx: None if groups is None else groups.subset(idx)
    q_id = effective_joints(state0, q[id_rows], sub_pl(id_rows))
    lin0 = linearize(state0, specs, scale, q_id, xyz[id_rows], sub(R_meas, id_rows), w,
                     keep_rows=np.arange(id_rows.size), payload=sub_pl(id_rows), groups=sub_g(id_rows))
    exc0 = excited_at(lin0)
    mask = exc0.excited
    if N * rows_per < mask.sum():
        raise CalibrationError(f"data: {N} samples give {N * rows_per} equations for {int(mask.sum())} parameters")
    act = np.flatnonzero(mask)
    held = np.flatnonzero(~mask & (np.isfinite(tol_si) | exc0.dependent))  # an undetermined start (tool metres off) too
    state = reset_held(pri.file_state, state0, specs, held, scale)  # what the data cannot tell: the robot file's
    it_sub = 0
    if N > 2 * _COARSE_SAMPLES:  # coarse-to-fine: converge on a spread subset, finish on all samples
        sel = np.unique(np.linspace(0, N - 1, _COARSE_SAMPLES).astype(np.int64))
        state, _, _, _, it_sub, _, _ = run_lm(state, q[sel], xyz[sel], sub(R_meas, sel), act, max_iter, pld=sub_pl(sel),
                                              gd=sub_g(sel))
    state, rp, ro, lin, it, converged, message = run_lm(
        state, q, xyz, R_meas, act, max(max_iter - it_sub, 1), id_rows=id_rows, pld=pl, gd=groups
    )
    it += it_sub
    before = residual_stats(*residual(model_poses(state0, q, pl, groups), xyz, R_meas, w, state0.pts), w)
    exc = excited_at(lin)  # the excitation at the solution
    end = exc.excited
    changed = bool(np.any(end != mask))
    if changed:
        lost, new = [names[k] for k in np.flatnonzero(mask & ~end)], [names[k] for k in np.flatnonzero(end & ~mask)]
        message += "; at the solution " + "; ".join(
            x for x in (f"{', '.join(lost)} no longer excited" if lost else "", f"{', '.join(new)} excited" if new else "") if x)
    at_bound = mask & is_comp & (state.c[np.maximum(comp_joint, 0)] <= 0)
    if at_bound.any():
        message += "; " + ", ".join(names[k] for k in np.flatnonzero(at_bound)) + " at the bound 0 (rigid; no std)"
    est = np.flatnonzero(mask & ~at_bound)
    sig2_p, sig2_o = noise_variances(rp, ro, est.size, pri.noise_m)
    sd, corr, strong, partners = posterior(lin, est, tol_si, scale, sig2_p, sig2_o, names,
                                           held=np.flatnonzero(~mask & np.isfinite(tol_si)), bound=np.flatnonzero(at_bound))
    std, status = statuses(mask, at_bound, est, sd, partners, tol_si, pri.label_scale(specs))
    by_k = {int(est[i]): lst for i, lst in partners.items()}
    corr_with = [by_k.get(k, []) for k in range(P)]
    values = deviations_between(state0, state, specs)
    m_p = rp.size
    m_o = 0 if ro is None else ro.size
    dof_frac = max(m_p + m_o - est.size, 1) / (m_p + m_o)
    s_p = float(np.sum(rp * rp)) / max(m_p * dof_frac, 1e-300)
    s_o = 0.0 if ro is None else float(np.sum(ro * ro)) / max(m_o * dof_frac, 1e-300)
    return CalibrationResult(
        robot=state.robot, names=names, values=values, std=std, identifiable=mask.copy(),
        correlation=corr, strong_correlations=strong, before=before, after=residual_stats(rp, ro, w), iterations=it,
        converged=converged, message=message, units=[s.unit for s in specs], n_samples=N,
        correlation_names=[names[k] for k in est],
        position_only=R_meas is None, orientation_weight_m_per_rad=w, sigma_pos_m=math.sqrt(s_p),
        sigma_rot_rad=math.sqrt(s_o) / w if R_meas is not None else float("nan"),
        seconds=time.perf_counter() - t0, point_offsets_m=state.pts.copy(), status=status,
        prior_std=tol_si, correlated_with=corr_with, station_frames=state.frames,
        effect_floors=np.where(exc.independent, exc.effect_m, 0.0),
    ), last["rel"], changed


def calibrate(
    robot: Robot,
    data,
    *,
    params="auto",
    compliance: bool = True,
    base: bool = True,
    tool: bool = True,
    position_only: bool | None = None,
    orientation_weight_m_per_rad: float | str = "auto",
    max_iter: int = 50,
    tol: float = 1e-12,
    rank_tol: float = 1e-6,
    negligible_tol: float = 1e-9,
    progress: Callable[[int, float], None] | None = None,
    initial: bool | str = "auto",
    restarts: int = 2,
    max_deviation: dict | None = None,
    checks: bool = True,
    payload_kg=None,
    payload_com_m=None,
    priors: dict | None = None,
    noise_m: float | None = None,
    outliers: str = "drop",
    outlier_ratio: float = DEFAULT_RATIO,
) -> CalibrationResult:
    """Identify geometry, base, tool and joint compliance of ``robot`` from measured poses.

    data: a :class:`hykin.io.dataset.Dataset` (or any object with ``q``, ``xyz_m``, ``quat_wxyz``), or a
    tuple ``(q (N, n) rad, poses (N, 4, 4) m)`` / ``(q, positions (N, 3) m)``. Measured poses may be
    in any frame (a tracker's, metres away and turned): base and tool are found first
    (:mod:`hykin.calibration.initial_registration`), then refined with everything else.
    params: ``"auto"`` (every candidate, see :func:`parameter_names`) or fnmatch patterns selecting
    candidates (``["base.*", "tool.*"]`` re-registers a measurement series only).
    compliance/base/tool: include those parameter groups. position_only: ignore orientations
    (default: only when the data have none). orientation_weight_m_per_rad: length scale ``w`` that
    weights orientation residuals (``w = 1``: 1 mrad counts like 1 mm); ``"auto"`` (default) takes
    ``w = σ_pos / σ_rot`` from the residuals of a first fit, so that each kind counts by its noise.
    max_iter / tol: LM iterations per pass and relative cost decrease at which it stops.
    rank_tol: a parameter whose column is explained by the others but for this fraction is held at its
    prior; negligible_tol: columns smaller than this times the largest are held. progress: called as
    ``progress(iteration, cost)``.
    initial: ``"auto"``/True: closed-form base + tool start when base and tool are calibrated
    (kept only where it explains the data better than the robot file's frames); False: start at
    the robot file. restarts: further LM passes when the iteration cap stopped a still-falling cost,
    and starts tried (robot file's frames) when the fit is implausible.
    max_deviation: overrides of :data:`hykin.calibration.checks.DEFAULT_MAX_DEVIATION`
    (``{"length_mm": 30}``). checks: refuse (raise :class:`CalibrationError`) a calibration that did
    not converge, a parameter beyond its plausible bound, or an implausible residual
    (:mod:`hykin.calibration.checks`); False returns whatever the fit gave.

    payload_kg / payload_com_m: per-row payload (``(N,)`` kg, ``(N, 3)`` m in the tool frame) that
    deflects the joints; by default read from the dataset's ``payload_kg``/``payload_com_*``
    columns (:mod:`hykin.io.payload`), else the robot's payload.

    priors: overrides of :data:`hykin.calibration.priors.DEFAULT_PRIORS` (tolerances per kind of the
    robot file's values, ``{"length_mm": 2, "tool_mm": 50, "base_mm": 10}``; the excitation floor
    ``excitation_mm``; ``refuse_tolerances``). noise_m: measurement noise per coordinate (m) that
    weights the priors and gives the posterior covariance; None: estimated from the residuals.

    outliers: rows more than ``outlier_ratio`` typical errors off the calibrated model
    (:mod:`hykin.calibration.outliers`) are ``"drop"``: left out and the calibration repeated without
    them (at most 2 % of the rows; the result's ``outliers`` names them, an :class:`OutlierWarning`
    says so), ``"warn"``: named only, ``"keep"``: not tested.

    Excitation (which parameters the data can tell; the others are held at the robot file's value,
    :mod:`hykin.calibration.priors`) is decided at the current estimate: after base and tool are
    found, and again at the solution (a further pass runs when the excited set changed there).
    """
    from .checks import check_calibration, resolve_max_deviation
    from .initial_registration import initial_registration

    t0 = time.perf_counter()
    auto_w = isinstance(orientation_weight_m_per_rad, str)
    if auto_w and orientation_weight_m_per_rad != "auto":
        raise CalibrationError(f"orientation_weight_m_per_rad must be a positive number or 'auto', got {orientation_weight_m_per_rad!r}")
    if not auto_w and not (orientation_weight_m_per_rad > 0 and math.isfinite(orientation_weight_m_per_rad)):
        raise CalibrationError(f"orientation_weight_m_per_rad must be a positive number, got {orientation_weight_m_per_rad}")
    if outliers not in OUTLIER_MODES or not (outlier_ratio > 1 and math.isfinite(outlier_ratio)):
        raise CalibrationError(f"outliers must be one of {', '.join(OUTLIER_MODES)} and outlier_ratio a number > 1, "
                               f"got {outliers!r}, {outlier_ratio!r}")
    if noise_m is not None and not (noise_m > 0 and math.isfinite(noise_m)):
        raise CalibrationError(f"noise_m must be a positive number (m) or None, got {noise_m}")
    try:
        lim = resolve_max_deviation(max_deviation)
        pri_kinds = resolve_priors(priors)
    except ValueError as e:
        raise CalibrationError(str(e)) from None
    q, xyz, R_meas = calibration_inputs(robot, data, position_only)
    if q.shape[0] == 0:
        raise CalibrationError("data: no samples")
    from ..io.payload import payload_of

    pl = payload_of(data, payload_kg, payload_com_m, n_rows=q.shape[0])
    w = 1.0 if auto_w else float(orientation_weight_m_per_rad)
    K = 1 if xyz.ndim == 2 else xyz.shape[1]
    groups = row_groups(data, q.shape[0])  # several stations / tools (hykin.calibration.stations)
    if groups is not None:
        check_groups(groups, xyz, R_meas is None)
    specs = select_specs(candidate_specs(robot, base=base, tool=tool, compliance=compliance, n_points=K,
                                         stations=groups.station_labels[1:] if groups else (),
                                         tools=groups.tool_labels[1:] if groups else ()), params)
    if R_meas is None and K > 1:  # reflectors fix where the tool body is, not how its TCP frame is turned: the file's
        specs = [s for s in specs if not (s.group in ("tool", "tools") and s.field in ("rx", "ry", "rz"))]
    names = {s.name for s in specs}
    frames = [s for s in specs if s.group in ("base", "tool", "point", "station", "tools")]
    pts_zero = np.zeros((K, 3))
    fr_of = lambda rob: None if groups is None else frame_starts(rob, fk(rob.copy(base=np.eye(4), tool=np.eye(4)), q),
                                                                 xyz, R_meas, groups)
    fr_file = fr_of(robot)  # further stations / tools: their start is their prior mean
    state0 = ModelState(robot=robot.copy(), c=compliance_of(robot), pts=pts_zero, frames=fr_file)
    tau_max = None
    if any(s.group == "comp" for s in specs):  # the compliance tolerance is a deflection under these torques
        rows = np.unique(np.linspace(0, q.shape[0] - 1, min(q.shape[0], 2000)).astype(np.int64))
        pl_rows = None if pl is None else (pl[0][rows], None if pl[1] is None else pl[1][rows])
        tau_max = np.abs(gravity_torques(robot, np.ascontiguousarray(q[rows]), **payload_kwargs(pl_rows))).max(0)
    tol_si = prior_tolerances(specs, pri_kinds, tau_max)
    pri = PriorContext(file_state=state0, tol_by_name={s.name: t for s, t in zip(specs, tol_si)},
                  floor_m=pri_kinds["excitation_mm"] * 1e-3, floor_rad=math.radians(pri_kinds["excitation_deg"]),
                  noise_m=noise_m, rank_tol=rank_tol, negligible_tol=negligible_tol,
                  label_by_name={s.name: t for s, t in zip(specs, label_scales(specs, tol_si, pri_kinds))})
    run = lambda rob, sp, ww, it, pts=None, fr=None, pr=None: _calibrate_pass(
        rob, q, xyz, R_meas, sp, ww, it, tol, progress, pr or pri, pts0=pts, pl=pl, groups=groups, frames0=fr)
    starts = [(robot, pts_zero, fr_file)]
    reg = None
    full_frames = all(f"base.{f}" in names for f in TWIST) and all(f"tool.{f}" in names for f in ("x", "y", "z"))
    if initial and full_frames:
        ref = np.arange(q.shape[0]) if groups is None else reference_rows(groups)
        reg = initial_registration(robot, q[ref], xyz[ref], None if R_meas is None else R_meas[ref], tool_tolerance_m=pri_kinds["tool_mm"] * 1e-3,
                                   floor_m=pri.floor_m)
        if reg.rms_m < reg.rms_before_m:
            # further reflectors: offsets from reflector 1 in the TCP frame
            pts = (reg.offsets_m - reg.offsets_m[0]) @ reg.tool[:3, :3]
            start = robot.copy(base=reg.base, tool=reg.tool)
            starts.insert(0, (start, pts, fr_of(start)))

    def chain(start):
        """frames, then everything (excitation at the estimate), then again at the solution."""
        iters, ww = 0, w
        cur, pts, fr = start
        if len(starts) > 1 and frames and len(frames) < len(specs):
            r, _, _ = run(cur, frames, ww, max_iter, pts=pts, fr=fr)
            cur, pts, fr, iters = r.robot, r.point_offsets_m, r.station_frames, iters + r.iterations
        res, rel, changed = run(cur, specs, ww, max_iter, pts=pts, fr=fr)
        iters += res.iterations
        if auto_w and R_meas is not None and res.sigma_rot_rad > 0 and math.isfinite(res.sigma_rot_rad):
            ww = orientation_weight_from_sigmas(res.sigma_pos_m, res.sigma_rot_rad)
        for _ in range(max(int(restarts), 0) + 1):
            again = ww != res.orientation_weight_m_per_rad or changed or (not res.converged and rel > _STALLED_REL)
            if not again:
                break
            res, rel, changed = run(res.robot, specs, ww, max_iter, pts=res.point_offsets_m, fr=res.station_frames)
            iters += res.iterations
        low = residual_floors(pri, res.after, pri_kinds["excitation_residual"])
        if low is not None:  # opt-in: what the fit leaves bounds the model error (hykin.calibration.priors)
            res, rel, _ = run(res.robot, specs, ww, max_iter, pts=res.point_offsets_m, fr=res.station_frames, pr=low)
            iters += res.iterations
            res.message += f"; excitation floors from the residual: {low.floor_m * 1e3:.3g} mm, {math.degrees(low.floor_rad):.3g} deg"
        elif not pri_kinds["excitation_residual"] and residual_floors(pri, res.after, PRECISE_NOTE) is not None:
            res.notes = [n for n in [precise_data_note(res, pri)] if n]
        return res, rel, iters

    best = None
    diverged = None
    for k, start in enumerate(starts[: 1 + max(int(restarts), 0)]):
        try:
            res, rel, iters = chain(start)
        except ComplianceError as e:  # the fit made joints too soft for an equilibrium: a bad start or file
            diverged = e
            continue
        cost = res.after["pos_rms_mm"] ** 2
        if best is None or cost < best[3]:
            best = (res, rel, iters, cost)
        plausible = res.after["pos_rms_mm"] <= lim["residual_mm"] and (res.converged or rel <= _STALLED_REL)
        if plausible:
            break
    if best is None:
        from .checks import ADVICE

        raise CalibrationError(f"calibration of {robot.name!r} diverged ({str(diverged).splitlines()[0]}); the data do "
                               f"not fit this robot file: {ADVICE}")
    res, rel, iters, _ = best
    res.notes += [n for n in [uninformative_note(res, specs)] if n]  # an inf tolerance the data could not honour
    res.coverage = coverage_warnings(res, q, tool_prior_given="tool_mm" in (priors or {}))  # a joint never moved ...
    if not res.converged and rel <= _STALLED_REL:  # the cap stopped a cost that no longer moves
        res.converged = True
        res.message += f"; iteration cap reached with the cost changing by {rel:.2g} (relative) per iteration"
    state1 = ModelState(robot=res.robot, c=compliance_of(res.robot), pts=res.point_offsets_m, frames=res.station_frames)
    res.values = deviations_between(state0, state1, specs)
    # before: the robot file as given (further reflectors at its TCP: their offsets are unknown)
    res.before = residual_stats(*residual(model_poses(state0, q, pl, groups), xyz, R_meas, res.orientation_weight_m_per_rad,
                                           pts_zero), res.orientation_weight_m_per_rad)
    res.iterations = iters
    res.seconds = time.perf_counter() - t0
    if reg is not None:
        res.message += (f"; start: base and tool from the nominal kinematics ({reg.rms_m * 1e3:.3g} mm RMS, robot "
                        f"file frames {reg.rms_before_m * 1e3:.3g} mm)" if reg.rms_m < reg.rms_before_m
                        else "; start: the robot file's base and tool")
    same = dict(params=params, compliance=compliance, base=base, tool=tool, position_only=position_only,
                orientation_weight_m_per_rad=orientation_weight_m_per_rad, max_iter=max_iter, tol=tol, rank_tol=rank_tol,
                negligible_tol=negligible_tol, initial=initial, restarts=restarts, max_deviation=max_deviation,
                checks=checks, payload_kg=payload_kg, payload_com_m=payload_com_m, priors=priors, noise_m=noise_m,
                outliers="keep")
    if outliers != "keep":
        found = find_outliers(*row_errors(model_poses(state1, q, pl, groups), xyz, R_meas, state1.pts), outlier_ratio)
        if found is not None and outliers == "drop" and found.droppable:
            keep = np.setdiff1d(np.arange(q.shape[0]), found.rows)
            sub = lambda v: subset_rows(v, keep, q.shape[0])
            res = calibrate(robot, sub(data), **{**same, "payload_kg": sub(payload_kg), "payload_com_m": sub(payload_com_m)})
            found.dropped = True
        if found is not None:
            res.outliers = found
            warnings.warn(OutlierWarning(found.message(getattr(data, "source", None) or None)), stacklevel=2)
        if found is not None and found.dropped:
            return res
    if checks:
        defl = None
        if np.any(state1.c):
            q_eff = effective_joints(state1, q, pl)
            tau = gravity_torques(state1.robot, np.ascontiguousarray(q_eff), **payload_kwargs(pl))
            defl = np.max(np.abs(state1.c * tau), axis=0)
        from .consistency import OrientationConflictError, check_orientation_consistency  # vs the positions' own residual

        recal = lambda d, po: calibrate(robot, d, **{**same, "position_only": po, "checks": False})
        try:
            try:
                check_calibration(res, specs, lim, still_falling=(not res.converged and rel > _STALLED_REL), deflection_rad=defl,
                                  refuse_tolerances=pri_kinds["refuse_tolerances"], explicit=set(max_deviation or {}),
                                  given_priors={k: pri_kinds[k] for k in priors or {}}, free_frames_mm=None if reg is None else reg.rms_m * 1e3)
            except CalibrationError as e0:  # a quaternion re-read that explains the positions names the cause
                check_orientation_consistency(res, data, recal, lim["orientation_conflict"], refused=e0)
        except CalibrationError as e:
            mirror = data_mistake_note(robot, q, xyz, R_meas, None if groups is None else reference_rows(groups))
            if mirror:
                raise CalibrationError(f"calibration of {robot.name!r}: {mirror}; fitted as given: "
                                       f"{str(e).removeprefix(f'calibration of {robot.name!r}: ')}") from None
            if groups is None or isinstance(e, OrientationConflictError):  # else: joints a row out of step?
                shift = "" if isinstance(e, OrientationConflictError) else rows_out_of_step(data, res.after["pos_rms_mm"], recal)
                raise (CalibrationError(f"{e}{shift}") if shift else e) from None
            raise CalibrationError(f"{e}; or a wrong station/tool label on some rows (RMS per station: "
                                   f"{station_rms(residual(model_poses(state1, q, pl, groups), xyz, None, 1.0, state1.pts)[0], groups)})") from None
        check_orientation_consistency(res, data, recal, lim["orientation_conflict"])
    return res


def calibrated_fk(robot: Robot, q) -> np.ndarray:
    """Prediction of the calibrated classical model: TCP poses ``(N, 4, 4)`` including joint
    compliance under gravity (:func:`hykin.kinematics.compliance.compliant_fk`)."""
    return compliant_fk(robot, q)
