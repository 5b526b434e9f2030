"""What the controller will do with a program's compensated targets, checked before it is written.

A controller runs its nominal model. For a target with configuration data it takes the nominal solution
of the written command with the written data; for one without, the nominal solution nearest the joints
it is at. The compensated joints ``q`` are right only where that is ``q`` itself.

* Configuration data (:func:`keep_configuration`, :func:`configuration_changes`): the written KUKA
  ``S``/``T`` are those of ``q``. They may differ from the program's only where the program did not ask
  for another configuration: a flag within ``slack_rad`` of its singular pose (stretched elbow, wrist
  centre on axis 1, ``A5 = 0``: the real robot reaches the target only on the other side) and a ``T`` bit
  of an axis within :data:`.branches.T_CROSS_RAD` of 0 (the correction moves it across 0): both noted,
  naming the axis and its angle. Any other change (the taught ``S`` wrong, an axis a full turn or an arm
  configuration away) is refused, naming the ``S``/``T`` the real robot reaches the target with; where one
  axis's ``T`` bit differs on most targets, the reason names ``--axis-signs`` (the sign convention).
  Before that a target that failed or left its configuration is solved again from the calibrated robot's
  solutions with its data (:func:`.program_branches.config_alternatives`). ABB ``cfx`` changes keep their
  note.
* The walk of targets without configuration data: :mod:`.walk_checks`.
"""

from __future__ import annotations

import numpy as np

from .result import fail_row

__all__ = ["FIELDS", "configuration_changes", "keep_configuration", "take"]

#: the per-row fields of a :class:`.result.Compensation`
FIELDS = ("command", "q", "success", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg", "in_support", "q_branch",
          "reason")


def take(comp, rows: np.ndarray, again, mask: np.ndarray) -> None:
    """In place: ``comp``'s rows ``rows[mask]`` from ``again`` (a :class:`.result.Compensation` of ``rows``)."""
    for name in FIELDS:
        getattr(comp, name)[rows[mask]] = getattr(again, name)[mask]


# ----------------------------------------------------------------------------- configuration data

def _kuka_diff(nom, targets: list, rows: np.ndarray, q: np.ndarray, axis_signs, slack_rad: float) -> list:
    """Per row ``(S, T, allowed S-bit text, allowed T-bit text, refused text)`` of the KUKA targets ``rows``
    at joints ``q`` ``(len(rows), n)`` (module docstring); the texts empty where nothing is said."""
    from .branches import T_CROSS_RAD, T_ZERO_RAD, arm_angles, default_axis_signs, kuka_status

    s = default_axis_signs(nom) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    S1, T1 = kuka_status(nom, q, s)
    lean, e = arm_angles(nom, q, s)
    A = np.degrees(q * s)
    sl = max(float(slack_rad), T_ZERO_RAD)
    out = []
    for j, k in enumerate(rows):
        cfg = targets[k].config
        S0, T0 = int(cfg["S"]), int(cfg.get("T", -1))
        flag = {1: ("wrist centre on axis 1", lean[j]), 2: ("elbow from stretched", e[j]), 4: ("A5", q[j, 4] * s[4])}
        ds = S0 ^ int(S1[j])
        s_ok = [f"{name} {np.degrees(a):+.3g}°" for b, (name, a) in flag.items() if ds & b and abs(a) <= sl]
        s_bad = [f"S bit {b.bit_length() - 1}" for b, (_, a) in flag.items() if ds & b and abs(a) > sl]
        dt = (T0 ^ int(T1[j])) if T0 >= 0 else 0
        t_ok = [f"A{i + 1} {A[j, i]:+.4g}°" for i in range(nom.dof) if dt >> i & 1 and abs(q[j, i]) <= T_CROSS_RAD]
        t_bad = [f"A{i + 1} {A[j, i]:+.1f}° where T {T0} has it {'< 0' if T0 >> i & 1 else '>= 0'}"
                 for i in range(nom.dof) if dt >> i & 1 and abs(q[j, i]) > T_CROSS_RAD]
        refused = ""
        if s_bad or t_bad:
            what = ([f"S {S0} -> {int(S1[j])}"] if s_bad else []) + t_bad
            refused = (f"a configuration change the program does not ask for: the solution nearest the program's "
                       f"S {S0}, T {T0} that the real robot has within its limits is S {int(S1[j])}, T {int(T1[j])} "
                       f"({', '.join(what)})")
        out.append((int(S1[j]), int(T1[j]), ", ".join(s_ok), ", ".join(t_ok), refused))
    return out


def _acceptable(model, targets: list, rows: np.ndarray, q: np.ndarray, axis_signs, slack_rad: float) -> np.ndarray:
    """``(len(rows),)`` bool: the joints ``q`` keep the configuration each target's data ask for (KUKA:
    :func:`_kuka_diff` refuses nothing; ABB: ``cfx`` equal)."""
    from .branches import abb_confdata

    ok = np.zeros(len(rows), dtype=bool)
    fin = np.isfinite(q).all(1)
    s = np.array(["S" in targets[k].config for k in rows], dtype=bool)
    i = np.flatnonzero(s & fin)
    if i.size:
        ok[i] = [not d[4] for d in _kuka_diff(model.nominal, targets, rows[i], q[i], axis_signs, slack_rad)]
    i = np.flatnonzero(~s & fin)
    if i.size:
        ok[i] = abb_confdata(model.nominal, q[i], axis_signs)[:, 3] == [targets[k].config["conf"][3] for k in rows[i]]
    return ok


def _turns(model, targets: list, rows: np.ndarray, q: np.ndarray, axis_signs) -> np.ndarray:
    """``q`` ``(len(rows), n)`` with each revolute joint whose KUKA ``T`` bit differs from the program's moved
    by a full turn where that lies within the limits and has the program's sign: ``T`` picks the
    representation (the same pose and command; a solve that slid along a wrist singularity, A4 ≈ -A6, may
    end in the other one, a full turn of A4 from the taught joints)."""
    from .branches import T_CROSS_RAD, default_axis_signs

    nom = model.nominal
    s = default_axis_signs(nom) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    rev = nom.revolute
    q = np.array(q, dtype=np.float64)
    for j, k in enumerate(rows):
        T0 = int(targets[k].config.get("T", -1))
        if T0 < 0 or not np.isfinite(q[j]).all():
            continue
        for i in np.flatnonzero(rev & (np.abs(q[j]) > T_CROSS_RAD)):
            want_neg = bool(T0 >> i & 1)
            if (s[i] * q[j, i] < 0) == want_neg:
                continue
            for v in (q[j, i] - 2 * np.pi, q[j, i] + 2 * np.pi):
                if nom.lower[i] <= v <= nom.upper[i] and (s[i] * v < 0) == want_neg:
                    q[j, i] = v
                    break
    return q


def keep_configuration(model, solve, targets: list, comp, other_flag: np.ndarray, T_cal: np.ndarray, axis_signs,
                       slack_rad: float) -> None:
    """Solve again (in place) the configuration targets that failed or whose compensated joints left the
    configuration their data ask for, from the calibrated robot's solutions with those data, then with the
    other flag within the slack (:func:`.program_branches.config_alternatives`); a row is replaced where
    the new solution succeeds and keeps the configuration (``other_flag`` set for the second).
    ``solve(rows, hints)``: a :class:`.result.Compensation` of those rows."""
    from .program_branches import config_alternatives

    conf = np.array(["S" in t.config or "conf" in t.config for t in targets], dtype=bool)
    rows = np.flatnonzero(conf)
    if not rows.size:
        return
    comp.q[rows] = _turns(model, targets, rows, comp.q[rows], axis_signs)
    bad = ~comp.success[rows] | ~_acceptable(model, targets, rows, comp.q[rows], axis_signs, slack_rad)
    # the rows that failed before the solve (no configuration matched) have no hint to try again from
    rows = rows[bad & np.isfinite(comp.q_branch[rows]).all(1)]
    if not rows.size:
        return
    left = np.ones(rows.size, dtype=bool)
    for hints, flipped in config_alternatives(model, targets, rows, T_cal, axis_signs, slack_rad):
        fin = left & np.isfinite(hints).all(1) & ~np.all(np.abs(hints - comp.q_branch[rows]) < 1e-9, axis=1)
        if not fin.any():
            continue
        sub = rows[fin]
        again = solve(sub, hints[fin])
        again.q = _turns(model, targets, sub, again.q, axis_signs)
        good = again.success & _acceptable(model, targets, sub, again.q, axis_signs, slack_rad)
        take(comp, sub, again, good)
        other_flag[sub[good]] = flipped
        left[np.flatnonzero(fin)[good]] = False
        if not left.any():
            return
    _wrist_sweep(model, solve, targets, comp, rows[left], axis_signs, slack_rad)


#: a hint this near the wrist singularity (|q5|, rad) has its A4/A6 split swept when its solve fails
def _wrist_sweep(model, solve, targets: list, comp, rows: np.ndarray, axis_signs, slack_rad: float) -> None:
    """In place: the configuration ``rows`` whose hint lies near the wrist singularity solved again from the
    hints with the A4/A6 split turned (:func:`.branches.wrist_split_seeds`), each in the representation its
    ``T`` names; the smallest turn that reaches it with the program's configuration is taken."""
    from .branches import wrist_split_seeds

    j, H = wrist_split_seeds(model.nominal, comp.q_branch[rows])
    if not j.size:
        return
    r = rows[j]
    H = np.clip(_turns(model, targets, r, H, axis_signs), model.nominal.lower, model.nominal.upper)
    again = solve(r, H)
    again.q = _turns(model, targets, r, again.q, axis_signs)
    good = again.success & _acceptable(model, targets, r, again.q, axis_signs, slack_rad)
    for k in np.unique(r):
        i = np.flatnonzero(good & (r == k))
        if i.size:  # seeds come in order of the turn: the first is the smallest
            for name in FIELDS:
                getattr(comp, name)[k] = getattr(again, name)[i[0]]


def configuration_changes(model, targets: list, comp, other_flag: np.ndarray, T_cal: np.ndarray, axis_signs,
                          slack_rad: float, slack_deg: float) -> list:
    """Refuse (in place) the KUKA targets whose compensated configuration is one the program does not ask
    for; returns the notes on the rewritten ones (module docstring). ABB: the ``cfx`` notes as before."""
    from .program_branches import reach_list

    notes, flag, turn, abb = [], [], [], []
    ok = np.flatnonzero(comp.success)
    kuka = np.array([k for k in ok if "S" in targets[k].config], dtype=np.int64)
    diffs = _kuka_diff(model.nominal, targets, kuka, comp.q[kuka], axis_signs, slack_rad) if kuka.size else []
    refused = [(k, d) for k, d in zip(kuka, diffs) if d[4]]
    hint = _sign_hint(model.nominal, targets, kuka, comp.q[kuka], axis_signs, [bool(d[4]) for d in diffs])
    if refused:
        tg, Tc = [targets[k] for k, _ in refused], T_cal[[k for k, _ in refused]]
        for (k, d), r, rs in zip(refused, reach_list(model, tg, Tc, axis_signs, with_turn=True),
                                 reach_list(model, tg, Tc, axis_signs)):
            S0 = int(targets[k].config["S"])
            has_s = rs.startswith("the real robot reaches it with S ") and str(S0) in rs.split("S ", 1)[1].split(", ")
            # no solution with the taught S at all: said as for a target whose data match nothing
            fail_row(comp, k, f"{d[4]}; {r}{hint}" if has_s else
                     f"no solution with the program's configuration data (S {S0}); {rs}{hint}")
    for k, d in zip(kuka, diffs):
        if d[4]:
            continue
        cfg, line = targets[k].config, targets[k].line
        if d[2]:
            flag.append(f"{line} (S {cfg['S']} -> {d[0]}: {d[2]})")
        elif other_flag[k]:  # solved from the other flag; the nominal's flag at the joints is the taught one
            flag.append(f"{line}")
        if d[3]:
            turn.append(f"{line} (T {cfg['T']} -> {d[1]}: {d[3]})")
    _taught_turns(model, targets, comp, ok, axis_signs)
    quad = []
    for k in ok:
        cfg = targets[k].config
        if "conf" in cfg:
            got = int(_abb_cfx(model, comp.q[k], axis_signs))
            if other_flag[k]:
                flag.append(f"{targets[k].line}" + (f" (cfx {cfg['conf'][3]} -> {got})" if got != cfg["conf"][3] else ""))
            elif got != cfg["conf"][3]:
                abb.append(f"{targets[k].line} (cfx {cfg['conf'][3]} -> {got})")
            quad += _abb_quadrants(model, targets[k], comp.q[k], axis_signs)
    lst = lambda v: f"lines {', '.join(v[:8])}{' ...' if len(v) > 8 else ''}"
    if flag:
        notes.append(f"{flag[0].split(' ')[0]}: {len(flag)} targets ({lst(flag)}) lie within {slack_deg:g}° of a "
                     "singular pose (stretched elbow, wrist centre on axis 1, A5 = 0), where the real robot reaches them "
                     "only with the other elbow / overhead / wrist flag: their configuration data are rewritten to it "
                     "(--config-slack-deg 0 refuses them)")
    if abb:
        notes.append(f"{abb[0].split(' ')[0]}: {len(abb)} targets ({lst(abb)}) are reached by the real robot only in "
                     "another configuration than taught (no solution with the program's configuration within the "
                     "joint limits): their configuration data are rewritten")
    if quad:  # probe s41 AN: cf1 1 -> -2 at axis 1 179.6° -> -179.9° (a MoveJ turns it by 359.5°), unsaid
        notes.append(f"{quad[0].split(' ')[0]}: {len(quad)} targets ({lst(quad)}) are reached with other quadrant data "
                     "(cf1/cf4/cf6) than taught, the compensated axis across a quadrant boundary: their confdata are "
                     "rewritten (near ±180° a joint move from a neighbouring target may turn that axis by up to a turn)")
    if turn:
        notes.append(f"{turn[0].split(' ')[0]}: {len(turn)} targets ({lst(turn)}) have an axis within 1° of 0° that "
                     "the correction moves across 0° (its compensated angle given): their T is rewritten to the "
                     "compensated joints' (the taught T would turn that axis by a full turn or find no solution)")
    return notes


def _taught_turns(model, targets: list, comp, rows: np.ndarray, axis_signs) -> None:
    """In place: an ABB target whose compensated axis 1, 4 or 6 lies whole turns from its taught quadrant
    (cf differs by a multiple of 4) takes the taught turn where it is within the limits and the model's pose
    there is the same (a 2π-periodic model): the compensated joints are the taught ones a turn away, not
    another configuration (probe s41 AO: axis 4 taught at +199.994° of ±200° was written at -160.006°,
    axis 6 at 399.994° of ±400° at 39.994°: a full turn to unwind on the next move)."""
    from .branches import abb_confdata

    nom = model.nominal
    if nom.dof < 6:
        return
    s = np.ones(nom.dof) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    for k in rows:
        cfg = targets[k].config
        if "conf" not in cfg:
            continue
        got = abb_confdata(nom, comp.q[k][None], axis_signs)[0]
        q = comp.q[k].copy()
        for i, a in enumerate((1, 4, 6)):
            d = int(cfg["conf"][i]) - int(got[i])
            if d and d % 4 == 0:  # whole turns of the controller's axis a: the joint moves by s · turns · 2π
                q[a - 1] += s[a - 1] * (d // 4) * 2 * np.pi
        if np.array_equal(q, comp.q[k]) or np.any(q < nom.lower) or np.any(q > nom.upper):
            continue
        P = np.asarray(landing_pose(model, np.stack([comp.q[k], q])))
        if np.abs(P[0] - P[1]).max() < 1e-9:
            comp.q[k] = q


def landing_pose(model, q: np.ndarray) -> np.ndarray:
    """The model's poses ``(M, 4, 4)`` at joints ``q`` ``(M, n)`` (warnings about the support silenced)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return np.asarray(model.predict(q), dtype=np.float64).reshape(-1, 4, 4)


def _abb_quadrants(model, target, q, axis_signs) -> list:
    """``["LINE (cf1 1 -> -2: axis 1 -179.9°)"]`` when the compensated joints ``q`` have other cf1/cf4/cf6
    than the target's taught confdata (one entry naming each changed axis), else ``[]``."""
    from .branches import abb_confdata

    got = abb_confdata(model.nominal, np.asarray(q)[None], axis_signs)[0]
    s = np.ones(model.nominal.dof) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    taught = target.config["conf"]
    ch = [f"cf{a} {int(taught[i])} -> {int(got[i])}: axis {a} {np.degrees(q[a - 1] * s[a - 1]):+.2f}°"
          for i, a in enumerate((1, 4, 6)) if a <= len(q) and int(got[i]) != int(taught[i])]
    return [f"{target.line} ({'; '.join(ch)})"] if ch else []


def _abb_cfx(model, q, axis_signs) -> int:
    from .branches import abb_confdata

    return abb_confdata(model.nominal, np.asarray(q)[None], axis_signs)[0, 3]


def _sign_hint(nom, targets: list, rows: np.ndarray, q: np.ndarray, axis_signs, refused: list) -> str:
    """Where one axis's ``T`` bit differs from the program's, away from 0, on most of the KUKA targets
    (at least 3): the text naming ``--axis-signs`` (a controller axis turning the other way than the robot
    file's joint reverses that bit on every target), else ``""``."""
    from .branches import T_CROSS_RAD, default_axis_signs, kuka_status

    if len(rows) < 3 or not any(refused):
        return ""
    s = default_axis_signs(nom) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    T1 = kuka_status(nom, q, s)[1]
    T0 = np.array([targets[k].config.get("T", -1) for k in rows])
    given = T0 >= 0
    far = np.abs(q) > T_CROSS_RAD  # (M, n)
    diff = np.array([[(int(a) ^ int(b)) >> i & 1 for i in range(nom.dof)] for a, b in zip(T0, T1)], dtype=bool)
    diff &= far & given[:, None]
    n_far = (far & given[:, None]).sum(0)
    axes = [i for i in range(nom.dof) if diff[:, i].sum() >= 3 and diff[:, i].sum() >= 0.5 * n_far[i]]
    if not axes:
        return ""
    which = ", ".join(f"A{i + 1} on {int(diff[:, i].sum())} of {int(n_far[i])}" for i in axes)
    return (f" (the T bit differs at {which} targets: the controller's axis may turn the other way than the robot "
            f"file's joint; check --axis-signs, now {','.join(f'{v:g}' for v in s)})")
