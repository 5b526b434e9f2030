"""Dataset files: read and write CSV (also ``.txt``/``.tsv``) and Parquet datasets (DESIGN.md §3).

File format: one row per measured pose, header required, columns ``q1..qN`` (joints), ``x,y,z``
(measured TCP position) and optionally ``qw,qx,qy,qz`` (unit quaternion, scalar first); every other
column is kept in :attr:`~hykin.io.dataset.Dataset.extra`. Units are **declared**, never guessed
(``length_unit``, ``angle_unit``; see :mod:`hykin.io.dataset`); Parquet files written by hykin
record them and a different declaration is refused.

Text files are read by :func:`hykin.io.text_table.read_delimited` and written by
:func:`hykin.io.csv_writer.write_csv`. Errors are :class:`~hykin.io.dataset.DatasetError` naming the
file, the data row (with its line in the file) and the column.
"""

from __future__ import annotations

import re

from collections.abc import Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..geometry import se3
from .csv_writer import DATASET_STYLE, write_csv
from .dataset import (
    ANGLE_UNITS,
    LABEL_COLUMNS,
    LENGTH_UNITS,
    POSITION_COLUMNS,
    QUAT_COLUMNS,
    Dataset,
    DatasetError,
    check_finite,
    check_units,
    joint_columns,
    label_cells,
    revolute_mask,
    row_error,
    validate,
    validate_joints,
    validate_poses,
)
from .text_table import (
    delimiter_name,
    detect_delimiter,
    float_column,
    lenient_column,
    read_delimited,
    read_lines,
    with_file_line,
)

__all__ = ["read_dataset", "read_joints", "read_poses", "write_dataset"]


def _joint_header(where: str, header: Sequence[str], robot, dof: int | None) -> list[str]:
    """The joint columns to read: ``q1..qN``, or (a robot from a URDF, no ``q1`` column) the URDF's
    names of its independent joints, in chain order. A URDF-named file that lacks one of them is
    refused in one line naming the column and the expected names."""
    names = None if robot is None else robot.independent_joint_names
    present = set(header)
    if names and "q1" not in present and any(c in present for c in robot.joint_names):
        missing = [c for c in names if c not in present]
        if missing:
            import difflib

            others = [h for h in header if h not in robot.joint_names]
            close = difflib.get_close_matches(missing[0], others, n=1, cutoff=0.6)
            col = close[0] if close else missing[0]
            why = f"column '{col}' is not a joint of the URDF (did you mean '{missing[0]}'?)" if close else \
                f"missing joint column '{missing[0]}'"
            raise DatasetError(f"{where}: {why}; expected the URDF's independent joints {', '.join(names)} "
                               f"(or q1..q{len(names)})", file=where, column=col)
        return list(names)
    return joint_columns(_dof_from_header(where, header, robot, dof))


def _check_mimic_columns(t, robot, q: np.ndarray, angle: float, length: float) -> None:
    """Columns named after a URDF mimic joint (a ROS log has them) must equal ``multiplier · leader +
    offset``; they are then redundant. Otherwise refused naming the column and row."""
    if robot is None or robot.mimic is None or robot.joint_names is None:
        return
    idx, mult, off = robot.expansion()
    for i, name in enumerate(robot.joint_names):
        if robot.mimic[i, 0] < 0 or name not in t.header:
            continue
        v = t.numeric(name) * (angle if robot.joint_type[i] == "revolute" else length)
        bad = np.abs(v - (mult[i] * q[:, idx[i]] + off[i])) > 1e-6 * np.maximum(1.0, np.abs(v))
        if bad.any():
            r = int(np.argmax(bad))
            lead = robot.joint_names[int(robot.mimic[i, 0])]
            raise row_error(t.where, f"{v[r]:.6g} but the URDF's <mimic> gives {mult[i]:g}·{lead} + {off[i]:g} = "
                            f"{mult[i] * q[r, idx[i]] + off[i]:.6g}: the data do not follow the URDF's mimic joint",
                            row=r, column=name, line_offset=t.line_offset)


def _dof_from_header(where: str, header: Sequence[str], robot, dof: int | None) -> int:
    present = {h for h in header}
    k = 0
    while f"q{k + 1}" in present:
        k += 1
    want = robot.dof if robot is not None else dof
    if want is None:
        if k == 0:
            raise DatasetError(
                f"{where}: no joint columns; expected q1..qN (found: {', '.join(header)})"
                f"{_header_hint(['q1'], header)}", file=where)
        return k
    if robot is not None and dof is not None and dof != robot.dof:
        raise DatasetError(f"{where}: dof={dof} given but robot {robot.name!r} has {robot.dof} joints", file=where)
    missing = [c for c in joint_columns(want) if c not in present]
    if missing:
        names = None if robot is None else robot.independent_joint_names
        alt = f" (or the URDF's joint names {', '.join(names)})" if names else ""
        raise DatasetError(
            f"{where}: missing column(s) {', '.join(missing)}; expected the joint columns {', '.join(joint_columns(want))}"
            f"{alt} (found: {', '.join(header)}){_header_hint(missing, header)}", file=where,
            column=missing[0])
    if f"q{want + 1}" in present:
        raise DatasetError(
            f"{where}: the file has joint columns q1..q{k} but the robot{'' if robot is None else ' ' + repr(robot.name)} "
            f"has {want} joints", file=where, column=f"q{want + 1}")
    return want



@dataclass
class _Table:
    """A read table: header, a strict numeric accessor (errors name row/column) and a lenient one.

    ``line_offset``: file line minus data row when constant (else None); ``lines``: ``(N,)`` file
    line of each row for text files (None for Parquet)."""

    where: str
    header: list[str]
    numeric: object  # (name) -> float64 (N,), raising DatasetError on a bad cell
    lenient: object  # (name) -> float64 or str (N,)
    line_offset: int | None
    metadata: dict
    lines: np.ndarray | None = None
    text: object = None  # (name) -> str (N,) cells as written (text files; label columns)
    deg_joints: tuple = ()  # joint columns read from ``q<i>_deg`` (:func:`_deg_joint_columns`)

    def extras(self, skip) -> dict[str, np.ndarray]:
        """Extra columns: label columns (station, tool, pose_id, pose) as text as written ("01" stays "01"),
        others as numbers when every cell is one."""
        skip = set(skip)
        return {c: (self.text(c) if self.text is not None and c in LABEL_COLUMNS else self.lenient(c))
                for c in self.header if c not in skip}


@contextmanager
def _file_lines(t: _Table):
    """Name the file line in a row error raised without one (rows not one line apart: blank lines)."""
    try:
        yield
    except DatasetError as e:
        if (type(e) is DatasetError and e.row is not None and t.line_offset is None and t.lines is not None
                and f"row {e.row} (line" not in str(e)):
            raise with_file_line(e, t.lines) from None
        raise


def _open_table(path: str | Path) -> _Table:
    """Open a ``.csv``/``.txt`` (comma), ``.tsv`` (tab) or ``.parquet`` table."""
    where = str(path)
    suffix = Path(path).suffix.lower()
    if suffix in (".parquet", ".pq"):
        return _open_parquet(path)
    if suffix not in (".csv", ".txt", ".tsv"):
        raise DatasetError(f"{where}: unknown dataset file type {suffix!r}; expected .csv or .parquet", file=where)
    try:
        t = read_delimited(path, delimiter="\t" if suffix == ".tsv" else ",", allow_empty_names=True,
                           layout_hint="is that the file's delimiter?")
    except DatasetError:
        # a ';'-separated export with decimal commas splits its rows on the commas: say what the file is
        first = next((ln for ln in read_lines(Path(path), None, where) if ln.strip()), "")
        _check_header(where, path, [first] if "," not in first else [])
        raise
    _check_header(where, path, t.header)
    return _Table(where, t.header, lambda c: float_column(t, c, finite=False), lambda c: lenient_column(t.col(c)),
                  t.line_offset(), {}, t.lines, lambda c: label_cells(t.col(c)))


_DEG_JOINT = re.compile(r"q(\d+)_deg")


def _deg_joint_columns(t: _Table, angle_unit: str) -> str:
    """Joint columns named with their unit, ``q<i>_deg`` (as ``hykin plan`` writes them for a robot file in
    degrees), read as ``q<i>`` in degrees (in place; returns the angle unit to read with: ``"deg"``).
    The name says the unit, so it holds whatever ``--angle-unit`` says (the default is rad); both a
    ``q<i>`` and a ``q<i>_deg`` column, or ``q<i>_deg`` beside plain revolute angles, is refused."""
    deg = {m.group(0): f"q{m.group(1)}" for h in t.header if (m := _DEG_JOINT.fullmatch(h))}
    if not deg:
        return angle_unit
    both = [c for c, q in deg.items() if q in t.header]
    if both:
        raise DatasetError(f"{t.where}: both '{deg[both[0]]}' and '{both[0]}' columns: one joint, two columns (drop one)",
                           file=t.where, column=both[0])
    alias = {q: c for c, q in deg.items()}
    t.header = [deg.get(h, h) for h in t.header]
    numeric, lenient, text = t.numeric, t.lenient, t.text
    t.numeric = lambda c: numeric(alias.get(c, c))
    t.lenient = lambda c: lenient(alias.get(c, c))
    t.text = None if text is None else (lambda c: text(alias.get(c, c)))
    t.deg_joints = tuple(alias)
    return "deg"


def _check_header(where: str, path, header: list) -> None:
    """Refuse a header that is one column holding another delimiter (a ';'/tab/'|'-separated file)."""
    if len(header) == 1 and (d := detect_delimiter(header[0], ".")) in ("\t", ";", "|"):
        tsv = ": name it .tsv" if d == "\t" else " (or tab-separated as .tsv)"
        raise DatasetError(f"{where}: the header is one column {header[0][:60]!r}...: the file looks "
                           f"{delimiter_name(d)}-separated; datasets are comma-separated{tsv}; any other layout: "
                           f"hykin import table {Path(path).name} --suggest", file=where)


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
            raise row_error(where, "cell is empty (null)", r, c, None)
        if pa.types.is_floating(col.type) or pa.types.is_integer(col.type):
            return np.asarray(col.to_numpy(), dtype=np.float64)
        cells = [str(v) for v in col.to_pylist()]
        arr = lenient_column(cells)
        if arr.dtype.kind != "f":
            for r, v in enumerate(cells):
                try:
                    float(v)
                except ValueError:
                    raise row_error(where, f"cell {v!r} is not a number (column type {col.type})", r, c, None) from None
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
    qn = _joint_header(t.where, t.header, robot, dof)
    q = np.stack([t.numeric(c) for c in qn], axis=1)
    check_finite(t.where, q, qn, t.line_offset)
    rev = revolute_mask(len(qn), robot)
    plain = [c for c, r in zip(qn, rev) if r and c not in t.deg_joints]
    if t.deg_joints and plain:  # q<i>_deg columns make every revolute angle degrees: a plain one would be read so
        raise DatasetError(f"{t.where}: joint column '{plain[0]}' has no unit in its name beside "
                           f"'{t.deg_joints[0]}_deg': name every revolute joint q<i>_deg (or none, with --angle-unit)",
                           file=t.where, column=plain[0])
    factor = np.where(rev, ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit])
    q = q * factor
    if robot is not None and robot.continuous.any():  # continuous joints: into [-pi, pi) (same poses)
        c = robot.continuous
        q[:, c] = np.mod(q[:, c] + np.pi, 2 * np.pi) - np.pi
    _check_mimic_columns(t, robot, q, ANGLE_UNITS[angle_unit], LENGTH_UNITS[length_unit])
    return q


def _header_hint(missing: list[str], header: list[str]) -> str:
    """``"; column names are lower-case: ..."`` when the missing columns are there in another case;
    ``"; the first line holds numbers: ..."`` when the file has no header line."""
    if header and all(_is_number(h) for h in header):
        return ("; the first line holds numbers, not column names: the file has no header line (add one naming "
                "the columns, e.g. q1,...,x,y,z,qw,qx,qy,qz, or map them: hykin import table FILE --suggest)")
    found = {h.strip().lower(): h for h in header}
    pairs = [(found[m], m) for m in missing if m in found]
    if not pairs:
        return ""
    shown = ", ".join(f"{h!r} for {m!r}" for h, m in pairs[:3]) + (", ..." if len(pairs) > 3 else "")
    return f"; column names are lower-case: the file has {shown} (rename them, or map them: hykin import table FILE --suggest)"


def _check_pose_header(t: _Table, expect: str) -> bool:
    """Raise for missing x/y/z or partial orientation columns; return True when orientation is present."""
    present = set(t.header)
    missing = [c for c in POSITION_COLUMNS if c not in present]
    if missing:
        raise DatasetError(
            f"{t.where}: missing column(s) {', '.join(missing)}; expected {expect} "
            f"(found: {', '.join(t.header)}){_header_hint(missing, t.header)}", file=t.where, column=missing[0])
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
    check_finite(t.where, xyz, POSITION_COLUMNS, t.line_offset)
    if quat is not None:
        check_finite(t.where, quat, QUAT_COLUMNS, t.line_offset)
    return xyz * LENGTH_UNITS[length_unit], quat


def _standard_columns(t: _Table, robot=None) -> set[str]:
    k = 0
    while f"q{k + 1}" in t.header:
        k += 1
    named = set(robot.joint_names) if robot is not None and robot.joint_names and not k else set()
    return set(joint_columns(k)) | set(POSITION_COLUMNS) | set(QUAT_COLUMNS) | named


def read_dataset(
    path: str | Path,
    *,
    length_unit: str = "m",
    angle_unit: str = "rad",
    robot=None,
    dof: int | None = None,
    plausibility: bool = True,
    unit_check: bool = True,
) -> Dataset:
    """Read a dataset file (``.csv`` or ``.parquet``, DESIGN.md §3) into SI units and validate it.

    ``length_unit`` (``"m"``/``"mm"``) and ``angle_unit`` (``"rad"``/``"deg"``) are the units *in the
    file*. Joint columns: ``q1..qN``, or for a robot read from a URDF its independent joints' names
    (columns of mimic joints are checked against ``<mimic>`` and dropped). ``robot`` (optional) fixes the number of joints, which joints are prismatic, and enables
    the joint-limit check and (``plausibility``) the unit and quaternion-order checks of
    :func:`hykin.io.plausibility.check_dataset` (positions vs the robot's motion, orientations vs its
    rotations); ``dof`` fixes the number of joints without a robot. Without either the joints are the
    contiguous ``q1, q2, ...`` columns of the header. ``unit_check=False`` (the CLI's
    ``--no-unit-check``) turns every unit heuristic off (:func:`hykin.io.dataset.validate`'s and the
    plausibility checks); declared units are still applied.
    """
    where = str(path)
    check_units(where, length_unit, angle_unit)
    t = _open_table(path)
    angle_unit = _deg_joint_columns(t, angle_unit)
    with _file_lines(t):
        _check_declared_units(t, length_unit, angle_unit)
        expect = f"{', '.join(_joint_header(where, t.header, robot, dof))}, x, y, z and optionally qw, qx, qy, qz"
        _check_pose_header(t, expect)  # name missing columns before reading any cell
        q = _joints_of(t, robot, dof, angle_unit, length_unit)
        xyz, quat = _poses_of(t, length_unit, expect)
        if q.shape[0] == 0:
            raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
        ds = Dataset(q=q, xyz_m=xyz, quat_wxyz=quat, extra=t.extras(_standard_columns(t, robot)), source=where,
                     meta={"length_unit_read": length_unit, "angle_unit_read": angle_unit, "unit_check": bool(unit_check)})
        from .reflectors import with_reflector_unit

        ds = with_reflector_unit(ds, length_unit)  # further reflectors x2,y2,z2, ... in metres like x,y,z
        validate(ds, robot, where=where, angle_unit=angle_unit, line_offset=t.line_offset,
                 joint_names=_joint_header(where, t.header, robot, dof), unit_check=unit_check)
        if robot is not None and plausibility and unit_check:
            from .plausibility import check_dataset

            check_dataset(robot, ds, where=where, length_unit=length_unit, angle_unit=angle_unit)
        return ds


def read_joints(
    path: str | Path,
    *,
    dof: int | None = None,
    angle_unit: str = "rad",
    length_unit: str = "m",
    robot=None,
    unit_check: bool = True,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Read joints ``q1..qN`` from a CSV/Parquet file: ``(q (N, dof) rad/m, extras)``.

    Pose columns (``x,y,z,qw..qz``), if present, are ignored; every other column is returned in
    ``extras``. Joint checks as in :func:`validate` (degrees-as-radians, limits when ``robot``).
    """
    where = str(path)
    check_units(where, length_unit, angle_unit)
    t = _open_table(path)
    angle_unit = _deg_joint_columns(t, angle_unit)
    with _file_lines(t):
        _check_declared_units(t, length_unit, angle_unit)
        q = _joints_of(t, robot, dof, angle_unit, length_unit)
        if q.shape[0] == 0:
            raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
        validate_joints(q, robot, where=where, angle_unit=angle_unit, line_offset=t.line_offset,
                        joint_names=_joint_header(where, t.header, robot, dof), unit_check=unit_check)
        return q, t.extras(_standard_columns(t, robot))


def read_poses(path: str | Path, *, length_unit: str = "m", extras: bool = False, unit_check: bool = True):
    """Read target poses ``x,y,z[,qw,qx,qy,qz]`` from a CSV/Parquet file: ``(T (N, 4, 4) m, has_orientation)``.

    Joint and other columns are ignored (returned as a third item ``{name: (N,)}`` with
    ``extras=True``). Without orientation columns the rotations are identity.
    """
    where = str(path)
    check_units(where, length_unit, "rad")
    t = _open_table(path)
    with _file_lines(t):
        if "hykin.length_unit" in t.metadata:
            _check_declared_units(t, length_unit, t.metadata.get("hykin.angle_unit", "rad"))
        xyz, quat = _poses_of(t, length_unit, "x, y, z and optionally qw, qx, qy, qz")
        if xyz.shape[0] == 0:
            raise DatasetError(f"{where}: the file has a header but no data rows", file=where)
        validate_poses(xyz, quat, where=where, line_offset=t.line_offset, **({} if unit_check else {"max_spread_m": None}))
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
    rev = revolute_mask(ds.dof, robot)
    out: dict[str, np.ndarray] = {}
    for j, c in enumerate(joint_columns(ds.dof)):
        out[c] = ds.q[:, j] / (A if rev[j] else L)
    for j, c in enumerate(POSITION_COLUMNS):
        out[c] = ds.xyz_m[:, j] / L
    if ds.quat_wxyz is not None:
        for j, c in enumerate(QUAT_COLUMNS):
            out[c] = ds.quat_wxyz[:, j]
    from .reflectors import reflector_columns

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
    check_units(where, length_unit, angle_unit)
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
    write_csv(path, cols, DATASET_STYLE)


def _is_number(cell: str) -> bool:
    try:
        float(cell.replace(",", "."))
    except ValueError:
        return False
    return True
