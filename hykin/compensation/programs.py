"""Rewriting robot programs in place: the part shared by URScript, KRL and RAPID.

A format module finds the Cartesian targets of a program (:class:`ProgramTarget`: the character span
of the literal, the pose in the controller's base frame, the configuration data it carries) and
formats a compensated literal; :func:`compensate_program` solves all targets in one batch and splices
the new literals into the text. Every character outside the replaced literals is kept, so every line
without a target is byte for byte the same (files are read and written as latin-1, which maps every
byte to one character and back).

Branches: a target with configuration data (KUKA ``S``/``T``, ABB ``confdata``) gets the nominal
solution matching it; a target without gets the nominal solution nearest the previous target's
(a controller moving through the program in text order), restarting from the joints of the last
joint-space move before it when the format has those. Where the nominal robot has no such solution,
the calibrated robot's is taken (the nominal model only hints; the hybrid model is solved); where
that has none either only because the target lies within ``config_slack_deg`` of a singular pose
(stretched elbow, wrist centre on axis 1), the calibrated robot's with that flag flipped, with a note.
A target without configuration data that neither reaches starts from the previous joints. Control flow
(loops, branches, calls) is not followed: text order stands for execution order.

Unreachable targets: :class:`ProgramResult` lists them (line, reason); the caller refuses to write
the program (default) or keeps their original literal and warns (``skip_unreachable``).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3
from .compensator import compensate, model_delta
from .result import Compensation

__all__ = ["NUMBER", "ProgramResult", "ProgramTarget", "TargetFrames", "comment_mask", "compensate_program", "line_of",
           "splice_numbers"]

NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
# a calibrated robot's singular poses (stretched elbow, wrist centre on axis 1) lie a fraction of a
# degree from the nominal's (joint offsets, link lengths): within this angle of one, a target may be
# reachable with one value of that configuration flag only
CONFIG_SLACK_DEG = 1.0


@dataclass
class ProgramTarget:
    """One Cartesian target of a program.

    start, end: character span of the literal to replace. line: 1-based line number.
    pose: ``(4, 4)`` wanted TCP pose in the controller's base frame (m).
    name: variable name (``""`` for an inline literal). kind: e.g. ``"p[]"``, ``"E6POS"``, ``"robtarget"``.
    config: configuration data read from the program (``{"S": 6, "T": 27}``, ``{"conf": [0, 0, 0, 1]}``);
    ``{"keep_status": True}``: a KRL continuous-path target without ``S``, walked on the KUKA status the
    previous joints have.
    tool_delta: ``(4, 4)`` program TCP relative to the nominal tool (URScript ``set_tcp``) or None.
    frame: ``(4, 4)`` the frame the literal is written in, in the controller's base frame (RAPID work
    objects: ``pose = frame · literal``), or None (the base frame).
    error: why the target cannot be compensated before solving (an unknown work object ...), or ``""``.
    reset: joints ``(n,)`` of the last joint-space move before the target, or None.
    order: where the target is executed, as a sort key (a declared variable: the position of the first
    motion that uses it, e.g. in the ``.src`` of a ``.dat`` point), or None (the literal's ``start``);
    the walk of targets without configuration data goes in this order.
    caveat: an assumption made for the target that may explain a failure (an undeclared tool taken to be
    the robot file's), named in its failure reason; ``""`` for none.
    parts: format-specific parse (number spans and texts) used to write the literal back.
    """

    start: int
    end: int
    line: int
    pose: np.ndarray
    name: str = ""
    kind: str = ""
    config: dict = field(default_factory=dict)
    tool_delta: np.ndarray | None = None
    reset: np.ndarray | None = None
    parts: dict = field(default_factory=dict)
    frame: np.ndarray | None = None
    error: str = ""
    order: int | None = None
    caveat: str = ""


@dataclass
class TargetFrames:
    """The frames of a program's targets (RAPID :mod:`.rapid_frames`, KRL :mod:`.krl_frames`), one entry
    per target: ``frame`` ``(4, 4)`` or None (the base frame), ``tool_delta`` ``(4, 4)`` or None (the
    robot file's tool), ``error`` (``""``: resolved); ``notes`` for the program."""

    frame: list = field(default_factory=list)
    tool_delta: list = field(default_factory=list)
    error: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    caveat: dict = field(default_factory=dict)  # {target index: assumption made for it} (ProgramTarget.caveat)
    #: targets no motion moves to, in a program that moves with other frames than the base and the robot
    #: file's tool: their frames are not known (the caller keeps their literals)
    unknown_frames: list = field(default_factory=list)

    #: a use's tool delta when the use does not tell the tool (it agrees with any other use's)
    ANY_TOOL = "any"

    def add(self, uses: list, conflict: str) -> None:
        """Append one target from its uses ``[(frame, tool_delta, error, label)]`` (at least one): their
        common frames, or ``conflict`` (followed by the uses' labels) when they differ."""
        same = lambda a, b: (a is None and b is None) or (a is not None and b is not None and np.allclose(a, b, atol=1e-12))
        told = [u for u in uses if not isinstance(u[1], str)]
        W, err = uses[0][0], uses[0][2]
        D = told[0][1] if told else None
        for W2, D2, err2, _ in uses[1:]:
            err = err or err2
            if not (same(W, W2) and (isinstance(D2, str) or same(D, D2))):
                err = f"{conflict} ({', '.join(u[3] for u in uses)}): one literal cannot be compensated for both"
                break
        self.frame.append(W)
        self.tool_delta.append(D)
        self.error.append(err)

    def apply(self, targets: list) -> list:
        """Set each target's frame, tool delta and error, its pose to ``frame · literal``; returns the notes."""
        for k, (t, W, D, err) in enumerate(zip(targets, self.frame, self.tool_delta, self.error)):
            t.frame, t.tool_delta, t.error = W, D, err
            t.caveat = self.caveat.get(k, t.caveat)
            if W is not None:
                t.pose = W @ t.pose
        return self.notes


@dataclass
class ProgramResult:
    """text: the rewritten program. targets: the targets found. comp: their :class:`Compensation`.
    failed: ``[(line, reason)]`` of unreachable targets (their literal is kept). notes: literals seen but
    not compensated, with why (relative moves, partial aggregates, tool/base frames ...)."""

    text: str
    targets: list
    comp: Compensation | None
    failed: list
    notes: list

    @property
    def n_compensated(self) -> int:
        return 0 if self.comp is None else int(self.comp.success.sum())


def line_of(text: str, pos: int) -> int:
    """1-based line number of character ``pos`` (a search in the text's newline offsets, found once per
    text: a program of 10,000 targets asks 10,000 times)."""
    return int(np.searchsorted(_newlines(text), pos)) + 1


@functools.lru_cache(maxsize=8)
def _newlines(text: str) -> np.ndarray:
    return np.array([m.start() for m in re.finditer("\n", text)], dtype=np.int64)


def comment_mask(text: str, comment: str, quote: str = '"') -> np.ndarray:
    """Bool per character: inside a comment (``comment`` to end of line) or a string literal."""
    mask = np.zeros(len(text) + 1, dtype=bool)
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if c == comment:
            j = text.find("\n", i)
            j = n if j < 0 else j
            mask[i:j] = True
            i = j
        elif c == quote:
            j = text.find(quote, i + 1)
            k = text.find("\n", i + 1)
            j = n if j < 0 else j
            j = min(j, k) if k >= 0 else j
            mask[i : j + 1] = True
            i = j + 1
        else:
            i += 1
    return mask


def _branch_joints(model, targets: list, Tm: np.ndarray, T_cal: np.ndarray, axis_signs,
                   slack_rad: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joints ``(N, n)`` choosing each target's branch (module docstring): the nominal solution that the
    configuration data (or the walk) mean; where the nominal robot has none, the calibrated robot's
    (targets ``T_cal`` in its world), and where that has none either, the calibrated robot's with the
    other elbow / overhead flag within ``slack_rad`` of that flag's singular pose (:mod:`.branches`); a
    target without configuration data and no solution on either takes the previous joints (the hybrid
    model decides). NaN only where configuration data match nothing. Also returns the rows that took
    another flag ``(N,)`` bool and, for the NaN rows, why ``(N,)`` (:func:`_unmatched_reasons`)."""
    from ..kinematics.ik import ik
    from .branches import default_axis_signs, match_abb_confdata, match_kuka_status, nearest_candidate

    nom = model.nominal
    N, n = len(targets), nom.dof
    qb = np.full((N, n), np.nan)
    has_s = np.array(["S" in t.config for t in targets], dtype=bool)
    has_c = np.array(["conf" in t.config for t in targets], dtype=bool)
    signs_cal = default_axis_signs(nom) if axis_signs is None else axis_signs
    passes = ((nom, Tm, axis_signs, 0.0), (model.robot_, T_cal, signs_cal, 0.0))
    if slack_rad > 0:
        passes += ((model.robot_, T_cal, signs_cal, slack_rad),)
    for rob, TT, signs, slack in passes:
        open_before = ~np.isfinite(qb).all(1)
        i = np.flatnonzero(has_s & open_before)
        if i.size:
            qb[i] = match_kuka_status(rob, TT[i], [targets[k].config["S"] for k in i],
                                      [targets[k].config.get("T", -1) for k in i], signs, slack)
        i = np.flatnonzero(has_c & open_before)
        if i.size:  # the calibrated robot names forward as the nominal does (branches.abb_confdata)
            qb[i] = match_abb_confdata(rob, TT[i], np.array([targets[k].config["conf"] for k in i]),
                                       axis_signs, reference=nom, slack_rad=slack)
    other_flag = (has_s | has_c) & open_before & np.isfinite(qb).all(1) if slack_rad > 0 else np.zeros(N, bool)
    free = np.flatnonzero(~has_s & ~has_c)
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
        for k in sorted(range(N), key=lambda k: (targets[k].start if targets[k].order is None else targets[k].order, k)):
            j = slot.get(k)
            if j is not None:
                if targets[k].reset is not None:
                    cur = np.asarray(targets[k].reset, dtype=np.float64)
                elif prev is not None and np.isfinite(qb[prev]).all():
                    cur = qb[prev]
                pick = None
                for (rob, q, ok), signs in zip(sols, (axis_signs, signs_cal)):
                    allowed = ok[j]
                    if targets[k].config.get("keep_status") and allowed.any():
                        allowed = _same_status(rob, q[j], allowed, cur, signs)
                    pick = nearest_candidate(rob, q[j], allowed, cur) if allowed.any() else None
                    if pick is not None:
                        break
                qb[k] = cur if pick is None else pick
            prev = k
    return qb, other_flag, _unmatched_reasons(model, targets, T_cal, ~np.isfinite(qb).all(1), axis_signs, signs_cal)


def _same_status(rob, q: np.ndarray, ok: np.ndarray, cur: np.ndarray, signs) -> np.ndarray:
    """``ok`` ``(K,)`` narrowed to the solutions ``q`` ``(K, n)`` with the KUKA status ``S`` of the
    joints ``cur`` (a continuous-path motion keeps it); ``ok`` itself where none has it (the motion would
    cross a singularity: the nearest solution stands)."""
    from .branches import kuka_status

    S = kuka_status(rob, np.vstack([cur[None], np.nan_to_num(q)]), signs)[0]
    same = ok & (S[1:] == S[0])
    return same if same.any() else ok


def _unmatched_reasons(model, targets: list, T_cal: np.ndarray, rows: np.ndarray, axis_signs, signs_cal) -> np.ndarray:
    """``(N,)`` why each of ``rows`` has no branch: its configuration data and those the real robot (the
    calibrated chain; targets ``T_cal``) has solutions with within its limits, or that it has none."""
    from .branches import abb_confdata, candidate_solutions, kuka_status

    why = np.full(len(targets), "", dtype=object)
    i = np.flatnonzero(rows)
    if not i.size:
        return why
    rob, nom = model.robot_, model.nominal
    q, ok = candidate_solutions(rob, T_cal[i])
    M, K, n = q.shape
    qz = np.nan_to_num(q.reshape(-1, n))
    S = kuka_status(rob, qz, signs_cal)[0].reshape(M, K)
    cfx = abb_confdata(rob, qz, axis_signs, reference=nom)[:, 3].reshape(M, K)
    for r, k in enumerate(i):
        cfg = targets[k].config
        name, want, have = ("S", cfg["S"], S[r]) if "S" in cfg else ("cfx", cfg["conf"][3], cfx[r])
        found = sorted({int(v) for v in have[ok[r]]})
        why[k] = (f"no solution with the program's configuration data ({name} {want}); " + (
            f"the real robot reaches it with {name} {', '.join(str(v) for v in found)}" if found else
            "the real robot reaches it in no configuration within its joint limits"))
    return why


def compensate_program(model, text: str, fmt, *, frame: str = "auto", axis_signs=None, context: str = "",
                       config_slack_deg: float = CONFIG_SLACK_DEG, flange: str | None = None, **ik_kw) -> ProgramResult:
    """Compensate every Cartesian target of ``text`` (a program in format module ``fmt``: one of
    :mod:`.urscript`, :mod:`.krl`, :mod:`.rapid`). ``context``: text of a companion file (KRL: the
    ``.src`` beside a ``.dat``, whose motion statements tell which variables are targets; RAPID: modules
    declaring the ``tooldata``/``wobjdata`` the program uses).
    ``frame``: how program poses map into the model's measurement frame (:mod:`.targets`).
    ``config_slack_deg``: a target whose configuration data the real robot cannot meet only because
    its elbow is within this angle of stretched (the reach boundary) or its wrist centre of axis 1 takes
    the other elbow / overhead flag, with a note; 0 refuses it (:mod:`.branches`).
    ``flange``: the URDF link the program's tools are given from (:func:`hykin.io.urdf_flange.choose_flange`:
    default ``flange`` for KRL, ``tool0`` otherwise, where the URDF has them).
    Returns a :class:`ProgramResult`; unreachable targets keep their literal and are listed in ``failed``.
    """
    from ..io.urdf_flange import choose_flange

    if not (config_slack_deg >= 0 and config_slack_deg <= 90):
        raise ValueError(f"config_slack_deg must be within 0-90 deg, got {config_slack_deg}")
    robot, fl_note = choose_flange(model.nominal, fmt.__name__.rsplit(".", 1)[-1], flange)
    targets, notes = fmt.find_targets(text, robot, context=context, axis_signs=axis_signs)
    if fl_note and any(t.tool_delta is not None for t in targets):  # said only where a program tool was used
        notes = [f" {fl_note}", *notes]
    if not targets:
        return ProgramResult(text=text, targets=[], comp=None, failed=[], notes=notes)
    ok = [k for k, t in enumerate(targets) if not t.error]
    comp = None
    if ok:
        comp, other = _solve(model, [targets[k] for k in ok], frame, axis_signs, np.radians(config_slack_deg), ik_kw)
        moved = [targets[k] for k, o in zip(ok, other) if o and comp.success[ok.index(k)]]
        if moved:
            lines = ", ".join(str(t.line) for t in moved[:8]) + (" ..." if len(moved) > 8 else "")
            notes = [*notes, f"{moved[0].line}: {len(moved)} targets (lines {lines}) lie within "
                             f"{config_slack_deg:g}° of a singular pose (stretched elbow, wrist centre on axis 1), "
                             "where the real robot reaches them only with the other elbow / overhead flag: their "
                             "configuration data are rewritten to it (--config-slack-deg 0 refuses them)"]
    comp = _scatter(comp, ok, targets, model.nominal.dof, frame)
    if ok:
        notes = [*notes, *_config_notes(model, targets, comp, np.isin(np.arange(len(targets)), [
            k for k, o in zip(ok, other) if o]), axis_signs)]
    pieces, last, failed = [], 0, []
    for k, t in enumerate(targets):
        if not comp.success[k]:
            why = comp.reason[k] if not t.caveat or t.error else f"{t.caveat}; {comp.reason[k]}"
            failed.append((t.line, f"{t.name or t.kind}: {why}"))
            continue
        command = comp.command[k] if t.frame is None else se3.invert(t.frame) @ comp.command[k]
        new = fmt.format_target(t, command, comp.q[k], model.nominal, axis_signs)
        pieces.append(text[last : t.start])
        pieces.append(new)
        last = t.end
    pieces.append(text[last:])
    return ProgramResult(text="".join(pieces), targets=targets, comp=comp, failed=failed, notes=notes)


def _solve(model, targets: list, frame: str, axis_signs, slack_rad: float,
           ik_kw: dict) -> tuple[Compensation, np.ndarray]:
    """:class:`Compensation` of ``targets`` (all with known frames), branches as the program means them,
    and which targets took another configuration flag ``(N,)`` bool (:func:`_branch_joints`). A target
    with configuration data whose compensated joints left its flags (KUKA ``S``, ABB ``cfx``: the hybrid
    solution slid off a hint at a joint limit) is solved again from the calibrated robot's solution with
    those flags; kept where that reaches (:func:`_keep_flags`)."""
    from .frames import resolve_frame, to_model_frame

    T = np.stack([t.pose for t in targets])
    D = np.stack([np.eye(4) if t.tool_delta is None else t.tool_delta for t in targets])
    fr = resolve_frame(model, frame)
    # branch from the nominal solutions of the uncompensated target, in the nominal robot's world
    # (= the measurement frame; the controller base sits at nominal.base in it)
    T_nom = (T if fr == "measurement" else model.nominal.base @ T) @ se3.invert(D)
    given = np.array([t.tool_delta is not None for t in targets])  # a program tool (else the model's TCP)
    Dm = model_delta(model, D, given)
    T_cal = se3.invert(model.frame_pre_) @ to_model_frame(model, T, fr) @ se3.invert(Dm) @ se3.invert(model.frame_post_)
    qb, other_flag, reason = _branch_joints(model, targets, T_nom, T_cal, axis_signs, slack_rad)
    comp = compensate(model, T, q_branch=qb, frame=fr, tool_delta=D, branch_reason=reason, tool_given=given, **ik_kw)
    _keep_flags(model, targets, comp, other_flag, T, D, T_cal, fr, axis_signs, ik_kw, given)
    return comp, other_flag


def _flags(model, targets: list, q: np.ndarray, axis_signs) -> tuple[np.ndarray, np.ndarray]:
    """``(got, want)`` ``(N,)`` int: the configuration flag of joints ``q`` ``(N, n)`` that each target's
    configuration data fix exactly (KUKA ``S``, ABB ``cfx``; -1 for a target without) and the program's."""
    from .branches import abb_confdata, kuka_status

    nom = model.nominal
    qz = np.nan_to_num(np.asarray(q, dtype=np.float64))
    got, want = np.full(len(targets), -1), np.full(len(targets), -1)
    s = np.array(["S" in t.config for t in targets], dtype=bool)
    c = np.array(["conf" in t.config for t in targets], dtype=bool)
    if s.any():
        got[s] = kuka_status(nom, qz[s], axis_signs)[0]
        want[s] = [t.config["S"] for t in targets if "S" in t.config]
    if c.any():
        got[c] = abb_confdata(nom, qz[c], axis_signs)[:, 3]
        want[c] = [t.config["conf"][3] for t in targets if "conf" in t.config]
    return got, want


def _keep_flags(model, targets: list, comp: Compensation, other_flag: np.ndarray, T, D, T_cal, fr: str, axis_signs,
                ik_kw: dict, given: np.ndarray) -> None:
    """Re-solve (in place) the successful targets whose compensated joints lost the configuration flag
    their data fix (not those moved to the other flag on purpose, ``other_flag``) from the calibrated
    robot's solution with the program's data; a row is replaced where that succeeds on the taught flag."""
    from .branches import default_axis_signs, match_abb_confdata, match_kuka_status

    got, want = _flags(model, targets, comp.q, axis_signs)
    rows = np.flatnonzero(comp.success & (want >= 0) & (got != want) & ~other_flag)
    if not rows.size:
        return
    rob, nom = model.robot_, model.nominal
    signs = default_axis_signs(nom) if axis_signs is None else axis_signs
    hint = np.full((rows.size, nom.dof), np.nan)
    for j, k in enumerate(rows):
        cfg = targets[k].config
        if "S" in cfg:
            hint[j] = match_kuka_status(rob, T_cal[k:k + 1], [cfg["S"]], [cfg.get("T", -1)], signs)[0]
        else:
            hint[j] = match_abb_confdata(rob, T_cal[k:k + 1], np.array([cfg["conf"]]), axis_signs, reference=nom)[0]
    fin = np.isfinite(hint).all(1)
    rows, hint = rows[fin], hint[fin]
    if not rows.size:
        return
    again = compensate(model, T[rows], q_branch=hint, frame=fr, tool_delta=D[rows], tool_given=given[rows], **ik_kw)
    g2, w2 = _flags(model, [targets[k] for k in rows], again.q, axis_signs)
    take = again.success & (g2 == w2)
    for name in ("command", "q", "success", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg", "in_support",
                 "q_branch", "reason"):
        getattr(comp, name)[rows[take]] = getattr(again, name)[take]


def _config_notes(model, targets: list, comp: Compensation, other_flag: np.ndarray, axis_signs) -> list:
    """Notes on the successful targets whose rewritten configuration data differ from the program's: a
    flag (KUKA ``S``, ABB ``cfx``) no solution on the taught one reaches (those within the slack of a
    singular pose, ``other_flag``, have their own note), and KUKA turn bits ``T`` of a joint the correction
    moves across 0° (ABB quadrants follow the joints without a note: confdata name quadrants, not turns)."""
    from .branches import kuka_status

    ok = np.flatnonzero(comp.success)
    if not ok.size:
        return []
    got, want = _flags(model, [targets[k] for k in ok], comp.q[ok], axis_signs)
    flag, turn = [], []
    qz = np.nan_to_num(comp.q[ok])
    Tk = kuka_status(model.nominal, qz, axis_signs)[1]
    for j, k in enumerate(ok):
        t, cfg = targets[k], targets[k].config
        if want[j] >= 0 and got[j] != want[j] and not other_flag[k]:
            flag.append(f"{t.line} ({'S' if 'S' in cfg else 'cfx'} {want[j]} -> {got[j]})")
        elif "T" in cfg and "S" in cfg and int(Tk[j]) != cfg["T"]:
            turn.append(f"{t.line} (T {cfg['T']} -> {int(Tk[j])})")
    out = []
    if flag:
        out.append(f"{flag[0].split(' ')[0]}: {len(flag)} targets (lines {', '.join(flag[:8])}"
                   f"{' ...' if len(flag) > 8 else ''}) are reached by the real robot only in another configuration "
                   "than taught (no solution with the program's configuration within the joint limits): their "
                   "configuration data are rewritten")
    if turn:
        out.append(f"{turn[0].split(' ')[0]}: {len(turn)} targets (lines {', '.join(turn[:8])}"
                   f"{' ...' if len(turn) > 8 else ''}) have a joint that the correction moves across 0°: their T is "
                   "rewritten to the compensated joints' (the taught T would turn that axis by a full turn or find no "
                   "solution)")
    return out


def _scatter(comp: Compensation | None, rows: list, targets: list, n: int, frame: str) -> Compensation:
    """``comp`` (of ``targets[rows]``) widened to every target: the others failed with their ``error``."""
    N = len(targets)
    if comp is not None and len(rows) == N:
        return comp
    nan = lambda *shape: np.full(shape, np.nan)
    out = Compensation(command=nan(N, 4, 4), q=nan(N, n), success=np.zeros(N, dtype=bool),
                       reason=np.array([t.error for t in targets], dtype=object), pos_err_mm=nan(N),
                       ang_err_deg=nan(N), shift_mm=nan(N), shift_deg=nan(N), in_support=np.zeros(N, dtype=bool),
                       q_branch=nan(N, n), frame=frame if comp is None else comp.frame)
    if comp is not None:
        for name in ("command", "q", "success", "pos_err_mm", "ang_err_deg", "shift_mm", "shift_deg", "in_support",
                     "q_branch"):
            getattr(out, name)[rows] = getattr(comp, name)
        out.reason[rows] = comp.reason
    out.reason = out.reason.astype(str)
    return out


def splice_numbers(literal: str, spans: list, values: list) -> str:
    """``literal`` with the number tokens at ``spans`` (``(start, end)`` relative to the literal, in
    increasing order) replaced by the strings ``values``; every other character kept."""
    out, last = [], 0
    for (a, b), v in zip(spans, values):
        out.append(literal[last:a])
        out.append(v)
        last = b
    out.append(literal[last:])
    return "".join(out)
