"""Measured-pose datasets: the :class:`Dataset` container, CSV/Parquet files, validation, splits.

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

import csv
import hashlib
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..kinematics import se3

__all__ = [
    "POSITION_COLUMNS",
    "QUAT_COLUMNS",
    "Dataset",
    "DatasetError",
    "concat",
    "dataset_hash",
    "joint_columns",
    "read_csv_table",
    "read_dataset",
    "read_joints",
    "read_poses",
    "split",
    "validate",
    "validate_joints",
    "validate_poses",
    "write_dataset",
]

POSITION_COLUMNS = ("x", "y", "z")
QUAT_COLUMNS = ("qw", "qx", "qy", "qz")
LENGTH_UNITS = {"m": 1.0, "mm": 1e-3}
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0}

QUAT_NORM_TOL = 1e-3  # |‖q‖ - 1| above this is an error; below, the quaternion is renormalised
MAX_POSITION_M = 10.0  # a TCP farther than this from the base is almost surely mm read as m
DEG_AS_RAD_MARGIN = 0.1  # rad beyond 2π before revolute joints are called "degrees"


class DatasetError(ValueError):
    """Bad dataset input. The message names the file, the row (1-based data row) and the column.

    Attributes ``file``, ``row`` (1-based data row or None) and ``column`` (or None) repeat them.
    """

    def __init__(self, message: str, *, file: str | None = None, row: int | None = None, column: str | None = None):
        super().__init__(message)
        self.file, self.row, self.column = file, row, column


def _err(where: str, msg: str, row: int | None = None, column: str | None = None, line_offset: int | None = 1) -> DatasetError:
    """Build a DatasetError '<where>: row R (line L), column 'c': msg'. ``row`` is 0-based here."""
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


# --------------------------------------------------------------------------- validation


def _revolute_mask(dof: int, robot) -> np.ndarray:
    if robot is None:
        return np.ones(dof, dtype=bool)
    return np.array([t == "revolute" for t in robot.joint_type], dtype=bool)


def _check_finite(where: str, arr: np.ndarray, names: Sequence[str], line_offset: int | None) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise _err(where, f"value {arr[r, c]!r} is not finite (NaN or inf); every cell must be a finite number",
                   r, names[c], line_offset)


def validate(
    ds: Dataset,
    robot=None,
    *,
    where: str | None = None,
    limit_tol: float = 1e-6,
    angle_unit: str = "rad",
    line_offset: int | None = 1,
) -> None:
    """Check a dataset (SI units) and raise :class:`DatasetError` naming file, row and column.

    Checks: not empty; dof matches ``robot``; every value finite; revolute joints look like radians
    (no ``|q| > 2π + 0.1``; not all whole numbers with some ``|q| > π``); joints within ``robot``
    limits ± ``limit_tol``; quaternions unit (``|‖q‖ − 1| > 1e-3`` is an error, smaller deviations
    are **renormalised in place**); positions look like metres (no ``‖xyz‖ > 10 m``).

    ``where`` names the file in messages (default ``ds.source``); ``angle_unit`` is the unit the user
    declared, only used to phrase the hint; ``line_offset`` = file line minus data row (1 for a CSV
    with one header line, ``None`` for sources without lines).
    """
    where = where or ds.source or "<dataset>"
    validate_joints(ds.q, robot, where=where, limit_tol=limit_tol, angle_unit=angle_unit, line_offset=line_offset)
    validate_poses(ds.xyz_m, ds.quat_wxyz, where=where, line_offset=line_offset)


def validate_joints(
    q: np.ndarray,
    robot=None,
    *,
    where: str = "<joints>",
    limit_tol: float = 1e-6,
    angle_unit: str = "rad",
    line_offset: int | None = 1,
) -> None:
    """Joint part of :func:`validate` for ``q`` ``(N, dof)`` in rad/m."""
    n, dof = q.shape
    if n == 0:
        raise DatasetError(f"{where}: the dataset is empty (no data rows)", file=where)
    if robot is not None and dof != robot.dof:
        raise DatasetError(
            f"{where}: {dof} joint column(s) (q1..q{dof}) but robot {robot.name!r} has {robot.dof} joints "
            f"(expected columns {', '.join(joint_columns(robot.dof))})",
            file=where,
        )
    qn = joint_columns(dof)
    _check_finite(where, q, qn, line_offset)
    rev = _revolute_mask(dof, robot)
    if rev.any():
        qr = q[:, rev]
        names = [c for c, m in zip(qn, rev) if m]
        hint = ("declare angle_unit='deg' (CLI: --angle-unit deg)" if angle_unit == "rad"
                else "check the file: the values were declared in degrees")
        big = np.abs(qr) > 2 * math.pi + DEG_AS_RAD_MARGIN
        if big.any():
            r, c = np.argwhere(big)[0]
            raise _err(where, f"joint value {qr[r, c]:.6g} rad is beyond ±2π: likely degrees passed as radians; {hint}",
                       r, names[c], line_offset)
        integral = np.all(np.abs(qr - np.round(qr)) < 1e-9)
        if integral and np.max(np.abs(qr)) > math.pi and qr.size > 1:
            r, c = np.unravel_index(int(np.argmax(np.abs(qr))), qr.shape)
            raise _err(where, f"all revolute joint values are whole numbers, up to {qr[r, c]:.6g}: likely degrees "
                       f"passed as radians; {hint}", r, names[c], line_offset)
    if robot is not None:
        lo, hi = robot.lower - limit_tol, robot.upper + limit_tol
        out = (q < lo) | (q > hi)
        if out.any():
            r, c = np.argwhere(out)[0]
            conv = np.degrees if rev[c] else (lambda v: v)
            u = "deg" if rev[c] else "m"
            raise _err(where, f"joint value {conv(q[r, c]):.6g} {u} is outside the limits "
                       f"[{conv(robot.lower[c]):.6g}, {conv(robot.upper[c]):.6g}] {u} of robot {robot.name!r}",
                       r, qn[c], line_offset)


def validate_poses(
    xyz_m: np.ndarray,
    quat_wxyz: np.ndarray | None = None,
    *,
    where: str = "<poses>",
    line_offset: int | None = 1,
) -> None:
    """Pose part of :func:`validate`: finite, unit quaternions (renormalised in place), metres."""
    if xyz_m.shape[0] == 0:
        raise DatasetError(f"{where}: the dataset is empty (no data rows)", file=where)
    _check_finite(where, xyz_m, POSITION_COLUMNS, line_offset)
    if quat_wxyz is not None:
        _check_finite(where, quat_wxyz, QUAT_COLUMNS, line_offset)
        norm = np.linalg.norm(quat_wxyz, axis=1)
        bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
        if bad.any():
            r = int(np.argmax(bad))
            raise _err(where, f"quaternion norm is {norm[r]:.6g}, not 1 (tolerance {QUAT_NORM_TOL:g}); "
                       "qw,qx,qy,qz must be a unit quaternion, scalar first", r, "qw,qx,qy,qz", line_offset)
        fix = np.abs(norm - 1.0) > 1e-12  # leave exact-to-rounding rows bit-identical (stable hashes)
        quat_wxyz[fix] /= norm[fix, None]
    dist = np.linalg.norm(xyz_m, axis=1)
    far = dist > MAX_POSITION_M
    if far.any():
        r = int(np.argmax(far))
        raise _err(where, f"TCP position is {dist[r]:.6g} m from the base (> {MAX_POSITION_M:g} m): likely millimetres "
                   "passed as metres; declare length_unit='mm' (CLI: --length-unit mm)", r, "x,y,z", line_offset)


# --------------------------------------------------------------------------- reading


def _check_units(where: str, length_unit: str, angle_unit: str) -> None:
    if length_unit not in LENGTH_UNITS:
        raise DatasetError(f"{where}: length_unit must be one of {tuple(LENGTH_UNITS)}, got {length_unit!r}", file=where)
    if angle_unit not in ANGLE_UNITS:
        raise DatasetError(f"{where}: angle_unit must be one of {tuple(ANGLE_UNITS)}, got {angle_unit!r}", file=where)


def _to_float_column(where: str, name: str, cells: Sequence[str], decimal: str = ".", line_offset: int = 1) -> np.ndarray:
    """Strings -> float64, raising a DatasetError naming the first bad row. Empty cells are errors."""
    if decimal != ".":
        cells = [c.replace(decimal, ".") for c in cells]
    try:
        arr = np.asarray(cells, dtype=np.float64)
        return arr
    except ValueError:
        pass
    for r, c in enumerate(cells):
        try:
            float(c)
        except ValueError:
            shown = c if c.strip() else "(empty)"
            raise _err(where, f"cell {shown!r} is not a number", r, name, line_offset) from None
    raise _err(where, "could not be read as numbers", None, name)  # pragma: no cover


def _try_float_column(cells: Sequence[str], decimal: str = ".") -> np.ndarray:
    """Strings -> float64 when all parse, else the strings themselves (extras are kept as read)."""
    if decimal != ".":
        conv = [c.replace(decimal, ".") for c in cells]
    else:
        conv = cells
    try:
        return np.asarray(conv, dtype=np.float64)
    except ValueError:
        return np.asarray(cells, dtype=str)


def read_csv_table(path: str | Path, *, delimiter: str = ",", decimal: str = ".") -> tuple[list[str], dict[str, list[str]]]:
    """Read a delimited text file with one header line into ``(header, {column: cells})``.

    Raises :class:`DatasetError` for a missing/empty file, duplicate column names or a row with the
    wrong number of cells (naming the row and the line). Lines that are completely empty are
    allowed only at the end of the file.
    """
    where = str(path)
    p = Path(path)
    if not p.exists():
        raise DatasetError(f"{where}: file not found", file=where)
    with p.open("r", newline="", encoding="utf-8-sig") as fh:
        rows = list(csv.reader(fh, delimiter=delimiter))
    while rows and not any(c.strip() for c in rows[-1]):
        rows.pop()
    if not rows:
        raise DatasetError(f"{where}: the file is empty (a header line is required)", file=where)
    header = [h.strip() for h in rows[0]]
    seen = set()
    for h in header:
        if h in seen:
            raise _err(where, "appears twice in the header", None, h)
        seen.add(h)
    body = rows[1:]
    ncol = len(header)
    for r, row in enumerate(body):
        if len(row) != ncol:
            raise _err(where, f"has {len(row)} cells, the header has {ncol} "
                       f"(is the delimiter {delimiter!r} right?)", r, None)
    cols = {h: [row[i].strip() for row in body] for i, h in enumerate(header)}
    return header, cols


def _dof_from_header(where: str, header: Sequence[str], robot, dof: int | None) -> int:
    present = {h for h in header}
    k = 0
    while f"q{k + 1}" in present:
        k += 1
    want = robot.dof if robot is not None else dof
    if want is None:
        if k == 0:
            raise DatasetError(
                f"{where}: no joint columns; expected q1..qN, x, y, z and optionally qw, qx, qy, qz "
                f"(found: {', '.join(header)})", file=where)
        return k
    if robot is not None and dof is not None and dof != robot.dof:
        raise DatasetError(f"{where}: dof={dof} given but robot {robot.name!r} has {robot.dof} joints", file=where)
    missing = [c for c in joint_columns(want) if c not in present]
    if missing:
        raise DatasetError(
            f"{where}: missing column(s) {', '.join(missing)}; expected {', '.join(joint_columns(want))}, x, y, z "
            f"and optionally qw, qx, qy, qz (found: {', '.join(header)})", file=where, column=missing[0])
    if f"q{want + 1}" in present:
        raise DatasetError(
            f"{where}: the file has joint columns q1..q{k} but the robot{'' if robot is None else ' ' + repr(robot.name)} "
            f"has {want} joints", file=where, column=f"q{want + 1}")
    return want


@dataclass
class _Table:
    """A read table: header, a strict numeric accessor (errors name row/column) and a lenient one."""

    where: str
    header: list[str]
    numeric: object  # (name) -> float64 (N,), raising DatasetError on a bad cell
    lenient: object  # (name) -> float64 or str (N,)
    line_offset: int | None
    metadata: dict

    def extras(self, skip) -> dict[str, np.ndarray]:
        skip = set(skip)
        return {c: self.lenient(c) for c in self.header if c not in skip}


def _open_table(path: str | Path) -> _Table:
    """Open a ``.csv`` (comma) or ``.parquet`` table."""
    where = str(path)
    suffix = Path(path).suffix.lower()
    if suffix in (".parquet", ".pq"):
        return _open_parquet(path)
    if suffix not in (".csv", ".txt", ".tsv"):
        raise DatasetError(f"{where}: unknown dataset file type {suffix!r}; expected .csv or .parquet", file=where)
    header, cols = read_csv_table(path, delimiter="\t" if suffix == ".tsv" else ",")
    if len(header) == 1 and ";" in header[0]:
        raise DatasetError(f"{where}: the header is one column {header[0][:60]!r}...: the file looks ';'-separated; "
                           "datasets are comma-separated (use hykin.importers for other layouts)", file=where)
    return _Table(where, header, lambda c: _to_float_column(where, c, cols[c]), lambda c: _try_float_column(cols[c]), 1, {})


def _open_parquet(path) -> _Table:
    where = str(path)
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:  # pragma: no cover
        raise DatasetError(f"{where}: reading Parquet needs pyarrow (pip install pyarrow)", file=where) from None
    if not Path(path).exists():
        raise DatasetError(f"{where}: file not found", file=where)
    try:
        table = pq.read_table(path)
    except Exception as e:  # pyarrow raises several types for corrupt files
        raise DatasetError(f"{where}: not a readable Parquet file ({e})", file=where) from None
    md = {k.decode(): v.decode() for k, v in (table.schema.metadata or {}).items() if k.startswith(b"hykin.")}
    header = [str(n) for n in table.column_names]

    def numeric(c: str) -> np.ndarray:
        col = table.column(c)
        if col.null_count:
            r = int(np.flatnonzero(np.asarray(col.is_null().to_numpy(zero_copy_only=False)))[0])
            raise _err(where, "cell is empty (null)", r, c, None)
        if pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
            return np.asarray(col.to_numpy(), dtype=np.float64)
        cells = [str(v) for v in col.to_pylist()]
        arr = _try_float_column(cells)
        if arr.dtype.kind != "f":
            for r, v in enumerate(cells):
                try:
                    float(v)
                except ValueError:
                    raise _err(where, f"cell {v!r} is not a number (column type {col.type})", r, c, None) from None
        return arr

    def lenient(c: str) -> np.ndarray:
        arr = table.column(c).to_numpy(zero_copy_only=False)
        return arr.astype(np.float64) if arr.dtype.kind in "iuf" else arr.astype(str)

    return _Table(where, header, numeric, lenient, None, md)


def _check_declared_units(t: _Table, length_unit: str, angle_unit: str) -> None:
    for key, declared in (("hykin.length_unit", length_unit), ("hykin.angle_unit", angle_unit)):
        if key in t.metadata and t.metadata[key] != declared:
            raise DatasetError(
                f"{t.where}: the file says it was written with {key.split('.')[1]}={t.metadata[key]!r} "
                f"but {declared!r} was declared; declare the file's unit", file=t.where)


def _joints_of(t: _Table, robot, dof, angle_unit: str, length_unit: str) -> np.ndarray:
    n_dof = _dof_from_header(t.where, t.header, robot, dof)
    qn = joint_columns(n_dof)
    q = np.stack([t.numeric(c) for c in qn], axis=1)
    _check_finite(t.where, q, qn, t.line_offset)
    rev = _revolute_mask(n_dof, robot)
    return q * np.where(rev, ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit])


def _check_pose_header(t: _Table, expect: str) -> bool:
    """Raise for missing x/y/z or partial orientation columns; return True when orientation is present."""
    present = set(t.header)
    missing = [c for c in POSITION_COLUMNS if c not in present]
    if missing:
        raise DatasetError(
            f"{t.where}: missing column(s) {', '.join(missing)}; expected {expect} "
            f"(found: {', '.join(t.header)})", file=t.where, column=missing[0])
    qcols = [c for c in QUAT_COLUMNS if c in present]
    if qcols and len(qcols) != 4:
        miss = [c for c in QUAT_COLUMNS if c not in present]
        raise DatasetError(
            f"{t.where}: orientation columns incomplete: missing {', '.join(miss)}; give all of qw, qx, qy, qz "
            "or none (position-only data)", file=t.where, column=miss[0])
    return bool(qcols)


def _poses_of(t: _Table, length_unit: str, expect: str) -> tuple[np.ndarray, np.ndarray | None]:
    qcols = _check_pose_header(t, expect)
    xyz = np.stack([t.numeric(c) for c in POSITION_COLUMNS], axis=1)
    quat = np.stack([t.numeric(c) for c in QUAT_COLUMNS], axis=1) if qcols else None
    _check_finite(t.where, xyz, POSITION_COLUMNS, t.line_offset)
    if quat is not None:
        _check_finite(t.where, quat, QUAT_COLUMNS, t.line_offset)
    return xyz * LENGTH_UNITS[length_unit], quat


def _standard_columns(t: _Table) -> set[str]:
    k = 0
    while f"q{k + 1}" in t.header:
        k += 1
    return set(joint_columns(k)) | set(POSITION_COLUMNS) | set(QUAT_COLUMNS)


def read_dataset(
    path: str | Path,
    *,
    length_unit: str = "m",
    angle_unit: str = "rad",
    robot=None,
    dof: int | None = None,
    plausibility: bool = True,
) -> Dataset:
    """Read a dataset file (``.csv`` or ``.parquet``, DESIGN.md §3) into SI units and validate it.

    ``length_unit`` (``"m"``/``"mm"``) and ``angle_unit`` (``"rad"``/``"deg"``) are the units *in the
    file*. ``robot`` (optional) fixes the number of joints, which joints are prismatic, and enables
    the joint-limit check and (``plausibility``) the unit and quaternion-order checks of
    :func:`hykin.plausibility.check_dataset` (positions vs the robot's motion, orientations vs its
    rotations); ``dof`` fixes the number of joints without a robot. Without either the joints are the
    contiguous ``q1, q2, ...`` columns of the header.
    """
    where = str(path)
    _check_units(where, length_unit, angle_unit)
    t = _open_table(path)
    _check_declared_units(t, length_unit, angle_unit)
    n_dof = _dof_from_header(where, t.header, robot, dof)
    expect = f"{', '.join(joint_columns(n_dof))}, x, y, z and optionally qw, qx, qy, qz"
    _check_pose_header(t, expect)  # name missing columns before reading any cell
    q = _joints_of(t, robot, dof, angle_unit, length_unit)
    xyz, quat = _poses_of(t, length_unit, expect)
    if q.shape[0] == 0:
        raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
    ds = Dataset(q=q, xyz_m=xyz, quat_wxyz=quat, extra=t.extras(_standard_columns(t)), source=where,
                 meta={"length_unit_read": length_unit, "angle_unit_read": angle_unit})
    from ..calibration.reflectors import with_reflector_unit

    ds = with_reflector_unit(ds, length_unit)  # further reflectors x2,y2,z2, ... in metres like x,y,z
    validate(ds, robot, where=where, angle_unit=angle_unit, line_offset=t.line_offset)
    if robot is not None and plausibility:
        from ..calibration.plausibility import check_dataset

        check_dataset(robot, ds, where=where, length_unit=length_unit, angle_unit=angle_unit)
    return ds


def read_joints(
    path: str | Path,
    *,
    dof: int | None = None,
    angle_unit: str = "rad",
    length_unit: str = "m",
    robot=None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read joints ``q1..qN`` from a CSV/Parquet file: ``(q (N, dof) rad/m, extras)``.

    Pose columns (``x,y,z,qw..qz``), if present, are ignored; every other column is returned in
    ``extras``. Joint checks as in :func:`validate` (degrees-as-radians, limits when ``robot``).
    """
    where = str(path)
    _check_units(where, length_unit, angle_unit)
    t = _open_table(path)
    _check_declared_units(t, length_unit, angle_unit)
    q = _joints_of(t, robot, dof, angle_unit, length_unit)
    if q.shape[0] == 0:
        raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
    validate_joints(q, robot, where=where, angle_unit=angle_unit, line_offset=t.line_offset)
    return q, t.extras(_standard_columns(t))


def read_poses(path: str | Path, *, length_unit: str = "m", extras: bool = False):
    """Read target poses ``x,y,z[,qw,qx,qy,qz]`` from a CSV/Parquet file: ``(T (N, 4, 4) m, has_orientation)``.

    Joint and other columns are ignored (returned as a third item ``{name: (N,)}`` with
    ``extras=True``). Without orientation columns the rotations are identity.
    """
    where = str(path)
    _check_units(where, length_unit, "rad")
    t = _open_table(path)
    if "hykin.length_unit" in t.metadata:
        _check_declared_units(t, length_unit, t.metadata.get("hykin.angle_unit", "rad"))
    xyz, quat = _poses_of(t, length_unit, "x, y, z and optionally qw, qx, qy, qz")
    if xyz.shape[0] == 0:
        raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
    validate_poses(xyz, quat, where=where, line_offset=t.line_offset)
    if quat is None:
        T = np.tile(np.eye(4), (len(xyz), 1, 1))
        T[:, :3, 3] = xyz
    else:
        T = se3.pose_to_transform(xyz, quat)
    if extras:
        return T, quat is not None, t.extras(_standard_columns(t))
    return T, quat is not None


# --------------------------------------------------------------------------- writing


def _columns_for_writing(ds: Dataset, length_unit: str, angle_unit: str, robot=None) -> dict[str, np.ndarray]:
    L, A = LENGTH_UNITS[length_unit], ANGLE_UNITS[angle_unit]
    rev = _revolute_mask(ds.dof, robot)
    out: dict[str, np.ndarray] = {}
    for j, c in enumerate(joint_columns(ds.dof)):
        out[c] = ds.q[:, j] / (A if rev[j] else L)
    for j, c in enumerate(POSITION_COLUMNS):
        out[c] = ds.xyz_m[:, j] / L
    if ds.quat_wxyz is not None:
        for j, c in enumerate(QUAT_COLUMNS):
            out[c] = ds.quat_wxyz[:, j]
    from ..calibration.reflectors import reflector_columns

    points = {n for names in reflector_columns(ds) for n in names}  # x2,y2,z2, ...: lengths like x,y,z
    for k, v in ds.extra.items():
        if k in out:
            raise DatasetError(f"{ds.source or '<dataset>'}: extra column '{k}' clashes with a standard column", column=k)
        out[k] = np.asarray(v, dtype=np.float64) / L if k in points else v
    return out


def write_dataset(ds: Dataset, path: str | Path, *, length_unit: str = "m", angle_unit: str = "rad", robot=None) -> None:
    """Write ``ds`` to CSV or Parquet (by suffix): ``q1..qN, x, y, z[, qw, qx, qy, qz]`` + extras.

    Values are converted to the declared units (extras as they are); CSV numbers use the shortest
    repr that reads back to the same float64. ``robot`` marks prismatic joints (length unit).
    """
    where = str(path)
    _check_units(where, length_unit, angle_unit)
    cols = _columns_for_writing(ds, length_unit, angle_unit, robot)
    suffix = Path(path).suffix.lower()
    if suffix in (".parquet", ".pq"):
        import pyarrow as pa
        import pyarrow.parquet as pq

        table = pa.table({k: pa.array(np.asarray(v)) for k, v in cols.items()})
        table = table.replace_schema_metadata(
            {"hykin.length_unit": length_unit, "hykin.angle_unit": angle_unit, "hykin.source": ds.source})
        pq.write_table(table, path)
        return
    if suffix not in (".csv", ".txt"):
        raise DatasetError(f"{where}: unknown dataset file type {suffix!r}; expected .csv or .parquet", file=where)
    names = list(cols)
    try:
        import pyarrow as pa
        import pyarrow.csv as pacsv
    except ImportError:  # optional dependency: fall back to Python's csv writer (same values, slower)
        pa = None
    if pa is not None and all(np.asarray(v).dtype.kind in "iuf" for v in cols.values()):
        # Arrow's writer prints the shortest round-trip repr of each float64, 4-5x faster than Python.
        table = pa.table({k: pa.array(np.asarray(v, dtype=np.float64)) for k, v in cols.items()})
        with open(path, "wb") as fh:
            fh.write((",".join(names) + "\n").encode("utf-8"))
            pacsv.write_csv(table, fh, write_options=pacsv.WriteOptions(include_header=False, quoting_style="none"))
        return
    text_cols = []
    for v in cols.values():
        v = np.asarray(v)
        text_cols.append(list(map(repr, v.astype(np.float64).tolist())) if v.dtype.kind in "iuf" else list(map(str, v.tolist())))
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.writer(fh, lineterminator="\n")
        w.writerow(names)
        w.writerows(zip(*text_cols))


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
