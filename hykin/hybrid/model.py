"""Hybrid forward kinematics: calibrated classical model + residual networks (DESIGN.md §1.1).

``T*(q)``: ``p* = p̂(q) + w(q) Δp(q)``, ``R* = exp(w(q) Δr(q)) · R̂(q)``, where ``T̂`` is the
calibrated classical model (geometry + joint compliance), ``Δp``/``Δr`` the position and orientation
networks (base frame) and ``w`` the support fade (below). When the training data carry a temperature
column, ``T̂`` also expands with temperature (one linear coefficient identified with the calibration,
:mod:`hykin.thermal`): ``predict(q, temperature_c=...)``; the networks learn at the reference
temperature. On rx160-nongeo (simulated 11.5e-6 /K) the coefficient is recovered to 0.3 % and the
hybrid error against noisy measurements is 1.28x the noise floor with the test temperatures given,
1.53x without (benchmarks/bench_paper.py).

Input representation (``periodic``, ``joint1``; chosen by measurement, benchmarks/bench_region.py):

* ``periodic="wrap"`` (default): every revolute joint is wrapped onto the circle, with the seam placed
  in the widest gap of the training angles. Kinematics, gravity and compliance are 2π-periodic in a
  revolute joint, so ``q`` and ``q + 2π`` get the same features (sin/cos of q plus the min-max
  scaled wrapped angle); a query reached through another turn of a wrist joint is not an
  extrapolation. ``"none"``: raw angles (paper). Measured on UR10 series A (3 seeds, held-out
  15 %): 0.120 mm / 0.0280 deg wrapped vs 0.119 mm / 0.0274 deg raw, equal within seed noise, so
  the representation that is right for another turn of a joint is the default.
* ``joint1="frame"``: residuals are learnt in the frame turning with joint 1 and the networks do not
  see ``q1`` (gravity, compliance and the errors of joints 2..n look the same at every ``q1`` when
  joint 1 is vertical). ``"input"`` (default): residuals in the base frame, ``q1`` an input. The
  real data show a ``q1`` dependence: UR10 series A held-out error 0.124 mm with ``q1`` as input vs
  0.208 mm without (calibrated 0.388 mm), so ``q1`` stays an input by default.
* ``input_joints``: the joints the networks see (others are neither inputs nor checked for support).

Training-region awareness (networks do not extrapolate). Coordinates below are the network's own:
wrapped angles, and ``q1`` left out with ``joint1="frame"`` (it is not an input then):

* :meth:`HybridModel.range_excess` ``(N, n)``: per joint, excess beyond the trained ``[min, max]`` in
  units of that range (0 inside).
* :meth:`HybridModel.support_distance` ``(N,)``: ``max(max_j range_excess_j, pair_gap, gap)``, gap = distance
  to the nearest training sample in min-max normalised joint space (cKDTree on <= 4000 samples)
  beyond ``2 ×`` the 95th percentile of the training samples' own nearest-neighbour spacing
  (holes inside the joint box).
* :meth:`HybridModel.predict` warns once per call (:class:`OutOfRangeWarning`, counts per joint);
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
  joint nearest-neighbour gap; 3-4x slower; :func:`hykin.register.register_model` sets it for a
  new measurement series, which samples the joint box differently from the training data);
  ``fade=False`` never fades. ``fade_cv=K`` (K >= 2) measures where the networks stop helping by
  leave-one-region-out at the end of ``fit`` and sets ``fade_offset`` (full correction up to that
  distance) and ``fade_width`` from it (:mod:`hykin.fade`).

Payload (:mod:`hykin.payload`). Training data may carry a ``payload_kg`` column (and
``payload_com_x/y/z``, tool frame): the calibration deflects every row under its own payload (joint
stiffness identified), the targets are taken against that physics, and ``predict(q, payload_kg=...,
payload_com_m=...)`` evaluates the calibrated compliance at any payload (default: the robot file's).
``payload_input`` ("auto" default): with several distinct payloads in the training data the
networks also take the payload as an input, clamped to the trained ``[min, max]`` payload
(``payload_range_``): beyond it the network's payload dependence is held at the nearest trained
payload and only the physics changes with payload. Measured (benchmarks/bench_payload.py, 4000
rows, 6000 steps; decided on kr-payload-virtual, rows at 0 and 12 kg): payload-agnostic networks
0.0325 / 0.0289 / 0.0322 / 0.0439 mm at 0 / 6 / 12 / 20 kg, payload as input 0.0289 / 0.0284 /
0.0290 / 0.0355 mm (holding beats fading to the payload-agnostic correction at 20 kg). Held-out
robot (rx160-nongeo): 0.0279 / 0.0279 / 0.0280 / 0.0280 mm with payload as input vs 0.0282 /
0.0278 / 0.0276 / 0.0276 mm agnostic (equal within seed noise: no harm where the physics leaves
no payload dependence). With one payload the networks stay payload-agnostic and the physics
carries every other payload. ``predict`` warns (:class:`OutOfRangeWarning`) for payloads outside
the trained ones. Not payload-aware yet: :meth:`predict_uncertainty` (bands of the trained
payloads) and the extrapolation growth of :mod:`hykin.uncertainty` (robot file's payload).

Uncertainty (:meth:`HybridModel.predict_uncertainty`): radii of the ``level`` band (e.g. 95 %) of the
position (mm) and orientation (deg) error per query, split-conformal: empirical quantiles of the
error norms of the hybrid and of the calibrated model on held-out validation samples, blended by
``w`` = the fade of :meth:`support_distance` (``w r_hybrid + (1 - w) max(g r_classical, r_hybrid)``):
outside the training data the band becomes that of the calibrated model, widened by
``g = 1 + max_j a_j + sum_j k_j e_j`` over the joints beyond their trained range (``e_j`` the
range excess): the calibration extrapolates too. The step ``a_j`` and slope ``k_j`` are measured
in ``fit`` by refitting the calibration on the middle of each joint's range and evaluating on its
ends (:mod:`hykin.uncertainty`; a few seconds). Cheap at query time (no ensemble), never on the
:meth:`predict` path. Coverage of the 95 % band on a virtual RX160 (rx160-nongeo) trained on the
middle half of every joint range, queried on the full range: outside the range 54 % (position)
with the in-range band alone, 90-93 % with the growth (orientation 72 % -> 90-92 %). UR10 series A
held-out 94.8 % (position) / 95.5 % (orientation); series B (new series, registered from 30 poses)
92.8 % / 94.8 %; virtual in range 94.4 % / 94.9 % (benchmarks/bench_region.py).
"""

from __future__ import annotations

import hashlib
import math
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from ..calibration.thermal import (
    MAX_PLAUSIBLE_PER_K,
    MIN_EFFECT_M,
    TEMPERATURE_COLUMNS,
    ThermalFit,
    fit_coefficient,
    scale_about,
    temperature_of,
    to_reference,
)
from ..io.modelfile import (
    ModelFileError,
    read_model_file,
    robot_from_json_dict,
    robot_to_dict,
    write_model_file,
)
from ..io.robot_file import load_robot
from ..io.robot_toml import robot_to_toml_string
from ..kinematics import se3
from ..kinematics.fk import HAVE_NUMBA, fk, fk_torch
from ..kinematics.payload import (
    PayloadRange,
    payload_column,
    payload_kwargs,
    payload_of,
    payload_outside,
    payload_range_of,
)
from ..kinematics.robot import Robot
from .nets import ResidualNet, count_parameters, make_net
from .train import Recipe, get_recipe, train_net

__all__ = ["HybridError", "HybridModel", "OutOfRangeWarning", "classical_fk", "classical_fk_torch", "support_report"]

_SUPPORT_POINTS = 4000
_GAP_FACTOR = 2.0
_TWO_PI = 2.0 * math.pi
_PAIR_GRID = 48  # nodes per axis of the pairwise hole grids
#: band levels at which the validation error quantiles are stored (predict_uncertainty interpolates)
_UNC_LEVELS = np.round(np.arange(0.5, 0.99501, 0.005), 4)


class HybridError(ValueError):
    """Bad input to a hybrid model (shape, NaN, unfitted model...)."""


class OutOfRangeWarning(UserWarning):
    """Queries outside the joint range the networks were trained on."""


def classical_fk(robot: Robot, q: np.ndarray, payload_kg=None, payload_com_m=None) -> np.ndarray:
    """Classical prediction ``(N, 4, 4)``: FK of the (calibrated) robot, with joint compliance when
    the robot has finite stiffness. ``payload_kg`` / ``payload_com_m``: per-row payload
    (:func:`hykin.compliance.gravity_torques`); default the robot's."""
    if robot.has_compliance:
        from ..kinematics.compliance import compliant_fk

        return compliant_fk(robot, q, payload_kg=payload_kg, payload_com_m=payload_com_m)
    return fk(robot, q)


def classical_fk_torch(robot: Robot, q, payload_kg=None, payload_com_m=None):
    """Differentiable twin of :func:`classical_fk` (float64 tensor ``(N, n)`` -> ``(N, 4, 4)``)."""
    if robot.has_compliance:
        from ..kinematics.compliance import compliant_fk_torch

        return compliant_fk_torch(robot, q, payload_kg=payload_kg, payload_com_m=payload_com_m)
    return fk_torch(robot, q)


def _rodrigues(rv: np.ndarray) -> np.ndarray:
    """Rotation vectors ``(N, 3)`` -> ``(N, 3, 3)`` (vectorised, Taylor-safe near 0)."""
    th2 = np.einsum("ij,ij->i", rv, rv)
    th = np.sqrt(th2)
    small = th2 < 1e-8
    ths = np.where(small, 1.0, th)
    A = np.where(small, 1 - th2 / 6, np.sin(ths) / ths)
    B = np.where(small, 0.5 - th2 / 24, (1 - np.cos(ths)) / np.where(small, 1.0, th2))
    x, y, z = rv[:, 0], rv[:, 1], rv[:, 2]
    K = np.zeros((rv.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -z, y, z, -x, -y, x
    return np.eye(3) + A[:, None, None] * K + B[:, None, None] * (K @ K)


def _fade_np(d: np.ndarray, width: float) -> np.ndarray:
    t = np.clip(d / width, 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * t))


if HAVE_NUMBA:
    import numba

    @numba.njit(cache=True, nogil=True, parallel=True)
    def _pair_gap_kernel(qn, lower, span, field, I, J, out):  # pragma: no cover
        """Numpy-path :meth:`HybridModel.pair_gap` on network coordinates ``qn`` (same operations, same numbers)."""
        G = field.shape[1]
        top = G - 1.0
        for k in numba.prange(qn.shape[0]):
            best = -np.inf
            for p in range(I.shape[0]):
                i, j = I[p], J[p]
                ui = min(max((qn[k, i] - lower[i]) / span[i], 0.0), 1.0) * top
                uj = min(max((qn[k, j] - lower[j]) / span[j], 0.0), 1.0) * top
                i0 = min(max(np.floor(ui), 0.0), G - 2.0)
                j0 = min(max(np.floor(uj), 0.0), G - 2.0)
                fi, fj = ui - i0, uj - j0
                a, b = int(i0), int(j0)
                v = (field[p, a, b] * (1 - fi) * (1 - fj) + field[p, a + 1, b] * fi * (1 - fj)
                     + field[p, a, b + 1] * (1 - fi) * fj + field[p, a + 1, b + 1] * fi * fj)
                best = max(best, v)
            out[k] = best


if HAVE_NUMBA:

    @numba.njit(cache=True, nogil=True, parallel=True)
    def _rotate_poses_kernel(rv, T):  # pragma: no cover
        """In place ``T[:, :3, :3] = exp(rv) @ T[:, :3, :3]`` (same formula as :func:`_rodrigues`)."""
        for k in numba.prange(rv.shape[0]):
            x, y, z = rv[k, 0], rv[k, 1], rv[k, 2]
            th2 = x * x + y * y + z * z
            if th2 < 1e-8:
                A = 1 - th2 / 6
                B = 0.5 - th2 / 24
            else:
                th = np.sqrt(th2)
                A = np.sin(th) / th
                B = (1 - np.cos(th)) / th2
            # R = I + A K + B K^2, K = [[0, -z, y], [z, 0, -x], [-y, x, 0]]
            r00 = 1 + B * (-z * z - y * y)
            r01 = -A * z + B * (x * y)
            r02 = A * y + B * (x * z)
            r10 = A * z + B * (x * y)
            r11 = 1 + B * (-z * z - x * x)
            r12 = -A * x + B * (y * z)
            r20 = -A * y + B * (x * z)
            r21 = A * x + B * (y * z)
            r22 = 1 + B * (-y * y - x * x)
            for c in range(3):
                t0, t1, t2 = T[k, 0, c], T[k, 1, c], T[k, 2, c]
                T[k, 0, c] = r00 * t0 + r01 * t1 + r02 * t2
                T[k, 1, c] = r10 * t0 + r11 * t1 + r12 * t2
                T[k, 2, c] = r20 * t0 + r21 * t1 + r22 * t2


def _seam_centres(q: np.ndarray, revolute: np.ndarray) -> np.ndarray:
    """Per joint the centre ``c`` of the wrapping window ``[c - π, c + π)`` (NaN: not wrapped).

    The seam ``c ± π`` sits in the middle of the widest gap between the training angles on the circle;
    of the equivalent centres ``c + 2πk`` the one nearest the median raw angle is kept, so wrapped
    training angles equal the raw ones whenever the data do not straddle the seam."""
    c = np.full(q.shape[1], np.nan)
    for j in np.flatnonzero(revolute):
        a = np.sort(np.mod(q[:, j], _TWO_PI))
        gaps = np.diff(np.r_[a, a[0] + _TWO_PI])
        k = int(np.argmax(gaps))
        cj = a[k] + 0.5 * gaps[k] + math.pi
        c[j] = cj + _TWO_PI * np.round((np.median(q[:, j]) - cj) / _TWO_PI)
    return c


def _rotate_about(u: np.ndarray, angle, v):
    """Rotate vectors ``v`` ``(N, 3)`` about the unit axis ``u`` ``(3,)`` by ``angle`` ``(N,)`` (numpy or torch)."""
    if isinstance(v, torch.Tensor):
        ut = torch.as_tensor(u, dtype=v.dtype, device=v.device)
        c, s = torch.cos(angle)[:, None], torch.sin(angle)[:, None]
        cross = torch.cross(ut.expand_as(v), v, dim=1)
        return v * c + cross * s + ut * (v @ ut)[:, None] * (1 - c)
    c, s = np.cos(angle)[:, None], np.sin(angle)[:, None]
    return v * c + np.cross(u, v) * s + u * (v @ u)[:, None] * (1 - c)


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
        out["message"] = (f"{out['outside']} of {len(q)} queries lie outside the training region of the networks"
                          + (f" (outside the trained joint range: {per}" if per else " (")
                          + (f"; in holes of the training data: {holes})" if holes else ")")
                          + "; the correction fades to the calibrated model there")
    return out


def _versions() -> dict:
    import platform

    import scipy

    try:
        from importlib.metadata import version

        hv = version("hykin")
    except Exception:  # noqa: BLE001 - not installed as a distribution
        hv = "dev"
    return {"hykin": hv, "torch": torch.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
            "python": platform.python_version()}


def _hash(ds) -> str:
    try:
        from ..io.dataset import dataset_hash

        return dataset_hash(ds)
    except Exception:  # noqa: BLE001 - duck-typed dataset
        h = hashlib.sha256()
        for a in (ds.q, ds.xyz_m) + ((ds.quat_wxyz,) if ds.quat_wxyz is not None else ()):
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
        return h.hexdigest()


def _json_safe(x):
    """Nested data -> JSON-safe (arrays to lists, non-finite floats to "nan"/"inf"/"-inf", others to str)."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if hasattr(x, "tolist"):
        return _json_safe(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return "nan" if x != x else ("inf" if x > 0 else "-inf")
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return str(x)


class HybridModel:
    """Calibrated classical model + residual networks (scikit-learn-like ``fit``/``predict``).

    robot: nominal robot (Robot, preset name or file). arch: network name (:mod:`hykin.nets`).
    recipe: training recipe name or :class:`hykin.train.Recipe` (:mod:`hykin.train`).
    calibrate: run :func:`hykin.calibrate.calibrate` first (``calibrate_kw`` passed on; with
    ``{"select": "region-cv"}`` the parameter set is chosen by region-blocked validation,
    :func:`hykin.region_cv.select_calibration`, result in ``calibration_cv_``).
    normalise: ``"data"`` (min-max over the training joints) or ``"full"`` (joint limits).
    fade: True (= "support": joint ranges and pairwise holes), "range", "full" or False (module
    docstring); fade_width in units of the range. fade_cv: number of regions (>= 2) for a fade measured
    by leave-one-region-out at the end of fit (:mod:`hykin.fade`; sets fade_offset and fade_width; 0 = off).
    periodic: "wrap" (revolute joints on the circle) or "none"; joint1: "input" or "frame";
    input_joints: 1-based joints the networks see (default all; module docstring, "Input representation").
    device: "cpu" or "cuda". seed: training seed. max_seconds: training time budget per network.
    val_fraction: share of the training set held out for validation when ``fit`` gets no ``val``.
    recipe_kw: overrides of recipe fields (e.g. ``{"max_epochs": 50}``).
    thermal: identify a linear thermal expansion coefficient from the training data's temperature
    column (:mod:`hykin.thermal`): ``"auto"`` (when there is one; kept only if significant and
    plausible), True (required), False (ignore temperatures). Fitted: ``thermal_``.
    payload_input: "auto"/True: payload is a network input when the training data hold several
    payloads (``payload_kg`` column); False: payload-agnostic networks. Fitted: ``payload_range_``
    (None without a payload column), ``payload_input_`` (module docstring, "Payload").
    """

    def __init__(self, robot, arch: str = "default", recipe: str | Recipe = "default", calibrate: bool = True,
                 calibrate_kw: dict | None = None, normalise: str = "data", fade: bool | str = True,
                 fade_width: float = 0.1, device: str = "cpu", seed: int = 0, max_seconds: float | None = None,
                 val_fraction: float | None = None, recipe_kw: dict | None = None, periodic: str = "wrap",
                 joint1: str = "input", input_joints=None, thermal: bool | str = "auto",
                 payload_input: bool | str = "auto", fade_cv: int = 0):
        self.robot = load_robot(robot)
        self.arch = arch
        self.recipe = get_recipe(recipe, **(recipe_kw or {}))
        self.calibrate = bool(calibrate)
        self.calibrate_kw = dict(calibrate_kw or {})
        if normalise not in ("data", "full"):
            raise HybridError(f"normalise must be 'data' or 'full', got {normalise!r}")
        self.normalise = normalise
        if fade not in (True, False, "support", "range", "full"):
            raise HybridError(f"fade must be True, False, 'support', 'range' or 'full', got {fade!r}")
        self.fade = fade
        if not (fade_width > 0):
            raise HybridError(f"fade_width must be > 0, got {fade_width}")
        self.fade_width = float(fade_width)
        # Support distance up to which the correction is fully applied (0: fade starts at the data);
        # set with fade_width by hykin.fade.calibrate_fade when fade_cv >= 2 (leave-one-region-out).
        self.fade_offset = 0.0
        self.fade_cv = int(fade_cv)
        self.fade_calibration_ = None
        if periodic not in ("wrap", "none"):
            raise HybridError(f"periodic must be 'wrap' or 'none', got {periodic!r}")
        if joint1 not in ("input", "frame"):
            raise HybridError(f"joint1 must be 'input' or 'frame', got {joint1!r}")
        self.periodic = periodic
        self.joint1 = joint1
        if thermal not in (True, False, "auto"):
            raise HybridError(f"thermal must be True, False or 'auto', got {thermal!r}")
        self.thermal = thermal
        if payload_input not in (True, False, "auto"):
            raise HybridError(f"payload_input must be True, False or 'auto', got {payload_input!r}")
        self.payload_input = payload_input
        n = self.robot.dof
        ij = tuple(range(1, n + 1)) if input_joints is None else tuple(int(j) for j in input_joints)
        if not ij or any(not 1 <= j <= n for j in ij) or len(set(ij)) != len(ij):
            raise HybridError(f"input_joints must be distinct joint numbers in 1..{n}, got {input_joints!r}")
        self.input_joints = ij
        self._mask = np.array([(j + 1) in ij and not (j == 0 and joint1 == "frame") for j in range(n)])
        self.device = device
        self.seed = int(seed)
        self.max_seconds = max_seconds
        self.val_fraction = self.recipe.val_fraction if val_fraction is None else float(val_fraction)
        make_net(arch, 1)  # validates the name early
        self.robot_: Robot | None = None
        self.net_pos_: ResidualNet | None = None
        self.net_rot_: ResidualNet | None = None
        self.meta_: dict = {}
        self.calibration_ = None  # CalibrationResult of the last fit (not saved; its summary is in meta_)
        self.calibration_cv_ = None  # hykin.region_cv.RegionCVResult when calibrate_kw selects by region CV
        # Rigid frames around the model, set by hykin.register for a new measurement series:
        # pose = frame_pre · T_model(q) · frame_post (identity for the series the model was trained on).
        self.frame_pre = np.eye(4)
        self.frame_post = np.eye(4)
        n = self.robot.dof
        self.wrap_centre_ = np.full(n, np.nan)  # per joint, NaN = not wrapped
        self.j1_axis_ = None  # unit joint-1 axis (world frame) when joint1 == "frame"
        self.unc_ = None  # validation error quantiles (predict_uncertainty)
        self.thermal_ = None  # hykin.thermal.ThermalFit when the training data had a temperature column
        self.pair_index_ = np.zeros((0, 2), dtype=np.int64)  # joint pairs of the hole grids
        self.pair_gap_ = np.zeros((0, _PAIR_GRID, _PAIR_GRID))  # (P, G, G) gap at the grid nodes
        self.payload_range_: PayloadRange | None = None  # payloads of the training data (payload_kg column)
        self.payload_input_ = False  # payload is a network input (training data with several payloads)
        self.payload_default_kg_ = None  # payload the networks see when predict gets none (None: robot_'s)

    # ------------------------------------------------------------------ input representation

    def _netq(self, q):
        """Joints as the networks see them (numpy or torch ``(N, n)``): wrapped revolute joints,
        ``q1`` zeroed with ``joint1="frame"``."""
        c = self.wrap_centre_
        wrapped = np.isfinite(c)
        if isinstance(q, torch.Tensor):
            out = q
            if wrapped.any():
                ct = torch.as_tensor(np.where(wrapped, c, 0.0), dtype=q.dtype, device=q.device)
                mt = torch.as_tensor(wrapped, device=q.device)
                out = torch.where(mt, ct - math.pi + torch.remainder(q - (ct - math.pi), _TWO_PI), q)
            if not self._mask.all():
                out = out * torch.as_tensor(self._mask, dtype=out.dtype, device=out.device)
            return out
        out = q
        if wrapped.any():
            cc = np.where(wrapped, c, 0.0)
            out = np.where(wrapped, cc - math.pi + np.mod(q - (cc - math.pi), _TWO_PI), q)
        if not self._mask.all():
            out = out * self._mask
        return out

    def _net_in(self, qn, payload_kg=None):
        """Network input: ``qn``, plus the payload column when payload is an input (clamped to the
        trained range: beyond it the networks' payload dependence is held, the physics extrapolates)."""
        if not self.payload_input_:
            return qn
        if payload_kg is None:
            payload_kg = self.robot_.payload_kg if self.payload_default_kg_ is None else self.payload_default_kg_
        return payload_column(qn, payload_kg, self.payload_range_)

    def _to_net_frame(self, q: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Base-frame residual vectors ``(N, 3)`` -> the frame the networks learn in."""
        return v if self.j1_axis_ is None else _rotate_about(self.j1_axis_, -q[:, 0], v)

    def _from_net_frame(self, q, v):
        return v if self.j1_axis_ is None else _rotate_about(self.j1_axis_, q[:, 0], v)

    @property
    def nominal(self) -> Robot:
        """The nominal (uncalibrated) robot the model was built on."""
        return self.robot

    @property
    def calibration(self):
        """The :class:`hykin.calibrate.CalibrationResult` of the last ``fit`` (None after ``load``)."""
        return self.calibration_

    @property
    def metadata(self) -> dict:
        """Training metadata: data hash, sizes, timings, versions, metrics."""
        return self.meta_

    def _framed(self, T: np.ndarray) -> np.ndarray:
        if np.array_equal(self.frame_pre, np.eye(4)) and np.array_equal(self.frame_post, np.eye(4)):
            return T
        return self.frame_pre @ T @ self.frame_post

    # ------------------------------------------------------------------ fitting

    def _targets(self, robot: Robot, ds) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        T_hat = classical_fk(robot, ds.q, **payload_kwargs(payload_of(ds)))
        dp = ds.xyz_m - T_hat[:, :3, 3]
        dr = None
        if ds.has_orientation:
            dr = se3.rotation_difference_rotvec(ds.rotations() if hasattr(ds, "rotations") else ds.poses()[:, :3, :3],
                                                T_hat[:, :3, :3])
        return dp, dr, T_hat

    def fit(self, train, val=None, progress: bool = True) -> HybridModel:
        """Calibrate (unless disabled), then train the residual networks on ``train`` (a Dataset).

        ``val``: validation Dataset for early stopping / best-epoch selection; by default
        ``val_fraction`` of ``train`` is held out (the calibration still uses all of ``train``).
        """
        t0 = time.perf_counter()
        q = np.asarray(train.q, dtype=np.float64)
        n = self.robot.dof
        if q.ndim != 2 or q.shape[1] != n:
            raise HybridError(f"training joints must be (N, {n}), got {q.shape}")
        from ..calibration.plausibility import check_fit_data

        check_fit_data(self.robot, train)  # minimum poses; units and quaternion order vs the robot
        if not (np.isfinite(q).all() and np.isfinite(train.xyz_m).all()):
            raise HybridError("training data contain NaN/inf")
        timings = {}
        train_in, val_in = train, val
        pl_train = payload_of(train)  # DatasetError naming row/column for bad payload values
        self.payload_range_ = None if pl_train is None else payload_range_of(pl_train[0])
        self.payload_input_ = bool(self.payload_input) and pl_train is not None and len(self.payload_range_.values_kg) > 1
        kg_all = np.full(len(q), self.robot.payload_kg) if pl_train is None else pl_train[0]
        if val is not None:
            payload_of(val)
        self._calibrate_on(train)
        self.thermal_ = None
        temp = None if self.thermal is False else temperature_of(train)
        if self.thermal is True and temp is None:
            raise HybridError(f"thermal=True but the training data have no temperature column ({', '.join(TEMPERATURE_COLUMNS)})")
        if temp is not None and np.ptp(temp) > 0:
            train, val = self._fit_thermal(train, val, temp)
        calib = None
        if self.calibration_ is not None:
            try:
                calib = _json_safe(self.calibration_.to_dict())
            except Exception:  # noqa: BLE001 - keep fitting; metadata is informative only
                calib = {"report": str(self.calibration_.report())}
        timings["calibrate_s"] = time.perf_counter() - t0

        dp, dr, T_hat = self._targets(self.robot_, train)
        revolute = np.array([t == "revolute" for t in self.robot.joint_type], dtype=bool)
        self.wrap_centre_ = _seam_centres(q, revolute) if self.periodic == "wrap" else np.full(n, np.nan)
        self.j1_axis_ = None
        if self.joint1 == "frame":
            if not revolute[0]:
                raise HybridError("joint1='frame' needs a revolute joint 1")
            from ..kinematics.chain import chain_of

            ch = chain_of(self.robot_)
            u = (ch.base @ ch.pre[0])[:3, 2]
            self.j1_axis_ = u / np.linalg.norm(u)
            dp = self._to_net_frame(q, dp)
            dr = None if dr is None else self._to_net_frame(q, dr)
        qn = self._netq(q)
        # The validation data are split in two: one half selects the best epoch, the other calibrates
        # the uncertainty bands. Calibrating on the half that picked the epoch would make the bands
        # too narrow: the selected epoch is the one that happens to fit those samples best (virtual
        # in-range coverage 88.5 % instead of 95 % at 30000 steps).
        rng = np.random.default_rng(self.seed)
        iv_cal, val_cal, cal_rows = None, None, None
        if val is None:
            perm = rng.permutation(len(q))
            nv = int(round(self.val_fraction * len(q))) if len(q) >= 20 else 0
            iv, it = perm[:nv], perm[nv:]
            if nv >= 40:
                iv, iv_cal = iv[: nv // 2], iv[nv // 2 :]
            qv, dpv, drv = q[iv], dp[iv], None if dr is None else dr[iv]
            qt, dpt, drt = q[it], dp[it], None if dr is None else dr[it]
            kv, kt = kg_all[iv], kg_all[it]
        else:
            qt, dpt, drt, kt = q, dp, dr, kg_all
            val_sel = val
            if len(val) >= 40:
                pv = rng.permutation(len(val))
                cal_rows = np.sort(pv[len(val) // 2 :])
                val_sel, val_cal = val.subset(np.sort(pv[: len(val) // 2])), val.subset(cal_rows)
            qv = np.asarray(val_sel.q, dtype=np.float64)
            pl_v = payload_of(val_sel)
            kv = np.full(len(qv), self.robot.payload_kg) if pl_v is None else pl_v[0]
            dpv, drv, _ = self._targets(self.robot_, val_sel)  # drv None for position-only val data
            dpv = self._to_net_frame(qv, dpv)
            drv = None if drv is None else self._to_net_frame(qv, drv)
        # Support of the training data in the networks' coordinates (always the data range,
        # whatever the normalisation).
        lo_d, hi_d = qn.min(0), qn.max(0)
        self.support_lower_, self.support_upper_ = lo_d, hi_d
        span = np.maximum(hi_d - lo_d, 1e-6)
        sub = np.random.default_rng(self.seed).permutation(len(q))[:_SUPPORT_POINTS]
        self.support_points_ = (qn[sub] - lo_d) / span
        self._build_support_tree()
        if len(self.support_points_) > 1:
            dd, _ = self._tree.query(self.support_points_, k=2)
            self.support_spacing_ = float(np.percentile(dd[:, 1], 95))
        else:
            self.support_spacing_ = 1.0
        self._build_pair_grids((qn - lo_d) / span)
        if self.normalise == "data":
            lo_n, hi_n = lo_d, hi_d
        else:
            lo_n, hi_n = self._netq(self.robot.lower[None])[0], self._netq(self.robot.upper[None])[0]
            lo_n, hi_n = np.minimum(lo_n, hi_n), np.maximum(lo_n, hi_n)
            full = np.isfinite(self.wrap_centre_) & (self.robot.upper - self.robot.lower >= _TWO_PI - 1e-9)
            lo_n = np.where(full, self.wrap_centre_ - math.pi, lo_n)
            hi_n = np.where(full, self.wrap_centre_ + math.pi, hi_n)
        dt = torch.float64 if self.recipe.dtype == "float64" else torch.float32
        results = {}
        cb_ctx = _Progress(progress)
        with cb_ctx:
            for key, yt, yv in (("pos", dpt, dpv), ("rot", drt, drv)):
                if yt is None:
                    continue
                torch.manual_seed(self.seed + (0 if key == "pos" else 1))
                net = make_net(self.arch, n + int(self.payload_input_), 3, dtype=dt)
                if self.payload_input_:
                    pr = self.payload_range_
                    net.set_input_range(np.r_[lo_n, pr.lower_kg], np.r_[hi_n, pr.upper_kg])
                else:
                    net.set_input_range(lo_n, hi_n)
                t1 = time.perf_counter()
                use_val = len(qv) > 0 and yv is not None
                r = train_net(net, self._net_in(self._netq(qt), kt), yt, self._net_in(self._netq(qv), kv) if use_val else None,
                              yv if use_val else None, self.recipe,
                              seed=self.seed, device=self.device, max_seconds=self.max_seconds,
                              callback=cb_ctx.callback(key))
                timings[f"train_{key}_s"] = time.perf_counter() - t1
                results[key] = r
                setattr(self, f"net_{key}_", net)
        if dr is None:
            self.net_rot_ = None
        timings["fit_s"] = time.perf_counter() - t0
        self.meta_ = {
            "data_hash": _hash(train_in),
            "val_hash": _hash(val_in) if val_in is not None else None,
            "n_train": len(qt), "n_val": len(qv), "n_total": len(q),
            "has_orientation": dr is not None,
            "seed": self.seed, "timings": timings, "versions": _versions(),
            "train_results": {k: {kk: vv for kk, vv in v.to_dict().items() if kk != "history"} | {
                "history": v.history[-50:]} for k, v in results.items()},
            "params": {k: count_parameters(getattr(self, f"net_{k}_")) for k in results},
            "calibration": calib,
            "calibration_cv": None if self.calibration_cv_ is None else _json_safe(self.calibration_cv_.to_dict()),
            "metrics": {},
            "inputs": {"periodic": self.periodic, "joint1": self.joint1},
            "thermal": None if self.thermal_ is None else self.thermal_.to_dict(),
        }
        if val is None:
            rows = iv_cal if iv_cal is not None else iv
            self._fit_uncertainty(train, None, rows)
            raw = train_in.subset(np.asarray(rows)) if len(rows) >= 10 else train_in
        else:
            self._fit_uncertainty(train, val_cal if val_cal is not None else val, None)
            raw = val_in.subset(cal_rows) if cal_rows is not None else val_in
        if self.thermal_ is not None and self.thermal_.coefficient_per_k != 0.0:
            self._fit_uncertainty_without_temperature(raw)
        if self.fade_cv >= 2 and self.fade is not False:  # hykin.fade: fade measured by leave-one-region-out
            from .fade import calibrate_fade

            self.fade_calibration_ = calibrate_fade(self, train, n_blocks=self.fade_cv, seed=self.seed)
            self.fade_offset, self.fade_width = self.fade_calibration_.offset, self.fade_calibration_.width
            self.meta_["fade_calibration"] = _json_safe(self.fade_calibration_.to_dict())
        self.meta_["metrics"]["train"] = self._metrics(train_in, progress_warn=False)
        if val_in is not None:
            self.meta_["metrics"]["val"] = self._metrics(val_in, progress_warn=False)
        elif len(iv):  # the rows held out from network training (the calibration saw them)
            held = np.sort(np.concatenate([iv, iv_cal if iv_cal is not None else iv[:0]]))
            self.meta_["metrics"]["held_out"] = self._metrics(train_in.subset(held), progress_warn=False)
        return self

    def _calibrate_on(self, ds) -> None:
        """Set ``robot_`` (and ``calibration_``) from ``ds``: calibrated, or the nominal robot."""
        if self.calibrate:
            from ..calibration.calibrate import calibrate as _calibrate

            kw = dict(self.calibrate_kw)
            if kw.pop("select", None) == "region-cv":  # parameter set by region-blocked validation (hykin.region_cv)
                from .region_cv import select_calibration

                self.calibration_cv_ = select_calibration(self.robot, ds, base_kw=kw)
                kw.update(self.calibration_cv_.kwargs)
            res = _calibrate(self.robot, ds, **kw)
            self.robot_, self.calibration_ = res.robot, res
        else:
            self.robot_, self.calibration_ = self.robot.copy(), None

    def _fit_thermal(self, train, val, temp: np.ndarray, rounds: int = 3):
        """Identify the expansion coefficient with the calibration (:mod:`hykin.thermal`); returns
        ``(train, val)`` mapped to the reference temperature (unchanged when it is not kept)."""
        ref = float(temp.mean())
        dt = temp - ref
        q = np.asarray(train.q, dtype=np.float64)
        first = (self.robot_, self.calibration_)
        alpha, std = 0.0, float("inf")
        for _ in range(rounds):
            b = self.robot_.base[:3, 3]
            alpha, std = fit_coefficient(train.xyz_m, classical_fk(self.robot_, q, **payload_kwargs(payload_of(train)))[:, :3, 3],
                                         b, dt, alpha)
            if not self.calibrate:
                break
            self._calibrate_on(to_reference(train, b, alpha, dt))
        rng_c = (float(temp.min()), float(temp.max()))
        # size of the effect in the data: alpha x temperature spread x reach (RMS), metres
        reach = float(np.sqrt(np.mean(np.sum((train.xyz_m - self.robot_.base[:3, 3]) ** 2, axis=1))))
        effect_m = abs(alpha) * float(np.std(dt)) * reach
        why = None
        if abs(alpha) < 3.0 * std:
            why = "not significant (|alpha| < 3 std)"
        elif abs(alpha) > MAX_PLAUSIBLE_PER_K:
            why = f"implausible (|alpha| > {MAX_PLAUSIBLE_PER_K:g} /K)"
        elif effect_m < MIN_EFFECT_M:
            why = f"negligible ({effect_m * 1e6:.2g} µm RMS in these data, below {MIN_EFFECT_M * 1e6:g} µm)"
        if why is not None:
            self.robot_, self.calibration_ = first
            self.thermal_ = ThermalFit(0.0, std, ref, rng_c, f"ignored: alpha = {alpha:.3g} +- {std:.2g} /K is {why}")
            return train, val
        self.thermal_ = ThermalFit(alpha, std, ref, rng_c, f"alpha = {alpha:.4g} +- {std:.2g} /K "
                                   f"({effect_m * 1e6:.2g} µm RMS in the training data)")
        b = self.robot_.base[:3, 3]
        train = to_reference(train, b, alpha, dt)
        tv = None if val is None else temperature_of(val)
        if tv is not None:
            val = to_reference(val, b, alpha, tv - ref)
        return train, val

    def _thermal_factor(self, temperature_c, n: int) -> np.ndarray | None:
        """Scale factors ``(n,)`` for queries at ``temperature_c`` (None: no thermal correction)."""
        if temperature_c is None or self.thermal_ is None or self.thermal_.coefficient_per_k == 0.0:
            return None
        t = np.broadcast_to(np.asarray(temperature_c, dtype=np.float64).reshape(-1), (n,))
        if not np.isfinite(t).all():
            raise HybridError(f"temperature_c: non-finite value in row {int(np.argmax(~np.isfinite(t))) + 1}")
        return 1.0 + self.thermal_.coefficient_per_k * (t - self.thermal_.reference_c)

    def _apply_thermal(self, T: np.ndarray, temperature_c) -> np.ndarray:
        f = self._thermal_factor(temperature_c, len(T))
        return T if f is None else scale_about(T, self.robot_.base[:3, 3], f)

    def targets_at_reference(self, T_target, temperature_c):
        """Targets measured at ``temperature_c`` (°C) mapped to the reference temperature, where
        :meth:`predict_torch` (and so hybrid IK) works: exact inverse of the thermal scaling of
        :meth:`predict`. ``T_target`` ``(N, 4, 4)`` poses or ``(N, 3)`` positions (m); returned as
        given when the model has no thermal coefficient or ``temperature_c`` is None. Registration
        frames are honoured; for positions ``frame_post``'s offset is scaled with the arm (an error of
        ``alpha dT |offset|``: 2 µm for a 2 cm offset at 9 K from the reference)."""
        T_target = np.asarray(T_target, dtype=np.float64)
        pos = T_target.shape[-2:] != (4, 4)  # positions (N, 3) / (3,), else poses (N, 4, 4) / (4, 4)
        n = T_target.size // (3 if pos else 16)
        f = self._thermal_factor(temperature_c, n)
        if f is None:
            return T_target
        T = np.tile(np.eye(4), (n, 1, 1)) if pos else T_target.reshape(-1, 4, 4).copy()
        if pos:
            T[:, :3, 3] = T_target.reshape(-1, 3)
        Tm = np.linalg.inv(self.frame_pre) @ T @ (np.eye(4) if pos else np.linalg.inv(self.frame_post))
        Tm = scale_about(Tm, self.robot_.base[:3, 3], 1.0 / f)
        out = self.frame_pre @ Tm @ (np.eye(4) if pos else self.frame_post)
        return out[:, :3, 3].reshape(T_target.shape) if pos else out.reshape(T_target.shape)

    def _metrics(self, ds, progress_warn: bool = True) -> dict:
        """Mean/max position (mm) and orientation (deg) errors of classical and hybrid on ``ds``."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            t = temperature_of(ds)
            pkw = payload_kwargs(payload_of(ds))
            T_c = self.predict_classical(ds.q, temperature_c=t, **pkw)
            T_h = self.predict(ds.q, temperature_c=t, **pkw)
        out = {}
        for name, T in (("classical", T_c), ("hybrid", T_h)):
            pe = np.linalg.norm(T[:, :3, 3] - ds.xyz_m, axis=1) * 1e3
            out[f"{name}_pos_mean_mm"] = float(pe.mean())
            out[f"{name}_pos_max_mm"] = float(pe.max())
            if ds.has_orientation:
                _, ae = se3.pose_error(ds.poses(), T)
                out[f"{name}_rot_mean_deg"] = float(ae.mean())
                out[f"{name}_rot_max_deg"] = float(ae.max())
        return out

    def score(self, ds) -> dict:
        """Error metrics (mm, deg) of the classical and the hybrid prediction on dataset ``ds``."""
        return self._metrics(ds)

    # ------------------------------------------------------------------ uncertainty

    def _predict_unframed(self, q, payload=None) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated and hybrid poses of ``q`` in the training series' frame (no registration
        frames, reference temperature, no range warnings)."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            fr = (self.frame_pre, self.frame_post)
            self.frame_pre, self.frame_post = np.eye(4), np.eye(4)
            try:
                pkw = payload_kwargs(payload)
                return self.predict_classical(q, **pkw), self.predict(q, **pkw)
            finally:
                self.frame_pre, self.frame_post = fr

    def _fit_uncertainty(self, train, val, held_out_index) -> None:
        """Quantiles of the hybrid and classical error norms on held-out samples (split conformal)."""
        if val is not None:
            ds, src = val, "val"
        elif held_out_index is not None and len(held_out_index) >= 10:
            ds, src = train.subset(np.asarray(held_out_index)), "held-out"
        else:
            ds, src = train, "train (in-sample: too few samples to hold out)"
        T_c, T_h = self._predict_unframed(ds.q, payload_of(ds))
        unc = {"levels": _UNC_LEVELS, "n": len(ds), "source": src}
        for name, T in (("classical", T_c), ("hybrid", T_h)):
            pe = np.linalg.norm(T[:, :3, 3] - ds.xyz_m, axis=1) * 1e3
            unc[f"{name}_pos_mm"] = np.quantile(pe, _UNC_LEVELS)
            if ds.has_orientation and self.net_rot_ is not None:
                _, ae = se3.pose_error(ds.poses(), T)
                unc[f"{name}_ang_deg"] = np.quantile(ae, _UNC_LEVELS)
        # how the calibrated model's band widens beyond the trained ranges (emulated extrapolation)
        from .uncertainty import extrapolation_growth

        g = extrapolation_growth(self.robot, train, self._netq(np.asarray(train.q, dtype=np.float64)), self._mask,
                                 _UNC_LEVELS, calibrate_kw=self.calibrate_kw if self.calibrate else None,
                                 with_rot="classical_ang_deg" in unc, seed=self.seed)
        for key in ("pos_mm", "ang_deg"):
            if g[key] is not None:
                unc[f"growth_{key}"], unc[f"step_{key}"] = g[key], g[key + "_step"]
        unc["growth_splits"], unc["growth_points"] = g["n_splits"], g["n_points"]
        self.unc_ = unc

    def _fit_uncertainty_without_temperature(self, ds_raw) -> None:
        """Quantiles for queries without a temperature (model with a thermal coefficient): the
        predictions at the reference temperature against the raw measurements, drift included."""
        T_c, T_h = self._predict_unframed(ds_raw.q, payload_of(ds_raw))
        for name, T in (("classical", T_c), ("hybrid", T_h)):
            pe = np.linalg.norm(T[:, :3, 3] - ds_raw.xyz_m, axis=1) * 1e3
            self.unc_[f"notemp_{name}_pos_mm"] = np.quantile(pe, _UNC_LEVELS)
            if f"{name}_ang_deg" in self.unc_:  # thermal expansion leaves orientations unchanged
                self.unc_[f"notemp_{name}_ang_deg"] = self.unc_[f"{name}_ang_deg"]

    def predict_uncertainty(self, q, level: float = 0.95, temperature_c=None) -> tuple[np.ndarray, np.ndarray | None]:
        """Radii of the ``level`` prediction band per query: ``(pos_mm (N,), ang_deg (N,) or None)``.

        The true position error of :meth:`predict` at ``q`` is below ``pos_mm`` with probability
        ``level`` (likewise orientation, degrees; None for position-only models). Split-conformal:
        validation-error quantiles of the hybrid and the calibrated model, blended by the fade weight
        of :meth:`support_distance` (holes included): inside the training data the hybrid's band,
        outside the calibrated model's, widened with the joint-range excess at the rate measured in
        ``fit`` (module docstring). ``level`` in [0.5, 0.995]. For a model with a thermal coefficient,
        pass the ``temperature_c`` given to :meth:`predict`: without it the bands include the thermal
        drift of the training session (calibrated on the raw held-out measurements).
        """
        self._check_fitted()
        if self.unc_ is None:
            raise HybridError("this model has no uncertainty calibration (saved by an older hykin): refit it")
        if not (0.5 <= level <= 0.995):
            raise HybridError(f"level must be in [0.5, 0.995], got {level}")
        q2, single = self._q(q)
        # support-based whatever the fade mode: without fade, an extrapolating network has no
        # validated band, and the calibrated model's is the best stated guess there
        w = self._fade_of(self.support_distance(q2))
        # the calibrated model extrapolates too: beyond a joint's trained range its band steps up and
        # grows with the excess (in units of that range) as measured in fit (hykin.uncertainty)
        ex = self.range_excess(q2)
        lv = self.unc_["levels"]

        pre = "notemp_" if temperature_c is None and "notemp_hybrid_pos_mm" in self.unc_ else ""

        def band(key):
            if f"hybrid_{key}" not in self.unc_:
                return None
            rh = float(np.interp(level, lv, self.unc_[f"{pre}hybrid_{key}"]))
            rc = float(np.interp(level, lv, self.unc_[f"{pre}classical_{key}"]))
            g = 1.0
            if f"growth_{key}" in self.unc_:
                k, a = (np.array([np.interp(level, lv, c) for c in
                                  np.asarray(self.unc_[f"{name}_{key}"], dtype=np.float64).reshape(len(lv), -1).T])
                        for name in ("growth", "step"))
                g = 1.0 + np.max(np.where(ex > 0, a, 0.0), axis=1) + ex @ k
            r = w * rh + (1 - w) * np.maximum(rc * g, rh)
            return r[0] if single else r

        return band("pos_mm"), band("ang_deg")

    # ------------------------------------------------------------------ support

    def _build_pair_grids(self, x: np.ndarray) -> None:
        """Hole grids: for every pair of network-input joints, the gap (distance from each node of a
        ``G x G`` grid over the normalised training box to the nearest training sample of that 2-D
        projection, minus a tolerance ``max(2 x p95 nearest-neighbour spacing, grid step)``)."""
        from scipy.spatial import cKDTree

        G = _PAIR_GRID
        idx = np.flatnonzero(self._mask & (self.support_upper_ - self.support_lower_ > 1e-9))
        pairs = np.array([(i, j) for a, i in enumerate(idx) for j in idx[a + 1 :]], dtype=np.int64).reshape(-1, 2)
        g = np.linspace(0.0, 1.0, G)
        nodes = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
        gaps = np.zeros((len(pairs), G, G))
        for k, (i, j) in enumerate(pairs):
            pts = np.unique(np.round(x[:, [i, j]], 6), axis=0)
            tree = cKDTree(pts)
            sp = tree.query(pts, k=2)[0][:, 1] if len(pts) > 1 else np.ones(1)
            tol = max(_GAP_FACTOR * float(np.percentile(sp, 95)), 1.0 / (G - 1))
            d = tree.query(nodes)[0]
            gaps[k] = np.maximum(0.0, d - tol).reshape(G, G)
        self.pair_index_, self.pair_gap_ = pairs, gaps

    def pair_gap(self, q):
        """``(N,)`` hole gap of queries ``q`` ``(N, n)`` (numpy) or a float64 tensor (torch, differentiable):
        max over joint pairs of the bilinearly interpolated pairwise gap grid (0 where the training
        data cover every 2-D projection of the query; normalised joint units)."""
        torch_in = isinstance(q, torch.Tensor)
        n_rows = q.shape[0]
        if len(self.pair_index_) == 0:
            return torch.zeros(n_rows, dtype=q.dtype, device=q.device) if torch_in else np.zeros(n_rows)
        if not torch_in:
            return self._pair_gap_qn(self._netq(np.asarray(q, dtype=np.float64)))
        G = self.pair_gap_.shape[1]
        I, J = self.pair_index_[:, 0], self.pair_index_[:, 1]
        span = np.maximum(self.support_upper_ - self.support_lower_, 1e-6)
        qn = self._netq(q)
        lo = torch.as_tensor(self.support_lower_, dtype=q.dtype, device=q.device)
        u = torch.clamp((qn - lo) / torch.as_tensor(span, dtype=q.dtype, device=q.device), 0.0, 1.0) * (G - 1)
        field = torch.as_tensor(self.pair_gap_, dtype=q.dtype, device=q.device).reshape(-1)
        ui, uj = u[:, I], u[:, J]
        i0 = torch.clamp(torch.floor(ui), 0, G - 2)
        j0 = torch.clamp(torch.floor(uj), 0, G - 2)
        fi, fj = ui - i0, uj - j0
        k00 = torch.as_tensor(np.arange(len(I)) * G * G, device=q.device) + i0.long() * G + j0.long()
        v = (field[k00] * (1 - fi) * (1 - fj) + field[k00 + G] * fi * (1 - fj) + field[k00 + 1] * (1 - fi) * fj
             + field[k00 + G + 1] * fi * fj)
        return v.max(1).values

    def _pair_gap_qn(self, qn: np.ndarray) -> np.ndarray:
        """:meth:`pair_gap` (numpy) of queries already in network coordinates ``qn`` ``(N, n)``."""
        n_rows = qn.shape[0]
        if len(self.pair_index_) == 0:
            return np.zeros(n_rows)
        G = self.pair_gap_.shape[1]
        I, J = self.pair_index_[:, 0], self.pair_index_[:, 1]
        span = np.maximum(self.support_upper_ - self.support_lower_, 1e-6)
        if HAVE_NUMBA:
            out = np.empty(n_rows)
            _pair_gap_kernel(np.ascontiguousarray(qn, dtype=np.float64), np.ascontiguousarray(self.support_lower_),
                             np.ascontiguousarray(span), np.ascontiguousarray(self.pair_gap_, dtype=np.float64),
                             np.ascontiguousarray(I), np.ascontiguousarray(J), out)
            return out
        u = np.clip((qn - self.support_lower_) / span, 0.0, 1.0) * (G - 1)
        field = self.pair_gap_.reshape(-1)
        ui, uj = u[:, I], u[:, J]
        i0 = np.clip(np.floor(ui), 0, G - 2)
        j0 = np.clip(np.floor(uj), 0, G - 2)
        fi, fj = ui - i0, uj - j0
        k00 = np.arange(len(I)) * G * G + i0.astype(np.int64) * G + j0.astype(np.int64)
        v = (field[k00] * (1 - fi) * (1 - fj) + field[k00 + G] * fi * (1 - fj) + field[k00 + 1] * (1 - fi) * fj
             + field[k00 + G + 1] * fi * fj)
        return v.max(1)

    def _nn_gap_torch(self, x):
        """Nearest-neighbour gap of :meth:`support_distance` for normalised queries ``x`` (tensor
        ``(N, n)``), differentiable; ``|x|^2 + |p|^2 - 2 x.p`` in row chunks (exportable to ONNX)."""
        pts = torch.as_tensor(self.support_points_, dtype=x.dtype, device=x.device)
        p2 = (pts * pts).sum(1)
        out = []
        for i in range(0, x.shape[0], 2048):
            xi = x[i : i + 2048]
            d2 = (xi * xi).sum(1, keepdim=True) + p2[None, :] - 2.0 * xi @ pts.T
            out.append(torch.sqrt(torch.clamp(d2.min(1).values, min=1e-24)))  # finite gradient at 0
        nn = torch.cat(out) if out else x.new_zeros(0)
        return torch.clamp(nn - _GAP_FACTOR * self.support_spacing_, min=0.0)

    def _build_support_tree(self) -> None:
        from scipy.spatial import cKDTree

        self._tree = cKDTree(self.support_points_)

    def _check_fitted(self) -> None:
        if self.robot_ is None or self.net_pos_ is None:
            raise HybridError("HybridModel is not fitted: call fit() or HybridModel.load()")

    def _q(self, q) -> tuple[np.ndarray, bool]:
        q = np.asarray(q, dtype=np.float64)
        single = q.ndim == 1
        q2 = q.reshape(1, -1) if single else q
        n = self.robot.dof
        if q2.ndim != 2 or q2.shape[1] != n:
            raise HybridError(f"joints must have shape (N, {n}) or ({n},), got {q.shape}")
        if not np.isfinite(q2).all():
            row = int(np.argwhere(~np.isfinite(q2))[0, 0])
            raise HybridError(f"joints contain NaN/inf (row {row})")
        return np.ascontiguousarray(q2), single

    def range_excess(self, q) -> np.ndarray:
        """``(N, n)`` per-joint excess beyond the trained ``[min, max]``, in units of that range (0 inside).

        In the networks' coordinates: wrapped revolute joints (``periodic="wrap"``); the column of
        ``q1`` is 0 with ``joint1="frame"`` (not a network input)."""
        self._check_fitted()
        return self._range_excess_qn(self._netq(self._q(q)[0]))

    def _range_excess_qn(self, qn: np.ndarray) -> np.ndarray:
        """:meth:`range_excess` of queries already in network coordinates ``qn`` ``(N, n)``."""
        span = np.maximum(self.support_upper_ - self.support_lower_, 1e-6)
        return np.maximum(0.0, np.maximum(self.support_lower_ - qn, qn - self.support_upper_)) / span

    def support_distance(self, q) -> np.ndarray:
        """``(N,)`` distance outside the training data in units of the trained joint range (0 inside):
        ``max(max_j range_excess_j, gap)``, gap = nearest-training-sample distance in normalised joint
        space beyond ``2 ×`` the training set's 95th-percentile nearest-neighbour spacing."""
        self._check_fitted()
        q2, _ = self._q(q)
        ex = self.range_excess(q2).max(1)
        span = np.maximum(self.support_upper_ - self.support_lower_, 1e-6)
        nn, _ = self._tree.query((self._netq(q2) - self.support_lower_) / span, k=1, workers=-1)
        gap = np.maximum(0.0, nn - _GAP_FACTOR * self.support_spacing_)
        return np.maximum(np.maximum(ex, gap), self.pair_gap(q2))

    def fade_weight(self, q) -> np.ndarray:
        """``(N,)`` weight in [0, 1] applied to the network correction (module docstring)."""
        q2, _ = self._q(q)
        if self.fade is False:
            return np.ones(len(q2))
        return self._fade_of(self._fade_distance(q2))

    def _fade_of(self, d: np.ndarray) -> np.ndarray:
        """Fade weight for support distances ``d``: 1 up to ``fade_offset``, 0 beyond a further ``fade_width``
        (the torch path in :meth:`predict_torch` mirrors it)."""
        return _fade_np(d - self.fade_offset, self.fade_width)

    def _fade_distance(self, q2: np.ndarray, ex: np.ndarray | None = None) -> np.ndarray:
        ex = self.range_excess(q2) if ex is None else ex
        if self.fade == "full":
            return self.support_distance(q2)
        if self.fade == "range":
            return ex.max(1)
        return np.maximum(ex.max(1), self.pair_gap(q2))

    # ------------------------------------------------------------------ prediction

    def predict_classical(self, q, temperature_c=None, payload_kg=None, payload_com_m=None) -> np.ndarray:
        """Calibrated classical poses ``(N, 4, 4)`` (or ``(4, 4)`` for one ``(n,)`` query).
        ``temperature_c``, ``payload_kg``, ``payload_com_m``: as in :meth:`predict`."""
        self._check_fitted()
        q2, single = self._q(q)
        T = self._framed(self._apply_thermal(classical_fk(self.robot_, q2, payload_kg, payload_com_m), temperature_c))
        return T[0] if single else T

    @torch.inference_mode()
    def _net_np(self, net: ResidualNet, q2: np.ndarray) -> np.ndarray:
        dev = next(net.parameters()).device
        x = torch.from_numpy(q2).to(dev)
        out = np.empty((len(q2), 3))
        B = 16384
        for i in range(0, len(q2), B):
            out[i : i + B] = net(x[i : i + B]).to(torch.float64).cpu().numpy()
        return out

    def predict(self, q, temperature_c=None, payload_kg=None, payload_com_m=None) -> np.ndarray:
        """Hybrid poses ``(N, 4, 4)`` float64 (``(4, 4)`` for one ``(n,)`` query), world frame, m.

        ``temperature_c``: arm temperature (°C, scalar or ``(N,)``) for a model that identified thermal
        expansion (``thermal_``, :mod:`hykin.thermal`); ``None`` gives the poses at the training
        reference temperature (also for models without a thermal coefficient, which ignore it).
        Warns once (:class:`OutOfRangeWarning`) with counts when queries leave the trained joint range
        or fall in holes of the training data (pairwise hole grids).
        ``payload_kg`` (scalar or ``(N,)`` kg) / ``payload_com_m`` (``(3,)`` or ``(N, 3)`` m, tool frame):
        the payload carried (default: the robot file's); the calibrated compliance model deflects
        the joints under it, the networks are payload-agnostic (module docstring, "Payload").
        """
        self._check_fitted()
        q2, single = self._q(q)
        T = classical_fk(self.robot_, q2, payload_kg, payload_com_m)
        qn = self._netq(q2)
        ex = self._range_excess_qn(qn)
        exm = ex.max(1)
        gap = self._pair_gap_qn(qn)
        out_rows = exm > 0
        holes = (gap > 0) & ~out_rows
        if out_rows.any() or holes.any():
            tail = "the correction fades to the calibrated model there" if self.fade else \
                "network corrections there are extrapolations"
            if out_rows.any():
                per = ", ".join(f"q{j + 1}: {int(c)}" for j, c in enumerate((ex > 0).sum(0)) if c)
                msg = f"{int(out_rows.sum())} of {len(q2)} queries are outside the joint range the networks were trained on ({per})"
                if holes.any():
                    msg += f"; {int(holes.sum())} more lie in holes of the training data"
            else:
                msg = f"{int(holes.sum())} of {len(q2)} queries lie in holes of the training data (inside its joint range)"
            warnings.warn(f"{msg}; {tail}", OutOfRangeWarning, stacklevel=2)
        if payload_kg is not None and self.payload_range_ is not None:
            out_pl = payload_outside(self.payload_range_, payload_kg)
            if out_pl.any():
                r = self.payload_range_
                warnings.warn(f"{int(out_pl.sum())} of {out_pl.size} payloads lie outside the trained payloads "
                              f"[{r.lower_kg:g}, {r.upper_kg:g}] kg; the calibrated compliance model carries the "
                              "payload there (network payload dependence held at the nearest trained payload)",
                              OutOfRangeWarning, stacklevel=2)
        if self.fade is False:
            w = None
        else:
            d = exm if self.fade == "range" else (self.support_distance(q2) if self.fade == "full" else np.maximum(exm, gap))
            w = self._fade_of(d)
            if np.all(w == 1.0):
                w = None
        qin = self._net_in(qn, payload_kg)
        dp = self._from_net_frame(q2, self._net_np(self.net_pos_, qin))
        if w is not None:
            dp *= w[:, None]
        T[:, :3, 3] += dp
        if self.net_rot_ is not None:
            dr = self._from_net_frame(q2, self._net_np(self.net_rot_, qin))
            if w is not None:
                dr *= w[:, None]
            if HAVE_NUMBA and T.flags.c_contiguous:
                _rotate_poses_kernel(np.ascontiguousarray(dr), T)
            else:
                T[:, :3, :3] = _rodrigues(dr) @ T[:, :3, :3]
        T = self._framed(self._apply_thermal(T, temperature_c))
        return T[0] if single else T

    def predict_torch(self, q, payload_kg=None, payload_com_m=None):
        """Differentiable hybrid poses: float64 tensor ``(N, n)`` -> ``(N, 4, 4)`` (autograd w.r.t. q).

        Same numbers as :meth:`predict` (range excess, pairwise hole gap and nearest-neighbour gap are
        piecewise smooth in q; the last, for ``fade="full"``, by brute force over the support points)."""
        self._check_fitted()
        if q.ndim != 2 or q.shape[1] != self.robot.dof:
            raise HybridError(f"joints must have shape (N, {self.robot.dof}), got {tuple(q.shape)}")
        q = q.to(torch.float64)
        T_hat = classical_fk_torch(self.robot_, q, payload_kg, payload_com_m)
        dev = next(self.net_pos_.parameters()).device
        qn = self._netq(q)
        qd = self._net_in(qn, payload_kg).to(dev)
        w = None
        if self.fade is not False:
            lo = torch.as_tensor(self.support_lower_, dtype=torch.float64, device=q.device)
            hi = torch.as_tensor(self.support_upper_, dtype=torch.float64, device=q.device)
            span = torch.clamp(hi - lo, min=1e-6)
            ex = torch.clamp(torch.maximum(lo - qn, qn - hi), min=0.0) / span
            dist = ex.max(1).values
            if self.fade not in ("range",):
                dist = torch.maximum(dist, self.pair_gap(q))
            if self.fade == "full":
                dist = torch.maximum(dist, self._nn_gap_torch((qn - lo) / span))
            t = torch.clamp((dist - self.fade_offset) / self.fade_width, 0.0, 1.0)
            w = (0.5 * (1 + torch.cos(math.pi * t)))[:, None]
        dp = self._from_net_frame(q, self.net_pos_(qd).to(device=q.device, dtype=torch.float64))
        if w is not None:
            dp = dp * w
        p = T_hat[:, :3, 3] + dp
        R = T_hat[:, :3, :3]
        if self.net_rot_ is not None:
            dr = self._from_net_frame(q, self.net_rot_(qd).to(device=q.device, dtype=torch.float64))
            if w is not None:
                dr = dr * w
            R = se3.so3_exp_torch(dr) @ R
        bottom = T_hat[:, 3:4, :]
        top = torch.cat([R, p[:, :, None]], dim=2)
        T = torch.cat([top, bottom], dim=1)
        if not (np.array_equal(self.frame_pre, np.eye(4)) and np.array_equal(self.frame_post, np.eye(4))):
            pre = torch.as_tensor(self.frame_pre, dtype=T.dtype, device=T.device)
            post = torch.as_tensor(self.frame_post, dtype=T.dtype, device=T.device)
            T = pre @ T @ post
        return T

    # ------------------------------------------------------------------ files

    def config(self) -> dict:
        return {"arch": self.arch, "recipe": self.recipe.to_dict(), "calibrate": self.calibrate,
                "calibrate_kw": _json_safe(self.calibrate_kw), "normalise": self.normalise, "fade": self.fade,
                "fade_width": self.fade_width, "device": self.device, "seed": self.seed,
                "max_seconds": self.max_seconds, "val_fraction": self.val_fraction, "periodic": self.periodic,
                "joint1": self.joint1, "input_joints": list(self.input_joints), "thermal": self.thermal,
                "payload_input": self.payload_input, "fade_offset": self.fade_offset, "fade_cv": self.fade_cv}

    def save(self, path: str | Path) -> None:
        """Write the model to ONE safetensors file (no pickle); see :mod:`hykin.modelfile`."""
        self._check_fitted()
        tensors = {f"pos.{k}": v for k, v in self.net_pos_.state_dict().items()}
        if self.net_rot_ is not None:
            tensors.update({f"rot.{k}": v for k, v in self.net_rot_.state_dict().items()})
        tensors["support.points"] = torch.from_numpy(np.ascontiguousarray(self.support_points_))
        tensors["support.pair_gap"] = torch.from_numpy(np.ascontiguousarray(self.pair_gap_, dtype=np.float64))
        tensors["support.pair_index"] = torch.from_numpy(np.ascontiguousarray(self.pair_index_, dtype=np.int64))
        meta = {
            "robot": robot_to_dict(self.robot_),
            "robot_nominal": robot_to_dict(self.robot),
            "robot_toml": robot_to_toml_string(self.robot_) if self.robot_.convention in ("dh", "mdh") else None,
            "config": self.config(),
            "support": {"lower": self.support_lower_.tolist(), "upper": self.support_upper_.tolist(),
                        "spacing": self.support_spacing_, "gap_factor": _GAP_FACTOR},
            "has_rot_net": self.net_rot_ is not None,
            "frames": {"pre": self.frame_pre.tolist(), "post": self.frame_post.tolist()},
            "inputs": {"wrap_centre": _json_safe(self.wrap_centre_),
                       "j1_axis": None if self.j1_axis_ is None else self.j1_axis_.tolist()},
            "uncertainty": _json_safe(self.unc_),
            "thermal": None if self.thermal_ is None else _json_safe(self.thermal_.to_dict()),
            "payload": None if self.payload_range_ is None else {"range": self.payload_range_.to_dict(),
                                                                 "input": bool(self.payload_input_)},
            "training": _json_safe(self.meta_),
        }
        write_model_file(path, tensors, meta)

    @classmethod
    def load(cls, path: str | Path, device: str = "cpu") -> HybridModel:
        """Read a model written by :meth:`save`. :class:`hykin.modelfile.ModelFileError` if it is not one."""
        tensors, meta = read_model_file(path)
        try:
            cfg = meta["config"]
            nominal = robot_from_json_dict(meta["robot_nominal"], f"{path}: robot_nominal")
            m = cls(nominal, arch=cfg["arch"], recipe=Recipe(**cfg["recipe"]), calibrate=cfg["calibrate"],
                    calibrate_kw=cfg.get("calibrate_kw"), normalise=cfg["normalise"], fade=cfg["fade"],
                    fade_width=cfg["fade_width"], device=device, seed=cfg["seed"], max_seconds=cfg.get("max_seconds"),
                    val_fraction=cfg.get("val_fraction"), periodic=cfg.get("periodic", "none"),
                    joint1=cfg.get("joint1", "input"), input_joints=cfg.get("input_joints"),
                    thermal=cfg.get("thermal", "auto"), payload_input=cfg.get("payload_input", False))
            m.robot_ = robot_from_json_dict(meta["robot"], f"{path}: robot")
            pl = meta.get("payload")  # absent in files before per-row payloads: behave as then
            if pl is not None:
                m.payload_range_ = PayloadRange.from_dict(pl["range"])
                m.payload_input_ = bool(pl.get("input", False))
            dt = torch.float64 if m.recipe.dtype == "float64" else torch.float32
            for key in ("pos", "rot") if meta["has_rot_net"] else ("pos",):
                net = make_net(m.arch, nominal.dof + int(m.payload_input_), 3, dtype=dt)
                sd = {k[len(key) + 1 :]: v for k, v in tensors.items() if k.startswith(key + ".")}
                net.load_state_dict(sd, strict=True)
                net.to(device).eval()
                setattr(m, f"net_{key}_", net)
            sup = meta["support"]
            m.support_lower_ = np.array(sup["lower"], dtype=np.float64)
            m.support_upper_ = np.array(sup["upper"], dtype=np.float64)
            m.support_spacing_ = float(sup["spacing"])
            m.support_points_ = tensors["support.points"].numpy().astype(np.float64)
            m._build_support_tree()
            if "support.pair_gap" in tensors:
                m.pair_gap_ = tensors["support.pair_gap"].numpy().astype(np.float64)
                m.pair_index_ = tensors["support.pair_index"].numpy().astype(np.int64).reshape(-1, 2)
            m.meta_ = meta.get("training", {})
            inp = meta.get("inputs") or {}
            if inp.get("wrap_centre") is not None:
                m.wrap_centre_ = np.array([np.nan if isinstance(v, str) else v for v in inp["wrap_centre"]], dtype=np.float64)
            if inp.get("j1_axis") is not None:
                m.j1_axis_ = np.array(inp["j1_axis"], dtype=np.float64)
            unc = meta.get("uncertainty")
            if unc is not None:
                m.unc_ = {k: (np.array(v, dtype=np.float64) if isinstance(v, list) else v) for k, v in unc.items()}
            m.fade_offset = float(cfg.get("fade_offset", 0.0))
            m.fade_cv = int(cfg.get("fade_cv", 0))
            th = meta.get("thermal")
            if th is not None:
                m.thermal_ = ThermalFit(float(th["coefficient_per_k"]), float(th["std_per_k"]), float(th["reference_c"]),
                                        tuple(float(v) for v in th["range_c"]), str(th["note"]))
            fr = meta.get("frames")
            if fr is not None:
                m.frame_pre = np.array(fr["pre"], dtype=np.float64).reshape(4, 4)
                m.frame_post = np.array(fr["post"], dtype=np.float64).reshape(4, 4)
        except ModelFileError:
            raise
        except (KeyError, TypeError, ValueError, RuntimeError) as e:
            raise ModelFileError(f"{path}: corrupt hykin model ({type(e).__name__}: {e})") from None
        return m


class _Progress:
    """Optional rich progress bar over training epochs."""

    def __init__(self, enabled: bool):
        self.enabled = enabled
        self.prog = None

    def __enter__(self):
        if self.enabled:
            try:
                from rich.progress import (
                    BarColumn,
                    Progress,
                    TextColumn,
                    TimeElapsedColumn,
                )

                self.prog = Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                                     TextColumn("{task.fields[info]}"), TimeElapsedColumn(), transient=True)
                self.prog.__enter__()
            except ImportError:  # pragma: no cover
                self.prog = None
        return self

    def __exit__(self, *exc):
        if self.prog is not None:
            self.prog.__exit__(*exc)

    def callback(self, key: str):
        if self.prog is None:
            return None
        unit, f = ("mm", 1e3) if key == "pos" else ("deg", 180 / math.pi)
        task = self.prog.add_task(f"training {key} net", total=None, info="")

        def cb(epoch, total, train_loss, val_loss):
            self.prog.update(task, completed=epoch, total=total,
                             info=f"train {train_loss * f:.4g} {unit}  val {val_loss * f:.4g} {unit}")

        return cb
