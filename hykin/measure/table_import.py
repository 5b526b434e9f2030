"""Any tracker/robot table into the standard dataset (``hykin import table``, DESIGN.md §3-4).

:func:`read_text_table` reads a delimited text file as laid out by a :class:`~hykin.measure.table_map.TableMap`
(delimiter, decimal comma, metadata lines, comments, dropped and filtered rows), keeping the file line
of every data row. :func:`read_mapped` turns the mapped columns into SI arrays (joints rad/m, positions
m, orientation as unit quaternions, further reflectors, time s); :func:`import_table` makes the
:class:`~hykin.io.dataset.Dataset` (with a ``nest``: the full pose from three reflectors).

Every error is a :class:`~hykin.io.dataset.DatasetError` naming the file, the data row with its line in
the file, the column and the likely cause (missing column with did-you-mean, non-numeric or empty
cell, decimal comma, NaN, joint count, values that look like another unit, a further joint column the
mapping leaves out).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..io.dataset import LABEL_COLUMNS, Dataset, DatasetError, label_cells, validate
from ..io.text_table import (
    TextTable,
    detect_delimiter,
    float_column,
    lenient_column,
    read_delimited,
    read_lines,
    split_lines,
    with_file_line,
)
from .orientation_names import check_orientation_names
from .suggest_orientation import RAD_LOOKS_LIKE_DEG  # |angle| above this, declared rad: degrees
from .table_map import (
    ANGLE_UNITS_RAD,
    LENGTH_UNITS_M,
    TIME_UNITS_S,
    TableMap,
    TableMapError,
    did_you_mean,
    euler_sequence,
    expand_joint_spec,
    load_table_map,
    table_map_from_dict,
)

__all__ = ["MappedTable", "check_lever_arms", "guess_layout", "import_table", "kept_cells", "read_mapped", "read_text_table"]

# Length units are judged by the RMS spread of the positions about their centroid, never by absolute
# coordinates (a tracker or total station may stand far from the robot): declared m, a spread above
# hykin.io.dataset.spread_limit_m (10 x the robot's reach, 50 m without a robot) is millimetres;
# declared mm, a spread below MM_LOOKS_LIKE_M (mm; a hundredth of the reach with a robot) is metres.
MM_LOOKS_LIKE_M = 5.0
QUAT_NORM_TOL = 1e-3


_COND = re.compile(r"^\s*(.+?)\s*(==|!=|<=|>=|<|>)\s*(.*?)\s*$")


def _filter_rows(t: TextTable, conditions: list[str], decimal: str) -> None:
    """Keep the rows where every ``"column op value"`` condition holds (numbers compared as numbers)."""
    keep = np.ones(len(t.rows), bool)
    for cond in conditions:
        m = _COND.match(cond)
        if not m:
            raise TableMapError(f"{t.where}: where condition {cond!r} must look like 'column == value' "
                                "(operators == != < <= > >=)", file=t.where, column="where")
        col, op, val = m.group(1).strip("\"'"), m.group(2), m.group(3).strip("\"'")
        if col not in t.header:
            raise TableMapError(f"{t.where}: where condition {cond!r}: no column {col!r}{did_you_mean(col, t.header)}",
                                file=t.where, column=col)
        cells = t.col(col)
        try:
            ref = float(val.replace(decimal, "."))
            vals = np.array([_num_or_nan(c, decimal) for c in cells])
        except ValueError:
            if op not in ("==", "!="):
                raise TableMapError(f"{t.where}: where condition {cond!r}: {op} needs a number", file=t.where, column=col) from None
            vals, ref = np.asarray(cells, dtype=object), val
        ok = {"==": vals == ref, "!=": vals != ref}.get(op) if op in ("==", "!=") else \
            {"<": vals < ref, "<=": vals <= ref, ">": vals > ref, ">=": vals >= ref}[op]
        keep &= np.asarray(ok, bool)
    t.rows = [r for r, k in zip(t.rows, keep) if k]
    t.lines = t.lines[keep]


def _num_or_nan(c: str, decimal: str) -> float:
    try:
        return float(c.replace(decimal, ".") if decimal != "." else c)
    except ValueError:
        return math.nan


def read_text_table(path: str | Path, m: TableMap | None = None) -> TextTable:
    """Read ``path`` as laid out by ``m`` (see :class:`~hykin.measure.table_map.TableMap`): header, rows, lines
    (:func:`hykin.io.text_table.read_delimited`), then ``m.where`` filters; no data rows is an error.

    Blank lines and ``comment`` lines are skipped anywhere; a trailing delimiter on every line is
    tolerated; a row with another number of cells than the header is an error naming its line. Header
    names that repeat (Motive's X,Y,Z per rigid body and marker) get the labels of the group lines
    above the header (``group_rows``, else found) joined in front; empty names become ``col<k>``.
    """
    m = m or TableMap()
    skip = m.skip_rows if not m.header_row else m.header_row - 1  # header_row = 0: no header, skip_rows still apply
    t = read_delimited(path, delimiter=m.delimiter, decimal=m.decimal, skip_rows=skip, header=m.header_row != 0,
                       comment=m.comment, drop_lines=m.drop_rows, encoding=m.encoding, groups=True,
                       group_lines=m.group_rows)
    if m.where:
        _filter_rows(t, m.where, m.decimal)
    if not t.rows:
        raise DatasetError(f"{t.where}: no data rows" + (" left after the where filters" if m.where else " under the header"),
                           file=t.where)
    return t


_UNIT_CELL = re.compile(r"(?i)^[\[(]?\s*(mm|m|cm|um|µm|in|ft|deg|degrees?|rad|radians?|°|s|sec|ms|us|ns|c|°c|k|kg|n|nm|"
                        r"hz|%|-|mm/s|m/s|deg/s|rad/s)\s*[\])]?$")


def _units_line(cells: list[str]) -> bool:
    """A line of units under a header (``,,deg,deg,mm,...``): no number, every cell empty or a unit."""
    return any(_UNIT_CELL.match(c) for c in cells) and all(not c or _UNIT_CELL.match(c) for c in cells)


def guess_layout(path: str | Path, m: TableMap | None = None) -> dict:
    """Guess ``skip_rows`` (metadata lines above the header), the delimiter, a decimal comma and a units
    line under the header (``drop_rows``; ``units`` = its cells, one per column), for
    :func:`~hykin.measure.table_map.suggest_map` only (the user confirms them in the mapping).

    The header is the first line of at least two cells, most of them non-empty names (not a group line
    such as Vicon's ``,,UR5Tool:Tool,,,``), followed (after an optional units line) by numeric rows of
    its width (Motive's group lines are not); failing that, the first line followed by rows of its width."""
    m = m or TableMap()
    where = str(path)
    text = read_lines(Path(path), m.encoding, where)
    numbered = [(i, ln) for i, ln in enumerate(text) if ln.strip() and not (m.comment and ln.lstrip().startswith(m.comment))]
    for strict in (True, False):  # first a named header over numeric rows, else the first line of the rows' width
        for k, (i, ln) in enumerate(numbered[:30]):
            delim = m.delimiter or detect_delimiter(ln, m.decimal)
            head = split_lines([ln], delim)[0]
            width = len(head)
            if width < 2 or (strict and (sum(1 for c in head if c) * 4 < width * 3 or _numeric_line(head, m.decimal))):
                continue
            nxt = split_lines([x for _, x in numbered[k + 1:k + 21]], delim)
            units = None
            if strict and nxt and len(nxt[0]) in (width, width + 1) and _units_line(nxt[0]):
                units, nxt = nxt[0][:width], nxt[1:]
            if strict and not (nxt and _numeric_line(nxt[0], m.decimal)):
                continue
            if nxt and all(len(r) == width or (len(r) == width + 1 and not r[-1]) for r in nxt):
                out = {"skip_rows": i, "delimiter": delim}
                if not strict and all(c and not math.isnan(_num_or_nan(c.replace(",", "."), ".")) for c in head):
                    out["header_row"] = 0  # the first line is numbers like the rows under it: no header
                cells = [c for r in nxt for c in r]
                # (comma-delimited: a cell holds a comma only when quoted, "-101,03" -- a decimal comma too)
                if m.decimal == "." and any(re.fullmatch(r"[+-]?\d*,\d+", c) for c in cells):
                    out["decimal"] = ","
                if units is not None:
                    out["drop_rows"] = [numbered[k + 1][0] + 1]
                    out["units"] = units
                return out
    return {}


def _numeric_line(cells: list[str], decimal: str) -> bool:
    """At least 80 % of the non-empty cells are numbers (a data row, not a header or group line)."""
    full = [c for c in cells if c]
    return bool(full) and sum(not math.isnan(_num_or_nan(c.replace(",", "."), ".")) for c in full) >= 0.8 * len(full)


@dataclass
class MappedTable:
    """The mapped quantities of a table in SI units (rows as filtered, ``lines`` = file lines).

    q ``(N, dof)`` rad/m or None; joint_columns; xyz_m ``(N, 3)`` or None; quat_wxyz ``(N, 4)`` or
    None; points_m ``(N, K, 3)`` further reflectors; time_s ``(N,)`` or None; extra ``{name: (N,)}``.
    """

    table: TextTable
    q: np.ndarray | None
    joint_columns: list[str]
    xyz_m: np.ndarray | None
    quat_wxyz: np.ndarray | None
    points_m: np.ndarray
    time_s: np.ndarray | None
    extra: dict[str, np.ndarray] = field(default_factory=dict)


def _stack(t: TextTable, names: list[str], decimal: str, allow_missing: bool = False) -> np.ndarray:
    return np.stack([float_column(t, c, decimal, allow_missing=allow_missing) for c in names], axis=1)


def _require(t: TextTable, names: list[str], role: str) -> None:
    for c in names:
        if c not in t.header:
            raise t.error(None, c, f"no such column (mapped as {role}){did_you_mean(c, t.header)}; "
                          f"the header is: {', '.join(t.header)}")


def _check_further_joints(t: TextTable, joints: list[str], used: set[str], m: TableMap, q_raw: np.ndarray) -> None:
    """Refuse a header column that continues the joints' numbering (``joint_7`` next to joint_1..6).

    Text columns and frame counters (integers increasing every row) are never joints. Without a header
    (names ``"1", "2", ...``) the name is no evidence: only the columns next to the mapped ones are
    looked at, and refused only when their values vary like the joints' (within 1.5 x the joints'
    largest magnitude, a range of at least a tenth of theirs, not increasing every row: a time column)."""
    bare = all(j.isdigit() for j in joints)
    if bare:
        nums = [int(j) for j in joints]
        cands = [str(k) for k in (min(nums) - 1, max(nums) + 1)]
    else:
        mm = re.fullmatch(r"(.*?)(\d+)(\D*)", joints[-1])
        if not mm:
            return
        rx = re.compile(re.escape(mm.group(1)) + r"(\d+)" + re.escape(mm.group(3)))
        cands = [h for h in t.header if rx.fullmatch(h)]
    for h in cands:
        if h not in t.header or h in used or h in m.ignore or h in m.keep_names():
            continue
        v = lenient_column(t.col(h), m.decimal)
        if v.dtype.kind != "f":
            continue  # text: not a joint
        v = v[np.isfinite(v)]
        rising = len(v) >= 3 and bool((np.diff(v) > 0).all())
        if rising and np.array_equal(v, np.round(v)):
            continue  # a frame counter
        if bare:
            qa = np.abs(q_raw)
            span = float(np.median(np.ptp(q_raw, axis=0))) if len(q_raw) else 0.0
            if rising or not len(v) or np.abs(v).max() > 1.5 * qa.max() or np.ptp(v) < 0.1 * span:
                continue
        raise t.error(None, h, f"looks like a further joint that the mapping leaves out (joints: {', '.join(joints)}"
                      f"{'; its values vary like theirs' if bare else ''}); map it under joints, or list it under ignore if "
                      "it is not a joint of this arm")


def _spread(xyz: np.ndarray) -> float:
    """RMS distance ``(N, 3)`` -> scalar of the points about their centroid (frame independent)."""
    return float(np.sqrt(np.mean(np.sum((xyz - xyz.mean(0)) ** 2, axis=1)))) if len(xyz) else 0.0


def _unit_checks(t: TextTable, m: TableMap, q_raw, rev, xyz_raw, ang_raw, ang_unit, ang_cols, jn, pos,
                 robot=None) -> None:
    if not m.check_units:
        return
    from ..io.dataset import spread_limit_m
    from ..kinematics.robot import robot_reach_m
    hint_off = " (check_units = false / --no-unit-check if the values are right)"
    if q_raw is not None and rev.any():
        qr = np.abs(q_raw[:, rev])
        names = [c for c, r in zip(jn, rev) if r]
        if m.angle_unit == "rad" and (qr > RAD_LOOKS_LIKE_DEG).any():
            r, c = np.argwhere(qr > RAD_LOOKS_LIKE_DEG)[0]
            raise t.error(int(r), names[c], f"joint value {q_raw[r, rev][c]:.6g} declared rad looks like degrees: "
                          "declare angle_unit = \"deg\" (--angle-unit deg)" + hint_off)
        span = np.ptp(q_raw[:, rev], axis=0).max() if len(q_raw) > 1 else 0.0
        if m.angle_unit == "deg" and len(q_raw) >= 10 and qr.max() <= 2 * math.pi + 0.1 and span > 0.5:
            r, c = np.unravel_index(int(np.argmax(qr)), qr.shape)
            raise t.error(int(r), names[c], f"every joint value is within ±2π although degrees were declared "
                          f"(largest {qr.max():.6g}): looks like radians; declare angle_unit = \"rad\"" + hint_off)
    if xyz_raw is not None and len(xyz_raw) >= 2:
        spread = _spread(xyz_raw)
        lim = spread_limit_m(robot)
        if m.length_unit == "m" and spread > lim:
            r, c = np.unravel_index(int(np.argmax(np.abs(xyz_raw - xyz_raw.mean(0)))), xyz_raw.shape)
            raise t.error(int(r), pos[c], f"positions declared m spread {spread:.6g} (RMS about their centroid; > {lim:.3g} m, "
                          "more than the arm moves): looks like millimetres; declare length_unit = \"mm\" (--length-unit mm)"
                          + hint_off)
        small = MM_LOOKS_LIKE_M if robot is None else 1e3 * float(robot_reach_m(robot)) / 100.0
        if m.length_unit == "mm" and spread < small and np.ptp(xyz_raw, axis=0).max() > 0:
            raise t.error(None, pos[0], f"positions declared mm spread only {spread:.3g} mm (RMS about their centroid): "
                          "looks like metres; declare length_unit = \"m\"" + hint_off)
    if ang_raw is not None and ang_unit == "rad":
        a = np.abs(ang_raw)
        if (a > RAD_LOOKS_LIKE_DEG).any():
            r, c = np.argwhere(a > RAD_LOOKS_LIKE_DEG)[0]
            key = "euler_unit" if m.euler is not None else "rotvec_unit"
            raise t.error(int(r), ang_cols[c], f"angle {ang_raw[r, c]:.6g} declared rad looks like degrees: "
                          f"declare {key} = \"deg\"" + hint_off)


LEVER_ARM_VARIATION = (1e-3, 0.02)  # m, fraction: a lever arm stays within max(1 mm, 2 %) of its median ...
LEVER_ARM_OFF_ROWS = 0.2  # ... in all but this fraction of the rows (a swapped or lost reflector in a few rows is
#                           named per row by the later checks, e.g. the nest fit)


def check_lever_arms(t: TextTable, m: TableMap, xyz_m: np.ndarray, P_m: np.ndarray) -> None:
    """Refuse a further reflector (``points``) that is not one: on a rigid tool its distance from the
    first reflector lies in ``m.lever_arm_m`` (default 3 mm - 2 m; it would otherwise be a duplicate of
    the first, or millimetres read as metres) and is constant over the rows: within
    :data:`LEVER_ARM_VARIATION` (``max(1 mm, 2 %)``) of its median in at least 80 % of the rows (an
    uncertainty, accelerometer or index column is not). ``xyz_m`` ``(N, 3)``, ``P_m`` ``(N, K, 3)``
    in metres; rows with a missing value are skipped. One line naming the columns."""
    lo, hi = m.lever_arm_m
    for k in range(P_m.shape[1]):
        ok = np.isfinite(P_m[:, k]).all(1) & np.isfinite(xyz_m).all(1)
        if ok.sum() < 1:
            continue
        d = np.linalg.norm(P_m[ok, k] - xyz_m[ok], axis=1)
        med = float(np.median(d))
        tol = max(LEVER_ARM_VARIATION[0], LEVER_ARM_VARIATION[1] * med)
        off = np.abs(d - med) > tol
        cols = ", ".join(f"'{c}'" for c in m.points[k])
        why = None
        if not lo <= med <= hi:
            why = (f"lies {med * 1e3:.4g} mm (median) from the first reflector, outside the lever arm of a second reflector "
                   f"on the same tool ({lo * 1e3:g} mm - {hi:g} m; lever_arm_m)")
        elif off.mean() > LEVER_ARM_OFF_ROWS:
            why = (f"changes its distance from the first reflector by more than {tol * 1e3:.3g} mm in {off.sum()} of "
                   f"{off.size} rows (median {med * 1e3:.4g} mm): not on the same rigid tool")
        if why:
            raise TableMapError(f"{t.where}, columns {cols}: reflector {k + 2} {why}; an uncertainty, sensor or index "
                                "column is not a reflector: leave it out of points (if they are the position, the columns may be swapped: "
                                f"is position = {', '.join(m.position or [])} the rotation?)", file=t.where, column=m.points[k][0])


def read_mapped(path: str | Path, m: TableMap, robot=None, *, need_joints: bool = True, need_position: bool = True,
                allow_missing: bool = False, dof: int | None = None) -> MappedTable:
    """Read ``path`` with mapping ``m`` into SI arrays (:class:`MappedTable`).

    ``robot`` (optional) fixes the joint count and marks prismatic joints (length unit); ``dof`` (or
    ``m.dof``) fixes the joint count. ``allow_missing`` lets position/orientation cells be empty or
    NaN (a tracker stream losing the beam); joints never.
    """
    t = read_text_table(path, m)
    d = m.decimal
    jn = expand_joint_spec(m.joints, t.header, t.where) if m.joints is not None else []
    if need_joints and not jn:
        raise TableMapError(f"{t.where}: the mapping names no joint columns (joints = [...] / --joints)", file=t.where,
                            column="joints")
    if need_position and m.position is None:
        raise TableMapError(f"{t.where}: the mapping names no position columns (position = [x, y, z] / --position)",
                            file=t.where, column="position")
    ori = {"quaternion": m.quaternion, "euler": m.euler, "rotvec": m.rotvec}.get(m.orientation or "", None) or []
    pts = [c for p in m.points for c in p]
    roles = [(jn, "joints"), (m.position or [], "position"), (ori, m.orientation or ""), (pts, "points"),
             ([m.time] if m.time else [], "time"), ([m.temperature] if m.temperature else [], "temperature"),
             ([m.payload] if m.payload else [], "payload")]
    keep = m.keep_names()
    keep_all = "*" in keep
    keep.pop("*", None)
    roles.append((list(keep), "keep"))
    used: dict[str, str] = {}
    for names, role in roles:
        _require(t, names, role)
    check_orientation_names(m, t.where)
    for names, role in roles:
        for c in names:
            if c in used and role != "keep":
                raise t.error(None, c, f"is mapped twice (as {used[c]} and as {role})")
            used.setdefault(c, role)
    want = robot.dof if robot is not None else (dof if dof is not None else m.dof)
    if robot is not None and (dof or m.dof) not in (None, robot.dof):
        raise DatasetError(f"{t.where}: dof {dof or m.dof} given but robot {robot.name!r} has {robot.dof} joints", file=t.where)
    if jn and want is not None and len(jn) != want:
        who = f"robot {robot.name!r}" if robot is not None else f"dof = {want}"
        raise t.error(None, jn[-1], f"the mapping names {len(jn)} joint column(s) ({', '.join(jn)}) but {who} "
                      f"has {want} joints")
    rev = robot.revolute if robot is not None else np.ones(len(jn), bool)
    q_raw = _stack(t, jn, d) if jn else None
    if jn:
        _check_further_joints(t, jn, set(used), m, q_raw)
    xyz_raw = _stack(t, m.position, d, allow_missing) if m.position else None
    ang_raw = ang_unit = None
    if m.orientation in ("euler", "rotvec"):
        ang_raw = _stack(t, ori, d, allow_missing)
        ang_unit = m.euler_unit if m.orientation == "euler" else m.rotvec_unit
    pos_ok = None if xyz_raw is None else np.isfinite(xyz_raw).all(1)
    _unit_checks(t, m, q_raw, rev, None if xyz_raw is None else xyz_raw[pos_ok], ang_raw, ang_unit, ori, jn, m.position,
                 robot)
    L = LENGTH_UNITS_M[m.length_unit]
    q = None if q_raw is None else q_raw * np.where(rev, ANGLE_UNITS_RAD[m.angle_unit], L)
    xyz = None if xyz_raw is None else xyz_raw * L
    quat = _orientation(t, m, ori, ang_raw, allow_missing)
    P = np.stack([_stack(t, p, d, allow_missing) * L for p in m.points], axis=1) if m.points else np.zeros((len(t.rows), 0, 3))
    if pts and xyz is not None:
        check_lever_arms(t, m, xyz, P)
    time_s = _time_column(t, m) if m.time else None
    extra: dict[str, np.ndarray] = {}
    if m.temperature:
        tc = float_column(t, m.temperature, d)
        extra["temperature_c"] = {"C": tc, "K": tc - 273.15, "F": (tc - 32.0) * 5.0 / 9.0}[m.temperature_unit]
    if m.payload:
        extra["payload_kg"] = float_column(t, m.payload, d)
    if keep_all:
        keep.update({c: c for c in t.header if c not in used})
    for c, new in keep.items():  # labels (station, tool, pose_id, pose) as written: "01" and "1" are two stations
        extra[new] = kept_cells(t.col(c), d, label=new in LABEL_COLUMNS)
    return MappedTable(t, q, jn, xyz, quat, P, time_s, extra)


_ZERO_PADDED = re.compile(r"^\s*[+-]?0\d")


def kept_cells(cells: list[str], decimal: str = ".", *, label: bool = False) -> np.ndarray:
    """A kept column ``(N,)``: numbers (float64, a decimal comma read) when every cell is a number and none
    is zero-padded; otherwise, and for a label column (``label``), the cells as written (str, stripped of
    surrounding blanks): ids ``0000, 0001`` stay ``"0000", "0001"``, never ``0, 1``."""
    if label or any(_ZERO_PADDED.match(c) for c in cells):
        return label_cells(cells)
    return lenient_column(cells, decimal)


def _time_column(t: TextTable, m: TableMap) -> np.ndarray:
    """Time column in seconds: numbers in ``time_unit``, ISO 8601 date-times or ``time_format`` text
    (date-times as seconds since 1970, clock taken as UTC)."""
    if m.time_format:
        from datetime import datetime, timezone

        out = np.empty(len(t.rows))
        for r, c in enumerate(t.col(m.time)):
            try:
                out[r] = datetime.strptime(c, m.time_format).replace(tzinfo=timezone.utc).timestamp()
            except ValueError:
                raise t.error(r, m.time, f"{c!r} does not match time_format {m.time_format!r}") from None
        return out
    try:
        return float_column(t, m.time, m.decimal) * TIME_UNITS_S[m.time_unit]
    except DatasetError as e:
        cells = [c.replace(" ", "T", 1) for c in t.col(m.time)]
        try:
            stamps = np.array(cells, dtype="datetime64[ns]")
        except ValueError:
            raise e from None
        if np.isnat(stamps).any():
            raise t.error(int(np.argmax(np.isnat(stamps))), m.time, "empty time stamp") from None
        return (stamps - np.datetime64(0, "ns")).astype(np.int64) * 1e-9


def _orientation(t: TextTable, m: TableMap, cols: list[str], ang_raw, allow_missing: bool) -> np.ndarray | None:
    """Unit quaternions ``(N, 4)`` scalar first, ``qw >= 0`` (NaN rows kept NaN with allow_missing)."""
    if m.orientation is None:
        return None
    raw = _stack(t, cols, m.decimal, allow_missing) if m.orientation == "quaternion" else ang_raw
    ok = np.isfinite(raw).all(1)
    out = np.full((len(raw), 4), np.nan)
    if m.orientation == "quaternion":
        qv = raw[ok] if m.quaternion_order == "wxyz" else raw[ok][:, [3, 0, 1, 2]]
        norm = np.linalg.norm(qv, axis=1)
        bad = np.abs(norm - 1.0) > QUAT_NORM_TOL
        if bad.any():
            r = int(np.flatnonzero(ok)[np.argmax(bad)])
            raise t.error(r, ",".join(cols), f"quaternion norm is {norm[np.argmax(bad)]:.6g}, not 1: not a unit quaternion "
                          "(are these the right four columns?)")
        rot = Rotation.from_quat(qv, scalar_first=True)
    elif m.orientation == "euler":
        rot = Rotation.from_euler(euler_sequence(m, t.where), raw[ok], degrees=m.euler_unit == "deg")
    else:
        rot = Rotation.from_rotvec(raw[ok], degrees=m.rotvec_unit == "deg")
    out[ok] = rot.as_quat(canonical=True, scalar_first=True)
    return out


def _nest_pose(mt: MappedTable, m: TableMap) -> tuple[np.ndarray, np.ndarray]:
    """Poses (tool frame -> measurement frame) and fit RMS (m) from position + two points and the nest."""
    from ..geometry.rigid import pose_from_three_points

    t = mt.table
    if mt.points_m.shape[1] != 2 or m.orientation is not None:
        raise TableMapError(f"{t.where}: a nest needs position plus exactly two further points (three reflectors) and no "
                            f"orientation columns; the mapping has {1 + mt.points_m.shape[1]} point(s)", file=t.where,
                            column="nest")
    nest = np.asarray(m.nest, dtype=np.float64) * LENGTH_UNITS_M[m.nest_unit]
    try:
        T, rms = pose_from_three_points(mt.xyz_m, mt.points_m[:, 0], mt.points_m[:, 1], nest, return_residual=True)
    except ValueError as e:  # collinear nest or measured points
        raise DatasetError(f"{t.where}: {e}", file=t.where) from None
    bad = rms > m.max_fit_rms_mm * 1e-3
    if bad.any():
        r = int(np.argmax(bad))
        raise t.error(r, m.position[0], f"the three points do not fit the nest (RMS {rms[r] * 1e3:.3f} mm > "
                      f"{m.max_fit_rms_mm:.3f} mm): wrong nest geometry, reflector order or length unit?")
    return T, rms


def import_table(path: str | Path, m: TableMap | dict | str | Path, robot=None, *, dof: int | None = None) -> Dataset:
    """Import any table into a :class:`~hykin.io.dataset.Dataset` (SI) with mapping ``m``.

    Output columns: ``q1..qN`` (the mapped joints in order), ``x,y,z`` (position), ``qw..qz`` (from
    the quaternion, Euler angles or rotation vector, if mapped), ``x2,y2,z2, ...`` (further points),
    ``time_s``, ``temperature_c``, ``payload_kg`` and the kept columns. With ``m.nest`` the pose is
    the rigid fit of the nest onto position + two points (extra ``smr_fit_rms_m``). Validated as any
    dataset (with ``robot``: joint count, limits). ``m`` may also be a dict of mapping keys or the
    path of a mapping TOML file.
    """
    if isinstance(m, dict):
        m = table_map_from_dict(m)
    elif not isinstance(m, TableMap):
        m = load_table_map(m)
    mt = read_mapped(path, m, robot, dof=dof)
    t = mt.table
    extra = {}
    if mt.time_s is not None:
        extra["time_s"] = mt.time_s
    extra.update(mt.extra)
    if m.nest is not None:
        T, rms = _nest_pose(mt, m)
        extra["smr_fit_rms_m"] = rms
        ds = Dataset.from_poses(mt.q, T, extra=extra, source=t.where)
    else:
        for k in range(mt.points_m.shape[1]):
            for a in range(3):
                extra[f"{'xyz'[a]}{k + 2}"] = mt.points_m[:, k, a]
        ds = Dataset(q=mt.q, xyz_m=mt.xyz_m, quat_wxyz=mt.quat_wxyz, extra=extra, source=t.where)
    from ..io.dataset import POSITION_COLUMNS, QUAT_COLUMNS, joint_columns

    clash = set(ds.extra) & (set(joint_columns(ds.dof)) | set(POSITION_COLUMNS) | set(QUAT_COLUMNS))
    if clash:
        c = min(clash)
        raise TableMapError(f"{t.where}, column '{c}': a kept column has the name of a dataset column; rename it "
                            f"(keep = {{ {c} = \"{c}_raw\" }})", file=t.where, column=c)
    ds.meta = {"frame": "file's", "imported_from": t.where, "joint_columns": mt.joint_columns,
               "unit_check": bool(m.check_units), "unmapped_columns": _unmapped(t, m, mt)}
    try:
        validate(ds, robot, where=t.where, angle_unit=m.angle_unit, line_offset=None, unit_check=m.check_units)
    except DatasetError as e:
        if e.row is None:
            raise
        msg = str(with_file_line(e, t.lines))
        jm = re.fullmatch(r"q(\d+)", e.column or "")
        if jm and int(jm.group(1)) <= len(mt.joint_columns):
            msg = msg.replace(f"column '{e.column}'", f"column '{mt.joint_columns[int(jm.group(1)) - 1]}'", 1)
        raise DatasetError(msg, file=e.file, row=e.row, column=e.column) from None
    if robot is not None and m.check_units and ds.quat_wxyz is not None:
        # the orientation convention (Euler order, quaternion order) against the robot's rotations, as
        # calibrate and evaluate check it: a wrong one is refused before the file is written
        from .orientation_fit import check_imported_orientations

        euler = seq = None
        if m.orientation == "euler":
            euler = np.degrees(_stack(t, m.euler, m.decimal) * ANGLE_UNITS_RAD[m.euler_unit])
            seq = euler_sequence(m, t.where)
        check_imported_orientations(robot, ds, where=t.where, euler_deg=euler, euler_seq=seq)
    return ds


def _unmapped(t: TextTable, m: TableMap, mt: MappedTable) -> list[str]:
    """The file's columns the mapping neither maps, keeps nor ignores: left out of the dataset (the
    import says so: a station or tool column left out puts every row in one frame)."""
    if "*" in m.keep_names():
        return []
    ori = {"quaternion": m.quaternion, "euler": m.euler, "rotvec": m.rotvec}.get(m.orientation or "", None) or []
    named = (set(mt.joint_columns) | set(m.position or []) | set(ori) | {c for p in m.points for c in p}
             | {m.time, m.temperature, m.payload} | set(m.keep_names()) | set(m.ignore or []))
    return [c for c in t.header if c not in named and c.strip()]
