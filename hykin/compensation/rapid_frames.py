"""ABB RAPID: the work object and tool each robtarget is used with.

A robtarget is a pose of the instruction's tool in the instruction's work object (``\\WObj:=name``,
default ``wobj0``, the robot base frame here). This module reads, from the program (and the
``--context`` modules):

* ``tooldata`` declarations ``[robhold, [[x,y,z],[q1..q4]], tload]`` (mm, quaternion scalar first) and
  ``wobjdata`` declarations ``[robhold, ufprog, "ufmec", uframe, oframe]``;
* motion statements (``MoveL ToPoint, Speed, Zone, Tool \\WObj:=W`` and the other instructions of
  :data:`TOOL_ARGUMENT`): which robtargets (literals, or declared names anywhere in the statement,
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
from .programs import TargetFrames

__all__ = ["TOOL_ARGUMENT", "frames_of_targets", "read_frame_data"]

#: instruction (lower case) -> index of its Tool argument among the positional ones
TOOL_ARGUMENT = {
    **dict.fromkeys(("movel", "movej", "moveldo", "movejdo", "movelao", "movejao", "movelgo", "movejgo", "movelsync",
                     "movejsync"), 3),
    **dict.fromkeys(("movec", "movecdo", "movecao", "movecgo", "movecsync", "triggl", "triggj", "searchl"), 4),
    **dict.fromkeys(("triggc", "searchc"), 5),
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
    (``clean``: its text with comments and strings blanked, ``text`` as read)."""
    out = {}
    for m in _DATA_DECL.finditer(clean):
        start = m.end() - 1
        end = bracket_end(clean, start)
        line = line_of(text, m.start())
        try:
            value, err = _literal(text[start:end]), ""
        except (ValueError, SyntaxError):
            value, err = None, f"{source}line {line}: {m.group(1)} {m.group(2)} could not be read"
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
    """``(tool_delta, error, note)`` of a tool name (None: not known)."""
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
        return se3.invert(robot.tool) @ _pose(tframe, where), "", ""
    except (TypeError, ValueError, IndexError) as e:
        return None, str(e) if str(e).startswith(where) else f"{where}: not [robhold, tframe, tload]", ""


def _split_args(s: str) -> list[str]:
    """Top-level comma-separated arguments (brackets and parentheses nest)."""
    out, depth, cur = [], 0, []
    for c in s:
        if c in "[(":
            depth += 1
        elif c in "])":
            depth -= 1
        if c == "," and depth == 0:
            out.append("".join(cur))
            cur = []
        else:
            cur.append(c)
    out.append("".join(cur))
    return out


def _positional(args: list[str]) -> list[str]:
    """The positional arguments (``\\Name[:=value]`` optional ones dropped, also when they follow a
    positional one without a comma, as ``tool1\\WObj:=wobj1``)."""
    out = []
    for a in args:
        head = a.split("\\", 1)[0].strip()
        if head:
            out.append(head)
    return out


def _statements(clean: str):
    """``(start, instruction (lower case), body start, end)`` of each simple statement: the text between
    two ``;`` from its first line that starts with a word other than a keyword (``PROC main()``,
    ``IF .. THEN``, declarations and the like stand on lines of their own before it)."""
    last = 0
    while last < len(clean):
        end = clean.find(";", last)
        end = len(clean) if end < 0 else end
        first = _WORD.match(clean, last, end)  # a statement after another on the same line
        for m in ([first] if first else []) + list(_LINE_WORD.finditer(clean, last, end)):
            if m.group(1).lower() not in _NOT_INSTRUCTIONS:
                yield m.start(1), m.group(1).lower(), m.end(1), end
                break
        last = end + 1


def frames_of_targets(clean: str, text: str, targets: list, robot, data: dict, line_of) -> TargetFrames:
    """Frames of ``targets`` (:class:`hykin.compensation.programs.ProgramTarget` of this module, in order)
    from the motion statements of ``clean``/``text`` and the declarations ``data`` (module docstring)."""
    starts = np.array([t.start for t in targets], dtype=np.int64)  # in text order (found left to right)
    names = {}  # declared robtarget name (lower) -> indices of its literals
    for m in _ROBT_DECL.finditer(clean):
        i = m.end()
        if i < len(clean) and clean[i] == "[":
            end = bracket_end(clean, i)
            names.setdefault(m.group(1).lower(), []).extend(
                range(int(np.searchsorted(starts, i)), int(np.searchsorted(starts, end))))
    uses: dict = {}  # target index -> [(tool name or None, wobj name, line)]
    ident = re.compile(r"\b(" + "|".join(re.escape(n) for n in names) + r")\b", re.IGNORECASE) if names else None
    for start, word, body_at, end in _statements(clean):
        body = clean[body_at:end]
        if re.match(r"\s*(?:\{[^}]*\})?\s*:=", body):  # an assignment, not an instruction
            continue
        wm = _WOBJ.search(body)
        wobj = wm.group(1) if wm else "wobj0"
        pos = _positional(_split_args(body))
        k = TOOL_ARGUMENT.get(word)
        tool = pos[k] if k is not None and k < len(pos) else None
        if k is None and not wm:
            continue  # not a motion we know, no work object named: the default frames
        line = line_of(text, start)
        hit = set(range(int(np.searchsorted(starts, body_at)), int(np.searchsorted(starts, end))))
        if ident is not None:
            for n in ident.finditer(body):
                hit.update(names[n.group(1).lower()])
        for j in hit:
            uses.setdefault(j, []).append((tool, wobj, line))
    out = TargetFrames()
    noted = set()
    for j in range(len(targets)):
        resolved = []
        for tool, wobj, line in uses.get(j, [(None, "wobj0", 0)]):
            W, err = _wobj(wobj, data)
            D, terr, note = _tool(tool, data, robot)
            if note and tool.lower() not in noted:
                noted.add(tool.lower())
                out.notes.append(f"{line}: {note}")
            resolved.append((W, D, err or terr, f"line {line}: {tool or 'tool?'} \\WObj:={wobj}"))
        out.add(resolved, "used with different tools or work objects")
    return out
