"""Orientation columns whose names contradict the order they are read in (``hykin import table``).

A quaternion named ``QX,QY,QZ,QW`` read in the default order w, x, y, z, or Euler angles named ``RZ,RY,RX``
read by a convention about x, y, z, give orientations up to 180 degrees wrong -- and the header alone shows
it. :func:`check_orientation_names` refuses such a mapping in one line naming the columns and the option.
"""

from __future__ import annotations

import re

from .table_map import TableMap, TableMapError, euler_sequence

__all__ = ["check_orientation_names"]

#: the component letter a column name ends with: "QW", "q_w", "qw", "Quat W", "Rotation X [deg]", "RZ", "W" --
#: a letter alone or after a separator or a quaternion/rotation prefix ("box", "index" name no component)
_COMPONENT = re.compile(r"^(?:.*[^a-z])?(?:q|quat|quaternion|r|rot|rotation|orientation|angle|euler)?[ _.:\-]*"
                        r"([wxyz])$")


def _component_letter(name: str) -> str | None:
    """The axis / quaternion component (w, x, y, z) a column name states, or None."""
    n = re.sub(r"\[[^\]]*\]|\([^)]*\)", "", name).strip().lower()
    mt = _COMPONENT.match(n)
    return mt.group(1) if mt else None


def check_orientation_names(m: TableMap, where: str = "<mapping>") -> None:
    """Refuse orientation columns whose names contradict the order they are read in: quaternion columns
    named x, y, z, w (``QX,QY,QZ,QW``) read as w, x, y, z (``quaternion_order``), or Euler columns named
    for axes z, y, x (``RZ,RY,RX``) read by a convention about x, y, z. Read in the wrong order the
    orientations are up to 180 degrees wrong, and the header alone shows it. Names that state no
    component (``q1..q4``, KUKA ``A,B,C``, Fanuc ``W,P,R``) are not judged."""
    if m.orientation == "quaternion" and m.quaternion:
        cols = list(m.quaternion)
        letters = [_component_letter(c) for c in cols]
        if None in letters or sorted(letters) != ["w", "x", "y", "z"]:
            return
        named, order = "".join(letters), m.quaternion_order
        if named == order:
            return
        fix = (f"give --quaternion-order {named} (quaternion_order = \"{named}\")" if named in ("wxyz", "xyzw") else
               "list them as w, x, y, z (--quaternion " + ",".join(cols[letters.index(k)] for k in "wxyz")
               + ") or as x, y, z, w with --quaternion-order xyzw")
        raise TableMapError(f"{where}, columns {','.join(cols)}: the quaternion columns are named {','.join(named)} but "
                            f"are read in the order {','.join(order)} (quaternion_order = \"{order}\", the default "
                            f"wxyz unless given): column {cols[order.index('w')]!r} would be taken as w and the "
                            f"orientations would be wrong by up to 180 deg; {fix}", file=where, column=",".join(cols))
    if m.orientation == "euler" and m.euler and m.euler_convention:
        cols = list(m.euler)
        letters = [_component_letter(c) for c in cols]
        if None in letters or "w" in letters:
            return
        seq = euler_sequence(m, where)
        named, axes = "".join(letters), seq.lower()
        if named == axes:
            return
        if len(set(named)) == 3:
            fix = (f"list the columns in the convention's order (--euler "
                   + ",".join(cols[named.index(k)] for k in axes) + ") if the convention is right, or give "
                   f"--euler-convention {named if seq.islower() else named.upper()} if the columns' order is")
        else:
            fix = "check the columns and --euler-convention"
        raise TableMapError(f"{where}, columns {','.join(cols)}: the Euler columns name the axes {','.join(named)} but "
                            f"euler_convention {m.euler_convention!r} ({'extrinsic' if seq.islower() else 'intrinsic'} "
                            f"{','.join(seq)}) rotates about {','.join(axes)} in that order (the angles are read in the "
                            f"convention's order): the orientations would be wrong; {fix}", file=where,
                            column=",".join(cols))
