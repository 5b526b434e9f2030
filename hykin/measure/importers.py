"""Importers of real measured datasets into standard :class:`~hykin.io.dataset.Dataset` s, the nominal
robot models they go with, rigid registration of tracker-frame poses, and three-SMR pose import.

Real data (read in place, never copied; see ``shared/data/README.md``):

* ``serial-robots-ur5`` (UR5, GTS3800 tracker, position only): :func:`import_ur5`,
  :func:`ur5_robot_for_dataset`.
* ``ipa-robot-accuracy`` (UR10, Leica tracker + T-Mac, full 6-D pose in the **tracker frame**):
  :func:`import_ipa_series`, :func:`ipa_nominal_robot`, :func:`register_rigid`.

Generic: :func:`import_three_smr` (pose from three reflectors in a known nest).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..geometry import se3
from ..io.dataset import Dataset, DatasetError, check_units, validate
from ..io.text_table import float_column, lenient_column, read_delimited

__all__ = [
    "IPA_BASE_LINK_FROM_DH",
    "IPA_TCP_FROM_FLANGE",
    "UR5_XT_D5_M",
    "import_ipa_series",
    "import_three_smr",
    "import_ur5",
    "ipa_nominal_robot",
    "register_rigid",
    "registration_errors",
    "ur5_robot_for_dataset",
]


# --------------------------------------------------------------------------- small geometry


def register_rigid(
    T_model: np.ndarray,
    T_meas: np.ndarray,
    *,
    use_orientation: bool = True,
    rot_weight_m_per_rad: float = 0.1,
) -> tuple[np.ndarray, np.ndarray]:
    """Fit ``T_base, T_tool`` (4x4 each) with ``T_meas ≈ T_base · T_model · T_tool``.

    ``T_model``: ``(N, 4, 4)`` model poses (e.g. nominal FK) in the robot base frame, m.
    ``T_meas``: ``(N, 4, 4)`` measured poses in the measurement (tracker) frame, m.
    ``T_base`` maps robot base -> measurement frame; ``T_tool`` maps model TCP -> measured TCP.

    Delegates to :func:`hykin.calibration.frames.fit_frames` (initial guess by Kabsch, rotation mean and
    linear least squares for the translations, then non-linear least squares on the position error
    (m) and, with ``use_orientation``, ``rot_weight_m_per_rad × log(R_meas R̂ᵀ)``), so any tool rotation
    (e.g. 180°) converges. Position-only data (``use_orientation=False``) fit the base and the tool
    translation; the tool rotation (unobservable) stays identity.
    """
    T_model = np.asarray(T_model, dtype=np.float64).reshape(-1, 4, 4)
    T_meas = np.asarray(T_meas, dtype=np.float64).reshape(-1, 4, 4)
    n = T_model.shape[0]
    if T_meas.shape[0] != n:
        raise ValueError(f"register_rigid: {n} model poses but {T_meas.shape[0]} measured poses")
    need = 3 if use_orientation else 4
    if n < need:
        raise ValueError(f"register_rigid: need at least {need} poses, got {n}")
    from ..calibration.frames import fit_frames

    return fit_frames(T_model, T_meas, position_only=not use_orientation, orientation_weight_m_per_rad=rot_weight_m_per_rad)


def registration_errors(T_model, T_meas, T_base, T_tool) -> tuple[np.ndarray, np.ndarray]:
    """Per-pose ``(pos_err_mm (N,), ang_err_deg (N,))`` of ``T_meas`` vs ``T_base · T_model · T_tool``."""
    return se3.pose_error(np.asarray(T_meas), np.asarray(T_base) @ np.asarray(T_model) @ np.asarray(T_tool))


# --------------------------------------------------------------------------- UR5 (serial-robots-ur5)

#: d5 (m) with which the dataset's nominal positions ``x_t`` were computed. The UR5 data sheet says
#: 0.09465; the dataset's ``x_t`` is reproduced to 0.004 mm only with 0.09456 (digits swapped);
#: with 0.09465 the difference is a near-constant 0.09 mm.
UR5_XT_D5_M = 0.09456

_UR5_COLUMNS = ["x_t", "y_t", "z_t", "x_dif", "y_dif", "z_dif"] + [f"joint_{i}" for i in range(1, 7)]


def ur5_robot_for_dataset(match_xt: bool = True):
    """The UR5 nominal model of the serial-robots-ur5 data: ``ur5`` preset, TCP 31 mm along tool z.

    ``match_xt=True`` (default) sets ``d5 = 0.09456 m`` (:data:`UR5_XT_D5_M`), the value with which the
    dataset's nominal positions ``x_t`` were computed: FK then reproduces ``x_t`` to < 0.005 mm, so
    errors against it equal the dataset's ``x_dif`` (the published "uncalibrated" 2.566 mm refers to
    this model). ``match_xt=False`` keeps the data-sheet ``d5 = 0.09465 m`` (0.09 mm off ``x_t``).
    Base is identity (``x_t`` is in the robot base frame).
    """
    from ..io.robot_file import load_robot

    r = load_robot("ur5")
    d = r.d_m.copy()
    if match_xt:
        d[4] = UR5_XT_D5_M
    return r.copy(d_m=d, tool=se3.trans(0.0, 0.0, 0.031), name="ur5-dataset" if match_xt else r.name)


def _refuse_unknown_columns(where: str, header, known: set, layout: str, dof: int) -> None:
    """A fixed-layout importer reads only files it fully understands: any other column (a 7th
    joint, a second reflector, ...) is refused with a pointer to the generic importer."""
    extra = [h for h in header if h not in known]
    if extra:
        c = extra[0]
        what = f"a further joint: this importer reads exactly {dof} joints" if "joint" in c.lower() \
            else f"not part of the {layout} layout"
        raise DatasetError(f"{where}, column '{c}': {what}; refusing to drop it silently: map the file with "
                           f"`hykin import table {where} --suggest`", file=where, column=c)


def import_ur5(path: str | Path) -> Dataset:
    """Read a serial-robots-ur5 CSV (``UR5/3D_UR5_uncalibrated_*_cleaned.csv``) into a Dataset.

    ``q`` = ``joint_1..6`` converted from degrees; ``xyz_m`` = measured position
    ``(x_t + x_dif) / 1000`` in the robot base frame; position-only (``quat_wxyz=None``).
    Extras: ``x_t_m, y_t_m, z_t_m`` (nominal FK position of the commanded joints, m) and
    ``step_order`` when present. Any other column (e.g. a ``joint_7``) is refused, not dropped:
    such files go through ``hykin import table``.
    """
    where = str(path)
    t = read_delimited(path, delimiter=",", layout_hint="is that the file's delimiter?")
    header = t.header
    missing = [c for c in _UR5_COLUMNS if c not in header]
    if missing:
        raise DatasetError(f"{where}: not a serial-robots-ur5 file: missing column(s) {', '.join(missing)} "
                           f"(expected {', '.join(_UR5_COLUMNS)})", file=where, column=missing[0])
    _refuse_unknown_columns(where, header, set(_UR5_COLUMNS) | {"step_order"}, "serial-robots-ur5", 6)
    num = {c: float_column(t, c, finite=False, empty_hint="(import ur5 reads every row and has no row filter: delete "
                           "or complete that row in the file)") for c in _UR5_COLUMNS}
    if num["x_t"].size == 0:
        raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
    q = np.radians(np.stack([num[f"joint_{i}"] for i in range(1, 7)], axis=1))
    xt = np.stack([num["x_t"], num["y_t"], num["z_t"]], axis=1)
    xyz = (xt + np.stack([num["x_dif"], num["y_dif"], num["z_dif"]], axis=1)) * 1e-3
    extra = {"x_t_m": xt[:, 0] * 1e-3, "y_t_m": xt[:, 1] * 1e-3, "z_t_m": xt[:, 2] * 1e-3}
    if "step_order" in header:
        extra["step_order"] = lenient_column(t.col("step_order"))
    ds = Dataset(q=q, xyz_m=xyz, quat_wxyz=None, extra=extra, source=where,
                 meta={"frame": "robot base", "dataset": "serial-robots-ur5", "robot": "ur5"})
    validate(ds, where=where, angle_unit="deg")
    return ds


# --------------------------------------------------------------------------- UR10 (ipa-robot-accuracy)

#: ROS ``base_link`` of the UR10 = DH base turned 180° about z: ``T_base_link = Rz(π) · T_DH``.
IPA_BASE_LINK_FROM_DH = se3.rotz(math.pi)
#: T-Mac point/frame in the DH flange frame (planning value): 109 mm along the tool axis, Rz(90°).
IPA_TCP_FROM_FLANGE = se3.trans(0.0, 0.0, 0.109) @ se3.rotz(math.pi / 2)

_IPA_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
_IPA_GOAL = ["Goal x", "Goal y", "Goal z", "Goal roll", "Goal pitch", "Goal yaw"]
_IPA_MEAS = ["measurement_x", "measurement_y", "measurement_z", "measurement_rx", "measurement_ry", "measurement_rz"]


def ipa_nominal_robot():
    """UR10 nominal model of the ipa-robot-accuracy data: ``ur10`` preset with
    ``tool = Trans(0, 0, 0.109 m) · Rz(90°)`` (:data:`IPA_TCP_FROM_FLANGE`), identity base (DH base).

    The data's ``Goal`` poses are in ROS ``base_link`` = ``Rz(π) ·`` DH base
    (:data:`IPA_BASE_LINK_FROM_DH`): ``Goal = Rz(π) · fk(ipa_nominal_robot(), q)`` (median 0.09 mm).
    Measurements are in the laser-tracker frame; bring them to the base with :func:`register_rigid`.
    """
    from ..io.robot_file import load_robot

    r = load_robot("ur10")
    return r.copy(tool=IPA_TCP_FROM_FLANGE.copy(), name="ur10-ipa")


def _ipa_file(series: str | Path) -> Path:
    p = Path(series)
    if p.is_file():
        return p
    if not p.is_dir():
        raise DatasetError(f"{p}: no such series folder or file", file=str(p))
    cands = sorted(p.glob("measurements_*.csv"))
    if len(cands) != 1:
        raise DatasetError(f"{p}: expected exactly one measurements_*.csv, found {[c.name for c in cands]}", file=str(p))
    return cands[0]


def _ipa_timestamps(raw: list[str]) -> np.ndarray:
    """``YYYYMMDDhhmmss`` strings -> POSIX seconds (clock time taken as UTC; the time zone is not
    recorded); anything else (e.g. spreadsheet-mangled ``2,02011E+13``) -> NaN."""
    out = np.full(len(raw), np.nan)
    for k, s in enumerate(raw):
        if len(s) == 14 and s.isdigit():
            try:
                iso = f"{s[:4]}-{s[4:6]}-{s[6:8]}T{s[8:10]}:{s[10:12]}:{s[12:14]}"
                out[k] = float(np.datetime64(iso, "s").astype(np.int64))
            except ValueError:  # an impossible date stays NaN
                pass
    return out


def import_ipa_series(
    series: str | Path,
    *,
    register_to=None,
    register_idx: np.ndarray | None = None,
    rot_weight_m_per_rad: float = 0.1,
) -> Dataset:
    """Read an ipa-robot-accuracy series (``Series_A`` / ``Series_B`` folder or its CSV) into a Dataset.

    Format: ``;``-separated, decimal comma. ``q`` = the six ``*_joint`` columns (rad). The measured
    T-Mac pose (``measurement_x,y,z`` mm; ``measurement_rx,ry,rz`` deg, **intrinsic** X-Y-Z) becomes
    ``xyz_m``/``quat_wxyz``.

    **Frame.** Without ``register_to`` the poses are in the **laser-tracker frame** (``meta['frame']
    = 'tracker'``), not the robot base: the tracker was moved between series, so each series needs
    its own rigid registration ``T_meas ≈ T_base · FK(q) · T_tool`` (:func:`register_rigid`). With
    ``register_to=robot`` (e.g. :func:`ipa_nominal_robot`) that registration is fitted on the rows
    ``register_idx`` (default: all) and the poses are returned as ``T_base⁻¹ · T_meas · T_tool⁻¹``:
    the measured pose of the robot's own TCP frame in its base frame, so ``fk(robot, q)`` differs
    from them only by what a rigid fit cannot explain. ``meta`` then holds ``T_base``, ``T_tool``
    and the mean residuals (``registration_pos_mean_mm``, ``registration_ang_mean_deg``).

    Extras: ``goal_x_m, goal_y_m, goal_z_m, goal_roll_rad, goal_pitch_rad, goal_yaw_rad`` (commanded
    T-Mac pose in ROS ``base_link``, RPY extrinsic x-y-z), ``goal_id`` (index of the distinct goal
    pose: rows sharing it are the same target reached by other IK branches or repeated),
    ``temperature_c``, ``timestamp_s`` (POSIX seconds from ``YYYYMMDDhhmmss``, clock taken as UTC;
    **NaN for series B**, whose timestamps were mangled by a spreadsheet to ``2,02011E+13``; the raw
    text is kept in ``timestamp_raw``), and for series B the per-point standard deviations
    ``std_x_mm, std_y_mm, std_z_mm, std_rx_deg, std_ry_deg, std_rz_deg``. Any column outside
    this layout (a further ``*_joint``, ...) is refused, not dropped: use ``hykin import table``.
    """
    path = _ipa_file(series)
    where = str(path)
    t = read_delimited(path, delimiter=";", decimal=",", layout_hint="is that the file's delimiter?")
    header = t.header
    need = _IPA_GOAL + _IPA_JOINTS + _IPA_MEAS + ["measurement_temperature"]
    missing = [c for c in need if c not in header]
    if missing:
        raise DatasetError(f"{where}: not an ipa-robot-accuracy series file: missing column(s) {', '.join(missing)}",
                           file=where, column=missing[0])
    known = set(need) | {"Timestamp"} | {f"measurement_std_{c}" for c in ("x", "y", "z", "rx", "ry", "rz")}
    _refuse_unknown_columns(where, header, known, "ipa-robot-accuracy", 6)
    num = {c: float_column(t, c, decimal=",", finite=False) for c in need}
    if num[need[0]].size == 0:
        raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
    q = np.stack([num[c] for c in _IPA_JOINTS], axis=1)
    p_m = np.stack([num[c] for c in _IPA_MEAS[:3]], axis=1) * 1e-3
    ang = np.stack([num[c] for c in _IPA_MEAS[3:]], axis=1)
    for j, c in enumerate(_IPA_MEAS[3:]):
        bad = ~np.isfinite(ang[:, j])
        if bad.any():
            raise DatasetError(f"{where}, row {int(np.argmax(bad)) + 1}, column '{c}': value is not finite",
                               file=where, row=int(np.argmax(bad)) + 1, column=c)
    R = Rotation.from_euler("XYZ", ang, degrees=True)
    quat = R.as_quat(canonical=True, scalar_first=True)
    goal = np.stack([num[c] for c in _IPA_GOAL], axis=1)
    _, goal_id = np.unique(goal, axis=0, return_inverse=True)
    extra = {
        "goal_x_m": goal[:, 0], "goal_y_m": goal[:, 1], "goal_z_m": goal[:, 2],
        "goal_roll_rad": goal[:, 3], "goal_pitch_rad": goal[:, 4], "goal_yaw_rad": goal[:, 5],
        "goal_id": goal_id.reshape(-1).astype(np.int64),
        "temperature_c": num["measurement_temperature"],
    }
    if "Timestamp" in header:
        raw = t.col("Timestamp")
        extra["timestamp_s"] = _ipa_timestamps(raw)
        extra["timestamp_raw"] = np.asarray(raw, dtype=str)
    for c, unit in (("x", "mm"), ("y", "mm"), ("z", "mm"), ("rx", "deg"), ("ry", "deg"), ("rz", "deg")):
        col = f"measurement_std_{c}"
        if col in header:
            extra[f"std_{c}_{unit}"] = float_column(t, col, decimal=",", finite=False)
    ds = Dataset(q=q, xyz_m=p_m, quat_wxyz=quat, extra=extra, source=where,
                 meta={"frame": "tracker", "dataset": "ipa-robot-accuracy", "robot": "ur10",
                       "series": path.parent.name})
    validate(ds, where=where)
    if register_to is None:
        return ds
    from ..kinematics.fk import fk

    T_model = fk(register_to, ds.q)
    T_meas = ds.poses()
    idx = np.arange(len(ds)) if register_idx is None else np.asarray(register_idx)
    T_base, T_tool = register_rigid(T_model[idx], T_meas[idx], rot_weight_m_per_rad=rot_weight_m_per_rad)
    pos, angd = registration_errors(T_model, T_meas, T_base, T_tool)
    T_new = se3.invert(T_base) @ T_meas @ se3.invert(T_tool)
    out = Dataset.from_poses(ds.q, T_new, extra=ds.extra, source=where)
    out.meta = dict(ds.meta, frame="robot base", T_base=T_base, T_tool=T_tool,
                    registered_to=getattr(register_to, "name", ""), registration_rows=len(idx),
                    registration_pos_mean_mm=float(pos.mean()), registration_ang_mean_deg=float(angd.mean()))
    return out


# --------------------------------------------------------------------------- three SMRs


def import_three_smr(
    path: str | Path,
    nest,
    *,
    length_unit: str = "m",
    angle_unit: str = "rad",
    robot=None,
    dof: int | None = None,
    max_fit_rms_m: float = 1e-3,
) -> Dataset:
    """Read a three-SMR export: columns ``q1..qN`` and ``p1x,p1y,p1z,p2x,...,p3z`` (reflector
    positions in the robot base frame, ``length_unit``), comma-separated, one header line.

    ``nest``: ``(3, 3)`` known positions of SMR 1..3 in the tool (TCP) frame, **in metres**. Each
    row's full pose is the Kabsch fit of the nest onto the three measured points
    (:func:`hykin.measure.referencing.pose_from_three_points`). A row whose fit RMS exceeds
    ``max_fit_rms_m`` (wrong nest, swapped reflectors, a bad measurement) is an error naming the
    row; swapped reflectors are only detectable when the nest's three sides differ in length. Extras: ``smr_fit_rms_m`` plus every other column as read.

    Other layouts (column names, delimiters, units): :func:`hykin.measure.table_import.import_table` with a
    :class:`~hykin.measure.table_map.TableMap` holding ``position``, two ``points`` and ``nest``
    (``hykin import three-smr``).
    """
    from .table_import import import_table
    from .table_map import TableMap

    where = str(path)
    check_units(where, length_unit, angle_unit)
    nest = np.asarray(nest, dtype=np.float64)
    if nest.shape != (3, 3) or not np.isfinite(nest).all():
        raise DatasetError(f"{where}: nest must be a finite (3, 3) array (rows = SMRs, m), got shape {nest.shape}", file=where)
    m = TableMap(joints="q*", position=["p1x", "p1y", "p1z"], points=[[f"p{k}{a}" for a in "xyz"] for k in (2, 3)],
                 nest=nest.tolist(), max_fit_rms_mm=max_fit_rms_m * 1e3, length_unit=length_unit, angle_unit=angle_unit,
                 delimiter=",", keep=["*"], dof=dof)
    return import_table(path, m, robot)
