"""URScript (Universal Robots): ``p[x, y, z, rx, ry, rz]`` poses — m, rotation vector (rad), base frame.

Targets: a pose literal that is the first argument of ``movel``/``movej``/``movep``/``movec`` (or the
second of ``movec``), or is assigned to a variable (``global``/``local`` or plain ``name = p[...]``)
that some ``movel/movej/movep/movec`` call uses directly. Every other pose literal (``set_tcp``,
``pose_trans``/``pose_add`` offsets, force frames) is kept and listed in the notes, except a move to
``pose_trans(F, p[...])`` or ``pose_trans(F, name)`` where the script assigns feature ``F`` a pose literal
(``global Plane_1 = p[...]``): that target is taken in ``F``'s frame and written back in it (a feature
the script does not define, e.g. one of the installation, is kept and noted). ``set_tcp(p[...])``
sets the TCP of the targets after it in text order: their compensation uses the tool delta
``inv(nominal tool) · tcp`` (before any ``set_tcp`` the installation TCP is taken to be the robot
file's tool). ``movej([j1, ..., j6])`` joint moves restart the branch walk (:mod:`.programs`).
Comments (``#``) and strings are ignored. Numbers are written with 7 decimals (m, 0.1 µm) and 8 (rad).
"""

from __future__ import annotations

import re

import numpy as np

from ..geometry import se3
from .programs import NUMBER, ProgramTarget, comment_mask, line_of, splice_numbers

__all__ = ["SUFFIXES", "find_targets", "format_target"]

SUFFIXES = (".script", ".urscript", ".urs")
_NUM = re.compile(NUMBER)
_POSE = re.compile(r"(?<![\w.])p\s*\[\s*" + r"\s*,\s*".join([f"({NUMBER})"] * 6) + r"\s*\]")
_MOVE_FIRST = re.compile(r"\b(?:movel|movej|movep|movec)\s*\(\s*$")
_MOVEC_SECOND = re.compile(r"\bmovec\s*\(\s*(?:p\s*\[[^\]]*\]|\w+)\s*,\s*$")
_SET_TCP = re.compile(r"\bset_tcp\s*\(\s*$")
_MOVE_FEATURE = re.compile(r"\b(?:movel|movej|movep|movec)\s*\(\s*pose_trans\s*\(\s*([A-Za-z_]\w*)\s*,\s*$")
_MOVE_VIA = re.compile(r"\b(?:movel|movej|movep|movec)\s*\(\s*pose_trans\s*\(\s*([A-Za-z_]\w*)\s*,\s*([A-Za-z_]\w*)\s*\)")
_ASSIGN = re.compile(r"(?:^|[;:])\s*(?:global\s+|local\s+)?([A-Za-z_]\w*)\s*=\s*$")


def _joint_moves(clean: str, n: int) -> list:
    pat = re.compile(r"\bmovej\s*\(\s*\[\s*" + r"\s*,\s*".join([f"({NUMBER})"] * n) + r"\s*\]")
    return [(m.start(), np.array([float(g) for g in m.groups()])) for m in pat.finditer(clean)]


def find_targets(text: str, robot, context: str = "", axis_signs=None) -> tuple[list, list]:
    """``(targets, notes)`` of a URScript program (module docstring)."""
    mask = comment_mask(text, "#", '"')
    clean = "".join(" " if m else c for c, m in zip(text, mask[: len(text)]))
    used = set()
    for m in re.finditer(r"\b(?:movel|movej|movep|movec)\s*\(\s*([A-Za-z_]\w*)\s*[,)]", clean):
        used.add(m.group(1))
    for m in re.finditer(r"\bmovec\s*\([^,()]*,\s*([A-Za-z_]\w*)\s*[,)]", clean):
        used.add(m.group(1))
    used.discard("p")
    via = {}  # variable -> {feature: position of the first move to pose_trans(feature, variable)}
    for m in _MOVE_VIA.finditer(clean):
        via.setdefault(m.group(2), {}).setdefault(m.group(1), m.start())
    # a frame that is itself moved to is rewritten too: what pose_trans composes with it is an offset
    # from a moving pose (kept, as before), not a target in a fixed feature
    via = {k: f for k, f in via.items() if not (set(f) & (used | set(via)))}
    features = {}  # name -> [(position, pose)] of its pose-literal assignments
    for m in _POSE.finditer(clean):
        a = _ASSIGN.search(clean[clean.rfind("\n", 0, m.start()) + 1 : m.start()])
        if a is not None:
            v = np.array([float(g) for g in m.groups()])
            features.setdefault(a.group(1), []).append((m.start(), se3.make_transform(se3.rotvec_to_matrix(v[3:]), v[:3])))
    jm = _joint_moves(clean, robot.dof)
    targets, notes = [], []
    tcp = None
    prev_end = 0
    for m in _POSE.finditer(clean):
        ls = clean.rfind("\n", 0, m.start()) + 1
        prefix = clean[ls : m.start()]
        v = np.array([float(g) for g in m.groups()])
        pose = se3.make_transform(se3.rotvec_to_matrix(v[3:]), v[:3])
        line = line_of(text, m.start())
        name = ""
        if _SET_TCP.search(prefix):
            tcp = pose
            notes.append(f"line {line}: set_tcp pose kept; later targets use this TCP")
            continue
        frame, feature, at = None, None, m.start()  # at: where the move is (the feature's pose there counts)
        f = _MOVE_FEATURE.search(prefix)
        if f is not None and f.group(1) not in used and f.group(1) not in via:
            feature = f.group(1)
        elif not (_MOVE_FIRST.search(prefix) or _MOVEC_SECOND.search(prefix)):
            a = _ASSIGN.search(prefix)
            if a is None or (a.group(1) not in used and a.group(1) not in via):
                notes.append(f"line {line}: pose literal not used as a move target (offset, frame, ...): kept")
                continue
            name = a.group(1)
            if name in via:
                if len(via[name]) > 1 or name in used:
                    where = sorted(via[name]) + (["base"] if name in used else [])
                    notes.append(f"line {line}: {name} is moved to in several frames ({', '.join(where)}): kept")
                    continue
                (feature, at), = via[name].items()
        if feature is not None:
            defs = [T for pos, T in features.get(feature, []) if pos < at]
            if not defs:
                notes.append(f"line {line}: move relative to feature {feature}, which this script does not define as "
                             "a pose (an installation feature?): kept")
                continue
            frame = defs[-1]
            pose = frame @ pose
        resets = [q for pos, q in jm if prev_end <= pos < m.start()]
        spans = [(m.start(i) - m.start(), m.end(i) - m.start()) for i in range(1, 7)]
        targets.append(ProgramTarget(
            start=m.start(), end=m.end(), line=line, pose=pose, name=name, kind="p[]",
            tool_delta=None if tcp is None else se3.invert(robot.tool) @ tcp,
            reset=resets[-1] if resets else None, parts={"spans": spans, "rv": v[3:], "literal": text[m.start():m.end()]},
            frame=frame,
        ))
        prev_end = m.end()
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
