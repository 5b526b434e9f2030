"""A measurement plan as a robot program: URScript, KUKA KRL, ABB RAPID (``hykin plan -o FILE``).

Each program moves joint-wise through the plan's moves in order (:class:`hykin.planning.moves.SafePath`:
measured poses and the via poses between them) and, at every measured pose, settles and triggers or
awaits the measurement:

* ``trigger="wait"``: wait ``dwell_s`` (the tracker measures on its own, e.g. on stillness);
* ``trigger="do:X"``: wait ``settle_s``, set digital output ``X`` high, wait ``dwell_s``, set it low
  (the tracker measures on the rising edge);
* ``trigger="di:X"``: wait ``settle_s``, then wait until digital input ``X`` is high (the tracker
  signals that it has measured).

Controller axes: ``A = sign · q + offset`` per joint (``axis_signs``, ``axis_offsets_rad``), the
convention of ``hykin compensate --axis-signs``. Joint moves use the syntax of each language's
reference:

* URScript: ``movej([j1, ..., j6], a=..., v=...)`` (rad, rad/s, rad/s²), ``sleep(s)``,
  ``set_standard_digital_out(n, True|False)``, ``while not get_standard_digital_in(n): sync() end``;
  the program is one ``def hykin_plan(): ... end``.
* KRL: a ``.src`` with ``DEF name()`` / ``END`` moving ``PTP XPk`` through ``E6AXIS`` points declared
  in the ``.dat`` (``DEFDAT name`` / ``ENDDAT``, axis angles in degrees), ``$VEL_AXIS[i]`` (percent of
  the axis' maximum speed: KRL has no joint speed in deg/s), ``WAIT SEC s``, ``$OUT[n]=TRUE``,
  ``WAIT FOR $IN[n]``.
* RAPID: ``MODULE`` / ``PROC main()`` with ``MoveAbsJ [[a1,...,a6],[9E9,...]]\\NoEOffs, v, fine, tool0;``
  (degrees), ``WaitTime s;``, ``SetDO name, 1;``, ``WaitDI name, 1;``.

Programs are written for 6-axis arms with revolute joints only (what the three languages' plain
joint moves address); other robots are refused with one line.

Every header states the robot, the number of poses and via moves, the speed, and the expected
measuring time.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["PROGRAM_SUFFIXES", "ProgramSettings", "ProgramError", "plan_program", "program_kind"]

#: output suffix -> program kind (``csv`` is the plain joints table)
PROGRAM_SUFFIXES = {".csv": "csv", ".script": "urscript", ".urscript": "urscript",
                    ".src": "krl", ".dat": "krl", ".mod": "rapid"}


class ProgramError(ValueError):
    """The plan cannot be written as the requested program (suffix, robot, trigger)."""


@dataclass
class ProgramSettings:
    """How a plan becomes a program (module docstring). Angles rad, times s.

    speed_rad_s: joint speed of the moves (URScript ``v``, RAPID ``v_ori``). accel_rad_s2: URScript
    ``a``. krl_vel_percent: KRL ``$VEL_AXIS``. dwell_s: wait per measured pose. settle_s: wait before
    a trigger. trigger: ``"wait"``, ``"do:X"`` or ``"di:X"``. axis_signs / axis_offsets_rad:
    ``(dof,)`` controller axes ``A = sign · q + offset``. name: program name. expected_s: the
    measuring time stated in the header. stream: a trajectory for dynamic collection: the robot
    moves through every row without stopping to measure (no dwell, no trigger; the tracker streams)."""

    speed_rad_s: float
    dwell_s: float
    trigger: str = "wait"
    settle_s: float = 0.5
    accel_rad_s2: float = 1.0
    krl_vel_percent: float = 20.0
    axis_signs: np.ndarray | None = None
    axis_offsets_rad: np.ndarray | None = None
    name: str = "hykin_plan"
    expected_s: float = 0.0
    stream: bool = False


def program_kind(path: str | Path) -> str:
    """``"csv"``, ``"urscript"``, ``"krl"`` or ``"rapid"`` from the output suffix; an unknown suffix
    raises :class:`ProgramError`."""
    suf = Path(path).suffix.lower()
    if suf not in PROGRAM_SUFFIXES:
        raise ProgramError(f"{path}: unknown output type {suf or '(no suffix)'!r}; use one of "
                           f"{', '.join(sorted(PROGRAM_SUFFIXES))}")
    return PROGRAM_SUFFIXES[suf]


def _trigger(trigger: str, kind: str) -> tuple[str, str]:
    if trigger == "wait":
        return "wait", ""
    m = re.fullmatch(r"(do|di):([A-Za-z_]\w*|\d+)", trigger or "")
    if m is None:
        raise ProgramError(f"--trigger: expected wait, do:X or di:X (X a digital output/input), got {trigger!r}")
    mode, sig = m.groups()
    if kind in ("urscript", "krl") and not sig.isdigit():
        raise ProgramError(f"--trigger {trigger}: {kind} addresses digital I/O by number, e.g. {mode}:1")
    if kind == "rapid" and sig.isdigit():
        raise ProgramError(f"--trigger {trigger}: RAPID addresses digital I/O by signal name, e.g. {mode}:doMeasure")
    return mode, sig


def _axes(q: np.ndarray, s: ProgramSettings) -> np.ndarray:
    sign = np.ones(q.shape[1]) if s.axis_signs is None else np.asarray(s.axis_signs, dtype=np.float64)
    off = np.zeros(q.shape[1]) if s.axis_offsets_rad is None else np.asarray(s.axis_offsets_rad, dtype=np.float64)
    return sign * q + off


def _header(comment: str, robot_name: str, n_meas: int, n_via: int, s: ProgramSettings, speed: str) -> list[str]:
    if s.stream:
        return [f"{comment} hykin measuring trajectory for robot {robot_name!r}: {n_meas + n_via} waypoints, the tracker streams",
                f"{comment} joint moves at {speed}; no stop to measure",
                f"{comment} expected measuring time: {s.expected_s / 60:.1f} min ({s.expected_s:.0f} s)",
                f"{comment} controller axes = sign * q + offset (signs and offsets as given to hykin plan)"]
    return [f"{comment} hykin measurement plan for robot {robot_name!r}: {n_meas} poses to measure, {n_via} via moves",
            f"{comment} joint moves at {speed}; {s.dwell_s:g} s dwell per pose; trigger: {s.trigger}",
            f"{comment} expected measuring time: {s.expected_s / 60:.1f} min ({s.expected_s:.0f} s)",
            f"{comment} controller axes = sign * q + offset (signs and offsets as given to hykin plan)"]


def _num(v: float, nd: int) -> str:
    out = f"{v:.{nd}f}"
    return "0." + "0" * nd if out.startswith("-") and float(out) == 0.0 else out


def _rows(lang: str, A: np.ndarray, measure: np.ndarray, s: ProgramSettings, comment: str, move, wait, out,
          await_in) -> list[str]:
    """The program body, one language's syntax given as functions: per row a comment, the joint move
    ``move(row_number, axes)``, then at a measured pose the trigger of ``s.trigger`` built from
    ``wait(seconds)``, ``out(signal, on)`` and ``await_in(signal)`` (each a list of lines)."""
    mode, sig = _trigger(s.trigger, lang)
    lines, k = [], 0
    for i, (a, m) in enumerate(zip(A, measure), start=1):
        if m:
            k += 1
            lines.append(f"{comment} pose {k}")
        else:
            lines.append(f"{comment} waypoint" if s.stream else f"{comment} via (not measured)")
        lines.append(move(i, a))
        if not m:
            continue
        if mode == "wait":
            lines += wait(s.dwell_s)
        elif mode == "do":
            lines += wait(s.settle_s) + out(sig, True) + wait(s.dwell_s) + out(sig, False)
        else:
            lines += wait(s.settle_s) + await_in(sig)
    return lines


def urscript(q: np.ndarray, measure: np.ndarray, robot_name: str, s: ProgramSettings) -> str:
    A = _axes(q, s)
    lines = _header("#", robot_name, int(measure.sum()), int((~measure).sum()), s,
                    f"{np.degrees(s.speed_rad_s):g} deg/s")
    lines.append(f"def {s.name}():")
    lines += _rows(
        "urscript", A, measure, s, "  #",
        lambda i, a: f"  movej([{', '.join(_num(x, 8) for x in a)}], a={s.accel_rad_s2:g}, v={s.speed_rad_s:.6g})",
        lambda t: [f"  sleep({t:g})"],
        lambda sig, on: [f"  set_standard_digital_out({sig}, {on})"],
        lambda sig: [f"  while not get_standard_digital_in({sig}):", "    sync()", "  end"])
    lines.append("end")
    return "\n".join(lines) + "\n"


def krl(q: np.ndarray, measure: np.ndarray, robot_name: str, s: ProgramSettings) -> tuple[str, str]:
    """``(src, dat)`` texts."""
    A = np.degrees(_axes(q, s))
    head = _header(";", robot_name, int(measure.sum()), int((~measure).sum()), s,
                   f"$VEL_AXIS {s.krl_vel_percent:g} % (time estimate at {np.degrees(s.speed_rad_s):g} deg/s)")
    src = ["&ACCESS RVP", f"DEF {s.name}( )"] + head
    src += [f"$VEL_AXIS[{i}]={s.krl_vel_percent:g}" for i in range(1, 7)]
    dat = ["&ACCESS RVP", f"DEFDAT {s.name}"] + head
    dat += [f"DECL E6AXIS XP{i}={{{', '.join(f'A{j + 1} {_num(x, 5)}' for j, x in enumerate(a))}, "
            "E1 0.0, E2 0.0, E3 0.0, E4 0.0, E5 0.0, E6 0.0}" for i, a in enumerate(A, start=1)]
    src += _rows("krl", A, measure, s, ";", lambda i, a: f"PTP XP{i}", lambda t: [f"WAIT SEC {t:g}"],
                 lambda sig, on: [f"$OUT[{sig}]={'TRUE' if on else 'FALSE'}"], lambda sig: [f"WAIT FOR $IN[{sig}]"])
    src.append("END")
    dat.append("ENDDAT")
    return "\n".join(src) + "\n", "\n".join(dat) + "\n"


def rapid(q: np.ndarray, measure: np.ndarray, robot_name: str, s: ProgramSettings) -> str:
    A = np.degrees(_axes(q, s))
    lines = [f"MODULE {s.name}"] + _header("  !", robot_name, int(measure.sum()), int((~measure).sum()), s,
                                           f"v_ori {np.degrees(s.speed_rad_s):g} deg/s")
    lines.append(f"  CONST speeddata vPlan := [500, {np.degrees(s.speed_rad_s):.4g}, 5000, 1000];")
    lines.append("  PROC main()")
    lines += _rows(
        "rapid", A, measure, s, "    !",
        lambda i, a: f"    MoveAbsJ [[{','.join(_num(x, 5) for x in a)}],[9E9,9E9,9E9,9E9,9E9,9E9]]\\NoEOffs, vPlan, fine, tool0;",
        lambda t: [f"    WaitTime {t:g};"], lambda sig, on: [f"    SetDO {sig}, {int(on)};"],
        lambda sig: [f"    WaitDI {sig}, 1;"])
    lines += ["  ENDPROC", "ENDMODULE"]
    return "\n".join(lines) + "\n"


def plan_program(kind: str, q: np.ndarray, measure: np.ndarray, robot, s: ProgramSettings) -> dict[str, str]:
    """Program texts by suffix (``{".script": text}``, KRL ``{".src": …, ".dat": …}``) for the moves
    ``q`` ``(M, dof)`` (rad) with ``measure`` ``(M,)`` bool (module docstring; with ``s.stream`` every
    row is a waypoint passed without measuring)."""
    q = np.asarray(q, dtype=np.float64)
    if s.stream:
        measure = np.zeros(len(q), bool)
    if robot.dof != 6 or robot.n_chain != robot.dof or any(t != "revolute" for t in robot.joint_type):
        raise ProgramError(f"{kind} programs are written for 6-axis arms with revolute joints; robot {robot.name!r} "
                           f"has {robot.n_chain} joints ({', '.join(robot.joint_type)}): write -o PLAN.csv instead")
    if not re.fullmatch(r"[A-Za-z][A-Za-z0-9_]{0,23}", s.name):
        raise ProgramError(f"program name {s.name!r}: use letters, digits and _ (at most 24, starting with a letter)")
    if kind == "urscript":
        return {".script": urscript(q, measure, robot.name, s)}
    if kind == "krl":
        src, dat = krl(q, measure, robot.name, s)
        return {".src": src, ".dat": dat}
    if kind == "rapid":
        return {".mod": rapid(q, measure, robot.name, s)}
    raise ProgramError(f"unknown program kind {kind!r}")
