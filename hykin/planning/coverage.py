"""Space-filling in the joint space the networks see.

The residual networks take the joints min-max normalised over the trained region, revolute joints
that can turn a full circle wrapped onto it (:class:`hykin.hybrid.model.HybridModel`, ``periodic="wrap"``).
Coverage is measured in the same coordinates: :func:`embed` maps joints to a Euclidean space where

* a joint whose region spans less than a full turn becomes ``u = (q - lo) / (hi - lo)`` in [0, 1];
* a revolute joint whose region spans a full turn (≥ 2π) becomes the point
  ``(cos q, sin q) / (2π)`` on a circle of circumference 1: distances along the circle are in
  units of a turn, so q and q + 2π (the same pose, the same network input) coincide.

:func:`farthest_point` is greedy maximin selection (Gonzalez's 2-approximation of the
k-centre problem): each new point is the candidate farthest from every point chosen so far.
:func:`fill_distance` is the covering radius of a set over a reference sample (smaller is better).

Coverage as the hybrid sees it (:func:`coverage_report`), in the unit-cube coordinates
``u = (q - lo) / (hi - lo)`` of the region (:func:`unit_coordinates`):

* :func:`centred_discrepancy`: the squared centred L2 discrepancy (Hickernell 1998; ``scipy.stats.qmc``),
  the mean squared difference between the set's empirical measure and the uniform one over all
  boxes anchored at the cube's corners, every subset of joints included (lower is more uniform; its
  expectation for a uniform random set falls as ``1/n``, for a low-discrepancy set nearly as ``1/n²``);
* :func:`marginal_ks`: the largest Kolmogorov-Smirnov distance of one joint's values from the uniform
  distribution (marginal stratification; a Latin hypercube reaches ``1/n``, a uniform random set
  about ``0.9 / √n``). Transmission errors are functions of one joint each, learnt from its marginal;
* :func:`deficit_select`: augmenting an existing design so that the union is as even as possible
  over a candidate pool drawn uniformly from the region (active selection, ``hykin plan --for-model``);
* :func:`hole_fraction`: the share of reference points (uniform over the region) that lie in a hole
  of the design by the rule :class:`hykin.hybrid.model.HybridModel` uses to fade its networks (module
  docstring there: for every pair of joints, distance in the 2-D projection to the nearest design
  point beyond ``max(2 x`` the 95th percentile of the design's own nearest-neighbour spacing in that
  projection``, 1/47)``, coordinates min-max normalised over the design). Reimplemented here without
  the wrap of full-turn joints (an approximation near the networks' seam for those joints).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..kinematics.robot import Robot

__all__ = ["centred_discrepancy", "coverage_report", "deficit_select", "embed", "farthest_point", "fill_distance",
           "hole_fraction", "marginal_ks", "min_spacing", "unit_coordinates"]

_TWO_PI = 2.0 * np.pi


def embed(robot: Robot, q, lower, upper) -> np.ndarray:
    """``(N, d)`` coverage coordinates of joints ``q`` ``(N, dof)`` for the region ``[lower, upper]``
    (module docstring; ``d = dof +`` the number of wrapped joints)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, robot.dof)
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    cols = []
    for j in range(robot.dof):
        if robot.independent_joint_type[j] == "revolute" and hi[j] - lo[j] >= _TWO_PI - 1e-9:
            cols += [np.cos(q[:, j]) / _TWO_PI, np.sin(q[:, j]) / _TWO_PI]
        else:
            cols.append((q[:, j] - lo[j]) / max(hi[j] - lo[j], 1e-12))
    return np.stack(cols, 1)


def farthest_point(X: np.ndarray, k: int, chosen=None, exclude=None) -> np.ndarray:
    """Indices of ``k`` rows of ``X`` ``(M, d)`` picked greedily by maximin distance.

    ``chosen``: indices already in the design (distances start from them; not returned). Without
    them the first pick is the row nearest the centroid. ``exclude``: bool mask of rows not to pick.
    """
    X = np.asarray(X, dtype=np.float64)
    M = len(X)
    dmin = np.full(M, np.inf)
    if exclude is not None:
        dmin[np.asarray(exclude, dtype=bool)] = -np.inf
    if chosen is not None and len(chosen):
        tree = cKDTree(X[np.asarray(chosen)])
        d, _ = tree.query(X, k=1)
        dmin = np.minimum(dmin, d)
        dmin[np.asarray(chosen)] = -np.inf
    out = np.empty(k, dtype=np.int64)
    for i in range(k):
        if i == 0 and (chosen is None or not len(chosen)):
            c = X.mean(0)
            s = np.einsum("ij,ij->i", X - c, X - c)
            s[dmin == -np.inf] = np.inf
            j = int(np.argmin(s))
        else:
            j = int(np.argmax(dmin))
        if not dmin[j] > -np.inf:
            raise ValueError(f"farthest_point: only {i} candidates available for {k} picks")
        out[i] = j
        diff = X - X[j]
        dmin = np.minimum(dmin, np.sqrt(np.einsum("ij,ij->i", diff, diff)))
        dmin[j] = -np.inf
    return out


def fill_distance(X_design: np.ndarray, X_ref: np.ndarray) -> tuple[float, float]:
    """(max, mean) distance from the reference points ``X_ref`` to their nearest design point."""
    d, _ = cKDTree(X_design).query(X_ref, k=1)
    return float(d.max()), float(d.mean())


def min_spacing(X_design: np.ndarray) -> float:
    """Smallest distance between two design points (maximin value)."""
    if len(X_design) < 2:
        return float("inf")
    d, _ = cKDTree(X_design).query(X_design, k=2)
    return float(d[:, 1].min())


def unit_coordinates(q, lower, upper) -> np.ndarray:
    """``(N, dof)`` joints ``q`` mapped to the unit cube of the region: ``(q - lower) / (upper - lower)``."""
    q = np.asarray(q, dtype=np.float64)
    lo, hi = np.asarray(lower, dtype=np.float64), np.asarray(upper, dtype=np.float64)
    return (q - lo) / np.maximum(hi - lo, 1e-12)


def centred_discrepancy(u: np.ndarray) -> float:
    """Squared centred L2 discrepancy of points ``u`` ``(N, d)`` in the unit cube (module docstring); ``O(N² d)``."""
    from scipy.stats import qmc

    return float(qmc.discrepancy(np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0), method="CD"))


def marginal_ks(u: np.ndarray) -> float:
    """Largest over the columns of ``u`` ``(N, d)`` of the Kolmogorov-Smirnov distance from U(0, 1)."""
    s = np.sort(np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0), axis=0)
    n = len(s)
    i = np.arange(1, n + 1, dtype=np.float64)[:, None]
    return float(np.maximum(i / n - s, s - (i - 1) / n).max())


_HOLE_GRID = 48  # the hybrid's pair-grid resolution: its tolerance is at least one grid step
_HOLE_FACTOR = 2.0  # the hybrid's _GAP_FACTOR


def hole_fraction(u_design: np.ndarray, u_ref: np.ndarray) -> float:
    """Share of the reference points ``u_ref`` ``(M, d)`` in a pairwise hole of ``u_design`` ``(N, d)``
    (module docstring: the hybrid's fade rule for holes). Coordinates are min-max normalised over the
    design first, as the hybrid normalises over its training data; constant columns are skipped."""
    X = np.asarray(u_design, dtype=np.float64)
    R = np.asarray(u_ref, dtype=np.float64)
    lo, span = X.min(0), np.ptp(X, axis=0)
    cols = np.flatnonzero(span > 1e-9)
    X = (X[:, cols] - lo[cols]) / span[cols]
    R = np.clip((R[:, cols] - lo[cols]) / span[cols], 0.0, 1.0)  # outside the range: the range test's, not a hole
    hole = np.zeros(len(R), bool)
    for a in range(len(cols)):
        for b in range(a + 1, len(cols)):
            pts = np.unique(np.round(X[:, [a, b]], 6), axis=0)
            tree = cKDTree(pts)
            sp = tree.query(pts, k=2)[0][:, 1] if len(pts) > 1 else np.ones(1)
            tol = max(_HOLE_FACTOR * float(np.percentile(sp, 95)), 1.0 / (_HOLE_GRID - 1))
            hole |= tree.query(R[:, [a, b]])[0] > tol
    return float(hole.mean())


def coverage_report(q, lower, upper, *, n_ref: int = 4000, seed: int = 0, max_discrepancy_n: int = 5000) -> dict:
    """Coverage of joints ``q`` ``(N, dof)`` over the region ``[lower, upper]`` (module docstring):
    ``discrepancy_cd`` (None above ``max_discrepancy_n`` poses: ``O(N²)``), ``marginal_ks``,
    ``holes_pct`` (share of ``n_ref`` uniform random reference poses in a pairwise hole, %)."""
    u = unit_coordinates(q, lower, upper)
    ref = np.random.default_rng([seed, 41]).random((n_ref, u.shape[1]))
    return {"discrepancy_cd": centred_discrepancy(u) if len(u) <= max_discrepancy_n else None,
            "marginal_ks": marginal_ks(u), "holes_pct": 100.0 * hole_fraction(u, ref)}


def deficit_select(X_pool: np.ndarray, X_have: np.ndarray, n: int, *, have_weight: float = 1.0, weight=None,
                   neighbours: float = 16.0) -> np.ndarray:
    """Indices of ``n`` rows of ``X_pool`` ``(M, d)`` that make the design ``X_have`` ``(K, d)`` plus the
    picks as even as possible over the pool, by **density deficit**.

    ``X_pool`` is a uniform sample of the region (the target density); every coordinate is a
    distance coordinate (e.g. unit-cube or :func:`embed`). Around each pool point, a ball of radius
    ``r`` should hold ``E = (K·have_weight + n) · m / M`` points of an even design of the final size
    (``m``: pool points in the ball, so balls clipped by the region's boundary expect fewer and the
    boundary is not favoured, unlike farthest-point designs); it holds ``O`` points of the current
    design (each row of ``X_have`` counts ``have_weight``: a subsample of the real design stands for
    all of it). Each pick is the pool point of largest ``(E - O) · weight`` (the most points
    missing), after which ``O`` grows by one in the balls it falls in. (Walking the pool in its
    low-discrepancy order and taking every point with half a point missing was the alternative:
    worse on the benchmark, docs/planning.md.)
    ``r`` is the median radius of a ball that holds ``neighbours`` points of the final design.
    ``weight`` ``(M,)``: optional positive factor per pool point (e.g. the model's uncertainty).
    """
    X_pool = np.asarray(X_pool, dtype=np.float64)
    X_have = np.asarray(X_have, dtype=np.float64).reshape(-1, X_pool.shape[1])
    M = len(X_pool)
    if n > M:
        raise ValueError(f"deficit_select: {n} picks from {M} candidates")
    total = len(X_have) * have_weight + n
    tree = cKDTree(X_pool)
    # r: the median radius of a ball holding `neighbours` points of the final design, measured on the
    # pool itself (any coordinates, circles of wrapped joints included)
    k = int(np.clip(round(neighbours * M / max(total, 1.0)), 2, M - 1))
    probe = np.random.default_rng(0).permutation(M)[: min(M, 256)]
    r = float(np.median(tree.query(X_pool[probe], k=k + 1)[0][:, -1]))
    expected = tree.query_ball_point(X_pool, r, return_length=True).astype(np.float64) * (total / M)
    observed = np.zeros(M)
    if len(X_have):
        observed += have_weight * cKDTree(X_have).query_ball_point(X_pool, r, return_length=True)
    w = np.ones(M) if weight is None else np.asarray(weight, dtype=np.float64)
    avail = np.ones(M, bool)
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        j = int(np.argmax(np.where(avail, (expected - observed) * w, -np.inf)))
        out[i] = j
        avail[j] = False
        observed[tree.query_ball_point(X_pool[j], r)] += 1.0
    return out
