"""Continuous measuring trajectories for dynamic data collection (``hykin plan --trajectory``).

The robot moves without stopping to measure while the tracker streams (DESIGN.md §1.4, the seed
paper's dynamic collection): the joints follow a smooth path through waypoints that cover the
region — a safe plan (:func:`hykin.planning.select.plan_poses`: calibration core, space-filling fill,
short order, moves checked for collisions with detours through via poses).

Between consecutive waypoints every joint follows the same minimum-jerk profile
``s(τ) = 10τ³ − 15τ⁴ + 6τ⁵`` (τ = t / T): the path is the straight joint-space move that the plan
checked, velocity and acceleration are zero at the waypoints and continuous everywhere. The segment
time is the shortest that keeps every joint within its speed and acceleration limits:
``T = max_j max(1.875 |Δq_j| / v_j, sqrt(5.7735 |Δq_j| / a_j))`` (peak speed ``1.875 Δ/T``, peak
acceleration ``10/√3 · Δ/T²`` of the profile). The robot passes a waypoint at rest and goes on.

:class:`Trajectory` evaluates the joints at any time (the tracker's samples fall between the robot
controller's), and :func:`sample` gives them at a controller rate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Trajectory", "min_jerk_trajectory"]

_V_PEAK = 1.875  # peak speed of the minimum-jerk profile, in Δ/T
_A_PEAK = 10.0 / np.sqrt(3.0)  # peak acceleration, in Δ/T²


@dataclass
class Trajectory:
    """A joint trajectory through ``waypoints`` ``(W, dof)`` (rad / m) with segment times
    ``segment_s`` ``(W - 1,)``; ``start_s`` ``(W,)`` is the time each waypoint is reached."""

    waypoints: np.ndarray
    segment_s: np.ndarray
    start_s: np.ndarray

    @property
    def duration_s(self) -> float:
        return float(self.start_s[-1])

    def at(self, t_s) -> tuple[np.ndarray, np.ndarray]:
        """Joints ``(N, dof)`` and joint speeds ``(N, dof)`` (per s) at times ``t_s`` ``(N,)``
        (clamped to the trajectory's span)."""
        t = np.clip(np.asarray(t_s, dtype=np.float64).reshape(-1), 0.0, self.duration_s)
        k = np.clip(np.searchsorted(self.start_s, t, side="right") - 1, 0, len(self.segment_s) - 1)
        T = self.segment_s[k]
        tau = np.where(T > 0, (t - self.start_s[k]) / np.where(T > 0, T, 1.0), 1.0)
        s = tau**3 * (10.0 - 15.0 * tau + 6.0 * tau**2)
        ds = np.where(T > 0, 30.0 * tau**2 * (1.0 - tau) ** 2 / np.where(T > 0, T, 1.0), 0.0)
        d = self.waypoints[k + 1] - self.waypoints[k]
        return self.waypoints[k] + s[:, None] * d, ds[:, None] * d

    def sample(self, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
        """``(t (M,), q (M, dof))`` at ``rate_hz`` from 0 to the end."""
        t = np.arange(0.0, self.duration_s + 0.5 / rate_hz, 1.0 / rate_hz)
        return t, self.at(t)[0]


def min_jerk_trajectory(waypoints, speed_limits, accel_limits) -> Trajectory:
    """The minimum-jerk trajectory through ``waypoints`` ``(W, dof)`` within ``speed_limits`` and
    ``accel_limits`` ``(dof,)`` (per s, per s²; module docstring)."""
    w = np.asarray(waypoints, dtype=np.float64)
    if w.ndim != 2 or len(w) < 2:
        raise ValueError(f"a trajectory needs at least 2 waypoints (W, dof), got shape {w.shape}")
    v = np.broadcast_to(np.asarray(speed_limits, dtype=np.float64), (w.shape[1],))
    a = np.broadcast_to(np.asarray(accel_limits, dtype=np.float64), (w.shape[1],))
    if not (np.all(v > 0) and np.all(a > 0) and np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
        raise ValueError("speed and acceleration limits must be finite and > 0")
    d = np.abs(np.diff(w, axis=0))
    T = np.max(np.maximum(_V_PEAK * d / v, np.sqrt(_A_PEAK * d / a)), axis=1)
    return Trajectory(waypoints=w, segment_s=T, start_s=np.concatenate([[0.0], np.cumsum(T)]))
