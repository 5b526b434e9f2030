"""Region-blocked validation of the calibration's parameter set.

A calibration is used on poses it was not fitted on: another day, another tracker placement,
another part of the workspace. Random held-out rows sit between training rows and reward a
parameter set that fits the training region closely; held-out *regions* reward one that
extrapolates. :func:`select_calibration` splits the data into ``n_blocks`` joint-space regions
(k-means on the z-scored joints), calibrates each candidate parameter set on the other regions,
re-registers base and tool on ``n_register`` representative poses of the held-out region (as a new
series would be, :func:`hykin.calibration.frames.fit_frames`) and scores the error on that region's other
poses. The candidate with the lowest mean held-out error wins; ties within ``tie_tol`` go to the
later (simpler) candidate.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np

__all__ = ["CANDIDATES", "RegionCVResult", "candidate_kwargs", "joint_blocks", "select_calibration"]

#: candidate parameter sets (``hykin.calibration.calibrate.calibrate`` keyword arguments), richest first
CANDIDATES: dict[str, dict] = {
    "full": {},
    "no-compliance": {"compliance": False},
    "no-beta": {"exclude": "beta*"},
    "geometry": {"compliance": False, "exclude": "beta*"},
}


def candidate_kwargs(robot, kw: dict) -> dict:
    """Candidate -> calibrate() keyword arguments (``exclude``: fnmatch pattern of names left out)."""
    import fnmatch

    from ..calibration.calibrate import parameter_names

    kw = dict(kw)
    ex = kw.pop("exclude", None)
    if ex is not None:
        names = parameter_names(robot, compliance=kw.get("compliance", True))
        kw["params"] = [n for n in names if not fnmatch.fnmatchcase(n, ex)]
    return kw


@dataclass
class RegionCVResult:
    """``best``: chosen candidate name; ``scores``: name -> per-region held-out mean error
    (position mm + orientation deg × 17.45 mm/deg, i.e. 1 m/rad), ``pos_mm``/``ang_deg`` the parts."""

    best: str
    kwargs: dict
    scores: dict = field(default_factory=dict)
    pos_mm: dict = field(default_factory=dict)
    ang_deg: dict = field(default_factory=dict)

    def table(self) -> str:
        rows = [f"{k}: held-out regions {np.mean(self.pos_mm[k]):.4f} mm"
                + (f" / {np.mean(self.ang_deg[k]):.4f} deg" if self.ang_deg.get(k) else "")
                + f" (per region {' '.join(f'{v:.4f}' for v in self.pos_mm[k])})" for k in self.scores]
        return "\n".join([f"calibration parameter set by region-blocked validation: {self.best}"] + rows)

    def to_dict(self) -> dict:
        return {"best": self.best, "kwargs": self.kwargs, "pos_mm": self.pos_mm, "ang_deg": self.ang_deg}


def joint_blocks(q: np.ndarray, n_blocks: int, seed: int = 0) -> np.ndarray:
    """``(N,)`` region labels ``0..n_blocks-1``: k-means (k-means++, ``seed``) on z-scored joints."""
    from scipy.cluster.vq import kmeans2

    q = np.asarray(q, dtype=np.float64)
    z = (q - q.mean(0)) / np.maximum(q.std(0), 1e-12)
    _, lab = kmeans2(z, n_blocks, seed=seed, minit="++")
    return lab.astype(np.int64)


def select_calibration(robot, ds, candidates: dict[str, dict] | None = None, n_blocks: int = 4,
                       n_register: int = 30, seed: int = 0, tie_tol: float = 0.0, base_kw: dict | None = None,
                       max_rows: int = 3000) -> RegionCVResult:
    """Choose the calibration parameter set by region-blocked validation (module docstring).

    ``robot``: nominal Robot; ``ds``: Dataset in ``robot``'s world frame; ``candidates``: name ->
    extra :func:`hykin.calibration.calibrate.calibrate` keyword arguments (default :data:`CANDIDATES`);
    ``base_kw``: keyword arguments common to all (e.g. ``position_only``); ``max_rows``: each
    calibration uses at most this many rows of the other regions (evenly spaced; cost). Data of
    several stations / tools are refused (one frame per held-out region is all it fits)."""
    from ..calibration.calibrate import calibrate
    from ..calibration.stations import row_groups

    if row_groups(ds, len(ds)) is not None:
        raise ValueError(f"{ds.source or 'training data'}: region-blocked selection of the calibration (--region-cv) "
                         "fits one frame per held-out region and does not handle several stations / tools yet; "
                         "drop --region-cv (the full calibration is used)")
    from ..calibration.frames import fit_frames, select_representative
    from ..geometry.se3 import pose_error
    from ..calibration.outliers import OutlierWarning
    from ..kinematics.classical import classical_fk

    cands = CANDIDATES if candidates is None else candidates
    base_kw = dict(base_kw or {})
    lab = joint_blocks(ds.q, n_blocks, seed)
    pos_only = not ds.has_orientation
    scores, pos, ang = {}, {}, {}
    for name, kw in cands.items():
        pos[name], ang[name], sc = [], [], []
        for k in range(n_blocks):
            hold = np.flatnonzero(lab == k)
            if len(hold) < n_register + 5:
                continue
            fit_rows = np.flatnonzero(lab != k)
            fit_rows = fit_rows[np.linspace(0, len(fit_rows) - 1, min(max_rows, len(fit_rows))).astype(int)]
            with warnings.catch_warnings():  # the fit on all rows names the outliers once
                warnings.simplefilter("ignore", OutlierWarning)
                res = calibrate(robot, ds.subset(fit_rows), **(base_kw | candidate_kwargs(robot, kw)))
            T_meas = ds.poses()[hold]
            T_mod = classical_fk(res.robot, ds.q[hold])  # with joint compliance when identified
            reg = select_representative(T_meas, n_register, seed, position_only=pos_only)
            B, E = fit_frames(T_mod[reg], T_meas[reg], position_only=pos_only)
            rest = np.setdiff1d(np.arange(len(hold)), reg)
            p, a = pose_error(B @ T_mod[rest] @ E, T_meas[rest])
            pos[name].append(float(p.mean()))
            ang[name].append(None if pos_only else float(a.mean()))
            sc.append(float(p.mean()) + (0.0 if pos_only else float(np.radians(a.mean()) * 1e3)))
        scores[name] = float(np.mean(sc)) if sc else float("inf")
        if pos_only:
            ang[name] = []
    best_score = min(scores.values())
    best = next(n for n in reversed(list(cands)) if scores[n] <= best_score * (1.0 + tie_tol))
    return RegionCVResult(best=best, kwargs=candidate_kwargs(robot, cands[best]), scores=scores, pos_mm=pos, ang_deg=ang)
