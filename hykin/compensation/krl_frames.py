"""KUKA KRL: the base and tool each target is used with.

A KRL Cartesian target is a pose of ``$TOOL`` in ``$BASE``. The program selects them, in text order,
with ``$BASE = BASE_DATA[n]`` / ``$TOOL = TOOL_DATA[n]`` (or ``$NULLFRAME``, or a frame aggregate),
``BAS(#BASE, n)`` / ``BAS(#TOOL, n)``, and the inline forms' ``FDAT_ACT = FPn`` (``BASE_NO``,
``TOOL_NO`` and ``IPO_FRAME`` of ``DECL FDAT FPn = {...}`` in the ``.dat``). ``BASE_DATA[n]`` and
``TOOL_DATA[n]`` are declared in the controller's ``$config.dat`` (``BASE_DATA[1]={X ..,Y ..,Z ..,A
..,B ..,C ..}``); hykin reads them from the program and the ``--context`` files.

Per target (the selection in force at the motion statement that uses it; before any, base 0 and the
robot file's tool): the frame ``W`` = ``BASE_DATA[n]`` the pose is written in (``$WORLD`` taken as
``$ROBROOT``, base 0 = the robot base frame) and the tool delta ``D = inv(robot file's tool) ·
TOOL_DATA[n]``. Tool 0 and tools whose data were not read are the robot file's tool (a note names
them). A target fails, with the reason, when its base is not declared in what was read, is set by an
expression hykin cannot evaluate, is an external TCP (``IPO_FRAME #TCP``), or when one target is used
with two different frames.
"""

from __future__ import annotations

import re

import numpy as np

from ..geometry import se3
from .programs import TargetFrames

__all__ = ["frames_of_targets"]

_FRAME_DATA = re.compile(r"\b(BASE_DATA|TOOL_DATA)\s*\[\s*(\d+)\s*\]\s*=\s*\{([^{}]*)\}", re.IGNORECASE)
_FDAT = re.compile(r"\bFDAT\s+([A-Za-z_]\w*)\s*=\s*\{([^{}]*)\}", re.IGNORECASE)
_SELECT = re.compile(
    r"(?P<var>\$BASE|\$TOOL)\s*=(?!=)\s*(?:(?P<data>BASE_DATA|TOOL_DATA)\s*\[\s*(?P<n>\d+)\s*\]|(?P<null>\$NULLFRAME|\$WORLD)\b"
    r"|\{(?P<agg>[^{}]*)\}|(?P<expr>[^\n]*))"
    r"|\bBAS\s*\(\s*#(?P<bas>BASE|TOOL)\s*,\s*(?P<bn>\d+)\s*\)"
    r"|\bFDAT_ACT\s*=\s*(?P<fdat>[A-Za-z_]\w*)", re.IGNORECASE)
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


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


def _walk(clean: str, fdat: dict) -> list:
    """Selections in text order: ``[(position, "base"|"tool", value)]``; value: an int (data index), a
    ``(4, 4)`` frame, or a str (why it is unknown)."""
    out = []
    for m in _SELECT.finditer(clean):
        if m.group("fdat"):
            d = fdat.get(m.group("fdat").upper())
            if d is None:
                out.append((m.start(), "base", f"FDAT_ACT = {m.group('fdat')}: its FDAT declaration (the .dat) was not read"))
                continue
            if d["IPO_FRAME"] == "TCP":
                out.append((m.start(), "base", f"{m.group('fdat')} moves relative to an external TCP (IPO_FRAME #TCP): "
                                               "not supported"))
            elif d["BASE_NO"] is not None:
                out.append((m.start(), "base", d["BASE_NO"]))
            if d["TOOL_NO"] is not None:
                out.append((m.start(), "tool", d["TOOL_NO"]))
        elif m.group("bas"):
            out.append((m.start(), m.group("bas").lower(), int(m.group("bn"))))
        else:
            kind = m.group("var")[1:].lower()
            if m.group("n") is not None:
                out.append((m.start(), kind, int(m.group("n"))))
            elif m.group("null"):
                out.append((m.start(), kind, 0))
            elif m.group("agg") is not None:
                T = _aggregate_frame(m.group("agg"))
                out.append((m.start(), kind, T if T is not None else f"${kind.upper()} = {{..}} is not a complete frame"))
            else:
                out.append((m.start(), kind, f"${kind.upper()} = {m.group('expr').strip()[:40]}: an expression hykin "
                                             "cannot evaluate"))
    return out


def _states(events: list) -> tuple[np.ndarray, list]:
    """``(positions (E,), states)``: the ``(base, tool)`` in force after each selection event."""
    base, tool, states = 0, 0, []
    for _, kind, value in events:
        if kind == "base":
            base = value
        else:
            tool = value
        states.append((base, tool))
    return np.array([p for p, _, _ in events], dtype=np.int64), states


def _state_at(positions: np.ndarray, states: list, pos: int) -> tuple:
    """The ``(base, tool)`` in force at ``pos`` (base 0 and tool 0 before any selection)."""
    i = int(np.searchsorted(positions, pos))  # events strictly before pos
    return states[i - 1] if i else (0, 0)


def frames_of_targets(src_clean: str, text_is_src: bool, targets: list, robot, cleans: list,
                      motions: list) -> TargetFrames:
    """Frames of ``targets`` (of the file read) from the base/tool selections of ``src_clean`` (the
    ``.src`` text with comments blanked: the file read itself when ``text_is_src``, else its
    companion), the data declared in ``cleans`` (every text read) and ``motions``: ``[(position in
    src_clean, target name (upper case) or None, index of an inline target or None)]``."""
    frames, fdat = _declared(cleans)
    positions, states = _states(_walk(src_clean, fdat))
    uses: dict = {}
    by_name: dict = {}
    for k, t in enumerate(targets):
        if t.name:
            by_name.setdefault(t.name.upper(), []).append(k)
    for pos, name, inline in motions:
        state = _state_at(positions, states, pos)
        hits = [inline] if inline is not None and text_is_src else by_name.get(name, []) if name else []
        for k in hits:
            uses.setdefault(k, []).append(state)
    out = TargetFrames()
    noted = set()
    for k in range(len(targets)):
        resolved = []
        for base, tool in uses.get(k, [(0, 0)]):
            W, err = None, ""
            if isinstance(base, str):
                err = base
            elif isinstance(base, np.ndarray):
                W = base
            elif base != 0:
                W = frames.get(("base", base))
                if W is None:
                    err = (f"base {base} (BASE_DATA[{base}]) is not declared in what was read: its pose is unknown "
                           "(give the controller's $config.dat with --context)")
            D = None
            if isinstance(tool, str) and tool not in noted:
                noted.add(tool)
                out.notes.append(f"{targets[k].line}: {tool}: the TCP is taken to be the robot file's tool")
            elif isinstance(tool, np.ndarray):
                D = se3.invert(robot.tool) @ tool
            elif isinstance(tool, int) and tool != 0:
                T = frames.get(("tool", tool))
                if T is not None:
                    D = se3.invert(robot.tool) @ T
                elif tool not in noted:
                    noted.add(tool)
                    out.notes.append(f"{targets[k].line}: tool {tool} (TOOL_DATA[{tool}]) was not read: its TCP is "
                                     "taken to be the robot file's tool (give $config.dat with --context)")
            label = f"base {base if isinstance(base, int) else '(frame)'}, tool {tool if isinstance(tool, int) else '(frame)'}"
            resolved.append((W, D, err, label))
        out.add(resolved, "used with different bases or tools")
    return out
