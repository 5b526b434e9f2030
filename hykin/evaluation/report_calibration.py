"""The report's calibration table: for every calibration parameter its nominal value, identified
value, deviation, posterior standard deviation, prior tolerance, unit and status, from a calibration
summary (the dict of :meth:`hykin.calibration.result.CalibrationResult.to_dict`, as a model file
stores it).

Status: the calibration's own per-parameter status (calibration with priors, docs/calibration-priors.md):
*identified*, *correlated with* the named partners (|posterior ρ| >= 0.99: the data tell their
combination, the priors the split), *held at prior* (not excited by the data: the robot file's value,
posterior std = prior tolerance) or *at bound 0* (a compliance held rigid, no std). A model file
written before the status existed gets a derived one (*held at nominal* where not identifiable,
*identified* otherwise). The *notes* column says whether an estimated deviation is significant
(> 3 σ), names further strong correlations (|ρ| > 0.9) and shows any per-parameter field the
calibration adds, so new fields show up without code here.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass

import numpy as np

from ..calibration.params import candidate_specs
from ..geometry import se3
from ..kinematics.compliance import compliance_of
from ..kinematics.robot import Robot

__all__ = ["CalibrationRow", "calibration_rows", "calibration_summary", "further_frames", "is_frame_parameter", "UNIT_SCALE"]

#: SI unit code -> (factor to the shown unit, shown unit)
UNIT_SCALE = {"m": (1e3, "mm"), "rad": (180 / math.pi, "deg"), "c": (1e6, "µrad/(N·m)")}
_KNOWN = {"name", "unit", "value", "std", "identifiable", "status", "posterior_std", "prior_std", "correlated_with"}
SIGNIFICANT_SIGMA = 3.0
#: deviations below these (SI: m, rad, rad/(N·m)) are at the level of floating-point rounding
NEGLIGIBLE = {"m": 1e-11, "rad": 1e-11, "c": 1e-14}


@dataclass
class CalibrationRow:
    """One parameter, in the shown unit: ``nominal`` / ``identified`` / ``std`` / ``prior`` None where not
    defined. ``state``: the calibration's status word ("identified", "correlated", "held at prior",
    "at bound 0"; "held at nominal" for a model file without statuses); ``status``: the shown cell
    (a correlated parameter names its partners)."""

    name: str
    nominal: float | None
    identified: float | None
    deviation: float | None  # None: no robot-file value to deviate from (a further station's or tool's frame)
    std: float | None
    prior: float | None
    unit: str
    state: str
    status: str
    notes: str

    @property
    def held(self) -> bool:
        """Kept at the robot file's value (greyed in the table)."""
        return self.state.startswith("held")

    def cells(self) -> list:
        return [self.name, self.nominal, self.identified, self.deviation, self.std, self.prior, self.unit, self.status,
                self.notes]


HEADER = ["parameter", "nominal", "identified", "deviation", "posterior std", "prior std", "unit", "status", "notes"]
#: the text columns of :data:`HEADER`
TEXT_COLS = {0, 6, 7, 8}


def _frame_values(T: np.ndarray) -> dict[str, float]:
    """x, y, z (m) and the rotation vector rx, ry, rz (rad) of a frame."""
    rv = se3.matrix_to_rotvec(np.asarray(T)[:3, :3])
    return dict(zip(("x", "y", "z", "rx", "ry", "rz"), [*np.asarray(T)[:3, 3], *rv]))


def parameter_values(robot: Robot) -> dict[str, float]:
    """SI value of every candidate calibration parameter of ``robot`` (name -> value): DH/MDH fields,
    base and tool frames (translation and rotation vector), URDF joint origins (xyz, rpy), compliances."""
    out: dict[str, float] = {}
    c = compliance_of(robot)
    fields = {"a": robot.a_m, "alpha": robot.alpha_rad, "d": robot.d_m, "theta": robot.theta_rad,
              "beta": robot.beta_rad if robot.beta_rad is not None else np.zeros(robot.dof)}
    for s in candidate_specs(robot, base=True, tool=True, compliance=True):
        if s.group in ("base", "tool"):
            out[s.name] = _frame_values(robot.base if s.group == "base" else robot.tool)[s.field]
        elif s.group == "geom":
            out[s.name] = float(fields[s.field][s.joint])
        elif s.group == "origin" and robot.origin_xyz_m is not None:
            k = ("x", "y", "z", "rx", "ry", "rz").index(s.field)
            src = robot.origin_xyz_m if k < 3 else robot.origin_rpy_rad
            out[s.name] = float(src[s.joint][k % 3])
        elif s.group == "comp":
            out[s.name] = float(c[s.joint])
    for j in range(robot.dof):  # beta is a candidate only for near-parallel axes
        out.setdefault(f"beta{j + 1}", float(fields["beta"][j]))
    return out


#: a further station's or tool's frame parameter: ``station[T2].x``, ``tool[smrB].rz``
_FRAME_ROW = re.compile(r"^(station|tool)\[(.+)\]\.(x|y|z|rx|ry|rz)$")


def is_frame_parameter(name: str) -> bool:
    """Whether ``name`` is a frame of the set-up (base, tool, further stations / tools, reflector offsets
    ``p2.x``) rather than one of the robot's own parameters (geometry, joint offsets, compliance)."""
    return name.startswith(("base.", "tool.", "station[", "tool[")) or re.match(r"^p\d+\.[xyz]$", name) is not None


def further_frames(calib: dict) -> dict[str, dict[str, np.ndarray]]:
    """The identified frames of the further stations and tools (no robot-file value): ``{"station": {label:
    (4, 4)}, "tool": {label: (4, 4)}}`` from the calibration's ``station_frames`` (station -> robot base;
    flange -> TCP), the reference (index 0) left out; empty without them."""
    sf = calib.get("station_frames") or {}
    out: dict[str, dict[str, np.ndarray]] = {"station": {}, "tool": {}}
    for kind, labs, frames in (("station", "station_labels", "station_bases"), ("tool", "tool_labels", "tool_frames")):
        for lab, T in list(zip(sf.get(labs) or [], sf.get(frames) or []))[1:]:
            out[kind][str(lab)] = np.asarray(T, dtype=np.float64).reshape(4, 4)
    return out


def _frame_row_values(name: str, frames: dict) -> tuple[float | None, str]:
    """``(identified SI value or None, note)`` of a further station's / tool's frame parameter: its value in
    the identified frame (x, y, z m; rotation vector rad, as for base and tool), and for the ``.x`` row
    the whole frame as ``hykin calibrate`` prints it (xyz mm, rpy deg)."""
    m = _FRAME_ROW.match(name)
    T = frames.get(m.group(1), {}).get(m.group(2)) if m else None
    if T is None:
        return None, "no robot-file value (a further station's or tool's frame)"
    what = "station -> robot base" if m.group(1) == "station" else "flange -> TCP"
    note = f"no robot-file value: the identified frame ({what}), not a deviation"
    if m.group(3) == "x":
        rpy = np.degrees(se3.matrix_to_rpy(T[:3, :3]))
        note += (f"; the frame: xyz {', '.join(f'{v:.4f}' for v in T[:3, 3] * 1e3)} mm, rpy "
                 f"{', '.join(f'{v:.4f}' for v in rpy)} deg")
    return _frame_values(T)[m.group(3)], note


def _correlated(calib: dict) -> dict[str, list[tuple[str, float]]]:
    out: dict[str, list[tuple[str, float]]] = {}
    for a, b, r in calib.get("strong_correlations") or []:
        out.setdefault(a, []).append((b, float(r)))
        out.setdefault(b, []).append((a, float(r)))
    return out


def _finite(v) -> float | None:
    return None if v is None or not np.isfinite(v) else float(v)


def _partners(pairs) -> str:
    return ", ".join(f"{b} (ρ {float(r):+.3f})" for b, r in sorted(pairs, key=lambda t: -abs(float(t[1]))))


def calibration_rows(calib: dict, nominal: Robot, calibrated: Robot | None = None) -> list[CalibrationRow]:
    """Rows of the calibration table for the summary ``calib`` of a calibration of ``nominal``
    (``calibrated``: the calibrated robot, for the identified values; without it nominal + deviation)."""
    nom = parameter_values(nominal)
    ide = parameter_values(calibrated) if calibrated is not None else {}
    strong = _correlated(calib)
    further = further_frames(calib)
    rows = []
    for p in calib.get("parameters", []):
        name, unit = p["name"], p.get("unit", "m")
        f, shown = UNIT_SCALE.get(unit, (1.0, unit))
        dev = float(p.get("value", 0.0))
        std = _finite(p.get("posterior_std", p.get("std")))
        ident = bool(p.get("identifiable", True))
        n0 = nom.get(name)
        n1 = ide.get(name, None if n0 is None or name.startswith(("base.", "tool.")) else n0 + dev)
        if _FRAME_ROW.match(name):  # no nominal: the identified frame, no deviation (as hykin calibrate prints it)
            rows.append(_further_row(p, name, unit, std, further, strong))
            continue
        state = str(p["status"]) if "status" in p else "identified" if ident else "held at nominal"
        partners = [(str(b), float(r)) for b, r in p.get("correlated_with") or []]
        if state == "correlated":
            status = "correlated with " + _partners(partners) if partners else state
        elif state == "held at nominal":
            status = "held at nominal (not identifiable from these poses)"
        else:
            status = state
        notes = []
        if state in ("identified", "correlated"):
            if std is None:
                notes.append("no std (at a bound)")
            elif abs(dev) < NEGLIGIBLE.get(unit, 0.0):
                notes.append("equals nominal (deviation at rounding level)")
            elif abs(dev) > SIGNIFICANT_SIGMA * std if std > 0 else dev != 0:
                notes.append("differs from nominal (> 3 σ)")
            else:
                notes.append("agrees with nominal (< 3 σ)")
        if ident and n0 is not None and n1 is not None and name.startswith(("base.", "tool.")) \
                and abs((n1 - n0) - dev) > 1e-9 * max(1.0, abs(n1)):  # a correction along the nominal frame's axes
            notes.append(f"deviation along the nominal {name.split('.')[0]} frame's axes; identified − nominal "
                         f"{(n1 - n0) * f:+.4g}")
        named = {b for b, _ in partners}
        more = [(b, r) for b, r in strong.get(name, []) if b not in named]
        if more:
            notes.append("strongly correlated with " + _partners(more))
        notes += [f"{k} {_note(v)}" for k, v in p.items() if k not in _KNOWN]
        prior = _finite(p.get("prior_std"))
        rows.append(CalibrationRow(
            name=name, nominal=None if n0 is None else n0 * f, identified=None if n1 is None else n1 * f,
            deviation=dev * f if ident else 0.0, std=None if std is None else std * f,
            prior=None if prior is None else prior * f, unit=shown, state=state, status=status, notes="; ".join(notes)))
    return rows


def _further_row(p: dict, name: str, unit: str, std, frames: dict, strong: dict) -> CalibrationRow:
    """The row of a further station's / tool's frame parameter: no nominal, no deviation, the identified
    value (mm / deg) and std; its notes name what the value is instead of a comparison with a nominal."""
    f, shown = UNIT_SCALE.get(unit, (1.0, unit))
    val, note = _frame_row_values(name, frames)
    state = str(p["status"]) if "status" in p else "identified" if p.get("identifiable", True) else "held at nominal"
    partners = [(str(b), float(r)) for b, r in p.get("correlated_with") or []]
    status = "correlated with " + _partners(partners) if state == "correlated" and partners else state
    notes = [note]
    more = [(b, r) for b, r in strong.get(name, []) if b not in {b for b, _ in partners}]
    if more:
        notes.append("strongly correlated with " + _partners(more))
    notes += [f"{k} {_note(v)}" for k, v in p.items() if k not in _KNOWN]
    prior = _finite(p.get("prior_std"))
    return CalibrationRow(name=name, nominal=None, identified=None if val is None else val * f, deviation=None,
                          std=None if std is None else std * f, prior=None if prior is None else prior * f, unit=shown,
                          state=state, status=status, notes="; ".join(notes))


def _note(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def _per_unit(rows: list[CalibrationRow], fmt) -> str:
    """The rows grouped by unit (lengths, angles, compliances: sizes in one unit compare), each group
    largest deviation first, joined with "; "."""
    units = sorted(dict.fromkeys(r.unit for r in rows), key=lambda u: {"mm": 0, "deg": 1}.get(u, 2))
    return "; ".join(fmt(sorted((r for r in rows if r.unit == u), key=lambda r: -abs(r.deviation))) for u in units)


def _before_words(calib: dict, before_mm: float, nominal_fitted: tuple[float, str] | None) -> str:
    """What the calibration's "before" residual is: the robot file as written, frame guesses included;
    beside it the nominal robot with fitted frames (``nominal_fitted``: ``(mean mm, where)``) when known."""
    further = any(further_frames(calib).values())
    s = ("the robot file as written, with its own base and tool" + (" (the further stations' and tools' frames from "
         "a first fit)" if further else ""))
    if nominal_fitted is None:
        return s + ": any error of those frames (the measuring instrument's place, a guessed tool) is in it, not only the robot's own"
    lead = (": most of it is the error of those frames (the measuring instrument's place, a guessed tool), not the "
            "robot's own error" if before_mm > 2.0 * nominal_fitted[0] else "")
    return s + f"{lead} (the nominal robot with base and tool fitted: {nominal_fitted[0]:.3g} mm {nominal_fitted[1]})"


def calibration_summary(calib: dict, rows: list[CalibrationRow], nominal_fitted: tuple[float, str] | None = None) -> list[str]:
    """Sentences on the calibration: what was identified, what was held, how well (the "before" residual named:
    the robot file as written; ``nominal_fitted``: ``(mean mm, where)`` of the nominal robot with fitted frames,
    the robot's own error, quoted beside it), the robot's own significant deviations (geometry, joint offsets,
    compliance) apart from the set-up's frames, what correlates."""
    n = len(rows)
    held = [r.name for r in rows if r.held]
    cor = [r.name for r in rows if r.state == "correlated"]
    bound = [r.name for r in rows if r.state == "at bound 0"]
    n_id = sum(r.state == "identified" for r in rows)
    sig = [r for r in rows if r.state == "identified" and r.std is not None and r.std > 0 and r.deviation is not None
           and abs(r.deviation) > SIGNIFICANT_SIGMA * r.std and "equals nominal" not in r.notes]
    sig.sort(key=lambda r: -abs(r.deviation) / r.std)
    own = [r for r in sig if not is_frame_parameter(r.name)]
    frames = [r for r in sig if is_frame_parameter(r.name)]
    b, a = calib.get("before") or {}, calib.get("after") or {}
    lst = lambda names: f" ({', '.join(names[:8])}{', …' if len(names) > 8 else ''})" if names else ""
    out = [f"Calibration: {n_id} of {n} parameters identified from {calib.get('n_samples', '?')} poses"
           f" ({'position only' if calib.get('position_only') else 'full pose'})"
           + (f"; {len(cor)} correlated (the data tell their combination, the priors the split){lst(cor)}" if cor else "")
           + (f"; {len(bound)} at the bound 0 (rigid){lst(bound)}" if bound else "")
           + f"; {len(held)} held{lst(held)}."]
    if "pos_mean_mm" in b and "pos_mean_mm" in a:
        s = f"On its own data the calibration takes the mean position residual from {b['pos_mean_mm']:.4g} mm to {a['pos_mean_mm']:.3g} mm"
        if "rot_mean_deg" in b and "rot_mean_deg" in a:
            s += f" and the orientation residual from {b['rot_mean_deg']:.4g}° to {a['rot_mean_deg']:.3g}°"
        s += f"; “before” is {_before_words(calib, float(b['pos_mean_mm']), nominal_fitted)}"
        out.append(s + ".")
    fmt = lambda rs: ", ".join(f"{r.name} {r.deviation:+.4g} {r.unit} (± {r.std:.2g})" for r in rs[:4])
    if own:
        out.append("Largest significant deviations of the robot's own parameters (geometry, joint offsets, compliance) "
                   f"from nominal, per unit: {_per_unit(own, fmt)}.")
    elif rows:
        out.append("No identified parameter of the robot's own (geometry, joint offsets, compliance) differs "
                   "significantly (> 3 σ) from its nominal value.")
    if frames:
        out.append(f"Frames of the set-up (the measuring instrument's place, the tool; not the robot's error) moved from "
                   f"the robot file's most: {fmt(frames)}.")
    sc = calib.get("strong_correlations") or []
    if sc:
        out.append(f"{len(sc)} pair(s) of parameters are strongly correlated (|ρ| > 0.9): their individual values are "
                   "uncertain, their combined effect is not (see the heatmap).")
    return out
