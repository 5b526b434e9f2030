"""URScript (Universal Robots): ``p[x, y, z, rx, ry, rz]`` poses — m, rotation vector (rad), base frame.

Targets: a pose literal that a motion (``movel``/``movej``/``movep``/``movec``: its first argument, and
the second of ``movec``) moves to: written inline, through a variable the script assigns it
(``global``/``local``/plain ``name = p[...]``), as the pose of ``get_inverse_kin(pose, qnear, ..., tcp)``
(Polyscope's MoveJ waypoints: ``movej(get_inverse_kin(Waypoint_1_p, qnear=Waypoint_1_q))``), or as
``pose_trans(F, pose)`` where the script assigns feature ``F`` a pose literal (``global Plane_1 = p[...]``):
that target is taken in ``F``'s frame and written back in it (a feature the script does not define, e.g.
one of the installation, is kept and noted). Every other pose literal (``set_tcp`` and TCP variables,
``pose_trans``/``pose_add`` offsets, force frames) is kept and listed in the notes.

A target is compensated for where it is executed, not where it is written: a variable's literal for
the first motion that moves to it while it holds that literal (Polyscope declares every waypoint at the
top, before the first move; :attr:`.ProgramTarget.order`). There:

* TCP: the latest ``set_tcp`` before it in text order, ``set_tcp(p[...])`` or ``set_tcp(name)`` with
  ``name``'s latest pose literal; ``get_inverse_kin``'s ``tcp`` replaces it for that move. The
  compensation uses the tool delta ``inv(nominal tool) · tcp`` (before any ``set_tcp`` the installation
  TCP is taken to be the robot file's tool). A ``set_tcp``/``tcp`` whose pose cannot be read (an
  expression, a call, a name without a pose literal) makes the targets under it fail ("TCP unknown"),
  as does one variable moved to under two different TCPs (one literal cannot serve both).
* Branch: ``get_inverse_kin``'s ``qnear`` (a joint list, rad, inline or in a variable) — the nominal
  solution nearest it, as the controller picks (:attr:`.ProgramTarget.reset`); an unreadable ``qnear``
  fails the target. Otherwise the walk of :mod:`.programs` (nearest the previous target's joints),
  restarted at joint moves (``movej([j1, ..., j6])``, ``movej(q_name)``) between the previous target
  and this one.

Comments (``#``) and strings are ignored. Numbers are written with 7 decimals (m, 0.1 µm) and 8 (rad).
"""

from __future__ import annotations

import bisect
import re
from dataclasses import dataclass

import numpy as np

from ..geometry import se3
from ..io.urdf_flange import flange_of
from .programs import NUMBER, ProgramTarget, comment_mask, line_of, splice_numbers

__all__ = ["SUFFIXES", "find_targets", "format_target", "written_pose"]

SUFFIXES = (".script", ".urscript", ".urs")
_POSE = re.compile(r"(?<![\w.])p\s*\[\s*" + r"\s*,\s*".join([f"({NUMBER})"] * 6) + r"\s*\]")
_MOVE = re.compile(r"\b(movel|movej|movep|movec)\s*\(")
_SET_TCP = re.compile(r"\bset_tcp\s*\(")
# a statement ``[global|local] name = ...`` (``==`` is a comparison; ``f(a=1)`` a keyword argument)
_ASSIGN = re.compile(r"(?:^|[;:])[ \t]*(?:global\s+|local\s+)?([A-Za-z_]\w*)\s*=(?!=)", re.M)
_NAME = re.compile(r"[A-Za-z_]\w*")
_CALL = re.compile(r"([A-Za-z_]\w*)\s*\(")
_KEYWORD = re.compile(r"([A-Za-z_]\w*)\s*=(?!=)")
_ACTUAL_Q = re.compile(r"get_actual_joint_positions\s*\(\s*\)")
_OPEN, _SHUT = "([{", ")]}"
_GENERIC = "pose literal not used as a move target (offset, frame, ...): kept"


@dataclass
class _Assign:
    """One assignment ``name = value``: ``pos`` of the name; ``kind`` ``"pose"`` (``value`` ``(4, 4)``,
    m; ``lit`` the literal's start), ``"joints"`` (``value`` ``(n,)``, rad) or ``"other"`` (not read)."""

    pos: int
    kind: str
    value: np.ndarray | None = None
    lit: int = -1


@dataclass
class _Use:
    """One motion to a Cartesian target: ``pos`` the statement's start, ``at`` where it executes (an inline
    literal's start, else ``pos``; ``movec``'s second argument: its start); the inline literal's start
    ``lit`` (-1: variable ``name``); ``feature`` of ``pose_trans(feature, .)`` or ``""``; ``qnear``
    ``(n,)`` rad or None (the walk); ``tcp`` ``(4, 4)`` flange → TCP (m) or None (the robot file's tool);
    ``error``: why the target cannot be compensated there (``""``: it can)."""

    pos: int
    at: int
    line: int
    lit: int
    name: str
    feature: str
    qnear: np.ndarray | None
    tcp: np.ndarray | None
    error: str


def _comments(text: str, mask: np.ndarray) -> np.ndarray:
    """Bool per character: inside a ``#`` comment (of the comment-or-string ``mask``)."""
    edge = np.diff(np.r_[0, mask.astype(np.int8), 0])
    out = np.zeros(len(text), dtype=bool)
    for a, b in zip(np.flatnonzero(edge == 1), np.flatnonzero(edge == -1)):
        if text[a] == "#":
            out[a:b] = True
    return out


class _Script:
    """A URScript text read for its targets: pose literals, assignments, ``set_tcp`` calls, motions.
    Positions are character offsets into the text; comments and strings are blanked (``clean``)."""

    def __init__(self, text: str, robot):
        mask = comment_mask(text, "#", '"')
        self.text = text
        codes = np.frombuffer(text.encode("utf-32-le", "surrogatepass"), dtype=np.uint32).copy()
        mask = mask[: len(text)]
        # strings blanked too for reading code, kept for telling an argument's extent ("active_tcp")
        self.blank = np.isin(codes, [9, 10, 11, 12, 13, 32]) | _comments(text, mask)
        codes[mask] = ord(" ")  # one code point per character: positions are the text's
        self.clean = codes.tobytes().decode("utf-32-le", "surrogatepass")
        self.joints_re = re.compile(r"\[\s*" + r"\s*,\s*".join([f"({NUMBER})"] * robot.dof) + r"\s*\]")
        self.lits = {m.start(): m for m in _POSE.finditer(self.clean)}
        # every literal's numbers and pose at once (one rotation batch: a program has thousands)
        v = np.array([[float(g) for g in m.groups()] for m in self.lits.values()]).reshape(-1, 6)
        T = se3.make_transform(se3.rotvec_to_matrix(v[:, 3:]), v[:, :3])
        self.lit_starts = list(self.lits)  # increasing
        self.values = dict(zip(self.lits, v))
        self.poses = dict(zip(self.lits, T))
        self.why = {}  # literal start -> note, for literals that are kept for a known reason
        self.assigns = self._assignments()
        self.tcp_names = set()  # variables used as a TCP (their literals are kept)
        self.tcps = self._tcp_changes()
        self.tcp_pos = [p for p, _, _ in self.tcps]

    # ------------------------------------------------------------------ reading expressions

    def _strip(self, a: int, b: int) -> tuple[int, int]:
        """``(a, b)`` less the white space and comments at either end (a string stays)."""
        while a < b and self.blank[a]:
            a += 1
        while b > a and self.blank[b - 1]:
            b -= 1
        return a, b

    def _close(self, i: int) -> int:
        """Index of the bracket closing the one at ``i`` (-1: unbalanced to the end of the text)."""
        depth = 0
        for j in range(i, len(self.clean)):
            c = self.clean[j]
            if c in _OPEN:
                depth += 1
            elif c in _SHUT:
                depth -= 1
                if depth == 0:
                    return j
        return -1

    def _args(self, i: int, j: int) -> list:
        """Spans ``[(a, b)]`` (stripped) of the top-level arguments between the brackets at ``i`` and ``j``."""
        out, depth, a = [], 0, i + 1
        for k in range(i + 1, j):
            c = self.clean[k]
            if c in _OPEN:
                depth += 1
            elif c in _SHUT:
                depth -= 1
            elif c == "," and depth == 0:
                out.append(self._strip(a, k))
                a = k + 1
        out.append(self._strip(a, j))
        return [] if len(out) == 1 and out[0][0] == out[0][1] else out

    def _call(self, a: int, b: int, fn: str) -> list | None:
        """The argument spans when ``clean[a:b]`` is exactly a call of ``fn``, else None."""
        m = _CALL.match(self.clean, a)
        if m is None or m.group(1) != fn or self._close(m.end() - 1) != b - 1:
            return None
        return self._args(m.end() - 1, b - 1)

    def _literal(self, a: int, b: int) -> tuple[str, np.ndarray | None]:
        """``("pose", (4, 4))`` / ``("joints", (n,))`` when ``clean[a:b]`` is such a literal (m, rad), else
        ``("other", None)``."""
        m = self.lits.get(a)
        if m is not None and m.end() == b:
            return "pose", self.poses[a]
        j = self.joints_re.fullmatch(self.clean, a, b)
        if j is not None:
            return "joints", np.array([float(g) for g in j.groups()])
        return "other", None

    def _assignments(self) -> dict:
        """``name -> [_Assign]`` in text order (the value: the rest of the statement's line)."""
        out = {}
        for m in _ASSIGN.finditer(self.clean):
            e = self.clean.find("\n", m.end())
            a, b = self._strip(m.end(), len(self.clean) if e < 0 else e)
            kind, value = self._literal(a, b)
            out.setdefault(m.group(1), []).append(_Assign(m.start(1), kind, value, a if kind == "pose" else -1))
        return out

    def latest(self, name: str, pos: int) -> _Assign | None:
        """The assignment of ``name`` that holds at ``pos``: the latest before it in text order, or the
        only one when none is before (a function defined above the declaration); None when unknown."""
        entries = self.assigns.get(name, [])
        before = [e for e in entries if e.pos < pos]
        return before[-1] if before else (entries[0] if len(entries) == 1 else None)

    def value(self, a: int, b: int, pos: int) -> tuple[str, np.ndarray | None]:
        """``clean[a:b]`` read as a pose or joint list (a literal, or a variable's value at ``pos``)."""
        kind, v = self._literal(a, b)
        if kind == "other" and _NAME.fullmatch(self.clean, a, b):
            d = self.latest(self.clean[a:b], pos)
            if d is not None:
                return d.kind, d.value
        return kind, v

    def expr_text(self, a: int, b: int) -> str:
        s = " ".join(self.text[a:b].split())
        return s if len(s) <= 60 else s[:57] + "..."

    # ------------------------------------------------------------------ TCP

    def _tcp_changes(self) -> list:
        """``[(pos, tcp, why)]`` of the ``set_tcp`` calls in text order: the TCP set ``(4, 4)`` (flange
        frame, m), or None and why it cannot be read."""
        out = []
        for m in _SET_TCP.finditer(self.clean):
            j = self._close(m.end() - 1)
            args = self._args(m.end() - 1, j) if j >= 0 else []
            kind, T = self.value(*args[0], m.start()) if len(args) == 1 else ("other", None)
            starts = self.lit_starts[bisect.bisect_left(self.lit_starts, m.end()):bisect.bisect_left(self.lit_starts, j)]
            for lit in starts:  # inside an expression that is not read
                self.why[lit] = "pose literal inside set_tcp(...) kept (that TCP is unknown to hykin)"
            if len(args) == 1 and args[0][0] in self.lits:
                self.why[args[0][0]] = "set_tcp pose kept; later targets use this TCP"
            elif len(args) == 1 and _NAME.fullmatch(self.clean, *args[0]):
                self.tcp_names.add(self.clean[slice(*args[0])])
            if kind == "pose":
                out.append((m.start(), T, ""))
            else:
                expr = self.expr_text(*args[0]) if len(args) == 1 else self.expr_text(m.end(), max(j, m.end()))
                out.append((m.start(), None, f"TCP unknown: set_tcp({expr}) at line {line_of(self.text, m.start())} "
                                             "could not be read"))
        return out

    def tcp_at(self, pos: int) -> tuple[np.ndarray | None, str]:
        """The TCP in effect at ``pos`` (None: the robot file's tool) and why it is unknown (``""``: known)."""
        i = bisect.bisect_left(self.tcp_pos, pos) - 1
        return (None, "") if i < 0 else self.tcps[i][1:]

    # ------------------------------------------------------------------ motions

    def _target_expr(self, a: int, b: int, pos: int):
        """What a motion argument moves to: ``("joints", q)``; ``("pose", lit, name, feature, ik_args)``
        (an inline literal's start or -1 and a variable name; ``ik_args``: ``get_inverse_kin``'s argument
        spans or None); None for anything else (an expression evaluated at run time)."""
        kind, v = self._literal(a, b)
        if kind == "pose":
            return "pose", a, "", "", None
        if kind == "joints":
            return "joints", v
        if _NAME.fullmatch(self.clean, a, b):
            d = self.latest(self.clean[a:b], pos)
            if d is not None and d.kind == "joints":  # movej(Waypoint_1_q)
                return "joints", d.value
            return "pose", -1, self.clean[a:b], "", None
        args = self._call(a, b, "pose_trans")
        if args is not None and len(args) == 2 and _NAME.fullmatch(self.clean, *args[0]):
            inner = self._target_expr(*args[1], pos)
            if inner is not None and inner[0] == "pose" and not inner[3] and inner[4] is None:
                return "pose", inner[1], inner[2], self.clean[slice(*args[0])], None
            return None
        args = self._call(a, b, "get_inverse_kin")
        if args:
            inner = self._target_expr(*args[0], pos)
            if inner is not None and inner[0] == "pose" and inner[4] is None:
                return (*inner[:4], args)
        return None

    def _ik_context(self, args: list, pos: int, line: int, tcp, tcp_err: str):
        """``(qnear, tcp, error)`` of ``get_inverse_kin(x, qnear, maxPositionError, maxOrientationError,
        tcp)`` (positional or keyword) at ``pos``, given the active TCP ``tcp`` / ``tcp_err``."""
        positional, kw = [], {}
        for a, b in args[1:]:
            k = _KEYWORD.match(self.clean, a, b)
            if k is not None:
                kw[k.group(1)] = self._strip(k.end(), b)
            else:
                positional.append((a, b))
        qn = kw.get("qnear", positional[0] if positional else None)
        tc = kw.get("tcp", positional[3] if len(positional) > 3 else None)
        q, q_err = None, ""
        if qn is not None and not _ACTUAL_Q.fullmatch(self.clean, *qn):  # the current joints: the walk's
            kind, v = self.value(*qn, pos)
            if kind == "joints":
                q = v
            else:
                q_err = f"branch unknown: get_inverse_kin qnear={self.expr_text(*qn)} at line {line} could not be read"
        if tc is not None and self.text[slice(*tc)].strip().strip("\"'") != "active_tcp":
            kind, v = self.value(*tc, pos)
            if tc[0] in self.lits:
                self.why[tc[0]] = "get_inverse_kin tcp pose kept (the TCP of that move)"
            elif _NAME.fullmatch(self.clean, *tc):
                self.tcp_names.add(self.clean[slice(*tc)])
            tcp, tcp_err = (v, "") if kind == "pose" else (
                None, f"TCP unknown: get_inverse_kin tcp={self.expr_text(*tc)} at line {line} could not be read")
        return q, tcp, tcp_err or q_err

    def motions(self) -> tuple[list, list]:
        """``(uses, joint_moves)``: every motion to a Cartesian target (:class:`_Use`, text order) and the
        ``[(pos, q)]`` the robot is known to be at after a motion (joint moves; ``get_inverse_kin``'s
        ``qnear``, close enough to restart the walk after a target that is not compensated there)."""
        uses, joints = [], []
        for m in _MOVE.finditer(self.clean):
            j = self._close(m.end() - 1)
            if j < 0:
                continue
            args = self._args(m.end() - 1, j)
            for k, (a, b) in enumerate(args[: 2 if m.group(1) == "movec" else 1]):
                e = self._target_expr(a, b, m.start())
                if e is None or (e[0] == "joints" and k > 0):
                    continue
                if e[0] == "joints":
                    joints.append((m.start(), e[1]))
                    continue
                _, lit, name, feature, ik_args = e
                line = line_of(self.text, m.start())
                tcp, err = self.tcp_at(m.start())
                q = None
                if ik_args is not None:
                    q, tcp, err = self._ik_context(ik_args, m.start(), line, tcp, err)
                    if q is not None:
                        joints.append((m.start(), q))
                # executed at the statement; movec's end point after its via point (both may be variables)
                at = lit if lit >= 0 else (m.start() if k == 0 else a)
                uses.append(_Use(m.start(), at, line, lit, name, feature, q, tcp, err))
        return uses, joints


def _same_tcp(a, b) -> bool:
    return (a is None and b is None) or (a is not None and b is not None and np.allclose(a, b, atol=1e-12))


def _target(s: _Script, lit: int, name: str, uses: list, inv_tool: np.ndarray) -> ProgramTarget | str:
    """The target of the pose literal at ``lit`` that ``uses`` (text order) move to, compensated for the
    first of them; or the note saying why it is kept."""
    m = s.lits[lit]
    line = line_of(s.text, lit)
    features = {u.feature for u in uses}
    if len(features) > 1:
        where = sorted(f for f in features if f) + (["base"] if "" in features else [])
        return f"line {line}: {name} is moved to in several frames ({', '.join(where)}): kept"
    first = uses[0]
    pose, frame = s.poses[lit], None
    if first.feature:
        d = s.latest(first.feature, first.at)  # the feature's pose where the move is counts
        if d is None or d.kind != "pose":
            return (f"line {line}: move relative to feature {first.feature}, which this script does not define as "
                    "a pose (an installation feature?): kept")
        frame = d.value
        pose = frame @ pose
    error = next((u.error for u in uses if u.error), "")
    if not error and not all(_same_tcp(first.tcp, u.tcp) for u in uses[1:]):
        error = (f"moved to with different TCPs (lines {', '.join(str(u.line) for u in uses)}): one literal cannot be "
                 "compensated for both")
    spans = [(m.start(i) - lit, m.end(i) - lit) for i in range(1, 7)]
    return ProgramTarget(
        start=lit, end=m.end(), line=line, pose=pose, name=name, kind="p[]",
        tool_delta=None if first.tcp is None else inv_tool @ first.tcp, reset=first.qnear,
        parts={"spans": spans, "rv": s.values[lit][3:], "literal": s.text[lit:m.end()]}, frame=frame, error=error,
        order=None if first.lit == lit else first.at,
    )


def _moved(uses: list) -> list:
    """``uses`` less the moves to ``pose_trans(F, x)`` where ``F`` is itself moved to: ``x`` is then an
    offset from a moving pose (kept), not a target in a fixed feature; a variable used as such an offset
    anywhere is not taken in a feature either (its direct moves still count)."""
    moving = {u.name for u in uses if u.name}
    offsets = {u.name for u in uses if u.feature in moving}
    return [u for u in uses if not u.feature or (u.feature not in moving and u.name not in offsets)]


def _set_resets(targets: list, joint_moves: list) -> None:
    """Restart the walk of each target without ``qnear`` at the last joint move between the previous
    compensated target and it, in execution order (``order``, else ``start``)."""
    joint_moves = sorted(joint_moves, key=lambda e: e[0])
    pos = [p for p, _ in joint_moves]
    prev = -1
    for t in sorted((t for t in targets if not t.error), key=lambda t: (_executed(t), t.start)):
        i = bisect.bisect_left(pos, _executed(t)) - 1
        if t.reset is None and i >= 0 and pos[i] > prev:
            t.reset = joint_moves[i][1]
        prev = _executed(t)


def _executed(t: ProgramTarget) -> int:
    """Where ``t`` is executed (the walk's sort key, :func:`.programs._branch_joints`)."""
    return t.start if t.order is None else t.order


def find_targets(text: str, robot, context: str = "", axis_signs=None) -> tuple[list, list]:
    """``(targets, notes)`` of a URScript program (module docstring); targets in text order."""
    s = _Script(text, robot)
    uses, joint_moves = s.motions()
    uses = _moved(uses)
    inv_tool = se3.invert(robot.tool) @ flange_of(robot)  # set_tcp is given from the flange (urdf_flange)
    found = []  # (literal start, target or the note saying why it is kept)
    for u in uses:
        if u.lit >= 0:
            found.append((u.lit, _target(s, u.lit, "", [u], inv_tool)))
    inline = {lit for lit, _ in found}
    by_name = {}
    for u in uses:
        if u.lit < 0:
            by_name.setdefault(u.name, []).append(u)
    for name, entries in s.assigns.items():
        for d in entries:
            if d.kind != "pose" or d.lit in inline:
                continue
            if name not in by_name:
                if name in s.tcp_names:
                    s.why[d.lit] = f"{name} is a TCP (set_tcp), not a move target: kept"
                continue
            # the moves made while the variable holds this literal; none (a loop, a dead value): all of them
            own = [u for u in by_name[name] if s.latest(name, u.pos) is d] or by_name[name]
            found.append((d.lit, _target(s, d.lit, name, own, inv_tool)))
    targets = sorted((t for _, t in found if not isinstance(t, str)), key=lambda t: t.start)
    _set_resets(targets, joint_moves)
    kept = {lit: t for lit, t in found if isinstance(t, str)}
    done = {t.start for t in targets}
    notes = [kept.get(lit) or f"line {line_of(text, lit)}: {s.why.get(lit, _GENERIC)}" for lit in sorted(s.lits)
             if lit not in done]
    return targets, notes


def format_target(t: ProgramTarget, command: np.ndarray, q, robot, axis_signs=None) -> str:
    """The literal of ``t`` with the command's numbers (rotation vector nearest the original's)."""
    rv = se3.matrix_to_rotvec(command[:3, :3])
    ang = np.linalg.norm(rv)
    if ang > 1e-9:  # the other representation of the same rotation: angle - 2π about the same axis
        alt = rv * (ang - 2 * np.pi) / ang
        if np.linalg.norm(alt - t.parts["rv"]) < np.linalg.norm(rv - t.parts["rv"]):
            rv = alt
    vals = [f"{x:.7f}" for x in command[:3, 3]] + [f"{x:.8f}" for x in rv]
    return splice_numbers(t.parts["literal"], t.parts["spans"], vals)


def written_pose(t: ProgramTarget, literal: np.ndarray) -> np.ndarray:
    """The pose ``(4, 4)`` the controller reads from the literal :func:`format_target` writes for the pose
    ``literal`` (its frame): the numbers rounded as written (near a singular pose the rounding can move a
    command out of the nominal robot's reach: :mod:`.program_checks`)."""
    rv = np.round(se3.matrix_to_rotvec(literal[:3, :3]), 8)
    return se3.make_transform(se3.rotvec_to_matrix(rv), np.round(literal[:3, 3], 7))
