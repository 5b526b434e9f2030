"""KUKA KRL: ``E6POS``/``POS``/``FRAME`` aggregates in ``.src`` and ``.dat`` files.

Aggregate ``{[TYPE:] X x, Y y, Z z, A a, B b, C c[, S s, T t][, E1 ...]}``: ``X, Y, Z`` in mm,
``A, B, C`` in degrees about Z, Y', X'' (``R = Rz(A) Ry(B) Rx(C)``), base frame; ``S``/``T`` status
and turn (decimal or ``'B010'`` binary), meaning as in :mod:`.branches`. Only the values of
``X, Y, Z, A, B, C, S, T`` are replaced; components, order, spacing, ``E1..E6`` are kept.

Targets: complete Cartesian aggregates (all of ``X, Y, Z, A, B, C``) that are ``E6POS``/``POS`` (by
prefix or declaration), untyped ones a motion statement moves to (``PTP/LIN/CIRC``, ``SPTP/SLIN/SCIRC``,
``SPL``: :mod:`.krl_motions`), and ``FRAME`` ones inline in a motion statement or assigned to a
variable (declared ``FRAME`` on any line of this file or its companion) some motion statement moves to.
Kept and noted: relative motions (``*_REL``), partial aggregates (KRL fills the missing components
from the current pose, which we cannot know), ``FRAME`` data not moved to (``$BASE``/``$TOOL``/
``BASE_DATA``/``TOOL_DATA``, ``fTool = {..}``, offsets), frame operands of geometric expressions
(``LIN XP1 : {..}``), aggregates in ``WITH`` clauses, assignments to system variables (``$TOOL =
{...}``, ``$BASE``, ``BASE_DATA[i]``, ``TOOL_DATA[i]``). Each target is walked (branch without ``S``/
``T``) where the ``.src`` first moves to it, restarted at the last ``PTP``/``SPTP`` joint move before
(axis aggregates or ``AXIS``/``E6AXIS`` variables, degrees, controller signs). Each target is taken in
the base and with the tool the program selects where it moves to it (:mod:`.krl_frames`: ``$BASE``/
``$TOOL``, ``BAS(#BASE, n)``, ``FDAT_ACT``, spline ``WITH`` clauses, ``FRAME`` variables; ``BASE_DATA``/
``TOOL_DATA`` from ``$config.dat`` in ``context``; base 0 = the robot base, tool 0 = the robot file's
tool) and written back in that base. Numbers are written with 4 decimals (mm) and 5 (deg).
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..geometry import se3
from .krl_frames import frames_of_targets
from .krl_motions import axis_values, declared_types, joint_moves, parse_motions, point_of, set_execution_order
from .programs import NUMBER, ProgramTarget, comment_mask, line_of, splice_numbers

__all__ = ["SUFFIXES", "abc_from_matrix", "find_targets", "format_target", "matrix_from_abc", "written_pose"]

SUFFIXES = (".src", ".dat")
_AGG = re.compile(r"\{([^{}]*)\}")
_COMP = re.compile(r"([A-Za-z_]\w*)\s+(" + NUMBER + r"|'[Bb][01]+')")
_DECL = re.compile(r"(?:\bDECL\s+)?(?:\bGLOBAL\s+)?\b(E6POS|POS|FRAME|E6AXIS|AXIS)\s+([A-Za-z_$]\w*)\s*=\s*$", re.IGNORECASE)
_ASSIGN = re.compile(r"([A-Za-z_$][\w.$\[\]]*)\s*=\s*$")
_CART = ("X", "Y", "Z", "A", "B", "C")
_CP_VERBS = {"LIN", "CIRC", "SLIN", "SCIRC", "SPL"}  # continuous-path motions (the robot keeps its S)


def matrix_from_abc(a_deg, b_deg, c_deg) -> np.ndarray:
    """``(3, 3)`` rotation ``Rz(A) Ry(B) Rx(C)`` (degrees)."""
    a, b, c = math.radians(float(a_deg)), math.radians(float(b_deg)), math.radians(float(c_deg))
    ca, sa, cb, sb, cc, sc = math.cos(a), math.sin(a), math.cos(b), math.sin(b), math.cos(c), math.sin(c)
    return np.array([[ca * cb, ca * sb * sc - sa * cc, ca * sb * cc + sa * sc],
                     [sa * cb, sa * sb * sc + ca * cc, sa * sb * cc - ca * sc],
                     [-sb, cb * sc, cb * cc]])


def abc_from_matrix(R: np.ndarray, a_hint_deg: float = 0.0) -> tuple[float, float, float]:
    """``(A, B, C)`` degrees with ``R = Rz(A) Ry(B) Rx(C)``; at ``B = ±90°`` (gimbal lock) ``A`` is
    ``a_hint_deg`` and ``C`` takes the rest."""
    (r00, r01, _), (r10, r11, _), (r20, r21, _) = np.asarray(R, dtype=np.float64)[:3, :3].tolist()
    h = math.hypot(r00, r10)
    a = math.atan2(r10, r00) if h > 1e-9 else math.radians(float(a_hint_deg))
    b = math.atan2(-r20, h)
    ca, sa, cb, sb = math.cos(a), math.sin(a), math.cos(b), math.sin(b)
    # M = (Rz(a) Ry(b))^T R; C = atan2(M[2, 1], M[1, 1])
    m11 = -sa * r01 + ca * r11
    m21 = sb * (ca * r01 + sa * r11) + cb * r21
    return math.degrees(a), math.degrees(b), math.degrees(math.atan2(m21, m11))


def _int_value(tok: str) -> int:
    return int(tok[2:-1], 2) if tok.startswith("'") else int(float(tok))


def _clean(text: str) -> str:
    mask = comment_mask(text, ";", '"')
    return "".join(" " if m else c for c, m in zip(text, mask[: len(text)]))


def _key(name: str) -> str:
    """A variable name as motions name it: upper case, no spaces (``pts[1]``)."""
    return re.sub(r"\s+", "", name).upper()


def _points(motions: list, types: dict) -> list:
    """``[(motion, argument index, operands, index of the point or None, why not known)]``."""
    return [(mo, i, ops, *point_of(ops, types)) for mo in motions for i, ops in enumerate(mo.points)]


def _roles(points: list) -> dict:
    """``{aggregate start: (role, motion)}`` of the aggregates moved to: role ``"point"`` (the target),
    ``"rel"`` (a relative motion's), ``"operand"`` (a frame in a geometric expression), ``"unsplit"`` (in
    an expression whose point is not known). Aggregates in ``WITH`` clauses are not among them."""
    roles = {}
    for mo, _, ops, pi, _why in points:
        for i, op in enumerate(ops):
            if op.what == "agg":
                role = "rel" if mo.rel else "point" if i == pi else "unsplit" if pi is None else "operand"
                roles[op.start] = (role, mo)
    return roles


def _in_spans(pos: int, starts: np.ndarray, spans: list) -> bool:
    """Whether ``pos`` lies in one of ``spans`` (``[(start, end)]``, disjoint, ``starts`` sorted)."""
    i = int(np.searchsorted(starts, pos, side="right")) - 1
    return i >= 0 and pos < spans[i][1]


def _kept(role, line: int) -> str | None:
    """The note of an aggregate of a motion statement that is not a target (None: it may be one)."""
    if role is None or role[0] == "point":
        return None
    what, mo = role
    if what == "rel":
        return f"line {line}: relative motion ({mo.verb}_REL): kept"
    if what == "operand":
        return f"line {line}: frame operand of a geometric expression ({mo.verb} ... : ...): kept"
    return f"line {line}: aggregate in a geometric expression whose point hykin cannot tell: kept"


def _pose_of(comps: dict) -> tuple[np.ndarray, float]:
    """``((4, 4) pose (m), A (deg))`` of a complete aggregate's ``{component: (start, end, token)}``."""
    v = {k: float(comps[k][2]) for k in _CART}
    R = matrix_from_abc(v["A"], v["B"], v["C"])
    return se3.make_transform(R, np.array([v["X"], v["Y"], v["Z"]]) * 1e-3), v["A"]


def find_targets(text: str, robot, context: str = "", axis_signs=None) -> tuple[list, list]:
    """``(targets, notes)`` of a KRL ``.src`` or ``.dat`` text; ``context``: the companion file (and
    ``$config.dat``). Each target's ``order`` is where the ``.src`` first moves to it and its ``reset``
    the joints of a joint move just before (:mod:`.krl_motions`)."""
    from .branches import default_axis_signs

    sgn = default_axis_signs(robot) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    clean = _clean(text)
    ctx_clean = _clean(context) if context else ""
    own, own_spans = parse_motions(clean)
    ctx, ctx_spans = parse_motions(ctx_clean)
    # the .src is the file read, unless that has no motions (a .dat) and the context has (its .src)
    text_is_src = bool(own) or not ctx
    src_clean, motions, spans = (clean, own, own_spans) if text_is_src else (ctx_clean, ctx, ctx_spans)
    others = [ctx_clean] if text_is_src else [clean]
    types = declared_types([clean, ctx_clean])
    points = _points(motions, types)
    spans = sorted(spans)
    starts = np.array([a for a, _ in spans], dtype=np.int64)
    roles = _roles(points) if text_is_src else {}
    used = {ops[pi].key for _, _, ops, pi, _ in points + (_points(ctx, types) if text_is_src else [])
            if pi is not None and ops[pi].what == "var"}
    targets, notes = [], []
    axes = [f"A{i + 1}" for i in range(robot.dof)]
    for m in _AGG.finditer(clean):
        body, b0 = m.group(1), m.start(1)
        line = line_of(text, m.start())
        ls = clean.rfind("\n", 0, m.start()) + 1
        prefix = clean[ls : m.start()]
        tm = re.match(r"\s*([A-Za-z_]\w*)\s*:", body)
        kind = tm.group(1).upper() if tm else ""
        comps = {}
        for c in _COMP.finditer(body, tm.end() if tm else 0):
            comps[c.group(1).upper()] = (c.start(2), c.end(2), c.group(2))
        role = roles.get(m.start())
        if role and role[0] == "point" and all(a in comps for a in axes) and "X" not in comps:
            continue  # a joint move: it restarts the walk (krl_motions.joint_moves)
        if not any(k in comps for k in _CART):
            continue  # not a Cartesian aggregate (axis data, other structures)
        if text_is_src and _in_spans(m.start(), starts, spans):
            notes.append(f"line {line}: aggregate in a WITH clause (a system variable for one motion): kept")
            continue
        why = _kept(role, line)
        if why:
            notes.append(why)
            continue
        mot = role is not None
        decl = _DECL.search(prefix)
        name = decl.group(2) if decl else (_ASSIGN.search(prefix).group(1) if _ASSIGN.search(prefix) else "")
        # a variable declared on another line (DECL FRAME fTool ... fTool = {..}) has that type
        kind = kind or (decl.group(1).upper() if decl else types.get(re.sub(r"\[.*", "", _key(name)), ""))
        if not all(k in comps for k in _CART):
            notes.append(f"line {line}: partial Cartesian aggregate (missing "
                         f"{', '.join(k for k in _CART if k not in comps)}): kept")
            continue
        if kind == "FRAME" and not mot and _key(name) not in used:
            notes.append(f"line {line}: FRAME {name or '(unnamed)'} is not a motion target (base/tool data?): kept")
            continue
        if kind not in ("", "E6POS", "POS", "FRAME"):
            notes.append(f"line {line}: aggregate of type {kind}: kept")
            continue
        if not mot and (name.startswith("$") or name.upper().startswith(("BASE_DATA", "TOOL_DATA", "MACHINE_"))):
            notes.append(f"line {line}: {name} is a system/frame variable, not a target: kept")
            continue
        if kind == "" and not mot and not name:
            notes.append(f"line {line}: untyped aggregate outside a motion statement: kept")
            continue
        pose, a_deg = _pose_of(comps)
        cfg = {k: _int_value(comps[k][2]) for k in ("S", "T") if k in comps}
        if "T" in cfg and "S" not in cfg:
            cfg = {}
        keys = [k for k in (*_CART, "S", "T") if k in comps and (k in _CART or k in cfg)]
        spans_k = [(b0 + comps[k][0] - m.start(), b0 + comps[k][1] - m.start()) for k in keys]
        targets.append(ProgramTarget(
            start=m.start(), end=m.end(), line=line, pose=pose, name=name, kind=kind or "POS", config=cfg,
            parts={"keys": keys, "spans": spans_k, "literal": text[m.start():m.end()], "A": a_deg,
                   "tokens": {k: comps[k][2] for k in keys}, "axis_signs": sgn},
        ))
    uses, first, verb, every = _uses(targets, points, text_is_src)
    jm = joint_moves(motions, axis_values(src_clean, others, robot.dof, sgn), robot.dof, sgn)
    set_execution_order(targets, first, len(src_clean), jm, every)
    for k, v in verb.items():  # a continuous-path motion keeps the arm's configuration (S): KSS ignores S there
        if v in _CP_VERBS and "S" not in targets[k].config:
            targets[k].config["keep_status"] = True
    fr = frames_of_targets(src_clean, others, motions, spans, uses, targets, robot, types,
                           where="" if text_is_src else "--context, ")
    notes = notes + fr.apply(targets) + _from_unseen_points(targets, first, motions, uses, jm, src_clean)
    return _unused(targets, first, motions, src_clean, notes)


_SELECTS = re.compile(r"\$BASE\s*=(?!=)|\$TOOL\s*=(?!=)|\bBAS\s*\(\s*#(?:BASE|TOOL)\b|\bFDAT_ACT\s*=", re.IGNORECASE)


def _unused(targets: list, first: dict, motions: list, src_clean: str, notes: list) -> tuple[list, list]:
    """``(targets, notes)`` less the points no motion of the ``.src`` moves to (``first``: the used ones),
    when the ``.src`` selects a base or tool anywhere: where such a point is used (another module, a
    subroutine) its frame is not known, so its literal is kept, noted. A ``.src`` that selects none runs
    every motion in base 0 with the robot file's tool: its unused points are compensated so, noted too.
    Without motion statements (no ``.src`` read) every point is taken so (base 0, the robot file's tool)."""
    unused = [k for k in range(len(targets)) if k not in first]
    if not unused or not motions:
        return targets, notes
    shown = ", ".join(f"{targets[k].name or targets[k].kind} (line {targets[k].line})" for k in unused[:8])
    shown += " ..." if len(unused) > 8 else ""
    if _SELECTS.search(src_clean):
        notes = [*notes, f"{targets[unused[0]].line}: {len(unused)} points no motion of the .src moves to: {shown}: "
                         "kept (their base and tool are not known where they are used; move to them in the .src, or "
                         "compensate them with the program that does)"]
        return [t for k, t in enumerate(targets) if k not in set(unused)], notes
    return targets, [*notes, f"{targets[unused[0]].line}: {len(unused)} points no motion of the .src moves to: "
                             f"{shown}: compensated in base 0 with the robot file's tool (the .src selects no other)"]


def _assigned(ks: list, targets: list, pos: int, text_is_src: bool) -> list:
    """Of the literals ``ks`` of one variable, those a motion at ``pos`` moves to: in the ``.src``, the
    last assigned before it (a variable assigned twice holds one literal at a time); else all."""
    if not text_is_src or len(ks) < 2:
        return ks
    before = [k for k in ks if targets[k].start < pos]
    return [max(before, key=lambda k: targets[k].start)] if before else ks


def _from_unseen_points(targets: list, first: dict, motions: list, uses: list, joint_moves: list,
                        src_clean: str) -> list:
    """Notes for targets without ``S`` whose motion comes right after a motion to a point that is not a
    target of this file (a ``.dat`` point given as context) nor a joint move: the walk does not know the
    arm's configuration there and takes the joints before that motion (probe s42 AX: a LIN after ``PTP P24``
    was walked from XHOME's configuration and landed 1.76 mm off on P24's)."""
    moved_to = {mo.pos for mo, *_ in uses} | {p for p, _ in joint_moves}
    before = sorted((mo for mo in motions if not mo.rel), key=lambda mo: mo.pos)
    bpos = np.array([mo.pos for mo in before], dtype=np.int64)
    out = []
    own = {}
    for mo, k, *_ in uses:  # the motion that first moves to each target
        own[k] = min(own.get(k, mo.pos), mo.pos)
    for k, pos in first.items():
        t = targets[k]
        if "S" in t.config:
            continue
        i = int(np.searchsorted(bpos, own.get(k, pos)))  # motions strictly before this target's
        if not i or before[i - 1].pos in moved_to:
            continue
        mo = before[i - 1]
        line = src_clean.count("\n", 0, mo.pos) + 1
        what = " : ".join(op.text for op in mo.points[0]) if mo.points and mo.points[0] else "a point"
        out.append(f"line {t.line}: comes after {mo.verb} {what[:40]} (line {line} of the .src), a point not solved "
                   f"here (declared in another file): its arm configuration is not known to this run, which walks "
                   f"this target from the joints before that motion; if that point's S differs, the controller "
                   f"executes it on another branch. Check it, or put a joint move (PTP to an axis aggregate) before it")
    return out


def _uses(targets: list, points: list, text_is_src: bool) -> tuple[list, dict, dict, dict]:
    """``(uses, first, verb, every)``: the motions using each target (``[(motion, target index, left operands,
    right operands, why the point is unknown)]``), where each is first executed ``{target index:
    position in the .src}`` (an inline target at its literal, a variable at the first motion to it at or
    after its literal (the .src's own variables) or anywhere (a .dat's)), that motion's verb, and the
    positions of every motion to it ``{target index: [position]}``."""
    by_name: dict = {}
    for k, t in enumerate(targets):
        if t.name:
            by_name.setdefault(_key(t.name), []).append(k)
    by_start = {t.start: k for k, t in enumerate(targets)} if text_is_src else {}
    uses, seen = [], {}
    for mo, ai, ops, pi, why in points:
        if mo.rel:
            continue
        # an expression whose point is unknown: every target in it fails with the reason
        for i in ([pi] if pi is not None else range(len(ops))):
            op = ops[i]
            if op.what == "agg":
                hits = [by_start[op.start]] if op.start in by_start else []
            else:
                hits = _assigned(by_name.get(op.key, []), targets, mo.pos, text_is_src)
            for k in hits:
                uses.append((mo, k, ops[:i], ops[i + 1:], why))
                seen.setdefault(k, []).append((targets[k].start if op.what == "agg" else mo.pos + ai, mo.verb))
    first, verb = {}, {}
    for k, pos in seen.items():
        after = [p for p in pos if text_is_src and p[0] >= targets[k].start]
        first[k], verb[k] = min(after) if after else min(pos)
    return uses, first, verb, {k: sorted(p for p, _ in pos) for k, pos in seen.items()}


def format_target(t: ProgramTarget, command: np.ndarray, q, robot, axis_signs=None) -> str:
    """The aggregate of ``t`` with the command's X..C and, where present, the joints' S and T."""
    from .branches import kuka_status

    a, b, c = abc_from_matrix(command[:3, :3], t.parts["A"])
    new = {"X": command[0, 3] * 1e3, "Y": command[1, 3] * 1e3, "Z": command[2, 3] * 1e3, "A": a, "B": b, "C": c}
    vals = {k: f"{new[k]:.4f}" if k in "XYZ" else f"{new[k]:.5f}" for k in _CART}
    if "S" in t.parts["keys"]:
        S, T = kuka_status(robot, np.asarray(q)[None], t.parts["axis_signs"] if axis_signs is None else axis_signs)
        for k, val in (("S", int(S[0])), ("T", int(T[0]))):
            if k not in t.parts["keys"]:
                continue
            tok = t.parts["tokens"][k]
            vals[k] = f"'B{val:0{max(len(tok) - 3, 1)}b}'" if tok.startswith("'") else str(val)
    return splice_numbers(t.parts["literal"], t.parts["spans"], [vals[k] for k in t.parts["keys"]])


def written_pose(t: ProgramTarget, literal: np.ndarray) -> np.ndarray:
    """The pose ``(4, 4)`` the controller reads from the aggregate :func:`format_target` writes for the pose
    ``literal`` (its frame): X..C rounded as written (:mod:`.program_checks`)."""
    a, b, c = np.round(abc_from_matrix(literal[:3, :3], t.parts["A"]), 5)
    return se3.make_transform(matrix_from_abc(a, b, c), np.round(literal[:3, 3] * 1e3, 4) * 1e-3)
