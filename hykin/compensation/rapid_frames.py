"""ABB RAPID: the work object and tool each robtarget is used with.

A robtarget is a pose of the instruction's tool in the instruction's work object (``\\WObj:=name``,
default ``wobj0``, the robot base frame here). This module reads, from the program (and the
``--context`` modules):

* ``tooldata`` declarations ``[robhold, [[x,y,z],[q1..q4]], tload]`` (mm, quaternion scalar first) and
  ``wobjdata`` declarations ``[robhold, ufprog, "ufmec", uframe, oframe]``;
* motion statements (``MoveL ToPoint, Speed, Zone, Tool \\WObj:=W`` and the other instructions of
  :data:`MOTION_ARGUMENTS`): which robtargets (literals, or declared names anywhere in the statement,
  ``Offs(p10, ..)`` included) each uses with which tool and work object.

Per target it gives the frame ``W = uframe · oframe`` the literal is expressed in (``pose in the base
frame = W · literal``) and the tool delta ``D = inv(robot file's tool) · tframe``. ``tool0`` and tools
not declared in what was read are the robot file's tool (the TCP the model was fitted for; a note
names an undeclared one). A target fails, with the reason, when its work object is not declared (its
pose in the base frame is unknown), is robot-held (``robhold TRUE``: a stationary tool), moved by a
mechanical unit (``ufmec``) or not programmed (``ufprog FALSE``), when its tool is stationary
(``robhold FALSE``), or when one literal is used with two different frames. World frame = robot base
frame (a robot whose base is placed elsewhere in the world needs its targets converted first).
"""

from __future__ import annotations

import ast
import re
from dataclasses import dataclass

import numpy as np

from ..geometry import se3
from ..io.urdf_flange import flange_of
from .programs import TargetFrames

__all__ = ["MOTION_ARGUMENTS", "frames_of_targets", "read_frame_data"]

#: instruction (lower case) -> (indices of its robtarget arguments, index of its Tool argument), among
#: the positional arguments (SearchL/C's SearchPoint is written by the instruction: not a target)
MOTION_ARGUMENTS = {
    **dict.fromkeys(("movel", "movej", "moveldo", "movejdo", "movelao", "movejao", "movelgo", "movejgo", "movelsync",
                     "movejsync"), ((0,), 3)),
    **dict.fromkeys(("movec", "movecdo", "movecao", "movecgo", "movecsync"), ((0, 1), 4)),
    **dict.fromkeys(("triggl", "triggj"), ((0,), 4)),
    "triggc": ((0, 1), 5), "searchl": ((2,), 4), "searchc": ((2, 3), 5),
}
_DATA_DECL = re.compile(r"\b(?:CONST|PERS|VAR)\s+(tooldata|wobjdata)\s+([A-Za-z_]\w*)\s*:=\s*\[", re.IGNORECASE)
_ROBT_DECL = re.compile(r"\b(?:CONST|PERS|VAR)\s+robtarget\s+([A-Za-z_]\w*)\s*(?:\{[^{}]*\})?\s*:=\s*", re.IGNORECASE)
_LINE_WORD = re.compile(r"^[ \t]*([A-Za-z_]\w*)", re.MULTILINE)
_WOBJ = re.compile(r"\\\s*WObj\s*:=\s*([A-Za-z_]\w*)", re.IGNORECASE)
_NOT_INSTRUCTIONS = {"const", "pers", "var", "local", "task", "module", "endmodule", "proc", "endproc", "func",
                     "endfunc", "trap", "endtrap", "if", "else", "elseif", "endif", "for", "endfor", "while",
                     "endwhile", "test", "case", "default", "endtest", "return", "goto", "record", "endrecord", "error",
                     "undo", "backward", "then", "do"}
_WORD = re.compile(r"[ \t]*([A-Za-z_]\w*)")
_IDENT = re.compile(r"(?<![\w.])[A-Za-z_]\w*")


@dataclass
class FrameData:
    """A ``tooldata`` or ``wobjdata`` declaration: ``value`` its literal as Python lists (``None`` when it
    could not be read: ``error`` says why), ``line`` where it is."""

    kind: str
    value: list | None
    line: int
    source: str
    error: str = ""


def bracket_end(text: str, i: int) -> int:
    """Index just past the bracket closing the ``[`` at ``text[i]``."""
    depth = 0
    for j in range(i, len(text)):
        if text[j] == "[":
            depth += 1
        elif text[j] == "]":
            depth -= 1
            if depth == 0:
                return j + 1
    return len(text)


def _literal(raw: str):
    """A RAPID aggregate as Python lists (strings, TRUE/FALSE, numbers); ValueError when it is not one."""
    strings = re.findall(r'"[^"]*"', raw)
    body = re.sub(r'"[^"]*"', '""', raw)
    body = re.sub(r"\bTRUE\b", "True", body, flags=re.IGNORECASE)
    body = re.sub(r"\bFALSE\b", "False", body, flags=re.IGNORECASE)
    value = ast.literal_eval(body)
    it = iter(strings)

    def fill(v):  # put the strings' contents back (the placeholder kept ast away from their text)
        if isinstance(v, (list, tuple)):
            return [fill(x) for x in v]
        return next(it)[1:-1] if v == "" else v

    return fill(value)


def read_frame_data(clean: str, text: str, source: str, line_of) -> dict:
    """``{name (lower case): FrameData}`` of the tooldata/wobjdata declarations of one module
    (``clean``: its text with comments and strings blanked, ``text`` as read; ``source``: the prefix of
    its line numbers in messages, ``""`` for the program)."""
    out = {}
    for m in _DATA_DECL.finditer(clean):
        start = m.end() - 1
        end = bracket_end(clean, start)
        line = line_of(text, m.start())
        try:
            value, err = _literal(text[start:end]), ""
        except (ValueError, SyntaxError):
            value, err = None, f"{m.group(1)} {m.group(2)} ({source}line {line}) could not be read"
        out[m.group(2).lower()] = FrameData(m.group(1).lower(), value, line, source, err)
    return out


def _pose(v, what: str) -> np.ndarray:
    """``[[x,y,z],[q1..q4]]`` (mm, scalar-first quaternion) as a (4, 4) transform (m)."""
    xyz, quat = np.asarray(v[0], dtype=np.float64), np.asarray(v[1], dtype=np.float64)
    if xyz.shape != (3,) or quat.shape != (4,):
        raise ValueError(f"{what}: a frame is [[x,y,z],[q1,q2,q3,q4]]")
    nq = np.linalg.norm(quat)
    if not 0.99 < nq < 1.01:
        raise ValueError(f"{what}: quaternion norm {nq:.4f} (must be 1)")
    return se3.pose_to_transform(xyz * 1e-3, quat / nq)


def _wobj(name: str, data: dict) -> tuple[np.ndarray | None, str]:
    if name.lower() == "wobj0":
        return None, ""
    d = data.get(name.lower())
    if d is None or d.kind != "wobjdata":
        return None, (f"work object {name} is not declared in this module: its pose in the base frame is unknown "
                      "(add its wobjdata declaration, or give the module that declares it with --context)")
    where = f"wobjdata {name} ({d.source}line {d.line})"
    if d.error:
        return None, d.error
    try:
        robhold, ufprog, ufmec, uframe, oframe = d.value
        if robhold:
            return None, f"{where} is held by the robot (a stationary tool): not supported"
        if not ufprog or str(ufmec).strip():
            return None, f"{where} is moved by a mechanical unit ({ufmec or 'ufprog FALSE'}): not supported"
        return _pose(uframe, where) @ _pose(oframe, where), ""
    except (TypeError, ValueError) as e:
        return None, str(e) if str(e).startswith(where) else f"{where}: not [robhold, ufprog, ufmec, uframe, oframe]"


def _tool(name: str | None, data: dict, robot) -> tuple[np.ndarray | None, str, str]:
    """``(tool_delta, error, note)`` of a tool name (None: not known); the note names an undeclared tool,
    or a declared one whose load differs from the robot file's payload (``--payload-kg``)."""
    if name is None or name.lower() == "tool0":
        return None, "", ""
    d = data.get(name.lower())
    if d is None or d.kind != "tooldata":
        return None, "", (f"tool {name} is not declared in this module: its TCP is taken to be the robot file's tool "
                          "(give the module that declares it with --context)")
    where = f"tooldata {name} ({d.source}line {d.line})"
    if d.error:
        return None, d.error, ""
    try:
        robhold, tframe = d.value[0], d.value[1]
        if not robhold:
            return None, f"{where} is a stationary tool (robhold FALSE): not supported", ""
        note = ""
        try:  # its load: the model deflects under the payload it is given, not under this one
            mass = float(d.value[2][0])
        except (TypeError, ValueError, IndexError):
            mass = robot.payload_kg
        if abs(mass - robot.payload_kg) > max(0.1, 0.05 * robot.payload_kg):
            note = (f"{where} carries {mass:g} kg, the robot file's payload is {robot.payload_kg:g} kg: give "
                    f"--payload-kg {mass:g} if the robot carries that load while running these targets")
        return se3.invert(robot.tool) @ flange_of(robot) @ _pose(tframe, where), "", note
    except (TypeError, ValueError, IndexError) as e:
        return None, str(e) if str(e).startswith(where) else f"{where}: not [robhold, tframe, tload]", ""


def _positional_spans(body: str, offset: int) -> list[tuple[int, int]]:
    """``(start, end)`` text offsets of the positional arguments of a statement's ``body`` (which starts at
    ``offset``): top-level commas split arguments (brackets and parentheses nest); an argument's part
    from a top-level ``\\`` on is an optional argument (``\\WObj:=wobj1``, also after a positional one
    without a comma); ``\\Conc,`` alone is no positional argument."""
    spans, depth, a, cut = [], 0, 0, None

    def close(b):
        e = b if cut is None else cut
        if body[a:e].strip():
            lead = len(body[a:e]) - len(body[a:e].lstrip())
            spans.append((offset + a + lead, offset + len(body[:e].rstrip())))

    for i, c in enumerate(body):
        if c in "[(":
            depth += 1
        elif c in "])":
            depth -= 1
        elif depth == 0 and c == "\\" and cut is None:
            cut = i
        elif depth == 0 and c == ",":
            close(i)
            a, cut = i + 1, None
    close(len(body))
    return spans


_MOTION_WORD = re.compile(r"(?<![\w.])(" + "|".join(sorted(MOTION_ARGUMENTS, key=len, reverse=True)) + r")\b",
                          re.IGNORECASE)


def _statements(clean: str):
    """``(start, instruction (lower case), body start, end)`` of each simple statement: the text between
    two ``;`` from its first line that starts with a word other than a keyword (``PROC main()``,
    ``IF .. THEN``, declarations and the like stand on lines of their own before it). A motion
    instruction anywhere in that text is the statement (``IF bPart MoveL p1, ..;`` -- a compact IF --
    and ``IF c THEN MoveJ p2, ..; ENDIF`` on one line)."""
    last = 0
    while last < len(clean):
        end = clean.find(";", last)
        end = len(clean) if end < 0 else end
        mw = _MOTION_WORD.search(clean, last, end)
        if mw:
            yield mw.start(1), mw.group(1).lower(), mw.end(1), end
        else:
            first = _WORD.match(clean, last, end)  # a statement after another on the same line
            for m in ([first] if first else []) + list(_LINE_WORD.finditer(clean, last, end)):
                if m.group(1).lower() not in _NOT_INSTRUCTIONS:
                    yield m.start(1), m.group(1).lower(), m.end(1), end
                    break
        last = end + 1


# instructions that take data but move nothing: a robtarget passed to them keeps the default frames
_NO_MOTION = {"tpwrite", "errwrite", "errlog", "write", "writebin", "writeanybin", "tperase", "waittime", "stop",
              "exit", "break", "confl", "confj", "singarea", "velset", "accset", "pathresol", "storepath", "restopath"}
_ASSIGN = re.compile(r"(?<![\w.])([A-Za-z_]\w*)\s*(?:\{[^{}]*\})?\s*:=\s*(?=\[)")
_PROC = re.compile(r"\bPROC\s+([A-Za-z_]\w*)\s*\(([^)]*)\)", re.IGNORECASE)
_ENDPROC = re.compile(r"\bENDPROC\b", re.IGNORECASE)


def _named(parts: list, clean: str, starts, names: dict, own: dict, proc, proc_uses: dict) -> set:
    """Target indices of the literals in the text spans ``parts`` and of the robtargets named there
    (``Offs(p10, ..)``, ``path{i}``); a name that is a robtarget parameter ``own`` of routine ``proc``
    queues ``(proc, index)`` under ``proc_uses[None]`` for the caller to give the statement's frames."""
    hit = set()
    for a, b in parts:
        hit.update(range(int(np.searchsorted(starts, a)), int(np.searchsorted(starts, b))))
        for n in _IDENT.finditer(clean, a, b):
            name = n.group(0).lower()
            hit.update(names.get(name, ()))
            if name in own:
                proc_uses.setdefault(None, []).append((proc, own[name]))
    return hit


def _robtarget_params(clean: str) -> tuple[dict, list]:
    """The module's routines with robtarget parameters: ``({proc (lower): {param (lower): positional
    index}}, [(body start, body end, proc)])``. Optional parameters (``\\name``) are passed by name, not
    position: they get no index."""
    params, bodies = {}, []
    for m in _PROC.finditer(clean):
        e = _ENDPROC.search(clean, m.end())
        bodies.append((m.end(), e.start() if e else len(clean), m.group(1).lower()))
        pos, own = 0, {}
        for p in m.group(2).split(","):
            words = _IDENT.findall(p)
            if p.strip().startswith("\\") or not words:
                continue
            if "robtarget" in (w.lower() for w in words[:-1]):
                own[words[-1].lower()] = pos
            pos += 1
        if own:
            params[m.group(1).lower()] = own
    return params, bodies


_CHANGE = re.compile(r"\s*(?:\{[^{}]*\})?\s*(?:\.\s*\w+\s*(?:\{[^{}]*\})?\s*)*:=")


def _run_time_changes(clean: str, text: str, line_of, where: str = "") -> tuple[dict, list]:
    """``({name (lower): [(position, why)]}, [(start, end, why)])``: the assignments to a variable or a
    component of it in the routines (``tGun.tframe.trans.z:=250;``, ``wMoved:=[..];``: the frames of the
    tools and work objects named so change at run time), and the spans of program displacement
    (``PDispOn``/``PDispSet`` up to the next ``PDispOff``: every robtarget is moved by a frame hykin does
    not know)."""
    changes: dict = {}
    disp, open_ = [], None
    for start, word, body_at, end in _statements(clean):
        at = f"{where or 'line '}{line_of(text, start)}"
        stmt = " ".join(clean[start:end].split())[:60]
        if word in ("pdispon", "pdispset"):
            if open_ is None:
                open_ = (start, f"{stmt} ({at}) displaces the program frame at run time: hykin does not follow "
                                "program displacement (compensate the displaced targets, or turn it off)")
        elif word == "pdispoff":
            if open_ is not None:
                disp.append((open_[0], start, open_[1]))
                open_ = None
        elif _CHANGE.match(clean, body_at, end):
            changes.setdefault(word, []).append((start, f"{stmt} ({at}) changes its frame at run time: hykin does not "
                                                       "follow run-time changes of tool and work object data"))
    if open_ is not None:
        disp.append((open_[0], len(clean), open_[1]))
    return changes, disp


def _changed(start: int, tool, wobj: str, changes: dict, disp: list) -> str:
    """Why the frames of a motion at ``start`` with ``tool`` (a name, None or ...) and work object ``wobj``
    are not the declared ones (a run-time change before it, a program displacement around it), or ``""``."""
    for name in ([tool.lower()] if isinstance(tool, str) else []) + [wobj.lower()]:
        hit = [w for p, w in changes.get(name, []) if p < start]
        if hit:
            return hit[-1]
    return next((w for a, b, w in disp if a < start < b), "")


def _scan(clean: str, text: str, starts, names: dict, line_of, where: str = ""):
    """One module's motion statements: ``(uses, proc_uses, calls, params)`` -- per target index its
    ``[(tool name or None or ..., wobj name, line label)]``; per ``(routine, positional index)`` the same
    for its moves on that robtarget parameter; the statements calling something not a known motion
    ``[(routine, body start, end, line)]``; the routines' robtarget parameters (:func:`_robtarget_params`).
    ``where``: prefix of the line labels (a context module's name)."""
    params, bodies = _robtarget_params(clean)
    changes, disp = _run_time_changes(clean, text, line_of, where)
    proc_uses: dict = {}
    calls = []
    uses: dict = {}
    for start, word, body_at, end in _statements(clean):
        body = clean[body_at:end]
        if re.match(r"\s*(?:\{[^}]*\})?\s*:=", body):  # an assignment, not an instruction
            continue
        wm = _WOBJ.search(body)
        wobj = wm.group(1) if wm else "wobj0"
        spec = MOTION_ARGUMENTS.get(word)
        line = line_of(text, start) if not where else f"{where}{line_of(text, start)}"
        if spec is None and not wm:
            if word not in _NO_MOTION:
                calls.append((word, body_at, end, line))
            continue  # not a motion we know, no work object named: the default frames
        if spec is None:  # another instruction naming a work object: every robtarget in it
            parts = [(body_at, end)]
            tool = ...  # not known: agrees with the tool of the target's other uses
        else:  # the target arguments only (their spans in the text)
            spans = _positional_spans(body, body_at)
            parts = [spans[i] for i in spec[0] if i < len(spans)]
            tool = clean[slice(*spans[spec[1]])].strip() if spec[1] < len(spans) else None
        proc = next((p for a, b, p in bodies if a <= start < b), None)
        why = _changed(start, tool, wobj, changes, disp)
        for j in _named(parts, clean, starts, names, params.get(proc, {}), proc, proc_uses):
            uses.setdefault(j, []).append((tool, wobj, line, why))
        for key in proc_uses.pop(None, ()):
            proc_uses.setdefault(key, []).append((tool, wobj, line, why))
    return uses, proc_uses, calls, params


def frames_of_targets(clean: str, text: str, targets: list, robot, data: dict, line_of,
                      context_clean: str = "", context: str = "") -> TargetFrames:
    """Frames of ``targets`` (:class:`hykin.compensation.programs.ProgramTarget` of this module, in order)
    from the motion statements of ``clean``/``text`` and the declarations ``data`` (module docstring).

    A robtarget passed to a routine of the module or of the ``context`` modules takes the frames of the
    routine's motions on that parameter; one passed to a routine defined in neither, and moved to
    nowhere else, fails (its tool and work object are not known)."""
    starts = np.array([t.start for t in targets], dtype=np.int64)  # in text order (found left to right)
    names = {}  # robtarget name (lower) -> indices of the literals declared or assigned to it
    for m in list(_ROBT_DECL.finditer(clean)) + list(_ASSIGN.finditer(clean)):
        i = m.end()
        if i < len(clean) and clean[i] == "[":
            end = bracket_end(clean, i)
            names.setdefault(m.group(1).lower(), set()).update(
                range(int(np.searchsorted(starts, i)), int(np.searchsorted(starts, end))))
    _, proc_uses, _, params = _scan(context_clean, context, starts[:0], {}, line_of, "--context, line ")
    uses, own_uses, calls, own_params = _scan(clean, text, starts, names, line_of)
    params.update(own_params)
    proc_uses.update(own_uses)
    unknown = {}  # target index -> (routine, line) it is passed to, which no module read defines
    for word, body_at, end, line in calls:
        spans = _positional_spans(clean[body_at:end], body_at)
        shown = clean[body_at - len(word):body_at]  # as written
        for k, (a, b) in enumerate(spans):
            hit = _named([(a, b)], clean, starts, names, {}, None, {})
            if word in params:
                for j in hit:
                    uses.setdefault(j, []).extend(proc_uses.get((word, k), []))
            else:
                for j in hit:
                    unknown.setdefault(j, (shown, line))
    out = TargetFrames()
    noted = set()
    if any(u[0] is ... or (u[0] or "tool0").lower() != "tool0" or str(u[1]).lower() != "wobj0"
           for us in uses.values() for u in us):  # the module moves with other frames: an unused target's are unknown
        out.unknown_frames = [j for j in range(len(targets)) if j not in uses and j not in unknown]
    for j in range(len(targets)):
        resolved = []
        if j not in uses and j in unknown:
            word, line = unknown[j]
            out.add([(None, None, f"used only as an argument of {word} (line {line}), a routine neither this module "
                                  "nor a --context module defines: the tool and work object the robot moves to it with "
                                  "are unknown (give the module that defines it with --context)", "")], "")
            continue
        for tool, wobj, line, why in uses.get(j, [(None, "wobj0", 0, "")]):
            W, err = _wobj(wobj, data)
            err = why or err
            D, terr, note = (TargetFrames.ANY_TOOL, "", "") if tool is ... else _tool(tool, data, robot)
            if note and "is not declared" in note:  # a failure of this target may come from that tool
                out.caveat[j] = (f"tool {tool} is not declared in what was read, so its TCP was taken to be the robot "
                                 "file's tool (give the module that declares it with --context)")
            if note and tool.lower() not in noted:  # once per tool
                noted.add(tool.lower())
                out.notes.append(f"{line}: {note}")
            label = "tool?" if tool is ... else tool or "tool0"
            at = f"line {line}" if isinstance(line, int) else line
            resolved.append((W, D, err or terr, f"{at}: {label} \\WObj:={wobj}"))
        out.add(resolved, "used with different tools or work objects")
    return out
