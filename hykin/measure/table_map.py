"""Column mappings for ``hykin import table``: which columns of a tracker/robot table hold what.

A :class:`TableMap` says, for any delimited text table, where the joints, the measured position, the
orientation (quaternion, Euler angles with a stated convention, or rotation vector), further
reflectors, time, temperature and payload are, in which units, and how the text is laid out
(delimiter, decimal comma, metadata lines, comments, rows to drop or filter). It is written as a
small TOML file (``--map``) and/or command-line options (options override the file); both go through
:func:`table_map_from_dict`, which refuses unknown keys with a did-you-mean.

:func:`suggest_map` guesses a mapping from a header by common column names, as TOML text for the
user to check and pass back: nothing is imported from a guess. See ``docs/import-table.md``.
"""

from __future__ import annotations

import difflib
import math
import re
from dataclasses import dataclass, field, fields
from pathlib import Path

from ..io.dataset import DatasetError
from .column_groups import quads as _quads
from .column_groups import rotation_triple as _rotation_triple
from .column_groups import triples as _triples
from .suggest_orientation import RAD_LOOKS_LIKE_DEG, orientation_lines

__all__ = [
    "ANGLE_UNITS_RAD",
    "LENGTH_UNITS_M",
    "TIME_UNITS_S",
    "TableMap",
    "TableMapError",
    "did_you_mean",
    "euler_sequence",
    "expand_joint_spec",
    "load_table_map",
    "never_position",
    "suggest_map",
    "table_map_from_dict",
]

#: metres per unit of the lengths a table may hold
LENGTH_UNITS_M = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "um": 1e-6, "in": 0.0254, "ft": 0.3048}
#: radians per unit
ANGLE_UNITS_RAD = {"rad": 1.0, "deg": math.pi / 180.0}
#: seconds per unit of a time column
TIME_UNITS_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "ns": 1e-9}
TEMPERATURE_UNITS = ("C", "K", "F")
DELIMITERS = {",": ",", ";": ";", "\t": "\t", "tab": "\t", "|": "|", " ": " ", "space": " ", "whitespace": " "}
#: Euler conventions by name: KUKA A, B, C = intrinsic Z, Y', X''; roll-pitch-yaw = extrinsic x, y, z (URDF)
EULER_ALIASES = {"kuka": "ZYX", "abc": "ZYX", "rpy": "xyz"}


class TableMapError(DatasetError):
    """A mapping that cannot be right (unknown key, wrong type, unknown unit, contradictory fields)."""


def did_you_mean(name: str, options) -> str:
    """``" (did you mean 'x'?)"`` for the closest of ``options`` (case-insensitive first), else ``""``."""
    options = [str(o) for o in options]
    low = {o.lower(): o for o in options}
    if name.lower() in low:
        return f" (did you mean {low[name.lower()]!r}?)"
    near = difflib.get_close_matches(name, options, n=1, cutoff=0.6)
    if not near:
        near = [low[m] for m in difflib.get_close_matches(name.lower(), list(low), n=1, cutoff=0.6)]
    return f" (did you mean {near[0]!r}?)" if near else ""


@dataclass
class TableMap:
    """Where a table's quantities are and in which units (the keys of a ``--map`` TOML file).

    joints: column names, base to tip, or a pattern: ``"joint_*"`` (``*`` = 1, 2, ... in numeric
        order, gaps refused) or ``"A1..A6"``. angle_unit: of revolute joints (``rad``/``deg``);
        prismatic joints (robot given) use length_unit.
    position: ``[x, y, z]`` columns of the measured point/TCP; length_unit: ``m mm cm um in ft``.
    Orientation, at most one of: quaternion (4 columns, quaternion_order ``wxyz``/``xyzw``);
        euler (3 columns, angles in the order of euler_convention: three axis letters, with
        euler_extrinsic true/false, or without it scipy's case rule (lowercase extrinsic, uppercase
        intrinsic); aliases ``kuka``/``abc`` = intrinsic ZYX, ``rpy`` = extrinsic xyz; euler_unit);
        rotvec (3 columns, axis·angle, rotvec_unit).
    points: further reflectors ``[[x2, y2, z2], ...]`` -> dataset columns ``x2,y2,z2, x3,...`` (m).
    nest: ``(3, 3)`` reflector positions in the tool frame (nest_unit) -> full pose from position +
        two points (three SMRs); max_fit_rms_mm bounds each row's fit residual.
    time (-> ``time_s``: numbers in time_unit, ISO 8601 date-times, or text in time_format, a
        ``strptime`` format such as ``"%Y%m%d%H%M%S"``; date-times as UTC seconds), temperature (-> ``temperature_c``, temperature_unit C/K/F),
        payload (-> ``payload_kg``); keep: further columns carried as written (numbers as numbers unless
        zero-padded, else text: :func:`hykin.measure.table_import.kept_cells`; list, ``["*"]`` =
        every unmapped column, or a table ``{column = "new_name"}``); ignore: columns the
        further-joint check should not complain about.
    Layout: delimiter (None = detect ``\\t ; , |`` else whitespace), decimal (``.``/``,``),
        skip_rows (lines above the header), header_row (1-based line of the header; 0 = no header,
        columns named ``"1", "2", ...``; skip_rows and drop_rows still apply), group_rows (1-based
        lines above the header whose labels are joined in front of names that repeat or are empty:
        Motive's ``"Tool Rotation X"``; None = found when names repeat, ``[]`` = none), comment (lines starting with it are skipped), drop_rows
        (1-based file lines), where (row filters ``"col op value"``, op in ``== != < <= > >=``,
        all must hold), encoding (None = UTF-8, else cp1252).
    dof: expected joint count; check_units: refuse values that look like the wrong unit.
    lever_arm_m: ``[min, max]`` distance (m) of a further reflector (``points``) from the first: a
        second reflector on the same rigid tool keeps a distance in this range, roughly constant over
        the rows (:func:`hykin.measure.table_import.check_lever_arms`).
    """

    joints: list[str] | str | None = None
    angle_unit: str = "rad"
    position: list[str] | None = None
    length_unit: str = "m"
    quaternion: list[str] | None = None
    quaternion_order: str = "wxyz"
    euler: list[str] | None = None
    euler_convention: str | None = None
    euler_extrinsic: bool | None = None
    euler_unit: str = "rad"
    rotvec: list[str] | None = None
    rotvec_unit: str = "rad"
    points: list[list[str]] = field(default_factory=list)
    nest: list[list[float]] | None = None
    nest_unit: str = "m"
    max_fit_rms_mm: float = 1.0
    time: str | None = None
    time_unit: str = "s"
    time_format: str | None = None
    temperature: str | None = None
    temperature_unit: str = "C"
    payload: str | None = None
    keep: list[str] | dict[str, str] = field(default_factory=list)
    ignore: list[str] = field(default_factory=list)
    delimiter: str | None = None
    decimal: str = "."
    skip_rows: int = 0
    header_row: int | None = None
    group_rows: list[int] | None = None
    comment: str | None = None
    drop_rows: list[int] = field(default_factory=list)
    where: list[str] = field(default_factory=list)
    encoding: str | None = None
    dof: int | None = None
    check_units: bool = True
    lever_arm_m: list[float] = field(default_factory=lambda: [0.003, 2.0])

    @property
    def orientation(self) -> str | None:
        """``"quaternion"``, ``"euler"``, ``"rotvec"`` or None."""
        for k in ("quaternion", "euler", "rotvec"):
            if getattr(self, k) is not None:
                return k
        return None

    def keep_names(self) -> dict[str, str]:
        """``{column: output name}`` of the kept columns (``"*"`` left to the reader)."""
        return dict(self.keep) if isinstance(self.keep, dict) else {c: c for c in self.keep}


KEYS = tuple(f.name for f in fields(TableMap))
_STR_LISTS = {"position": 3, "quaternion": 4, "euler": 3, "rotvec": 3}
_CHOICES = {
    "angle_unit": tuple(ANGLE_UNITS_RAD), "euler_unit": tuple(ANGLE_UNITS_RAD), "rotvec_unit": tuple(ANGLE_UNITS_RAD),
    "length_unit": tuple(LENGTH_UNITS_M), "nest_unit": tuple(LENGTH_UNITS_M), "time_unit": tuple(TIME_UNITS_S),
    "temperature_unit": TEMPERATURE_UNITS, "quaternion_order": ("wxyz", "xyzw"), "decimal": (".", ","),
}


def _names(where: str, key: str, v, n: int | None = None) -> list[str]:
    if isinstance(v, str):
        v = [s.strip() for s in v.split(",")]
    if not isinstance(v, (list, tuple)) or not all(isinstance(s, str) and s for s in v):
        raise TableMapError(f"{where}: {key} must be a list of column names, got {v!r}", file=where, column=key)
    if n is not None and len(v) != n:
        raise TableMapError(f"{where}: {key} needs {n} column names, got {len(v)} ({', '.join(v)})", file=where, column=key)
    return list(v)


def table_map_from_dict(d: dict, where: str = "<mapping>") -> TableMap:
    """Validate a mapping (TOML document or CLI options, same keys) into a :class:`TableMap`.

    Unknown keys, wrong types, unknown units and contradictions raise :class:`TableMapError`.
    """
    unknown = [k for k in d if k not in KEYS]
    if unknown:
        k = unknown[0]
        raise TableMapError(f"{where}: unknown mapping key {k!r}{did_you_mean(k, KEYS)}; known keys: {', '.join(KEYS)}",
                            file=where, column=k)
    kw = {}
    for k, v in d.items():
        if v is None:
            continue
        if k in _STR_LISTS:
            v = _names(where, k, v, _STR_LISTS[k])
        elif k == "joints":
            v = v.strip() if isinstance(v, str) and ("*" in v or ".." in v) else _names(where, k, v)
        elif k == "points":
            if not isinstance(v, (list, tuple)):
                raise TableMapError(f"{where}: points must be a list of [x, y, z] column triples", file=where, column=k)
            v = [_names(where, f"points[{i}]", p, 3) for i, p in enumerate(v)]
        elif k in ("keep", "ignore", "where"):
            if isinstance(v, str):
                v = [v] if k == "where" else [s.strip() for s in v.split(",") if s.strip()]
            if k == "keep" and isinstance(v, dict):
                if not all(isinstance(a, str) and isinstance(b, str) and b for a, b in v.items()):
                    raise TableMapError(f"{where}: keep as a table maps column names to new names (strings)", file=where, column=k)
            elif not isinstance(v, (list, tuple)) or not all(isinstance(s, str) for s in v):
                raise TableMapError(f"{where}: {k} must be a list of strings, got {v!r}", file=where, column=k)
            v = dict(v) if isinstance(v, dict) else list(v)
        elif k in ("drop_rows", "group_rows"):
            if isinstance(v, str):
                v = [s.strip() for s in v.split(",") if s.strip()]
            try:
                v = [int(x) for x in v]
            except (TypeError, ValueError):
                raise TableMapError(f"{where}: {k} must be a list of 1-based line numbers, got {v!r}",
                                    file=where, column=k) from None
        elif k in ("skip_rows", "header_row", "dof"):
            if isinstance(v, bool) or not isinstance(v, int) or v < 0 or (k == "dof" and v < 1):
                raise TableMapError(f"{where}: {k} must be a {'positive' if k == 'dof' else 'non-negative'} integer, got {v!r}",
                                    file=where, column=k)
        elif k in ("euler_extrinsic", "check_units"):
            if not isinstance(v, bool):
                raise TableMapError(f"{where}: {k} must be true or false, got {v!r}", file=where, column=k)
        elif k == "lever_arm_m":
            ok = isinstance(v, (list, tuple)) and len(v) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
            if not ok or not 0 <= v[0] < v[1]:
                raise TableMapError(f"{where}: lever_arm_m must be [min, max] in metres with 0 <= min < max, got {v!r}",
                                    file=where, column=k)
            v = [float(x) for x in v]
        elif k == "max_fit_rms_mm":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not v > 0:
                raise TableMapError(f"{where}: {k} must be a positive number, got {v!r}", file=where, column=k)
            v = float(v)
        elif k == "nest":
            try:
                import numpy as np

                arr = np.asarray(v, dtype=np.float64)
            except (TypeError, ValueError):
                arr = None
            if arr is None or arr.shape != (3, 3) or not np.isfinite(arr).all():
                raise TableMapError(f"{where}: nest must be three [x, y, z] reflector positions in the tool frame, got {v!r}",
                                    file=where, column=k)
            v = arr.tolist()
        elif k == "delimiter":
            if v not in DELIMITERS:
                raise TableMapError(f"{where}: delimiter must be one of ',', ';', 'tab', '|', 'whitespace', got {v!r}",
                                    file=where, column=k)
            v = DELIMITERS[v]
        elif k == "temperature_unit" and isinstance(v, str):
            v = v.upper().lstrip("°")
        elif k in ("euler_convention",) and isinstance(v, str):
            v = v.strip()
        if k in _CHOICES and v not in _CHOICES[k]:
            raise TableMapError(f"{where}: {k} must be one of {', '.join(map(repr, _CHOICES[k]))}, got {v!r}"
                                f"{did_you_mean(str(v), _CHOICES[k])}", file=where, column=k)
        if k in ("time", "time_format", "temperature", "payload", "comment", "encoding", "euler_convention") and not isinstance(v, str):
            raise TableMapError(f"{where}: {k} must be a string, got {v!r}", file=where, column=k)
        kw[k] = v
    m = TableMap(**kw)
    given = [k for k in ("quaternion", "euler", "rotvec") if getattr(m, k) is not None]
    if len(given) > 1:
        raise TableMapError(f"{where}: give one orientation (quaternion, euler or rotvec), not {' and '.join(given)}", file=where)
    if m.euler is not None:
        euler_sequence(m, where)  # fail early on a bad convention
    if m.header_row is not None and m.header_row > 0 and m.skip_rows and m.header_row != m.skip_rows + 1:
        raise TableMapError(f"{where}: header_row = {m.header_row} contradicts skip_rows = {m.skip_rows} "
                            f"(the header would be line {m.skip_rows + 1}); give one of them", file=where)
    return m


def load_table_map(path: str | Path, overrides: dict | None = None) -> TableMap:
    """Read a ``--map`` TOML file; ``overrides`` (CLI options, same keys) replace its values."""
    from ..io.toml_compat import tomllib

    where = str(path)
    p = Path(path)
    if not p.is_file():
        raise TableMapError(f"{where}: mapping file not found", file=where)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise TableMapError(f"{where}: not a valid TOML file ({e})", file=where) from None
    doc.update({k: v for k, v in (overrides or {}).items() if v is not None})
    return table_map_from_dict(doc, where)


def euler_sequence(m: TableMap, where: str = "<mapping>") -> str:
    """The scipy Euler sequence of ``m`` (uppercase = intrinsic, lowercase = extrinsic)."""
    conv = m.euler_convention
    if conv is None:
        raise TableMapError(f"{where}: euler columns need euler_convention (e.g. \"xyz\" with euler_extrinsic = true, "
                            "\"kuka\" for A,B,C = intrinsic Z,Y',X'', \"rpy\" = extrinsic x,y,z)", file=where,
                            column="euler_convention")
    if conv.lower() in EULER_ALIASES:
        seq = EULER_ALIASES[conv.lower()]
        if m.euler_extrinsic is not None and m.euler_extrinsic != seq.islower():
            raise TableMapError(f"{where}: euler_convention {conv!r} is {'extrinsic' if seq.islower() else 'intrinsic'}; "
                                "drop euler_extrinsic", file=where, column="euler_extrinsic")
        return seq
    if len(conv) != 3 or set(conv.lower()) - set("xyz") or conv[0].lower() == conv[1].lower() or conv[1].lower() == conv[2].lower():
        raise TableMapError(f"{where}: euler_convention {conv!r} is not three axis letters like 'xyz' or 'zyz' "
                            "(nor 'kuka' or 'rpy')", file=where, column="euler_convention")
    if m.euler_extrinsic is not None:
        return conv.lower() if m.euler_extrinsic else conv.upper()
    if not (conv.islower() or conv.isupper()):
        raise TableMapError(f"{where}: euler_convention {conv!r} mixes cases; state euler_extrinsic = true or false",
                            file=where, column="euler_convention")
    return conv


def expand_joint_spec(spec, header: list[str], where: str = "<table>") -> list[str]:
    """Joint column names from a list, a ``prefix*suffix`` pattern (``*`` = 1, 2, ... consecutive)
    or an ``A1..A6`` range."""
    if isinstance(spec, list):
        return spec
    if ".." in spec:
        m = re.fullmatch(r"(.*?)(\d+)\.\.(.*?)(\d+)(.*)", spec)
        if not m or m.group(1) != m.group(3) or int(m.group(2)) > int(m.group(4)):
            raise TableMapError(f"{where}: joints range {spec!r} must look like 'A1..A6'", file=where, column="joints")
        return [f"{m.group(1)}{k}{m.group(5)}" for k in range(int(m.group(2)), int(m.group(4)) + 1)]
    if spec.count("*") != 1:
        raise TableMapError(f"{where}: joints pattern {spec!r} needs exactly one '*'", file=where, column="joints")
    pre, post = spec.split("*")
    rx = re.compile(re.escape(pre) + r"(\d+)" + re.escape(post))
    found = sorted((int(m.group(1)), h) for h in header if (m := rx.fullmatch(h)))
    if not found:
        raise TableMapError(f"{where}: no column matches the joints pattern {spec!r} (header: {', '.join(header)})",
                            file=where, column="joints")
    nums = [k for k, _ in found]
    if nums != list(range(nums[0], nums[0] + len(nums))):
        raise TableMapError(f"{where}: the columns matching {spec!r} are not consecutively numbered "
                            f"({', '.join(h for _, h in found)}); list the joints explicitly", file=where, column="joints")
    return [h for _, h in found]


# --------------------------------------------------------------------------- suggestion

_JOINT_RX = re.compile(r"(?i)^(q|joint|jnt|j|a|axis|achse|axe|gelenk|theta|ax)[ _\-]?(\d+)(?:[ _\-]?[\[(]?(deg|rad)[\])]?)?$")
_NOT_MEASURED = re.compile(r"(?i)goal|target|cmd|command|nominal|std|sigma|dif|err|_t$|(^|_)t_|set|desired|flange|vel|speed")
# Never a measured position, reflector or joint, whatever else the name says: uncertainties (U95,
# unc, std, sigma, err, rms, mpe, tol), sensors (accelerometer, gyro, IMU, temperature, humidity,
# pressure, force, torque, current, voltage, velocity) and index / time columns.
_NEVER_POSITION = re.compile(
    r"(?i)(?<![a-z])u\d{2}(?!\d)|(?<![a-z])(unc|uncert|uncertainty|std|stdev|sigma|err|error|rms|mpe|tol|acc|accel|"
    r"accelerometer|acceleration|gyro|imu|temp|temperature|humid|humidity|press|pressure|force|torque|curr|current|volt|"
    r"voltage|vel|velocity|speed|idx|index|id|count|sample|row|nr|no|time|timestamp|stamp)[xyz]?(?![a-z])")


def never_position(name: str) -> bool:
    """True for a column name that is an uncertainty, a sensor, an index or a time column (see
    ``_NEVER_POSITION``): never suggested as a position, a further reflector or a joint."""
    tokens = re.sub(r"([a-z])([A-Z])", r"\1 \2", name)  # AccX -> Acc X: camelCase words are separate
    return bool(_NEVER_POSITION.search(tokens))


def _unit_in_name(name: str, units: dict) -> str | None:
    """A unit written into a column name: ``X [mm]``, ``x_mm``, ``A1 (deg)``, ``A1 [°]``."""
    if "°" in name:
        return "deg" if "deg" in units else None
    toks = re.findall(r"[A-Za-z]+", name)
    for tok in re.findall(r"[\[(]\s*([A-Za-z]+)\s*[\])]", name) + toks[-1:] * (len(toks) > 1):
        if tok.lower() in units:
            return tok.lower()
    return None


def _toml_list(names) -> str:
    return "[" + ", ".join('"' + c + '"' for c in names) + "]"


def suggest_map(header: list[str], sample_rows: list[list[str]] | None = None, *, delimiter: str | None = None,
                decimal: str = ".", skip_rows: int = 0, group_rows: list[int] | None = None,
                drop_rows: list[int] | None = None, units: dict[str, str] | None = None,
                header_row: int | None = None) -> str:
    """A suggested mapping (TOML text with comments) for ``header``; every guess is marked CHECK.

    ``sample_rows`` (a few data rows as text) let it guess units from magnitudes; ``units`` (column ->
    unit, from a units line under the header, dropped by ``drop_rows``) name them. ``group_rows``: the
    lines above the header whose labels were joined into repeated names (Motive), printed back.
    """
    rows = sample_rows or []
    units = {c: u for c, u in (units or {}).items() if u}

    def values(col, signed=False):
        i = header.index(col)
        out = []
        for r in rows:
            try:
                v = float(r[i].replace(decimal, "."))
                out.append(v if signed else abs(v))
            except (ValueError, IndexError):
                pass
        return out

    def unit_of(col, table):
        u = units.get(col, "").lower().strip("[]()")
        u = {"°": "deg", "degree": "deg", "degrees": "deg", "radian": "rad", "radians": "rad", "µm": "um"}.get(u, u)
        return u if u in table else None

    lines = ["# hykin import table: suggested mapping. CHECK every line, then pass it with --map.",
             f"# header: {', '.join(header)}"]
    if delimiter is not None:
        lines.append(f"delimiter = {({chr(9): 'tab', ' ': 'whitespace'}).get(delimiter, delimiter)!r}".replace("'", '"'))
    if decimal != ".":
        lines.append(f'decimal = "{decimal}"')
    if header_row:
        lines.append(f"header_row = {header_row}")
    elif skip_rows:
        lines.append(f"skip_rows = {skip_rows}")
    if header_row == 0:
        lines.append("header_row = 0  # no header: columns named 1, 2, ...")
    if group_rows:
        lines.append(f"group_rows = {list(group_rows)}  # lines above the header naming the groups of repeated "
                     "names (joined in front: the names above)")
    if drop_rows:
        lines.append(f"drop_rows = {list(drop_rows)}  # the units line under the header")
    quads = _quads(header, values)
    in_quad = {c for qd in quads for c in qd}
    fams: dict[str, list[tuple[int, str, str | None]]] = {}
    for h in header:
        m = None if never_position(h) or h in in_quad else _JOINT_RX.match(h)
        if m:
            fams.setdefault(m.group(1).lower(), []).append((int(m.group(2)), h, m.group(3)))
    ros = [h for h in header if re.search(r"(?i)_joint$", h)]
    joints, unit_hint = [], None
    if fams:
        best = max(fams.values(), key=len)
        best.sort()
        joints = [h for _, h, _ in best]
        unit_hint = next((u.lower() for _, _, u in best if u), None)
    elif ros:
        joints = ros
    if joints:
        lines.append(f"joints = {_toml_list(joints)}  # CHECK order base to tip")
        big = max((v for j in joints for v in values(j)), default=0.0)
        named = unit_of(joints[0], ANGLE_UNITS_RAD)
        unit_hint = unit_hint or _unit_in_name(joints[0], ANGLE_UNITS_RAD)
        unit = named or unit_hint or ("deg" if big > RAD_LOOKS_LIKE_DEG else "rad")
        why = ("from the units line" if named else "from the column names" if unit_hint else
               f"largest value {big:.4g}" if rows else "no data seen")
        lines.append(f'angle_unit = "{unit}"  # CHECK ({why})')
    else:
        lines.append('# joints = ["J1", "J2", ...]  # no joint columns recognised')
    all_trips = _triples([h for h in header if h not in joints and h not in in_quad])
    rot = [t for t in all_trips if _rotation_triple(t) and not _NOT_MEASURED.search(t[0]) and not never_position(t[0])]
    trips = [t for t in all_trips if not any(never_position(c) for c in t) and not _rotation_triple(t)]
    meas = [t for t in trips if not _NOT_MEASURED.search(t[0])] or trips
    vicon = "Sub Frame" in header and bool(rot)  # Vicon Nexus: RX, RY, RZ are helical angles (a rotation vector)
    ori_lines = orientation_lines(header, quads, rot, vicon, values, unit_of, ANGLE_UNITS_RAD)
    has_ori = any(not ln.startswith("#") for ln in ori_lines)  # an orientation mapped: the pose is complete
    if meas:
        pos, rest = meas[0], [t for t in meas[1:]]
        lines.append(f"position = {_toml_list(pos)}  # CHECK")
        big = max((math.sqrt(sum(v * v for v in r)) for r in zip(*(values(c) for c in pos))), default=0.0)
        from_line = unit_of(pos[0], LENGTH_UNITS_M)
        named = from_line or _unit_in_name(pos[0], LENGTH_UNITS_M)
        why = ("from the units line" if from_line else "from the column names" if named else
               f"largest distance {big:.4g}" if rows else "no data seen")
        lines.append(f'length_unit = "{named or ("mm" if big > 50 else "m")}"  # CHECK ({why})')
        pts = [t for t in rest if not _NOT_MEASURED.search(t[0])]
        if pts and has_ori:
            lines.append("# further reflectors / markers (the pose is complete without them; their cells must never be "
                         "empty, a lost marker's are):")
            lines.append("# points = [" + ", ".join(_toml_list(t) for t in pts) + "]")
        elif pts:
            lines.append("points = [" + ", ".join(_toml_list(t) for t in pts) + "]  # CHECK further reflectors")
    else:
        lines.append('# position = ["X", "Y", "Z"]  # no position columns recognised')
    lines += ori_lines
    for h in header:
        if re.search(r"(?i)temp", h):
            lines.append(f'temperature = "{h}"  # -> temperature_c; temperature_unit = "C"')
            break
    keep = {}  # label columns (names as written): a station / tool per row, a pose id for ISO cycles
    for h in header:
        n = h.strip()
        if re.fullmatch(r"(?i)(station|stn|setup|tracker[ _]?(station|position|pos))([ _]?(id|no|name))?", n):
            keep.setdefault("station", h)
        elif re.fullmatch(r"(?i)(tool|tcp|smr|nest|reflector)([ _]?(id|no|name))?", n):
            keep.setdefault("tool", h)
        elif re.fullmatch(r"(?i)(pt|point|pose|pose[ _]?id|point[ _]?(id|name))", n):
            keep.setdefault("pose_id", h)
        elif re.fullmatch(r"(?i)(load|payload|mass)\s*([\[(]\s*kg\s*[\])])?", n):
            lines.append(f'payload = "{h}"  # -> payload_kg (kg) CHECK')
    if keep:
        items = ", ".join(f'"{h}" = "{k}"' for k, h in keep.items())
        lines.append(f"keep = {{ {items} }}  # CHECK: labels kept as text ({', '.join(keep)})")
    for h in header:
        if re.fullmatch(r"(?i)(time|timestamp|t)([ _]?(s|\(s\)|\[s\]|\(seconds\)|sec))?", h):
            lines.append(f'# time = "{h}"  # -> time_s, for `hykin import stream`; time_unit = "s"')
            break
    return "\n".join(lines) + "\n"
