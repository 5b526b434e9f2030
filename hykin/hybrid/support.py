"""The training support of the networks and the fade of their correction (:mod:`hykin.hybrid.model`,
"Training-region awareness"): one implementation used by ``predict``, ``predict_torch``,
``fade_weight``, the uncertainty bands, :func:`support_report` and :mod:`hykin.hybrid.fade`.

Training-region awareness (networks do not extrapolate). Coordinates below are the network's own:
wrapped angles, and ``q1`` left out with ``joint1="frame"`` (it is not an input then):

* :meth:`HybridModel.range_excess` ``(N, n)``: per joint, excess beyond the trained ``[min, max]`` in
  units of that range (0 inside).
* :meth:`HybridModel.support_distance` ``(N,)``: ``max(max_j range_excess_j, pair_gap, gap)``, gap = distance
  to the nearest training sample in min-max normalised joint space (cKDTree on <= 4000 samples)
  beyond ``2 ×`` the 95th percentile of the training samples' own nearest-neighbour spacing
  (holes inside the joint box). Samples are one per configuration (:func:`distinct_groups`) and the
  spacing skips neighbours within a configuration (:func:`spacing_of`): with every row measured twice
  (repeated ISO 9283 cycles, a plan run twice) the raw rows' spacing is 0 and every query read as
  outside (probe X: 500 of 500 test poses, and ``register``'s ``fade="full"`` faded the networks away).
* :meth:`HybridModel.predict` warns once per call (:class:`hykin.hybrid.errors.OutOfRangeWarning`, counts per joint);
  :func:`support_report` gives the same counts as data (for CLI messages).
* :meth:`HybridModel.pair_gap` ``(N,)``: holes inside the joint box, fast: for every pair of input
  joints a 48 x 48 grid over the normalised training box holds the distance from the node to the
  nearest training sample of that 2-D projection minus a tolerance (2 x the 95th-percentile
  spacing, at least one grid step); a query's gap is the maximum over pairs of the bilinearly
  interpolated grids (continuous, piecewise linear, differentiable, ~15 small gathers per query).
  Measured on the UR10 data (benchmarks/bench_region.py): no series-B configuration lies within
  20 deg (every joint) of a series-A one, the A-trained networks' corrections are uncorrelated with
  B's errors (r = -0.02..-0.11) and double B's error; the pairwise grids flag those holes.
* Fade (``fade=True`` = ``"support"``, default): the network correction is multiplied by
  ``w = 1`` for ``d <= 0``, ``w = (1 + cos(π d / fade_width)) / 2`` for ``0 < d < fade_width``,
  ``w = 0`` beyond, with ``d = max(max_j range_excess_j, pair_gap)`` and ``fade_width = 0.1`` (10 %
  of the trained range). Far outside, the hybrid equals the calibrated classical model exactly.
  ``fade="range"``: per-joint ranges only; ``fade="full"``: :meth:`support_distance` (adds the
  joint nearest-neighbour gap; 3-4x slower; :func:`hykin.measure.register.register_model` sets it for a
  new measurement series, which samples the joint box differently from the training data);
  ``fade=False`` never fades. ``fade_cv=K`` (K >= 2) measures where the networks stop helping by
  leave-one-region-out at the end of ``fit`` and sets ``fade_offset`` (full correction up to that
  distance) and ``fade_width`` from it (:mod:`hykin.hybrid.fade`).

Here all of it is functions over the fitted arrays (:class:`Support`), in network coordinates
(:mod:`hykin.hybrid.inputs`) normalised by the trained range ``upper - lower`` of each joint.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np
import torch

from ..io.payload import payload_outside
from ..kinematics.chunks import run_chunked, worker_count
from ..kinematics.fk import HAVE_NUMBA
from .errors import OutOfRangeWarning

__all__ = ["GAP_FACTOR", "PAIR_GRID", "SAME_JOINTS", "SUPPORT_POINTS", "Support", "distinct_groups", "fade_distance", "fade_distance_torch",
           "fade_weight", "fit_support", "nn_gap", "nn_gap_torch", "pair_gap", "pair_gap_torch", "range_excess",
           "range_excess_torch", "spacing_of", "support_distance", "support_report", "support_tree", "warn_outside"]

SUPPORT_POINTS = 4000  # training samples kept for the nearest-neighbour gap
GAP_FACTOR = 2.0  # tolerance of the gaps, in 95th-percentile nearest-neighbour spacings
PAIR_GRID = 48  # nodes per axis of the pairwise hole grids
# Rows whose joints agree to this fraction of every joint's data range are one configuration (0.036° of a
# 360° joint; an encoder's jitter between repeated cycles is far below it, neighbouring poses of a plan far above).
SAME_JOINTS = 1e-4


@dataclass
class Support:
    """Fitted support of the networks (arrays owned by the model; this is a view of them).

    lower, upper: ``(n,)`` trained range per joint (network coordinates); points: ``(M, n)`` training
    samples normalised to that range; spacing: their 95th-percentile nearest-neighbour distance;
    tree: ``scipy.spatial.cKDTree`` over ``points`` (None: not built); pair_index: ``(P, 2)`` joint
    pairs of the hole grids; pair_gap: ``(P, G, G)`` gap at the grid nodes."""

    lower: np.ndarray
    upper: np.ndarray
    points: np.ndarray
    spacing: float
    tree: object
    pair_index: np.ndarray
    pair_gap: np.ndarray

    @property
    def span(self) -> np.ndarray:
        """``(n,)`` trained range per joint, at least 1e-6 (the normalisation of every distance)."""
        return np.maximum(self.upper - self.lower, 1e-6)


def support_tree(points: np.ndarray):
    """Nearest-neighbour tree (``cKDTree``) over normalised support points ``(M, n)``."""
    from scipy.spatial import cKDTree

    return cKDTree(points)


def _pair_grids(x: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hole grids over normalised training joints ``x`` ``(N, n)`` for every pair of ``joints``
    (indices): ``(pairs (P, 2), gaps (P, G, G))``, the gap being the distance from each node of a
    ``G x G`` grid over ``[0, 1]^2`` to the nearest training sample of that 2-D projection, minus a
    tolerance ``max(2 x p95 nearest-neighbour spacing, grid step)``."""
    from scipy.spatial import cKDTree

    G = PAIR_GRID
    idx = joints
    pairs = np.array([(i, j) for a, i in enumerate(idx) for j in idx[a + 1 :]], dtype=np.int64).reshape(-1, 2)
    g = np.linspace(0.0, 1.0, G)
    nodes = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    gaps = np.zeros((len(pairs), G, G))
    for k, (i, j) in enumerate(pairs):
        p2 = x[:, [i, j]]
        pts = p2[np.unique(distinct_groups(p2), return_index=True)[1]]  # repeats would make the spacing ~0
        tree = cKDTree(pts)
        tol = max(GAP_FACTOR * spacing_of(pts), 1.0 / (G - 1))
        d = tree.query(nodes)[0]
        gaps[k] = np.maximum(0.0, d - tol).reshape(G, G)
    return pairs, gaps


def distinct_groups(q: np.ndarray) -> np.ndarray:
    """``(N,)`` configuration id of each row of joints ``q`` ``(N, n)``: rows in one cell of a grid of
    :data:`SAME_JOINTS` x each joint's data range share an id (repeated measurements of one pose). A grid,
    not chains of near pairs: a slow, densely sampled stream must not collapse into one "configuration";
    the price is that an encoder's jitter splits a repeat across a cell face now and then (rare: jitter
    is far below the cell). Ids count configurations in order of their first row (no repeats: ``0..N-1``)."""
    q = np.asarray(q, dtype=np.float64)
    if len(q) == 0:
        return np.zeros(0, dtype=np.int64)
    lo = q.min(0)
    key = np.floor((q - lo) / np.maximum(q.max(0) - lo, 1e-12) / SAME_JOINTS).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[np.asarray(inv).reshape(-1)]


def spacing_of(x: np.ndarray) -> float:
    """95th percentile of each point's distance to its nearest neighbour among normalised points ``x``
    ``(M, n)``, neighbours closer than a :data:`SAME_JOINTS` cell diagonal (repeats of the point) skipped
    (1.0 for fewer than two distinct points). Without near repeats: the plain nearest-neighbour spacing."""
    from scipy.spatial import cKDTree

    if len(x) < 2:
        return 1.0
    d = cKDTree(x).query(x, k=min(len(x), 17))[0][:, 1:]
    d = np.where(d > SAME_JOINTS * math.sqrt(x.shape[1]), d, np.inf).min(1)
    d = d[np.isfinite(d)]
    return float(np.percentile(d, 95)) if len(d) else 1.0


def fit_support(qn: np.ndarray, mask: np.ndarray, seed: int) -> Support:
    """Support of training joints ``qn`` ``(N, n)`` (network coordinates; always the data range,
    whatever the networks' input normalisation). ``mask`` ``(n,)``: joints that are network inputs
    (the hole grids pair those); ``seed``: subsample of the support points. Points and spacing are
    over distinct joint vectors (:func:`distinct_groups`): repeated rows would make the spacing 0."""
    lo, hi = qn.min(0), qn.max(0)
    span = np.maximum(hi - lo, 1e-6)
    sub = np.random.default_rng(seed).permutation(len(qn))
    first = np.zeros(len(qn), dtype=bool)
    first[np.unique(distinct_groups(qn), return_index=True)[1]] = True
    sub = sub[first[sub]][:SUPPORT_POINTS]  # the first row of each configuration (all rows without repeats)
    points = (qn[sub] - lo) / span
    tree = support_tree(points)
    spacing = spacing_of(points)
    pairs, gaps = _pair_grids((qn - lo) / span, np.flatnonzero(mask & (hi - lo > 1e-9)))
    return Support(lo, hi, points, spacing, tree, pairs, gaps)


def range_excess(sup: Support, qn: np.ndarray) -> np.ndarray:
    """``(N, n)`` per-joint excess of ``qn`` beyond the trained range, in units of that range (0 inside)."""
    return np.maximum(0.0, np.maximum(sup.lower - qn, qn - sup.upper)) / sup.span


def range_excess_torch(sup: Support, qn):
    """Differentiable :func:`range_excess` (float64 tensor ``(N, n)``)."""
    lo = torch.as_tensor(sup.lower, dtype=torch.float64, device=qn.device)
    hi = torch.as_tensor(sup.upper, dtype=torch.float64, device=qn.device)
    span = torch.clamp(hi - lo, min=1e-6)
    return torch.clamp(torch.maximum(lo - qn, qn - hi), min=0.0) / span


if HAVE_NUMBA:
    import numba

    @numba.njit(cache=True, nogil=True)
    def pair_gap_row(qk, lower, span, field, I, J):  # pragma: no cover
        """:func:`pair_gap` of one query ``qk`` ``(n,)`` (compiled; the fast hybrid kernel calls it too)."""
        G = field.shape[1]
        top = G - 1.0
        best = -np.inf
        for p in range(I.shape[0]):
            i, j = I[p], J[p]
            ui = min(max((qk[i] - lower[i]) / span[i], 0.0), 1.0) * top
            uj = min(max((qk[j] - lower[j]) / span[j], 0.0), 1.0) * top
            i0 = min(max(np.floor(ui), 0.0), G - 2.0)
            j0 = min(max(np.floor(uj), 0.0), G - 2.0)
            fi, fj = ui - i0, uj - j0
            a, b = int(i0), int(j0)
            v = (field[p, a, b] * (1 - fi) * (1 - fj) + field[p, a + 1, b] * fi * (1 - fj)
                 + field[p, a, b + 1] * (1 - fi) * fj + field[p, a + 1, b + 1] * fi * fj)
            best = max(best, v)
        return best

    @numba.njit(cache=True, nogil=True)
    def _pair_gap_range(qn, lower, span, field, I, J, out, k0, k1):  # pragma: no cover
        """Numpy-path :func:`pair_gap` of rows ``k0:k1`` (same operations, same numbers)."""
        for k in range(k0, k1):
            out[k] = pair_gap_row(qn[k], lower, span, field, I, J)


#: batches at least this large spread the pair gap over the worker threads (:func:`run_chunked`)
_PAIR_GAP_PARALLEL_MIN = 2048


def pair_gap(sup: Support, qn: np.ndarray) -> np.ndarray:
    """``(N,)`` hole gap of ``qn`` ``(N, n)``: max over joint pairs of the bilinearly interpolated
    pairwise gap grid (0 where the training data cover every 2-D projection of the query)."""
    n_rows = qn.shape[0]
    if len(sup.pair_index) == 0:
        return np.zeros(n_rows)
    G = sup.pair_gap.shape[1]
    I, J = sup.pair_index[:, 0], sup.pair_index[:, 1]
    span = sup.span
    if HAVE_NUMBA:
        out = np.empty(n_rows)
        args = (np.ascontiguousarray(qn, dtype=np.float64), np.ascontiguousarray(sup.lower),
                np.ascontiguousarray(span), np.ascontiguousarray(sup.pair_gap, dtype=np.float64),
                np.ascontiguousarray(I), np.ascontiguousarray(J), out)
        run_chunked(_pair_gap_range, args, n_rows, min_chunk=_PAIR_GAP_PARALLEL_MIN // 2)
        return out
    u = np.clip((qn - sup.lower) / span, 0.0, 1.0) * (G - 1)
    field = sup.pair_gap.reshape(-1)
    ui, uj = u[:, I], u[:, J]
    i0 = np.clip(np.floor(ui), 0, G - 2)
    j0 = np.clip(np.floor(uj), 0, G - 2)
    fi, fj = ui - i0, uj - j0
    k00 = np.arange(len(I)) * G * G + i0.astype(np.int64) * G + j0.astype(np.int64)
    v = (field[k00] * (1 - fi) * (1 - fj) + field[k00 + G] * fi * (1 - fj) + field[k00 + 1] * (1 - fi) * fj
         + field[k00 + G + 1] * fi * fj)
    return v.max(1)


def pair_gap_torch(sup: Support, qn):
    """Differentiable :func:`pair_gap` (tensor ``(N, n)`` in network coordinates -> ``(N,)``)."""
    n_rows = qn.shape[0]
    if len(sup.pair_index) == 0:
        return torch.zeros(n_rows, dtype=qn.dtype, device=qn.device)
    G = sup.pair_gap.shape[1]
    I, J = sup.pair_index[:, 0], sup.pair_index[:, 1]
    span = np.maximum(sup.upper - sup.lower, 1e-6)
    lo = torch.as_tensor(sup.lower, dtype=qn.dtype, device=qn.device)
    u = torch.clamp((qn - lo) / torch.as_tensor(span, dtype=qn.dtype, device=qn.device), 0.0, 1.0) * (G - 1)
    field = torch.as_tensor(sup.pair_gap, dtype=qn.dtype, device=qn.device).reshape(-1)
    ui, uj = u[:, I], u[:, J]
    i0 = torch.clamp(torch.floor(ui), 0, G - 2)
    j0 = torch.clamp(torch.floor(uj), 0, G - 2)
    fi, fj = ui - i0, uj - j0
    k00 = torch.as_tensor(np.arange(len(I)) * G * G, device=qn.device) + i0.long() * G + j0.long()
    v = (field[k00] * (1 - fi) * (1 - fj) + field[k00 + G] * fi * (1 - fj) + field[k00 + 1] * (1 - fi) * fj
         + field[k00 + G + 1] * fi * fj)
    return v.max(1).values


_NN_PARALLEL_ROWS = 4096  # nearest-neighbour queries below this many rows run on the calling thread


def nn_gap(sup: Support, qn: np.ndarray) -> np.ndarray:
    """``(N,)`` distance of ``qn`` to the nearest support point beyond ``GAP_FACTOR x spacing``."""
    # scipy starts its worker threads on every call (~1.5 ms for two): one thread for small batches
    workers = worker_count() if len(qn) >= _NN_PARALLEL_ROWS else 1
    nn, _ = sup.tree.query((qn - sup.lower) / sup.span, k=1, workers=workers)
    return np.maximum(0.0, nn - GAP_FACTOR * sup.spacing)


def nn_gap_torch(sup: Support, x):
    """Differentiable :func:`nn_gap` of normalised queries ``x`` (tensor ``(N, n)``, already
    ``(qn - lower) / span``): ``|x|^2 + |p|^2 - 2 x.p`` in row chunks (exportable to ONNX)."""
    pts = torch.as_tensor(sup.points, dtype=x.dtype, device=x.device)
    p2 = (pts * pts).sum(1)
    out = []
    for i in range(0, x.shape[0], 2048):
        xi = x[i : i + 2048]
        d2 = (xi * xi).sum(1, keepdim=True) + p2[None, :] - 2.0 * xi @ pts.T
        out.append(torch.sqrt(torch.clamp(d2.min(1).values, min=1e-24)))  # finite gradient at 0
    nn = torch.cat(out) if out else x.new_zeros(0)
    return torch.clamp(nn - GAP_FACTOR * sup.spacing, min=0.0)


def support_distance(sup: Support, qn: np.ndarray, ex: np.ndarray | None = None,
                     pg: np.ndarray | None = None) -> np.ndarray:
    """``(N,)`` distance outside the training data: max of range excess, nearest-neighbour gap and
    pair gap (``ex`` ``(N, n)`` / ``pg`` ``(N,)``: already computed range excess / pair gap)."""
    ex = range_excess(sup, qn) if ex is None else ex
    pg = pair_gap(sup, qn) if pg is None else pg
    return np.maximum(np.maximum(ex.max(1), nn_gap(sup, qn)), pg)


def fade_distance(sup: Support, qn: np.ndarray, mode, ex: np.ndarray | None = None,
                  pg: np.ndarray | None = None) -> np.ndarray:
    """``(N,)`` the distance fade ``mode`` uses: ``"range"`` range excess, ``"full"``
    :func:`support_distance`, otherwise (True / ``"support"``) range excess and pair gap."""
    ex = range_excess(sup, qn) if ex is None else ex
    if mode == "range":
        return ex.max(1)
    pg = pair_gap(sup, qn) if pg is None else pg
    if mode == "full":
        return support_distance(sup, qn, ex, pg)
    return np.maximum(ex.max(1), pg)


def fade_distance_torch(sup: Support, qn, mode):
    """Differentiable :func:`fade_distance` (tensor ``(N, n)`` in network coordinates -> ``(N,)``)."""
    ex = range_excess_torch(sup, qn)
    dist = ex.max(1).values
    if mode != "range":
        dist = torch.maximum(dist, pair_gap_torch(sup, qn))
    if mode == "full":
        lo = torch.as_tensor(sup.lower, dtype=torch.float64, device=qn.device)
        hi = torch.as_tensor(sup.upper, dtype=torch.float64, device=qn.device)
        dist = torch.maximum(dist, nn_gap_torch(sup, (qn - lo) / torch.clamp(hi - lo, min=1e-6)))
    return dist


def fade_weight(d, offset: float, width: float):
    """Fade weight for support distances ``d`` (numpy or torch ``(N,)``): 1 up to ``offset``, a cosine
    to 0 over ``width``, 0 beyond."""
    if isinstance(d, torch.Tensor):
        t = torch.clamp((d - offset) / width, 0.0, 1.0)
        return 0.5 * (1 + torch.cos(math.pi * t))
    t = np.clip((d - offset) / width, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


def support_report(model, q) -> dict:
    """Counts of queries ``q`` ``(N, n)`` outside a model's training region, for messages.

    Returns ``{"n": N, "outside": int, "per_joint": {1-based joint: count}, "message": str}``
    (``message`` empty when all are inside). Works for any model with ``range_excess`` /
    ``support_distance``; other models give zero counts."""
    q = np.atleast_2d(np.asarray(q, dtype=np.float64))
    out = {"n": len(q), "outside": 0, "per_joint": {}, "message": ""}
    if not hasattr(model, "range_excess"):
        return out
    ex = model.range_excess(q)
    d = model.support_distance(q) if hasattr(model, "support_distance") else ex.max(1)
    outside = (ex.max(1) > 0) | (d > 0)
    out["outside"] = int(outside.sum())
    out["per_joint"] = {j + 1: int(c) for j, c in enumerate((ex > 0).sum(0)) if c}
    if out["outside"]:
        per = ", ".join(f"q{j}: {c}" for j, c in out["per_joint"].items())
        holes = int(((d > 0) & ~(ex.max(1) > 0)).sum())
        parts = ([f"outside the trained joint range: {per}"] if per else []) \
            + ([f"in holes of the training data: {holes}"] if holes else [])
        out["message"] = (f"{out['outside']} of {len(q)} queries lie outside the training region of the networks"
                          + (f" ({'; '.join(parts)})" if parts else "")
                          + "; the correction fades to the calibrated model there")
    return out


def circular_joints(robot, wrap_centre) -> np.ndarray:
    """``(n,)`` bool: the network inputs taken modulo a turn (``wrap_centre`` not NaN) of joints whose
    limits span more than a turn (within less the wrap changes nothing)."""
    w = ~np.isnan(np.asarray(wrap_centre, dtype=np.float64)) if wrap_centre is not None else np.zeros(robot.dof, bool)
    return w & (np.asarray(robot.upper) - np.asarray(robot.lower) > 2 * np.pi)


def warn_outside(ex: np.ndarray, gap: np.ndarray, fading: bool, payload_range=None, payload_kg=None,
                 stacklevel: int = 2, circular=None, sup: Support | None = None) -> None:
    """One :class:`OutOfRangeWarning` with counts for queries outside the trained joint range (range
    excess ``ex`` ``(N, n)``) or in holes (pair gap ``gap`` ``(N,)``), and one for payloads
    ``payload_kg`` outside the trained ``payload_range``. ``fading``: the model fades its correction
    (the message says so). ``stacklevel``: as in :func:`warnings.warn`, counted from the caller.
    ``circular`` ``(n,)`` bool (:func:`circular_joints`) and ``sup``: a joint of more than a turn is taken
    modulo a turn, so a query "outside" its trained range lies in a gap of the data on its circle: said so,
    with how much of the circle the data cover (probe s41 AF: "outside the joint range" for a 2.5° gap of
    ±248°)."""
    out_rows = ex.max(1) > 0
    holes = (gap > 0) & ~out_rows
    if out_rows.any() or holes.any():
        tail = "the correction fades to the calibrated model there" if fading else \
            "network corrections there are extrapolations"
        if out_rows.any():
            counts = (ex > 0).sum(0)
            wr = np.zeros(len(counts), dtype=bool) if circular is None else np.asarray(circular, dtype=bool)
            per = ", ".join(f"q{j + 1}: {int(c)}" for j, c in enumerate(counts) if c and not wr[j])
            circ = ", ".join(f"q{j + 1}: {int(c)}" + ("" if sup is None else
                             f", data on {np.degrees(sup.upper[j] - sup.lower[j]):.1f}° of its 360°")
                             for j, c in enumerate(counts) if c and wr[j])
            parts = ([f"outside the joint range the networks were trained on ({per})"] if per else []) + \
                ([f"in a gap of the training data on a joint of more than a turn ({circ})"] if circ else [])
            msg = f"{int(out_rows.sum())} of {len(ex)} queries are " + "; or ".join(parts)
            if holes.any():
                msg += f"; {int(holes.sum())} more lie in holes of the training data"
        else:
            msg = f"{int(holes.sum())} of {len(ex)} queries lie in holes of the training data (inside its joint range)"
        warnings.warn(f"{msg}; {tail}", OutOfRangeWarning, stacklevel=stacklevel + 1)
    if payload_kg is not None and payload_range is not None:
        out_pl = payload_outside(payload_range, payload_kg)
        if out_pl.any():
            r = payload_range
            warnings.warn(f"{int(out_pl.sum())} of {out_pl.size} payloads lie outside the trained payloads "
                          f"[{r.lower_kg:g}, {r.upper_kg:g}] kg; the calibrated compliance model carries the "
                          "payload there (network payload dependence held at the nearest trained payload)",
                          OutOfRangeWarning, stacklevel=stacklevel + 1)
