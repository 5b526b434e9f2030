"""Measured-pose datasets: the :class:`Dataset` container, validation, splits and hashing.

Files (CSV/Parquet reading and writing) are in :mod:`hykin.io.dataset_files`.

File format (DESIGN.md §3): one row per measured pose, header required, columns
``q1..qN`` (joints), ``x,y,z`` (measured TCP position in the robot base frame) and optionally
``qw,qx,qy,qz`` (measured orientation, unit quaternion, scalar first). Every other column is kept in
:attr:`Dataset.extra` (timestamp, temperature, std...) and ignored by the kinematics.

Units are **declared**, never guessed: ``length_unit`` in ``("m", "mm")`` scales ``x,y,z`` (and the
joints of prismatic joints); ``angle_unit`` in ``("rad", "deg")`` scales revolute joints. Extra
columns are kept as read (no unit conversion). In memory a :class:`Dataset` is always SI (m, rad).

Errors are :class:`DatasetError` (a ``ValueError``); their message names the file, the row and the
column. Rows are counted as **data rows, 1-based** (the first row under the header is row 1, i.e.
line 2 of a CSV file); messages give both the row and the file line.
"""

from __future__ import annotations

import hashlib
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..geometry import se3

__all__ = [
    "POSITION_COLUMNS",
    "QUAT_COLUMNS",
    "Dataset",
    "DatasetError",
    "JointLimitWarning",
    "check_finite",
    "check_limits",
    "check_units",
    "concat",
    "dataset_hash",
    "joint_columns",
    "label_cells",
    "revolute_mask",
    "row_error",
    "row_labels",
    "split",
    "validate",
    "validate_joints",
    "validate_poses",
]

POSITION_COLUMNS = ("x", "y", "z")
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
#: optional label columns: rows of one instrument placement / one tool (or reflector mount) share a frame
STATION_COLUMN, TOOL_COLUMN = "station", "tool"
#: columns that hold labels, not numbers: read and carried as text exactly as written ("01" and "1" are two
#: stations, tool "007" stays "007"); ``pose_id`` / ``pose`` name ISO 9283 poses
LABEL_COLUMNS = (STATION_COLUMN, TOOL_COLUMN, "pose_id", "pose")
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}

QUAT_NORM_TOL = 1e-3  # |‖q‖ - 1| above this is an error; below, the quaternion is renormalised
# RMS spread (m) of the measured positions about their centroid above which, with no robot to compare
# with, millimetres were read as metres (any serial arm of up to ~50 m reach; a 0.5 m arm read in mm
# spreads ~200 "m"). Frame independent: a tracker or total station may stand kilometres away. With a
# robot the limit is ``SPREAD_PER_REACH`` x its reach; the exact check against the robot's own motion
# is :func:`hykin.io.plausibility.check_position_scale`.
MAX_SPREAD_M = 50.0
SPREAD_PER_REACH = 10.0
MAX_POSITION_M = MAX_SPREAD_M  # former name (an absolute distance limit, now a spread limit)
# Joint values this far beyond a robot file's limits are accepted with a warning (counts per joint): a
# controller's soft limits differ from a data sheet's, and a measured row 0.001° past 60° is a good row. Beyond
# it the value is refused: degrees read as radians or a wrong robot file land far outside, not within 0.5°.
LIMIT_SLACK_RAD = math.radians(0.5)
LIMIT_SLACK_M = 0.5e-3  # prismatic joints: the same idea (an axis' stroke is known to well under a millimetre)
DEG_AS_RAD_MARGIN = 0.4 * math.pi  # rad beyond 2π (2π·1.2 in all, docs/import-table.md) before revolute joints
# are called "degrees" when no robot is given; with one, its own limits count too (±400° axes)


class DatasetError(ValueError):
    """Bad dataset input. The message names the file, the row (1-based data row) and the column.

    Attributes ``file``, ``row`` (1-based data row or None) and ``column`` (or None) repeat them.
    """

    def __init__(self, message: str, *, file: str | None = None, row: int | None = None, column: str | None = None):
        super().__init__(message)
        self.file, self.row, self.column = file, row, column


def row_error(where: str, msg: str, row: int | None = None, column: str | None = None,
              line_offset: int | None = 1) -> DatasetError:
    """A DatasetError '<where>, row R (line L of the file), column 'c': msg'. ``row`` is 0-based here;
    ``line_offset`` = file line minus data row (None: no line is named)."""
    parts = [where]
    if row is not None:
        r = int(row) + 1
        parts.append(f"row {r}" + (f" (line {r + line_offset} of the file)" if line_offset is not None else ""))
    if column is not None:
        parts.append(f"column '{column}'")
    return DatasetError(": ".join([", ".join(parts), msg]), file=where, row=None if row is None else int(row) + 1, column=column)


def joint_columns(dof: int) -> list[str]:
    """``['q1', ..., 'q<dof>']``."""
    return [f"q{i + 1}" for i in range(dof)]


# --------------------------------------------------------------------------- container


@dataclass
class Dataset:
    """Measured poses of a serial robot, SI units, float64.

    Attributes
    ----------
    q: ``(N, dof)`` joints, rad (m for prismatic joints).
    xyz_m: ``(N, 3)`` measured TCP position in the robot base frame (or the frame stated by
        ``source``/``meta``, e.g. a laser-tracker frame before registration), m.
    quat_wxyz: ``(N, 4)`` unit quaternions (scalar first) or ``None`` for position-only data.
    extra: other per-row columns, each ``(N,)`` (timestamp, temperature, std...), kept as read.
    source: file path or free-text description.
    meta: dataset-level facts that are not per-row (frame, registration transforms, units of
        extras...). Not written to CSV files.
    """

    q: np.ndarray
    xyz_m: np.ndarray
    quat_wxyz: np.ndarray | None = None
    extra: dict[str, np.ndarray] = field(default_factory=dict)
    source: str = ""
    meta: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.q = np.array(self.q, dtype=np.float64, copy=True)
        if self.q.ndim == 1:
            self.q = self.q.reshape(-1, 1) if self.q.size else self.q.reshape(0, 0)
        self.xyz_m = np.array(self.xyz_m, dtype=np.float64, copy=True).reshape(-1, 3)
        where = self.source or "<dataset>"
        n = self.q.shape[0]
        if self.q.ndim != 2:
            raise DatasetError(f"{where}: q must be (N, dof), got shape {self.q.shape}", file=where)
        if self.xyz_m.shape[0] != n:
            raise DatasetError(f"{where}: xyz_m has {self.xyz_m.shape[0]} rows, q has {n}", file=where)
        if self.quat_wxyz is not None:
            self.quat_wxyz = np.array(self.quat_wxyz, dtype=np.float64, copy=True).reshape(-1, 4)
            if self.quat_wxyz.shape[0] != n:
                raise DatasetError(f"{where}: quat_wxyz has {self.quat_wxyz.shape[0]} rows, q has {n}", file=where)
        extra = {}
        for k, v in dict(self.extra).items():
            v = np.asarray(v)
            if v.shape[:1] != (n,):
                raise DatasetError(f"{where}: extra column '{k}' has shape {v.shape}, expected ({n},)", file=where, column=k)
            extra[str(k)] = v.copy()
        self.extra = extra
        self.meta = dict(self.meta)

    def __len__(self) -> int:
        return int(self.q.shape[0])

    @property
    def dof(self) -> int:
        """Number of joint columns."""
        return int(self.q.shape[1])

    @property
    def has_orientation(self) -> bool:
        """True when measured orientations are present."""
        return self.quat_wxyz is not None

    def poses(self) -> np.ndarray:
        """``(N, 4, 4)`` measured poses (identity rotation for position-only data)."""
        if self.quat_wxyz is None:
            T = np.tile(np.eye(4), (len(self), 1, 1))
            T[:, :3, 3] = self.xyz_m
            return T
        return se3.pose_to_transform(self.xyz_m, self.quat_wxyz)

    def rotations(self) -> np.ndarray:
        """``(N, 3, 3)`` measured rotations. Raises if the data are position-only."""
        if self.quat_wxyz is None:
            raise DatasetError(f"{self.source or '<dataset>'}: position-only dataset has no orientations")
        return se3.quat_to_matrix(self.quat_wxyz)

    def subset(self, idx) -> Dataset:
        """Rows ``idx`` (integer indices, boolean mask or slice) as a new Dataset (copies)."""
        if isinstance(idx, slice):
            idx = np.arange(len(self))[idx]
        idx = np.asarray(idx)
        if idx.dtype == bool:
            if idx.shape != (len(self),):
                raise DatasetError(f"{self.source or '<dataset>'}: boolean mask of shape {idx.shape} for {len(self)} rows")
            idx = np.flatnonzero(idx)
        idx = idx.astype(np.int64).reshape(-1)
        return Dataset(
            q=self.q[idx],
            xyz_m=self.xyz_m[idx],
            quat_wxyz=None if self.quat_wxyz is None else self.quat_wxyz[idx],
            extra={k: v[idx] for k, v in self.extra.items()},
            source=self.source,
            meta=self.meta,
        )

    @classmethod
    def concat(cls, datasets: Sequence[Dataset], source: str | None = None) -> Dataset:
        """Rows of several datasets one after the other (same dof; all or none with orientation).

        Extra columns present in only some datasets are dropped; ``meta`` is taken from the first.
        """
        return concat(datasets, source=source)

    @classmethod
    def from_poses(cls, q, T, extra: dict | None = None, source: str = "", orientation: bool = True) -> Dataset:
        """Dataset from joints ``(N, dof)`` and poses ``(N, 4, 4)`` (m); ``orientation=False`` keeps
        positions only."""
        T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
        xyz, quat = se3.transform_to_pose(T)
        return cls(q=q, xyz_m=xyz, quat_wxyz=quat if orientation else None, extra=extra or {}, source=source)


def concat(datasets: Sequence[Dataset], source: str | None = None) -> Dataset:
    """See :meth:`Dataset.concat`."""
    datasets = list(datasets)
    if not datasets:
        raise DatasetError("concat: no datasets given")
    dofs = {d.dof for d in datasets}
    if len(dofs) != 1:
        raise DatasetError(f"concat: datasets have different numbers of joints {sorted(dofs)}")
    ori = {d.has_orientation for d in datasets}
    if len(ori) != 1:
        raise DatasetError("concat: some datasets have orientation columns and some do not")
    keys = [k for k in datasets[0].extra if all(k in d.extra for d in datasets)]
    return Dataset(
        q=np.concatenate([d.q for d in datasets]),
        xyz_m=np.concatenate([d.xyz_m for d in datasets]),
        quat_wxyz=np.concatenate([d.quat_wxyz for d in datasets]) if datasets[0].has_orientation else None,
        extra={k: np.concatenate([d.extra[k] for d in datasets]) for k in keys},
        source=source if source is not None else " + ".join(d.source for d in datasets if d.source),
        meta=datasets[0].meta,
    )


#: a number written without leading zeros ("2", "2.0", "-1.5", "1e3"; not "01", "007", "0.50" is one): such a
#: label reads as before text labels were kept (``2.0`` -> ``"2"``, ``2.50`` -> ``"2.5"``)
_PLAIN_NUMBER = re.compile(r"[+-]?(?:0|[1-9]\d*)(?:\.\d*)?(?:[eE][+-]?\d+)?")


def _canonical_label(cell: str) -> str:
    """A label cell as written; plain numbers (no leading zeros) as :func:`row_labels` wrote numbers."""
    if not _PLAIN_NUMBER.fullmatch(cell):
        return cell
    x = float(cell)
    if not math.isfinite(x):
        return cell
    return str(int(x)) if x == round(x) else repr(x)


def label_cells(cells) -> np.ndarray:
    """``(N,)`` str: a label column's cells as written (stripped of surrounding blanks), never parsed as
    numbers -- "01" and "1" stay two labels (see :data:`LABEL_COLUMNS`)."""
    return np.char.strip(np.asarray(list(cells), dtype=str))


def row_labels(ds: Dataset, column: str, *, line_offset: int | None = 1) -> np.ndarray | None:
    """``(N,)`` str labels of the label column ``column`` (``"station"``, ``"tool"``) of ``ds``, or None
    without it. Any label is accepted: text as read (stripped; "01" and "1" are two labels), numbers
    and plain-number text as written (``2.0`` / ``"2.0"`` -> ``"2"``). An empty, "nan" or non-finite cell is a :class:`DatasetError` naming the row and the column."""
    if column not in ds.extra:
        return None
    v = np.asarray(ds.extra[column])
    where = ds.source or "<dataset>"
    if v.dtype.kind in "fiub":
        f = v.astype(np.float64)
        bad = ~np.isfinite(f)
        if bad.any():
            raise row_error(where, f"label {f[bad][0]!r} is not a {column} name (every row needs one)",
                            int(np.argmax(bad)), column, line_offset)
        whole = np.all(f == np.round(f))
        return np.array([str(int(x)) if whole else repr(float(x)) for x in f], dtype=str)
    out = np.array([_canonical_label(c) for c in np.char.strip(v.astype(str))], dtype=str)
    empty = (out == "") | (np.char.lower(out) == "nan")
    if empty.any():
        raise row_error(where, f"empty {column} label (every row needs one when the column is given)",
                        int(np.argmax(empty)), column, line_offset)
    return out


# --------------------------------------------------------------------------- validation


def revolute_mask(dof: int, robot) -> np.ndarray:
    """``(dof,)`` bool: which joints are revolute (all of them without a ``robot``)."""
    if robot is None:
        return np.ones(dof, dtype=bool)
    return robot.revolute


def check_finite(where: str, arr: np.ndarray, names: Sequence[str], line_offset: int | None) -> None:
    """Raise :class:`DatasetError` naming the first non-finite cell of ``arr`` ``(N, len(names))``."""
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise row_error(where, f"value {float(arr[r, c])} is not finite (NaN or inf); every cell must be a finite number",
                   r, names[c], line_offset)


def validate(
    ds: Dataset,
    robot=None,
    *,
    where: str | None = None,
    limit_tol: float = 1e-6,
    angle_unit: str = "rad",
    line_offset: int | None = 1,
    joint_names: Sequence[str] | None = None,
    unit_check: bool = True,
) -> None:
    """Check a dataset (SI units) and raise :class:`DatasetError` naming file, row and column.

    Checks: not empty; dof matches ``robot``; every value finite; joints within ``robot`` limits ±
    ``limit_tol``; quaternions unit (``|‖q‖ − 1| > 1e-3`` is an error, smaller deviations are
    **renormalised in place**). Unit checks (``unit_check``, the CLI's ``--no-unit-check`` turns them
    off): revolute joints look like radians (no ``|q| > 2π + 0.1``; not all whole numbers with some
    ``|q| > π``); positions look like metres: their RMS spread about the centroid is at most
    :data:`SPREAD_PER_REACH` x the robot's reach (:data:`MAX_SPREAD_M` without a robot). The spread,
    not the distance from the origin: data in a tracker frame far away are fine.

    ``where`` names the file in messages (default ``ds.source``); ``angle_unit`` is the unit the user
    declared, only used to phrase the hint; ``line_offset`` = file line minus data row (1 for a CSV
    with one header line, ``None`` for sources without lines); ``joint_names``: the file's joint
    columns when not ``q1..qN`` (URDF joint names), used in messages.
    """
    where = where or ds.source or "<dataset>"
    validate_joints(ds.q, robot, where=where, limit_tol=limit_tol, angle_unit=angle_unit, line_offset=line_offset,
                    joint_names=joint_names, unit_check=unit_check)
    validate_poses(ds.xyz_m, ds.quat_wxyz, where=where, line_offset=line_offset,
                   max_spread_m=spread_limit_m(robot) if unit_check else None)


def spread_limit_m(robot=None) -> float:
    """RMS position spread (m) above which data declared in metres look like millimetres:
    :data:`SPREAD_PER_REACH` x the reach of ``robot`` (:data:`MAX_SPREAD_M` without one)."""
    if robot is None:
        return MAX_SPREAD_M
    from ..kinematics.robot import robot_reach_m

    return SPREAD_PER_REACH * max(float(robot_reach_m(robot)), 1e-3)


def validate_joints(
    q: np.ndarray,
    robot=None,
    *,
    where: str = "<joints>",
    limit_tol: float = 1e-6,
    angle_unit: str = "rad",
    line_offset: int | None = 1,
    joint_names: Sequence[str] | None = None,
    unit_check: bool = True,
) -> None:
    """Joint part of :func:`validate` for ``q`` ``(N, dof)`` in rad/m (``joint_names``: the columns' names
    in messages, default ``q1..qN``; ``unit_check``: the degrees-as-radians checks)."""
    n, dof = q.shape
    if n == 0:
        raise DatasetError(f"{where}: the dataset is empty (no data rows)", file=where)
    if robot is not None and dof != robot.dof:
        raise DatasetError(
            f"{where}: {dof} joint column(s) (q1..q{dof}) but robot {robot.name!r} has {robot.dof} joints "
            f"(expected columns {', '.join(joint_columns(robot.dof))})",
            file=where,
        )
    qn = list(joint_names) if joint_names is not None and len(joint_names) == dof else joint_columns(dof)
    check_finite(where, q, qn, line_offset)
    rev = revolute_mask(dof, robot)
    cont = robot.continuous if robot is not None else np.zeros(dof, dtype=bool)  # any value is valid
    if (rev & ~cont).any() and unit_check:
        qr = q[:, rev & ~cont]
        names = [c for c, m in zip(qn, rev & ~cont) if m]
        hint = ("declare angle_unit='deg' (CLI: --angle-unit deg)" if angle_unit == "rad"
                else "check the file: the values were declared in degrees")
        reach = 2 * math.pi + DEG_AS_RAD_MARGIN  # a value within the robot's own limits is radians (±400° axes)
        if robot is not None:
            reach = np.maximum(reach, np.maximum(np.abs(robot.lower), np.abs(robot.upper))[rev & ~cont] + limit_tol)
        big = np.abs(qr) > reach
        if big.any():
            r, c = np.argwhere(big)[0]
            raise row_error(where, f"joint value {qr[r, c]:.6g} rad is beyond ±2π"
                       f"{'' if robot is None else ' and the robot limits'}: likely degrees passed as radians; {hint}",
                       r, names[c], line_offset)
        integral = np.all(np.abs(qr - np.round(qr)) < 1e-9)
        if integral and np.max(np.abs(qr)) > math.pi and qr.size > 1:
            r, c = np.unravel_index(int(np.argmax(np.abs(qr))), qr.shape)
            raise row_error(where, f"all revolute joint values are whole numbers, up to {qr[r, c]:.6g}: likely degrees "
                       f"passed as radians; {hint}", r, names[c], line_offset)
    if robot is not None:
        check_limits(q, robot, where, limit_tol, qn, rev, cont, line_offset)


class JointLimitWarning(UserWarning):
    """Joint values slightly beyond the robot file's limits (within :data:`LIMIT_SLACK_RAD` /
    :data:`LIMIT_SLACK_M`): accepted, counted per joint."""


def check_limits(q, robot, where: str, limit_tol: float, names, rev, cont, line_offset) -> None:
    """Joint values ``q`` ``(N, dof)`` against ``robot``'s limits: within ``limit_tol`` silent, up to the slack
    (:data:`LIMIT_SLACK_RAD`, :data:`LIMIT_SLACK_M`) one :class:`JointLimitWarning` with counts, beyond it a
    :class:`DatasetError` naming the first such row, column, value and limit (``names``: column names,
    ``rev`` / ``cont``: revolute / continuous joints, ``line_offset`` as in :func:`row_error`)."""
    import warnings

    with np.errstate(invalid="ignore"):  # a continuous joint's limits may be infinite: never beyond them
        excess = np.where(cont, 0.0, np.maximum(robot.lower - q, q - robot.upper))  # (N, dof) > 0 beyond, rad or m
    slack = np.where(rev, LIMIT_SLACK_RAD, LIMIT_SLACK_M) + limit_tol
    far = excess > slack
    if far.any():
        r, c = np.argwhere(far)[0]
        conv = np.degrees if rev[c] else (lambda v: v)
        u = "deg" if rev[c] else "m"
        raise row_error(where, f"joint value {conv(q[r, c]):.6g} {u} is outside the limits "
                        f"[{conv(robot.lower[c]):.6g}, {conv(robot.upper[c]):.6g}] {u} of robot {robot.name!r} "
                        f"by more than the {conv(slack[c] - limit_tol):.3g} {u} accepted (a unit slip or another "
                        "robot's data? If the values are right, widen min/max of that joint in the robot file)",
                        r, names[c], line_offset)
    near = excess > limit_tol
    if near.any():
        per = ", ".join(f"{names[c]}: {int(k)}" for c, k in enumerate(near.sum(0)) if k)
        worst = ", ".join(f"{names[c]} {np.degrees(e) if rev[c] else e * 1e3:.3g} {'deg' if rev[c] else 'mm'}"
                          for c, e in enumerate(excess.max(0)) if near[:, c].any())
        warnings.warn(JointLimitWarning(
            f"{where}: {int(near.any(1).sum())} of {len(q)} rows have joints slightly beyond the limits of robot "
            f"{robot.name!r} ({per}; at most {worst} past); accepted (within {np.degrees(LIMIT_SLACK_RAD):g} deg / "
            f"{LIMIT_SLACK_M * 1e3:g} mm). Widen min/max in the robot file if the robot really goes there"), stacklevel=4)


def validate_poses(
    xyz_m: np.ndarray,
    quat_wxyz: np.ndarray | None = None,
    *,
    where: str = "<poses>",
    line_offset: int | None = 1,
    max_spread_m: float | None = MAX_SPREAD_M,
) -> None:
    """Pose part of :func:`validate`: finite, unit quaternions (renormalised in place), metres: the RMS
    spread of ``xyz_m`` about its centroid at most ``max_spread_m`` (None: no unit check)."""
    if xyz_m.shape[0] == 0:
        raise DatasetError(f"{where}: the dataset is empty (no data rows)", file=where)
    check_finite(where, xyz_m, POSITION_COLUMNS, line_offset)
    if quat_wxyz is not None:
        check_finite(where, quat_wxyz, QUAT_COLUMNS, line_offset)
        norm = np.linalg.norm(quat_wxyz, axis=1)
        bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
        if bad.any():
            r = int(np.argmax(bad))
            raise row_error(where, f"quaternion norm is {norm[r]:.6g}, not 1 (tolerance {QUAT_NORM_TOL:g}); "
                       "qw,qx,qy,qz must be a unit quaternion, scalar first", r, "qw,qx,qy,qz", line_offset)
        fix = np.abs(norm - 1.0) > 1e-12  # leave exact-to-rounding rows bit-identical (stable hashes)
        quat_wxyz[fix] /= norm[fix, None]
    if max_spread_m is None or len(xyz_m) < 2:
        return
    d = np.linalg.norm(xyz_m - xyz_m.mean(0), axis=1)
    spread = float(np.sqrt(np.mean(d**2)))
    if spread > max_spread_m:
        r = int(np.argmax(np.abs(xyz_m).max(1)))  # the largest value (as a pointer; the test is the spread)
        raise row_error(where, f"TCP positions spread {spread:.6g} m (RMS about their centroid; > {max_spread_m:.3g} m, "
                        f"far more than the arm moves): likely millimetres "
                        "passed as metres; declare length_unit='mm' (CLI: --length-unit mm; --no-unit-check if the "
                        "values are right)", r, "x,y,z", line_offset)



def check_units(where: str, length_unit: str, angle_unit: str) -> None:
    """Raise :class:`DatasetError` unless ``length_unit`` is in :data:`LENGTH_UNITS` and ``angle_unit`` in
    :data:`ANGLE_UNITS` (``where`` names the file)."""
    if length_unit not in LENGTH_UNITS:
        raise DatasetError(f"{where}: length_unit must be one of {tuple(LENGTH_UNITS)}, got {length_unit!r}", file=where)
    if angle_unit not in ANGLE_UNITS:
        raise DatasetError(f"{where}: angle_unit must be one of {tuple(ANGLE_UNITS)}, got {angle_unit!r}", file=where)



# --------------------------------------------------------------------------- splits and hashing


def _check_fractions(fractions: Sequence[float]) -> np.ndarray:
    f = np.asarray(fractions, dtype=np.float64)
    if f.ndim != 1 or f.size == 0 or np.any(f < 0) or abs(f.sum() - 1.0) > 1e-6:
        raise DatasetError(f"split: fractions must be non-negative and sum to 1, got {tuple(fractions)}")
    return f


def split(ds: Dataset, fractions: Sequence[float] = (0.8, 0.1, 0.1), seed: int = 0, *, group: str | None = None) -> tuple[Dataset, ...]:
    """Random disjoint splits covering every row exactly once, in ``fractions`` proportions.

    Sizes are ``round(cumsum(fractions) * N)`` differences. With ``group`` (the name of an extra
    column, e.g. a goal-pose id) whole groups go to one split, so repeated measurements of the same
    configuration never straddle train/test; sizes are then as close as whole groups allow.
    """
    f = _check_fractions(fractions)
    rng = np.random.default_rng(seed)
    n = len(ds)
    if group is None:
        perm = rng.permutation(n)
        cuts = np.round(np.cumsum(f) * n).astype(int)
        cuts[-1] = n
        parts = np.split(perm, cuts[:-1])
    else:
        if group not in ds.extra:
            raise DatasetError(f"{ds.source or '<dataset>'}: split by group: no extra column '{group}' "
                               f"(have: {', '.join(ds.extra) or 'none'})", column=group)
        _, inv, counts = np.unique(ds.extra[group], return_inverse=True, return_counts=True)
        order = rng.permutation(counts.size)
        cum = np.cumsum(counts[order])  # rows covered after each group in shuffled order
        targets = np.cumsum(f) * n
        # group k goes to the first split whose cumulative target its midpoint does not exceed
        mid = cum - counts[order] / 2.0
        which = np.minimum(np.searchsorted(targets, mid, side="left"), f.size - 1)
        split_of_group = np.empty(counts.size, dtype=int)
        split_of_group[order] = which
        row_split = split_of_group[inv]
        parts = [rng.permutation(np.flatnonzero(row_split == k)) for k in range(f.size)]
    return tuple(ds.subset(np.sort(p)) for p in parts)


def dataset_hash(ds: Dataset) -> str:
    """SHA-256 (hex) of the kinematic arrays (q, xyz_m, quat_wxyz) as little-endian float64.

    Extras and ``source`` are not hashed: two files with the same poses give the same hash.
    """
    h = hashlib.sha256()
    h.update(f"hykin-dataset-v1 n={len(ds)} dof={ds.dof} ori={int(ds.has_orientation)}".encode())
    for a in (ds.q, ds.xyz_m) + ((ds.quat_wxyz,) if ds.quat_wxyz is not None else ()):
        h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
    return h.hexdigest()
