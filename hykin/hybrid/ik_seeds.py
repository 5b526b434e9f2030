"""Classical seeds of hybrid IK: one joint vector per closed-form branch of the calibrated robot
(or of a nearby robot with a closed form), boundary seeds for branches only the hybrid model reaches."""

from __future__ import annotations

import numpy as np

from ..kinematics.ik import ik as classical_ik
from ..kinematics.ik import ik_closed_form
from ..kinematics.ik_closed_form import has_closed_form
from ..kinematics.robot import Robot
from .ik_result import classical_robot

__all__ = ["LSQ_SEED", "boundary_seeds", "classical_seeds", "closed_form_proxy", "seed_robot_of"]

#: ``(m, rad)``: an under-actuated arm's least-squares classical solutions that miss a target by less
#: than this seed the hybrid solve (the target is a hybrid or measured pose, off the classical arm's
#: reachable poses by its correction: ~1-3 mm / 0.2° on a real arm)
LSQ_SEED = (0.01, float(np.radians(2.0)))



def closed_form_proxy(robot: Robot) -> Robot | None:
    """A nearby robot with a closed-form IK, to seed the branches of a calibrated robot that has none.

    Calibration leaves tiny deviations (``beta``, ``alpha`` off multiples of 90°, sub-mm ``a``/``d``
    offsets) that break the OPW/UR structure; they are snapped (``alpha`` within 0.02 rad of a multiple
    of π/2, ``beta`` to 0, DH lengths under 5 mm to 0). Returns ``None`` when even that has no closed form.
    """
    if robot.dof != 6 or robot.convention == "urdf":
        return None
    if has_closed_form(robot):
        return robot
    q90 = np.round(robot.alpha_rad / (np.pi / 2)) * (np.pi / 2)
    alpha = np.where(np.abs(robot.alpha_rad - q90) < 0.02, q90, robot.alpha_rad)
    snap = lambda x: np.where(np.abs(x) < 5e-3, 0.0, x)
    proxy = robot.copy(alpha_rad=alpha, beta_rad=np.zeros(robot.dof), a_m=snap(robot.a_m), d_m=snap(robot.d_m))
    return proxy if has_closed_form(proxy) else None


def boundary_seeds(robot, sr, T, q, ok, pull_m):
    """Seeds for branches the classical robot cannot reach but the hybrid one may (workspace edge).

    Near a stretched elbow a ~mm correction decides whether a branch exists. For targets with a
    missing branch, the closed form is retried on the target pulled towards the robot base by each
    distance in ``pull_m``; the hybrid solve (box widened once) then decides. ``q`` ``(N, K, n)``.
    """
    miss = ~np.all(np.isfinite(q), axis=2)
    idx = np.flatnonzero(miss.any(1))
    if idx.size == 0 or q.ndim != 3:
        return q, ok
    base_p = robot.base[:3, 3]
    for d in pull_m:
        if idx.size == 0:
            break
        Tp = T[idx].copy()
        v = Tp[:, :3, 3] - base_p
        Tp[:, :3, 3] -= d * v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
        br = classical_ik(robot, Tp, all_branches=True, seed_robot=sr)
        qn, okn = np.asarray(br.q, dtype=np.float64), np.asarray(br.success, dtype=bool)
        if qn.shape[1] != q.shape[1]:
            break
        fill = miss[idx] & okn
        sub_q, sub_ok = q[idx], ok[idx]
        sub_q[fill] = qn[fill]
        sub_ok[fill] = False  # a seed, not a classical solution of the real target
        q[idx], ok[idx] = sub_q, sub_ok
        miss[idx] &= ~fill
        idx = idx[miss[idx].any(1)]
    return q, ok


def classical_seeds(robot: Robot, T: np.ndarray, *, all_branches: bool = True, q_seed=None,
                    position_only: bool = False, seed_robot: Robot | None = None,
                    pull_m: tuple[float, ...] = (1e-3, 4e-3)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Classical IK of ``robot`` (rigid) for targets ``T`` ``(N, 4, 4)``: seeds for the hybrid refinement.

    All branches come from :func:`hykin.kinematics.ik.ik` with the closed form of ``seed_robot`` (default: the
    robot itself if it has one, else :func:`closed_form_proxy`) polished by LM on ``robot``; without
    any closed form, from ik's numerical multi-start search. ``q_seed`` ``(N, dof)`` / ``(N, S, dof)``
    adds one numerical solution per seed (the only ones when ``all_branches=False``). Branches with
    no classical solution are re-seeded from targets pulled ``pull_m`` towards the base (see
    :func:`boundary_seeds`). An under-actuated arm (fewer than 6 joints) reaches most poses only in the
    least-squares sense: its least-squares solutions within :data:`LSQ_SEED` seed it. Returns ``q0`` ``(N, B, dof)`` (NaN where a branch has no classical solution), ``branch``
    ``(N, B)`` str labels and ``ok`` ``(N, B)`` bool (the classical solver reports success).
    """
    N, n = T.shape[0], robot.dof
    outs_q, outs_b, outs_ok = [], [], []

    def _add(q, ok, lab):
        q = np.asarray(q, dtype=np.float64).reshape(N, -1, n)
        ok = np.asarray(ok, dtype=bool).reshape(N, -1)
        lab = np.asarray(lab, dtype=object).reshape(ok.shape)
        outs_q.append(q)
        outs_b.append(np.where(lab == "", "numeric", lab).astype(str))
        outs_ok.append(ok)

    if all_branches and not position_only:
        sr = seed_robot if seed_robot is not None else closed_form_proxy(robot)
        br = classical_ik(robot, T, all_branches=True, seed_robot=sr, least_squares=LSQ_SEED)
        q, ok = np.array(br.q, dtype=np.float64), np.array(br.success, dtype=bool)
        if sr is not None and (~ok).any():
            # a branch just outside the joint limits (or failing the classical polish) still seeds the
            # hybrid solve: the hybrid solution may lie inside; the closed form returns it clipped
            cf = ik_closed_form(sr, T, tol_m=np.inf, tol_rad=np.inf)
            if cf.q.shape == q.shape:
                # only candidates that clipping moved a little (~1-2° beyond a limit), not far-off ones
                near = (cf.pos_err_m <= 0.02) & (cf.ang_err_rad <= 0.03)
                fill = ~ok & np.all(np.isfinite(cf.q), axis=2) & near
                q[fill] = cf.q[fill]
        if sr is not None and pull_m:
            q, ok = boundary_seeds(robot, sr, T, q, ok, pull_m)
        _add(q, ok, br.label)
    if q_seed is not None:
        qs = np.asarray(q_seed, dtype=np.float64).reshape(N, -1, n)
        for s in range(qs.shape[1]):
            r = classical_ik(robot, T, q_seed=qs[:, s], position_only=position_only, least_squares=LSQ_SEED)
            lab = np.full(N, "seed" if qs.shape[1] == 1 else f"seed{s}", dtype=object)
            _add(r.q, r.success, lab)
    if not outs_q:
        r = classical_ik(robot, T, position_only=position_only, least_squares=LSQ_SEED)
        _add(r.q, r.success, np.where(np.asarray(r.label, dtype=object) == "", "numeric", r.label))
    return np.concatenate(outs_q, 1), np.concatenate(outs_b, 1), np.concatenate(outs_ok, 1)



def seed_robot_of(model, seed_robot, robot: Robot | None = None):
    """The robot whose closed form seeds ``model``'s branches: ``seed_robot`` if given, else the classical
    ``robot`` (default :func:`classical_robot`; hybrid IK passes it in the registered frames) if it has a
    closed form, else the nominal robot in its base and tool, else :func:`closed_form_proxy`."""
    if seed_robot is not None:
        return seed_robot
    cls = classical_robot(model) if robot is None else robot
    if has_closed_form(cls):
        return cls
    for name in ("nominal", "robot"):  # HybridModel: robot = nominal, robot_ = calibrated
        nom = getattr(model, name, None)
        if isinstance(nom, Robot) and nom is not cls and nom.dof == cls.dof and has_closed_form(nom):
            # in the calibrated robot's base and tool: a model fitted on tracker data has its base metres
            # from the nominal one, whose closed form would seed targets it does not reach
            return nom.copy(base=cls.base, tool=cls.tool)
    return closed_form_proxy(cls)

