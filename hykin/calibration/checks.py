"""Refusals of a calibration that cannot be right (never a silent wrong robot).

:func:`hykin.calibration.calibrate.calibrate` ends with :func:`check_calibration`; it raises
:class:`hykin.calibration.result.CalibrationError` with one line saying what is wrong and what to check when

* the Levenberg–Marquardt did not converge (iteration cap reached while the cost still fell by
  more than ``1e-5`` relative per iteration, after the restarts);
* a parameter the data excite (estimated, not held at its prior: :mod:`hykin.calibration.priors`)
  deviates from the robot file beyond ``refuse_tolerances`` (4) of its prior tolerance, or beyond
  the bound of :data:`DEFAULT_MAX_DEVIATION` given explicitly for its kind: a wrong robot file,
  units or joint order make the fit bend the geometry by centimetres or degrees to absorb the
  mismatch. A parameter held at its prior never triggers it (it stays at the robot file), so an
  unexcited direction cannot cause a refusal;
* the residual after the fit is larger than any correct robot file could leave (RMS position
  ``residual_mm``, RMS orientation ``residual_deg``): an industrial arm with the right file,
  calibrated geometry, base, tool and compliance is within a few tenths of a millimetre.

Bounds (deviation from the robot file; SI in the code, mm/deg in the keys). ``length_mm``,
``angle_deg`` and ``joint_offset_deg`` apply only when given (``max_deviation`` / ``--max-deviation``);
by default the bound is ``refuse_tolerances`` x the prior tolerance, which is the same 20 mm /
2 deg / 5 deg with the default priors:

==================  =======  ==========================================================
key                 default  applies to
==================  =======  ==========================================================
length_mm           20       DH/MDH ``a``, ``d``; URDF origin ``x, y, z``
angle_deg           2        DH/MDH ``alpha``, ``beta``; URDF origin ``rx, ry, rz``
joint_offset_deg    5        DH/MDH ``theta`` (joint zero offsets)
deflection_deg      1        largest joint deflection under gravity ``c_i · tau_i`` over the data
                             (the compliance itself is not bounded: a joint with little gravity torque
                             in a robot file without payload mass gets a large, harmless ``c``)
tool_m              2        distance of the TCP (and every reflector) from the flange
residual_mm         3        RMS position residual after the calibration
residual_deg        1        RMS orientation residual after the calibration
orientation_conflict 3       a calibration with orientations leaves at most this times the position
                             RMS of the same calibration on the positions alone (the data's own noise
                             and model error; :mod:`hykin.calibration.consistency`)
==================  =======  ==========================================================

Base and tool are otherwise unbounded: they are what the calibration finds for data in a
tracker's frame (the default priors: base ``inf``, tool a 100 mm guess). A tolerance the user states
for them (``--prior base_mm=2 --prior base_deg=0.05``: a surveyed base) bounds the robot file's own
``[base]`` / ``[tool]`` like any other: more than ``refuse_tolerances`` of it away is refused, naming
the option that widens it. A residual no robot file leaves under a stated base names that base (data
in a tracker's own frame), and a tool offset beyond ``tool_m`` that the data do not determine
(undetermined, or ``tool_mm=inf``) names ``--prior tool_mm``, not the robot file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

__all__ = ["DEFAULT_MAX_DEVIATION", "check_calibration", "parse_max_deviation", "resolve_max_deviation"]

DEFAULT_MAX_DEVIATION: dict[str, float] = {
    "length_mm": 20.0,
    "angle_deg": 2.0,
    "joint_offset_deg": 5.0,
    "deflection_deg": 1.0,
    "tool_m": 2.0,
    "residual_mm": 3.0,
    "residual_deg": 1.0,
    "orientation_conflict": 3.0,
}

#: the one line of advice appended to every refusal
ADVICE = ("check the robot file (right robot, DH table), units (--length-unit/--angle-unit), tool, joint order and "
          "joint directions (a controller axis counting the other way: negate that joint's column)")


def parse_max_deviation(text: str | None) -> dict[str, float]:
    """``"length_mm=30,angle_deg=3"`` -> ``{"length_mm": 30.0, "angle_deg": 3.0}`` (ValueError on bad keys)."""
    from .priors import parse_kind_values

    return resolve_max_deviation(parse_kind_values(text, "--max-deviation", DEFAULT_MAX_DEVIATION))


def resolve_max_deviation(overrides: Mapping[str, float] | None) -> dict[str, float]:
    """The defaults with ``overrides`` applied; unknown kinds and non-positive values are refused."""
    out = dict(DEFAULT_MAX_DEVIATION)
    for k, v in dict(overrides or {}).items():
        if k not in DEFAULT_MAX_DEVIATION:
            raise ValueError(f"max_deviation: unknown kind {k!r}; kinds are {', '.join(DEFAULT_MAX_DEVIATION)}")
        v = float(v)
        if not (v > 0 and not math.isnan(v)):
            raise ValueError(f"max_deviation: {k} must be > 0, got {v}")
        out[k] = v
    return out


_FIELD_WORD = {"a": "length", "d": "offset", "alpha": "twist", "theta": "zero", "beta": "tilt"}


def _limit_of(spec, lim: dict, tol: float, refuse_tolerances: float, explicit, given=()) -> tuple[float, float, str] | None:
    """(bound in SI, display factor, display unit) for one parameter, None when unbounded. ``given``: the
    prior kinds the user stated (``base_mm`` ...): only those bound the robot file's own base and tool."""
    from .priors import PRIOR_KEY, kind_of

    kind = kind_of(spec)
    f, un = (1e3, "mm") if spec.unit == "m" else (180 / math.pi, "deg")
    if kind.startswith(("base", "tool")):
        # the defaults (base inf, a tool-sized 100 mm guess) bound nothing: a tracker's frame is metres from the file,
        # a file without [tool] decimetres from the tool. A stated survey (--prior base_mm=2) is a claim the data test.
        stated = spec.group in ("base", "tool") and PRIOR_KEY[kind] in given and math.isfinite(tol)
        return (refuse_tolerances * tol, f, un) if stated else None
    if kind == "compliance":  # the deflection check
        return None
    key = {"length": "length_mm", "joint_zero": "joint_offset_deg"}.get(kind, "angle_deg")
    if key in explicit or not math.isfinite(tol):
        return lim[key] / (1e3 if key == "length_mm" else 180 / math.pi), f, un
    return refuse_tolerances * tol, f, un


def _label(spec) -> str:
    if spec.group in ("geom", "origin") and spec.joint >= 0:
        return f"joint {spec.joint + 1} {_FIELD_WORD.get(spec.field, 'origin')} {spec.name}"
    return spec.name


def check_calibration(res, specs, lim: dict, *, still_falling: bool, deflection_rad=None, refuse_tolerances: float = 4.0,
                      explicit=(), given_priors: Mapping[str, float] | None = None, free_frames_mm: float | None = None) -> None:
    """Raise :class:`~hykin.calibration.result.CalibrationError` when ``res`` cannot be a correct calibration.

    res: the :class:`~hykin.calibration.result.CalibrationResult` (values relative to the robot file);
    specs: its parameter specs (``name, group, field, unit``); lim: resolved bounds;
    still_falling: the cost still fell materially in the last iteration (not converged);
    deflection_rad: ``(n,)`` largest gravity deflection of each joint over the data (or None);
    refuse_tolerances: tolerances beyond which an estimated parameter is refused; explicit: the kinds
    of ``lim`` the user gave (they bound their kind instead); given_priors: the prior kinds the user gave
    (``{"base_mm": 2}``): a finite ``base_*`` / ``tool_*`` among them bounds the robot file's base / tool
    like any tolerance, and is named as the likely cause of a residual no robot file leaves;
    free_frames_mm: the RMS the robot file leaves with base and tool fitted freely (the closed-form start),
    or None: the evidence for that cause.
    """
    from .result import CalibrationError

    given = {k: v for k, v in dict(given_priors or {}).items() if math.isfinite(v)}
    name = res.robot.name
    if not res.converged and still_falling:
        raise CalibrationError(
            f"calibration of {name!r} did not converge in {res.iterations} iterations "
            f"(residual {res.after['pos_rms_mm']:.3g} mm RMS): {ADVICE}; or raise max_iter")
    worst = None
    tols = res.prior_std if getattr(res, "prior_std", None) is not None else np.full(len(specs), np.inf)
    for s, v, m, t in zip(specs, res.values, res.identifiable, tols):
        if not m:  # held at its prior: the robot file's value, whatever the data
            continue
        lb = _limit_of(s, lim, float(t), refuse_tolerances, set(explicit), given)
        if lb is None:
            continue
        bound, f, un = lb
        if s.unit == "rad":  # an angle 360° away is the same angle
            v = (v + math.pi) % (2 * math.pi) - math.pi
        if abs(v) > bound and (worst is None or abs(v) / bound > worst[0]):
            worst = (abs(v) / bound, s, v * f, bound * f, un, abs(v) / t if math.isfinite(t) else math.nan, t * f)
    if worst is not None:
        _, sp, v, b, un, n_tol, t = worst
        tol_txt = f", {n_tol:.1f} tolerances of {t:.3g} {un}" if math.isfinite(n_tol) else ""
        if sp.group in ("base", "tool"):  # a stated frame (above): the data contradict it, not the robot file's joints
            from .priors import PRIOR_KEY, kind_of

            key = PRIOR_KEY[kind_of(sp)]
            raise CalibrationError(
                f"calibration of {name!r}: the data put {sp.name} {v:+.4g} {un} from the robot file's [{sp.group}], "
                f"{n_tol:.1f} tolerances of --prior {key}={t:g} (plausible: ±{b:.4g} {un}): the data contradict the "
                f"{sp.group} stated in the robot file with that tolerance: check the robot file's [{sp.group}] (the survey) "
                f"and the frame of the data, or widen --prior {key} (inf: the {sp.group} comes from the data)")
        rms = res.after["pos_rms_mm"]
        if rms > lim["residual_mm"]:  # the fit stopped far from the data: its amount is not what they want
            raise CalibrationError(
                f"calibration of {name!r}: {_label(sp)} went to {v:+.4g} {un} from the robot file{tol_txt} (plausible: "
                f"±{b:.4g} {un}) and the fit stopped there still leaving {rms:.3g} mm RMS (a correct robot file leaves < "
                f"{lim['residual_mm']:g} mm): the data want a different value, possibly far more; the data do not fit "
                f"this robot file: {ADVICE} (or widen --prior / --max-deviation)")
        raise CalibrationError(
            f"calibration of {name!r}: {_label(sp)} deviates {v:+.4g} {un} from the robot file{tol_txt} (plausible: "
            f"±{b:.4g} {un}); the data do not fit this robot file: {ADVICE} (or widen --prior / --max-deviation)")
    if deflection_rad is not None and np.max(deflection_rad) > math.radians(lim["deflection_deg"]):
        j = int(np.argmax(deflection_rad))
        raise CalibrationError(
            f"calibration of {name!r}: joint {j + 1} deflects up to {math.degrees(deflection_rad[j]):.3g} deg under gravity "
            f"(compliance c{j + 1} = {1e6 * (1.0 / res.robot.stiffness_nm_per_rad[j]):.4g} µrad/N·m; plausible: "
            f"<= {lim['deflection_deg']:g} deg); the data do not fit this robot file: {ADVICE} (masses, payload)")
    tool_len = float(np.linalg.norm(res.robot.tool[:3, 3]))
    if getattr(res, "point_offsets_m", None) is not None:  # further reflectors: as far from the flange
        pts = res.robot.tool[:3, :3] @ np.asarray(res.point_offsets_m).T + res.robot.tool[:3, 3:4]
        tool_len = max(tool_len, float(np.linalg.norm(pts, axis=0).max()))
    if tool_len > lim["tool_m"]:
        st = dict(zip(res.names, getattr(res, "status", None) or []))
        loose = [n for n in ("tool.x", "tool.y", "tool.z") if st.get(n) == "undetermined"]
        if loose or not math.isfinite(dict(given_priors or {}).get("tool_mm", 0.0)):  # the data, not the file
            sd = dict(zip(res.names, res.std))
            raise CalibrationError(
                f"calibration of {name!r}: the tool offset came out {tool_len:.3g} m from the flange (plausible: <= "
                f"{lim['tool_m']:g} m), " + (", ".join(f"{n} ± {sd[n] * 1e3:.4g} mm" for n in loose) or "with --prior tool_mm=inf")
                + ": the data do not determine the tool (measured at too few orientations, its offset does what the base "
                "does): give a finite --prior tool_mm (default 100) to hold it near the robot file's [tool], or measure "
                "the tool at more orientations")
        raise CalibrationError(
            f"calibration of {name!r}: the tool offset came out {tool_len:.3g} m from the flange (plausible: "
            f"<= {lim['tool_m']:g} m); the data do not fit this robot file: {ADVICE}")
    rms = res.after["pos_rms_mm"]
    if rms > lim["residual_mm"]:
        stated = [f"{k}={given[k]:g}" for k in ("base_mm", "base_deg") if k in given]
        if stated:  # a base held near the file's [base]: data in another frame (a tracker's) leave metres
            free = ("" if free_frames_mm is None or free_frames_mm >= rms else
                    f" (with base and tool fitted freely this robot file leaves {free_frames_mm:.3g} mm)")
            raise CalibrationError(
                f"calibration of {name!r} leaves {rms:.3g} mm RMS (a correct robot file leaves < {lim['residual_mm']:g} mm)"
                f"{free}: the data are likely not in the frame of the robot file's [base] that --prior {', '.join(stated)} "
                f"hold{'s' if len(stated) == 1 else ''}: for data in a tracker's own frame leave --prior base_mm / base_deg "
                f"at inf (the default); else {ADVICE}, and its [base]")
        raise CalibrationError(
            f"calibration of {name!r} leaves {rms:.3g} mm RMS (a correct robot file leaves < {lim['residual_mm']:g} mm): "
            f"the data do not fit this robot file: {ADVICE}")
    if "rot_rms_deg" in res.after and res.after["rot_rms_deg"] > lim["residual_deg"]:
        raise CalibrationError(
            f"calibration of {name!r} leaves {res.after['rot_rms_deg']:.3g} deg RMS orientation residual (a correct "
            f"robot file leaves < {lim['residual_deg']:g} deg): the data do not fit this robot file: {ADVICE}")
