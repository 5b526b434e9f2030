"""Outcome of a calibration: :class:`CalibrationResult` (parameters, uncertainties, residual
statistics, report) and :func:`residual_stats`. Produced by :func:`hykin.calibration.calibrate.calibrate`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..geometry.se3 import transform_to_xyzrpy
from ..kinematics.robot import Robot

__all__ = ["CalibrationResult", "frame_text", "orientation_weight_from_sigmas", "residual_stats"]

ORIENTATION_WEIGHT_BOUNDS = (1e-3, 1e3)
#: parameter-name prefixes of further stations' and tools' frames: they start from the data, not the robot file
_NO_FILE_VALUE = ("station[", "tool[")  # m/rad: the automatic weight stays within these


def frame_text(T: np.ndarray) -> str:
    """``xyz [x, y, z] mm, rpy [r, p, y] deg`` of a frame ``(4, 4)`` in the robot file's convention
    (:func:`hykin.geometry.se3.transform_to_xyzrpy`, as ``[base]`` / ``[tool]`` are written)."""
    xyz, rpy = transform_to_xyzrpy(np.asarray(T, dtype=np.float64))
    return (f"xyz [{', '.join(f'{v:.4f}' for v in xyz * 1e3)}] mm, "
            f"rpy [{', '.join(f'{v:.4f}' for v in np.degrees(rpy))}] deg")


def orientation_weight_from_sigmas(sigma_pos_m: float, sigma_rot_rad: float) -> float:
    """The automatic orientation weight ``w = σ_pos / σ_rot`` (m/rad) of the calibration and the
    registration, so each kind of residual counts by its noise; clipped to
    :data:`ORIENTATION_WEIGHT_BOUNDS` (``σ_rot`` is floored at 1e-12 rad)."""
    return float(np.clip(sigma_pos_m / max(sigma_rot_rad, 1e-12), *ORIENTATION_WEIGHT_BOUNDS))


def residual_stats(rp: np.ndarray, ro: np.ndarray | None, w: float) -> dict:
    """Mean / RMS / p95 / max of position residuals ``rp`` ``(N, 3)`` m (reported in mm) and of
    rotation residuals ``ro`` ``(N, 3)`` (weighted by ``w`` m/rad; reported in deg) or None."""
    e = np.linalg.norm(rp, axis=1) * 1e3
    d = {
        "pos_mean_mm": float(e.mean()), "pos_rms_mm": float(np.sqrt(np.mean(e * e))),
        "pos_p95_mm": float(np.percentile(e, 95)), "pos_max_mm": float(e.max()),
    }
    if ro is not None:
        a = np.degrees(np.linalg.norm(ro, axis=1) / w)
        d.update({
            "rot_mean_deg": float(a.mean()), "rot_rms_deg": float(np.sqrt(np.mean(a * a))),
            "rot_p95_deg": float(np.percentile(a, 95)), "rot_max_deg": float(a.max()),
        })
    return d



class CalibrationError(ValueError):
    """Bad input to :func:`hykin.calibration.calibrate.calibrate` (shapes, non-finite values, unknown parameter
    names) or a calibration refused by :mod:`hykin.calibration.checks`."""


@dataclass
class CalibrationResult:
    """Outcome of :func:`calibrate`.

    robot: the calibrated robot (geometry, base, tool, ``stiffness_nm_per_rad = 1 / c``).
    names: parameter names (priority order); values: deviations from the input robot (SI: m, rad,
    rad/N·m; base/tool/URDF-origin deviations as ``(x, y, z, rx, ry, rz)`` of ``T0⁻¹ T``); std:
    posterior standard deviations (:mod:`hykin.calibration.priors`; a parameter held at its prior has
    its prior tolerance, nan where that is uninformative or at a bound); identifiable: bool mask of
    the parameters estimated from the data (the data excite them; ``status`` tells which of those are
    ``"correlated"``). status: per parameter ``"identified"``, ``"correlated"`` (|posterior
    correlation| >= 0.99 with the parameters in ``correlated_with``: the data tell their combination,
    the priors the split), ``"undetermined"`` (estimated, but the posterior std reaches half the
    tolerance, or for an uninformative one half its kind's geometry tolerance: the data hardly tell it,
    :func:`hykin.calibration.posterior.statuses`), ``"held at prior"`` (not excited by the data: the
    robot file's value) or ``"at bound 0"`` (a compliance held rigid). prior_std: ``(P,)`` prior tolerances (SI; inf =
    uninformative). correlated_with: per parameter ``[(name, rho)]``.
    correlation: ``(k, k)`` among the estimated parameters, ``correlation_names`` order (identifiable
    ones that did not end at a bound: a compliance at 0 has no std).
    strong_correlations: ``(name_i, name_j, rho)`` with ``|rho| > 0.9``.
    before / after: residual statistics on the calibration data (``pos_mean_mm``, ``pos_rms_mm``,
    ``pos_p95_mm``, ``pos_max_mm`` and the ``rot_*_deg`` twins for full-pose data).
    sigma_pos_m / sigma_rot_rad: residual standard deviations per coordinate after calibration.
    point_offsets_m: ``(K, 3)`` offsets of every reflector from the TCP (= reflector 1), TCP frame
    (``p_k = T_tcp · point_offsets_m[k]``); one zero row for one point per pose.
    """

    robot: Robot
    names: list[str]
    values: np.ndarray
    std: np.ndarray
    identifiable: np.ndarray
    correlation: np.ndarray
    strong_correlations: list[tuple[str, str, float]]
    before: dict
    after: dict
    iterations: int
    converged: bool
    message: str
    units: list[str] = field(default_factory=list)
    correlation_names: list[str] = field(default_factory=list)
    n_samples: int = 0
    position_only: bool = False
    orientation_weight_m_per_rad: float = 1.0
    sigma_pos_m: float = float("nan")
    sigma_rot_rad: float = float("nan")
    seconds: float = 0.0
    point_offsets_m: np.ndarray | None = None
    #: several stations / tools: every station's and tool's frame (:class:`hykin.calibration.stations.StationFrames`)
    station_frames: object | None = None
    status: list[str] = field(default_factory=list)
    prior_std: np.ndarray | None = None
    correlated_with: list = field(default_factory=list)
    #: rows far off the calibrated model (:class:`hykin.calibration.outliers.Outliers`; row indices into the data given)
    outliers: object | None = None
    #: notes for the user (e.g. :func:`hykin.calibration.priors.precise_data_note`)
    notes: list = field(default_factory=list)
    #: warnings on what the data did not cover (a joint never moved, the tool at one orientation:
    #: :func:`hykin.calibration.coverage.coverage_warnings`); the calibrated robot holds only where the data were taken
    coverage: list = field(default_factory=list)
    #: ``(P,)`` each parameter's RMS effect on the data per tolerance that no other explains, in excitation
    #: floors, at the solution (:func:`hykin.calibration.priors.excitation`; inf: uninformative; 0 where
    #: the data cannot tell it whatever the floor: a rank-deficient column); None: not computed
    effect_floors: np.ndarray | None = None

    @property
    def identified_names(self) -> list[str]:
        """Parameters identified by the data (excited and not correlated at >= 0.99 with another)."""
        st = self.status or ["identified" if m else "held at prior" for m in self.identifiable]
        return [n for n, s in zip(self.names, st) if s == "identified"]

    @property
    def held_names(self) -> list[str]:
        """Parameters held at the robot file's value (the data do not excite them)."""
        return [n for n, s in zip(self.names, self.status) if s == "held at prior"]

    @property
    def rms_before_mm(self) -> float:
        return self.before["pos_rms_mm"]

    @property
    def rms_after_mm(self) -> float:
        return self.after["pos_rms_mm"]

    def value(self, name: str) -> float:
        """Identified deviation of parameter ``name`` (SI)."""
        return float(self.values[self.names.index(name)])

    def summary(self) -> str:
        """One line: how many parameters are identified / correlated / held at prior, and which are held."""
        st = self.status or ["identified" if m else "held at prior" for m in self.identifiable]
        held = [n for n, s in zip(self.names, st) if s == "held at prior"]
        cor = [n for n, s in zip(self.names, st) if s == "correlated"]
        und = [n for n, s in zip(self.names, st) if s == "undetermined"]
        return (f"calibration: {len(self.identified_names)} identified, {len(cor)} correlated"
                + (f" ({', '.join(cor)})" if cor else "")
                + (f", {len(und)} undetermined ({', '.join(und)})" if und else "") + f", {len(held)} held at prior"
                + (f" ({', '.join(held)})" if held else "") + f"; {self.after['pos_rms_mm']:.4g} mm RMS"
                + ("" if self.outliers is None else f"; {len(self.outliers.rows)} outlier rows "
                   + ("left out" if self.outliers.dropped else "kept")))

    def report(self) -> str:
        """Human-readable table (lengths in mm, angles in deg, compliance in µrad/(N·m)): deviation from
        the robot file, posterior std, prior tolerance and status of every parameter; then the residuals,
        the frames as written to the robot file (xyz mm, rpy deg) and every station's / tool's frame.

        Frame rows (``base.*``, ``tool.*``) are the deviation twist from the robot file's frame, not rpy:
        translation and rotation vector of ``T_file⁻¹ · T`` (in the file frame's axes). Further stations'
        and tools' rows (``station[B].*``, ``tool[T].*``) have no robot-file value: their deviation column
        is ``-`` (the fit started from a frame of its own) and their frames are listed below the table."""
        n_id = len(self.identified_names)
        n_est = int(np.sum(self.identifiable))
        lines = [
            f"Calibration of {self.robot.name!r}: {self.n_samples} samples, "
            f"{'position only' if self.position_only else f'full pose (w = {self.orientation_weight_m_per_rad:g} m/rad)'}, "
            f"{n_id} identified, {sum(st == 'correlated' for st in self.status) if self.status else n_est - n_id} correlated, "
            + (f"{sum(st == 'at bound 0' for st in self.status)} at bound 0, " if "at bound 0" in self.status else "")
            + (f"{sum(st == 'undetermined' for st in self.status)} undetermined, " if "undetermined" in self.status else "")
            + f"{len(self.names) - n_est} held at prior (of {len(self.names)}), "
            f"{self.iterations} iterations, {'converged' if self.converged else 'NOT converged'} ({self.message}), "
            f"{self.seconds:.2f} s",
            f"{'parameter':<10} {'deviation':>14} {'std':>12} {'prior':>10}  {'unit':<9} status",
        ]
        status = self.status or ["identified" if m else "held at prior" for m in self.identifiable]
        prior = self.prior_std if self.prior_std is not None else np.full(len(self.names), np.nan)
        cw = self.correlated_with or [[] for _ in self.names]
        held = {n for n, s in zip(self.names, status) if s == "held at prior"}
        by_held = False
        for n, v, s, u, st, p, c in zip(self.names, self.values, self.std, self.units, status, prior, cw):
            f, un = {"m": (1e3, "mm"), "rad": (180 / math.pi, "deg"), "c": (1e6, "µrad/N·m")}[u]
            ss = f"{s * f:12.6f}" if np.isfinite(s) else f"{'-':>12}"
            ps = f"{p * f:10.4g}" if np.isfinite(p) else f"{'none':>10}"
            vs = f"{'-':>14}" if n.startswith(_NO_FILE_VALUE) else f"{v * f:14.6f}"
            if st == "correlated":
                st = "correlated with " + ", ".join(f"{a} ({r:+.3f}{'; held at prior' if a in held else ''})" for a, r in c)
                by_held = by_held or any(a in held for a, _ in c)
            lines.append(f"{n:<10} {vs} {ss} {ps}  {un:<9} {st}")
        if any(n.startswith(("base.", "tool.")) for n in self.names):
            lines.append("base.* / tool.* rows: deviation twist from the robot file's frame T_file (not rpy): x, y, z "
                         "(mm) and rx, ry, rz (deg, rotation vector) of T_file^-1 · T; the frames themselves: below")
        if any(n.startswith(_NO_FILE_VALUE) for n in self.names):
            lines.append("station[..] / tool[..] rows: no robot-file value (deviation -); std of the same twist "
                         "at the solution; the frames themselves: below")
        if "undetermined" in status:
            lines.append("undetermined: estimated, but its std is at least half its tolerance (uninformative: half its kind's "
                         "length / angle tolerance): the data hardly tell it, it is not identified")
        if by_held:
            lines.append("correlated with a parameter held at prior: that parameter's tolerance, propagated through the "
                         "fit, makes at least 98 % of the std (the data tell the combination, the robot file the split)")
        lines.append(f"{'':<10} {'before':>14} {'after':>12}")
        for key, lab in (("pos_mean_mm", "pos mean mm"), ("pos_p95_mm", "pos p95 mm"), ("pos_max_mm", "pos max mm"),
                         ("rot_mean_deg", "rot mean deg"), ("rot_p95_deg", "rot p95 deg"), ("rot_max_deg", "rot max deg")):
            if key in self.before:
                lines.append(f"{lab:<14} {self.before[key]:10.6f} {self.after[key]:12.6f}")
        lines.append("identified at the solution: " + (", ".join(self.identified_names) or "none"))
        if self.outliers is not None:
            lines.append("outliers: " + self.outliers.message())
        fr = self.station_frames
        if fr is not None:  # several stations / tools: every frame (hykin.calibration.stations)
            for kind, labels, Ts in (("station", fr.station_labels, fr.station_bases), ("tool", fr.tool_labels, fr.tool_frames)):
                if len(labels) > 1:
                    xyz, rpy = transform_to_xyzrpy(np.asarray(Ts))
                    lines.append(f"{kind} frames (xyz m, rpy deg; {'station -> robot base' if kind == 'station' else 'flange -> TCP'}"
                                 f", first = reference): " + "; ".join(
                                     f"{lab}: [{', '.join(f'{v:.6f}' for v in p)}] [{', '.join(f'{v:.4f}' for v in np.degrees(r))}]"
                                     for lab, p, r in zip(labels, xyz, rpy)))
        lines.append(f"frames of the calibrated robot, as written to the robot file: base (measurement frame -> robot "
                     f"base) {frame_text(self.robot.base)}; tool (flange -> TCP) {frame_text(self.robot.tool)}")
        held = [n for n, s in zip(self.names, status) if s == "held at prior"]
        if held:
            lines.append("held at prior (the data do not excite them; the robot file's value): " + ", ".join(held))
        if self.strong_correlations:
            lines.append("strong correlations (|rho| > 0.9): " + ", ".join(
                f"{a}~{b} {r:+.3f}" for a, b, r in self.strong_correlations))
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-able summary (SI units)."""
        f = lambda x: None if not np.isfinite(x) else float(x)
        return {
            "robot": self.robot.name,
            "n_samples": self.n_samples,
            "position_only": self.position_only,
            "orientation_weight_m_per_rad": self.orientation_weight_m_per_rad,
            "parameters": [
                {"name": n, "unit": u, "value": float(v), "std": f(s), "identifiable": bool(m), "status": st,
                 "prior_std": f(p), "correlated_with": [[a, float(r)] for a, r in c]}
                for n, u, v, s, m, st, p, c in zip(
                    self.names, self.units, self.values, self.std, self.identifiable,
                    self.status or ["identified" if m else "held at prior" for m in self.identifiable],
                    self.prior_std if self.prior_std is not None else np.full(len(self.names), np.nan),
                    self.correlated_with or [[] for _ in self.names])
            ],
            "identified_names": self.identified_names,
            "correlation_names": self.correlation_names,
            "correlation": self.correlation.tolist(),
            "strong_correlations": [[a, b, float(r)] for a, b, r in self.strong_correlations],
            "before": self.before,
            "after": self.after,
            "sigma_pos_m": f(self.sigma_pos_m),
            "sigma_rot_rad": f(self.sigma_rot_rad),
            "iterations": self.iterations,
            "converged": self.converged,
            "message": self.message,
            "seconds": self.seconds,
            "point_offsets_m": None if self.point_offsets_m is None else np.asarray(self.point_offsets_m).tolist(),
            "station_frames": None if self.station_frames is None else self.station_frames.to_dict(),
            "outliers": None if self.outliers is None else self.outliers.to_dict(),
            "coverage": list(getattr(self, "coverage", None) or []),  # a joint never moved, one tool orientation
        }


