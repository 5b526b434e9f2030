"""KUKA KRL: ``E6POS``/``POS``/``FRAME`` aggregates in ``.src`` and ``.dat`` files.

Aggregate ``{[TYPE:] X x, Y y, Z z, A a, B b, C c[, S s, T t][, E1 ...]}``: ``X, Y, Z`` in mm,
``A, B, C`` in degrees about Z, Y', X'' (``R = Rz(A) Ry(B) Rx(C)``), base frame; ``S``/``T`` status
and turn (decimal or ``'B010'`` binary), meaning as in :mod:`.branches`. Only the values of
``X, Y, Z, A, B, C, S, T`` are replaced; components, order, spacing, ``E1..E6`` are kept.

Targets: complete Cartesian aggregates (all of ``X, Y, Z, A, B, C``) that are ``E6POS``/``POS`` (by
prefix or declaration), untyped ones in a motion statement (``PTP/LIN/CIRC`` and ``SPTP/SLIN/SCIRC``),
and ``FRAME`` ones inline in a motion statement or declared under a name some motion statement of
this file or its companion (``.src`` for a ``.dat``) uses. Kept and noted: relative motions
(``*_REL``), partial aggregates (KRL fills the missing components from the current pose, which we
cannot know), ``FRAME`` data not used as a motion target (``$BASE``/``$TOOL``/``BASE_DATA``/
``TOOL_DATA``), assignments to system variables (``$TOOL = {...}``, ``$BASE``, ``BASE_DATA[i]``,
``TOOL_DATA[i]``). ``PTP {A1 .., A6 ..}`` joint moves restart the branch walk (axis angles, degrees,
controller signs). Each target is taken in the base and with the tool the program selects where it
moves to it (:mod:`.krl_frames`: ``$BASE``/``$TOOL``, ``BAS(#BASE, n)``, ``FDAT_ACT``; ``BASE_DATA``/
``TOOL_DATA`` from ``$config.dat`` in ``context``; base 0 = the robot base, tool 0 = the robot file's
tool) and written back in that base. Numbers are written with 4 decimals (mm) and 5 (deg).
"""

from __future__ import annotations

import math
import re

import numpy as np

from ..geometry import se3
from .krl_frames import frames_of_targets
from .programs import NUMBER, ProgramTarget, comment_mask, line_of, splice_numbers

__all__ = ["SUFFIXES", "abc_from_matrix", "find_targets", "format_target", "matrix_from_abc"]

SUFFIXES = (".src", ".dat")
_AGG = re.compile(r"\{([^{}]*)\}")
_COMP = re.compile(r"([A-Za-z_]\w*)\s+(" + NUMBER + r"|'[Bb][01]+')")
_MOTION = re.compile(r"\b(?:S?PTP|S?LIN|S?CIRC)(_REL)?\b", re.IGNORECASE)
_DECL = re.compile(r"(?:\bDECL\s+)?(?:\bGLOBAL\s+)?\b(E6POS|POS|FRAME|E6AXIS|AXIS)\s+([A-Za-z_$]\w*)\s*=\s*$", re.IGNORECASE)
_ASSIGN = re.compile(r"([A-Za-z_$][\w.$\[\]]*)\s*=\s*$")
_CART = ("X", "Y", "Z", "A", "B", "C")


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


def _motion_uses(clean: str) -> list:
    """``[(position, variable name (upper case))]`` of the variables motion statements move to."""
    uses = []
    for m in re.finditer(r"\b(?:S?PTP|S?LIN)\s+([A-Za-z_$]\w*)", clean, re.IGNORECASE):
        uses.append((m.start(), m.group(1).upper()))
    for m in re.finditer(r"\bS?CIRC\s+([A-Za-z_$]\w*)\s*,\s*([A-Za-z_$]\w*)", clean, re.IGNORECASE):
        uses += [(m.start(), m.group(1).upper()), (m.start(), m.group(2).upper())]
    return uses


def _motion_names(clean: str) -> set:
    return {name for _, name in _motion_uses(clean)}


def _clean(text: str) -> str:
    mask = comment_mask(text, ";", '"')
    return "".join(" " if m else c for c, m in zip(text, mask[: len(text)]))


def find_targets(text: str, robot, context: str = "", axis_signs=None) -> tuple[list, list]:
    """``(targets, notes)`` of a KRL ``.src`` or ``.dat`` text; ``context``: the companion file."""
    from .branches import default_axis_signs

    sgn = default_axis_signs(robot) if axis_signs is None else np.asarray(axis_signs, dtype=np.float64)
    clean = _clean(text)
    ctx_clean = _clean(context) if context else ""
    used = _motion_names(clean) | _motion_names(ctx_clean)
    targets, notes = [], []
    last_joint, prev_end = None, 0
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
        mot = _MOTION.search(prefix)
        decl = _DECL.search(prefix)
        name = decl.group(2) if decl else (_ASSIGN.search(prefix).group(1) if _ASSIGN.search(prefix) else "")
        kind = kind or (decl.group(1).upper() if decl else "")
        axes = [f"A{i + 1}" for i in range(robot.dof)]
        if mot and not mot.group(1) and all(a in comps for a in axes) and "X" not in comps:
            last_joint = (m.start(), sgn * np.radians([float(comps[a][2]) for a in axes]))
            continue
        if not any(k in comps for k in _CART):
            continue  # not a Cartesian aggregate (axis data, other structures)
        if mot and mot.group(1):
            notes.append(f"line {line}: relative motion ({mot.group(0)}): kept")
            continue
        if not all(k in comps for k in _CART):
            notes.append(f"line {line}: partial Cartesian aggregate (missing "
                         f"{', '.join(k for k in _CART if k not in comps)}): kept")
            continue
        if kind == "FRAME" and not mot and name.upper() not in used:
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
        v = {k: float(comps[k][2]) for k in _CART}
        pose = se3.make_transform(matrix_from_abc(v["A"], v["B"], v["C"]), np.array([v["X"], v["Y"], v["Z"]]) * 1e-3)
        cfg = {k: _int_value(comps[k][2]) for k in ("S", "T") if k in comps}
        if "T" in cfg and "S" not in cfg:
            cfg = {}
        keys = [k for k in (*_CART, "S", "T") if k in comps and (k in _CART or k in cfg)]
        spans = [(b0 + comps[k][0] - m.start(), b0 + comps[k][1] - m.start()) for k in keys]
        reset = last_joint[1] if last_joint is not None and last_joint[0] >= prev_end else None
        targets.append(ProgramTarget(
            start=m.start(), end=m.end(), line=line, pose=pose, name=name, kind=kind or "POS", config=cfg,
            reset=reset, parts={"keys": keys, "spans": spans, "literal": text[m.start():m.end()], "A": v["A"],
                                "tokens": {k: comps[k][2] for k in keys}, "axis_signs": sgn},
        ))
        prev_end = m.end()
    # the base and tool of each target: the selections in force where the .src moves to it
    text_is_src = bool(_motion_uses(clean)) or not context
    src_clean = clean if text_is_src else ctx_clean
    motions = [(p, name, None) for p, name in _motion_uses(src_clean)]
    motions += [(t.start, None, k) for k, t in enumerate(targets) if not t.name]
    fr = frames_of_targets(src_clean, text_is_src, targets, robot, [clean, ctx_clean], motions)
    return targets, notes + fr.apply(targets)


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
