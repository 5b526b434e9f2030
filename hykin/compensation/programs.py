"""Rewriting robot programs in place: the part shared by URScript, KRL and RAPID.

A format module finds the Cartesian targets of a program (:class:`ProgramTarget`: the character span
of the literal, the pose in the controller's base frame, the configuration data it carries) and
formats a compensated literal; :func:`compensate_program` solves all targets in one batch and splices
the new literals into the text. Every character outside the replaced literals is kept, so every line
without a target is byte for byte the same (files are read and written as latin-1, which maps every
byte to one character and back).

Branches (:mod:`.program_branches`): a target with configuration data (KUKA ``S``/``T``, ABB
``confdata``) gets the nominal solution matching it; a target without gets the nominal solution nearest
the previous target's (a controller moving through the program in text order); one right after a
joint-space move (where the format has those) is solved from that move's joints, as CSV targets are
from their given joints. Where the nominal robot has no such solution, the calibrated robot's is taken
(the nominal model only hints; the hybrid model is solved); where that has none either only because the
target lies within ``config_slack_deg`` of a singular pose (stretched elbow, wrist centre on axis 1,
``A5 = 0``), the calibrated robot's with that flag flipped, with a note. A target without configuration
data that neither reaches starts from the previous joints. Control flow (loops, branches, calls) is not
followed: text order stands for execution order.

Checks before writing (:mod:`.program_checks`): a KUKA target whose written ``S``/``T`` are a
configuration the program does not ask for fails, naming those the real robot reaches it with; a target
without configuration data fails where the controller would execute its command on another branch than
the compensated joints (after solving it again from the joints the robot is at).

Unreachable targets: :class:`ProgramResult` lists them (line, reason); the caller refuses to write
the program (default) or keeps their original literal and warns (``skip_unreachable``).
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3
from .tool_shift import tool_shift_note
from .result import Compensation, edge_notes

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
    after: the index of the target the robot moves to just before this one's motion, where a program moves
    to some target more than once (a ``.dat`` point used again), else None (the one before in ``order``).
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
    after: int | None = None


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


def compensate_program(model, text: str, fmt, *, frame: str = "auto", axis_signs=None, context: str = "",
                       config_slack_deg: float = CONFIG_SLACK_DEG, flange: str | None = None, **ik_kw) -> ProgramResult:
    """Compensate every Cartesian target of ``text`` (a program in format module ``fmt``: one of
    :mod:`.urscript`, :mod:`.krl`, :mod:`.rapid`). ``context``: text of a companion file (KRL: the
    ``.src`` beside a ``.dat``, whose motion statements tell which variables are targets; RAPID: modules
    declaring the ``tooldata``/``wobjdata`` the program uses).
    ``frame``: how program poses map into the model's measurement frame (:mod:`.targets`).
    ``config_slack_deg``: a target whose configuration data the real robot cannot meet only because
    its elbow is within this angle of stretched (the reach boundary), its wrist centre of axis 1 or its A5
    of 0 takes the other elbow / overhead / wrist flag, with a note; 0 refuses it (:mod:`.branches`).
    ``ik_kw``: :class:`.compensator.Compensator` keywords (``tolerance_mm``, ``tolerance_deg``, ...).
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
        comp, more = _solve(model, [targets[k] for k in ok], frame, axis_signs, config_slack_deg, ik_kw,
                            getattr(fmt, "written_pose", None))
        notes = [*notes, *more]
    comp = _scatter(comp, ok, targets, model.nominal.dof, frame)
    pieces, last, failed = [], 0, []
    for k, t in enumerate(targets):
        if not comp.success[k]:
            why = comp.reason[k] if not t.caveat or t.error else f"{t.caveat}; {comp.reason[k]}"
            failed.append((t.line, f"{t.name or 'inline ' + t.kind.replace('[]', '[...]')}: {why}"))
            continue
        command = comp.command[k] if t.frame is None else se3.invert(t.frame) @ comp.command[k]
        new = fmt.format_target(t, command, comp.q[k], model.nominal, axis_signs)
        pieces.append(text[last : t.start])
        pieces.append(new)
        last = t.end
    pieces.append(text[last:])
    return ProgramResult(text="".join(pieces), targets=targets, comp=comp, failed=failed, notes=notes)


def _solve(model, targets: list, frame: str, axis_signs, slack_deg: float, ik_kw: dict,
           written=None) -> tuple[Compensation, list]:
    """:class:`Compensation` of ``targets`` (all with known frames), branches as the program means them
    (:func:`.program_branches.branch_hints`), and the notes on rewritten configuration data. A configuration
    target that failed or left its configuration is solved again from the calibrated robot's solutions with
    its data (:func:`.program_checks.keep_configuration`); one whose written configuration the program does
    not ask for fails (:func:`.program_checks.configuration_changes`); a target without configuration data
    must be the controller's choice from the joints the robot is at (:func:`.walk_checks.check_walk`;
    ``written``: the format's ``written_pose``, the literal as the controller reads it)."""
    from .compensator import Compensator
    from .frames import resolve_frame, to_model_frame
    from .program_branches import branch_hints
    from .program_checks import configuration_changes, keep_configuration
    from .walk_checks import check_walk

    T = np.stack([t.pose for t in targets])
    D = np.stack([np.eye(4) if t.tool_delta is None else t.tool_delta for t in targets])
    fr = resolve_frame(model, frame)
    slack_rad = float(np.radians(slack_deg))
    comp_of = Compensator(model, frame=fr, **ik_kw)
    # branch from the nominal solutions of the uncompensated target, in the nominal robot's world
    # (= the measurement frame; the controller base sits at nominal.base in it)
    T_nom = comp_of.nominal_world(T, D)
    given = np.array([t.tool_delta is not None for t in targets])  # a program tool (else the model's TCP)
    Dm = comp_of.model_delta(D, given)
    T_cal = se3.invert(model.frame_pre_) @ to_model_frame(model, T, fr) @ se3.invert(Dm) @ se3.invert(model.frame_post_)
    qb, other_flag, reason = branch_hints(model, targets, T_nom, T_cal, axis_signs, slack_rad)
    # a target moved to from a joint move (movej([...]), PTP to an axis aggregate, get_inverse_kin's qnear) is
    # solved from those joints, as the CSV path solves from given joints (the nominal solution of the
    # uncompensated target nearest them can lie on another branch at a joint limit or singularity)
    first = qb.copy()
    for k, t in enumerate(targets):  # (a continuous-path motion keeps the status: its hint has it already)
        if t.reset is not None and not ("S" in t.config or "conf" in t.config or t.config.get("keep_status")):
            first[k] = np.clip(np.asarray(t.reset, dtype=np.float64), model.nominal.lower, model.nominal.upper)

    def solve(rows, hints):
        return comp_of(T[rows], q_branch=hints, tool_delta=D[rows], tool_given=given[rows], controller_check=False)

    # (the hints are configuration data's branches, not joints the robot stands at: the checks are below)
    comp = comp_of(T, q_branch=first, tool_delta=D, branch_reason=reason, tool_given=given, controller_check=False)
    comp.reason = comp.reason.astype(object)  # reasons get longer below
    keep_configuration(model, solve, targets, comp, other_flag, T_cal, axis_signs, slack_rad)
    notes = configuration_changes(model, targets, comp, other_flag, T_cal, axis_signs, slack_rad, slack_deg)
    if model.nominal.dof >= 6:  # an arm of fewer joints reaches a rounded literal's orientation only in the
        # least-squares sense: the controller's exact nominal solution the check looks for does not exist
        notes += check_walk(model, comp_of, solve, targets, comp, qb, T, D, Dm, axis_signs, written, T_nominal=T_nom)
    comp.reason = comp.reason.astype(str)
    if model.nominal.dof >= 6:  # accepted at the model's reach boundary: said, as for a list
        notes += edge_notes(comp, comp_of.tolerance_mm, comp_of.tolerance_deg, comp_of.accuracy_mm,
                            [t.line for t in targets])
    # the targets written with a program tool (probe s42 AX: the note counted refused ones too)
    return comp, notes + tool_shift_note(model, D, given & comp.success, comp_of.tool_shift, comp_of.accuracy_mm)


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
