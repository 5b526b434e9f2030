"""Unit and convention plausibility: catch data declared in the wrong unit or convention before a
fit, a calibration, a registration or a query turns them into a confident wrong answer.

Each check compares the data with what the robot itself implies, with quantities that do not depend
on the measurement frame (data may be in a tracker frame metres away, with an unknown tool):

* **length unit** (:func:`check_position_scale`): the ratio ``s`` of the RMS spread (about the
  centroid) of the measured positions to that of the nominal FK positions at the same joints. The
  right units give ``s ≈ 1`` (tool offsets and calibration errors move it by tens of per cent at
  most); metre data declared mm give ``s ≈ 1e-3``, mm data declared m ``s ≈ 1e3``; radians declared
  degrees shrink the nominal motion and give ``s`` of tens or more.
* **quaternion order** (:func:`check_orientation_order`): relative rotations ``R_i R_jᵀ`` equal the
  nominal ``R̂_i R̂_jᵀ`` turned by one fixed rotation (measurement frame), found by the rigid fit
  :func:`hykin.geometry.rigid.kabsch` of their rotation vectors; the misfit is compared under the
  declared scalar-first reading and the scalar-last one.
* **joint unit without poses** (:func:`check_joint_unit`): radians declared degrees leave every
  revolute joint within ±6.3° (degrees declared radians are caught in :mod:`hykin.io.dataset`:
  values beyond ±2π or the limits).
* **target reach** (:func:`check_target_reach`): IK targets against the robot's reach.

Every check subsamples at most ``MAX_ROWS`` rows and is vectorised (milliseconds). A failed check
raises :class:`PlausibilityError` (a ``ValueError``) with one line naming the file and the likely cause.
"""

from __future__ import annotations

import numpy as np

from ..kinematics.robot import Robot, robot_reach_m

__all__ = [
    "MAX_ROWS",
    "MIN_FIT_ROWS",
    "PlausibilityError",
    "check_calibration_size",
    "check_dataset",
    "check_fit_data",
    "check_fit_size",
    "check_joint_unit",
    "check_orientation_order",
    "check_position_scale",
    "check_target_reach",
    "frame_groups",
    "minimum_fit_rows",
]

MAX_ROWS = 500
# A spread ratio outside [1/SCALE_LIMIT, SCALE_LIMIT] cannot come from tool offsets or calibration
# errors (those stay within a factor ~2); a unit slip is a factor 1000 (tens for rad read as deg).
SCALE_LIMIT = 10.0
# With every revolute joint within ±6.3° under --angle-unit deg (radians read as degrees), a spread
# ratio above this is a unit slip (a real small-angle sweep in degrees gives s ~ 1).
RAD_AS_DEG_SCALE = 2.0
# Median misfit (deg) of the relative rotation vectors after the frame fit above which orientations do
# not belong to the robot's rotations. Real rotation errors of a robot (calibration, compliance) are
# below 1° (measured 0.11° on UR10 series B, tracker frame).
ORIENTATION_LIMIT_DEG = 5.0


class PlausibilityError(ValueError):
    """Data inconsistent with the robot in a way a unit or convention slip explains (one line)."""


def _rows(n: int) -> np.ndarray:
    """At most MAX_ROWS evenly spread row indices (deterministic)."""
    return np.unique(np.linspace(0, n - 1, min(n, MAX_ROWS)).astype(np.int64))


def _nominal(robot: Robot, q: np.ndarray) -> np.ndarray:
    from ..kinematics.fk import fk

    return fk(robot, q)


def check_position_scale(robot: Robot, q, xyz_m, *, where: str = "<data>", length_unit: str = "m",
                         angle_unit: str = "rad", T_nominal=None) -> float | None:
    """Similarity scale of nominal FK positions onto measured ``xyz_m`` ``(N, 3)`` (m) at joints ``q``
    ``(N, dof)`` (rad); raises :class:`PlausibilityError` when it is a unit slip. Returns the scale
    (None when the data are too few or degenerate to tell)."""
    q = np.asarray(q, dtype=np.float64)
    xyz = np.asarray(xyz_m, dtype=np.float64)
    if len(q) < 4:
        return None
    idx = _rows(len(q))
    P_hat = (_nominal(robot, q[idx]) if T_nominal is None else np.asarray(T_nominal)[idx])[:, :3, 3]
    P = xyz[idx]
    # RMS spread about the centroid: frame independent, and unlike the Umeyama scale not shrunk
    # toward 0 when the two point sets correlate poorly (e.g. radians read as degrees).
    spread_hat = np.sqrt(np.mean(np.sum((P_hat - P_hat.mean(0)) ** 2, axis=1)))
    spread = np.sqrt(np.mean(np.sum((P - P.mean(0)) ** 2, axis=1)))
    if spread_hat < 1e-9 or spread < 1e-12:
        return None  # no motion to compare
    s = float(spread / spread_hat)
    rev = robot.revolute
    # radians declared degrees leave every revolute joint within ±6.3° and shrink the nominal motion:
    # with that joint pattern, positions spreading clearly more than the nominal motion are evidence
    # enough (a robot with short links, e.g. a UR5, gives s ~ 3-5 rather than tens)
    small_q = rev.any() and np.abs(q[:, rev]).max() < np.radians(6.3) * 1.01
    if angle_unit == "deg" and small_q and s > RAD_AS_DEG_SCALE:
        raise PlausibilityError(
            f"{where}: measured positions span {s:.3g}x what robot {robot.name!r} moves at these joints while every "
            "joint is within ±6.3°: the joints look like radians declared --angle-unit deg (use --angle-unit rad)")
    if 1.0 / SCALE_LIMIT <= s <= SCALE_LIMIT:
        return s
    if s < 1.0 / SCALE_LIMIT:
        if length_unit == "mm":
            cause = "the positions look like metres declared --length-unit mm (use --length-unit m)"
        else:
            cause = "wrong --length-unit, or data of another robot"
    else:
        if length_unit == "m":
            cause = "the positions look like millimetres declared metres (use --length-unit mm)"
        else:
            cause = "wrong --length-unit or --angle-unit, or data of another robot"
    raise PlausibilityError(
        f"{where}: measured positions span {s:.3g}x what robot {robot.name!r} moves at these joints "
        f"(expected ~1): {cause}")


def _pair_rotvecs(R: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """Rotation vectors (rad) of ``R_i R_jᵀ`` for index pairs, ``(P, 3)``."""
    from ..geometry.se3 import matrix_to_rotvec

    return matrix_to_rotvec(np.einsum("nab,ncb->nac", R[i], R[j]))


def _pairs(n: int, ref_R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs (three random matchings, deterministic) whose nominal relative rotation is between
    10° and 150° (clear axis, away from the ±π ambiguity of the rotation vector)."""
    rng = np.random.default_rng(0)
    i = np.tile(np.arange(n), 3)
    j = np.concatenate([rng.permutation(n) for _ in range(3)])
    keep = i != j
    i, j = i[keep], j[keep]
    ang = np.linalg.norm(_pair_rotvecs(ref_R, i, j), axis=1)
    keep = (ang > np.radians(10.0)) & (ang < np.radians(150.0))
    return i[keep], j[keep]


# an Euler import with the wrong convention or angle order gives rotations that look reordered or inverted
_EULER_HINT = ("; if these orientations were converted from Euler angles (hykin import table --euler), the "
               "quaternion reading is not the cause: check --euler-convention, --euler-extrinsic/--euler-intrinsic "
               "and the order of the angle columns (KUKA A,B,C: --euler-convention kuka)")


def check_orientation_order(robot: Robot, q, quat_wxyz, *, where: str = "<data>", T_nominal=None,
                            order_only: bool = False) -> float | None:
    """Compare measured orientations (unit quaternions as read, scalar first) with the robot's
    rotations at joints ``q``; raises :class:`PlausibilityError` when the scalar-last reading fits
    clearly better, or when neither reading matches (``order_only``: not then, for joints that only
    hint at the rotations, e.g. a compensation's branch joints). Returns the median misfit (deg) of the
    declared reading (None when too few rows or too little rotation to tell).

    Measured ``R_i = B R̂_i U`` (unknown measurement frame ``B`` and tool rotation ``U``), so the
    relative rotations ``R_i R_jᵀ = B R̂_i R̂_jᵀ Bᵀ``: their rotation vectors are those of the nominal
    model turned by the one rotation ``B``, found by the rigid fit :func:`hykin.geometry.rigid.kabsch`
    (the vector sets are symmetrised so the fit's translation is zero). A pair-angle comparison would
    not do: the angle of ``q_i* q_j`` is ``2 acos|q_i·q_j|``, blind to any fixed reordering of the
    quaternion components."""
    from ..geometry.lsq import ReferencingError
    from ..geometry.rigid import kabsch
    from ..geometry.se3 import matrix_to_rotvec, quat_to_matrix

    q = np.asarray(q, dtype=np.float64)
    quat = np.asarray(quat_wxyz, dtype=np.float64)
    if len(q) < 6:
        return None
    idx = _rows(len(q))
    R_hat = (_nominal(robot, q[idx]) if T_nominal is None else np.asarray(T_nominal)[idx])[:, :3, :3]
    i, j = _pairs(len(idx), R_hat)
    if len(i) < 6:
        return None  # the robot hardly rotates: nothing to compare
    v_hat = _pair_rotvecs(R_hat, i, j)
    conj = np.array([1.0, -1.0, -1.0, -1.0])
    readings = {"wxyz": quat[idx], "xyzw": quat[idx][:, [3, 0, 1, 2]], "inverse": quat[idx] * conj}
    mis, direct = {}, {}
    for name, quat_read in readings.items():
        R = quat_to_matrix(quat_read)
        v = _pair_rotvecs(R, i, j)
        try:
            B, _ = kabsch(np.concatenate([v_hat, -v_hat]), np.concatenate([v, -v]))
        except ReferencingError:
            return None  # all relative rotations about one axis: the frame is not determined
        mis[name] = float(np.degrees(np.median(np.linalg.norm(v - v_hat @ B.T, axis=1))))
        # without any frame change (data in the robot base frame, nominal tool)
        direct[name] = float(np.degrees(np.median(np.linalg.norm(
            matrix_to_rotvec(np.einsum("nab,ncb->nac", R, R_hat)), axis=1))))
        if name == "wxyz" and mis[name] <= ORIENTATION_LIMIT_DEG:
            return mis[name]
    # Up to the unknown frames, reading x,y,z,w as w,x,y,z is the same as inverting the rotations
    # (the reordering is a quaternion product with a conjugation), so the relative fit cannot tell
    # the two apart; the direct comparison can when the data are in the robot base frame.
    best = min(mis["xyzw"], mis["inverse"])
    if best < 0.3 * mis["wxyz"]:
        if direct["xyzw"] <= ORIENTATION_LIMIT_DEG:
            cause = "quaternions look scalar-last (x,y,z,w) under a qw,qx,qy,qz header; reorder the columns"
        elif direct["inverse"] <= ORIENTATION_LIMIT_DEG:
            cause = ("quaternions look inverted (the tool->base rotation, or conjugated); "
                     "give the base->tool rotation, qw,qx,qy,qz")
        else:
            cause = ("quaternions look scalar-last (x,y,z,w) under a qw,qx,qy,qz header, or inverted "
                     "(tool->base rotation); give the base->tool rotation as qw,qx,qy,qz")
        raise PlausibilityError(
            f"{where}: {cause} (rotations fit robot {robot.name!r} to {best:.2g}° so read vs "
            f"{mis['wxyz']:.2g}° as given){_EULER_HINT}")
    if order_only:
        return mis["wxyz"]
    raise PlausibilityError(
        f"{where}: measured orientations do not match the rotations of robot {robot.name!r} at these joints "
        f"(median misfit {mis['wxyz']:.2g}° after the best frame rotation): check the quaternion convention "
        "(unit, scalar first, base->tool rotation), the joint order and directions (an axis counting the other way), "
        "the robot file (twists, joint zero offsets, "
        "DH vs MDH convention, angle_unit: a calibration of the positions alone, without the orientation columns, "
        "names the parameter that is off), whether the rows come from several tracker stations or tools (a station / "
        "tool column gives each row its own frame), whether joints and measurements are out of step (a row missing or doubled "
        f"in one of the files), or drop the orientation columns{_EULER_HINT}")


def check_joint_unit(robot: Robot, q, *, where: str = "<joints>", angle_unit: str = "rad") -> None:
    """Joints only: radians declared as degrees leave every revolute joint within ±6.3°; refuse that
    when the robot's ranges are wide and there are several rows (``q`` ``(N, dof)`` in rad as read)."""
    q = np.asarray(q, dtype=np.float64)
    rev = robot.revolute
    if angle_unit != "deg" or len(q) < 5 or not rev.any():
        return
    wide = (robot.upper - robot.lower)[rev] > np.radians(60.0)
    if not wide.any():
        return
    qr = q[:, rev][:, wide]
    if np.abs(qr).max() <= np.radians(2 * np.pi) * 1.0001 and np.ptp(qr, axis=0).max() > 0:
        raise PlausibilityError(
            f"{where}: every revolute joint value is within ±{np.degrees(np.abs(qr).max()):.3g}° "
            "(= ±2π read as degrees): the joints look like radians declared --angle-unit deg (use --angle-unit rad)")


def check_target_reach(robot: Robot, T_target, *, where: str = "<targets>", length_unit: str = "m",
                       frame=None) -> None:
    """IK targets ``(N, 4, 4)`` (m) against the robot's reach: all far beyond it, or all within a
    hundredth of it around the base, is a unit slip. ``frame`` ``(4, 4)``: world -> model frame
    applied before the robot base (a registered model's ``frame_pre``)."""
    T = np.asarray(T_target, dtype=np.float64)
    if len(T) == 0:
        return
    reach = robot_reach_m(robot)
    base = robot.base if frame is None else np.asarray(frame) @ robot.base
    d = np.linalg.norm(T[_rows(len(T)), :3, 3] - base[:3, 3], axis=1)
    if np.median(d) > 10.0 * reach:
        hint = ("the targets look like millimetres declared metres (use --length-unit mm)" if length_unit == "m"
                else "wrong --length-unit")
        raise PlausibilityError(f"{where}: targets lie {np.median(d):.3g} m (median) from the base of robot "
                                f"{robot.name!r}, which reaches {reach:.3g} m: {hint}")
    if len(d) >= 3 and d.max() < reach / 100.0:
        hint = ("the targets look like metres declared --length-unit mm (use --length-unit m)" if length_unit == "mm"
                else "wrong --length-unit")
        raise PlausibilityError(f"{where}: every target lies within {d.max() * 1e3:.3g} mm of the base of robot "
                                f"{robot.name!r}, which reaches {reach:.3g} m: {hint}")


def check_dataset(robot: Robot, ds, *, where: str | None = None, length_unit: str = "m", angle_unit: str = "rad") -> None:
    """Every check a measured dataset (joints and poses) allows: position scale, then orientation
    order (when the data have orientation). One nominal FK of at most ``MAX_ROWS`` rows."""
    where = where or getattr(ds, "source", "") or "<data>"
    q = np.asarray(ds.q, dtype=np.float64)
    if q.ndim != 2 or q.shape[1] != robot.dof or len(q) < 4:
        return
    groups = frame_groups(ds)
    if groups is not None:  # several stations / tools: each has its own frames, checked on its own rows
        for key in dict.fromkeys(groups.tolist()):
            check_dataset(robot, ds.subset(groups == key), where=f"{where} ({key})", length_unit=length_unit,
                          angle_unit=angle_unit)
        return
    idx = _rows(len(q))
    T_hat = np.full((len(q), 4, 4), np.nan)
    T_hat[idx] = _nominal(robot, q[idx])
    check_position_scale(robot, q, ds.xyz_m, where=where, length_unit=length_unit, angle_unit=angle_unit,
                         T_nominal=T_hat)
    if getattr(ds, "quat_wxyz", None) is not None:
        check_orientation_order(robot, q, ds.quat_wxyz, where=where, T_nominal=T_hat)


def frame_groups(ds) -> np.ndarray | None:
    """``(N,)`` "station 'A', tool 'T1'" of each row when ``ds`` names several stations or tools, else None."""
    from .dataset import STATION_COLUMN, TOOL_COLUMN, row_labels

    if not isinstance(getattr(ds, "extra", None), dict) or not hasattr(ds, "subset"):
        return None
    parts = [(c, row_labels(ds, c)) for c in (STATION_COLUMN, TOOL_COLUMN)]
    parts = [(c, v) for c, v in parts if v is not None and len(set(v.tolist())) > 1]
    if not parts:
        return None
    return np.array([", ".join(f"{c} {x!r}" for (c, _), x in zip(parts, row)) for row in zip(*(v.tolist() for _, v in parts))])


# --------------------------------------------------------------------------- tiny data

MIN_FIT_ROWS = 30


def minimum_fit_rows(robot: Robot, has_orientation: bool) -> int:
    """Least number of poses :meth:`hykin.HybridModel.fit` accepts: ``max(30, ⌈2 P / m⌉)`` with
    ``P = 5·dof + 12`` (geometry a, α, d, θ, β per joint, base and tool 6 each; an upper bound of
    what the calibration may identify, compliance included) and ``m`` = 6 values per pose (3 for
    position-only data): twice as many equations as parameters, and enough rows that the 10 %
    validation hold-out (early stopping, uncertainty bands) has at least 3 rows."""
    P = 5 * robot.dof + 12
    m = 6 if has_orientation else 3
    return max(MIN_FIT_ROWS, int(np.ceil(2 * P / m)))


def check_fit_size(robot: Robot, data, what: str = "fit") -> None:
    """Raise :class:`PlausibilityError` when ``data`` (a Dataset) has fewer rows than
    :func:`minimum_fit_rows` (say what the minimum is and why)."""
    n = len(np.asarray(data.q))
    has_rot = getattr(data, "quat_wxyz", None) is not None
    need = minimum_fit_rows(robot, has_rot)
    if n < need:
        raise PlausibilityError(
            f"{getattr(data, 'source', '') or 'training data'}: {n} poses are too few to {what} robot {robot.name!r}: "
            f"at least {need} are needed (the calibration identifies up to {5 * robot.dof + 12} parameters from "
            f"{6 if has_rot else 3} values per pose, with a 2x margin, and 10 % are held out for validation)")


def check_fit_data(robot: Robot, data) -> None:
    """What :meth:`hykin.HybridModel.fit` checks first: enough poses (:func:`check_fit_size`), and
    positions / orientations consistent with the robot (:func:`check_dataset`; units are those of
    the in-memory data, SI), unless the data were read with the unit checks off
    (``data.meta["unit_check"]`` False: :func:`hykin.io.dataset_files.read_dataset`'s ``unit_check``)."""
    check_fit_size(robot, data)
    if not (getattr(data, "meta", None) or {}).get("unit_check", True):
        return
    if np.isfinite(np.asarray(data.q)).all() and np.isfinite(np.asarray(data.xyz_m)).all():
        check_dataset(robot, data)


def check_calibration_size(n_poses: int, n_params: int, values_per_pose: int) -> None:
    """Raise :class:`PlausibilityError` when ``n_poses`` poses cannot determine ``n_params`` parameters
    (fewer equations than unknowns: the calibration would fit the noise exactly)."""
    need = int(np.ceil(n_params / values_per_pose))
    if n_poses < need:
        raise PlausibilityError(
            f"calibration: {n_poses} poses are too few for {n_params} parameters: at least {need} are needed "
            f"({values_per_pose} values per pose); measure more poses or select fewer parameters")
