r"""ABB RAPID: ``robtarget`` literals ``[[x,y,z],[q1,q2,q3,q4],[cf1,cf4,cf6,cfx],[e1,...,e6]]``.

``x, y, z`` in mm; ``q1..q4`` the orientation quaternion, scalar first; ``confdata`` as in
:mod:`.branches` (it picks the nominal solution the program means and is rewritten from the
compensated joints); external axes kept. Any literal of that shape is a robtarget (``CONST``/``PERS``/
``VAR robtarget`` declarations, arrays of them, and inline ``MoveL``/``MoveJ`` arguments; ``jointtarget``,
``tooldata``, ``wobjdata`` and ``pose`` have other shapes). Comments (``!``) and strings are ignored.
Each target is taken in the work object and with the tool its motion statements name
(:mod:`.rapid_frames`: ``\WObj:=`` and ``tooldata``/``wobjdata`` declared in the module or in the
``context`` modules; ``wobj0`` = the robot base frame, ``tool0`` and undeclared tools = the robot
file's tool) and written back in that work object. A robtarget no motion moves to is taken in ``wobj0``
with ``tool0`` in a module that moves with no other frames; in one that does, its frames are not known:
its literal is kept, noted. Numbers are written with 4 decimals (mm) and 9
(quaternion, normalised).
"""

from __future__ import annotations

import re

import numpy as np

from ..geometry import se3
from .programs import NUMBER, ProgramTarget, comment_mask, line_of, splice_numbers
from .rapid_frames import frames_of_targets, read_frame_data

__all__ = ["SUFFIXES", "find_targets", "format_target"]

SUFFIXES = (".mod", ".prg", ".sys")
_INT = r"[-+]?\d+"


def _group(n: int, pat: str) -> str:
    return r"\[\s*" + r"\s*,\s*".join([f"({pat})"] * n) + r"\s*\]"


_ROBT = re.compile(
    r"\[\s*" + _group(3, NUMBER) + r"\s*,\s*" + _group(4, NUMBER) + r"\s*,\s*" + _group(4, _INT)
    + r"\s*,\s*\[[^\[\]]*\]\s*\]"
)


def find_targets(text: str, robot, context: str = "", axis_signs=None) -> tuple[list, list]:
    """``(targets, notes)`` of a RAPID module text; ``context``: the text of further modules whose
    ``tooldata``/``wobjdata`` declarations the program uses (module docstring)."""
    clean = _blank(text)
    ctx_clean = _blank(context) if context else ""
    data = read_frame_data(ctx_clean, context, "--context, ", line_of) if context else {}
    data.update(read_frame_data(clean, text, "", line_of))
    targets = []
    for m in _ROBT.finditer(clean):
        g = [float(x) for x in m.groups()[:7]]
        conf = [int(x) for x in m.groups()[7:11]]
        quat = np.array(g[3:7])
        nq = np.linalg.norm(quat)
        if not 0.99 < nq < 1.01:
            raise ValueError(f"line {line_of(text, m.start())}: robtarget quaternion has norm {nq:.4f} (must be 1)")
        pose = se3.pose_to_transform(np.array(g[:3]) * 1e-3, quat / nq)
        decl = re.search(r"\b(?:CONST|PERS|VAR|LOCAL|TASK)?\s*robtarget\s+(\w+)\s*:=\s*$",
                         clean[clean.rfind("\n", 0, m.start()) + 1 : m.start()], re.IGNORECASE)
        spans = [(m.start(i) - m.start(), m.end(i) - m.start()) for i in range(1, 12)]
        targets.append(ProgramTarget(
            start=m.start(), end=m.end(), line=line_of(text, m.start()), pose=pose,
            name=decl.group(1) if decl else "", kind="robtarget", config={"conf": conf},
            parts={"spans": spans, "literal": text[m.start():m.end()], "quat": quat},
        ))
    fr = frames_of_targets(clean, text, targets, robot, data, line_of, ctx_clean, context)
    notes = fr.apply(targets)
    if fr.unknown_frames:  # as KRL's unused .dat points: kept, noted
        k = fr.unknown_frames
        shown = ", ".join(f"{targets[j].name or 'robtarget'} (line {targets[j].line})" for j in k[:8])
        shown += " ..." if len(k) > 8 else ""
        notes = [*notes, f"{targets[k[0]].line}: {len(k)} robtarget{'s' if len(k) > 1 else ''} no motion of the module moves to: {shown}: kept "
                         "(their tool and work object are not known where they are used; move to them in the module, "
                         "or compensate them with the program that does)"]
        targets = [t for j, t in enumerate(targets) if j not in set(k)]
    return targets, notes


def _blank(text: str) -> str:
    """``text`` with its comments and strings replaced by spaces (offsets kept)."""
    mask = comment_mask(text, "!", '"')
    return "".join(" " if m else c for c, m in zip(text, mask[: len(text)]))


def format_target(t: ProgramTarget, command: np.ndarray, q, robot, axis_signs=None) -> str:
    """The literal of ``t`` with the command's position, quaternion (sign nearest the original's)
    and the compensated joints' confdata."""
    from .branches import abb_confdata

    xyz, quat = se3.transform_to_pose(command[None])
    quat = quat[0] / np.linalg.norm(quat[0])
    if np.dot(quat, t.parts["quat"]) < 0:
        quat = -quat
    conf = abb_confdata(robot, np.asarray(q)[None], axis_signs)[0]
    vals = [f"{v:.4f}" for v in xyz[0] * 1e3] + [f"{v:.9f}" for v in quat] + [str(int(c)) for c in conf]
    return splice_numbers(t.parts["literal"], t.parts["spans"], vals)
