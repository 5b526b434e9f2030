"""Imported orientations against the robot's rotations (``hykin import table --robot``).

With a robot given, an import checks what ``calibrate`` and ``evaluate`` would check later: that the
orientations, read as mapped, are the robot's rotations up to one fixed frame
(:func:`hykin.io.plausibility.check_orientation_order`). A wrong Euler convention (``xyz`` for KUKA's
``A, B, C``, which are intrinsic ``Z, Y', X''``; ``rpy`` with the columns in ``A, B, C`` order) gives
orientations up to 180° wrong; it is refused before the file is written, and the line names the axis
sequences, of the 24 (12 orders, intrinsic or extrinsic), under which the same columns fit.
"""

from __future__ import annotations

import itertools

import numpy as np
from scipy.spatial.transform import Rotation

from ..io.plausibility import PlausibilityError, check_orientation_order, frame_groups

__all__ = ["check_imported_orientations", "euler_sequences"]


def euler_sequences() -> list[str]:
    """The 24 scipy Euler sequences: proper (``zyz``) and Tait–Bryan (``zyx``) orders, extrinsic (lower
    case) and intrinsic (upper case)."""
    orders = ["".join(p) for p in itertools.product("xyz", repeat=3) if p[0] != p[1] and p[1] != p[2]]
    return [s for o in orders for s in (o, o.upper())]


def _named(seq: str) -> str:
    return f'euler_convention = "{seq.lower()}", euler_extrinsic = {"true" if seq.islower() else "false"}'


def check_imported_orientations(robot, ds, *, where: str, euler_deg=None, euler_seq: str | None = None) -> None:
    """Refuse orientations of dataset ``ds`` (joints rad / m, ``quat_wxyz`` scalar first) that do not fit
    ``robot`` in one line; rows of each station / tool (:func:`hykin.io.plausibility.frame_groups`) are
    checked on their own, as each has its own frames. ``euler_deg`` ``(N, 3)``: the Euler angles they
    were made from (degrees, columns as mapped) under ``euler_seq`` (scipy's sequence): the line then
    names the sequence under which those columns fit instead."""
    q = np.asarray(ds.q, dtype=np.float64)
    groups = frame_groups(ds)
    parts = [np.arange(len(q))] if groups is None else [np.flatnonzero(groups == g) for g in dict.fromkeys(groups.tolist())]

    def misfit(quat):  # the worst group's median misfit (deg; None: too little rotation to tell)
        got = [check_orientation_order(robot, q[i], quat[i], where=where) for i in parts]
        got = [g for g in got if g is not None]
        return max(got) if got else None

    try:
        misfit(np.asarray(ds.quat_wxyz, dtype=np.float64))
        return
    except PlausibilityError as e:
        if euler_deg is None:
            raise
        first = str(e)
    ang = np.asarray(euler_deg, dtype=np.float64)
    fits = []
    for seq in euler_sequences():
        if seq == euler_seq:
            continue
        quat = Rotation.from_euler(seq, ang, degrees=True).as_quat(canonical=True, scalar_first=True)
        try:
            mis = misfit(quat)
        except PlausibilityError:
            continue
        if mis is not None:
            fits.append((mis, seq))
    given = f"read as {_named(euler_seq)}" if euler_seq else "as mapped"
    m = next(iter(_misfit(first)), None)
    head = (f"{where}: the Euler angles {given} do not match the rotations of robot {robot.name!r} at these joints"
            + (f" (median misfit {m})" if m else ""))
    if fits:
        # cyclic relabellings of the axes (zyx, yxz, xzy) differ by fixed rotations, which the measurement and
        # tool frames absorb: they fit alike; the usual names first
        common = ("zyx", "xyz", "zyz", "zxz")
        fits.sort(key=lambda f: (round(f[0], 2), f[1].lower() not in common, f[1]))
        best, alike = fits[0], [s for d, s in fits[1:] if d <= 1.01 * fits[0][0] + 1e-9 and s.islower() == fits[0][1].islower()]
        also = f" (alike: {', '.join(a.lower() for a in alike)}, the same axes relabelled)" if alike else ""
        raise PlausibilityError(f"{head}; the same columns fit as {_named(best[1])} ({best[0]:.2g}°){also}: set that "
                                "in the mapping") from None
    raise PlausibilityError(f"{head}, nor under any other of the 24 axis sequences: check the euler columns, "
                            "euler_unit, the joint columns' order and the robot file") from None


def _misfit(msg: str) -> list[str]:
    """The "median misfit …°" figure of a check's line, if it has one."""
    import re

    return re.findall(r"median misfit ([0-9.e+\-]+°)", msg)
