"""The report's calibration table: for every calibration parameter its nominal value, identified
value, deviation, posterior standard deviation, unit and status, from a calibration summary (the
dict of :meth:`hykin.calibration.result.CalibrationResult.to_dict`, as a model file stores it).

Status: a ``status`` entry of the parameter wins when the calibration provides one (e.g. "held at
prior"); otherwise it is derived: *held at nominal* (not identifiable from these poses), *at a bound*
(no standard deviation), *identified* — with whether the deviation is significant (> 3 σ) and the
parameters it is strongly correlated with (|ρ| > 0.9). Any further per-parameter entries the
calibration adds (prior, …) appear in the *notes* column, so new fields show up without code here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..calibration.params import candidate_specs
from ..geometry import se3
from ..kinematics.compliance import compliance_of
from ..kinematics.robot import Robot

__all__ = ["CalibrationRow", "calibration_rows", "calibration_summary", "UNIT_SCALE"]

#: SI unit code -> (factor to the shown unit, shown unit)
UNIT_SCALE = {"m": (1e3, "mm"), "rad": (180 / math.pi, "deg"), "c": (1e6, "µrad/(N·m)")}
_KNOWN = {"name", "unit", "value", "std", "identifiable", "status", "posterior_std"}
SIGNIFICANT_SIGMA = 3.0
#: deviations below these (SI: m, rad, rad/(N·m)) are at the level of floating-point rounding
NEGLIGIBLE = {"m": 1e-11, "rad": 1e-11, "c": 1e-14}


@dataclass
class CalibrationRow:
    """One parameter, in the shown unit: ``nominal`` / ``identified`` None where not defined."""

    name: str
    nominal: float | None
    identified: float | None
    deviation: float
    std: float | None
    unit: str
    status: str
    notes: str
    held: bool

    def cells(self) -> list:
        return [self.name, self.nominal, self.identified, self.deviation, self.std, self.unit, self.status, self.notes]


HEADER = ["parameter", "nominal", "identified", "deviation", "posterior std", "unit", "status", "notes"]


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


def _correlated(calib: dict) -> dict[str, list[tuple[str, float]]]:
    out: dict[str, list[tuple[str, float]]] = {}
    for a, b, r in calib.get("strong_correlations") or []:
        out.setdefault(a, []).append((b, float(r)))
        out.setdefault(b, []).append((a, float(r)))
    return out


def calibration_rows(calib: dict, nominal: Robot, calibrated: Robot | None = None) -> list[CalibrationRow]:
    """Rows of the calibration table for the summary ``calib`` of a calibration of ``nominal``
    (``calibrated``: the calibrated robot, for the identified values; without it nominal + deviation)."""
    nom = parameter_values(nominal)
    ide = parameter_values(calibrated) if calibrated is not None else {}
    corr = _correlated(calib)
    rows = []
    for p in calib.get("parameters", []):
        name, unit = p["name"], p.get("unit", "m")
        f, shown = UNIT_SCALE.get(unit, (1.0, unit))
        dev = float(p.get("value", 0.0))
        std = p.get("posterior_std", p.get("std"))
        std = None if std is None or not np.isfinite(std) else float(std)
        ident = bool(p.get("identifiable", True))
        n0 = nom.get(name)
        n1 = ide.get(name, None if n0 is None or name.startswith(("base.", "tool.")) else n0 + dev)
        if "status" in p:
            status = str(p["status"])
        elif not ident:
            status = "held at nominal (not identifiable from these poses)"
        elif std is None:
            status = "identified, at a bound (no std)"
        elif abs(dev) < NEGLIGIBLE.get(unit, 0.0):
            status = "identified, equals nominal (deviation at rounding level)"
        else:
            sig = abs(dev) > SIGNIFICANT_SIGMA * std if std > 0 else dev != 0
            status = "identified, differs from nominal" if sig else "identified, agrees with nominal (< 3 σ)"
        if name in corr:
            status += "; correlated with " + ", ".join(f"{b} (ρ {r:+.2f})" for b, r in sorted(corr[name], key=lambda t: -abs(t[1])))
        notes = "; ".join(f"{k} {_note(v)}" for k, v in p.items() if k not in _KNOWN)
        rows.append(CalibrationRow(
            name=name, nominal=None if n0 is None else n0 * f, identified=None if n1 is None else n1 * f,
            deviation=dev * f if ident else 0.0, std=None if std is None else std * f, unit=shown,
            status=status, notes=notes, held=not ident or "held" in status))
    return rows


def _note(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def calibration_summary(calib: dict, rows: list[CalibrationRow]) -> list[str]:
    """Sentences on the calibration: what was identified, what was held, how well, what correlates."""
    n = len(rows)
    held = [r.name for r in rows if r.held]
    sig = [r for r in rows if not r.held and r.std is not None and r.std > 0 and abs(r.deviation) > SIGNIFICANT_SIGMA * r.std
           and "equals nominal" not in r.status]
    sig.sort(key=lambda r: -abs(r.deviation) / r.std)
    b, a = calib.get("before") or {}, calib.get("after") or {}
    out = [f"Calibration: {n - len(held)} of {n} parameters identified from {calib.get('n_samples', '?')} poses"
           f" ({'position only' if calib.get('position_only') else 'full pose'}); {len(held)} held"
           + (f" ({', '.join(held[:8])}{', …' if len(held) > 8 else ''})." if held else ".")]
    if "pos_mean_mm" in b and "pos_mean_mm" in a:
        s = f"On its own data the calibration takes the mean position residual from {b['pos_mean_mm']:.4g} mm to {a['pos_mean_mm']:.3g} mm"
        if "rot_mean_deg" in b and "rot_mean_deg" in a:
            s += f" and the orientation residual from {b['rot_mean_deg']:.4g}° to {a['rot_mean_deg']:.3g}°"
        out.append(s + ".")
    if sig:
        out.append("Largest significant deviations from nominal: " + ", ".join(
            f"{r.name} {r.deviation:+.4g} {r.unit} (± {r.std:.2g})" for r in sig[:4]) + ".")
    elif rows:
        out.append("No identified parameter differs significantly (> 3 σ) from its nominal value.")
    sc = calib.get("strong_correlations") or []
    if sc:
        out.append(f"{len(sc)} pair(s) of parameters are strongly correlated (|ρ| > 0.9): their individual values are "
                   "uncertain, their combined effect is not (see the heatmap).")
    return out
