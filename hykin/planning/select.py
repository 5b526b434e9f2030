"""Choosing poses from a candidate pool: D-optimal core + space-filling fill, and active selection.

:func:`plan_poses` (``hykin plan ROBOT``), two stages on one feasible candidate pool (scrambled
Sobol over the working region, :func:`hykin.sim.sampling.uniform`, filtered by
:func:`hykin.planning.constraints.feasible`):

1. **Optimal core** for the calibration, ``core_factor × P / r`` poses (default twice the minimum
   number of poses for the ``P`` identifiable parameters at ``r`` rows per pose), chosen among the
   first 5,000 feasible candidates by greedy

   * **I-optimality** (default): minimise ``tr(W M⁻¹)``, ``W`` = mean ``J_tᵀ J_t`` of the position
     rows over uniform poses of the working region: the mean squared TCP error that parameter noise
     causes where the model will be used (:func:`i_optimal`); or
   * **D-optimality**: maximise ``log det M`` (:func:`d_optimal`),

   with ``M = εI + Σ J_iᵀ J_i`` over the scaled identification Jacobian of the identifiable
   parameters (:mod:`hykin.planning.criteria`; ``ε = 1e-3`` a weak prior so the first picks are
   defined). Adding pose ``i`` multiplies ``det M`` by ``det(I_r + J_i M⁻¹ J_iᵀ)`` (matrix
   determinant lemma) and lowers ``tr(W M⁻¹)`` by ``tr((I + G_i)⁻¹ C_i W C_iᵀ)`` (Woodbury); the
   per-candidate quantities are updated after each pick, ``O(pool · r² · P)`` per pick.
   The core is small on purpose: a calibration's error on a real arm is dominated by what it cannot
   model (transmission errors, unmodelled elasticity), not by tracker noise, and optimal designs
   put every pose at the extremes where those errors are largest; measured on the benchmark robot
   (docs/planning.md), 60 poses all I-optimal calibrate worse than 12 I-optimal + 48 spread ones.
2. **Space-filling fill** for the networks: ``fill="sobol"`` (default) takes the feasible
   candidates in the order of their scrambled Sobol sequence (a low-discrepancy, uniform-like set
   over the feasible region, in the joint coordinates the networks see); ``fill="maximin"`` picks
   by greedy farthest point in the normalised, wrapped coordinates (:mod:`hykin.planning.coverage`),
   starting from the core. On the benchmark the Sobol fill trained better networks than maximin
   (maximin designs crowd the boundary of a 6-D box). The criterion is the plan's discrepancy
   (:func:`hykin.planning.coverage.coverage_report`, in ``Plan.criteria``). Measured on the
   benchmark robot (docs/planning.md): uniformity is the one lever a plan has on the networks'
   error (about 7 % below uniform random poses at 1,000 poses; Lloyd-relaxed or
   discrepancy-optimised Sobol sets were no better); more poses near the range ends, density
   following the lever arm and closing the fade's holes gained nothing there.

The plan is nested: its first ``k`` poses (before ordering) are the plan for ``k``, which
:mod:`hykin.planning.forecast` uses. The output is ordered for a short path (:mod:`hykin.planning.order`).

:func:`active_poses` (``hykin plan --for-model``): the next poses for a fitted
:class:`hykin.hybrid.model.HybridModel`, where its training data are thinnest relative to an even
cover of the region, weighted by its uncertainty. On a feasible uniform candidate pool, in the
networks' own coordinates (joints as they see them, scaled by their training data's range; joints
that are not network inputs left out), :func:`hykin.planning.coverage.deficit_select` picks greedily
the candidate with the most design points missing around it (the count an even design of the final
size would have in a ball there, minus the model's training poses and the poses already picked),
times ``(s / median s) ** uncertainty_power`` with the uncertainty score
``s = band95(q) · (1 + d(q) / fade_width) + 1.96 σ_cal(q)``: the model's 95 % position band
(:meth:`~hykin.hybrid.model.HybridModel.predict_uncertainty`), grown with the distance outside its
training support (:meth:`~hykin.hybrid.model.HybridModel.support_distance`), plus the calibrated model's
position standard deviation from the parameter covariance stored with the model. Choosing by ``s``
alone (the former rule) was measured worse than adding uniform random poses (1.15× the error,
docs/planning.md): it piles poses where the band is widest, at the edges of the region, and leaves
the interior as thin as before.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..kinematics.robot import Robot
from ..sim.sampling import uniform
from .constraints import Constraints, PlanningError, feasible, region_bounds
from .coverage import coverage_report, deficit_select, embed, farthest_point, min_spacing
from .criteria import (
    IdentificationModel,
    identification_model,
    observability,
    scaled_rows,
)
from .moves import SafePath, safe_path
from .order import order_path, path_travel

__all__ = ["DEFAULT_SPEEDS_RAD_S", "Plan", "active_poses", "candidate_pool", "d_optimal", "i_optimal", "plan_poses", "usage_weight",
           "with_safe_moves"]

DEFAULT_SPEEDS_RAD_S = 0.5  # conservative joint speed for a measuring campaign (rad/s, every joint)
_CORE_POOL = 5000  # candidates searched for the optimal core
ACTIVE_UNCERTAINTY_POWER = 0.5  # weight of the model's uncertainty in active selection (decided on bench_plan seed 2)
_PRIOR = 1e-3  # weak prior of the information matrix (scaled units: (mm per typical deviation)^2)


@dataclass
class Plan:
    """A measurement plan.

    q: ``(N, dof)`` joints in measuring order (rad / m). core: ``(N,)`` bool, D-optimal core poses.
    pick_order: ``(N,)`` rank of each row in the (nested) selection. travel: :func:`path_travel`
    of the order. criteria: :func:`hykin.planning.criteria.observability` of the plan, its
    ``min_spacing`` and :func:`hykin.planning.coverage.coverage_report` (``discrepancy_cd``,
    ``marginal_ks``, ``holes_pct``; :func:`plan_poses` only).
    id_model: the identification model used. n_pool / n_feasible: candidates drawn / feasible.
    lower/upper: the working region. score: active-selection score per pose (``--for-model``).
    moves: the moves to execute (:class:`hykin.planning.moves.SafePath`: the poses in order with via
    poses where a direct move is not clear); poses no safe move reaches are already left out of ``q``.
    """

    q: np.ndarray
    core: np.ndarray
    pick_order: np.ndarray
    travel: dict
    criteria: dict
    id_model: IdentificationModel | None
    n_pool: int
    n_feasible: int
    lower: np.ndarray
    upper: np.ndarray
    speeds: np.ndarray
    score: np.ndarray | None = None
    info: dict = field(default_factory=dict)
    moves: SafePath | None = None

    def nested(self) -> np.ndarray:
        """Joints in selection order (the first ``k`` rows are the plan for ``k``)."""
        return self.q[np.argsort(self.pick_order)]


def _move_check(robot: Robot, c: Constraints):
    """``(M, dof) -> (M,) bool`` for configurations met while moving (body, floor, keep-out, tracker), or None."""
    from ..kinematics.fk import fk
    from .bodies import body_clear

    if c.bodies is not None:
        pts = () if c.tracker_m is None else (c.tracker_m,)
        return lambda Q: body_clear(robot, Q, c.bodies, c.floor_z_m, c.keep_out_m, points_m=pts)
    if c.floor_z_m is not None:
        return lambda Q: fk(robot, Q)[:, 2, 3] >= c.floor_z_m
    return None


def _order(robot: Robot, c: Constraints, q: np.ndarray, speeds, start, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """A short path through ``q`` whose moves are clear where a clear one is near (:func:`order_path`):
    ``(order (N,), the poses in that order (N, dof))``, full-turn joints unwrapped along the path
    (:func:`hykin.planning.order.unwrap_path`: the same poses by shorter moves)."""
    from .moves import moves_clear
    from .order import full_turn_joints, nearest_turn, unwrap_path

    ok_fn = _move_check(robot, c) if check else None
    pris = np.array([t == "prismatic" for t in robot.independent_joint_type])
    tw = full_turn_joints(c.lower, c.upper, robot.independent_joint_type)
    rep = lambda a, b: nearest_turn(a, b, c.lower, c.upper, tw)
    clear = None if ok_fn is None else (lambda I, J: moves_clear(q[I], rep(q[I], q[J]), ok_fn, pris))
    path = order_path(q, speeds, start, clear=clear, turns=tw)
    return path, unwrap_path(q[path], c.lower, c.upper, tw)


def with_safe_moves(plan: Plan, robot: Robot, c: Constraints, via_pool: np.ndarray, start=None) -> Plan:
    """``plan`` with :attr:`Plan.moves` set: each move checked against the body constraints of ``c``
    (:mod:`.moves`); poses that no safe move reaches are dropped from the plan (``info['dropped']``)."""
    ok_fn = _move_check(robot, c)
    if ok_fn is None:
        plan.moves = SafePath(q=plan.q.copy(), measure=np.ones(len(plan.q), bool), dropped=np.zeros(0, np.int64))
        return plan
    dwell = (plan.travel["total_s"] - plan.travel["move_s"]) / max(len(plan.q), 1)
    pris = np.array([t == "prismatic" for t in robot.independent_joint_type])
    from .order import full_turn_joints, nearest_turn

    tw = full_turn_joints(c.lower, c.upper, robot.independent_joint_type)
    # via poses are moved through, not measured: any configuration of the region whose body is clear
    # will do (line of sight and the Cartesian box do not apply to them)
    q_free = uniform(robot, 4096, np.random.default_rng([len(plan.q), 53]), lower=c.lower, upper=c.upper)
    via_pool = np.vstack([via_pool, q_free[ok_fn(q_free)]])
    sp = safe_path(plan.q, ok_fn, via_pool, plan.speeds, prismatic=pris, start=start,
                   rep=lambda a, b: nearest_turn(a, b, c.lower, c.upper, tw))
    plan.moves = sp
    if sp.order is not None:  # measured poses in the order the moves visit them (dropped ones left out)
        o = sp.order
        rank = np.argsort(np.argsort(plan.pick_order[o]))
        plan.q, plan.core, plan.pick_order = sp.q[sp.measure], plan.core[o], rank
        if plan.score is not None:
            plan.score = plan.score[o]
    plan.info["dropped"] = int(sp.dropped.size)
    plan.info["via"] = int((~sp.measure).sum())
    plan.travel = path_travel(sp.q, plan.speeds, 0.0)
    plan.travel["total_s"] = plan.travel["move_s"] + dwell * len(plan.q)
    return plan


def d_optimal(J: np.ndarray, k: int, *, chosen=None, prior: float = _PRIOR, exclude=None) -> np.ndarray:
    """Greedy D-optimal selection of ``k`` rows from scaled Jacobian rows ``J`` ``(M, r, P)``.

    ``chosen``: indices already in the design (their information is included; not returned).
    ``exclude``: bool mask of candidates not to pick. Returns indices ``(k,)`` in pick order.
    """
    M_, r, P = J.shape
    avail = np.ones(M_, bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    Minfo = prior * np.eye(P)
    if chosen is not None and len(chosen):
        Jc = J[np.asarray(chosen)].reshape(-1, P)
        Minfo += Jc.T @ Jc
        avail[np.asarray(chosen)] = False
    if avail.sum() < k:
        raise PlanningError(f"only {int(avail.sum())} feasible candidates for {k} poses: enlarge the pool or relax the constraints")
    Minv = np.linalg.inv(Minfo)
    A = J.reshape(-1, P)
    G = np.einsum("nrp,nsp->nrs", (A @ Minv).reshape(M_, r, P), J)
    I_r = np.eye(r)
    out = np.empty(k, dtype=np.int64)
    for i in range(k):
        gain = np.linalg.slogdet(I_r + G)[1]
        gain[~avail] = -np.inf
        j = int(np.argmax(gain))
        out[i] = j
        avail[j] = False
        Sinv = np.linalg.inv(I_r + G[j])
        U = Minv @ J[j].T  # (P, r)
        V = (A @ U).reshape(M_, r, r)  # J_i M⁻¹ J_jᵀ
        G -= np.einsum("nab,bc,ndc->nad", V, Sinv, V)
        Minv -= U @ Sinv @ U.T
        Minv = 0.5 * (Minv + Minv.T)
    return out


def i_optimal(J: np.ndarray, k: int, W: np.ndarray, *, prior: float = _PRIOR, exclude=None) -> np.ndarray:
    """Greedy I-optimal (integrated prediction variance) selection of ``k`` rows of ``J`` ``(M, r, P)``:
    each pick minimises ``tr(W M⁻¹)``, ``W = mean J_tᵀ J_t`` over the poses where the model is used
    (``(P, P)``), i.e. the mean squared TCP error caused by parameter noise over that region.

    Adding pose ``i`` lowers ``tr(W M⁻¹)`` by ``tr((I + G_i)⁻¹ C_i W C_iᵀ)`` with ``C_i = J_i M⁻¹``
    and ``G_i = C_i J_iᵀ`` (Woodbury); ``C``, ``C W`` and ``G`` are updated in place after each pick,
    ``O(M · r² · P)`` per pick. Returns indices ``(k,)`` in pick order."""
    M_, r, P = J.shape
    avail = np.ones(M_, bool) if exclude is None else ~np.asarray(exclude, dtype=bool)
    if avail.sum() < k:
        raise PlanningError(f"only {int(avail.sum())} feasible candidates for {k} poses: enlarge the pool or relax the constraints")
    W = np.asarray(W, dtype=np.float64)
    Minv = np.eye(P) / prior
    A = J.reshape(-1, P)
    C = (A @ Minv).reshape(M_, r, P)
    CW = (C.reshape(-1, P) @ W).reshape(M_, r, P)
    G = np.einsum("nrp,nsp->nrs", C, J)
    I_r = np.eye(r)
    out = np.empty(k, dtype=np.int64)
    for i in range(k):
        H = np.einsum("nrp,nsp->nrs", CW, C)
        gain = np.trace(np.linalg.solve(I_r + G, H), axis1=1, axis2=2)
        gain[~avail] = -np.inf
        j = int(np.argmax(gain))
        out[i] = j
        avail[j] = False
        Sinv = np.linalg.inv(I_r + G[j])
        U = C[j].T.copy()  # M⁻¹ J_jᵀ (P, r)
        V = (A @ U).reshape(M_, r, r)  # J_i M⁻¹ J_jᵀ
        VS = V @ Sinv
        G -= np.einsum("nab,ncb->nac", VS, V)
        C -= np.einsum("nab,pb->nap", VS, U)
        CW -= np.einsum("nab,pb->nap", VS, W @ U)
        Minv -= U @ Sinv @ U.T
    return out


def candidate_pool(robot: Robot, c: Constraints, n_needed: int, seed: int = 0, pool: int = 20_000,
                   max_pool: int = 400_000) -> tuple[np.ndarray, int]:
    """Feasible candidates ``(M, dof)`` (scrambled Sobol over the region, filtered) and the number drawn.

    The pool grows (×4, up to ``max_pool``) until it holds ``max(2 n_needed, pool / 4)`` feasible poses."""
    lo, hi = region_bounds(robot, c.lower, c.upper)
    size = int(pool)
    while True:
        q = uniform(robot, size, np.random.default_rng([seed, 17]), lower=lo, upper=hi)
        ok = feasible(robot, q, c)
        if ok.sum() >= max(2 * n_needed, pool // 4) or size >= max_pool:
            if ok.sum() < n_needed:
                raise PlanningError(_too_few_message(int(ok.sum()), size, n_needed))
            return q[ok], size
        size = min(4 * size, max_pool)


def _too_few_message(n_ok: int, size: int, n_needed: int) -> str:
    """One-line refusal when ``n_ok`` of ``size`` candidates are feasible and ``n_needed`` are needed:
    names the constraints and ``--pool``, with a pool size expected to hold the poses needed with a 25 % margin."""
    what = "(region, box, line of sight, keep-out, body)"
    relax = "relax them (e.g. --max-incidence, --box, tracker position)"
    if n_ok == 0:
        return (f"only 0 of {size} candidate poses meet the constraints {what} for {n_needed} poses: {relax}; "
                f"a larger --pool than {size} draws more candidates but is unlikely to help when none passed")
    more = int(np.ceil(size * 1.25 * n_needed / n_ok / 1000.0)) * 1000
    return (f"only {n_ok} of {size} candidate poses meet the constraints {what} for {n_needed} poses: draw more "
            f"candidates (--pool {more} should hold enough) or {relax}")


def plan_poses(robot: Robot, n: int, constraints: Constraints | None = None, *, seed: int = 0, pool: int = 20_000,
               position_only: bool = True, orientation_weight_m_per_rad: float = 1.0, compliance: bool = True,
               criterion: str = "I", core_factor: float = 2.0, fill: str = "sobol", speeds=DEFAULT_SPEEDS_RAD_S,
               start=None, dwell_s: float = 0.0, safe_moves: bool = True) -> Plan:
    """``n`` poses for calibration + networks within ``constraints`` (module docstring), ordered.

    position_only: the tracker measures positions (SMR) or full poses (6-D probe). criterion: ``"I"``
    (default) or ``"D"`` for the core. core_factor: core size in multiples of the minimum number of
    poses (identifiable parameters / rows per pose). fill: ``"sobol"`` (default: the feasible
    low-discrepancy candidates in sequence order) or ``"maximin"`` (greedy farthest point). speeds: joint speeds (rad/s) for the order and
    the time estimate. start: joints the robot starts from. dwell_s: settle + measure time per pose.
    safe_moves: check and detour the moves between poses (:func:`with_safe_moves`); False for plans
    that are only studied (the accuracy forecast), not run."""
    if isinstance(n, bool) or int(n) != n or n < 1:
        raise PlanningError(f"number of poses must be a positive integer, got {n!r}")
    if criterion not in ("I", "D"):
        raise PlanningError(f"criterion must be 'I' or 'D', got {criterion!r}")
    if fill not in ("sobol", "maximin"):
        raise PlanningError(f"fill must be 'sobol' or 'maximin', got {fill!r}")
    n = int(n)
    c = (constraints or Constraints()).check(robot)
    speeds = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (robot.dof,)).copy()
    if not np.all(speeds > 0):
        raise PlanningError(f"joint speeds must be > 0, got {speeds.tolist()}")
    cand, drawn = candidate_pool(robot, c, n, seed, pool)
    idm = identification_model(robot, cand, position_only=position_only,
                               orientation_weight_m_per_rad=orientation_weight_m_per_rad, compliance=compliance)
    k_core = min(n, int(np.ceil(core_factor * idm.n_params / idm.rows_per_pose)))
    # the core is chosen among the first _CORE_POOL feasible candidates (a Sobol prefix: still spread)
    m_core = min(len(cand), max(_CORE_POOL, 2 * k_core))
    J = scaled_rows(idm, cand[:m_core])
    if criterion == "D":
        core_idx = d_optimal(J, k_core)
    else:
        core_idx = i_optimal(J, k_core, usage_weight(idm, robot, c, seed))
    X = embed(robot, cand, c.lower, c.upper)
    if n <= k_core:
        fill_idx = np.zeros(0, np.int64)
    elif fill == "maximin":
        fill_idx = farthest_point(X, n - k_core, chosen=core_idx)
    else:  # the pool is a scrambled Sobol sequence: its feasible prefix is a low-discrepancy set
        rest = np.ones(len(cand), bool)
        rest[core_idx] = False
        fill_idx = np.flatnonzero(rest)[: n - k_core]
    sel = np.concatenate([core_idx, fill_idx])
    q_sel = cand[sel]
    path, q_ord = _order(robot, c, q_sel, speeds, start, check=safe_moves)
    crit = observability(scaled_rows(idm, q_sel))
    crit["min_spacing"] = min_spacing(X[sel])
    crit.update(coverage_report(q_sel, c.lower, c.upper, seed=seed))
    pick_order = path.copy()  # ordered row i is selection rank path[i]
    core = path < k_core
    plan = Plan(q=q_ord, core=core, pick_order=pick_order, travel=path_travel(q_ord, speeds, dwell_s),
                criteria=crit, id_model=idm, n_pool=drawn, n_feasible=len(cand), lower=c.lower, upper=c.upper,
                speeds=speeds, info={"core_size": k_core, "n_params": idm.n_params, "criterion": criterion, "fill": fill})
    return with_safe_moves(plan, robot, c, cand, start) if safe_moves else plan


def usage_weight(idm: IdentificationModel, robot: Robot, c: Constraints, seed: int = 0, n: int = 2048) -> np.ndarray:
    """``(P, P)`` mean ``J_tᵀ J_t`` of the position rows over uniform poses of the working region (where
    the model will be used; not filtered by the line of sight): the weight of the I-criterion."""
    qt = uniform(robot, n, np.random.default_rng([seed, 23]), lower=c.lower, upper=c.upper)
    Jt = scaled_rows(idm, qt)[:, :3]
    return np.einsum("trp,trq->pq", Jt, Jt) / len(Jt)


def calibration_std_mm(model, q) -> np.ndarray | None:
    """``(N,)`` position standard deviation (mm, root of the trace over x, y, z) of a fitted model's
    calibrated classical prediction from the parameter covariance stored in its metadata (None when
    there is none)."""
    from ..calibration.calibrate import identification_jacobian

    cal = (getattr(model, "meta_", {}) or {}).get("calibration") or {}
    names = cal.get("correlation_names") or []
    if not names:
        return None
    params = {p["name"]: p for p in cal.get("parameters", [])}
    std = np.array([params[nm]["std"] if params.get(nm, {}).get("std") is not None else np.nan for nm in names])
    corr = np.asarray(cal.get("correlation"), dtype=np.float64)
    if corr.shape != (len(names), len(names)) or not np.isfinite(std).all():
        return None
    cov = corr * np.outer(std, std)
    all_names, J = identification_jacobian(model.robot_, q, position_only=True)
    cols = [all_names.index(nm) for nm in names if nm in all_names]
    if len(cols) != len(names):
        return None
    Jc = J[:, :, cols]  # (N, 3, k) m per SI unit
    var = np.einsum("nrp,pq,nrq->n", Jc, cov, Jc)
    return np.sqrt(np.clip(var, 0, None)) * 1e3


def active_poses(model, n: int, constraints: Constraints | None = None, *, seed: int = 0, pool: int = 20_000,
                 speeds=DEFAULT_SPEEDS_RAD_S, start=None, dwell_s: float = 0.0,
                 uncertainty_power: float = ACTIVE_UNCERTAINTY_POWER) -> Plan:
    """The next ``n`` poses for a fitted :class:`hykin.hybrid.model.HybridModel`: where its training data
    are thinnest relative to an even cover of the region, weighted by its uncertainty (module
    docstring), ordered for a short path."""
    import warnings

    from ..hybrid.inputs import net_coordinates

    if isinstance(n, bool) or int(n) != n or n < 1:
        raise PlanningError(f"number of poses must be a positive integer, got {n!r}")
    n = int(n)
    robot = model.robot
    c = (constraints or Constraints()).check(robot)
    speeds = np.broadcast_to(np.asarray(speeds, dtype=np.float64), (robot.dof,)).copy()
    cand, drawn = candidate_pool(robot, c, n, seed, pool)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        band, _ = model.predict_uncertainty(cand)
        dsup = model.support_distance(cand)
    s = np.asarray(band, dtype=np.float64) * (1.0 + dsup / model.fade_width_)
    sc = calibration_std_mm(model, cand)
    if sc is not None:
        s = s + 1.96 * sc
    # the networks' own coordinates: joints as they see them, scaled like the model's support points
    sup, mask = model.support, np.asarray(model.input_mask_, dtype=bool)
    U = ((net_coordinates(cand, model.wrap_centre_, model.input_mask_) - sup.lower) / sup.span)[:, mask]
    have = np.asarray(sup.points, dtype=np.float64)[:, mask]
    n_have = int((getattr(model, "meta_", {}) or {}).get("n_total") or len(have))
    weight = (s / max(float(np.median(s)), 1e-12)) ** uncertainty_power
    sel = deficit_select(U, have, n, have_weight=n_have / max(len(have), 1), weight=weight)
    X = embed(robot, cand, c.lower, c.upper)
    q_sel = cand[sel]
    path, q_ord = _order(robot, c, q_sel, speeds, start)
    plan = Plan(q=q_ord, core=np.zeros(n, bool), pick_order=path, travel=path_travel(q_ord, speeds, dwell_s),
                criteria={"min_spacing": min_spacing(X[sel]), "score_mean_mm": float(s[sel].mean()),
                          "pool_score_mean_mm": float(s.mean())},
                id_model=None, n_pool=drawn, n_feasible=len(cand), lower=c.lower, upper=c.upper, speeds=speeds,
                score=s[sel][path], info={"uncertainty_power": uncertainty_power, "n_existing": n_have})
    return with_safe_moves(plan, robot, c, cand, start)

