"""The orientation part of ``hykin import table --suggest``, and the import's note on orientation columns
it leaves out.

:func:`orientation_lines` proposes the orientation mapping (quaternion, Vicon helical angles, KUKA
``A,B,C``, ``roll/pitch/yaw``, a rotation vector ``rx,ry,rz``) with the angle unit guessed by the rule
the import's unit check applies (:data:`RAD_LOOKS_LIKE_DEG`: a value beyond it declared rad is refused
as degrees), so a printed suggestion is never one the import then refuses. Rotation columns whose
meaning cannot be told are printed commented out under a line saying that, as printed, they are not
imported. :func:`orientation_like_columns` names the columns of a list that look like an orientation
(the import's "position only" note). See ``docs/import-table.md`` §1.
"""

from __future__ import annotations

import math
import re

from .column_groups import quads, rotation_triple, triples

__all__ = ["RAD_LOOKS_LIKE_DEG", "ROTVEC_MIN_ROWS", "angle_unit_guess", "orientation_lines", "orientation_like_columns",
           "rotvec_like"]

#: |angle| above this (rad) declared rad is degrees: the import's unit check and the suggestion's guess
RAD_LOOKS_LIKE_DEG = 2 * math.pi * 1.2
#: sample rows a triple named ``rx, ry, rz`` needs, all with an angle |r| <= 180°, to be proposed as a
#: rotation vector (Euler angles of random orientations pass one row with p ~ 0.8, ten with p ~ 0.1)
ROTVEC_MIN_ROWS = 10
_ROTVEC_NAME = re.compile(r"(?i)^(r|rv|rvec|rotvec|rot[ _]?vec)[ _]?[xyz](?:[ _]?[\[(]?(rad|deg)[\])]?)?$")


def _toml_list(names) -> str:
    return "[" + ", ".join('"' + c + '"' for c in names) + "]"


def angle_unit_guess(values: list[float], default: str) -> tuple[str, str]:
    """``(unit, why)`` of angle columns from their absolute sample ``values`` (deg or rad): ``"deg"`` when
    one exceeds :data:`RAD_LOOKS_LIKE_DEG` (the import would refuse it as rad), else ``default``."""
    if not values:
        return default, "no data seen"
    big = max(values)
    if big > RAD_LOOKS_LIKE_DEG:
        return "deg", f"largest value {big:.4g} > 2π·1.2: degrees"
    return default, f"largest value {big:.4g}"


def rotvec_like(cols, values, unit: str) -> bool:
    """True when ``cols`` (three names) are named as a rotation vector (``rx``, ``RX``, ``rv_x``, ...) and
    every one of at least :data:`ROTVEC_MIN_ROWS` sample rows (``values(col, signed=True)``) has an angle
    ``|r|`` of at most 180° in ``unit``: an axis·angle vector (URScript ``p[x, y, z, rx, ry, rz]``)."""
    if not all(_ROTVEC_NAME.match(c) for c in cols):
        return False
    v = [values(c, signed=True) for c in cols]
    n = min(len(x) for x in v)
    if n < ROTVEC_MIN_ROWS or len({len(x) for x in v}) != 1:
        return False
    lim = (math.pi if unit == "rad" else 180.0) * (1 + 1e-6)
    return all(math.sqrt(sum(x[i] ** 2 for x in v)) <= lim for i in range(n))


def _rot_lines(rot, values, unit_of, angle_units) -> list[str]:
    """Lines for a rotation triple with no convention in its names: a rotation vector when
    :func:`rotvec_like`, else every alternative commented out under a NOT MAPPED line."""
    named = unit_of(rot[0], angle_units)
    unit, why = (named, "from the units line") if named else \
        angle_unit_guess([v for c in rot for v in values(c)], "rad")
    if rotvec_like(rot, values, unit):
        return [f"rotvec = {_toml_list(rot)}  # CHECK: a rotation vector (axis·angle, URScript p[x, y, z, rx, ry, rz]): "
                "every sample row's angle |r| <= 180°; Euler angles if your export says so",
                f'rotvec_unit = "{unit}"  # CHECK ({why})']
    return [f"# NOT MAPPED: {', '.join(rot)} look like an orientation; as printed the import is position only. Either",
            f"# euler = {_toml_list(rot)}",
            '# euler_convention = "XYZ"   # uppercase intrinsic, lowercase extrinsic; CHECK your tracker manual',
            f'# euler_unit = "{unit}"  # ({why})',
            f"# or rotvec = {_toml_list(rot)}  # axis·angle (e.g. URScript)",
            f'# rotvec_unit = "{unit}"']


def orientation_lines(header: list[str], quads, rot, vicon: bool, values, unit_of, angle_units) -> list[str]:
    """The orientation lines of a suggested mapping: ``quads`` (quaternion column groups, scalar first),
    ``rot`` (rotation-named triples), ``vicon`` (Vicon's helical angles); ``values(col, signed=False)``
    the parsed sample cells of a column; ``unit_of(col, units)`` the unit of a units line, or None."""
    low = {h.lower(): h for h in header}
    if quads:
        return [f"quaternion = {_toml_list(quads[0])}  # CHECK (scalar first)",
                'quaternion_order = "wxyz"  # order of the names above']
    if vicon:
        named = unit_of(rot[0][0], angle_units)
        unit, why = (named, "from the units line") if named else \
            angle_unit_guess([v for c in rot[0] for v in values(c)], "deg")
        return [f"rotvec = {_toml_list(rot[0])}  # CHECK: Vicon's helical angles (axis·angle); Euler angles if "
                "your export says so",
                f'rotvec_unit = "{unit}"  # CHECK ({why})']
    for names, conv, note, default in ((("a", "b", "c"), "kuka", "intrinsic Z, Y', X''", "deg"),
                                       (("roll", "pitch", "yaw"), "rpy", "extrinsic x, y, z", "rad")):
        if all(k in low for k in names):
            cols = [low[k] for k in names]
            named = unit_of(cols[0], angle_units)
            unit, why = (named, "from the units line") if named else \
                angle_unit_guess([v for c in cols for v in values(c)], default)
            what = "  # CHECK: KUKA A, B, C" if conv == "kuka" else "  # CHECK"
            return [f"euler = {_toml_list(cols)}{what}", f'euler_convention = "{conv}"  # {note}',
                    f'euler_unit = "{unit}"  # CHECK ({why})']
    return _rot_lines(rot[0], values, unit_of, angle_units) if rot else []


def orientation_like_columns(names: list[str]) -> list[str]:
    """The columns among ``names`` that look like an orientation: quaternion groups (``qw..qz``,
    ``Q0,QX,QY,QZ``), rotation-named triples (``rx, ry, rz``, ``Rot X..Z``), KUKA ``A, B, C`` and
    ``roll, pitch, yaw``; in the order of ``names``."""

    found = {c for qd in quads(names) for c in qd}
    found |= {c for t in triples([n for n in names if n not in found]) if rotation_triple(t) for c in t}
    low = {n.lower(): n for n in names}
    for group in (("a", "b", "c"), ("roll", "pitch", "yaw")):
        if all(k in low for k in group):
            found |= {low[k] for k in group}
    return [n for n in names if n in found]
