"""Planning command: which joint configurations to measure, in which order, and how many (``hykin plan``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from .common import BaseLink, CLIError, Force, TipLink, app, check_output, load_model_or_robot, write_rows


def _vec3(text: str | None, what: str, factor: float = 1.0) -> np.ndarray | None:
    if text is None:
        return None
    try:
        v = np.array([float(x) for x in str(text).replace(";", ",").split(",")])
    except ValueError:
        raise CLIError(f"{what}: expected three numbers X,Y,Z, got {text!r}") from None
    if v.shape != (3,) or not np.isfinite(v).all():
        raise CLIError(f"{what}: expected three finite numbers X,Y,Z, got {text!r}")
    return v * factor


@app.command("plan")
def plan_cmd(
    robot: str | None = typer.Argument(None, help="Robot file, URDF or preset name (not with --for-model)."),
    n: int = typer.Option(..., "-n", help="Number of poses to plan.", min=1),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    out: Path | None = typer.Option(None, "-o", "--out", help="Output by its suffix: .csv (joints, the unit in the header), .script (URScript), .src/.dat (KUKA KRL, both written), .mod (ABB RAPID)."),
    for_model: str | None = typer.Option(None, "--for-model", help="Fitted model file: plan the next poses where its training data are thinnest, weighted by its uncertainty."),
    seed: int = typer.Option(0, "--seed", help="Random seed of the candidate pool."),
    region: str | None = typer.Option(None, "--region", help="Joint ranges lo:hi per joint, comma-separated (deg; ':' keeps a limit)."),
    box: str | None = typer.Option(None, "--box", help="Cartesian box for the reflector: xmin,ymin,zmin,xmax,ymax,zmax (world frame)."),
    tracker: str | None = typer.Option(None, "--tracker", help="Tracker position X,Y,Z (world frame): enables the line-of-sight test."),
    max_tracker_distance: float = typer.Option(100.0, "--max-tracker-distance-m", help="Farthest tracker from the robot base (m): a farther --tracker is refused as a unit slip (laser trackers reach ~80 m).", min=0.0),
    max_incidence: float = typer.Option(30.0, "--max-incidence", help="Max angle (deg) between reflector axis and tracker direction (SMR ~30, 6-D probe ~45)."),
    reflector_offset: str = typer.Option("0,0,0", "--reflector-offset", help="Reflector point in the tool frame X,Y,Z."),
    reflector_axis: str = typer.Option("0,0,1", "--reflector-axis", help="Reflector normal in the tool frame."),
    keep_out: list[str] | None = typer.Option(None, "--keep-out", help="Keep-out box xmin,ymin,zmin,xmax,ymax,zmax (repeatable): no reflector inside, no beam through."),
    length_unit: str = typer.Option("m", "--length-unit", help="Unit of --box, --tracker, --keep-out, --reflector-offset: m or mm."),
    measure: str = typer.Option("position", "--measure", help="What the tracker measures: position (SMR) or pose (6-D probe)."),
    speed: float = typer.Option(30.0, "--speed", help="Joint speed for ordering and the time estimate (deg/s; mm/s for prismatic joints).", min=1e-6),
    dwell: float = typer.Option(5.0, "--dwell", help="Settle + measure time per pose (s) for the time estimate.", min=0.0),
    pool: int = typer.Option(20_000, "--pool", help="Candidate poses drawn (scrambled Sobol) before the constraints.", min=100),
    floor: float | None = typer.Option(None, "--floor", help="Floor height Z (world frame, --length-unit): no link, tool or move goes below it."),
    link_radii: str | None = typer.Option(None, "--link-radii", help="Capsule radii (--length-unit) of base column, links 1..N and tool, comma-separated (default: estimated from the reach)."),
    body_check: bool = typer.Option(True, "--body-check/--no-body-check", help="Check the robot's body (self-collision, floor, keep-out boxes) at the poses and along the moves."),
    angle_unit: str | None = typer.Option(None, "--angle-unit", help="Joint unit of a .csv output: rad or deg (default: deg for a robot file declared in degrees, else rad)."),
    trigger: str = typer.Option("wait", "--trigger", help="Programs: at each pose wait the dwell (wait), pulse a digital output (do:N, RAPID do:NAME) or await a digital input (di:N)."),
    settle: float = typer.Option(0.5, "--settle", help="Programs: settle time (s) before a do:/di: trigger.", min=0.0),
    axis_signs: str | None = typer.Option(None, "--axis-signs", help="Programs: controller axis = sign × joint + offset, signs e.g. -1,1,1,-1,1,-1 (default: from the robot preset)."),
    axis_offsets: str | None = typer.Option(None, "--axis-offsets", help="Programs: controller axis zero offsets (deg), comma-separated (default 0)."),
    krl_vel_percent: float = typer.Option(20.0, "--krl-vel-percent", help="KRL programs: $VEL_AXIS in percent of each axis' maximum speed.", min=0.1, max=100.0),
    trajectory: bool = typer.Option(False, "--trajectory", help="Dynamic collection: a continuous joint trajectory through the N poses as waypoints (the tracker streams): .csv gets t_s and joints at --rate, programs the waypoints."),
    max_speed: float | None = typer.Option(None, "--max-joint-speed", help="Trajectory: joint speed limit (deg/s; mm/s prismatic; default --speed).", min=1e-6),
    max_accel: float | None = typer.Option(None, "--max-joint-accel", help="Trajectory: joint acceleration limit (deg/s²; mm/s² prismatic; default 2 × the speed limit per s).", min=1e-6),
    rate: float = typer.Option(250.0, "--rate", help="Trajectory: sample rate of the .csv output (Hz).", min=1.0),
    report: bool = typer.Option(False, "--report", help="Print predicted accuracy against the number of poses."),
    noise_mm: float = typer.Option(0.01, "--noise-mm", help="Report: tracker noise per axis (mm).", min=0.0),
    unmodelled_mm: float | None = typer.Option(None, "--unmodelled-mm", help="Report: RMS error a calibration cannot model (mm; default 0.15, or the model's own)."),
    plot: Path | None = typer.Option(None, "--plot", help="Report: write the accuracy-vs-N curve as a PNG."),
    report_max: int = typer.Option(2000, "--report-max", help="Report: largest N in the table.", min=10),
    force: bool = Force,
) -> None:
    """Plan which joint configurations to measure (I-optimal calibration core + space-filling for the
    networks, within the region and the tracker's line of sight), ordered for a short path."""
    from ..planning import Constraints, PlanningError, parse_box, parse_region
    from ..planning.select import active_poses, plan_poses

    if (robot is None) == (for_model is None):
        raise CLIError("plan: give either ROBOT or --for-model MODEL (exactly one)")
    from ..planning.programs import ProgramError, program_kind

    if out is None and not report:
        raise CLIError("plan: give -o JOINTS.csv (and/or --report)")
    kind = None
    if out is not None:
        check_output(out, (robot, for_model), force)
        try:
            kind = program_kind(out)
        except ProgramError as e:
            raise CLIError(str(e)) from None
        if kind == "krl":
            check_output(out.with_suffix(".dat" if out.suffix.lower() == ".src" else ".src"), (robot, for_model), force)
    if angle_unit not in (None, "rad", "deg"):
        raise CLIError(f"--angle-unit must be rad or deg, got {angle_unit!r}")
    if plot is not None:
        check_output(plot, (robot, for_model, out), force)
    if length_unit not in ("m", "mm"):
        raise CLIError(f"--length-unit must be m or mm, got {length_unit!r}")
    if measure not in ("position", "pose"):
        raise CLIError(f"--measure must be position or pose, got {measure!r}")
    f = 1e-3 if length_unit == "mm" else 1.0
    model = None
    if for_model is not None:
        model, rob = load_model_or_robot(for_model, base_link, tip_link)
        if model is None:
            raise CLIError(f"--for-model {for_model}: not a hykin model file")
    else:
        _, rob = load_model_or_robot(robot, base_link, tip_link)
    try:
        lo, hi = parse_region(rob, region) if region else (None, None)
        c = Constraints(
            lower=lo, upper=hi, box_m=parse_box(box, "--box", length_unit) if box else None,
            tracker_m=_vec3(tracker, "--tracker", f), max_incidence_deg=max_incidence,
            reflector_offset_m=_vec3(reflector_offset, "--reflector-offset", f),
            reflector_axis=_vec3(reflector_axis, "--reflector-axis"),
            keep_out_m=[parse_box(b, f"--keep-out {k + 1}", length_unit) for k, b in enumerate(keep_out or [])],
            floor_z_m=None if floor is None else floor * f, body=body_check,
            link_radii_m=None if link_radii is None else _floats(link_radii, "--link-radii") * f,
            max_tracker_distance_m=max_tracker_distance, length_unit=length_unit,
        ).check(rob)
        speeds = np.where(rob.revolute, np.radians(speed), speed * 1e-3)
        if model is not None:
            p = active_poses(model, n, c, seed=seed, pool=pool, speeds=speeds, dwell_s=dwell)
        else:
            p = plan_poses(rob, n, c, seed=seed, pool=pool, position_only=measure == "position", speeds=speeds,
                           dwell_s=dwell)
    except PlanningError as e:
        raise CLIError(str(e)) from None
    con = _console()
    tr = p.travel
    if c.tracker_m is None:
        con.print("note: no --tracker given: the line of sight to the tracker was not checked", highlight=False)
    if not body_check:
        con.print("note: --no-body-check: the robot's body was not checked (self-collision, floor, keep-out boxes, tracker inside it)",
                  highlight=False)
    dropped, via = p.info.get("dropped", 0), p.info.get("via", 0)
    if dropped:
        con.print(f"[yellow]warning:[/] {dropped} of {n} poses were left out: no collision-free move reaches them "
                  f"(relax --keep-out/--floor/--link-radii or plan more poses)", highlight=False)
    if via:
        con.print(f"{via} via poses (not measured) detour around collisions between consecutive poses", highlight=False)
    con.print(f"planned {n} poses from {p.n_feasible} feasible of {p.n_pool} candidates"
              + (f"; {p.info['criterion']}-optimal core of {p.info['core_size']} poses for {p.info['n_params']} identifiable "
                 f"parameters" if model is None else ""))
    con.print(f"measuring path: joint travel {tr['joint_rad']:.1f} rad, moves {tr['move_s'] / 60:.1f} min at {speed:g} deg/s, "
              f"total {tr['total_s'] / 3600:.2f} h with {dwell:g} s per pose")
    if model is None and n * p.id_model.rows_per_pose < p.info["n_params"]:
        con.print(f"[yellow]note:[/] {n} poses give {n * p.id_model.rows_per_pose} equations for {p.info['n_params']} "
                  f"parameters: a calibration needs at least {-(-p.info['n_params'] // p.id_model.rows_per_pose)} poses")
    if model is None:
        cr = p.criteria
        con.print(f"identifiability: log det M {cr['logdet']:.2f}, O1 {cr['O1']:.4g}, O3 {cr['O3']:.4g}, "
                  f"condition {cr['condition']:.4g}; coverage min spacing {cr['min_spacing']:.4f}")
    if trajectory and out is not None:
        _write_trajectory(out, kind, rob, robot, p, angle_unit, speed if max_speed is None else max_speed,
                          max_accel, rate, axis_signs, axis_offsets, krl_vel_percent)
    elif out is not None:
        _write_plan(out, kind, rob, robot, p, c, angle_unit, speed, dwell, trigger, settle, axis_signs, axis_offsets,
                    krl_vel_percent)
    if report:
        _report(rob, model, p, c, n, noise_mm, unmodelled_mm, plot, measure, seed, pool, speeds, dwell, report_max)


def _floats(text: str, what: str) -> np.ndarray:
    try:
        return np.array([float(x) for x in str(text).replace(";", ",").split(",")])
    except ValueError:
        raise CLIError(f"{what}: expected comma-separated numbers, got {text!r}") from None


def _declared_angle_unit(spec: str | None) -> str:
    """The ``angle_unit`` a robot TOML file declares ("rad" for presets, URDFs and models)."""
    p = Path(spec) if spec else None
    if p is None or not p.is_file() or p.suffix.lower() != ".toml":
        return "rad"
    from ..io.toml_compat import tomllib

    try:
        return str(tomllib.loads(p.read_text(encoding="utf-8")).get("angle_unit", "rad"))
    except (OSError, ValueError):
        return "rad"


def _joint_columns(rob, q: np.ndarray, unit: str) -> dict:
    rev = rob.revolute
    return {f"q{j + 1}{'_deg' if unit == 'deg' and rev[j] else ''}": q[:, j] * (np.degrees(1.0) if unit == "deg" and rev[j] else 1.0)
            for j in range(rob.dof)}


def _program_settings(out: Path, rob, axis_signs, axis_offsets, **kw):
    from ..planning.programs import ProgramSettings
    from .common import parse_axis_signs

    signs = parse_axis_signs(axis_signs, rob.dof)
    if signs is None:
        from ..compensation.branches import default_axis_signs

        signs = default_axis_signs(rob)
    offs = None if axis_offsets is None else np.radians(_floats(axis_offsets, "--axis-offsets"))
    if offs is not None and offs.shape != (rob.dof,):
        raise CLIError(f"--axis-offsets: expected {rob.dof} comma-separated values (deg), got {axis_offsets!r}")
    name = "".join(ch if ch.isalnum() or ch == "_" else "_" for ch in out.stem)[:24]
    name = name if name[:1].isalpha() else ("p" + name)[:24]
    return ProgramSettings(axis_signs=signs, axis_offsets_rad=offs, name=name, **kw)


def _write_programs(out: Path, kind: str, q, meas, rob, s) -> None:
    from ..planning.programs import ProgramError, plan_program

    try:
        texts = plan_program(kind, q, meas, rob, s)
    except ProgramError as e:
        raise CLIError(str(e)) from None
    out.parent.mkdir(parents=True, exist_ok=True)
    for suf, text in texts.items():
        path = out.with_suffix(suf) if kind == "krl" else out
        path.write_text(text, encoding="utf-8", newline="\n" if kind != "krl" else "\r\n")
        typer.echo(f"wrote {path}")


def _write_trajectory(out: Path, kind: str, rob, robot_spec, p, angle_unit, speed, accel, rate, axis_signs, axis_offsets,
                      krl_vel_percent) -> None:
    from ..planning.trajectory import min_jerk_trajectory

    rev = rob.revolute
    v = np.where(rev, np.radians(speed), speed * 1e-3)
    a = 2.0 * v if accel is None else np.where(rev, np.radians(accel), accel * 1e-3)
    tr = min_jerk_trajectory(p.moves.q, v, a)
    if kind == "csv":
        t, q = tr.sample(rate)
        unit = angle_unit or _declared_angle_unit(robot_spec)
        write_rows({"t_s": t, **_joint_columns(rob, q, unit)}, out)
        typer.echo(f"wrote a {tr.duration_s / 60:.1f} min trajectory through {len(tr.waypoints)} waypoints: {len(t)} samples "
                   f"at {rate:g} Hz to {out}" + (" (joint angles in degrees)" if unit == "deg" else " (joint angles in rad)"))
        return
    s = _program_settings(out, rob, axis_signs, axis_offsets, speed_rad_s=float(np.radians(speed)), dwell_s=0.0,
                          krl_vel_percent=krl_vel_percent, expected_s=tr.duration_s, stream=True)
    _write_programs(out, kind, tr.waypoints, np.zeros(len(tr.waypoints), bool), rob, s)
    typer.echo(f"{len(tr.waypoints)} waypoints, expected duration {tr.duration_s / 60:.1f} min at the joint limits given")


def _write_plan(out: Path, kind: str, rob, robot_spec, p, c, angle_unit, speed, dwell, trigger, settle, axis_signs,
                axis_offsets, krl_vel_percent) -> None:
    from ..planning.constraints import incidence_deg, reflector_pose

    mv = p.moves
    q, meas = mv.q, mv.measure
    n_meas = int(meas.sum())
    if kind == "csv":
        unit = angle_unit or _declared_angle_unit(robot_spec)
        rows = _joint_columns(rob, q, unit)
        step = np.zeros(len(q), np.int64)
        step[meas] = np.arange(1, n_meas + 1)
        rows["step"] = step
        rows["measure"] = meas
        core = np.zeros(len(q), bool)
        core[meas] = p.core
        rows["core"] = core
        if c.tracker_m is not None:
            pp, nn = reflector_pose(rob, q, c)
            rows["incidence_deg"] = incidence_deg(pp, nn, c.tracker_m)
        if p.score is not None:
            sc = np.full(len(q), np.nan)
            sc[meas] = p.score
            rows["score_mm"] = sc
        write_rows(rows, out)
        typer.echo(f"wrote {n_meas} poses ({int((~meas).sum())} via moves) to {out}"
                   + (" (joint angles in degrees: columns q<i>_deg)" if unit == "deg" else " (joint angles in rad)"))
        return
    s = _program_settings(out, rob, axis_signs, axis_offsets, speed_rad_s=float(np.radians(speed)), dwell_s=dwell,
                          trigger=trigger, settle_s=settle, krl_vel_percent=krl_vel_percent,
                          expected_s=float(p.travel["total_s"]))
    _write_programs(out, kind, q, meas, rob, s)
    typer.echo(f"{n_meas} poses, {int((~meas).sum())} via moves, expected measuring time {p.travel['total_s'] / 60:.1f} min")


def _console():
    from .common import console

    return console()


def _report(rob, model, p, c, n, noise_mm, unmodelled_mm, plot, measure, seed, pool, speeds, dwell, report_max) -> None:
    from ..planning.forecast import LEARNING_A, LEARNING_B, forecast_accuracy
    from ..planning.select import plan_poses
    from ..sim.sampling import uniform

    if model is not None:
        # the forecast is for a plan of that size for the model's robot; anchor the learning curve on the model
        meta = model.meta_ or {}
        cal = meta.get("calibration") or {}
        after = (cal.get("after") or {}).get("pos_rms_mm")
        u = float(after) if unmodelled_mm is None and after is not None else (0.15 if unmodelled_mm is None else unmodelled_mm)
        ntr = int(meta.get("n_total", 0) or 0)
        hyb = ((meta.get("metrics") or {}).get("val") or (meta.get("metrics") or {}).get("train") or {})
        learning = (LEARNING_A, LEARNING_B)
        h_mm = hyb.get("hybrid_pos_mean_mm")
        if ntr > 0 and h_mm:  # anchor the curve's level on the model's own error at its size
            learning = (float(h_mm) * ntr**LEARNING_B, LEARNING_B)
        base = plan_poses(rob, max(n, report_max), c, seed=seed, pool=pool, position_only=True, speeds=speeds, dwell_s=dwell,
                          safe_moves=False)
    else:
        u = 0.15 if unmodelled_mm is None else unmodelled_mm
        learning = (LEARNING_A, LEARNING_B)
        base = p if n >= report_max else plan_poses(rob, report_max, c, seed=seed, pool=pool, position_only=measure == "position",
                                                    speeds=speeds, dwell_s=dwell, safe_moves=False)
    q_test = uniform(rob, 2048, np.random.default_rng([seed, 29]), lower=c.lower, upper=c.upper)
    per_pose = base.travel["move_s"] / max(len(base.q), 1) + dwell
    ns = [m for m in (15, 30, 60, 100, 250, 500, 1000, 2000, 5000, 10000, n) if m <= len(base.q)]
    fc = forecast_accuracy(base.id_model, base.nested(), q_test, ns, noise_mm=noise_mm, unmodelled_mm=u,
                           learning=learning, seconds_per_pose=per_pose)
    typer.echo("predicted mean position error over the region (planned poses):")
    typer.echo(fc.table())
    if plot is not None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4))
        ax.loglog(fc.n, fc.calibrated_mm, "o-", label="calibrated model")
        ax.loglog(fc.n, fc.hybrid_mm, "s-", label="hybrid")
        ax.set_xlabel("planned poses N")
        ax.set_ylabel("predicted mean position error (mm)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        fig.tight_layout()
        plot.parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(plot, dpi=120)
        plt.close(fig)
        typer.echo(f"wrote {plot}")
