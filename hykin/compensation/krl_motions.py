"""KUKA KRL: motion statements, declarations, and the order the robot executes its targets in.

Motion statements (one per line, comments blanked): ``PTP``/``LIN``/``CIRC``, their ``_REL`` forms, the
spline motions ``SPTP``/``SLIN``/``SCIRC`` and ``SPL`` (inside ``SPLINE`` / ``PTP_SPLINE`` ...
``ENDSPLINE`` blocks)::

    VERB point[, point2][[,] CA angle] [C_DIS|C_PTP|C_VEL|C_ORI|C_SPL] [WITH $VAR = expr, ...]

``CIRC``/``SCIRC`` move through their first point (auxiliary) to their second. A point is a variable,
an aggregate ``{...}``, or a geometric expression ``F1 : P : F2`` (KRL's frame product, left to right)
of those. The ``WITH`` items of a motion, and of the ``SPLINE`` block around it, are kept per motion
(:mod:`.krl_frames` resolves the ``$BASE``/``$TOOL`` they select).

Execution order: the robot meets a ``.dat`` point (or a ``.src`` variable) where a ``.src`` motion moves
to it, not where it is declared; :func:`set_execution_order` gives each target that position as its
``order`` and the joints of the last joint-space move (``PTP``/``SPTP`` to an ``AXIS``/``E6AXIS``
aggregate or variable) before it, when no other target lies between, as its ``reset``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Motion", "Operand", "axis_values", "declared_types", "is_declaration", "joint_moves", "parse_motions",
           "point_of", "set_execution_order", "split_top"]

_MOTION_LINE = re.compile(r"^[ \t]*(?P<verb>S?PTP|S?LIN|S?CIRC|SPL)(?P<rel>_REL)?\b(?P<rest>[^\n]*)",
                          re.IGNORECASE | re.MULTILINE)
_BLOCK_LINE = re.compile(r"^[ \t]*(?P<start>(?:PTP_)?SPLINE\b(?P<rest>[^\n]*))|^[ \t]*(?P<end>ENDSPLINE)\b",
                         re.IGNORECASE | re.MULTILINE)
_WITH = re.compile(r"\bWITH\b", re.IGNORECASE)
_APPROX = re.compile(r"\bC_(?:DIS|PTP|VEL|ORI|SPL)\b", re.IGNORECASE)
# a circular motion's circular angle ``CA angle``: after the end point, with or without a comma
_CA = re.compile(r"(?:,\s*)?\bCA\b(?=\s*[-+(\w.])", re.IGNORECASE)
_IDENT = re.compile(r"[A-Za-z_$][\w$]*(?:\s*\[[^\[\]]*\])?$")
_TYPE_DECL = re.compile(r"^[ \t]*(?:(?:DECL|GLOBAL|CONST)\s+)*(?P<type>E6POS|POS|FRAME|E6AXIS|AXIS)\s+(?P<rest>[^\n]*)",
                        re.IGNORECASE | re.MULTILINE)
_AXIS_AGG = re.compile(r"([A-Za-z_$][\w$]*)\s*=\s*\{([^{}]*)\}")
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_POINT_TYPES = ("POS", "E6POS")


@dataclass
class Operand:
    """One operand of a motion's point: ``text`` (stripped), its span in the text, and what it is:
    ``"agg"`` (an aggregate ``{...}``), ``"var"`` (a variable, ``key`` its upper-case name without
    spaces) or ``"expr"`` (anything else: a function call, arithmetic)."""

    text: str
    start: int
    end: int
    what: str
    key: str = ""


@dataclass
class Motion:
    """A motion statement: ``pos`` (its first character), ``verb`` (upper case), ``rel`` (a ``_REL``
    form), ``points``: per point argument the operands of its geometric expression (``:``, left to
    right), ``with_items``: ``[(variable (upper case), expression, position)]`` of its own ``WITH``
    clause, ``block_items``: those of the enclosing ``SPLINE`` block, ``with_span``: the
    ``(start, end)`` of its ``WITH`` clause (or None)."""

    pos: int
    verb: str
    rel: bool
    points: list
    with_items: list = field(default_factory=list)
    block_items: list = field(default_factory=list)
    with_span: tuple | None = None


def split_top(s: str, sep: str) -> list:
    """``[(piece, offset)]``: ``s`` split at the ``sep`` characters outside ``{} [] ()``."""
    out, depth, last = [], 0, 0
    for i, c in enumerate(s):
        if c in "{[(":
            depth += 1
        elif c in "}])":
            depth = max(depth - 1, 0)
        elif c == sep and depth == 0:
            out.append((s[last:i], last))
            last = i + 1
    out.append((s[last:], last))
    return out


def _top_search(pattern: re.Pattern, s: str) -> re.Match | None:
    """The first match of ``pattern`` in ``s`` outside ``{} [] ()`` (a ``WITH`` inside a string or an
    aggregate is not the clause)."""
    for m in pattern.finditer(s):
        head = s[: m.start()]
        if sum(head.count(c) for c in "{[(") <= sum(head.count(c) for c in "}])"):
            return m
    return None


def _operand(text: str, start: int) -> Operand | None:
    """The operand ``text`` (raw, as in the statement) starting at ``start``; None when blank."""
    lead = len(text) - len(text.lstrip())
    body = re.sub(r"\s+#\w+\s*$", "", text.strip())  # a relative motion's #TOOL / #BASE qualifier
    if not body:
        return None
    s = start + lead
    if body.startswith("{") and body.endswith("}"):
        return Operand(body, s, s + len(body), "agg")
    if _IDENT.match(body):
        return Operand(body, s, s + len(body), "var", re.sub(r"\s+", "", body).upper())
    return Operand(body, s, s + len(body), "expr")


def _with_items(clause: str, start: int) -> list:
    """``[(variable (upper case), expression, position)]`` of a ``WITH`` clause starting at ``start``."""
    items = []
    for piece, off in split_top(clause, ","):
        m = re.match(r"\s*([$A-Za-z_][\w$]*(?:\s*\[[^\]]*\])?)\s*=(?!=)\s*(.*?)\s*$", piece, re.DOTALL)
        if m:
            items.append((re.sub(r"\s+", "", m.group(1)).upper(), m.group(2), start + off + m.start(1)))
    return items


def _blocks(clean: str) -> list:
    """``[(start, end, WITH items, WITH span or None)]`` of the ``SPLINE`` / ``PTP_SPLINE`` blocks (end:
    the ``ENDSPLINE``)."""
    out, open_ = [], None
    for m in _BLOCK_LINE.finditer(clean):
        if m.group("start"):
            rest, r0 = m.group("rest"), m.start("rest")
            w = _top_search(_WITH, rest)
            open_ = (m.start("start"), _with_items(rest[w.end():], r0 + w.end()) if w else [],
                     (r0 + w.start(), m.end("rest")) if w else None)
        elif open_ is not None:
            out.append((open_[0], m.start("end"), open_[1], open_[2]))
            open_ = None
    if open_ is not None:  # no ENDSPLINE: the block runs to the end of the text
        out.append((open_[0], len(clean), open_[1], open_[2]))
    return out


def parse_motions(clean: str) -> tuple[list, list]:
    """``(motions, with_spans)`` of a text with comments and strings blanked: the :class:`Motion` s in
    text order and the ``(start, end)`` of every ``WITH`` clause (motions' and blocks')."""
    blocks = _blocks(clean)
    bstart = np.array([b[0] for b in blocks], dtype=np.int64)
    spans = [b[3] for b in blocks if b[3] is not None]
    motions = []
    for m in _MOTION_LINE.finditer(clean):
        rest, r0 = m.group("rest"), m.start("rest")
        w = _top_search(_WITH, rest)
        args = rest[: w.start()] if w else rest
        a = _top_search(_APPROX, args)
        args = args[: a.start()] if a else args
        n_points = 2 if m.group("verb").upper().endswith("CIRC") else 1
        if n_points == 2:  # CIRC aux, end CA 90.0: the angle is no part of the end point
            ca = _top_search(_CA, args)
            if ca and len(split_top(args[: ca.start()], ",")) >= 2:  # after the end point
                args = args[: ca.start()]
        points = []
        for piece, off in split_top(args, ",")[:n_points]:
            ops = [_operand(t, r0 + off + o) for t, o in split_top(piece, ":")]
            if all(op is not None for op in ops):
                points.append(ops)
        span = (r0 + w.start(), m.end("rest")) if w else None
        if span:
            spans.append(span)
        i = int(np.searchsorted(bstart, m.start())) - 1  # the last block opened before the motion
        block = blocks[i][2] if i >= 0 and m.start() < blocks[i][1] else []
        motions.append(Motion(pos=m.start("verb"), verb=m.group("verb").upper(), rel=bool(m.group("rel")),
                              points=points, with_items=_with_items(rest[w.end():], r0 + w.end()) if w else [],
                              block_items=block, with_span=span))
    return motions, spans


def declared_types(cleans: list) -> dict:
    """``{variable (upper case): "E6POS"|"POS"|"FRAME"|"E6AXIS"|"AXIS"}`` from the declarations of the
    texts (``DECL FRAME fA, fB`` declares both; arrays by their name)."""
    types = {}
    for clean in cleans:
        for m in _TYPE_DECL.finditer(clean):
            for piece, _ in split_top(m.group("rest"), ","):
                name = re.match(r"\s*([A-Za-z_$][\w$]*)", piece)
                if name:
                    types.setdefault(name.group(1).upper(), m.group("type").upper())
    return types


def _axes(body: str, n: int, signs: np.ndarray) -> np.ndarray | None:
    """Joints ``(n,)`` rad (hykin's signs) of an aggregate body with every ``A1..An`` and no ``X``; else None."""
    comps = {k.upper(): float(v) for k, v in re.findall(r"\b([A-Za-z]\w*)\s+(" + _NUMBER + ")", body)}
    if "X" in comps or not all(f"A{i + 1}" in comps for i in range(n)):
        return None
    return signs * np.radians([comps[f"A{i + 1}"] for i in range(n)])


def axis_values(src_clean: str, others: list, n: int, signs: np.ndarray) -> dict:
    """``{variable (upper case): [(position in src_clean, or -1 elsewhere, joints (n,) rad)]}`` of the
    complete axis aggregates declared or assigned to variables (``DECL E6AXIS XHOME={A1 0,..}``)."""
    out: dict = {}
    for clean, here in [(c, False) for c in others] + [(src_clean, True)]:
        for m in _AXIS_AGG.finditer(clean):
            q = _axes(m.group(2), n, signs)
            if q is not None:
                pos = m.start() if here and not is_declaration(clean, m.start()) else -1
                out.setdefault(m.group(1).upper(), []).append((pos, q))
    return out


def is_declaration(clean: str, pos: int) -> bool:
    """Whether the statement at ``pos`` is a declaration (``DECL ...``, ``E6AXIS x = ..``): its value holds
    from the start, wherever the text (the ``.src``, ``$config.dat`` joined after it) puts it."""
    ls = clean.rfind("\n", 0, pos) + 1
    return (_TYPE_DECL.match(clean, ls) is not None
            or re.match(r"[ \t]*DECL\b", clean[ls:pos], re.IGNORECASE) is not None)


def joint_moves(motions: list, axes: dict, n: int, signs: np.ndarray) -> list:
    """``[(position, joints (n,) rad)]`` of the joint-space moves: ``PTP``/``SPTP`` to an axis aggregate,
    or to a variable holding one (its value last assigned before the move, else its declaration)."""
    out = []
    for mo in motions:
        if mo.verb not in ("PTP", "SPTP") or mo.rel or len(mo.points) != 1 or len(mo.points[0]) != 1:
            continue
        op = mo.points[0][0]
        q = None
        if op.what == "agg":
            q = _axes(op.text[1:-1], n, signs)
        elif op.what == "var" and op.key in axes:
            before = [v for p, v in axes[op.key] if p < mo.pos]
            q = before[-1] if before else None
        if q is not None:
            out.append((mo.pos, q))
    return out


def point_of(ops: list, types: dict) -> tuple[int | None, str]:
    """Which operand of a geometric expression ``ops`` is the point moved to: ``(index, "")``, or
    ``(None, why)``. One operand: it. Several: the one of type ``POS``/``E6POS`` (a typed aggregate or a
    declared variable); else the one not of type ``FRAME`` when exactly one is not."""
    if len(ops) == 1:
        return 0, ""

    def typ(op):
        if op.what == "agg":
            m = re.match(r"\{\s*([A-Za-z_]\w*)\s*:", op.text)
            return m.group(1).upper() if m else "FRAME"  # an untyped aggregate in an expression is a frame
        return types.get(re.sub(r"\[.*", "", op.key), "") if op.what == "var" else ""

    kinds = [typ(op) for op in ops]
    pts = [i for i, k in enumerate(kinds) if k in _POINT_TYPES]
    if len(pts) != 1:
        pts = [i for i, k in enumerate(kinds) if k != "FRAME"]
    if len(pts) == 1 and all(op.what != "expr" for op in ops):
        return pts[0], ""
    return None, (f"the point of the geometric expression {' : '.join(op.text for op in ops)[:60]} is not one "
                  "variable or aggregate of type POS/E6POS among FRAME operands")


def set_execution_order(targets: list, first_use: dict, span: int, joints: list, every: dict | None = None) -> None:
    """Set ``order``, ``reset`` and ``after`` of ``targets`` (:class:`.programs.ProgramTarget`): ``first_use``
    ``{target index: position}`` (of the motion that first moves to it, in the ``.src`` text of length
    ``span``); unused targets come after every used one, in text order. ``every`` ``{target index:
    [position]}``: every motion to each target (default: the first). ``after``: the target of the last motion
    before this one's, where that is a later use of a target than its first (a ``.dat`` point moved to
    again: probe s42 AX, a LIN after ``PTP P24`` was walked from the target before P24's first use and
    executed 1.76 mm off). ``reset``: the joints of the last of ``joints`` ``[(position, q)]`` between that
    motion and this one (None when there is none or the target is unused)."""
    for k, t in enumerate(targets):
        t.order = first_use.get(k, span + t.start)
    every = every or {k: [p] for k, p in first_use.items()}
    events = sorted((p, k) for k, ps in every.items() for p in ps)  # every motion to a target, in the .src
    epos = np.array([p for p, _ in events], dtype=np.int64)
    jpos = np.array([p for p, _ in joints], dtype=np.int64)
    below = cur = -1  # the largest order of a used target before this one's, and this one's group's
    for k in sorted(range(len(targets)), key=lambda k: (targets[k].order, k)):
        t = targets[k]
        if k not in first_use:
            t.reset = None
            continue
        if t.order > cur:
            below, cur = cur, t.order
        e = int(np.searchsorted(epos, t.order))  # motions strictly before this target's
        last_pos, last_k = events[e - 1] if e else (-1, None)
        t.after = last_k if last_k is not None and last_pos > below else None
        i = int(np.searchsorted(jpos, t.order))  # joint moves strictly before the target's motion
        t.reset = joints[i - 1][1] if i and jpos[i - 1] > last_pos else None
