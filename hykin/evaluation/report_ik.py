"""Warm timing of hybrid inverse kinematics for the report: targets are the model's own poses at
sample joints (so every target is reachable), one untimed call first (imports, compiled kernels,
caches), then the best of ``repeats`` timed calls, per target. What a figure includes is stated next to it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

__all__ = ["IKTiming", "time_hybrid_ik"]


@dataclass
class IKTiming:
    """Warm per-target times (ms) of hybrid IK on ``n_targets`` targets, all branches and nearest
    branch only, with the share of targets solved (position and orientation within 1e-4 mm / deg)."""

    n_targets: int
    all_branches_ms: float
    nearest_ms: float
    solved_all: float
    solutions_per_target: float

    def rows(self) -> list[list]:
        return [
            ["all branches", self.all_branches_ms, self.all_branches_ms / max(self.solutions_per_target, 1e-12),
             f"{self.solutions_per_target:.1f}", f"{100 * self.solved_all:.0f} %",
             "seeds from every closed-form branch of the calibrated robot, hybrid refinement of each (network "
             "evaluation + Levenberg–Marquardt), support and joint-limit checks"],
            ["nearest branch", self.nearest_ms, self.nearest_ms, "1", "",
             "the same, keeping one solution per target (the one nearest to the given current joints)"],
        ]


HEADER = ["hybrid IK", "time per target [ms]", "per target and branch [ms]", "solutions per target", "targets solved",
          "what the time includes"]


def time_hybrid_ik(model, q: np.ndarray, repeats: int = 2) -> IKTiming | None:
    """Warm timings of :func:`hykin.hybrid.ik.hybrid_ik` on the model's poses at joints ``q`` ``(N, n)``
    rad; None for a model without networks (a robot)."""
    if not hasattr(model, "predict_classical") or len(q) == 0:
        return None
    from ..hybrid.ik import hybrid_ik

    q = np.asarray(q, float)
    T = model.predict(q)
    hybrid_ik(model, T[: min(3, len(T))], all_branches=True)  # warm-up: imports, kernels, caches

    def best(**kw):
        t, res = np.inf, None
        for _ in range(max(int(repeats), 1)):
            t0 = time.perf_counter()
            res = hybrid_ik(model, T, **kw)
            t = min(t, time.perf_counter() - t0)
        return t / len(T) * 1e3, res

    t_all, res = best(all_branches=True)
    t_near, _ = best(all_branches=True, q_current=q, nearest=True)
    ok = np.asarray(res.success, bool)
    solved = len(set(np.asarray(res.target)[ok].tolist())) / len(T)
    return IKTiming(len(T), float(t_all), float(t_near), float(solved), float(len(res.target) / len(T)))
