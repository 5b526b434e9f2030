"""Virtual robots: a known "real" robot behind a classical model, and its simulated measurements.

A :class:`VirtualRobot` pairs the classical model a user has (``nominal``) with the robot that
"really" moves (``truth``: geometric deviations, base/tool frame errors, joint stiffness, masses,
centres of mass and payload), plus optional non-geometric effects:

* periodic transmission errors (:class:`PeriodicError`): the link-side joint angle is
  ``q + A sin(order * gear_ratio * q + phase)`` — harmonics of the joint angle (``gear_ratio = 1``)
  or of a gear stage turning ``gear_ratio`` times faster;
* thermal drift (:class:`ThermalDrift`): all link lengths (a, d, tool offset) expand by
  ``1 + coefficient * (T - reference)``, which scales the TCP position in the robot base frame by
  that factor (exact for the rigid chain; the deflection is computed at reference temperature,
  a 1e-5 relative effect on a 1e-3 effect); temperature follows a warm-up profile over the sample
  index or is given per sample;
* measurement noise: isotropic Gaussian, ``noise_position_m`` per axis (m) and
  ``noise_orientation_rad`` per axis of a rotation vector applied in the base frame (rad).

The true pose is ``fk(truth, deflected_joints(truth, q + transmission_error(q)))`` (thermal scaling
next, then noise). :func:`simulate` turns joints into a :class:`hykin.io.dataset.Dataset`;
:func:`save_truth` / :func:`load_truth` keep the truth beside the data (JSON, SI units).

Presets of virtual robots live in :mod:`hykin.sim.presets`; :func:`hykin.sim.generate.simulate_to_file`
writes a simulated dataset and its truth file.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import se3
from ..io.robot_codec import robot_from_json, robot_to_json
from ..kinematics.compliance import deflected_joints
from ..kinematics.fk import fk
from ..kinematics.robot import Robot

__all__ = [
    "PeriodicError",
    "SimulationError",
    "ThermalDrift",
    "VirtualRobot",
    "dataset_error",
    "geometric_deviation",
    "load_truth",
    "mass_deviation",
    "save_truth",
    "simulate",
    "transmission_error",
    "true_poses",
    "truth_path_for",
]


class SimulationError(ValueError):
    """Bad virtual-robot definition, preset name, truth file or simulation input."""


@dataclass
class PeriodicError:
    """Periodic transmission error of one joint: ``A sin(order * gear_ratio * q + phase)`` (rad).

    joint: 1-based joint number. amplitude_rad: A. order: harmonic order. gear_ratio: 1 for
    harmonics of the joint angle, the stage ratio for harmonics of a faster gear stage.
    """

    joint: int
    amplitude_rad: float
    order: float = 1.0
    gear_ratio: float = 1.0
    phase_rad: float = 0.0


@dataclass
class ThermalDrift:
    """Thermal expansion of the link lengths.

    coefficient_per_k: linear expansion coefficient (1/K; steel 11.5e-6, aluminium 23e-6).
    reference_c: temperature of the nominal geometry (°C). Warm-up profile over the sample index i:
    ``T(i) = start_c + (end_c - start_c) * (1 - exp(-i / time_constant_samples))``.
    """

    coefficient_per_k: float = 11.5e-6
    reference_c: float = 20.0
    start_c: float = 20.0
    end_c: float = 26.0
    time_constant_samples: float = 20_000.0

    def temperature_c(self, index) -> np.ndarray:
        """Temperature (°C) at sample indices ``index`` ``(N,)``."""
        i = np.asarray(index, dtype=np.float64)
        tau = max(float(self.time_constant_samples), 1e-12)
        return self.start_c + (self.end_c - self.start_c) * (1.0 - np.exp(-i / tau))

    def scale(self, temperature_c) -> np.ndarray:
        """Length scale factor ``1 + coefficient * (T - reference)``, ``(N,)``."""
        return 1.0 + self.coefficient_per_k * (np.asarray(temperature_c, dtype=np.float64) - self.reference_c)


@dataclass
class VirtualRobot:
    """A virtual robot: the classical model (``nominal``) and the robot that really moves (``truth``).

    transmission: periodic transmission errors; thermal: thermal drift or ``None``;
    noise_position_m / noise_orientation_rad: measurement noise σ per axis; description: text;
    seed: seed the preset was drawn with (also the default noise seed of :func:`simulate`).
    """

    name: str
    nominal: Robot
    truth: Robot
    transmission: list[PeriodicError] = field(default_factory=list)
    thermal: ThermalDrift | None = None
    noise_position_m: float = 0.0
    noise_orientation_rad: float = 0.0
    description: str = ""
    seed: int = 0

    def __post_init__(self) -> None:
        if self.nominal.dof != self.truth.dof:
            raise SimulationError(f"virtual robot {self.name!r}: nominal has {self.nominal.dof} joints, truth {self.truth.dof}")
        for e in self.transmission:
            if not 1 <= int(e.joint) <= self.truth.dof:
                raise SimulationError(f"virtual robot {self.name!r}: transmission error on joint {e.joint}, robot has {self.truth.dof}")
        for nm in ("noise_position_m", "noise_orientation_rad"):
            v = float(getattr(self, nm))
            if not (v >= 0 and math.isfinite(v)):
                raise SimulationError(f"virtual robot {self.name!r}: {nm} must be finite and >= 0, got {v}")
            setattr(self, nm, v)


# --------------------------------------------------------------------------- simulation


def _check_joints(vr: VirtualRobot, q) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 1 and q.shape[0] == vr.truth.dof:
        q = q[None]
    if q.ndim != 2 or q.shape[1] != vr.truth.dof:
        raise SimulationError(f"joints must have shape (N, {vr.truth.dof}), got {q.shape}")
    if not np.all(np.isfinite(q)):
        r, c = np.argwhere(~np.isfinite(q))[0]
        raise SimulationError(f"joints: non-finite value at row {r}, column q{c + 1}")
    return np.ascontiguousarray(q)


def transmission_error(vr: VirtualRobot, q: np.ndarray) -> np.ndarray:
    """``(N, n)`` periodic transmission errors (rad) at commanded joints ``q``."""
    e = np.zeros_like(q)
    for p in vr.transmission:
        j = int(p.joint) - 1
        e[:, j] += p.amplitude_rad * np.sin(p.order * p.gear_ratio * q[:, j] + p.phase_rad)
    return e


def true_poses(vr: VirtualRobot, q, temperature_c=None, start_index: int = 0, payload_kg=None,
               payload_com_m=None) -> np.ndarray:
    """Noise-free true TCP poses ``(N, 4, 4)`` (world frame) for commanded joints ``q`` ``(N, n)``.

    ``temperature_c``: ``(N,)`` °C (default: the thermal warm-up profile at sample indices
    ``start_index + arange(N)``); ignored without thermal drift. ``payload_kg`` (scalar or ``(N,)``)
    / ``payload_com_m`` (``(3,)`` or ``(N, 3)`` m, tool frame): the payload carried, row by row
    (default: the truth robot's payload at the TCP).
    """
    q = _check_joints(vr, q)
    q_link = q + transmission_error(vr, q) if vr.transmission else q
    kw = {} if payload_kg is None and payload_com_m is None else {"payload_kg": payload_kg, "payload_com_m": payload_com_m}
    try:
        T = fk(vr.truth, deflected_joints(vr.truth, q_link, **kw))
    except ValueError as e:  # ComplianceError: bad payload values
        raise SimulationError(str(e)) from None
    if vr.thermal is not None:
        temp = _temperature(vr, len(q), temperature_c, start_index)
        s = vr.thermal.scale(temp)
        Tb = np.linalg.inv(vr.truth.base)
        p_base = T[:, :3, 3] @ Tb[:3, :3].T + Tb[:3, 3]
        T[:, :3, 3] = (s[:, None] * p_base) @ vr.truth.base[:3, :3].T + vr.truth.base[:3, 3]
    return T


def _temperature(vr: VirtualRobot, n: int, temperature_c, start_index: int) -> np.ndarray:
    if temperature_c is None:
        return vr.thermal.temperature_c(start_index + np.arange(n))
    t = np.broadcast_to(np.asarray(temperature_c, dtype=np.float64), (n,)).copy()
    if not np.all(np.isfinite(t)):
        raise SimulationError("temperature_c: non-finite value")
    return t


def simulate(vr: VirtualRobot, q, *, noise: bool = True, rng=None, temperature=None, start_index: int = 0,
             payload_kg=None, payload_com_m=None):
    """Simulated measurements of ``vr`` at commanded joints ``q`` ``(N, n)`` -> :class:`~hykin.io.dataset.Dataset`.

    Positions (m) and orientations (wxyz) of the true TCP in the world frame (= the nominal robot's
    base frame, where the nominal model's poses live), with measurement noise when ``noise`` and the
    preset has some. ``rng``: Generator or seed (default ``vr.seed``): same seed, same data.
    ``temperature``: ``(N,)`` °C for thermal drift (default: warm-up profile from ``start_index``);
    with thermal drift the temperature is kept as extra column ``temperature_c``. ``payload_kg`` /
    ``payload_com_m``: payload per row (see :func:`true_poses`), kept as columns ``payload_kg`` and
    ``payload_com_x/y/z`` (:mod:`hykin.io.payload`).
    """
    from ..io.dataset import Dataset

    q = _check_joints(vr, q)
    T = true_poses(vr, q, temperature, start_index, payload_kg, payload_com_m)
    rng = rng if isinstance(rng, np.random.Generator) else np.random.default_rng(vr.seed if rng is None else rng)
    N = len(q)
    if noise and (vr.noise_position_m > 0 or vr.noise_orientation_rad > 0):
        # one (N, 6) draw per call: consecutive calls on one generator give the same numbers as a
        # single call on all rows, so chunked simulation does not change the data
        z = rng.standard_normal((N, 6))
        T[:, :3, 3] += vr.noise_position_m * z[:, :3]
        if vr.noise_orientation_rad > 0:
            T[:, :3, :3] = se3.rotvec_to_matrix(vr.noise_orientation_rad * z[:, 3:]) @ T[:, :3, :3]
    extra = {}
    if vr.thermal is not None:
        extra["temperature_c"] = _temperature(vr, N, temperature, start_index)
    xyz, quat = se3.transform_to_pose(T)
    ds = Dataset(q=q, xyz_m=xyz, quat_wxyz=quat, extra=extra, source=f"hykin.simulate:{vr.name}")
    if payload_kg is None and payload_com_m is None:
        return ds
    from ..io.payload import with_payload

    return with_payload(ds, vr.truth.payload_kg if payload_kg is None else payload_kg, payload_com_m)


def dataset_error(vr: VirtualRobot, q) -> tuple[float, float]:
    """Mean (position mm, orientation deg) error of the nominal model against the noise-free truth."""
    from ..kinematics.compliance import compliant_fk

    pos, ang = se3.pose_error(compliant_fk(vr.nominal, q), true_poses(vr, q))
    return float(pos.mean()), float(ang.mean())


# --------------------------------------------------------------------------- deviations

def _frame_error(rng, sigma_m: float, sigma_rad: float) -> np.ndarray:
    return se3.make_transform(se3.rotvec_to_matrix(rng.normal(0, sigma_rad, 3)), rng.normal(0, sigma_m, 3))


def geometric_deviation(robot: Robot, rng, sigma_m: float, sigma_rad: float, frame_sigma_m: float,
                         frame_sigma_rad: float) -> Robot:
    """Copy of ``robot`` with Gaussian deviations of a, d, alpha, theta (and beta where consecutive
    axes are parallel: alpha ≈ 0), and of the base and tool frames."""
    n = robot.n_chain
    parallel = np.abs(np.sin(robot.alpha_rad)) < 1e-6
    beta = robot.beta_rad + np.where(parallel, rng.normal(0, sigma_rad, n), 0.0)
    beta[-1] = robot.beta_rad[-1]  # last joint: beta is a tool rotation, kept in the tool error
    return robot.copy(
        a_m=robot.a_m + rng.normal(0, sigma_m, n),
        d_m=robot.d_m + rng.normal(0, sigma_m, n),
        alpha_rad=robot.alpha_rad + rng.normal(0, sigma_rad, n),
        theta_rad=robot.theta_rad + rng.normal(0, sigma_rad, n),
        beta_rad=beta,
        base=robot.base @ _frame_error(rng, frame_sigma_m, frame_sigma_rad),
        tool=robot.tool @ _frame_error(rng, frame_sigma_m, frame_sigma_rad),
    )


def mass_deviation(robot: Robot, rng, rel: float = 0.05, com_sigma_m: float = 0.01) -> Robot:
    """Copy of ``robot`` with masses and payload off by ``rel`` (relative σ) and COMs by ``com_sigma_m``:
    the mass model the user has is not exact either."""
    n = robot.n_chain
    return robot.copy(
        mass_kg=robot.mass_kg * (1 + rng.normal(0, rel, n)).clip(0.5, 1.5),
        com_m=robot.com_m + rng.normal(0, com_sigma_m, (n, 3)) * (robot.mass_kg > 0)[:, None],
        payload_kg=robot.payload_kg * float(np.clip(1 + rng.normal(0, rel), 0.5, 1.5)),
    )


# --------------------------------------------------------------------------- truth files

def _robot_from_truth(d, where: str) -> Robot:
    """A robot entry of a truth file (:func:`hykin.io.robot_codec.robot_from_json`; null = rigid)."""
    try:
        return robot_from_json(d)
    except ValueError as e:  # RobotDictError (missing field, bad type) or RobotFileError
        raise SimulationError(f"{where}: {e}") from None


def _deviations(vr: VirtualRobot) -> dict:
    n, t = vr.nominal, vr.truth
    out = {k: (np.asarray(getattr(t, k)) - np.asarray(getattr(n, k))).tolist()
           for k in ("a_m", "alpha_rad", "d_m", "theta_rad", "beta_rad")}
    for k in ("base", "tool"):
        D = np.linalg.inv(getattr(n, k)) @ getattr(t, k)
        out[f"{k}_xyz_m"] = D[:3, 3].tolist()
        out[f"{k}_rotvec_rad"] = se3.matrix_to_rotvec(D[:3, :3]).tolist()
    return out


def save_truth(vr: VirtualRobot, path) -> Path:
    """Write ``vr`` (nominal, truth, non-geometric effects, noise) to a human-readable JSON file (SI:
    m, rad, kg, N·m/rad, °C; stiffness ``null`` = rigid). ``deviations`` (truth − nominal) is for
    reading only. Returns the path."""
    doc = {
        "format": "hykin-virtual-robot",
        "version": 1,
        "name": vr.name,
        "description": vr.description,
        "seed": vr.seed,
        "units": "SI: lengths m, angles rad, masses kg, stiffness N*m/rad (null = rigid), temperature degC",
        "noise": {"position_m": vr.noise_position_m, "orientation_rad": vr.noise_orientation_rad},
        "transmission": [vars(p).copy() for p in vr.transmission],
        "thermal": None if vr.thermal is None else vars(vr.thermal).copy(),
        "deviations": _deviations(vr),
        "nominal": robot_to_json(vr.nominal, inf_as="null"),
        "truth": robot_to_json(vr.truth, inf_as="null"),
    }
    path = Path(path)
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")
    return path


def load_truth(path) -> VirtualRobot:
    """Read a file written by :func:`save_truth`. Errors name the file and the field."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SimulationError(f"{path}: file not found") from None
    except json.JSONDecodeError as e:
        raise SimulationError(f"{path}: invalid JSON: {e}") from None
    if not isinstance(doc, dict) or doc.get("format") != "hykin-virtual-robot":
        raise SimulationError(f"{path}: not a hykin virtual-robot file (field 'format')")
    try:
        trans = [PeriodicError(**p) for p in doc.get("transmission", [])]
        thermal = None if doc.get("thermal") is None else ThermalDrift(**doc["thermal"])
    except TypeError as e:
        raise SimulationError(f"{path}: transmission/thermal: {e}") from None
    noise = doc.get("noise", {})
    return VirtualRobot(
        name=str(doc.get("name", path.stem)),
        nominal=_robot_from_truth(doc.get("nominal"), f"{path}: nominal"),
        truth=_robot_from_truth(doc.get("truth"), f"{path}: truth"),
        transmission=trans,
        thermal=thermal,
        noise_position_m=float(noise.get("position_m", 0.0)),
        noise_orientation_rad=float(noise.get("orientation_rad", 0.0)),
        description=str(doc.get("description", "")),
        seed=int(doc.get("seed", 0)),
    )


def truth_path_for(data_path) -> Path:
    """``data.csv`` -> ``data.truth.json`` (beside the dataset)."""
    p = Path(data_path)
    return p.with_name(p.stem + ".truth.json")
