"""Branch hints of a program's targets: which joint solution each target means (:mod:`.programs`).

A target with configuration data (KUKA ``S``/``T``, ABB ``confdata``) means the solution with those data;
one without means the solution nearest the joints the robot is at: those of the previous target in
execution order, or of the joint move before it (URScript ``movej([...])``, ``get_inverse_kin``'s
``qnear``, KRL ``PTP`` to an axis aggregate; :attr:`.programs.ProgramTarget.reset`).

Passes for configuration data (:func:`branch_hints`): the nominal robot's solution of the uncompensated
target, else the calibrated robot's, else the calibrated robot's with the other elbow / overhead / wrist
flag within ``slack_rad`` of that flag's singular pose (:mod:`.branches`). Solutions up to
:data:`.branches.LIMIT_MARGIN_RAD` beyond a joint limit count (after those within), and the calibrated
chain's branches are seeded by a closed form (:func:`hykin.hybrid.ik_seeds.seed_robot_of`): the hybrid
solve decides. :func:`config_alternatives` gives the other hints a target may be solved again from.
"""

from __future__ import annotations

import numpy as np

__all__ = ["branch_hints", "config_alternatives", "execution_order", "reach_list", "seed_of"]


def seed_of(model):
    """The closed-form robot seeding the calibrated chain's branches (None: the chain's own IK)."""
    from ..hybrid.ik_seeds import seed_robot_of
    from ..kinematics.ik_closed_form import has_closed_form

    if has_closed_form(model.robot_):
        return None
    try:
        return seed_robot_of(model, None, model.robot_)
    except Exception:  # noqa: BLE001 - no closed form near this chain: its own numerical IK only
        return None


def execution_order(targets: list) -> list:
    """Target indices in execution order (``order``, else the literal's ``start``; ties: text order)."""
    return sorted(range(len(targets)), key=lambda k: (targets[k].start if targets[k].order is None else targets[k].order, k))


def _match(rob, TT, targets, rows, signs, abb_signs, nom, slack, margin, seed) -> np.ndarray:
    """Hints ``(len(rows), n)`` of the configuration targets ``rows`` on robot ``rob`` (targets ``TT[rows]``)."""
    from .branches import match_abb_confdata, match_kuka_status

    out = np.full((len(rows), nom.dof), np.nan)
    s = np.array(["S" in targets[k].config for k in rows], dtype=bool)
    if s.any():
        i = rows[s]
        out[s] = match_kuka_status(rob, TT[i], [targets[k].config["S"] for k in i],
                                   [targets[k].config.get("T", -1) for k in i], signs, slack, margin, seed)
    c = ~s
    if c.any():  # the calibrated robot names forward as the nominal does (branches.abb_confdata)
        i = rows[c]
        out[c] = match_abb_confdata(rob, TT[i], np.array([targets[k].config["conf"] for k in i]), abb_signs,
                                    reference=nom, slack_rad=slack, margin_rad=margin, seed_robot=seed)
    return out


def branch_hints(model, targets: list, Tm: np.ndarray, T_cal: np.ndarray, axis_signs,
                 slack_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joints ``(N, n)`` choosing each target's branch (module docstring): the nominal solution that the
    configuration data (or the walk) mean (targets ``Tm`` in the nominal robot's world); where the nominal
    robot has none, the calibrated robot's (targets ``T_cal`` in its world), and where that has none either,
    the calibrated robot's with the other elbow / overhead / wrist flag within ``slack_rad`` of that flag's
    singular pose; a target without configuration data and no solution on either takes the joints the robot
    is at (the hybrid model decides). NaN only where configuration data match nothing. Also returns the
    rows that took another flag ``(N,)`` bool and, for the NaN rows, why ``(N,)`` (:func:`reach_list`)."""
    from ..kinematics.ik import ik
    from .branches import LIMIT_MARGIN_RAD, default_axis_signs, nearest_candidate

    nom = model.nominal
    N, n = len(targets), nom.dof
    qb = np.full((N, n), np.nan)
    conf = np.array(["S" in t.config or "conf" in t.config for t in targets], dtype=bool)
    signs_cal = default_axis_signs(nom) if axis_signs is None else axis_signs
    seed = seed_of(model)
    passes = ((nom, Tm, axis_signs, 0.0, None), (model.robot_, T_cal, signs_cal, 0.0, seed))
    if slack_rad > 0:
        passes += ((model.robot_, T_cal, signs_cal, slack_rad, seed),)
    open_before = np.zeros(N, dtype=bool)
    for rob, TT, signs, slack, sd in passes:
        open_before = ~np.isfinite(qb).all(1)
        rows = np.flatnonzero(conf & open_before)
        if rows.size:
            qb[rows] = _match(rob, TT, targets, rows, signs, axis_signs, nom, slack, LIMIT_MARGIN_RAD, sd)
    other_flag = conf & open_before & np.isfinite(qb).all(1) if slack_rad > 0 else np.zeros(N, bool)
    free = np.flatnonzero(~conf)
    if free.size:
        sols = []
        for rob, TT in ((nom, Tm), (model.robot_, T_cal)):
            br = ik(rob, TT[free], all_branches=True)
            sols.append((rob, np.asarray(br.q, dtype=np.float64).reshape(free.size, -1, n),
                         np.asarray(br.success, dtype=bool).reshape(free.size, -1)))
        cur = np.clip(np.zeros(n), nom.lower, nom.upper)
        slot = {int(k): j for j, k in enumerate(free)}
        prev = None
        # a walk in execution order: each choice depends on the joints the previous target left
        for k in execution_order(targets):
            j = slot.get(k)
            if j is not None:
                p = prev if targets[k].after is None else targets[k].after  # (a target moved to again)
                if targets[k].reset is not None:
                    cur = np.asarray(targets[k].reset, dtype=np.float64)
                elif p is not None and np.isfinite(qb[p]).all():
                    cur = qb[p]
                pick = None
                for (rob, q, ok), signs in zip(sols, (axis_signs, signs_cal)):
                    allowed = ok[j]
                    if targets[k].config.get("keep_status") and allowed.any():
                        allowed = same_status(rob, q[j], allowed, cur, signs)
                    pick = nearest_candidate(rob, q[j], allowed, cur) if allowed.any() else None
                    if pick is not None:
                        break
                qb[k] = cur if pick is None else pick
            prev = k
    unmatched = ~np.isfinite(qb).all(1)
    why = np.full(N, "", dtype=object)
    if unmatched.any():
        why[unmatched] = [f"no solution with the program's configuration data ({_data(targets[k].config)}); " + r
                          for k, r in zip(np.flatnonzero(unmatched),
                                          reach_list(model, [targets[k] for k in np.flatnonzero(unmatched)],
                                                     T_cal[unmatched], axis_signs))]
    return qb, other_flag, why


def _data(cfg: dict) -> str:
    return f"S {cfg['S']}" if "S" in cfg else f"cfx {cfg['conf'][3]}"


def config_alternatives(model, targets: list, rows: np.ndarray, T_cal: np.ndarray, axis_signs,
                        slack_rad: float) -> list:
    """``[(hints (len(rows), n), other_flag)]``: the calibrated robot's solutions with each configuration
    target's data (NaN where none), then (``slack_rad > 0``) those with the other elbow / overhead / wrist
    flag within ``slack_rad`` of its singular pose: hints to solve ``rows`` again from where the first
    solve failed or left the taught configuration."""
    from .branches import LIMIT_MARGIN_RAD, default_axis_signs

    nom = model.nominal
    signs = default_axis_signs(nom) if axis_signs is None else axis_signs
    seed = seed_of(model)
    out = [(_match(model.robot_, T_cal, targets, rows, signs, axis_signs, nom, 0.0, LIMIT_MARGIN_RAD, seed), False)]
    if slack_rad > 0:
        out.append((_match(model.robot_, T_cal, targets, rows, signs, axis_signs, nom, slack_rad, LIMIT_MARGIN_RAD,
                           seed), True))
    return out


def same_status(rob, q: np.ndarray, ok: np.ndarray, cur: np.ndarray, signs) -> np.ndarray:
    """``ok`` ``(K,)`` narrowed to the solutions ``q`` ``(K, n)`` with the KUKA status ``S`` of the
    joints ``cur`` (a continuous-path motion keeps it); ``ok`` itself where none has it (the motion would
    cross a singularity: the nearest solution stands)."""
    from .branches import kuka_status

    S = kuka_status(rob, np.vstack([cur[None], np.nan_to_num(q)]), signs)[0]
    same = ok & (S[1:] == S[0])
    return same if same.any() else ok


def reach_list(model, targets: list, T_cal: np.ndarray, axis_signs, with_turn: bool = False) -> list:
    """Per target, the configuration data the real robot (the calibrated chain; targets ``T_cal`` in its
    world) reaches it with within its limits: ``"the real robot reaches it with S 2, 6"`` (``with_turn``:
    ``S 2 T 35, S 6 T 27``; ABB: ``cfx``), or that it reaches it in no configuration there."""
    from .branches import abb_confdata, candidates, default_axis_signs, kuka_status

    if not targets:
        return []
    rob, nom = model.robot_, model.nominal
    signs_cal = default_axis_signs(nom) if axis_signs is None else axis_signs
    q, ok, penalty = candidates(rob, T_cal, 0.0, seed_of(model))
    ok = ok & (penalty == 0)  # the chain's own solutions (not a seed robot's, which only hint)
    M, K, n = q.shape
    qz = np.nan_to_num(q.reshape(-1, n))
    S, Tt = (v.reshape(M, K) for v in kuka_status(rob, qz, signs_cal))
    cfx = abb_confdata(rob, qz, axis_signs, reference=nom)[:, 3].reshape(M, K)
    out = []
    for r, t in enumerate(targets):
        if "S" in t.config and with_turn:
            # those nearest the program's data first: fewest differing T bits, then S bits
            S0, T0 = int(t.config["S"]), max(int(t.config.get("T", 0)), 0)
            found = sorted({(int(a), int(b)) for a, b in zip(S[r][ok[r]], Tt[r][ok[r]])},
                           key=lambda st: (bin(st[1] ^ T0).count("1"), bin(st[0] ^ S0).count("1"), st))
            txt = ", ".join(f"S {a} T {b}" for a, b in found[:6]) + (" ..." if len(found) > 6 else "")
        elif "S" in t.config:
            found = sorted({int(v) for v in S[r][ok[r]]})
            txt = "S " + ", ".join(str(v) for v in found) if found else ""
        else:
            found = sorted({int(v) for v in cfx[r][ok[r]]})
            txt = "cfx " + ", ".join(str(v) for v in found) if found else ""
        out.append(f"the real robot reaches it with {txt}" if txt else
                   "the real robot reaches it in no configuration within its joint limits")
    return out
