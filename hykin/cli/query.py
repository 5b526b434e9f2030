"""Query commands: fk and ik on a model file or a robot."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import typer

from ..geometry import se3
from .common import (
    AngleUnit,
    BaseLink,
    CLIError,
    Force,
    LengthUnit,
    TipLink,
    UnitCheck,
    app,
    check_output,
    console,
    load_model_or_robot,
    temperature_of,
    warn_orientation_unmeasured,
    note_default_payload,
    warn_payload_no_effect,
    write_rows,
)

PAYLOAD_HELP = ("Payload mass (kg, at the TCP) for a file without a payload_kg column; a model file, or a robot file with joint stiffness, deflects "
                "the joints under it (default: the file's column, else the robot file's payload).")

@app.command("fk")
def fk_cmd(
    model: str = typer.Argument(..., help="Model file, robot file, URDF or preset (nominal FK)."),
    joints: Path = typer.Argument(..., help="CSV/Parquet with columns q1..qN (or a URDF's joint names)."),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    out: Path = typer.Option(..., "-o", "--out", help="Output poses (dataset columns q…, x,y,z,qw,qx,qy,qz)."),
    angle_unit: str = AngleUnit,
    length_unit: str = typer.Option("m", "--length-unit", help="Unit of prismatic joint columns (m or mm); the "
                                    "written poses are in m."),
    no_fade: bool = typer.Option(False, "--no-fade", help="Apply the network correction even outside the training region."),
    payload_kg: float | None = typer.Option(None, "--payload-kg", help=PAYLOAD_HELP),
    unit_check: bool = UnitCheck,
    station: str | None = typer.Option(
        None, "--station",
        help="Poses in this station's frame (a model fitted on data with a station column). Default: the model's own "
             "frame, i.e. that of its robot's [base] (with several stations: the reference station's, the one with "
             "the most training rows)."),
    tool: str | None = typer.Option(
        None, "--tool", help="Poses of this tool's TCP (a model fitted on data with a tool column). Default: the "
                             "model's own tool (with several tools: the reference tool, the one with the most training rows)."),
    force: bool = Force,
) -> None:
    """Forward kinematics: full hybrid model for a model file, classical FK for a robot."""
    from ..io.dataset import Dataset
    from ..io.dataset_files import read_joints, write_dataset
    from ..io.plausibility import check_joint_unit
    from ..kinematics.classical import classical_fk

    check_output(out, (model, joints), force)
    mdl, rob = load_model_or_robot(model, base_link, tip_link)
    q, extra = read_joints(joints, dof=rob.dof, angle_unit=angle_unit, length_unit=length_unit, robot=rob,
                           unit_check=unit_check)
    # measured further reflectors (x2, y2, z2, ...) would read as predicted ones beside the predicted x, y, z
    extra = {k: v for k, v in extra.items() if not (k[:1] in "xyz" and k[1:].isdigit())}
    if unit_check:
        check_joint_unit(rob, q, where=str(joints), angle_unit=angle_unit)
    warn_payload_no_effect(mdl, rob, payload_kg)
    note_default_payload(mdl, payload_kg, extra, joints)
    if mdl is None:
        if station is not None or tool is not None:
            raise CLIError(f"--station/--tool: {model} is a robot, not a model fitted on data with stations or tools")
        from ..io.payload import payload_from_columns, payload_kwargs

        # a robot file with joint stiffness (a calibrated one) deflects under its payload or the given one
        T = classical_fk(rob, q, **payload_kwargs(payload_from_columns(extra, len(q), str(joints), payload_kg)))
    else:
        from ..hybrid.stations import station_transform

        L, Rt = station_transform(mdl, station, tool)  # ValueError naming the model's stations / tools
        if no_fade:
            mdl.fade = False
        temp = temperature_of(mdl, extra, joints)
        from ..io.payload import payload_from_columns, payload_kwargs

        T = L @ mdl.predict(q, temperature_c=temp, **payload_kwargs(payload_from_columns(extra, len(q), str(joints), payload_kg))) @ Rt
        extra = dict(extra)
        extra["support_distance"] = mdl.support_distance(q)
        if mdl.unc_ is not None:  # an optional step of fit: a model may have no bands
            band_mm, band_deg = mdl.predict_uncertainty(q, temperature_c=temp)
            extra["pos_band95_mm"] = band_mm
            if band_deg is not None:
                extra["ang_band95_deg"] = band_deg
    write_dataset(Dataset.from_poses(q, T, extra=extra, source=str(joints)), out)
    warn_orientation_unmeasured(mdl, "the orientation columns written are that, not the robot's")
    fr = None if mdl is None else getattr(mdl, "station_frames_", None)
    where = (f"station {station!r}" if station is not None else f"the reference station {fr.reference_station!r}") if fr else ""
    where += f", tool {tool!r}" if tool is not None else f", reference tool {fr.tool_labels[0]!r}" if fr and len(fr.tool_labels) > 1 else ""
    # (a data file is SI: joints read in degrees are written back in radians, which the line says)
    rad = "; joints q1..qN in rad, as every hykin data file" if angle_unit == "deg" else ""
    typer.echo(f"wrote {len(q)} poses to {out}" + (f" (frame of {where})" if where else "") + rad)


@app.command("ik")
def ik_cmd(
    model: str = typer.Argument(..., help="Model file (hybrid IK) or robot file / preset (classical IK)."),
    poses: Path = typer.Argument(..., help="Target poses: x,y,z[,qw,qx,qy,qz] (m)."),
    base_link: str | None = BaseLink,
    tip_link: str | None = TipLink,
    out: Path = typer.Option(..., "-o", "--out", help="Output joints CSV: target, branch, q…, errors."),
    all_branches: bool = typer.Option(False, "--all-branches", help="Every solution branch, not only the nearest one."),
    turn_copies: int = typer.Option(8, "--turn-copies", min=1, max=4096, help="With --all-branches: list a solution's 2π copies within the joint limits (joints of more than a turn) when it has at most this many; a note counts those left out."),
    seed_joints: Path | None = typer.Option(None, "--seed-joints", help="CSV of current joints (one row per target, or one row)."),
    position_only: bool = typer.Option(False, "--position-only", help="Solve for position only."),
    length_unit: str = LengthUnit,
    angle_unit: str = AngleUnit,
    payload_kg: float | None = typer.Option(None, "--payload-kg", help=PAYLOAD_HELP),
    station: str | None = typer.Option(
        None, "--station", help="Targets in this station's frame (a model fitted on data with a station column; "
                                "a station column in the targets file names each row's). Default: the model's own frame."),
    tool: str | None = typer.Option(
        None, "--tool", help="Targets of this tool's TCP (a model fitted on data with a tool column; a tool column "
                             "in the targets file names each row's). Default: the model's own tool."),
    unit_check: bool = UnitCheck,
    force: bool = Force,
) -> None:
    """Inverse kinematics: every branch (or the one nearest the seed joints), failures reported.

    A target that is not solved gets one row with no joint values and a reason (out of reach, joint
    limits, singular, not converged)."""
    from ..io.dataset_files import read_joints, read_poses
    from ..io.plausibility import check_target_reach

    check_output(out, (model, poses, seed_joints), force)
    mdl, rob = load_model_or_robot(model, base_link, tip_link)
    T, has_rot, pose_extra = read_poses(poses, length_unit=length_unit, extras=True, unit_check=unit_check)
    T = _targets_in_model_frame(mdl, T, has_rot, pose_extra, station, tool, model, poses)
    if unit_check:
        check_target_reach(mdl.robot_ if mdl is not None else rob, T, where=str(poses), length_unit=length_unit,
                           frame=None if mdl is None else mdl.frame_pre_)
    position_only = position_only or not has_rot
    warn_payload_no_effect(mdl, rob, payload_kg)
    note_default_payload(mdl, payload_kg, pose_extra, poses)
    if not position_only:
        warn_orientation_unmeasured(mdl, "the targets' orientations are solved for that (--position-only ignores them)")
    q_cur = None
    if seed_joints is not None:
        q_cur, _ = read_joints(seed_joints, dof=rob.dof, angle_unit=angle_unit, length_unit=length_unit, robot=rob,
                               unit_check=unit_check)
        if len(q_cur) == 1:
            q_cur = np.repeat(q_cur, len(T), axis=0)
        elif len(q_cur) != len(T):
            raise CLIError(f"{seed_joints}: {len(q_cur)} rows, expected 1 or {len(T)} (one per target)")
    nearest = not all_branches
    if nearest and q_cur is None:
        q_cur = np.zeros((len(T), rob.dof))  # nearest to the zero pose when no seed is given
    if mdl is None and not rob.has_compliance:
        from ..kinematics.ik_rows import classical_ik_rows

        rows = classical_ik_rows(rob, T, q_cur if nearest else None, position_only, max_copies=turn_copies)
    elif mdl is None:  # joint stiffness: solved on the deflecting robot (the rigid closed form seeds it)
        from ..hybrid.ik import hybrid_ik, ik_result_to_rows
        from ..io.payload import payload_from_columns
        from ..kinematics.classical import ClassicalModel

        target = T[:, :3, 3] if position_only else T
        pl = payload_from_columns(pose_extra, len(T), str(poses), payload_kg)
        if pl is None:
            res = hybrid_ik(ClassicalModel(rob), target, all_branches=True, q_current=q_cur, nearest=nearest,
                            position_only=position_only)
            rows = ik_result_to_rows(res, robot=rob, targets=target)
        else:
            rows = _ik_rows_per_payload(lambda kg, com: ClassicalModel(rob, kg, com), target, pl, q_cur, nearest,
                                        position_only, None)
    else:
        from ..hybrid.ik import hybrid_ik, ik_result_to_rows
        from ..io.payload import payload_from_columns

        target = T[:, :3, 3] if position_only else T
        temp = temperature_of(mdl, pose_extra, poses)
        pl = payload_from_columns(pose_extra, len(T), str(poses), payload_kg)
        res = None
        if pl is None:
            res = hybrid_ik(mdl, target, all_branches=True, q_current=q_cur, nearest=nearest, position_only=position_only,
                            temperature_c=temp)
            rows = ik_result_to_rows(res, robot=mdl.robot_, targets=target)
        else:  # one solve per distinct payload, rows back in target order
            from ..io.payload import model_with_payload

            rows = _ik_rows_per_payload(lambda kg, com: model_with_payload(mdl, kg, com), target, pl, q_cur, nearest,
                                        position_only, temp)
        from ..hybrid.model import support_report

        qs = np.stack([np.asarray(rows[f"q{j + 1}"], dtype=np.float64) for j in range(rob.dof)], 1)
        has_q = np.isfinite(qs).all(axis=1)
        msg = support_report(mdl, qs[has_q])["message"] if has_q.any() else ""
        if msg:
            console().print(f"[yellow]warning:[/] {msg} (see the in_support column)")
    if all_branches:  # (classical_ik_rows listed the copies already)
        rows = _with_turn_copies(mdl, rob, rows, turn_copies, expand=not (mdl is None and not rob.has_compliance))
    write_rows(rows, out)
    ok = np.asarray(rows["success"], dtype=bool)
    n_targets = len(T)
    solved = len(set(np.asarray(rows["target"])[ok].tolist()))
    typer.echo(f"wrote {len(ok)} solution rows for {n_targets} targets to {out} ({solved} solved, {n_targets - solved} failed)")
    if nearest and seed_joints is not None and ok.any():
        _note_far_from_seed(rob, rows, q_cur, ok)


def _note_far_from_seed(rob, rows: dict, q_cur: np.ndarray, ok: np.ndarray) -> None:
    """A note where a solution nearest the seed joints lies more than 90° (a revolute joint) from them: on
    another branch than the seed's (probe s42 AR: where the seed's branch missed the tolerance at a stretched
    elbow, the wrist was turned 180°, without a word)."""
    from ..kinematics.ik_rows import far_from_seed, far_from_seed_note

    qs = np.stack([np.asarray(rows[f"q{j + 1}"], dtype=np.float64) for j in range(rob.dof)], 1)
    tgt = np.asarray(rows["target"], dtype=np.int64)
    far = ok & far_from_seed(rob, qs, q_cur[tgt])
    if far.any():
        console().print("note: " + far_from_seed_note(tgt[far], "their seed joints"), highlight=False, markup=False)


def _with_turn_copies(mdl, rob, rows: dict, max_copies: int, expand: bool = True) -> dict:
    """``--all-branches`` rows with each solution's 2π copies within the limits (up to ``max_copies`` per
    solution; a robot's and a ``periodic="wrap"`` model's poses repeat every turn), and a note counting
    those left out (probe s41 AK: 326 of 429 copies on a ±400° wrist were dropped without a word).
    ``expand=False``: rows that list their copies already (:func:`hykin.kinematics.ik_rows.classical_ik_rows`)."""
    from ..kinematics.ik_rows import expand_turn_copies, representations_per_solution, turn_copies_note

    robot = rob if mdl is None else mdl.robot_
    if mdl is not None and getattr(mdl, "periodic", "wrap") != "wrap":
        return rows
    if expand:
        rows = expand_turn_copies(robot, rows, max_copies)
    note = turn_copies_note(robot, rows, max_copies, how=f"--turn-copies {representations_per_solution(robot)} lists them")
    if note:
        typer.echo(note, err=True)
    return rows


def _targets_in_model_frame(mdl, T, has_rot: bool, extra: dict, station, tool, model, poses):
    """IK targets ``(N, 4, 4)`` given in a station's frame / of a tool's TCP (``--station``/``--tool``, or the
    targets file's ``station``/``tool`` columns per row) -> the model's own frame and tool, where it solves:
    ``inv(L) · T · inv(Rt)`` (:func:`hykin.hybrid.stations.station_transform`, what ``fk --station/--tool``
    applies). Targets in another station's frame were otherwise "out of reach" metres away."""
    from ..hybrid.stations import station_transform

    cols = {c: np.asarray(extra[c]).astype(str) for c in ("station", "tool") if c in extra}
    if mdl is None:
        if station is not None or tool is not None or cols:
            what = "--station/--tool" if station is not None or tool is not None else f"{poses}: the {'/'.join(cols)} column"
            raise CLIError(f"{what}: {model} is a robot, not a model fitted on data with stations or tools")
        return T
    st = cols.get("station", np.full(len(T), station, dtype=object) if station is not None else None)
    tl = cols.get("tool", np.full(len(T), tool, dtype=object) if tool is not None else None)
    if st is None and tl is None:
        return T
    if tl is not None and not has_rot:
        raise CLIError(f"{poses}: targets of another tool need their orientations (qw,qx,qy,qz): where that tool's "
                       "TCP lies depends on them")
    out = np.array(T, dtype=np.float64, copy=True)
    keys = list(zip(st if st is not None else [None] * len(T), tl if tl is not None else [None] * len(T)))
    for key in dict.fromkeys(keys):
        rows = np.array([k == key for k in keys])
        L, Rt = station_transform(mdl, *key)  # ValueError naming the model's stations / tools
        out[rows] = se3.invert(L) @ T[rows] @ se3.invert(Rt)
    return out


def _ik_rows_per_payload(carrying, target, pl, q_cur, nearest: bool, position_only: bool, temp) -> dict:
    """Hybrid IK rows when targets carry payloads: one solve per distinct (mass, centre of mass), on
    the model ``carrying(kg, com or None)`` returns for it; ``target`` numbering of the whole file."""
    from ..hybrid.ik import hybrid_ik, ik_result_to_rows
    from ..io.payload import payload_groups

    parts = []
    for idx, kg, com in payload_groups(pl):
        m = carrying(kg, com)
        t = None if temp is None else np.asarray(temp)[idx]
        res = hybrid_ik(m, target[idx], all_branches=True, q_current=None if q_cur is None else q_cur[idx],
                        nearest=nearest, position_only=position_only, temperature_c=t)
        r = ik_result_to_rows(res, robot=m.robot_, targets=target[idx])
        r["target"] = idx[np.asarray(r["target"], dtype=int)]
        parts.append(r)
    order = np.argsort(np.concatenate([p["target"] for p in parts]), kind="stable")
    return {k: np.concatenate([np.asarray(p[k]) for p in parts])[order] for k in parts[0]}
