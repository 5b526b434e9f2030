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
* The walk (:func:`check_walk`): a target without configuration data is executed on the nominal solution
  of its written command (the literal as written, rounded) nearest the joints the robot is at (the joint
  move before it, else the previous target's compensated joints; a KRL continuous-path motion among those
  with the status ``S`` it is in). Where that is not ``q`` and the model's robot there misses the target by
  more than the tolerance (probe report s40: a URScript ``movel`` after ``movej`` at a joint limit, executed
  9 mm off), the target is solved again from the controller's solution, from those joints and from its walk
  hint (right after a joint move from those joints only, or a continuous-path motion's hint with the
  status: the target means that move's branch); where none gives the controller's choice it fails, saying
  so (noted instead where the miss is within the model's own accuracy, e.g. the other elbow a hair from
  the stretched elbow). The check goes target after target as the robot moves, so that a target solved
  again or a wrist taken a turn further changes where the next one is chosen from. A plain list of
  targets (CSV, :class:`.compensator.Compensator` without hints) is checked the same way
  (:class:`WalkRow`); its failed targets are not sent, so the robot stays at the one before.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3

__all__ = ["FIELDS", "WalkRow", "check_walk", "joint_gap", "landing", "configuration_changes", "keep_configuration", "take"]

#: the per-row fields of a :class:`.result.Compensation`
FIELDS = ("command", "q", "success", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg", "in_support", "q_branch",
          "reason")


@dataclass
class WalkRow:
    """Target ``start`` of a plain list (CSV rows, :class:`.compensator.Compensator` batches) as
    :func:`check_walk` sees a program's target: no configuration data, no joint move before it, the base
    frame, executed in list order (named by its 0-based index, as the CSV's ``target`` column)."""

    start: int
    config: dict = field(default_factory=dict)
    reset: np.ndarray | None = None  # the first: the joints the walk starts from
    frame: None = None
    order: None = None

    @property
    def line(self) -> int:
        return self.start


def _named(t) -> str:
    """How a reason names target ``t``: its program line, or a list's target index."""
    return f"target {t.start}" if isinstance(t, WalkRow) else f"line {t.line}"


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
    rev = np.array([t == "revolute" for t in nom.independent_joint_type])
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
_SWEEP_NEAR_RAD = np.radians(10.0)
_SWEEP_STEP_DEG = 30.0


def _wrist_sweep(model, solve, targets: list, comp, rows: np.ndarray, axis_signs, slack_rad: float) -> None:
    """In place: the configuration ``rows`` whose hint lies near the wrist singularity (``|q5|`` under 10°)
    solved again from hints with the A4/A6 split turned in 30° steps (q4 + δ, q6 ∓ δ: the same flange
    orientation at q5 = 0). Near it the hint's split is the closed form's arbitrary choice, and the real
    robot's solutions (a non-spherical wrist: discrete ones) can lie 90° along that valley, farther than a
    solve slides (probe report s40: a target taught at A5 = 0 failed with 0.47 mm residual)."""
    from ..kinematics.fk import fk_frames

    nom = model.nominal
    if nom.dof < 6:
        return
    h = comp.q_branch[rows]
    rows = rows[np.isfinite(h).all(1) & (np.abs(np.nan_to_num(h[:, 4])) < _SWEEP_NEAR_RAD)]
    if not rows.size:
        return
    h = comp.q_branch[rows]
    z = fk_frames(nom, h).joint[:, :, :3, 2]
    same = np.sign(np.sum(z[:, 3] * z[:, 5], -1))  # axes 4 and 6 aligned (+1) or opposed (-1) at q5 = 0
    steps = np.arange(1, int(180 / _SWEEP_STEP_DEG) + 1) * _SWEEP_STEP_DEG
    deltas = np.radians([d for a in steps for d in ((a, -a) if a < 180 else (a,))])  # 30, -30, 60, ..., 180
    H = np.repeat(h, len(deltas), axis=0)
    r = np.repeat(rows, len(deltas))
    d = np.tile(deltas, len(rows))
    H[:, 3] += d
    H[:, 5] -= np.repeat(same, len(deltas)) * d
    rev = np.array([t == "revolute" for t in nom.independent_joint_type])
    H = np.where(rev, (H + np.pi) % (2 * np.pi) - np.pi, H)  # the representation nearest zero, then the one T names
    H = np.clip(_turns(model, targets, r, H, axis_signs), nom.lower, nom.upper)
    again = solve(r, H)
    again.q = _turns(model, targets, r, again.q, axis_signs)
    good = again.success & _acceptable(model, targets, r, again.q, axis_signs, slack_rad)
    for j, k in enumerate(rows):
        i = np.flatnonzero(good[j * len(deltas):(j + 1) * len(deltas)])
        if i.size:  # the smallest turn of the split that reaches it with the program's configuration
            for name in FIELDS:
                getattr(comp, name)[k] = getattr(again, name)[j * len(deltas) + i[0]]


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
            comp.reason[k] = (f"{d[4]}; {r}{hint}" if has_s else
                              f"no solution with the program's configuration data (S {S0}); {rs}{hint}")
            comp.success[k] = False
            for name in ("q", "command", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg"):
                getattr(comp, name)[k] = np.nan
            comp.in_support[k] = False
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
    for k in ok:
        cfg = targets[k].config
        if "conf" in cfg:
            got = int(_abb_cfx(model, comp.q[k], axis_signs))
            if other_flag[k]:
                flag.append(f"{targets[k].line}" + (f" (cfx {cfg['conf'][3]} -> {got})" if got != cfg["conf"][3] else ""))
            elif got != cfg["conf"][3]:
                abb.append(f"{targets[k].line} (cfx {cfg['conf'][3]} -> {got})")
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
    if turn:
        notes.append(f"{turn[0].split(' ')[0]}: {len(turn)} targets ({lst(turn)}) have an axis within 1° of 0° that "
                     "the correction moves across 0° (its compensated angle given): their T is rewritten to the "
                     "compensated joints' (the taught T would turn that axis by a full turn or find no solution)")
    return notes


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


# ----------------------------------------------------------------------------- the walk

class _Picks:
    """The controller's choices for written commands ``T_world`` ``(M, 4, 4)`` (their TCP in the nominal
    robot's world): every nominal solution solved once, then :meth:`from_joints` for any joints the robot
    stands at (``keep`` ``(M,)``: a continuous-path motion, among the solutions with that status ``S``)."""

    def __init__(self, nom, T_world: np.ndarray, keep: np.ndarray, axis_signs):
        from ..kinematics.ik import ik
        from .branches import Candidates

        br = ik(nom, T_world, all_branches=True)
        self.Q = np.asarray(br.q, dtype=np.float64).reshape(len(T_world), -1, nom.dof)
        self.OK = np.asarray(br.success, dtype=bool).reshape(len(T_world), -1)
        self.cand = Candidates(nom, self.Q, self.OK)
        self.nom, self.keep, self.axis_signs = nom, np.asarray(keep, dtype=bool), axis_signs

    def one(self, i: int, cur: np.ndarray) -> np.ndarray:
        """Command ``i``'s nominal solution nearest ``cur`` ``(n,)``; NaN where none lies within the limits."""
        from .branches import nearest_candidate
        from .program_branches import same_status

        if not self.keep[i]:
            pick = self.cand.nearest(i, cur) if np.isfinite(cur).all() else None
        else:
            allowed = self.OK[i]
            if allowed.any():
                allowed = same_status(self.nom, self.Q[i], allowed, cur, self.axis_signs)
            pick = nearest_candidate(self.nom, self.Q[i], allowed, cur) if allowed.any() else None
        return np.full(self.nom.dof, np.nan) if pick is None else pick

    def from_joints(self, cur: np.ndarray) -> np.ndarray:
        """``(M, n)``: each command's solution nearest ``cur`` ``(M, n)`` (all rows at once: a CSV walk checks
        thousands)."""
        out = self.cand.nearest_each(cur)
        for i in np.flatnonzero(self.keep):
            out[i] = self.one(i, cur[i])
        return out


def _controller_picks(nom, T_world: np.ndarray, cur: np.ndarray, keep: np.ndarray, axis_signs) -> np.ndarray:
    """The nominal solution of ``T_world`` ``(M, 4, 4)`` (the written command's TCP in the nominal robot's
    world) nearest ``cur`` ``(M, n)``, as the controller picks it for a command without configuration data
    (``keep``: among those with ``cur``'s status ``S``); NaN rows where none lies within the limits."""
    return _Picks(nom, T_world, keep, axis_signs).from_joints(cur)


def _read_back(nom, targets: list, rows: np.ndarray, command: np.ndarray, D: np.ndarray, written) -> np.ndarray:
    """``(M, 4, 4)``: what the controller solves for the commands ``command`` of ``rows`` (controller base
    frame, the program's TCP ``D``): the literal as written (``written(t, literal)``, the format's rounding;
    None: exact), back in the controller's base, as the robot file's TCP in the nominal robot's world."""
    command = np.asarray(command, dtype=np.float64)
    if written is None and all(targets[k].frame is None for k in rows):  # a list: all rows at once
        C = np.where(np.isfinite(command).all((1, 2))[:, None, None], np.nan_to_num(command), np.eye(4))
        return nom.base @ C @ se3.invert(np.asarray(D)[rows])
    out = np.empty((len(rows), 4, 4))
    for j, k in enumerate(rows):
        W = targets[k].frame
        C = np.nan_to_num(command[j]) if np.isfinite(command[j]).all() else np.eye(4)
        if written is not None:
            L = C if W is None else se3.invert(W) @ C
            L = written(targets[k], L)
            C = L if W is None else W @ L
        out[j] = nom.base @ C @ se3.invert(D[k])
    return out


def check_walk(model, compensator, solve, targets: list, comp, alt_hint: np.ndarray, T: np.ndarray, D, Dm, axis_signs,
               written=None, T_nominal: np.ndarray | None = None) -> list:
    """Check (in place) that the controller executes each compensated target without configuration data
    at its compensated joints (module docstring), target after target in execution order as the robot
    moves: each from the joints it stands at (a joint move before it; else the previous target's
    compensated joints, which the check may just have changed; for a list of :class:`WalkRow` targets the
    last one sent: a failed target's NaN command is not). Where the controller's choice is the compensated
    joints a full turn away on some axis, those are taken (the same pose; the next target is chosen from
    them). Where it is another solution that misses, the target is solved again from the controller's
    choice, from the nominal solution of ``T_nominal`` ``(N, 4, 4)`` (the uncompensated targets' TCP in the
    nominal robot's world) nearest the joints the robot is at, from those joints and from ``alt_hint``
    ``(N, n)`` (the walk's hint). Those the controller still executes elsewhere fail where the model's robot
    lands there farther from the target than the model's own accuracy
    (:func:`hykin.hybrid.ik_result.model_accuracy`, at least the tolerance), and are noted where it lands
    within it (returns the notes). ``compensator``: the :class:`.compensator.Compensator` whose tolerance
    judges a landing; ``D``, ``Dm``: the targets' tools relative to the robot file's and the model's TCP;
    ``written(target, literal)``: the pose the controller reads from the written literal (the format's
    rounding; :func:`.urscript.written_pose`). ``solve(rows, hints)``: a :class:`.result.Compensation` of
    those rows."""
    from ..hybrid.ik_result import model_accuracy
    from .program_branches import execution_order

    N = len(targets)
    free = np.array([not ("S" in t.config or "conf" in t.config) for t in targets], dtype=bool)
    if not free.any():
        return []
    order = execution_order(targets)
    keep = np.array([bool(t.config.get("keep_status")) for t in targets], dtype=bool)
    listed = isinstance(targets[0], WalkRow)
    nom = model.nominal
    Tm = compensator.model_targets(T, Dm)
    acc = max(compensator.tolerance_mm, model_accuracy(model)[0] or 0.0)
    # every command's controller choice from the joints the robot stands at as compensated so far, at once;
    # the walk below revisits only rows whose standing joints it changes or whose choice differs
    cur0, _, _ = _standing(targets, comp, order, listed)
    rows = np.flatnonzero(free & comp.success)
    picks = _Picks(nom, _read_back(nom, targets, rows, comp.command[rows], D, written), keep[rows], axis_signs)
    pos = np.full(N, -1)
    pos[rows] = np.arange(len(rows))
    pick0 = np.full(comp.q.shape, np.nan)
    pick0[rows] = picks.from_joints(cur0[rows])
    same = np.zeros(N, dtype=bool)
    same[rows] = np.abs(np.nan_to_num(pick0[rows], nan=np.inf) - comp.q[rows]).max(1) <= 1e-6
    # not the controller's choice right after a joint move: the target means the branch of those joints (where
    # the written literal's rounding lost it, the controller's is another one, landing only after a
    # reconfiguration the move cannot make); nor the walk's hint there (the nominal solution of the
    # uncompensated target nearest the move's joints: at a limit or a singular pose another branch), but for a
    # continuous-path motion, whose hint is the one with the status the robot is in
    after_move = np.array([t.reset is not None and not isinstance(t, WalkRow) for t in targets], dtype=bool)
    noted, prev = [], -1
    for k in order:
        t = targets[k]
        if t.reset is not None:
            cur, where = np.asarray(t.reset, dtype=np.float64), "the joint move before it"
        elif prev >= 0 and comp.success[prev]:
            cur, where = comp.q[prev].copy(), f"the previous target's ({_named(targets[prev])})"
        else:
            cur, where = None, ""
        if free[k] and comp.success[k] and cur is not None and (not same[k] or not np.array_equal(cur, cur0[k])):
            pick = picks.one(pos[k], cur) if pos[k] >= 0 else np.full(nom.dof, np.nan)
            miss = _walk_miss(model, compensator, comp, k, pick, Tm)
            if miss > 0:
                hints = [] if after_move[k] else [pick]
                if T_nominal is not None and not after_move[k]:
                    hints.append(_Picks(nom, T_nominal[k][None], keep[k:k + 1], axis_signs).one(0, cur))
                hints += [cur] + ([] if after_move[k] and not keep[k] else [alt_hint[k]])
                for h in hints:
                    if not np.isfinite(h).all() or np.all(np.abs(h - comp.q_branch[k]) < 1e-9):
                        continue
                    again = solve(np.array([k]), h[None])
                    if not again.success[0]:
                        continue
                    p2 = _controller_picks(nom, _read_back(nom, targets, np.array([k]), again.command, D, written),
                                           cur[None], keep[k:k + 1], axis_signs)[0]
                    if _misses(model, compensator, again.q, p2[None], Tm[k][None])[0] == 0:
                        take(comp, np.array([k]), again, np.ones(1, dtype=bool))
                        _walk_miss(model, compensator, comp, k, p2, Tm)  # a turned choice: taken
                        miss = 0.0
                        break
            if miss > acc:
                comp.reason[k] = _walk_reason(model, compensator, targets, comp, k, cur, where, keep[k], Tm[k], D,
                                              written, axis_signs)
                comp.success[k] = False
                for name in ("q", "command", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg"):
                    getattr(comp, name)[k] = np.nan
                comp.in_support[k] = False
            elif miss > 0:  # within what the model can tell: the command stands, said
                noted.append(f"{targets[k].line} ({miss:.3g} mm)")
        if not (listed and not comp.success[k]):
            prev = k
    if not noted:
        return []
    lines = ", ".join(noted[:8]) + (" ..." if len(noted) > 8 else "")
    head = "" if listed else f"{noted[0].split(' ')[0]}: "
    return [f"{head}{len(noted)} targets ({'targets' if listed else 'lines'} {lines}) "
            "are executed by the controller on another solution of their command than the compensated joints (the "
            "nominal solution nearest the joints the robot is at, e.g. the other elbow at the stretched elbow): the "
            f"model's robot lands there within its accuracy ({acc:.3g} mm) of the target, by the amounts given"]


def _walk_miss(model, compensator, comp, k: int, pick: np.ndarray, Tm: np.ndarray) -> float:
    """How far the controller's choice ``pick`` ``(n,)`` for target ``k`` misses (:func:`_misses`); where it is
    the compensated joints a full turn away on some axis, those are taken (in place) and it does not miss."""
    if _same_but_turned(model.nominal, comp.q[k][None], pick[None])[0]:
        comp.q[k] = pick
        return 0.0
    return float(_misses(model, compensator, comp.q[k][None], pick[None], Tm[k][None])[0])


def _same_but_turned(nom, q: np.ndarray, pick: np.ndarray) -> np.ndarray:
    """``(M,)`` bool: ``pick`` is ``q`` with some revolute joint a multiple of 2π away (and not ``q`` itself)."""
    rev = np.array([t == "revolute" for t in nom.independent_joint_type])
    d = np.nan_to_num(pick - q, nan=np.inf)
    with np.errstate(invalid="ignore"):  # inf (no pick) % 2π is NaN: such rows are not finite below
        wrapped = np.where(rev, (d + np.pi) % (2 * np.pi) - np.pi, d)
    return np.isfinite(d).all(1) & (np.abs(wrapped).max(1) < 1e-6) & (np.abs(d).max(1) > 1e-6)


def _standing(targets: list, comp, order: list, listed: bool = False) -> tuple[np.ndarray, list, np.ndarray]:
    """``(joints (N, n), where (N,), prev (N,))``: the joints the robot is at before each target (NaN where
    not known: after a target that failed), a text saying whose they are, and the target they are of (-1:
    a joint move, or not known)."""
    N, n = comp.q.shape
    cur, where, before = np.full((N, n), np.nan), [""] * N, np.full(N, -1)
    prev = None
    for k in order:
        t = targets[k]
        if t.reset is not None:
            cur[k], where[k] = np.asarray(t.reset, dtype=np.float64), "the joint move before it"
        elif prev is not None and comp.success[prev]:
            cur[k], where[k], before[k] = comp.q[prev], f"the previous target's ({_named(targets[prev])})", prev
        # a list's failed target is not sent (its command is NaN): the robot stays at the one before
        if not (listed and not comp.success[k]):
            prev = k
    return cur, where, before


#: a landing of the controller's joints this close (mm, deg) to the target is the target: 10 times what the
#: rounding of a written literal (URScript 1e-7 m; KRL 1e-4 mm, 1e-5°) moves a pose
_WRITTEN_MM, _WRITTEN_DEG = 1e-3, 1e-4


def _misses(model, compensator, q: np.ndarray, pick: np.ndarray, Tm: np.ndarray) -> np.ndarray:
    """``(M,)``: 0 where the controller's pick is ``q`` (1e-6 rad) or the model's robot at it reaches the
    target ``Tm`` (measurement frame) within the compensator's tolerance (at least :data:`_WRITTEN_MM` /
    :data:`_WRITTEN_DEG`); else the miss (mm; inf: no pick;
    an orientation miss alone counts as the tolerance's mm times its factor over the degree tolerance)."""
    out = np.zeros(len(q))
    none = ~np.isfinite(pick).all(1)
    out[none] = np.inf
    other = np.flatnonzero(~none & (np.abs(np.nan_to_num(pick) - q).max(1) > 1e-6))
    if other.size:
        pe, ae = landing(model, pick[other], Tm[other])
        # at least what the written literal's rounding moves a pose by (0.1 µm, 1e-8 rad: near a singular
        # pose the controller's joints follow it by more than 1e-6 rad)
        tm, td = max(compensator.tolerance_mm, _WRITTEN_MM), max(compensator.tolerance_deg, _WRITTEN_DEG)
        far = (pe > tm) | (ae > td)
        out[other[far]] = np.maximum(pe[far], tm * ae[far] / td)
    return out


def joint_gap(nom, a: np.ndarray, b: np.ndarray) -> str:
    """How far joints ``a`` are from ``b`` ``(n,)``: the largest revolute difference in degrees, and the
    largest prismatic one in mm where the arm has such joints (a rail)."""
    d = np.abs(np.asarray(a, dtype=np.float64) - np.asarray(b, dtype=np.float64))
    rev = np.array([t == "revolute" for t in nom.independent_joint_type])
    parts = ([f"{np.degrees(d[rev].max()):.1f}°"] if rev.any() else []) + \
        ([f"{d[~rev].max() * 1e3:.1f} mm"] if (~rev).any() else [])
    return " / ".join(parts)


def landing(model, q: np.ndarray, Tm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(mm, deg)``: the model's pose at ``q`` to the targets ``Tm`` (measurement frame)."""
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # out of the training support: the number is still the model's
        P = np.asarray(model.predict(q), dtype=np.float64).reshape(-1, 4, 4)
    pe, ae = se3.pose_error(P, Tm)
    return np.asarray(pe, dtype=np.float64), np.asarray(ae, dtype=np.float64)


def _walk_reason(model, compensator, targets, comp, k, cur, where, keep, Tm, D, written, axis_signs) -> str:
    """Why target ``k`` fails the walk check: where the controller would go instead, and how far off."""
    nom, q = model.nominal, comp.q[k]
    rk = np.array([k])
    pick = _controller_picks(nom, _read_back(nom, targets, rk, comp.command[rk], D, written), cur[None],
                             np.array([keep]), axis_signs)[0]
    exact = _controller_picks(nom, _read_back(nom, targets, rk, comp.command[rk], D, None), cur[None],
                              np.array([keep]), axis_signs)[0]
    rounding = ""
    if written is not None and np.isfinite(exact).all() and not _misses(model, compensator, q[None], exact[None],
                                                                          Tm[None])[0]:
        rounding = (" (the written literal's rounding moves the command across this singular pose for the nominal "
                    "robot: the compensated joints' solution is lost)")
    fix = "send the compensated joints instead (--joints) or move to joints on the wanted branch before it"
    if not np.isfinite(pick).all():
        return (f"the controller has no nominal solution of the written command within the joint limits (the "
                f"compensated joints are {joint_gap(nom, q, cur)} from the joints the robot is at, "
                f"{where}){rounding}; {fix}")
    pe, _ = landing(model, pick[None], Tm[None])
    return (f"the controller would execute it on another branch: its nominal solution of the written command "
            f"nearest the joints the robot is at ({where}) is {joint_gap(nom, pick, q)} from the "
            f"compensated joints and lands {pe[0]:.3g} mm from the target{rounding}; no solution of the model's robot "
            f"that the controller executes reaches it within the tolerance {compensator.tolerance_mm:.3g} mm: {fix}")
