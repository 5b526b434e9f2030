"""The flange of a URDF robot: the frame a robot program's tool is given in.

A robot program names its TCP relative to the controller's flange frame (KRL ``TOOL_DATA``, RAPID
``tooldata``, URScript ``set_tcp``, ``hykin compensate --tool``). For a DH/MDH robot file that is the end
of its chain, where the file's ``[tool]`` starts. A URDF, read by :mod:`hykin.io.urdf`, folds every fixed
joint after the last movable joint into the robot's tool, so the chain ends at the last movable joint's
frame — for many makers' URDFs the wrist centre, not the flange: a tool given from the flange was applied
115 mm short (probe report s40).

A maker's URDF names its flange. ROS-Industrial (REP 199) gives two links fixed to the last link: ``flange``
(x out of the flange, the ROS convention; KUKA's own flange frame has x out too) and ``tool0`` (the
frame of the controller's null tool: z out for ABB, UR, Fanuc). :func:`choose_flange` takes ``--flange
LINK`` when given, else ``flange`` for KRL and CSV targets (``--tool`` is "in the flange frame") and
``tool0`` for RAPID and URScript (then the other name), else
the chain end. The choice is kept in the robot's ``urdf`` record (``flange_link``), and
:func:`flange_of` gives its transform from the chain end. A program without a tool (KRL tool 0, RAPID
``tool0``, URScript without ``set_tcp``) keeps the robot file's TCP, as documented.
"""

from __future__ import annotations

import functools
import xml.etree.ElementTree as ET

import numpy as np

from ..kinematics.robot import Robot, RobotFileError

__all__ = ["choose_flange", "flange_candidates", "flange_of"]

#: preferred flange links per program format (first found wins)
PREFERRED = {"krl": ("flange", "tool0"), "rapid": ("tool0", "flange"), "urscript": ("tool0", "flange"),
             "csv": ("flange", "tool0")}


def _is_urdf(robot: Robot) -> bool:
    return isinstance(getattr(robot, "urdf", None), dict) and "xml" in robot.urdf


@functools.lru_cache(maxsize=32)
def _candidates(xml: str, base_link: str, tip_link: str) -> tuple[tuple[str, tuple], ...]:
    """``((link, chain end -> link as a nested tuple), ...)``: the chain end (the child of the last movable
    joint on the path to ``tip_link``) and every link fixed to it (through fixed joints only), in order."""
    from .urdf import load_urdf_string

    root = ET.fromstring(xml)
    parent_of = {}  # child link -> (joint type, parent link)
    kids: dict[str, list[str]] = {}
    for el in root.findall("joint"):
        p, c = el.find("parent").get("link"), el.find("child").get("link")
        parent_of[c] = (el.get("type"), p)
        kids.setdefault(p, []).append(c)
    end, ln = None, tip_link
    while ln != base_link and ln in parent_of:
        jt, p = parent_of[ln]
        if jt != "fixed":
            end = ln
            break
        ln = p
    if end is None:
        return ()
    out, todo = [], [end]
    while todo:
        ln = todo.pop(0)
        T = load_urdf_string(xml, base_link, ln).tool
        out.append((ln, tuple(map(tuple, T))))
        todo.extend(c for c in kids.get(ln, []) if parent_of[c][0] == "fixed")
    return tuple(out)


def flange_candidates(robot: Robot) -> dict[str, np.ndarray]:
    """``{link: (4, 4)}``: the links a URDF robot's flange may be (the chain end and every link fixed to
    it), each as the transform from the chain end; empty for a robot not read from a URDF."""
    if not _is_urdf(robot):
        return {}
    u = robot.urdf
    return {ln: np.array(T) for ln, T in _candidates(u["xml"], u["base_link"], u["tip_link"])}


def choose_flange(robot: Robot, fmt: str, link: str | None = None, where: str = "--flange") -> tuple[Robot, str]:
    """``(robot, note)``: ``robot`` with its flange chosen (module docstring) in its ``urdf`` record, and a
    note naming the choice where the URDF offers several. ``fmt``: ``krl``, ``rapid``, ``urscript`` or
    ``csv``. :class:`RobotFileError` for a ``link`` that is not a flange candidate, or given for a robot
    that is not a URDF."""
    cands = flange_candidates(robot)
    if link is not None and not cands:
        raise RobotFileError(f"{where}: names a URDF link, but robot {robot.name!r} is not read from a URDF: its "
                             "flange is the end of its chain (where its [tool] starts)")
    if not cands:
        return robot, ""
    names = list(cands)
    if link is not None:
        if link not in cands:
            raise RobotFileError(f"{where}: '{link}' is not a link fixed to the last moving link of robot "
                                 f"{robot.name!r}; the flange can be one of: {', '.join(names)}")
        chosen = link
    else:
        chosen = next((n for n in PREFERRED.get(fmt, PREFERRED["csv"]) if n in cands), names[0])
    note = ""
    if len(names) > 1:
        how = "" if link is not None else " (--flange LINK to choose another"
        how += f": {', '.join(names)})" if how else ""
        note = f"program tools are taken relative to URDF link '{chosen}', the controller's flange{how}"
    return robot.copy(urdf={**robot.urdf, "flange_link": chosen}), note


def flange_of(robot: Robot) -> np.ndarray:
    """``(4, 4)``: the flange (where a program's tool is given from) relative to the chain end: the
    chosen URDF link's transform (:func:`choose_flange`), else the identity."""
    link = robot.urdf.get("flange_link") if _is_urdf(robot) else None
    if not link:
        return np.eye(4)
    return flange_candidates(robot)[link]
