"""What a calibration's data did not cover, said in one line each (warnings, never refusals).

A calibration from a campaign that never moved a joint, or that held the tool at one orientation,
fits its data to the noise and is still wrong elsewhere: the parameters the missing motion would tell
are held at the robot file (or mixed with the base) and the calibrated robot holds only where the data
were taken. :func:`coverage_warnings` names such gaps:

* a joint whose range in the data is below :data:`MIN_RANGE_DEG` (revolute) or :data:`MIN_RANGE_MM`
  (prismatic): what the fit tells about it (its zero, its link, and the tool / base next to it) holds
  only at that joint value;
* a tool offset the data did not determine (``tool.x/y/z`` held at the robot file or undetermined):
  with the tool at one orientation its offset does what the base does, so the calibrated base and tool
  hold only at that orientation.

:func:`mirrored_note` tests, for a refused calibration, whether the measured positions fit the nominal
kinematics much better mirrored (a left-handed measurement frame, two swapped position columns) than
as given, and says so instead of blaming a DH parameter; :func:`quarter_turn_note` whether one joint
zero turned by ±90° / 180° does (a fit started a quarter turn off stops wherever the prior holds it, and
the amount a refusal would report is not what the data want).
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry.rigid import nearest_rotation
from ..kinematics.fk import fk
from ..kinematics.robot import Robot

__all__ = ["MIN_RANGE_DEG", "MIN_RANGE_MM", "coverage_warnings", "data_mistake_note", "joint_range_warnings",
           "mirrored_note", "quarter_turn_note", "rotation_spread_deg", "tool_orientation_warning"]

#: a revolute joint moved by less than this (deg) over the data is reported
MIN_RANGE_DEG = 5.0
#: a prismatic joint moved by less than this (mm) over the data is reported
MIN_RANGE_MM = 5.0
#: a tool rotation spread (deg) below which the tool counts as held at one orientation
ONE_ORIENTATION_DEG = 5.0
#: the mirrored positions must fit at least this many times better than the positions as given
MIRROR_RATIO = 5.0
#: rows used by the mirror test (evenly spread): it is a cheap rigid fit, not a calibration
_MIRROR_ROWS = 2000
#: rows used by the joint-zero turn test (18 rigid fits on a 6-axis arm)
_TURN_ROWS = 400

_TOOL_XYZ = ("tool.x", "tool.y", "tool.z")


def _joint_range(values: np.ndarray, revolute: bool) -> tuple[float, float, float]:
    """``(range, low, high)`` of one joint's values (rad or m); a revolute joint's angles are taken
    relative to the first one, wrapped to ±π (q and q + 2π are the same pose)."""
    if not revolute:
        return float(np.ptp(values)), float(values.min()), float(values.max())
    d = (values - values[0] + math.pi) % (2 * math.pi) - math.pi
    return float(np.ptp(d)), float(values[0] + d.min()), float(values[0] + d.max())


def _num(v: float) -> str:
    """``v`` to 4 significant digits, rounded to 1e-4 first (no ``-3e-13``, no ``-0``)."""
    return f"{round(v, 4) + 0.0:.4g}"


def _neighbours(j: int, n: int) -> str:
    """What joint ``j`` (0-based of ``n``) shares its fixed transform with when it does not move."""
    if n == 1:
        return "the base and the tool"
    return "the base" if j == 0 else ("the tool" if j == n - 1 else "the links next to it")


def joint_range_warnings(robot: Robot, q: np.ndarray, min_deg: float = MIN_RANGE_DEG,
                         min_mm: float = MIN_RANGE_MM) -> list[str]:
    """One warning per joint whose range in ``q`` ``(N, dof)`` (rad / m) is below ``min_deg`` (revolute)
    or ``min_mm`` (prismatic): the calibrated robot holds only near that joint value."""
    out = []
    q = np.asarray(q, dtype=np.float64)
    if q.ndim != 2 or q.shape[0] == 0:
        return out
    n = q.shape[1]
    for j in range(n):
        rev = robot.joint_type[j] != "prismatic"
        rng, lo, hi = _joint_range(q[:, j], rev)
        f, un, lim = (180 / math.pi, "°", min_deg) if rev else (1e3, " mm", min_mm)
        if rng * f >= lim:
            continue
        still = rng * f < 1e-3
        at = f"{_num(lo * f)}{un}" if still else f"{_num(lo * f)}{un} to {_num(hi * f)}{un}"
        moved = "never moved" if still else f"moved only {rng * f:.3g}{un}"
        out.append(f"joint {j + 1} {moved} in the data (range {0 if still else rng * f:.3g}{un}, q{j + 1} = {at}): its parameters and "
                   f"{_neighbours(j, n)} are fitted at that value only, so the calibrated robot holds only near q{j + 1} "
                   f"= {at} (elsewhere it may be off by up to the priors' tolerances): measure with joint {j + 1} "
                   f"moved over its range (a robot whose axis {j + 1} is locked there: the file holds where it is used)")
    return out


def rotation_spread_deg(R: np.ndarray) -> float:
    """Largest angle (deg) of the rotations ``R`` ``(N, 3, 3)`` from their chordal mean."""
    R = np.asarray(R, dtype=np.float64)
    M = nearest_rotation(R.sum(0))
    c = (np.einsum("nij,ij->n", R, M) - 1.0) / 2.0  # cos of the angle of M^T R_i
    return float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0))).max())


def _axes_parallel(robot: Robot, q: np.ndarray) -> bool:
    """Whether every revolute joint axis of ``robot`` is parallel to the others at the first row of ``q``
    (a SCARA, a planar arm): its tool turns about one direction only (probe s41 AP: a SCARA was told to
    measure with the tool at several orientations, which it cannot take)."""
    from ..kinematics.fk import fk_frames

    rev = robot.revolute
    if rev.sum() < 2:
        return True
    z = fk_frames(robot, np.asarray(q[:1], dtype=np.float64)).joint[0, :, :3, 2][: len(rev)][rev]
    return bool(np.all(np.linalg.norm(np.cross(z[0], z), axis=1) < 0.01))  # within ~0.6°: a calibration tilts them


def tool_orientation_warning(res, q: np.ndarray, tool_prior_given: bool = False) -> str | None:
    """The warning for a tool offset the data did not determine (``tool.x/y/z`` of ``res`` held at the
    robot file or undetermined), with the spread of the calibrated tool's orientations over ``q``
    ``(N, dof)`` (measurement frame); None when the offset was determined, not calibrated, or held on
    purpose (``tool_prior_given``: the user stated the tool's tolerance)."""
    st = dict(zip(res.names, res.status or []))
    loose = [n for n in _TOOL_XYZ if st.get(n) in ("held at prior", "undetermined")]
    if not loose or tool_prior_given or _axes_parallel(res.robot, q):
        return None  # (all axes parallel, a SCARA: the tool cannot tilt, its offset along them is never observable)
    spread = rotation_spread_deg(fk(res.robot, np.ascontiguousarray(q))[:, :3, :3])
    how = (f"the tool was held at one orientation (rotation spread {spread:.3g}°), so its offset does what the base does"
           if spread < ONE_ORIENTATION_DEG else f"the tool's orientations (rotation spread {spread:.3g}°) do not tell it")
    return (f"the tool offset was not observable: {how}; {', '.join(loose)} stay at the robot file's [tool] and the "
            f"calibrated base and tool hold only at the measured orientation{'' if spread < ONE_ORIENTATION_DEG else 's'}: "
            f"measure with the tool at several orientations (tens of degrees apart), or give the tool's offset in the "
            f"robot file's [tool] with a tight prior (--prior tool_mm=0.05)")


def coverage_warnings(res, q: np.ndarray, tool_prior_given: bool = False) -> list[str]:
    """All coverage warnings of a calibration ``res`` from joints ``q`` ``(N, dof)`` (rad / m)."""
    out = joint_range_warnings(res.robot, q)
    tw = tool_orientation_warning(res, q, tool_prior_given)
    return out + ([tw] if tw else [])


# --------------------------------------------------------------------------- mirrored data

#: improper signed permutations a user makes by mistake: measured = M @ right-handed
_MIRRORS = {
    "x and y swapped": np.array([[0, 1, 0], [1, 0, 0], [0, 0, 1]], float),
    "y and z swapped": np.array([[1, 0, 0], [0, 0, 1], [0, 1, 0]], float),
    "x and z swapped": np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0]], float),
    "x negated": np.diag([-1.0, 1.0, 1.0]),
    "y negated": np.diag([1.0, -1.0, 1.0]),
    "z negated": np.diag([1.0, 1.0, -1.0]),
}


def _which_mirror(robot: Robot, q: np.ndarray, R_meas: np.ndarray, Q: np.ndarray) -> str | None:
    """Name of the column mistake ``M`` (:data:`_MIRRORS`) with ``Q ≈ M R_b``: ``Q`` the improper map
    robot -> measured positions, ``R_b`` the base rotation the (right-handed) orientations give with the
    robot file's tool; None when no simple mistake is within 5°."""
    T = fk(robot.copy(base=np.eye(4)), q)
    Rb = nearest_rotation(np.einsum("nij,nkj->ik", R_meas, T[:, :3, :3]))  # mean of R_meas,i R_model,i^T
    M = Q @ Rb.T
    for name, Mk in _MIRRORS.items():
        c = (np.trace(Mk.T @ M) - 1.0) / 2.0  # Mk^T M is a rotation: its angle
        if math.degrees(math.acos(min(max(c, -1.0), 1.0))) < 5.0:
            return name
    return None


def _subsample(q: np.ndarray, xyz: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``n`` evenly spread rows of joints ``q`` ``(N, dof)`` and first points ``xyz`` ``(N, [K,] 3)``."""
    P = np.asarray(xyz, dtype=np.float64)
    P = P[:, 0] if P.ndim == 3 else P
    rows = np.unique(np.linspace(0, q.shape[0] - 1, min(q.shape[0], n)).astype(np.int64))
    return np.ascontiguousarray(np.asarray(q, dtype=np.float64)[rows]), P[rows]


def quarter_turn_note(robot: Robot, q: np.ndarray, xyz: np.ndarray) -> str | None:
    """A sentence when turning one DH/MDH joint zero of ``robot`` by ±90° or 180° makes its nominal
    kinematics (base and tool offset free) fit the measured positions ``xyz`` (m) at least
    :data:`MIRROR_RATIO` times better than the robot file as given, else None. A zero a quarter turn off
    makes the fit stop wherever the prior holds it (a few degrees): the amount it reports is not the data's."""
    from .initial_registration import initial_registration

    if robot.convention not in ("dh", "mdh") or q.shape[0] < 6:
        return None
    q, P = _subsample(q, xyz, _TURN_ROWS)
    free = robot.copy(base=np.eye(4))
    given = initial_registration(free, q, P).rms_m
    best = None
    for j in range(robot.dof):
        if robot.joint_type[j] == "prismatic":
            continue
        for turn in (90.0, -90.0, 180.0):
            th = robot.theta_rad.copy()
            th[j] += math.radians(turn)
            rms = initial_registration(free.copy(theta_rad=th), q, P).rms_m
            if best is None or rms < best[0]:
                best = (rms, j, turn)
    if best is None or not (best[0] * MIRROR_RATIO < given and given > 1e-3):
        return None
    rms, j, turn = best
    return (f"joint {j + 1}'s zero looks {'a half' if turn == 180 else 'a quarter'} turn off: with theta{j + 1} "
            f"{turn:+g}° from the robot file the nominal kinematics fit the positions to {rms * 1e3:.3g} mm RMS, against "
            f"{given * 1e3:.3g} mm as given (base and tool fitted freely): check joint {j + 1}'s zero (theta{j + 1} in the "
            f"robot file, or the controller's zero / an offset in the joint column)")


def data_mistake_note(robot: Robot, q: np.ndarray, xyz: np.ndarray, R_meas: np.ndarray | None = None,
                      rows: np.ndarray | None = None) -> str | None:
    """For a refused calibration: :func:`mirrored_note`, else :func:`quarter_turn_note`, else None; on
    ``rows`` only (the reference station's and tool's: one frame) when given."""
    if rows is not None:
        q, xyz, R_meas = q[rows], xyz[rows], None if R_meas is None else R_meas[rows]
    return mirrored_note(robot, q, xyz, R_meas) or quarter_turn_note(robot, q, xyz)


def mirrored_note(robot: Robot, q: np.ndarray, xyz: np.ndarray, R_meas: np.ndarray | None = None) -> str | None:
    """A sentence when the measured positions ``xyz`` ``(N, 3)`` or ``(N, K, 3)`` (m) fit the nominal
    kinematics of ``robot`` (base and tool offset free: :func:`initial_registration`) at least
    :data:`MIRROR_RATIO` times better mirrored than as given, else None. With orientations ``R_meas``
    ``(N, 3, 3)`` that are right-handed, the swapped / negated columns are named."""
    from .initial_registration import initial_registration

    if q.shape[0] < 6:
        return None
    rows = np.unique(np.linspace(0, q.shape[0] - 1, min(q.shape[0], _MIRROR_ROWS)).astype(np.int64))
    q, P = _subsample(q, xyz, _MIRROR_ROWS)
    flip = np.diag([1.0, 1.0, -1.0])
    free = robot.copy(base=np.eye(4))
    given = initial_registration(free, q, P)
    mirr = initial_registration(free, q, P @ flip)
    if not (mirr.rms_m * MIRROR_RATIO < given.rms_m and given.rms_m > 1e-3):
        return None
    which = None
    if R_meas is not None:
        which = _which_mirror(robot, q, np.asarray(R_meas, dtype=np.float64)[rows], flip @ mirr.base[:3, :3])
    cols = f"{which}?" if which else "two of x, y, z swapped or one negated?"
    return (f"the measured positions look mirrored (a left-handed frame or a column mistake: {cols}): the nominal "
            f"kinematics fit them to {mirr.rms_m * 1e3:.3g} mm RMS mirrored against {given.rms_m * 1e3:.3g} mm as given "
            f"(base and tool fitted freely): check the position columns' names and signs and the tracker's frame")
