"""Virtual-robot presets: named, seeded :class:`~hykin.sim.simulate.VirtualRobot` definitions.

Presets (:func:`virtual_preset`, :func:`list_virtual_presets`); dataset errors measured as the mean
pose error of ``nominal`` against the noise-free truth on 4096 Sobol-uniform joint samples
(``python -m hykin.sim.presets``):

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

* ``kr-payload-virtual`` — a 120 kg-class arm for payload studies (:mod:`hykin.io.payload`): masses
  and centres of mass in its robot file, stiffness unknown, geometric and transmission errors,
  noise; draw it at several payloads (``simulate_to_file(..., payloads=[0, 12])``). Measured (seed
  0, noise-free, payload 0 kg): **5.43 mm / 0.199°** (5.83 mm at 12 kg, 6.10 mm at 20 kg).

The ``nominal`` robot of every preset carries the known masses and payload (they do not change its
rigid FK), so calibration can model joint compliance; its stiffness is infinite.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from ..io.robot_file import load_robot
from ..kinematics.robot import Robot
from .simulate import (
    PeriodicError,
    SimulationError,
    ThermalDrift,
    VirtualRobot,
    dataset_error,
    geometric_deviation,
    mass_deviation,
)

__all__ = ["list_virtual_presets", "payload_virtual_robot", "virtual_preset"]

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


_KR_STIFFNESS = np.array([9e5, 1.1e6, 6e5, 9e4, 9e4, 6e4])  # N·m/rad, truth only (unknown to the user)


def payload_virtual_robot(seed: int = 0) -> VirtualRobot:
    """The ``kr-payload-virtual`` preset (:func:`virtual_preset`): nominal = the robot
    preset ``kr-payload`` (``hykin/presets/kr-payload.toml``: a 2.7 m-reach, 120 kg-class arm with
    an 8 kg gripper in link 6; masses and centres of mass given, rigid: stiffness unknown);
    truth = geometric deviations (σ 0.3 mm, 0.03°), base/tool frame errors, joint springs, mass model
    off by 3 % / 5 mm, periodic transmission errors (orders 1-3 on joints 1-3, 1-2 on 4-6) and
    tracker noise 10 µm / 50 µrad. Simulate it at several payloads: ``hykin simulate
    kr-payload-virtual --payloads 0,12``."""
    nominal = load_robot("kr-payload")
    rng = np.random.default_rng([seed, 120, 1])
    truth = geometric_deviation(nominal, rng, 3e-4, np.radians(0.03), 5e-4, np.radians(0.05))
    truth = mass_deviation(truth, rng, 0.03, 0.005).copy(stiffness_nm_per_rad=_KR_STIFFNESS, name="kr-payload-truth")
    trans = []
    for j in (1, 2, 3):
        for order, amp in ((1, 1.2e-4), (2, 6e-5), (3, 3e-5)):
            trans.append(PeriodicError(j, float(amp * rng.uniform(0.7, 1.3)), float(order), 1.0, float(rng.uniform(0, 2 * np.pi))))
    for j in (4, 5, 6):
        for order, amp in ((1, 1.5e-4), (2, 8e-5)):
            trans.append(PeriodicError(j, float(amp * rng.uniform(0.7, 1.3)), float(order), 1.0, float(rng.uniform(0, 2 * np.pi))))
    return VirtualRobot(
        name="kr-payload-virtual", nominal=nominal, truth=truth, transmission=trans, noise_position_m=10e-6,
        noise_orientation_rad=50e-6, seed=seed,
        description=(
            "KR 120-class arm for payload studies: masses/COMs in the robot file, stiffness unknown, geometric and "
            "transmission errors, noise 10 um / 50 urad; use --payloads 0,12.\n"
            "Per-row payload (payload_kg column) deflects the truth; the nominal is rigid."
        ),
    )


_PRESETS: dict[str, Callable[[int], VirtualRobot]] = {
    "rx160-virtual": _rx160_virtual,
    "rx160-geometric": _rx160_geometric,
    "rx160-nongeo": _rx160_nongeo,
    "ur10-virtual": _ur10_virtual,
    "kr-payload-virtual": payload_virtual_robot,
}


def list_virtual_presets() -> list[str]:
    """Names of the virtual-robot presets."""
    return list(_PRESETS)


def virtual_preset(name: str, seed: int = 0) -> VirtualRobot:
    """A virtual-robot preset (see the module docstring); ``seed`` draws its random deviations."""
    key = str(name).lower()
    if key not in _PRESETS:
        raise SimulationError(f"unknown virtual robot {name!r}; choose one of {', '.join(_PRESETS)}")
    return _PRESETS[key](int(seed))


if __name__ == "__main__":  # measure the presets' dataset errors (figures in the module docstring)
    from .sampling import uniform

    for name in list_virtual_presets():
        v = virtual_preset(name)
        q = uniform(v.nominal, 4096, 0)
        pm, ad = dataset_error(v, q)
        print(f"{name:16s} {pm:7.3f} mm {ad:7.4f} deg")
