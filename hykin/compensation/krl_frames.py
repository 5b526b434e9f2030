"""KUKA KRL: the base and tool each target is used with.

A KRL Cartesian target is a pose of ``$TOOL`` in ``$BASE``. The program selects them, in text order,
with ``$BASE = BASE_DATA[n]`` / ``$TOOL = TOOL_DATA[n]`` (or ``$NULLFRAME``, a frame aggregate, a
``FRAME`` variable the program assigns an aggregate), ``BAS(#BASE, n)`` / ``BAS(#TOOL, n)``, the inline
forms' ``FDAT_ACT = FPn`` (``BASE_NO``, ``TOOL_NO`` and ``IPO_FRAME`` of ``DECL FDAT FPn = {...}`` in the
``.dat``), and the spline inline forms' ``WITH $TOOL = STOOL2(FPn), $BASE = SBASE(FPn.BASE_NO),
$IPO_MODE = SIPO_MODE(FPn.IPO_FRAME)`` (the same ``FDAT`` data). ``BASE_DATA[n]`` and ``TOOL_DATA[n]``
are declared in the controller's ``$config.dat`` (``BASE_DATA[1]={X ..,Y ..,Z ..,A ..,B ..,C ..}``);
hykin reads them from the program and the ``--context`` files.

A ``WITH`` selection is taken for its own motion (a ``SPLINE`` block's for the block's motions). Whether
it outlasts the motion is not taken for granted: a later motion without its own selection, whose
frame would differ either way, fails and says so.

Per target (the selection in force at the motion statement that uses it; before any, base 0 and the
robot file's tool): the frame ``W`` = ``BASE_DATA[n]`` the pose is written in (``$WORLD`` taken as
``$ROBROOT``, base 0 = the robot base frame) and the tool delta ``D = inv(robot file's tool) ·
TOOL_DATA[n]``. Tool 0 and tools whose data were not read are the robot file's tool (a note names
them). A point moved to inside a geometric expression ``L : P : R`` with known frames ``L``, ``R`` is
in frame ``W · L`` with the TCP ``TOOL · inv(R)``: the controller then sends the flange where the
compensated ``P`` puts it. A target fails, with the reason, when its base or tool is not declared in
what was read (tools: noted instead), is set by an expression hykin cannot evaluate, is an external TCP
(``IPO_FRAME #TCP``), or when one target is used with two different frames.
"""

from __future__ import annotations

import re

import numpy as np

from ..geometry import se3
from ..io.urdf_flange import flange_of
from .krl_motions import is_declaration
from .programs import TargetFrames, line_of

__all__ = ["frame_variables", "frames_of_targets"]

_FRAME_DATA = re.compile(r"\b(BASE_DATA|TOOL_DATA)\s*\[\s*(\d+)\s*\]\s*=\s*\{([^{}]*)\}", re.IGNORECASE)
_FDAT = re.compile(r"\bFDAT\s+([A-Za-z_]\w*)\s*=\s*\{([^{}]*)\}", re.IGNORECASE)
_SELECT = re.compile(
    r"(?P<var>\$BASE|\$TOOL|\$IPO_MODE)\s*=(?!=)\s*(?P<expr>[^\n]*)"
    r"|\bBAS\s*\(\s*#(?P<bas>BASE|TOOL)\s*,\s*(?P<bn>\d+)\s*\)"
    r"|\bFDAT_ACT\s*=\s*(?P<fdat>[A-Za-z_]\w*)", re.IGNORECASE)
_FRAME_ASSIGN = re.compile(r"(?<![\w$.])([A-Za-z_][\w]*)\s*(\.\s*[A-Za-z]\w*)?\s*=(?!=)\s*([^\n]*)")
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
# run-time changes of frame data: a component of $BASE/$TOOL (``$TOOL.X = 30.0``), a BASE_DATA/TOOL_DATA
# entry or its component (``BASE_DATA[1].Z = BASE_DATA[1].Z + 20.0``), ``+=`` forms too
_CHANGE = re.compile(r"(?P<sys>\$BASE|\$TOOL)\s*\.\s*\w+(?:\s*\.\s*\w+)*\s*[-+*/]?=(?!=)[^\n]*"
                     r"|\b(?P<data>BASE_DATA|TOOL_DATA)\s*\[\s*(?P<n>[^\]]*?)\s*\](?:\s*\.\s*\w+)*\s*[-+*/]?=(?!=)[^\n]*",
                     re.IGNORECASE)
_DATA_BLOCK = re.compile(r"^[ \t]*DEFDAT\b.*?(?:^[ \t]*ENDDAT\b|\Z)", re.IGNORECASE | re.MULTILINE | re.DOTALL)
_INDEX = r"(?:(?P<i>\d+)|(?P<f>[A-Za-z_]\w*)\s*\.\s*(?P<field>BASE_NO|TOOL_NO))"
_KINDS = ("base", "tool", "ipo")


def _aggregate_frame(body: str) -> np.ndarray | None:
    """A complete ``X, Y, Z`` (mm), ``A, B, C`` (deg) aggregate as a (4, 4) frame (m), else None.
    ``R = Rz(A) Ry(B) Rx(C)`` is URDF roll-pitch-yaw ``(C, B, A)``."""
    comps = {m.group(1).upper(): float(m.group(2)) for m in re.finditer(r"\b([XYZABC])\s+(" + _NUMBER + ")", body)}
    if not all(k in comps for k in "XYZABC"):
        return None
    return se3.xyzrpy_to_transform(np.array([comps["X"], comps["Y"], comps["Z"]]) * 1e-3,
                                   np.radians([comps["C"], comps["B"], comps["A"]]))


def _declared(cleans: list) -> tuple[dict, dict]:
    """``({("base"|"tool", n): (4, 4)}, {FDAT name: {"TOOL_NO": n, "BASE_NO": n, "IPO_FRAME": str}})``."""
    frames, fdat = {}, {}
    for clean in cleans:
        for m in _FRAME_DATA.finditer(clean):
            T = _aggregate_frame(m.group(3))
            if T is not None:
                frames[(m.group(1).upper()[:4].lower(), int(m.group(2)))] = T
        for m in _FDAT.finditer(clean):
            d = {k.upper(): v for k, v in re.findall(r"\b(TOOL_NO|BASE_NO)\s+(\d+)", m.group(2), re.IGNORECASE)}
            ipo = re.search(r"\bIPO_FRAME\s+#(\w+)", m.group(2), re.IGNORECASE)
            fdat[m.group(1).upper()] = {"TOOL_NO": int(d["TOOL_NO"]) if "TOOL_NO" in d else None,
                                        "BASE_NO": int(d["BASE_NO"]) if "BASE_NO" in d else None,
                                        "IPO_FRAME": ipo.group(1).upper() if ipo else "BASE"}
    return frames, fdat


def frame_variables(src_clean: str, others: list, types: dict) -> dict:
    """``{variable (upper case): [(position in src_clean, or -1 elsewhere, value)]}`` of the variables
    declared ``FRAME``: value ``(4, 4)`` for a complete aggregate, else a str (why it is unknown: a
    partial aggregate, an expression, a component assignment ``f.X = ..``)."""
    out: dict = {}
    for clean, here in [(c, False) for c in others] + [(src_clean, True)]:
        for m in _FRAME_ASSIGN.finditer(clean):
            name = m.group(1).upper()
            if types.get(name) != "FRAME":
                continue
            rhs = m.group(3).strip()
            agg = re.fullmatch(r"\{(?:\s*FRAME\s*:)?([^{}]*)\}", rhs, re.IGNORECASE)
            T = _aggregate_frame(agg.group(1)) if agg and not m.group(2) else None
            where = f"line {line_of(clean, m.start())}{'' if here else ' of a companion file'}"
            why = T if T is not None else f"{m.group(1)}{m.group(2) or ''} = {rhs[:30]} ({where}): not a frame aggregate"
            pos = m.start() if here and not is_declaration(clean, m.start()) else -1
            out.setdefault(name, []).append((pos, why))
    return out


def _index(expr: str, fdat: dict) -> int | str:
    """A data index: a number, or ``FPn.BASE_NO`` / ``FPn.TOOL_NO`` of a declared ``FDAT``."""
    m = re.fullmatch(r"\s*" + _INDEX + r"\s*", expr, re.IGNORECASE)
    if m is None:
        return f"index {expr.strip()[:30]}: an expression hykin cannot evaluate"
    if m.group("i") is not None:
        return int(m.group("i"))
    d = fdat.get(m.group("f").upper())
    if d is None:
        return f"{m.group('f')}: its FDAT declaration (the .dat) was not read"
    n = d[m.group("field").upper()]
    return n if n is not None else f"{m.group('f')} has no {m.group('field').upper()}"


class _Selections:
    """Evaluates the right-hand sides of ``$BASE``/``$TOOL``/``$IPO_MODE`` assignments: a base or tool is
    an int (data index, 0 = none), a (4, 4) frame, or a str (why it is unknown); the interpolation mode
    ``"BASE"``, ``"TCP"`` or a str."""

    def __init__(self, fdat: dict, fvars: dict, types: dict, changed: dict | None = None):
        self.fdat, self.fvars, self.types = fdat, fvars, types
        self.changed = changed or {}  # {("base"|"tool", n or None = any): [(position, why)]}: run-time changes

    def checked(self, kind: str, value, pos: int):
        """``value`` (a data index) as selected at ``pos``: a str where the program changes that entry of
        ``BASE_DATA``/``TOOL_DATA`` at run time before ``pos`` (its value there is not the declared one)."""
        if kind not in ("base", "tool") or isinstance(value, (str, np.ndarray)) or value == 0:
            return value
        hit = [w for k in ((kind, value), (kind, None)) for p, w in self.changed.get(k, []) if p < pos]
        return hit[-1] if hit else value

    def is_frame(self, name: str) -> bool:
        """Whether ``name`` is a variable declared ``FRAME`` (or assigned like one)."""
        return name.upper() in self.fvars or self.types.get(name.upper()) == "FRAME"

    def fdat_act(self, name: str) -> list:
        """``[(kind, value)]`` that ``FDAT_ACT = name`` selects."""
        d = self.fdat.get(name.upper())
        if d is None:
            why = f"FDAT_ACT = {name}: its FDAT declaration (the .dat) was not read"
            return [("base", why), ("tool", why)]
        out = [("ipo", d["IPO_FRAME"])]
        out += [("base", d["BASE_NO"])] if d["BASE_NO"] is not None else []
        return out + ([("tool", d["TOOL_NO"])] if d["TOOL_NO"] is not None else [])

    def fdat_act_at(self, name: str, pos: int) -> list:
        """:meth:`fdat_act` at ``pos`` (:meth:`checked`)."""
        return [(k, self.checked(k, v, pos)) for k, v in self.fdat_act(name)]

    def assign(self, var: str, expr: str, pos: int) -> list:
        """``[(kind, value)]`` that ``var = expr`` (at ``pos`` in the ``.src``) selects; other variables: []."""
        var, e = var.upper(), expr.strip()
        if var == "$IPO_MODE":
            return [("ipo", self._ipo(e))]
        if var not in ("$BASE", "$TOOL"):
            return []
        kind = var[1:].lower()
        return [(kind, self.checked(kind, self._frame(kind, e, pos), pos))]

    def _ipo(self, e: str) -> str:
        m = re.fullmatch(r"#(BASE|TCP)", e, re.IGNORECASE) or re.fullmatch(
            r"SIPO_MODE\s*\(\s*([A-Za-z_]\w*)\s*\.\s*IPO_FRAME\s*\)", e, re.IGNORECASE)
        if m is None:
            return f"$IPO_MODE = {e[:40]}: an expression hykin cannot evaluate"
        if m.group(1).upper() in ("BASE", "TCP") and e.startswith("#"):
            return m.group(1).upper()
        d = self.fdat.get(m.group(1).upper())
        return d["IPO_FRAME"] if d else f"{m.group(1)}: its FDAT declaration (the .dat) was not read"

    def _frame(self, kind: str, e: str, pos: int):
        data = re.fullmatch(r"(BASE_DATA|TOOL_DATA)\s*\[(.*)\]", e, re.IGNORECASE)
        call = re.fullmatch(r"(STOOL2|SBASE)\s*\((.*)\)", e, re.IGNORECASE)
        if data and data.group(1).upper()[:4].lower() == kind:
            return _index(data.group(2), self.fdat)
        if call and (call.group(1).upper() == "SBASE") == (kind == "base"):
            if call.group(1).upper() == "SBASE":
                return _index(call.group(2), self.fdat)
            return _index(call.group(2).strip() + ".TOOL_NO", self.fdat)  # STOOL2(F): TOOL_DATA[F.TOOL_NO]
        if re.fullmatch(r"\$(NULLFRAME|WORLD|ROBROOT)", e, re.IGNORECASE):
            return 0
        agg = re.fullmatch(r"\{(?:\s*FRAME\s*:)?([^{}]*)\}", e, re.IGNORECASE)
        if agg:
            T = _aggregate_frame(agg.group(1))
            return T if T is not None else f"${kind.upper()} = {{..}} is not a complete frame"
        if re.fullmatch(r"[A-Za-z_]\w*", e) and self.is_frame(e):
            return self.variable(e, pos)
        return f"${kind.upper()} = {e[:40]}: an expression hykin cannot evaluate"

    def variable(self, name: str, pos: int):
        """The value of ``FRAME`` variable ``name`` at ``pos``: its last assignment before, else its
        declaration elsewhere (the ``.dat``), else a str."""
        vals = [v for p, v in self.fvars.get(name.upper(), []) if p < pos]
        return vals[-1] if vals else f"FRAME {name} is not assigned a frame aggregate before it is used here"


def _persistent_events(src_clean: str, with_spans: list, sel: _Selections) -> list:
    """``[(position, kind, value)]``: the selections outside ``WITH`` clauses, in text order."""
    blank = list(src_clean)
    for a, b in with_spans:  # WITH items select for their motion only: taken per motion
        blank[a:b] = " " * (b - a)
    text = "".join(blank)
    out = []
    for m in _SELECT.finditer(text):
        if m.group("fdat"):
            out += [(m.start(), k, v) for k, v in sel.fdat_act_at(m.group("fdat"), m.start())]
        elif m.group("bas"):
            kind = m.group("bas").lower()
            out.append((m.start(), kind, sel.checked(kind, int(m.group("bn")), m.start())))
        else:
            out += [(m.start(), k, v) for k, v in sel.assign(m.group("var"), m.group("expr"), m.start())]
    out += [(p, kind, why) for (kind, n), changes in sel.changed.items() if n == "$" for p, why in changes]
    return sorted(out, key=lambda e: e[0])


def run_time_changes(src_clean: str, where: str = "") -> dict:
    """``{(kind, n): [(position, why)]}`` of the statements of ``src_clean`` (outside its ``DEFDAT`` blocks:
    not ``$config.dat``'s declarations) that change frame data at run time: ``BASE_DATA[n]``/``TOOL_DATA[n]``
    or a component of them (``n`` None: an index hykin cannot read), and components of ``$BASE``/``$TOOL``
    (``n`` ``"$"``: the selection in force becomes unknown from there). ``where``: the prefix of the line
    numbers (the companion file's ``"--context, "``)."""
    data = [(m.start(), m.end()) for m in _DATA_BLOCK.finditer(src_clean)]
    out: dict = {}
    for m in _CHANGE.finditer(src_clean):
        if any(a <= m.start() < b for a, b in data) or is_declaration(src_clean, m.start()):
            continue
        stmt = " ".join(m.group(0).split())[:60]
        at = f"{where}line {line_of(src_clean, m.start())}"
        if m.group("sys"):
            kind = m.group("sys")[1:].lower()
            key = (kind, "$")
        else:
            kind = m.group("data")[:4].lower()
            key = (kind, int(m.group("n")) if m.group("n").isdigit() else None)
        why = (f"{stmt} ({at}) changes the {kind} at run time: hykin does not follow run-time changes of "
               f"frame data (select a {kind} whose data are declared, or move the change into $config.dat)")
        out.setdefault(key, []).append((m.start(), why))
    return out


def _same(a, b) -> bool:
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        return isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and np.allclose(a, b, atol=1e-12)
    return a == b


def motion_states(src_clean: str, motions: list, with_spans: list, sel: _Selections) -> dict:
    """``{id(motion): {"base", "tool", "ipo": value}}``: the selections in force at each motion: the
    persistent ones, overridden by the ``SPLINE`` block's and the motion's own ``WITH`` items. A kind a
    motion does not select itself, where an earlier ``WITH`` selected another value since the last
    persistent selection, is a str: it depends on whether that ``WITH`` outlasted its motion."""
    events = _persistent_events(src_clean, with_spans, sel)
    state = {"base": 0, "tool": 0, "ipo": "BASE"}
    scoped: dict = {}  # kind -> (value, position) of the last WITH selection since the persistent one
    out, i = {}, 0
    for mo in sorted(motions, key=lambda mo: mo.pos):
        while i < len(events) and events[i][0] < mo.pos:
            _, kind, value = events[i]
            state[kind] = value
            scoped.pop(kind, None)
            i += 1
        own = {}
        for var, expr, pos in mo.block_items + mo.with_items:
            own.update(dict(sel.assign(var, expr, pos)))
        st = dict(state)
        for kind in _KINDS:
            if kind in own:
                st[kind] = own[kind]
                scoped[kind] = (own[kind], mo.pos)
            elif kind in scoped and not _same(scoped[kind][0], state[kind]):
                st[kind] = (f"${'IPO_MODE' if kind == 'ipo' else kind.upper()} of this motion depends on whether the "
                            f"WITH selection of line {line_of(src_clean, scoped[kind][1])} outlasts its motion: select "
                            "it before the motion or in its own WITH")
        out[id(mo)] = st
    return out


def _operand_frame(op, sel: _Selections, pos: int):
    """The frame ``(4, 4)`` of an operand of a geometric expression (an aggregate or a ``FRAME``
    variable), else a str."""
    if op.what == "agg":
        T = _aggregate_frame(re.sub(r"^\{\s*[A-Za-z_]\w*\s*:", "{", op.text)[1:-1])
        return T if T is not None else f"{op.text[:30]} is not a complete frame"
    if op.what == "var" and sel.is_frame(op.key):
        return sel.variable(op.text, pos)
    return f"{op.text[:30]}: hykin cannot evaluate this operand of a geometric expression"


def _product(ops: list, sel: _Selections, pos: int):
    """The product of the operands' frames (None for no operand), or a str."""
    T = None
    for op in ops:
        F = _operand_frame(op, sel, pos)
        if isinstance(F, str):
            return F
        T = F if T is None else T @ F
    return T


def frames_of_targets(src_clean: str, others: list, motions: list, with_spans: list, uses: list, targets: list,
                      robot, types: dict, where: str = "") -> TargetFrames:
    """Frames of ``targets`` (of the file read) from the selections of ``src_clean`` (the ``.src`` text
    with comments blanked), its ``motions`` and ``with_spans`` (:func:`.krl_motions.parse_motions`), the
    data declared in it and ``others`` (the other texts read, comments blanked), the variables' ``types``
    and ``uses``: ``[(motion, target index, left operands, right operands, error)]`` (the operands of the
    geometric expression around the point; error: why the point is not known, or "")."""
    frames, fdat = _declared([src_clean, *others])
    sel = _Selections(fdat, frame_variables(src_clean, others, types), types, run_time_changes(src_clean, where))
    states = motion_states(src_clean, motions, with_spans, sel)
    per: dict = {}
    for mo, k, left, right, err in uses:
        L = _product(left, sel, mo.pos)
        R = _product(right, sel, mo.pos)
        per.setdefault(k, []).append((states[id(mo)], err or (L if isinstance(L, str) else "")
                                      or (R if isinstance(R, str) else ""), L, R))
    out, noted = TargetFrames(), set()
    default = ({"base": 0, "tool": 0, "ipo": "BASE"}, "", None, None)
    for k in range(len(targets)):
        out.add([_resolve(st, err, L, R, frames, robot, targets[k].line, out.notes, noted)
                 for st, err, L, R in per.get(k, [default])], "used with different bases or tools")
        unread = sorted({st["tool"] for st, *_ in per.get(k, []) if isinstance(st["tool"], int) and st["tool"] != 0
                         and ("tool", st["tool"]) not in frames})
        if unread:  # a failure of this target may come from that tool
            out.caveat[k] = (f"tool {unread[0]} (TOOL_DATA[{unread[0]}]) was not read, so its TCP was taken to be the "
                             "robot file's tool (give $config.dat with --context)")
    return out


def _resolve(st: dict, err: str, L, R, frames: dict, robot, line: int, notes: list, noted: set) -> tuple:
    """``(W, D, error, label)`` of one use: the base frame (times the expression's left frames), the tool
    delta (the tool times the inverse of its right frames), why it is unknown, a label for messages."""
    base, tool, ipo = st["base"], st["tool"], st["ipo"]
    W = None
    if isinstance(base, str):
        err = err or base
    elif isinstance(base, np.ndarray):
        W = base
    elif base != 0:
        W = frames.get(("base", base))
        if W is None:
            err = err or (f"base {base} (BASE_DATA[{base}]) is not declared in what was read: its pose is unknown "
                          "(give the controller's $config.dat with --context)")
    if ipo != "BASE":
        err = err or (ipo if ipo != "TCP" else "it moves relative to an external TCP (IPO_FRAME #TCP): not supported")
    T = None  # the program's TCP in the flange frame; None: the robot file's tool
    if isinstance(tool, str):
        err = err or tool
    elif isinstance(tool, np.ndarray):
        T = tool
    elif tool != 0:
        T = frames.get(("tool", tool))
        if T is None and tool not in noted:
            noted.add(tool)
            notes.append(f"{line}: tool {tool} (TOOL_DATA[{tool}]) was not read: its TCP is taken to be the robot "
                         "file's tool (give $config.dat with --context)")
    if isinstance(L, np.ndarray):
        W = L if W is None else W @ L
    if T is not None:  # TOOL_DATA is given from the controller's flange (a URDF's flange link: urdf_flange)
        T = flange_of(robot) @ T
    if isinstance(R, np.ndarray):  # moving TOOL to P · R = moving TOOL · inv(R) to P
        T = (robot.tool if T is None else T) @ se3.invert(R)
    D = None if T is None else se3.invert(robot.tool) @ T
    label = (f"base {base if isinstance(base, int) else '(frame)'}, tool {tool if isinstance(tool, int) else '(frame)'}"
             + (" in a geometric expression" if L is not None or R is not None else ""))
    return W, D, err, label
