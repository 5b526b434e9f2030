"""``hykin import ...``: measured data into the standard dataset format (DESIGN.md §3-4).

``ur5`` and ``ipa`` read the two public datasets (fixed layouts, refused when a file holds anything
else); ``table`` reads any table through a column mapping (``--map`` TOML and/or options,
``--suggest`` proposes one); ``three-smr`` fits the full pose from three reflectors; ``stream``
aligns a robot joint log with a tracker stream.
"""

from __future__ import annotations

from pathlib import Path

import typer

from .common import BaseLink, CLIError, Force, TipLink, app, check_output

import_app = typer.Typer(no_args_is_help=True, help="Import measured data into the standard dataset format.")
app.add_typer(import_app, name="import")


def _write(ds, out: Path, inputs, what: str = "") -> None:
    from ..io.dataset_files import write_dataset

    write_dataset(ds, out)
    left = ds.meta.get("unmapped_columns") or []
    if left:  # said, not silent: a station, tool or payload column left out changes what the rows mean
        from ..measure.suggest_orientation import orientation_like_columns
        from .common import console

        ori = [] if ds.has_orientation else orientation_like_columns(left)
        if ori:  # an orientation left out makes the data position only: said in so many words
            console().print(f"note: columns {', '.join(ori)} look like an orientation but are not mapped: the dataset is "
                            "position only (map them with rotvec = [..] / euler = [..] / quaternion = [..] in the mapping, "
                            "or --rotvec / --euler / --quaternion)", highlight=False)
        console().print(f"note: columns not mapped, left out: {', '.join(left)} (keep = [..] in the mapping, or "
                        "--keep C,.., carries them; a station / tool column gives each row its frame, a load "
                        "column maps with payload)", highlight=False)
    frame = ds.meta.get("frame", "robot base")
    typer.echo(f"wrote {len(ds)} samples ({ds.dof} joints{', with orientation' if ds.has_orientation else ', position only'}"
               f"{what}) to {out} (poses in the {frame} frame)")


# --------------------------------------------------------------------------- fixed layouts

RobotOut = typer.Option(None, "--robot-out", help="Also write the nominal robot file matching this data (tool/TCP of the setup).")
Out = typer.Option(..., "-o", "--out", help="Output dataset in the standard format (.csv/.parquet).")


@import_app.command("ur5")
def import_ur5_cmd(
    path: Path = typer.Argument(..., help="serial-robots-ur5 CSV (joint_1..joint_6, x_t.., x_dif..)."),
    out: Path = Out,
    robot_out: Path | None = RobotOut,
    force: bool = Force,
) -> None:
    """Import a serial-robots-ur5 CSV (exactly six joints; anything else: `hykin import table`)."""
    from ..measure.importers import import_ur5, ur5_robot_for_dataset

    _import_fixed(path, out, robot_out, force, lambda: import_ur5(path), ur5_robot_for_dataset)


@import_app.command("ipa")
def import_ipa_cmd(
    path: Path = typer.Argument(..., help="ipa-robot-accuracy Series_X folder or its measurements_*.csv."),
    out: Path = Out,
    register: bool = typer.Option(
        False, "--register/--tracker-frame",
        help="Express poses in the robot base by a rigid base+tool fit of the nominal UR10 (default: keep the tracker frame).",
    ),
    robot_out: Path | None = RobotOut,
    force: bool = Force,
) -> None:
    """Import an ipa-robot-accuracy series (UR10, laser tracker + T-Mac)."""
    from ..measure.importers import import_ipa_series, ipa_nominal_robot

    _import_fixed(path, out, robot_out, force,
                  lambda: import_ipa_series(path, register_to=ipa_nominal_robot() if register else None), ipa_nominal_robot)


def _import_fixed(path: Path, out: Path, robot_out: Path | None, force: bool, read, nominal_robot) -> None:
    """A fixed-layout import: outputs checked first, then ``read()`` -> dataset, and the set-up's nominal
    robot (``nominal_robot()``) written to ``robot_out`` when asked."""
    from ..io.robot_toml import save_robot_toml

    check_output(out, (path,), force)
    if robot_out is not None:
        check_output(robot_out, (path, out), force)
    ds = read()
    _write(ds, out, [path])
    if robot_out is not None:
        save_robot_toml(nominal_robot(), robot_out)
        typer.echo(f"wrote the matching nominal robot to {robot_out}")


# --------------------------------------------------------------------------- mapped tables

MapOpt = typer.Option(None, "--map", help="Mapping TOML (docs/import-table.md); options below override its keys.")
JointsOpt = typer.Option(None, "--joints", help="Joint columns base to tip: 'J1,J2,...', a pattern 'joint_*' or a range 'A1..A6'.")
AngleOpt = typer.Option(None, "--angle-unit", help="Unit of the joint columns: rad or deg (default rad).")
PositionOpt = typer.Option(None, "--position", help="Position columns 'X,Y,Z'.")
LengthOpt = typer.Option(None, "--length-unit", help="Unit of positions: m, mm, cm, um, in, ft (default m).")
PointOpt = typer.Option(None, "--point", help="Further reflector columns 'X2,Y2,Z2' (repeat for more) -> x2,y2,z2, ...")
DelimOpt = typer.Option(None, "--delimiter", help="',', ';', 'tab', '|' or 'whitespace' (default: detected from the header line).")
DecimalOpt = typer.Option(None, "--decimal", help="Decimal separator: '.' or ','.")
SkipOpt = typer.Option(None, "--skip-rows", help="Lines above the header (metadata).")
HeaderOpt = typer.Option(None, "--header-row", help="1-based line of the header (0: no header, columns named 1, 2, ...).")
CommentOpt = typer.Option(None, "--comment", help="Lines starting with this are skipped.")
DofOpt = typer.Option(None, "--dof", help="Expected number of joints (checked against the mapping).")
RobotOpt = typer.Option(None, "--robot", help="Robot file/preset: joint count, prismatic joints, limits checked.")
UnitCheckOpt = typer.Option(None, "--unit-check/--no-unit-check", help="Refuse values that look like another unit (default on).")


def _csv_names(s: str | None):
    return None if s is None else [c.strip() for c in s.split(",")]


def _joint_spec(s: str | None):
    if s is None:
        return None
    return s.strip() if ("*" in s or ".." in s) else _csv_names(s)


def _build_map(map_path: Path | None, opts: dict):
    from ..measure.table_map import load_table_map, table_map_from_dict

    opts = {k: v for k, v in opts.items() if v is not None and v != []}
    if map_path is not None:
        return load_table_map(map_path, opts)
    return table_map_from_dict(opts, "command line")


def _robot(spec: str | None, base: str | None = None, tip: str | None = None):
    if spec is None:
        if base is not None or tip is not None:
            raise CLIError("--base/--tip name links of the --robot URDF; give --robot")
        return None
    from .common import load_model_or_robot

    return load_model_or_robot(spec, base, tip)[1]


@import_app.command("table")
def import_table_cmd(
    path: Path = typer.Argument(..., help="Delimited text table (any tracker/robot export)."),
    out: Path | None = typer.Option(None, "-o", "--out", help="Output dataset (.csv/.parquet)."),
    map_path: Path | None = MapOpt,
    suggest: bool = typer.Option(False, "--suggest", help="Print the header and a suggested mapping TOML; import nothing."),
    joints: str | None = JointsOpt,
    angle_unit: str | None = AngleOpt,
    position: str | None = PositionOpt,
    length_unit: str | None = LengthOpt,
    quaternion: str | None = typer.Option(None, "--quaternion", help="Quaternion columns, in quaternion-order."),
    quaternion_order: str | None = typer.Option(None, "--quaternion-order", help="wxyz (scalar first) or xyzw."),
    euler: str | None = typer.Option(None, "--euler", help="Euler angle columns, in the order of --euler-convention."),
    euler_convention: str | None = typer.Option(
        None, "--euler-convention", help="Axis letters, e.g. xyz, zyx, zyz (case: scipy's, lowercase extrinsic), or kuka / rpy."),
    euler_extrinsic: bool | None = typer.Option(None, "--euler-extrinsic/--euler-intrinsic", help="Rotations about fixed / moving axes."),
    euler_unit: str | None = typer.Option(None, "--euler-unit", help="rad or deg (default rad)."),
    rotvec: str | None = typer.Option(None, "--rotvec", help="Rotation-vector (axis·angle) columns."),
    rotvec_unit: str | None = typer.Option(None, "--rotvec-unit", help="rad or deg (default rad)."),
    point: list[str] | None = PointOpt,
    time: str | None = typer.Option(None, "--time", help="Time column -> time_s."),
    time_unit: str | None = typer.Option(None, "--time-unit", help="s, ms, us or ns."),
    temperature: str | None = typer.Option(None, "--temperature", help="Temperature column -> temperature_c."),
    temperature_unit: str | None = typer.Option(None, "--temperature-unit", help="C, K or F."),
    payload: str | None = typer.Option(None, "--payload", help="Payload mass column (kg) -> payload_kg."),
    keep: list[str] | None = typer.Option(None, "--keep", help="Further columns to carry as written (zero-padded ids and text as text; '*' = all unmapped; repeatable)."),
    ignore: str | None = typer.Option(None, "--ignore", help="Columns that look like joints but are not (comma-separated)."),
    delimiter: str | None = DelimOpt,
    decimal: str | None = DecimalOpt,
    skip_rows: int | None = SkipOpt,
    header_row: int | None = HeaderOpt,
    group_rows: str | None = typer.Option(
        None, "--group-rows", help="1-based lines above the header naming column groups, joined in front of repeated "
        "names (Motive/Vicon multi-line headers; default: found when names repeat)."),
    comment: str | None = CommentOpt,
    drop_rows: str | None = typer.Option(None, "--drop-rows", help="1-based file lines to drop, comma-separated (e.g. a units line)."),
    where: list[str] | None = typer.Option(None, "--where", help="Row filter 'column op value' (== != < <= > >=); repeat to AND."),
    encoding: str | None = typer.Option(None, "--encoding", help="Text encoding (default UTF-8, falling back to cp1252)."),
    dof: int | None = DofOpt,
    robot: str | None = RobotOpt,
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    unit_check: bool | None = UnitCheckOpt,
    force: bool = Force,
) -> None:
    """Import any table into the standard dataset through a column mapping (see docs/import-table.md)."""
    opts = dict(
        joints=_joint_spec(joints), angle_unit=angle_unit, position=_csv_names(position), length_unit=length_unit,
        quaternion=_csv_names(quaternion), quaternion_order=quaternion_order, euler=_csv_names(euler),
        euler_convention=euler_convention, euler_extrinsic=euler_extrinsic, euler_unit=euler_unit,
        rotvec=_csv_names(rotvec), rotvec_unit=rotvec_unit, points=[_csv_names(p) for p in point or []],
        time=time, time_unit=time_unit, temperature=temperature, temperature_unit=temperature_unit, payload=payload,
        keep=[c for k in keep or [] for c in _csv_names(k)], ignore=_csv_names(ignore), delimiter=delimiter,
        decimal=decimal, skip_rows=skip_rows, header_row=header_row, group_rows=_csv_names(group_rows), comment=comment,
        drop_rows=_csv_names(drop_rows), where=list(where or []), encoding=encoding, dof=dof, check_units=unit_check,
    )
    if suggest:
        _suggest(path, map_path, opts)
        return
    if out is None:
        raise CLIError("import table: give -o OUT (or --suggest to see a suggested mapping)")
    if map_path is None and opts["joints"] is None and opts["position"] is None:
        raise CLIError(f"{path}: no column mapping given; `hykin import table {path} --suggest` prints the header and a "
                       "suggested mapping to check and pass with --map")
    from ..measure.table_import import import_table

    check_output(out, (path, map_path), force)
    m = _build_map(map_path, opts)
    ds = import_table(path, m, _robot(robot, base_link, tip_link))
    _write(ds, out, [path, map_path], f", orientation from {m.orientation}" if m.orientation else "")


def _suggest(path: Path, map_path: Path | None, opts: dict) -> None:
    from ..measure.table_import import guess_layout, read_text_table
    from ..measure.table_map import suggest_map

    layout = {k: opts[k] for k in ("delimiter", "decimal", "skip_rows", "header_row", "group_rows", "comment", "encoding",
                                   "drop_rows")}
    m = _build_map(map_path, layout)
    guessed = {}
    if all(layout[k] is None for k in ("skip_rows", "header_row")) and map_path is None:
        guessed = guess_layout(path, m)
        m = _build_map(None, {**layout, **{k: v for k, v in guessed.items() if layout.get(k) is None and k != "units"}})
    t = read_text_table(path, m)
    typer.echo(suggest_map(t.header, t.rows[:50], delimiter=t.delimiter, decimal=m.decimal,
                           skip_rows=m.skip_rows, group_rows=t.group_lines,
                           drop_rows=m.drop_rows, units=dict(zip(t.header, guessed.get("units") or [])),
                           header_row=m.header_row), nl=False)


# --------------------------------------------------------------------------- three SMRs


def _parse_nest(spec: str):
    """``"x,y,z; x,y,z; x,y,z"`` or a TOML file with ``nest`` (and ``nest_unit``) -> (nest, unit or None)."""
    p = Path(spec)
    if p.suffix.lower() == ".toml" or p.is_file():
        from ..io.toml_compat import tomllib

        try:
            doc = tomllib.loads(p.read_text(encoding="utf-8"))
        except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
            raise CLIError(f"{spec}: cannot read the nest file ({e})") from None
        if "nest" not in doc:
            raise CLIError(f"{spec}: no 'nest = [[x, y, z], [x, y, z], [x, y, z]]' in the nest file")
        return doc["nest"], doc.get("nest_unit")
    try:
        rows = [[float(v) for v in r.split(",")] for r in spec.split(";")]
    except ValueError:
        raise CLIError(f"--nest {spec!r}: give 'x1,y1,z1; x2,y2,z2; x3,y3,z3' (tool frame) or a TOML file") from None
    return rows, None


@import_app.command("three-smr")
def import_three_smr_cmd(
    path: Path = typer.Argument(..., help="Table with joints and three reflector positions per pose."),
    out: Path = Out,
    nest: str | None = typer.Option(
        None, "--nest", help="Reflector positions in the tool frame: 'x1,y1,z1; x2,y2,z2; x3,y3,z3' or a TOML file with nest = [...]."),
    nest_unit: str | None = typer.Option(None, "--nest-unit", help="Unit of the nest: m or mm, ... (default m)."),
    max_fit_rms_mm: float | None = typer.Option(None, "--max-fit-rms-mm", help="Largest accepted fit residual per pose (default 1 mm)."),
    map_path: Path | None = MapOpt,
    joints: str | None = JointsOpt,
    angle_unit: str | None = AngleOpt,
    position: str | None = typer.Option(None, "--position", help="Reflector 1 columns 'X1,Y1,Z1' (default p1x,p1y,p1z)."),
    length_unit: str | None = LengthOpt,
    point: list[str] | None = typer.Option(None, "--point", help="Reflector 2 and 3 columns (give twice; default p2x.., p3x..)."),
    delimiter: str | None = DelimOpt,
    decimal: str | None = DecimalOpt,
    skip_rows: int | None = SkipOpt,
    comment: str | None = CommentOpt,
    dof: int | None = DofOpt,
    robot: str | None = RobotOpt,
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    force: bool = Force,
) -> None:
    """Full poses from three reflectors per pose (a rigid fit of the known nest onto the three points).

    Without a mapping the columns are q1..qN and p1x,p1y,p1z, p2x,..., p3z (comma-separated) and every
    other column is kept.
    """
    from ..measure.table_import import import_table

    check_output(out, (path, map_path), force)
    opts = dict(joints=_joint_spec(joints), angle_unit=angle_unit, position=_csv_names(position), length_unit=length_unit,
                points=[_csv_names(p) for p in point or []], delimiter=delimiter, decimal=decimal, skip_rows=skip_rows,
                comment=comment, dof=dof, nest_unit=nest_unit, max_fit_rms_mm=max_fit_rms_mm)
    if nest is not None:
        opts["nest"], unit = _parse_nest(nest)
        if unit is not None and nest_unit is None:
            opts["nest_unit"] = unit
    if map_path is None:
        opts.setdefault("joints", None)
        opts["joints"] = opts["joints"] or "q*"
        opts["position"] = opts["position"] or ["p1x", "p1y", "p1z"]
        opts["points"] = opts["points"] or [[f"p{k}{a}" for a in "xyz"] for k in (2, 3)]
        opts["keep"] = ["*"]
    m = _build_map(map_path, opts)
    if m.nest is None:
        raise CLIError("import three-smr: give the reflector nest (--nest 'x1,y1,z1; x2,y2,z2; x3,y3,z3' or nest = [...] in --map)")
    ds = import_table(path, m, _robot(robot, base_link, tip_link))
    rms = ds.extra["smr_fit_rms_m"]
    _write(ds, out, [path, map_path], f", nest fit RMS mean {rms.mean() * 1e3:.4f} mm, max {rms.max() * 1e3:.4f} mm")


# --------------------------------------------------------------------------- streams


def _read_streams(robot_log, tracker_stream, robot_map, tracker_map, r_opts, t_opts, rob):
    """Robot log and tracker stream as arrays: the plain layout (CSV with plain names, Parquet) in
    chunks (:mod:`hykin.measure.stream_files`), anything else through the mapping reader."""
    from ..measure.stream_files import plain_layout, read_robot_log, read_tracker_stream
    from ..measure.table_import import read_mapped

    plain = robot_map is None and tracker_map is None and r_opts.get("joints") == "q*" \
        and plain_layout(robot_log) and plain_layout(tracker_stream)
    if plain:
        rev = [t == "revolute" for t in getattr(rob, "independent_joint_type", rob.joint_type)]
        t_r, q_r = read_robot_log(robot_log, dof=rob.dof, revolute=rev, time=r_opts["time"],
                                  angle_unit=r_opts.get("angle_unit") or "rad", time_unit=r_opts.get("time_unit") or "s")
        t_t, p_t, quat_t = read_tracker_stream(tracker_stream, time=t_opts["time"], position=t_opts["position"],
                                               quaternion=t_opts.get("quaternion"),
                                               length_unit=t_opts.get("length_unit") or "m",
                                               time_unit=t_opts.get("time_unit") or "s")
        return t_r, q_r, t_t, p_t, quat_t
    rm = read_mapped(robot_log, _build_map(robot_map, r_opts), rob, need_position=False)
    tm = read_mapped(tracker_stream, _build_map(tracker_map, t_opts), need_joints=False, allow_missing=True)
    for mt, name in ((rm, robot_log), (tm, tracker_stream)):
        if mt.time_s is None:
            raise CLIError(f"{name}: no time column mapped (time = \"...\" in the map, or --robot-time / --tracker-time)")
    return rm.time_s, rm.q, tm.time_s, tm.xyz_m, tm.quat_wxyz


#: ``import stream``'s bound on the robot's positions against the tracker's (RMS after the rigid map of the
#: clock fit): a robot file is mm off a real robot (1-6 mm), another robot or a unit slip is 100s of mm off
#: (measured on an own 6R's stream: the right file 2.43 mm, UR10 / KR6 / RX160 files 159-1,170 mm) -- but so
#: is a right file without the tool (100s of mm for a 100-300 mm tool), so a robot file only gets a warning;
#: a fitted model (tool included) is off by about its own error (the right model 0.029 mm for a held-out
#: 0.027 mm), so a model file is refused beyond the bound
_STREAM_RMS_ROBOT_MM = 50.0
_STREAM_RMS_MODEL_X, _STREAM_RMS_MODEL_MIN_MM = 20.0, 1.0


def _stream_rms_bound(model, max_rms_mm: float | None) -> float:
    """The RMS bound (mm) of ``import stream`` (see the constants above)."""
    if max_rms_mm is not None:
        return float(max_rms_mm)
    if model is None:
        return _STREAM_RMS_ROBOT_MM
    held = ((getattr(model, "metadata", None) or {}).get("metrics") or {}).get("held_out") or {}
    err = held.get("hybrid_pos_mean_mm")
    if err is None or not err == err:  # no held-out figure in the file: the robot file's bound, refused beyond it
        return _STREAM_RMS_ROBOT_MM
    return max(_STREAM_RMS_MODEL_MIN_MM, _STREAM_RMS_MODEL_X * float(err))


def _not_a_stream(e, robot_log: Path, tracker_stream: Path, maps=(None, None)) -> str:
    """The one line of a :class:`~hykin.measure.stream_checks.NotAStreamError` (static data given to
    ``import stream``), naming the file that samples too slowly and the import for static data (and the
    time unit, when the slow log samples ~1000x slower than the other)."""
    where = robot_log if e.which == "robot log" else tracker_stream
    period = e.period_robot_s if e.which == "robot log" else e.period_tracker_s
    other = e.period_tracker_s if e.which == "robot log" else e.period_robot_s
    has_map = (maps[0] if e.which == "robot log" else maps[1]) is not None
    what = (f"one tracker point per robot sample ({e.n_tracker} points, {e.n_robot} robot samples): a static campaign "
            "(the robot stops, one measurement per stop)" if e.static else "static measurements, one per stop")
    return (f"{where}: not a stream: a sample every {period:.3g} s (median; robot log {e.period_robot_s:.3g} s, tracker "
            f"{e.period_tracker_s:.3g} s), {what}; `import stream` would interpolate across the moves between stops. "
            "For static data put each stop's joints and tracker point in one row (joined by stop name or nearest time) "
            f"and use `hykin import table`; if these are streams, --max-gap S (above {period:.3g} s) accepts them"
            + (f" -- but first check the {e.which}'s time unit: a sample ~{period / max(other, 1e-300):.3g}x slower than the "
               f"{'tracker' if e.which == 'robot log' else 'robot log'}'s suggests {e.time_unit_hint} read as s "
               f"({_time_unit_fix(e.which, e.time_unit_hint, has_map)})" if getattr(e, "time_unit_hint", None) else ""))


def _time_unit_fix(which: str, unit: str, has_map: bool) -> str:
    """Where the time unit of ``which`` ("robot log" / "tracker") is set: its map or the option."""
    opt = "--robot-time-unit" if which == "robot log" else "--tracker-time-unit"
    mp = "--robot-map" if which == "robot log" else "--tracker-map"
    return f"time_unit = \"{unit}\" in the map ({mp})" if has_map else f"{opt} {unit}"


def _time_unit_slip(e, robot_log: Path, tracker_stream: Path, maps) -> str:
    """The one line of a :class:`~hykin.measure.stream_checks.TimeUnitError`: the log whose time is likely
    in ms (us, ns) read as s, and where to say so."""
    where = robot_log if e.which == "robot log" else tracker_stream
    has_map = (maps[0] if e.which == "robot log" else maps[1]) is not None
    slow, fast = ((e.period_robot_s, e.period_tracker_s) if e.which == "robot log"
                  else (e.period_tracker_s, e.period_robot_s))
    other = "tracker" if e.which == "robot log" else "robot log"
    return (f"{where}: the {e.which} samples every {slow:.3g} s, the {other} every {fast:.3g} s, and lasts "
            f"{(e.span_robot_s if e.which == 'robot log' else e.span_tracker_s):.4g} s against "
            f"{(e.span_tracker_s if e.which == 'robot log' else e.span_robot_s):.4g} s: the {e.which}'s time is likely "
            f"in {e.unit}, read as s: {_time_unit_fix(e.which, e.unit, has_map)}")


@import_app.command("stream")
def import_stream_cmd(
    robot_log: Path = typer.Argument(..., help="Robot joint log: a time column and the joints."),
    tracker_stream: Path = typer.Argument(..., help="Tracker stream: a time column and positions (empty cells = beam lost)."),
    out: Path = Out,
    robot: str = typer.Option(..., "--robot", help="Robot file/preset (or model file): FK of the logged joints for the clock fit."),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    robot_map: Path | None = typer.Option(None, "--robot-map", help="Mapping TOML of the robot log (time, joints, angle_unit, layout)."),
    tracker_map: Path | None = typer.Option(None, "--tracker-map", help="Mapping TOML of the tracker stream (time, position, orientation, units, layout)."),
    robot_time: str | None = typer.Option(None, "--robot-time", help="Time column of the robot log (default t)."),
    joints: str | None = typer.Option(None, "--joints", help="Joint columns of the robot log (default q*)."),
    angle_unit: str | None = AngleOpt,
    tracker_time: str | None = typer.Option(None, "--tracker-time", help="Time column of the tracker stream (default t)."),
    position: str | None = typer.Option(None, "--position", help="Position columns of the tracker stream (default x,y,z)."),
    quaternion: str | None = typer.Option(None, "--quaternion", help="Quaternion columns (wxyz) of the tracker stream, if any."),
    length_unit: str | None = LengthOpt,
    robot_time_unit: str | None = typer.Option(None, "--robot-time-unit", help="Unit of the robot log's time: s, ms, us, ns (default s)."),
    tracker_time_unit: str | None = typer.Option(None, "--tracker-time-unit", help="Unit of the tracker's time: s, ms, us, ns (default s)."),
    offset: float | None = typer.Option(None, "--offset", help="Known clock offset t_tracker - t_robot (s); default: estimated."),
    fit_drift: bool = typer.Option(False, "--fit-drift", help="Also estimate a clock drift (needs a log of >= 2 windows)."),
    method: str | None = typer.Option(None, "--method", metavar="speed|positions", help="Offset estimate: speed (frame-free; "
                                      "the default with a robot file) or positions (accurate model; the default with a model file)."),
    max_offset: float = typer.Option(1.0, "--max-offset", help="Search the offset within ± this (s).", min=0.0),
    max_speed: float = typer.Option(0.1, "--max-speed", help="Drop samples where the TCP moves faster (m/s); 0 keeps all.", min=0.0),
    max_gap: float | None = typer.Option(None, "--max-gap", help="Longest tracker gap bridged (s; default 3 tracker "
                                         "periods); logs sampling slower than max(0.5 s, this) are refused as static data."),
    frame: str = typer.Option("tracker", "--frame", help="tracker (keep the tracker frame) or fit (robot base by the rigid map of the clock fit)."),
    max_rms_mm: float | None = typer.Option(None, "--max-rms-mm", metavar="MM", min=0.0, help="Refuse when the robot's "
                                            "positions, rigidly mapped, stay further than this RMS from the tracker's (default: "
                                            f"with a model file {_STREAM_RMS_MODEL_X:g}x its held-out error, at least "
                                            f"{_STREAM_RMS_MODEL_MIN_MM:g} mm; with a robot file a warning above "
                                            f"{_STREAM_RMS_ROBOT_MM:g} mm, since a file without the tool is that far off)."),
    force: bool = Force,
) -> None:
    """Align a robot joint log with a tracker stream (clock offset, interpolation) into a dataset."""
    from ..measure.streams import (
        MIN_JOIN_CORRELATION,
        ClockRangeError,
        NoOverlapError,
        NotAStreamError,
        TimeUnitError,
        align_streams,
    )

    if frame not in ("tracker", "fit"):
        raise CLIError(f"import stream: --frame must be tracker or fit, got {frame!r}")
    from .common import load_model_or_robot

    model, rob = load_model_or_robot(robot, base_link, tip_link)
    if method is None:
        method = "positions" if model is not None else "speed"
    check_output(out, (robot_log, tracker_stream, robot_map, tracker_map), force)
    r_opts = dict(time=robot_time, joints=_joint_spec(joints), angle_unit=angle_unit, time_unit=robot_time_unit)
    t_opts = dict(time=tracker_time, position=_csv_names(position), quaternion=_csv_names(quaternion),
                  length_unit=length_unit, time_unit=tracker_time_unit)
    if robot_map is None:
        r_opts = {"time": "t", "joints": "q*", **{k: v for k, v in r_opts.items() if v is not None}}
    if tracker_map is None:
        t_opts = {"time": "t", "position": ["x", "y", "z"], **{k: v for k, v in t_opts.items() if v is not None}}
    t_r, q_r, t_t, p_t, quat_t = _read_streams(robot_log, tracker_stream, robot_map, tracker_map, r_opts, t_opts, rob)
    p_robot = None
    if model is not None and offset is None:
        # a fitted model: the clock is fitted to its hybrid positions (second pass of a streamed campaign:
        # import with the robot file, fit, import again with the model; the model's error no longer
        # leaks into the clock)
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # out-of-range counts belong to evaluation, not to a clock fit
            p_robot = model.predict(q_r)[:, :3, 3]
    try:
        a = align_streams(t_r, q_r, t_t, p_t, quat_t, rob, clock=offset, p_robot=p_robot,
                          max_speed_m_s=max_speed or None, max_gap_s=max_gap, fit_drift=fit_drift,
                          T_base_tracker="fit" if frame == "fit" else None,
                          **({} if offset is not None else {"method": method, "max_offset_s": max_offset}))
    except TimeUnitError as e:
        raise CLIError(_time_unit_slip(e, robot_log, tracker_stream, (robot_map, tracker_map))) from None
    except NotAStreamError as e:
        raise CLIError(_not_a_stream(e, robot_log, tracker_stream, (robot_map, tracker_map))) from None
    except NoOverlapError as e:
        rr, tr = getattr(e, "robot_range_s", None), getattr(e, "tracker_range_s", None)
        if rr is None or tr is None:
            raise CLIError(f"{tracker_stream}: {e}") from None
        raise CLIError(f"{tracker_stream}: its times ({tr[0]:.6f} to {tr[1]:.6f} s) and those of {robot_log} "
                       f"({rr[0]:.6f} to {rr[1]:.6f} s) do not overlap within the offset search ±{e.half_s:g} s "
                       f"(--max-offset): the clocks count from different origins (e.g. one on the epoch)? Give the "
                       f"offset t_tracker - t_robot with --offset S (about {(tr[0] + tr[1] - rr[0] - rr[1]) / 2:.6f} s here, from the middles of the two logs; it is then "
                       "taken as known, not fitted) or widen --max-offset S; or check --robot-time-unit / "
                       "--tracker-time-unit") from None
    except ClockRangeError as e:
        raise CLIError(f"{tracker_stream}: the clock offset found, {e.offset_s * 1e3:.4g} ms, lies at the edge of the "
                       f"search range ±{e.half_s:g} s (--max-offset): the range's limit, not a result; the true offset "
                       "lies beyond it (give --max-offset S wider, or --offset S if known) or the two files do not "
                       "belong together") from None
    ds = a.dataset
    clk = a.info["clock"]
    rms_mm, bound = clk.rms_m * 1e3, _stream_rms_bound(model, max_rms_mm)
    if offset is None and rms_mm > bound and max_rms_mm is None and clk.correlation < MIN_JOIN_CORRELATION:
        # the speed profiles do not match at the offset found: no clock joins these files (measured in
        # stream_checks.MIN_JOIN_CORRELATION); the positions' distance is then that of a bad join, not of a tool
        raise CLIError(f"{tracker_stream}: no clock offset joins the two files: the TCP speed profiles of "
                       f"{robot_log} and the tracker correlate at most {clk.correlation:.2f} (at {clk.offset_s * 1e3:.4g} "
                       f"ms; a right join >= {MIN_JOIN_CORRELATION:g}) and the positions stay {rms_mm:.3g} mm RMS apart: "
                       f"the offset lies beyond ±{max_offset:g} s (--max-offset), the files do not belong together, or "
                       "the joint columns' order or --angle-unit is wrong (--max-rms-mm MM accepts the join)")
    if offset is None and rms_mm > bound and model is None and max_rms_mm is None:
        # a robot file without the tool (calibration identifies it) is as far off as another robot: say it, write
        typer.echo(f"warning: the robot file's positions stay {rms_mm:.3g} mm RMS from the tracker's after the best "
                   f"rigid map (a robot is 1-6 mm off its file): expected when the file lacks the tool, else another "
                   "robot, the joint columns' order or --angle-unit, or the tracker's --length-unit? (--max-rms-mm refuses)")
    elif offset is None and rms_mm > bound:  # the clock fit's rigid map: the robot (file or model) does not fit the data
        raise CLIError(f"{tracker_stream}: the {'model' if model is not None else 'robot'} {robot!r} does not fit this "
                       f"stream: its positions stay {rms_mm:.3g} mm RMS from the tracker's after the best rigid map "
                       f"(bound {bound:.3g} mm, --max-rms-mm): another robot or tool, the joint columns' order or "
                       "--angle-unit, or the tracker's --length-unit?")
    if len(ds) == 0:
        raise CLIError(f"{tracker_stream}: no robot sample kept ({a.info['n_dropped_gap']} outside valid tracker data, "
                       f"{a.info['n_dropped_speed']} faster than {max_speed} m/s)")
    info = a.info
    _write(ds, out, [robot_log, tracker_stream, robot_map, tracker_map],
           f"; clock offset {info['offset_s'] * 1e3:.4f} ms"
           + (f", drift {info['drift'] * 1e6:.4f} ppm" if fit_drift else "")
           + (f" ({method}{', hybrid positions of the model' if p_robot is not None else ''}; robot positions "
              f"{info['clock'].rms_m * 1e3:.3g} mm RMS from the tracker's)" if offset is None else "")
           + f", dropped {info['n_dropped_gap']} in tracker gaps and "
           f"{info['n_dropped_speed']} above {max_speed} m/s")
    if model is None and offset is None and (max_speed == 0 or max_speed > 0.1):
        # the clock of a nominal model is good to ~0.05 ms: at speed v that is v x 0.05 ms of error the
        # networks would learn (docs/dynamic-collection.md, "Two passes")
        typer.echo(f"note: samples up to {max_speed or 'any'} m/s kept, clock timed on the robot file; for them import "
                   "first with --max-speed 0.1, fit on that, then import again with --robot MODEL.hykin (its hybrid "
                   "positions time the clock)")
