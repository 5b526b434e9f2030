"""Compensation commands: compensate (targets and programs), serve (HTTP service), export-urdf."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from .common import (
    AngleUnit,
    CLIError,
    Force,
    LengthUnit,
    app,
    check_output,
    check_rt_priority,
    console,
    load_model,
    PayloadKg,
    parse_axis_signs,
    temperature_of,
    warn_orientation_unmeasured,
    warn_payloads_outside,
    with_payload,
    write_rows,
)

_FORMATS = ("csv", "urscript", "krl", "rapid")


def _format_of(path: Path, fmt: str | None) -> str:
    from ..compensation import krl, rapid, urscript

    if fmt is not None:
        if fmt not in _FORMATS:
            raise CLIError(f"--format must be one of {', '.join(_FORMATS)}, got {fmt!r}")
        return fmt
    suf = path.suffix.lower()
    if suf in (".csv", ".parquet"):
        return "csv"
    for name, mod in (("urscript", urscript), ("krl", krl), ("rapid", rapid)):
        if suf in mod.SUFFIXES:
            return name
    raise CLIError(f"{path}: unknown input type {suf!r}; give --format ({', '.join(_FORMATS)})")


@app.command("compensate")
def compensate_cmd(
    model: str = typer.Argument(..., help="Model file (hykin fit)."),
    inp: Path = typer.Argument(..., metavar="INPUT", help="Targets CSV (x,y,z[,qw,qx,qy,qz][,q1..qN]) or a program: URScript (.script), KRL (.src/.dat), RAPID (.mod)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output: commands CSV, the rewritten program, or joints CSV (--joints)."),
    joints: bool = typer.Option(False, "--joints", help="Write the joints the real robot needs (CSV: target, q1..qN, status) instead of poses."),
    frame: str = typer.Option("auto", "--frame", help="Frame of the targets: measurement (the model's data frame), base (controller base placed by the fitted base), auto (CSV: measurement; programs: base when the fitted base is far from the nominal one)."),
    skip_unreachable: bool = typer.Option(False, "--skip-unreachable", help="Programs: keep an unreachable target's original line and warn, instead of refusing to write."),
    fmt: str | None = typer.Option(None, "--format", help="Input format: csv, urscript, krl, rapid (default: by suffix)."),
    context: list[Path] | None = typer.Option(None, "--context", help="More files the program needs (repeatable). KRL: the companion .src/.dat (read from beside the input by default) and $config.dat (BASE_DATA/TOOL_DATA). RAPID: modules declaring the tooldata/wobjdata the program uses."),
    tool: str | None = typer.Option(None, "--tool", help="CSV: the targets are poses of another TCP than the model's: x,y,z[,roll,pitch,yaw] of that TCP in the flange frame, as the tool table of a robot file (xyz, rpy), in --length-unit / --angle-unit (programs name their tool: set_tcp, tooldata, TOOL_DATA)."),
    config_slack_deg: float = typer.Option(1.0, "--config-slack-deg", help="Programs: a target the real robot reaches only with the other elbow / overhead / wrist flag than its configuration data (S, confdata) say, within this angle of that flag's singular pose (stretched elbow, wrist centre on axis 1, A5 = 0), is written with the flag it reaches, with a note; 0 refuses it."),
    axis_signs: str | None = typer.Option(None, "--axis-signs", help="Controller axis = sign × joint, e.g. -1,1,1,-1,1,-1 (default: from the robot preset)."),
    payload_kg: float | None = typer.Option(None, "--payload-kg", help="Payload (kg, at the TCP) the robot carries while executing these targets: the model deflects under it (default: the robot file's payload)."),
    flange: str | None = typer.Option(None, "--flange", help="URDF robots: the link that is the controller's flange, from which program tools (TOOL_DATA, tooldata, set_tcp) and --tool are given (default: 'flange' for KRL and --tool, 'tool0' for RAPID and URScript, where the URDF has them; else the last moving link)."),
    tool_shift: str = typer.Option("mount", "--tool-shift", metavar="mount|flange", help="Where a program's own tool (--tool, set_tcp, tooldata, TOOL_DATA) sits: the calibrated TCP's shift from the robot file's [tool] is the measurement tool's mount ('mount': program tools on the calibrated chain's flange) or the flange's own error ('flange': they move with it; right where the file's [tool] is the measurement tool as measured). The data cannot tell them apart; a note says where it matters."),
    quaternion_order: str | None = typer.Option(None, "--quaternion-order", metavar="wxyz|xyzw", help="CSV: the order of the qw,qx,qy,qz columns' values: wxyz (as the header says) or xyzw (scalar last); given, the order is not checked (default: refused where the targets clearly read better the other way)."),
    tool_angle_unit: str | None = typer.Option(None, "--tool-angle-unit", metavar="rad|deg", help="Unit of --tool's roll, pitch, yaw (default: --angle-unit)."),
    tolerance_mm: float | None = typer.Option(None, "--tolerance-mm", help="Success tolerance, mm: a target the model's robot reaches within it (and --tolerance-deg) is compensated (default: half the model's held-out mean position error, at least 1e-4 mm)."),
    tolerance_deg: float | None = typer.Option(None, "--tolerance-deg", help="Success tolerance, degrees (default: half the model's held-out mean orientation error, at least 1e-4 deg)."),
    force: bool = Force,
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
) -> None:
    """Compensated targets for a controller that runs the nominal model (see docs/compensation.md)."""
    kind = _format_of(inp, fmt)
    if frame not in ("auto", "measurement", "base"):
        raise CLIError(f"--frame must be auto, measurement or base, got {frame!r}")
    if not (0 <= config_slack_deg <= 90):
        raise CLIError(f"--config-slack-deg must be within 0-90 deg, got {config_slack_deg}")
    tol = _tolerances(tolerance_mm, tolerance_deg)
    if tool_shift not in ("mount", "flange"):
        raise CLIError(f"--tool-shift must be mount or flange, got {tool_shift!r}")
    tol["tool_shift"] = tool_shift
    if quaternion_order not in (None, "wxyz", "xyzw"):
        raise CLIError(f"--quaternion-order must be wxyz or xyzw, got {quaternion_order!r}")
    if tool_angle_unit not in (None, "rad", "deg"):
        raise CLIError(f"--tool-angle-unit must be rad or deg, got {tool_angle_unit!r}")
    context = list(context or [])
    if kind == "krl" and inp.suffix.lower() in (".src", ".dat"):  # the companion file beside it is read too
        sib = inp.with_suffix(".src" if inp.suffix.lower() == ".dat" else ".dat")
        if sib.is_file() and not any(Path(c).resolve() == sib.resolve() for c in context):
            context = [sib, *context]
    check_output(out, [inp, model, *context], force)
    if not inp.is_file():
        raise CLIError(f"{inp}: no such file")
    if kind == "csv":  # the file's payload and temperature columns, else --payload-kg / the reference temperature
        mdl = load_model(model)
        parse_axis_signs(axis_signs, mdl.nominal.dof)
        D = _tool_delta(mdl, tool, length_unit, tool_angle_unit or angle_unit, flange)
        _compensate_csv(mdl, inp, out, joints, "measurement" if frame == "auto" else frame, length_unit, angle_unit, D,
                        payload_kg, tol, quaternion_order)
        return
    mdl = with_payload(load_model(model), payload_kg)
    signs = parse_axis_signs(axis_signs, mdl.nominal.dof)
    th = getattr(mdl, "thermal_", None)
    if th is not None and th.coefficient_per_k != 0.0:
        console().print(f"note: the model has thermal expansion; targets are compensated at its reference "
                        f"{th.reference_c:.2f} °C", highlight=False)
    if tool is not None:
        raise CLIError(f"--tool applies to CSV targets; {inp} is a {kind} program, which names its own tool "
                       "(URScript set_tcp, RAPID tooldata, KRL TOOL_DATA via --context)")
    else:
        _compensate_program(mdl, inp, out, kind, joints, frame, skip_unreachable, context, signs, config_slack_deg,
                            flange, tol)


def _tolerances(mm: float | None, deg: float | None) -> dict:
    """``--tolerance-mm`` / ``--tolerance-deg`` as :class:`hykin.compensation.Compensator` keywords (the
    model's default for one not given); each must be a positive number."""
    out = {}
    for name, key, v in (("--tolerance-mm", "tolerance_mm", mm), ("--tolerance-deg", "tolerance_deg", deg)):
        if v is None:
            continue
        if not (np.isfinite(v) and v > 0):
            raise CLIError(f"{name} must be a positive number, got {v}")
        out[key] = float(v)
    return out


def _tool_delta(mdl, text: str | None, length_unit: str, angle_unit: str, flange: str | None = None):
    """``--tool`` as the tool delta ``inv(nominal tool) · flange · tcp`` ((4, 4); the flange of a URDF:
    :func:`hykin.io.urdf_flange.choose_flange`), or None when not given."""
    from ..io.urdf_flange import choose_flange, flange_of

    robot, note = choose_flange(mdl.nominal, "csv", flange)
    if text is None:
        return None
    from ..geometry import se3
    from ..io.dataset import ANGLE_UNITS, LENGTH_UNITS, check_units

    check_units("--tool", length_unit, angle_unit)
    try:
        v = np.array([float(x) for x in text.split(",")])
    except ValueError:
        v = np.array([])
    if v.shape not in ((3,), (6,)) or not np.isfinite(v).all():
        raise CLIError(f"--tool: expected x,y,z or x,y,z,roll,pitch,yaw (numbers), got {text!r}")
    xyz = v[:3] * LENGTH_UNITS[length_unit]
    rpy = (v[3:] if v.size == 6 else np.zeros(3)) * ANGLE_UNITS[angle_unit]
    if np.linalg.norm(xyz) > 2.0:
        raise CLIError(f"--tool: a TCP {np.linalg.norm(xyz):.4g} m from the flange; if its numbers are mm, add "
                       "--length-unit mm")
    if np.abs(rpy).max() > 2 * np.pi + 1e-9:
        raise CLIError(f"--tool: angles up to {np.abs(rpy).max():.4g} rad; if they are degrees, add --tool-angle-unit deg")
    if note:
        console().print(f"note: --tool: {note}", highlight=False)
    return se3.invert(mdl.nominal.tool) @ flange_of(robot) @ se3.xyzrpy_to_transform(xyz, rpy)


def _compensate_csv(mdl, inp: Path, out: Path, joints: bool, frame: str, length_unit: str, angle_unit: str,
                    tool_delta=None, payload_kg: float | None = None, tol: dict | None = None,
                    quaternion_order: str | None = None) -> None:
    """CSV targets; per-row ``payload_kg`` / ``payload_com_*`` columns: one compensation per distinct payload
    on the model carrying it; a ``temperature_c`` column: the targets mapped to the model's reference
    temperature (where its joints are solved; the controller's nominal model has no temperature)."""
    from ..compensation.frames import to_model_frame
    from ..compensation.result import merge_parts
    from ..compensation.targets import command_rows, compensate
    from ..io.dataset_files import read_joints, read_poses
    from ..io.payload import model_with_payload, payload_from_columns

    T, has_rot, extra = read_poses(inp, length_unit=length_unit, extras=True)
    if has_rot and quaternion_order == "xyzw":  # the columns hold x,y,z,w: read them so
        from ..geometry import se3

        T[:, :3, :3] = se3.quat_to_matrix(se3.matrix_to_quat(T[:, :3, :3])[:, [3, 0, 1, 2]])
    if tool_delta is None:
        _warn_tool_mismatch(mdl)
    pl = payload_from_columns(extra, len(T), str(inp), payload_kg) if "payload_kg" in extra else None
    if pl is None:
        mdl = with_payload(mdl, payload_kg)
    temp = temperature_of(mdl, extra, inp)
    if temp is not None:
        T = mdl.targets_at_reference(to_model_frame(mdl, T, frame), temp)
        frame = "measurement"
    if tool_delta is not None and not has_rot:
        raise CLIError(f"{inp}: --tool needs the targets' orientations (qw,qx,qy,qz columns): where another TCP "
                       "lies depends on them")
    n = mdl.nominal.dof
    qb = None
    if all(f"q{j + 1}" in _columns(inp) for j in range(n)):
        from ..io.plausibility import check_joint_unit

        qb, _ = read_joints(inp, dof=n, angle_unit=angle_unit, length_unit=length_unit, robot=mdl.nominal)
        # joints in radians under --angle-unit deg would hint every target wrong
        check_joint_unit(mdl.nominal, qb, where=str(inp), angle_unit=angle_unit)
    if has_rot:
        from ..compensation.target_checks import check_quaternion_order

        warn_orientation_unmeasured(mdl, "the targets' orientations are compensated with that")
        try:  # scalar-last quaternions under a scalar-first header (probe s42 AQ: exit 0, 27 targets 180° off)
            said = "" if quaternion_order else check_quaternion_order(mdl, T, frame, qb, tool_delta, where=str(inp))
        except ValueError as e:
            raise CLIError(str(e)) from None
        if said:
            console().print(f"[yellow]warning:[/] {said}", highlight=False)
    target = T if has_rot else T[:, :3, 3]
    tol = tol or {}
    if pl is None:
        comp = compensate(mdl, target, q_branch=qb, frame=frame, tool_delta=tool_delta, **tol)
    else:
        from ..io.payload import payload_groups

        warn_payloads_outside(mdl, pl[0], "{n} of " + f"{len(T)} targets carry payloads")
        parts = [(idx, compensate(model_with_payload(mdl, kg, com), target[idx], q_branch=None if qb is None else qb[idx],
                                  frame=frame, tool_delta=tool_delta, **tol)) for idx, kg, com in payload_groups(pl)]
        comp = merge_parts(parts, len(T))
    write_rows(command_rows(comp, joints_only=joints), out)
    for note in comp.notes:
        console().print(f"note: {inp}: {note}", highlight=False, markup=False)
    _summary(comp, out, len(T))


#: the calibrated TCP this far from the robot file's (mm, deg): the file lacks the tool the data were measured with
TOOL_MISMATCH_MM, TOOL_MISMATCH_DEG = 20.0, 5.0


def _warn_tool_mismatch(mdl, what: str = "--tool") -> None:
    """Warn when the model's calibrated tool (with its registration) is far from the robot file's: the
    commands are poses of the file's TCP, which the controller must then have as its tool (``what``: how
    the targets can name another TCP)."""
    from ..geometry import se3
    from ..hybrid.ik_result import model_tcp_shift

    E = model_tcp_shift(mdl)
    mm = float(np.linalg.norm(E[:3, 3]) * 1e3)
    deg = float(np.degrees(np.linalg.norm(se3.matrix_to_rotvec(E[:3, :3]))))
    if mm > TOOL_MISMATCH_MM or deg > TOOL_MISMATCH_DEG:
        console().print(f"[yellow]warning:[/] the calibrated TCP is {mm:.1f} mm / {deg:.2f} deg from the robot file's tool: "
                        "the commands are poses of the robot file's TCP (and shift_mm includes that offset); the "
                        f"controller must use that tool, or put the controller's TCP into the robot file's [tool], or "
                        f"give it with {what}", highlight=False)


def _columns(path: Path) -> list:
    """Column names of a CSV (first line that is not a ``#`` comment) or Parquet file."""
    if path.suffix.lower() == ".parquet":
        import pyarrow.parquet as pq

        return list(pq.read_schema(path).names)
    import csv

    with open(path, newline="") as f:
        for row in csv.reader(f):
            if row and not row[0].lstrip().startswith("#"):
                return [c.strip() for c in row]
    return []


#: starts of the reasons of a program target refused for its configuration data or for the branch the
#: controller would take (hykin.compensation.program_branches / program_checks)
_CONFIG_REASONS = ("no solution with the program's configuration data", "a configuration change",
                   "the controller would", "the controller has no")


def _summary(comp, out: Path, n: int, program: bool = False, listed: bool = False) -> None:
    ok = comp.success
    line = f"wrote {out}: {int(ok.sum())} of {n} targets compensated"
    if ok.any():
        line += (f" (command shift mean {np.mean(comp.shift_mm[ok]):.3f} mm, max {np.max(comp.shift_mm[ok]):.3f} mm; "
                 f"model error max {np.max(comp.pos_err_mm[ok]):.2e} mm)")
    # a target fails for its pose (unreachable, blocked by a limit), for its configuration data or the
    # controller's branch, or for a frame or TCP the program does not define (its reason says which):
    # counted apart; a program's reasons are the lines above (``listed``), a CSV's are in its status column
    where = "listed above" if listed else "status column"
    reasons = [str(r) for r in comp.reason[~ok]]
    solvable = [r for r in reasons if r.startswith(("unreachable", "blocked")) or "out of reach" in r]
    config = [r for r in reasons if r not in solvable and any(c in r for c in _CONFIG_REASONS)]
    if solvable:
        line += f"; {len(solvable)} unreachable ({where})"
        far = int(sum("out of reach" in r for r in solvable))
        if far:
            line += f", {far} of them beyond the arm's reach"
    if config:
        line += (f"; {len(config)} refused for their configuration data or the branch the controller would take "
                 f"({where})")
    if len(reasons) > len(solvable) + len(config):
        line += (f"; {len(reasons) - len(solvable) - len(config)} failed for a frame or TCP the "
                 f"{'program' if program else 'input'} does not define ({where})")
    typer.echo(line)
    # most targets out of reach: the usual cause is the targets' frame (not when they failed for a frame,
    # TCP or configuration the program does not define: their reasons say so)
    if 2 * len(solvable) > n:
        from ..compensation.frames import other_frame

        other, name = other_frame(comp.frame)
        console().print(f"[yellow]hint:[/] most targets failed in the {comp.frame} frame; if they are given in {name}, "
                        f"pass --frame {other}")
    if ok.any() and not comp.in_support[ok].all():
        console().print(f"[yellow]warning:[/] {int((~comp.in_support[ok]).sum())} compensated targets need joints outside "
                        "the model's training support: the correction fades to the calibrated model there")


def _compensate_program(mdl, inp: Path, out: Path, kind: str, joints: bool, frame: str, skip: bool,
                        context: list, signs, slack_deg: float, flange: str | None = None, tol: dict | None = None) -> None:
    from ..compensation import krl, rapid, urscript
    from ..compensation.programs import compensate_program

    fmt = {"urscript": urscript, "krl": krl, "rapid": rapid}[kind]
    text = inp.read_bytes().decode("latin-1")  # one char per byte: unchanged bytes stay unchanged
    for c in context:
        if not Path(c).is_file():
            raise CLIError(f"--context {c}: no such file")
    texts = [Path(c).read_bytes().decode("latin-1") for c in context]
    ctx = "\n".join(texts)
    try:
        res = compensate_program(mdl, text, fmt, frame=frame, axis_signs=signs, context=ctx, config_slack_deg=slack_deg,
                                 flange=flange, **(tol or {}))
    except ValueError as e:
        raise CLIError(f"{inp}: {_context_lines(str(e).splitlines()[0], context, texts)}") from None
    res.notes = [_context_lines(n, context, texts) for n in res.notes]
    res.failed = [(line, _context_lines(r, context, texts)) for line, r in res.failed]
    if any(t.tool_delta is None for t in res.targets):  # targets of the robot file's TCP, as CSV targets without --tool
        _warn_tool_mismatch(mdl, "the program's tool (TOOL_DATA, tooldata, set_tcp)")
    con = console()
    for note in res.notes:
        con.print(f"note: {inp}:{note}", highlight=False)
    if not res.targets:
        # a KRL .src whose points all live in its .dat (inline forms): one call per file, so the .src
        # goes to -o unchanged and the .dat is the file to compensate
        dat = inp.with_suffix(".dat")
        rest = [t for c, t in zip(context, texts) if Path(c).resolve() != dat.resolve()]
        if kind == "krl" and inp.suffix.lower() == ".src" and dat.is_file() and not joints and fmt.find_targets(
                dat.read_bytes().decode("latin-1"), mdl.nominal, context="\n".join([text, *rest]), axis_signs=signs)[0]:
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_bytes(inp.read_bytes())
            con.print(f"note: {inp}: no Cartesian targets of its own; its points are in {dat.name}: written "
                      f"unchanged to {out} (compensate {dat.name} too)", highlight=False)
            return
        raise CLIError(f"{inp}: no Cartesian targets found (format {kind}); nothing written")
    unknown = {t.line for t in res.targets if t.error}  # frames the files do not define (work objects, bases)
    for line, reason in res.failed:
        what = "target's frame unknown" if line in unknown else "target unreachable"
        con.print(f"{'warning' if skip else 'error'}: {inp}:{line}: {what} ({reason})", highlight=False)
    if res.failed and not skip:
        n_frame = sum(1 for line, _ in res.failed if line in unknown)
        why = "unreachable" if not n_frame else ("with unknown frames" if n_frame == len(res.failed)
                                                  else f"unreachable or with unknown frames ({n_frame})")
        raise CLIError(f"{inp}: {len(res.failed)} of {len(res.targets)} targets {why}; nothing written "
                       "(--skip-unreachable keeps their original lines)")
    if joints:
        rows = {"target": np.arange(len(res.targets)), "line": [t.line for t in res.targets],
                "name": [t.name for t in res.targets]}
        for j in range(mdl.nominal.dof):
            rows[f"q{j + 1}"] = res.comp.q[:, j]
        rows["success"] = res.comp.success.astype(int)
        rows["status"] = np.where(res.comp.success, "ok", res.comp.reason)
        write_rows(rows, out)
    else:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(res.text.encode("latin-1"))
    if res.comp.frame == "base" and frame == "auto":
        con.print("note: the model's fitted base is far from the nominal one (tracker-frame data): program poses "
                  "taken in the controller's base frame (--frame base)", highlight=False)
    _summary(res.comp, out, len(res.targets), program=True, listed=not joints)


def _context_lines(msg: str, paths: list, texts: list) -> str:
    """``msg`` with each "--context, line N" (N counted in the joined context files) as "FILE, line n"."""
    import re

    starts = np.cumsum([0] + [t.count("\n") + 1 for t in texts])  # first joined line of each file, 0-based

    def one(m):
        n = int(m.group(1)) - 1
        k = int(np.searchsorted(starts, n, side="right")) - 1
        if not 0 <= k < len(paths):
            return m.group(0)
        return f"{Path(paths[k]).name}, line {n - starts[k] + 1}"

    return re.sub(r"--context, line (\d+)", one, msg)


@app.command("serve")
def serve_cmd(
    model: str = typer.Argument(..., help="Model file (hykin fit)."),
    host: str = typer.Option("127.0.0.1", "--host", help="Address to listen on (default: this machine only)."),
    port: int = typer.Option(8000, "--port", help="TCP port."),
    token_file: Path | None = typer.Option(None, "--token-file", help="File holding a bearer token: every request but "
                                    "GET /health must then send 'Authorization: Bearer <token>' (401 / WebSocket 403 otherwise)."),
    max_targets: int = typer.Option(10_000, "--max-targets", help="Targets (rows) in one HTTP request (422 above)."),
    max_body_kb: int = typer.Option(4096, "--max-body-kb", help="Size of one HTTP request body, KiB (413 above)."),
    max_message_bytes: int = typer.Option(4096, "--max-message-bytes", help="Size of one WebSocket message, bytes "
                                          "(the stream is closed with 1009 above)."),
    queue: int = typer.Option(64, "--queue", help="HTTP requests waiting for the model or running, all clients "
                              "together (503 above). Streamed targets are not counted and never refused for it."),
    max_connections: int = typer.Option(64, "--max-connections", help="Requests and streams in progress (503 above; "
                                        "GET /health not counted)."),
    header_timeout_s: float = typer.Option(5.0, "--header-timeout-s", help="A connection that has not sent a complete "
                                           "request header within this many seconds is closed."),
    body_timeout_s: float = typer.Option(10.0, "--body-timeout-s", help="A request body not received in full within "
                                         "this many seconds of its header (plus the time --body-min-rate-kib-s "
                                         "allows for what arrived) gets 408 and the connection is closed."),
    body_min_rate_kib_s: float = typer.Option(64.0, "--body-min-rate-kib-s", help="Each KiB of a body that arrived "
                                              "extends --body-timeout-s by 1/this seconds: a body arriving at this "
                                              "rate or faster is never cut off, a slower one is. 0: a total deadline."),
    send_timeout_s: float = typer.Option(10.0, "--send-timeout-s", help="A connection whose answer waits for the client "
                                         "to read it (write buffer full) is aborted after this many seconds, plus "
                                         "the time --send-min-rate-kib-s allows for what the client took."),
    send_min_rate_kib_s: float = typer.Option(16.0, "--send-min-rate-kib-s", help="Each KiB of a waiting answer that "
                                              "the client reads extends --send-timeout-s by 1/this seconds: a client "
                                              "reading at this rate or faster gets every answer."),
    max_step_deg: float | None = typer.Option(None, "--max-step-deg", help="Refuse a streamed answer whose joints move "
                                              "more than this many degrees from the message's 'q' (default: no limit)."),
    refusal_delay_ms: float = typer.Option(100.0, "--refusal-delay-ms", help="Every refused request is answered after "
                                           "this delay, which slows a client flooding bad requests (0: at once)."),
    payload_kg: float | None = PayloadKg,
    rt_priority: int = typer.Option(0, "--rt-priority", metavar="N", help="Serve under SCHED_FIFO at this priority "
                                    "(1-99; its threads inherit it), so that other processes cannot delay a streamed "
                                    "answer; 0 (default): normal priority. Without the right it runs at normal priority and says so."),
) -> None:
    """Serve fk / ik / compensate over HTTP (JSON batches), a WebSocket stream of single targets (/stream) and GET /health."""
    from ..compensation.service import serve
    from ..compensation.service_guard import ServiceLimits, load_served_model, read_token_file

    if not 0 < port < 65536:
        raise CLIError(f"--port must be 1..65535, got {port}")
    for name, v in (("--max-targets", max_targets), ("--max-body-kb", max_body_kb), ("--max-message-bytes", max_message_bytes),
                    ("--queue", queue), ("--max-connections", max_connections)):
        if v < 1:
            raise CLIError(f"{name} must be at least 1, got {v}")
    check_rt_priority(rt_priority)
    if not 0 <= refusal_delay_ms <= 60_000:
        raise CLIError(f"--refusal-delay-ms must be in 0..60000, got {refusal_delay_ms}")
    for name, v in (("--header-timeout-s", header_timeout_s), ("--body-timeout-s", body_timeout_s),
                    ("--send-timeout-s", send_timeout_s)):
        if not 0 < v <= 3600:
            raise CLIError(f"{name} must be in (0, 3600] s, got {v}")
    if not 0 < send_min_rate_kib_s <= 1e6:
        raise CLIError(f"--send-min-rate-kib-s must be in (0, 1e6] KiB/s, got {send_min_rate_kib_s}")
    if not 0 <= body_min_rate_kib_s <= 1e6:
        raise CLIError(f"--body-min-rate-kib-s must be in 0..1e6 KiB/s (0: a total deadline), got {body_min_rate_kib_s}")
    if max_step_deg is not None and not 0 < max_step_deg <= 360:
        raise CLIError(f"--max-step-deg must be in (0, 360] deg, got {max_step_deg}")
    try:
        token = read_token_file(token_file) if token_file is not None else None
    except ValueError as e:
        raise CLIError(str(e)) from None
    import socket as _socket

    host = host.strip("[]")  # --host [::1]: the brackets of a URL, not of the address (probe s42 AY)
    url_host = f"[{host}]" if ":" in host else host
    try:  # the port first: one line naming it, before the banner and the model (uvicorn sets SO_REUSEADDR too)
        with _socket.socket(_socket.AF_INET6 if ":" in host else _socket.AF_INET, _socket.SOCK_STREAM) as probe:
            probe.setsockopt(_socket.SOL_SOCKET, _socket.SO_REUSEADDR, 1)
            probe.bind((host, port))
    except OSError as e:
        raise CLIError(f"--port {port}: cannot listen on {url_host}:{port} ({e.strerror or e})") from None
    limits = ServiceLimits(max_targets=max_targets, max_body_bytes=max_body_kb * 1024, max_message_bytes=max_message_bytes,
                           queue=queue, max_connections=max_connections, refusal_delay_s=refusal_delay_ms / 1e3, token=token,
                           header_timeout_s=header_timeout_s, body_timeout_s=body_timeout_s,
                           body_min_rate_kib_s=body_min_rate_kib_s or None, send_timeout_s=send_timeout_s,
                           send_min_rate_kib_s=send_min_rate_kib_s,
                           max_step_deg=max_step_deg)
    mdl, identity = load_served_model(model)  # one read: /health's hashes are of the bytes loaded
    mdl = with_payload(mdl, payload_kg)
    typer.echo(f"hykin serve: {mdl.nominal.name} (sha256 {identity['model_sha256'] or identity['file_sha256']}) on "
               f"http://{url_host}:{port} (GET /health, POST /fk /ik /compensate, WebSocket /stream"
               f"{'; bearer token required' if token else ''})")
    if rt_priority:  # before the app and its model thread exist: threads inherit the policy
        from ..realtime.udp_bridge import raise_priority

        typer.echo(f"hykin serve: {raise_priority(rt_priority)}")
    serve(mdl, host, port, limits, identity)


@app.command("export-urdf")
def export_urdf_cmd(
    model: str = typer.Argument(..., help="Model file (hykin fit)."),
    out: Path = typer.Option(..., "-o", "--out", help="Output .urdf file."),
    force: bool = Force,
) -> None:
    """Calibrated URDF: geometry, joint offsets, base and tool of the calibrated model in the joint origins.

    A URDF is rigid: with joint compliance, the line says how far its FK is from the calibrated robot
    (mean / max mm at the robot file's payload over the model's training range). The output must end in .urdf."""
    from ..io.urdf import calibrated_urdf

    check_output(out, [Path(model)], force)
    if out.suffix.lower() != ".urdf":
        raise CLIError(f"{out}: export-urdf writes URDF; name the output {out.with_suffix('.urdf').name}")
    mdl = load_model(model)
    text, info = calibrated_urdf(mdl)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text)
    typer.echo(f"wrote {out}; not in a URDF: {info} (use hykin compensate to get them to a controller)")
