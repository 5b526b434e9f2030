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
next, then noise). :func:`simulate` turns joints into a :class:`hykin.dataset.Dataset`;
:func:`save_truth` / :func:`load_truth` keep the truth beside the data (JSON, SI units).

Presets (:func:`virtual_preset`, :func:`list_virtual_presets`); dataset errors measured as the mean
pose error of ``nominal`` against the noise-free truth on 4096 Sobol-uniform joint samples
(``python -m hykin.simulate``):

* ``rx160-virtual`` — the paper's virtual experiment (Ojer et al. 2024, Table I: 1.80 mm / 0.170°):
  RX160 nominal, truth = same geometry with torsional joint springs (k = 5.2e5, 5.2e5, 2.6e5,
  1.35e4, 1.35e4, 1.35e4 N·m/rad) under gravity, a 10 kg gripper on the flange (COM 0.05, 0, 0.10 m
  in the flange frame) and a 20 kg payload at the TCP; noise-free. Measured: **1.80 mm / 0.170°**.
* ``rx160-geometric`` — rx160-virtual plus random geometric deviations (σ 0.3 mm, 0.03°), base and
  tool frame errors; no noise, no non-geometric effects: what parametric calibration must recover
  exactly. Measured (seed 0): **2.98 mm / 0.205°**.
* ``rx160-nongeo`` — rx160-geometric plus periodic transmission errors (orders 1–3 on joints 1–3,
  orders 1–2 on joints 4–6), thermal warm-up (11.5e-6 /K, 20 -> 26 °C), masses/COMs/payload off
  the nominal mass model (5 %, 1 cm) and tracker noise (10 µm, 50 µrad): the non-geometric effects
  the networks must learn. Measured (seed 0, noise-free
  part, at reference temperature): **2.99 mm / 0.204°**.
* ``ur10-virtual`` — UR10 with geometric deviations (σ 0.6 mm, 0.12°), base/tool errors, mass model
  errors (5 %, 1 cm), soft joints
  (k = 6e4, 6e4, 3e4, 8e3, 8e3, 8e3 N·m/rad), 2 kg tool + 5 kg payload, tracker noise 20 µm /
  100 µrad. Measured (seed 0, noise-free): **4.95 mm / 0.479°** (compliance alone ≈ 2.2 mm).

* ``kr-payload-virtual`` — a 120 kg-class arm for payload studies (:mod:`hykin.payload`): masses
  and centres of mass in its robot file, stiffness unknown, geometric and transmission errors,
  noise; draw it at several payloads (``simulate_to_file(..., payloads=[0, 12])``). Measured (seed
  0, noise-free, payload 0 kg): **5.43 mm / 0.199°** (5.83 mm at 12 kg, 6.10 mm at 20 kg).

The ``nominal`` robot of every preset carries the known masses and payload (they do not change its
rigid FK), so calibration can model joint compliance; its stiffness is infinite.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..io.robot_codec import robot_from_json, robot_to_json
from ..io.robot_file import load_robot
from ..kinematics import se3
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
    "list_virtual_presets",
    "load_truth",
    "mass_deviation",
    "save_truth",
    "simulate",
    "simulate_to_file",
    "transmission_error",
    "true_poses",
    "truth_path_for",
    "virtual_preset",
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
    """Simulated measurements of ``vr`` at commanded joints ``q`` ``(N, n)`` -> :class:`~hykin.dataset.Dataset`.

    Positions (m) and orientations (wxyz) of the true TCP in the world frame (= the nominal robot's
    base frame, where the nominal model's poses live), with measurement noise when ``noise`` and the
    preset has some. ``rng``: Generator or seed (default ``vr.seed``): same seed, same data.
    ``temperature``: ``(N,)`` °C for thermal drift (default: warm-up profile from ``start_index``);
    with thermal drift the temperature is kept as extra column ``temperature_c``. ``payload_kg`` /
    ``payload_com_m``: payload per row (see :func:`true_poses`), kept as columns ``payload_kg`` and
    ``payload_com_x/y/z`` (:mod:`hykin.payload`).
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
    from ..kinematics.payload import with_payload

    return with_payload(ds, vr.truth.payload_kg if payload_kg is None else payload_kg, payload_com_m)


def dataset_error(vr: VirtualRobot, q) -> tuple[float, float]:
    """Mean (position mm, orientation deg) error of the nominal model against the noise-free truth."""
    from ..kinematics.compliance import compliant_fk

    pos, ang = se3.pose_error(compliant_fk(vr.nominal, q), true_poses(vr, q))
    return float(pos.mean()), float(ang.mean())


# --------------------------------------------------------------------------- presets

_RX160_STIFFNESS = np.array([5.2e5, 5.2e5, 2.6e5, 1.35e4, 1.35e4, 1.35e4])
_RX160_GRIPPER_KG, _RX160_GRIPPER_COM = 10.0, np.array([0.05, 0.0, 0.10])
_RX160_PAYLOAD_KG = 20.0


def _add_flange_mass(robot: Robot, kg: float, com: np.ndarray) -> Robot:
    """Robot with a rigid body of ``kg`` at ``com`` (flange frame) added to the last link."""
    m, c = robot.mass_kg.copy(), robot.com_m.copy()
    total = m[-1] + kg
    c[-1] = (m[-1] * c[-1] + kg * np.asarray(com)) / total
    m[-1] = total
    return robot.copy(mass_kg=m, com_m=c)


def _frame_error(rng, sigma_m: float, sigma_rad: float) -> np.ndarray:
    return se3.make_transform(se3.rotvec_to_matrix(rng.normal(0, sigma_rad, 3)), rng.normal(0, sigma_m, 3))


def geometric_deviation(robot: Robot, rng, sigma_m: float, sigma_rad: float, frame_sigma_m: float,
                         frame_sigma_rad: float) -> Robot:
    """Copy of ``robot`` with Gaussian deviations of a, d, alpha, theta (and beta where consecutive
    axes are parallel: alpha ≈ 0), and of the base and tool frames."""
    n = robot.dof
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
    n = robot.dof
    return robot.copy(
        mass_kg=robot.mass_kg * (1 + rng.normal(0, rel, n)).clip(0.5, 1.5),
        com_m=robot.com_m + rng.normal(0, com_sigma_m, (n, 3)) * (robot.mass_kg > 0)[:, None],
        payload_kg=robot.payload_kg * float(np.clip(1 + rng.normal(0, rel), 0.5, 1.5)),
    )


def _rx160_pair() -> tuple[Robot, Robot]:
    rob = _add_flange_mass(load_robot("rx160"), _RX160_GRIPPER_KG, _RX160_GRIPPER_COM)
    nominal = rob.copy(payload_kg=_RX160_PAYLOAD_KG, name="rx160")
    truth = nominal.copy(stiffness_nm_per_rad=_RX160_STIFFNESS, name="rx160-truth")
    return nominal, truth


def _rx160_virtual(seed: int) -> VirtualRobot:
    nominal, truth = _rx160_pair()
    return VirtualRobot(
        name="rx160-virtual", nominal=nominal, truth=truth, seed=seed,
        description=(
            "Paper virtual experiment (Ojer et al. 2024): RX160 with torsional joint springs under gravity, "
            "10 kg gripper + 20 kg payload; noise-free; dataset error 1.80 mm / 0.170 deg.\n"
            "Truth geometry equals the nominal; only joint compliance separates them (deterministic, "
            "the seed only seeds the default noise generator)."
        ),
    )


def _rx160_geometric(seed: int) -> VirtualRobot:
    nominal, truth = _rx160_pair()
    rng = np.random.default_rng([seed, 160, 1])
    truth = geometric_deviation(truth, rng, 3e-4, np.radians(0.03), 5e-4, np.radians(0.05))
    return VirtualRobot(
        name="rx160-geometric", nominal=nominal, truth=truth, seed=seed,
        description=(
            "RX160 with geometric deviations (0.3 mm, 0.03 deg), base/tool errors and joint compliance; no noise.\n"
            "Everything is parametric: calibration should recover it exactly."
        ),
    )


def _rx160_nongeo(seed: int) -> VirtualRobot:
    vr = _rx160_geometric(seed)
    rng = np.random.default_rng([seed, 160, 2])
    trans = []
    for j in (1, 2, 3):
        for order, amp in ((1, 1.5e-4), (2, 8e-5), (3, 4e-5)):
            trans.append(PeriodicError(j, float(amp * rng.uniform(0.7, 1.3)), float(order), 1.0, float(rng.uniform(0, 2 * np.pi))))
    for j in (4, 5, 6):
        for order, amp in ((1, 2e-4), (2, 1e-4)):
            trans.append(PeriodicError(j, float(amp * rng.uniform(0.7, 1.3)), float(order), 1.0, float(rng.uniform(0, 2 * np.pi))))
    truth = mass_deviation(vr.truth, rng).copy(name="rx160-nongeo-truth")
    return VirtualRobot(
        name="rx160-nongeo", nominal=vr.nominal, truth=truth, transmission=trans,
        thermal=ThermalDrift(), noise_position_m=10e-6, noise_orientation_rad=50e-6, seed=seed,
        description=(
            "RX160: geometric + compliance + periodic transmission errors + thermal drift + tracker noise.\n"
            "Non-geometric effects for the residual networks to learn (noise 10 um, 50 urad)."
        ),
    )


def _ur10_virtual(seed: int) -> VirtualRobot:
    nominal = _add_flange_mass(load_robot("ur10"), 2.0, np.array([0.0, 0.0, 0.05])).copy(payload_kg=5.0, name="ur10")
    rng = np.random.default_rng([seed, 10, 1])
    truth = geometric_deviation(nominal, rng, 6e-4, np.radians(0.12), 1e-3, np.radians(0.2))
    truth = mass_deviation(truth, rng).copy(stiffness_nm_per_rad=np.array([6e4, 6e4, 3e4, 8e3, 8e3, 8e3]), name="ur10-truth")
    return VirtualRobot(
        name="ur10-virtual", nominal=nominal, truth=truth, noise_position_m=20e-6, noise_orientation_rad=100e-6,
        seed=seed,
        description=(
            "UR10 collaborative arm: geometric deviations (0.6 mm, 0.12 deg), soft joints, 2 kg tool + 5 kg payload, "
            "tracker noise 20 um / 100 urad."
        ),
    )


_PRESETS: dict[str, Callable[[int], VirtualRobot]] = {
    "rx160-virtual": _rx160_virtual,
    "rx160-geometric": _rx160_geometric,
    "rx160-nongeo": _rx160_nongeo,
    "ur10-virtual": _ur10_virtual,
    "kr-payload-virtual": lambda seed: _payload_preset(seed),
}


def _payload_preset(seed: int) -> VirtualRobot:
    from ..kinematics.payload import (
        payload_virtual_robot,  # defined beside the payload columns it is made for
    )

    return payload_virtual_robot(seed)


def list_virtual_presets() -> list[str]:
    """Names of the virtual-robot presets."""
    return list(_PRESETS)


def virtual_preset(name: str, seed: int = 0) -> VirtualRobot:
    """A virtual-robot preset (see the module docstring); ``seed`` draws its random deviations."""
    key = str(name).lower()
    if key not in _PRESETS:
        raise SimulationError(f"unknown virtual robot {name!r}; choose one of {', '.join(_PRESETS)}")
    return _PRESETS[key](int(seed))


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


def simulate_to_file(preset, n: int, out_path, plan: str = "uniform", seed: int = 0, noise: bool = True,
                     progress: Callable[[int, int], None] | None = None, chunk: int = 50_000,
                     payloads=None) -> str:
    """Sample ``n`` joints with ``plan`` (hykin.sampling), simulate them in chunks, write the dataset
    to ``out_path`` (.csv/.parquet) and the truth beside it (``*.truth.json``); returns the truth path.

    ``preset``: a preset name, a :class:`VirtualRobot` or a truth file (.json). ``seed`` seeds the
    preset's deviations, the plan and the noise: same arguments, same files. ``progress(done, total)``
    is called after each chunk; the data do not depend on ``chunk``. With ``plan="iso_cube"`` the pose label (1..5) is kept as column
    ``pose``; a ``sample`` column holds the sample index (the time axis of thermal drift).
    ``payloads``: payload masses (kg) to draw the data at (row ``i`` carries ``payloads[i % k]``,
    at the TCP), kept as column ``payload_kg``; default: the preset's payload, no column.
    """
    from ..io.dataset import concat
    from ..io.dataset_files import write_dataset
    from .sampling import iso_cube, sample

    if isinstance(preset, VirtualRobot):
        vr = preset
    elif str(preset).lower().endswith(".json"):
        vr = load_truth(preset)
    else:
        vr = virtual_preset(str(preset), seed=seed)
    n = int(n)
    if n < 1:
        raise SimulationError(f"number of samples must be >= 1, got {n}")
    plan_name = str(plan).replace("-", "_").lower()
    rng_plan = np.random.default_rng([seed, 7])
    rng_noise = np.random.default_rng([seed, 11])
    extra_all: dict[str, np.ndarray] = {}
    if plan_name == "iso_cube":
        p = iso_cube(vr.nominal, cycles=-(-n // 5), rng=rng_plan)
        q, extra_all["pose"] = p.q[:n], p.labels[:n]
    else:
        q = sample(plan_name, vr.nominal, n, rng_plan)
    kg = None
    if payloads is not None:
        pl = np.asarray(payloads, dtype=np.float64).reshape(-1)
        if pl.size == 0 or not np.all(np.isfinite(pl) & (pl >= 0)):
            raise SimulationError(f"payloads must be masses >= 0 kg, got {list(pl)}")
        kg = np.resize(pl, n)
    parts = []
    for s in range(0, n, chunk):
        e = min(n, s + chunk)
        ds = simulate(vr, q[s:e], noise=noise, rng=rng_noise, start_index=s, payload_kg=None if kg is None else kg[s:e])
        ds.extra["sample"] = np.arange(s, e)
        for k, v in extra_all.items():
            ds.extra[k] = v[s:e]
        parts.append(ds)
        if progress is not None:
            progress(e, n)
    data = parts[0] if len(parts) == 1 else concat(parts)
    data.source = f"hykin simulate {vr.name} -n {n} --plan {plan_name} --seed {seed}" + ("" if noise else " --no-noise") + (
        "" if payloads is None else " --payloads " + ",".join(f"{v:g}" for v in np.asarray(payloads).reshape(-1)))
    write_dataset(data, out_path)
    return str(save_truth(vr, truth_path_for(out_path)))


if __name__ == "__main__":  # measure the presets' dataset errors (figures in the module docstring)
    from .sampling import uniform

    for name in list_virtual_presets():
        v = virtual_preset(name)
        q = uniform(v.nominal, 4096, 0)
        pm, ad = dataset_error(v, q)
        print(f"{name:16s} {pm:7.3f} mm {ad:7.4f} deg")
