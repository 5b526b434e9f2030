"""What a real cell records during dynamic collection: a robot joint log and a tracker stream.

A virtual robot (:class:`hykin.sim.simulate.VirtualRobot`) follows a joint trajectory given as
samples ``(t_s, q)`` (interpolated by a C² cubic spline). Two devices record it, each on its own
clock:

* the **robot controller** logs its joints at ``robot_rate_hz`` (its clock is the reference);
* the **tracker** streams the reflector position (and orientation for a 6-D probe) at
  ``tracker_rate_hz`` on its own clock. A sample taken at robot time ``t`` is stamped
  ``τ = t + offset_s + latency_s + drift · (t − t_ref)`` (``t_ref`` the middle of the robot log, the
  clock model of :mod:`hykin.measure.streams`: what alignment estimates is ``offset_s + latency_s``
  and ``drift``). Positions carry the virtual robot's measurement noise; the beam is lost (empty
  cells) where the reflector moves faster than ``beam_loss_speed_m_s`` and in random dropouts
  (``dropouts_per_min`` gaps of exponential length, mean ``dropout_mean_s``).

Everything is computed in chunks of ``chunk`` tracker samples, so millions of samples fit in
bounded memory.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.interpolate import CubicSpline

from ..geometry import se3
from .simulate import SimulationError, VirtualRobot, true_poses

__all__ = ["CellRecording", "record_cell"]


@dataclass
class CellRecording:
    """Robot log ``t_robot_s (M,)``, ``q_robot (M, dof)``; tracker stream ``t_tracker_s (K,)`` (its
    clock), ``p_tracker_m (K, 3)`` and ``quat_tracker (K, 4)`` or None, NaN rows where the beam was
    lost. ``truth``: the clock (``offset_s`` = offset + latency, ``drift``, ``t_ref_s``) and counts."""

    t_robot_s: np.ndarray
    q_robot: np.ndarray
    t_tracker_s: np.ndarray
    p_tracker_m: np.ndarray
    quat_tracker: np.ndarray | None
    truth: dict = field(default_factory=dict)


def record_cell(vr: VirtualRobot, t_traj_s, q_traj, *, robot_rate_hz: float = 100.0, tracker_rate_hz: float = 1000.0,
                offset_s: float = 0.0123, latency_s: float = 0.002, drift: float = 20e-6, noise: bool = True,
                orientation: bool = False, beam_loss_speed_m_s: float = 1.0, dropouts_per_min: float = 2.0,
                dropout_mean_s: float = 0.05, seed: int = 0, chunk: int = 200_000, progress=None) -> CellRecording:
    """Record the virtual cell along the trajectory ``(t_traj_s (T,), q_traj (T, dof))`` (module
    docstring). ``orientation``: the tracker measures full poses (6-D probe). ``progress(done, total)``
    is called per chunk of tracker samples."""
    t = np.asarray(t_traj_s, dtype=np.float64).reshape(-1)
    q = np.asarray(q_traj, dtype=np.float64)
    if q.ndim != 2 or q.shape != (len(t), vr.truth.dof):
        raise SimulationError(f"trajectory: expected times (T,) and joints (T, {vr.truth.dof}), got {t.shape} and {q.shape}")
    if len(t) < 4 or not np.all(np.diff(t) > 0):
        raise SimulationError("trajectory: at least 4 samples with strictly increasing times are needed")
    for nm, v in (("robot_rate_hz", robot_rate_hz), ("tracker_rate_hz", tracker_rate_hz)):
        if not (v > 0 and np.isfinite(v)):
            raise SimulationError(f"{nm} must be > 0, got {v}")
    spline = CubicSpline(t, q, axis=0)
    rng = np.random.default_rng([seed, 71])
    t_robot = np.arange(t[0], t[-1] + 1e-12, 1.0 / robot_rate_hz)
    q_robot = spline(t_robot)
    t_ref = 0.5 * (t_robot[0] + t_robot[-1])
    off = offset_s + latency_s
    # tracker sample k is stamped tau_k on its clock; it sees the robot at t = (tau - off + drift t_ref) / (1 + drift)
    tau0 = t[0] + off + drift * (t[0] - t_ref)
    n_tr = int(np.floor(((t[-1] + off + drift * (t[-1] - t_ref)) - tau0) * tracker_rate_hz)) + 1
    tau = tau0 + np.arange(n_tr) / tracker_rate_hz
    t_meas = (tau - off + drift * t_ref) / (1.0 + drift)
    P = np.empty((n_tr, 3))
    Qt = np.empty((n_tr, 4)) if orientation else None
    speed = np.empty(n_tr)
    sig_p = vr.noise_position_m if noise else 0.0
    sig_r = vr.noise_orientation_rad if noise else 0.0
    for s in range(0, n_tr, chunk):
        tm = np.clip(t_meas[s : s + chunk], t[0], t[-1])
        qs = spline(tm)
        T = true_poses(vr, qs)
        # reflector speed from the joint speeds: finite difference of the true positions over 1 ms
        T2 = true_poses(vr, spline(np.clip(tm + 1e-3, t[0], t[-1])))
        speed[s : s + chunk] = np.linalg.norm(T2[:, :3, 3] - T[:, :3, 3], axis=1) / 1e-3
        z = rng.standard_normal((len(tm), 6))
        P[s : s + chunk] = T[:, :3, 3] + sig_p * z[:, :3]
        if orientation:
            R = se3.rotvec_to_matrix(sig_r * z[:, 3:]) @ T[:, :3, :3]
            Qt[s : s + chunk] = se3.matrix_to_quat(R)
        if progress is not None:
            progress(min(s + chunk, n_tr), n_tr)
    lost = speed > beam_loss_speed_m_s
    n_fast = int(lost.sum())
    # random dropouts: Poisson starts over the stream, exponential lengths
    dur = n_tr / tracker_rate_hz
    n_drop = rng.poisson(dropouts_per_min * dur / 60.0)
    starts = rng.uniform(0, dur, n_drop)
    lens = rng.exponential(dropout_mean_s, n_drop)
    edges = np.searchsorted(tau - tau0, np.stack([starts, starts + lens], axis=1))
    cover = np.zeros(n_tr + 1, np.int64)
    np.add.at(cover, edges[:, 0], 1)
    np.add.at(cover, edges[:, 1], -1)
    lost |= np.cumsum(cover)[:n_tr] > 0
    P[lost] = np.nan
    if Qt is not None:
        Qt[lost] = np.nan
    truth = {"offset_s": float(off), "offset_without_latency_s": float(offset_s), "latency_s": float(latency_s),
             "drift": float(drift), "t_ref_s": float(t_ref), "n_robot": int(len(t_robot)), "n_tracker": int(n_tr),
             "n_lost_fast": n_fast, "n_lost": int(lost.sum()), "n_dropouts": int(n_drop),
             "beam_loss_speed_m_s": float(beam_loss_speed_m_s)}
    return CellRecording(t_robot_s=t_robot, q_robot=q_robot, t_tracker_s=tau, p_tracker_m=P, quat_tracker=Qt, truth=truth)
