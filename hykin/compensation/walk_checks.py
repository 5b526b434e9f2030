"""The walk: targets without configuration data as the controller executes them, checked before they
are written or sent.

A target without configuration data is executed on the nominal solution
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
from .program_checks import take
from .result import fail_row

__all__ = ["WalkRow", "check_walk", "joint_gap", "landing", "same_but_turned", "take_other_branches"]


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
    cur0 = _standing(targets, comp, order, listed)
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
        elif (p := _before(t, prev)) >= 0 and comp.success[p]:
            cur, where = comp.q[p].copy(), f"the previous target's ({_named(targets[p])})"
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
                fail_row(comp, k, _walk_reason(model, compensator, targets, comp, k, cur, where, keep[k], Tm[k], D,
                                               written, axis_signs))
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
    if same_but_turned(model.nominal, comp.q[k][None], pick[None])[0]:
        comp.q[k] = pick
        return 0.0
    return float(_misses(model, compensator, comp.q[k][None], pick[None], Tm[k][None])[0])


def same_but_turned(nom, q: np.ndarray, pick: np.ndarray) -> np.ndarray:
    """``(M,)`` bool: ``pick`` is ``q`` with some revolute joint a multiple of 2π away (and not ``q`` itself)."""
    rev = nom.revolute
    d = np.nan_to_num(pick - q, nan=np.inf)
    with np.errstate(invalid="ignore"):  # inf (no pick) % 2π is NaN: such rows are not finite below
        wrapped = np.where(rev, (d + np.pi) % (2 * np.pi) - np.pi, d)
    return np.isfinite(d).all(1) & (np.abs(wrapped).max(1) < 1e-6) & (np.abs(d).max(1) > 1e-6)


def _before(t, prev: int) -> int:
    """The target the robot moves to just before ``t``: its ``after`` (a program's target moved to again),
    else ``prev``, the one before in execution order (-1: none)."""
    after = getattr(t, "after", None)
    return prev if after is None else int(after)


def _standing(targets: list, comp, order: list, listed: bool = False) -> np.ndarray:
    """``(N, n)``: the joints the robot is at before each target as compensated so far (NaN where not known:
    after a target that failed; a list's failed target is not sent, so the robot stays at the one before)."""
    cur, prev = np.full(comp.q.shape, np.nan), None
    for k in order:
        t = targets[k]
        p = _before(t, -1 if prev is None else prev)
        if t.reset is not None:
            cur[k] = np.asarray(t.reset, dtype=np.float64)
        elif p >= 0 and comp.success[p]:
            cur[k] = comp.q[p]
        if not (listed and not comp.success[k]):
            prev = k
    return cur


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
    rev = nom.revolute
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


def take_other_branches(compensator, comp, T: np.ndarray, Dm, solve) -> None:
    """In place, before the walk's check: a target refused as unreachable for the model on the walk's branch
    (not out of reach) that the model's robot reaches on another branch (the calibrated robot's solutions as
    seeds) is taken on that branch (near a tie of two branches: at a stretched elbow the nominal solution
    nearest the target before can be the other elbow, where the model misses by tenths of a millimetre); the
    check then decides whether the controller executes it there (probe s42 AV: 19 of 60 stretched-elbow targets
    were refused as unreachable, some of which a nearest-joints controller executes right). ``solve(rows,
    hints)``: a :class:`.result.Compensation` of those rows."""
    from ..kinematics.ik import ik
    from .program_checks import take

    rows = np.array([k for k, r in enumerate(comp.reason) if str(r).startswith("unreachable for the model: residual")],
                    dtype=np.int64)
    if not rows.size:
        return
    Tm = compensator.model_targets(T[rows], None if Dm is None else Dm[rows])
    br = ik(compensator.robot, compensator.robot_world(Tm), all_branches=True)
    Q = np.asarray(br.q, dtype=np.float64).reshape(len(rows), -1, compensator.dof)
    OK = np.asarray(br.success, dtype=bool).reshape(len(rows), -1)
    for j, k in enumerate(rows):
        for qs in Q[j][OK[j]]:
            if np.abs(qs - comp.q_branch[k]).max() < 1e-3:
                continue
            again = solve(np.array([k]), qs[None])
            if again.success[0]:
                take(comp, np.array([k]), again, np.ones(1, dtype=bool))
                break
