"""Hybrid inverse kinematics (DESIGN.md §1.3): joints that reach a target with the *hybrid* model.

Method (Ojer et al. 2024, §1.3), batched over every target × branch:

1. Classical IK on the model's calibrated classical robot (:func:`classical_robot`): closed form for all
   branches where the robot has one (:func:`hykin.kinematics.ik.ik`), numerical otherwise. Each branch gives a
   seed ``q0``.
2. Bounded non-linear least squares in the box ``q0 ± δ`` (clipped to the joint limits): minimise
   the Cartesian error between the target and the hybrid pose ``T*(q)`` — position (m) and
   orientation (rotation vector ``log(R* R_targetᵀ)``, rad, weighted by ``orientation_weight_m``), or
   position only. Solver: vectorised projected Levenberg–Marquardt in float64 over all rows at once
   (no per-target Python loop; :func:`hykin.kinematics.lm.lm_solve`, damping scaled by the mean
   diagonal of JᵀJ). Jacobian: the classical geometric Jacobian of the calibrated robot at the
   current joints plus the correction to it (networks, compliance), measured once at the seed and
   kept — a quasi-Newton "frozen correction": the correction is ~1e-3 of the classical Jacobian and
   barely changes inside the box, so each iteration gains ~3 digits and 3–5 iterations reach
   ~1e-12 m. The correction is taken by central differences of ``model.predict`` (``jacobian_mode=
   "frozen-fd"``, default: 12 batched hybrid FK calls, the fastest), by autograd of
   ``model.predict_torch`` (``"frozen"``), or re-taken by autograd every iteration (``"exact"``).
3. Default box ``δ = 3°`` (``delta_rad``): the hybrid correction of a real arm is ~1–3 mm / 0.2°, which
   moves the joints by ~0.1–0.5°; near the wrist singularity joints 4 and 6 may need more, so a row
   that ends on the box boundary above tolerance is re-solved once in a box ``widen`` times larger,
   and otherwise reported as failed.

4. Near singularities the hybrid correction can move a solution far from its classical seed, or
   move a fold (two branches that meet, e.g. a nearly stretched elbow) so that both seeds find the
   same root. Rows that stalled under 1 mm are polished with the Jacobian re-taken every iteration;
   failed rows whose seed is near a singularity restart along its singular direction; rows that
   converged onto another branch's root restart from the other root of the local quadratic model
   (``more_roots``). A restart counts only when it is a new, distinct solution.

5. Under-actuated arms (fewer than 6 joints: SCARA, palletizer) cannot match all six components of an
   arbitrary (measured) pose: the answer is the least-squares solution. Their classical seeds are the
   calibrated arm's least-squares solutions (``least_squares`` of :func:`hykin.kinematics.ik.ik`), and a
   row succeeds when the joints can reduce the error no further and what is left is within the model's
   own accuracy (its held-out maximum error, :func:`~hykin.hybrid.ik_result.model_accuracy`);
   :func:`~hykin.hybrid.ik_solve.hybrid_ik_from_seeds`.

Solutions of one target closer than ``dedupe_rad`` (max joint difference) are merged.
:func:`branch_count_report` compares the distinct solutions per target with the closed form of the
nominal robot and explains each difference (joint limit, singularity / workspace edge, or unexplained). Failed rows
carry a reason and are never marked successful. :func:`wang_ik` is the comparison method of
Wang et al. (2019): classical IK → hybrid FK → compensated target → classical IK again.

The "model" is anything with ``robot`` (classical :class:`hykin.kinematics.robot.Robot`), ``predict(q)`` →
``(N, 4, 4)`` numpy hybrid poses and, for exact Jacobians, ``predict_torch(q)`` (differentiable,
float64); ``support_distance(q)`` → ``(N,)`` (0 inside the training region) is used when present.
Units: joints rad (m for prismatic), positions m, reported errors mm and degrees.

Modules: this one holds the public entry points (:func:`hybrid_ik`, :func:`wang_ik`);
:mod:`~hykin.hybrid.ik_result` the result type and input checks, :mod:`~hykin.hybrid.ik_seeds` the
classical seeds (step 1), :mod:`~hykin.hybrid.ik_solve` the residual, Jacobians and box solve (steps
2–3, on the shared LM of :mod:`hykin.kinematics.lm`), :mod:`~hykin.hybrid.ik_roots` the searches of
step 4 and duplicates, :mod:`~hykin.hybrid.ik_report` the output rows and branch-count report.
"""

from __future__ import annotations

import numpy as np

from ..geometry import se3
from ..kinematics.fk import fk
from ..kinematics.ik import ik as classical_ik
from ..kinematics.robot import Robot
from .ik_report import BranchCountReport, branch_count_report, ik_result_to_rows
from .ik_result import (
    DEFAULT_DELTA_RAD,
    HybridIKError,
    HybridIKResult,
    check_model,
    parse_targets,
    predict_quiet,
    support_of,
)
from .ik_seeds import classical_robot, classical_seeds, closed_form_proxy, seed_robot_of
from .ik_solve import hybrid_ik_from_seeds

__all__ = [
    "BranchCountReport",
    "HybridIKError",
    "HybridIKResult",
    "branch_count_report",
    "classical_robot",
    "classical_seeds",
    "closed_form_proxy",
    "hybrid_ik",
    "hybrid_ik_from_seeds",
    "ik_result_to_rows",
    "wang_ik",
]

def hybrid_ik(
    model,
    T_target,
    *,
    all_branches: bool = True,
    q_current=None,
    q_seed=None,
    nearest: bool = False,
    delta_rad: float = DEFAULT_DELTA_RAD,
    position_only: bool = False,
    tol_m: float = 1e-12,
    seed_robot: Robot | None = None,
    temperature_c=None,
    **kwargs,
) -> HybridIKResult:
    """Joints reaching ``T_target`` with the hybrid model: all branches by default.

    ``T_target``: ``(N, 4, 4)`` poses or ``(N, 3)`` positions (position-only) in the world frame, m.
    ``all_branches``: seed from every closed-form branch of the calibrated robot (when it has a
    closed form; otherwise numerical IK). ``q_seed`` ``(N, dof)`` / ``(N, S, dof)``: extra seeds for
    the classical IK (with ``all_branches=False``, the only seeds). ``q_current`` ``(N, dof)`` or
    ``(dof,)``: current joints; with ``nearest=True`` only the solution nearest to them is kept per
    target (the nearest; where the network correction applies only among solutions within 5° of joint
    distance of the nearest: :func:`hybrid_ik_from_seeds`), and, for a
    robot without a closed form (7 DOF), they seed a solution of their own; without a seed they also
    seed position-only IK.
    ``delta_rad``: half-width of the box around each classical solution (default 3°).
    ``seed_robot``: robot whose closed form seeds the branches (default: the calibrated robot if it has
    one, else the nominal robot — ``model.nominal`` or a HybridModel's ``model.robot`` — else
    :func:`closed_form_proxy` of the calibrated robot). ``tol_m``: stopping tolerance (and 1e-12 rad).
    ``temperature_c``: arm temperature (°C, scalar or ``(N,)``) at which the targets are to be reached,
    for a model with a thermal coefficient (:meth:`HybridModel.targets_at_reference`); errors are
    then reported at the reference temperature (they differ by ``alpha dT`` relative, ~1e-5).
    Success needs ``pos_err_mm <= success_mm`` (1e-4) and ``ang_err_deg <= success_deg`` (1e-4) and
    joints within limits; for an under-actuated arm (fewer than 6 joints, full poses) also a least-squares
    solution whose error is within the model's accuracy (``underactuated_mm`` / ``underactuated_deg``,
    default :func:`~hykin.hybrid.ik_result.model_accuracy`: module docstring, step 5). Other keywords go to :func:`hybrid_ik_from_seeds` (``widen`` = 5,
    ``orientation_weight_m`` = 1, ``success_mm``, ``success_deg``, ``max_iter`` = 60,
    ``jacobian_mode``, ``keep_failed``, ``dedupe_rad``, ``torch_threads`` = 1: torch threads while solving,
    ``restarts`` = 16: random starts in the widened box for rows that stalled near the target — local
    minima near singularities; ``more_roots`` = True, ``sing_rel`` = 0.02: the searches near
    singularities of step 4 of the module docstring).
    Returns a :class:`HybridIKResult`: per target its distinct successful solutions (one per branch;
    joints with a range over 2π in the closed form's representation, nearest zero — or nearest
    ``q_current`` with ``nearest=True``: the hybrid model is not 2π-periodic, so ``q ± 2π`` is another
    configuration that would need a solve of its own; it is tried only for targets no representation
    nearest zero reaches), or one failed row. Classical IK rows (``hykin ik`` on a robot file,
    :func:`hykin.kinematics.ik_rows.classical_ik_rows`) list every 2π copy within the limits instead, for
    robots with at most 8 per solution (not a UR arm: 64).
    """
    robot = check_model(model)
    if temperature_c is not None and hasattr(model, "targets_at_reference"):
        T_target = model.targets_at_reference(T_target, temperature_c)
    T, pos_only_in = parse_targets(T_target)
    pos_only = bool(position_only or pos_only_in)
    N = T.shape[0]
    seeds = q_seed
    sr = seed_robot_of(model, seed_robot, robot)
    # nearest without a closed form (a redundant arm has no finite set of branches: numerical ones may all
    # lie elsewhere): the current joints seed a solution of their own
    own = nearest and sr is None
    if seeds is None and q_current is not None and (pos_only or not all_branches or own):
        seeds = np.broadcast_to(np.asarray(q_current, dtype=np.float64).reshape(-1, robot.dof), (N, robot.dof))
    q0, labels, _ = classical_seeds(robot, T, all_branches=all_branches, q_seed=seeds, position_only=pos_only,
                                     seed_robot=sr)
    return hybrid_ik_from_seeds(
        model, T[:, :3, 3] if pos_only else T, q0, branch=labels, delta_rad=delta_rad, position_only=pos_only,
        tol_m=tol_m, q_current=q_current, nearest=nearest, **kwargs,
    )



def wang_ik(model, T_target, *, all_branches: bool = True, q_seed=None, success_mm: float = 1e-4,
            success_deg: float = 1e-4, orientation_weight_m: float = 1.0) -> HybridIKResult:
    """Comparison method of Wang et al. (2019): classical IK, hybrid FK, compensated target, classical IK.

    For each branch: ``q1`` = classical IK of the target on the calibrated robot; the hybrid model predicts
    the pose error at ``q1``, ``E = T*(q1) T̂(q1)⁻¹`` (``T̂`` the rigid classical FK that the classical IK
    inverts, so ``T̂(q1)`` = target); the compensated target is
    ``E⁻¹ T_target`` (position ``p − Δp``, rotation ``exp(−Δr) R``); ``q2`` = classical IK of it, seeded
    with ``q1``. Errors are those of ``T*(q2)`` to the target, so the result is comparable with
    :func:`hybrid_ik`. Same result type; successes use the same thresholds.
    """
    robot = check_model(model)
    T, pos_only = parse_targets(T_target)
    if pos_only:
        raise HybridIKError("wang_ik: needs full (N, 4, 4) target poses")
    N, n = T.shape[0], robot.dof
    q1, labels, ok1 = classical_seeds(robot, T, all_branches=all_branches, q_seed=q_seed,
                                      seed_robot=seed_robot_of(model, None, robot))
    B = q1.shape[1]
    flat = q1.reshape(-1, n)
    fin = np.all(np.isfinite(flat), axis=1) & ok1.reshape(-1)
    tgt = np.repeat(np.arange(N), B)
    q2 = np.full_like(flat, np.nan)
    reason = np.full(N * B, "no classical solution (unreachable for this branch)", dtype=object)
    if fin.any():
        i = np.flatnonzero(fin)
        Th = fk(robot, flat[i])  # what the (rigid) classical IK inverted: Th = T at q1
        Ts = predict_quiet(model, flat[i])
        # E = T* T̂^-1 maps classical to hybrid; compensated target Tc = E^-1 T  (p - Δp, exp(-Δr) R)
        dp = Ts[:, :3, 3] - Th[:, :3, 3]
        dR = Ts[:, :3, :3] @ np.swapaxes(Th[:, :3, :3], 1, 2)
        Tc = T[tgt[i]].copy()
        Tc[:, :3, 3] -= dp
        Tc[:, :3, :3] = np.swapaxes(dR, 1, 2) @ Tc[:, :3, :3]
        res2 = classical_ik(robot, Tc, q_seed=flat[i])
        q2i = np.asarray(res2.q, dtype=np.float64).reshape(-1, n)
        ok2 = np.asarray(res2.success, dtype=bool).reshape(-1)
        q2[i[ok2]] = q2i[ok2]
        reason[i] = np.where(ok2, "", "classical IK of the compensated target failed")
    good = np.all(np.isfinite(q2), axis=1)
    pe = np.full(N * B, np.nan)
    ae = np.full(N * B, np.nan)
    if good.any():
        Tp = predict_quiet(model, q2[good])
        pe[good], ae[good] = se3.pose_error(Tp, T[tgt[good]])
    okk = good & (pe <= success_mm) & (ae <= success_deg)
    reason = np.where(good & ~okk, np.array([f"error {a:.3g} mm / {b:.3g} deg" for a, b in zip(pe, ae)], dtype=object),
                      reason)
    reason[okk] = ""
    dist, ins = support_of(model, q2)
    res = HybridIKResult(
        target=tgt, branch=labels.reshape(-1).astype(str), q=q2, success=okk, pos_err_mm=pe, ang_err_deg=ae,
        reason=reason.astype(str), in_support=ins, support_distance=dist, iterations=np.ones(N * B, dtype=int),
        n_targets=N, info={"method": "wang2019"},
    )
    # keep every branch that produced joints; a target with none keeps one row saying why
    keep = good.reshape(N, B).copy()
    none = ~keep.any(1)
    keep[none, 0] = True
    return res.select(keep.reshape(-1))


