"""Virtual measurement campaigns of issue #24 for the calibration tests (a robot of our own, not a
preset): a 6-axis arm with a hand-written DH table, a tracker metres away and turned, a 6-D probe,
the tool held at one orientation or the joints kept in a small region."""

from __future__ import annotations

import numpy as np

from hykin.geometry import se3
from hykin.kinematics.compliance import compliant_fk
from hykin.kinematics.ik import ik_numeric
from hykin.kinematics.robot import Robot

PI = np.pi
#: tracker 4.4 m from the robot base, turned 131 degrees
TRACKER = se3.make_transform(se3.rotvec_to_matrix(np.radians(131.0) * np.array([0.48, 0.6, 0.64])), [3.1, -2.7, 1.6])


def arm(tool_xyz=(0.0, 0.0, 0.1)) -> Robot:
    """The hand-written robot file: a 6R arm, masses, no [base], a tool guess (100 mm)."""
    return Robot(
        name="maker-arm", convention="dh", a_m=[0.18, 0.70, 0.12, 0, 0, 0], alpha_rad=[-PI / 2, 0, -PI / 2, PI / 2, -PI / 2, 0],
        d_m=[0.52, 0, 0, 0.80, 0, 0.12], theta_rad=[0, -PI / 2, 0, 0, 0, 0],
        lower=np.radians([-170, -100, -120, -190, -125, -360]), upper=np.radians([170, 100, 150, 190, 125, 360]),
        mass_kg=[40, 30, 18, 6, 3, 1], com_m=np.array([[0, 0, 0], [-0.35, 0, 0], [0, 0, 0], [0, 0, -0.35], [0, 0, 0], [0, 0, 0]]),
        tool=se3.make_transform(np.eye(3), list(tool_xyz)), payload_kg=8.0,
    )


def truth_of(nom: Robot, rng) -> Robot:
    """The real arm: geometry off by ~0.5 mm / 0.5 mrad, joint springs, the tool 2.4 mm off the guess."""
    tool = nom.tool.copy()
    tool[:3, 3] += [0.0015, -0.001, 0.0016]
    return nom.copy(a_m=nom.a_m + rng.normal(0, 5e-4, 6), d_m=nom.d_m + rng.normal(0, 5e-4, 6),
                    alpha_rad=nom.alpha_rad + rng.normal(0, 5e-4, 6), theta_rad=nom.theta_rad + rng.normal(0, 1e-3, 6),
                    stiffness_nm_per_rad=np.array([np.inf, 3e5, 2e5, 1e5, 8e4, 6e4]), tool=tool)


def one_orientation_joints(truth: Robot, n: int, rng, spread_deg: float = 0.1) -> np.ndarray:
    """``(n, 6)`` joints reaching positions in front of the arm with the tool at one orientation (pointing
    down), each within ``spread_deg`` of it (uniform per axis); solved on the (rigid) truth."""
    R0 = se3.rotvec_to_matrix(np.array([PI, 0.0, 0.0]))
    p = np.column_stack([rng.uniform(0.7, 1.3, 4 * n), rng.uniform(-0.6, 0.6, 4 * n), rng.uniform(0.2, 1.0, 4 * n)])
    half = np.radians(spread_deg) / np.sqrt(3.0)
    R = se3.rotvec_to_matrix(rng.uniform(-half, half, (4 * n, 3))) @ R0
    T = np.tile(np.eye(4), (4 * n, 1, 1))
    T[:, :3, :3], T[:, :3, 3] = R, p
    seed = np.radians([0, 10, 20, 0, 60, 0])
    res = ik_numeric(truth.copy(tool=truth.tool, base=np.eye(4)), T, q_seed=seed, restarts=4)
    ok = np.flatnonzero(np.asarray(res.success))
    if ok.size < n:
        raise RuntimeError(f"only {ok.size} of {4 * n} one-orientation targets reachable")
    return np.asarray(res.q)[ok[:n]]


def region_joints(nom: Robot, n: int, rng, half_range_deg: float = 12.0) -> np.ndarray:
    """``(n, 6)`` joints in a small region of joint space (each joint within ``half_range_deg`` of a pose)."""
    centre = np.radians([20, 15, 25, 10, 40, 30])
    return centre + rng.uniform(-1, 1, (n, 6)) * np.radians(half_range_deg)


def measure(truth: Robot, q: np.ndarray, rng, noise_m: float = 1e-5, noise_rad: float = 2e-5,
            gear_rad: float = 0.0) -> np.ndarray:
    """Poses ``(N, 4, 4)`` the tracker's 6-D probe reports (tracker frame, noisy). ``gear_rad``: amplitude
    of a gear transmission error ``gear_rad sin(3 q_i + i)`` on every joint, an error no geometric
    model represents (a few hundredths of a mm at 1e-5 rad)."""
    if gear_rad:
        q = q + gear_rad * np.sin(3.0 * q + np.arange(q.shape[1]))
    T = TRACKER @ compliant_fk(truth, q)
    T[:, :3, 3] += rng.normal(0, noise_m, (len(q), 3))
    T[:, :3, :3] = se3.rotvec_to_matrix(rng.normal(0, noise_rad, (len(q), 3))) @ T[:, :3, :3]
    return T
