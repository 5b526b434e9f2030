"""Hybrid forward kinematics: calibrated classical model + residual networks (DESIGN.md §1.1).

``T*(q)``: ``p* = p̂(q) + w(q) Δp(q)``, ``R* = exp(w(q) Δr(q)) · R̂(q)``, where ``T̂`` is the
calibrated classical model (geometry + joint compliance), ``Δp``/``Δr`` the position and orientation
networks (base frame) and ``w`` the support fade (below).

Training-region awareness (networks do not extrapolate):

* :meth:`HybridModel.support_distance` — how far outside the training data a query is, in units of
  the trained joint range: ``max(range_excess, gap)`` with ``range_excess = max_j`` (excess of
  ``q_j`` beyond the trained ``[min_j, max_j]``) / (max_j − min_j), and ``gap`` = distance to the
  nearest training sample in min-max normalised joint space (cKDTree on ≤ 4000 training samples)
  beyond ``2 ×`` the 95th percentile of the training samples' own nearest-neighbour spacing.
* :meth:`HybridModel.predict` warns once per call (:class:`OutOfRangeWarning`, with counts per
  joint) when queries leave the trained joint range.
* Fade (``fade=True``, default): the network correction is multiplied by
  ``w = 1`` for ``d <= 0``, ``w = (1 + cos(π d / fade_width)) / 2`` for ``0 < d < fade_width``,
  ``w = 0`` beyond, with ``d`` the per-joint ``range_excess`` (cheap, keeps predict fast) and
  ``fade_width = 0.1`` (10 % of the trained range). Far outside, the hybrid equals the calibrated
  classical model exactly. ``fade="full"`` uses the full :meth:`support_distance` (adds the
  nearest-neighbour gap; ~10x slower predict), ``fade=False`` never fades.
"""

from __future__ import annotations

import hashlib
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from . import se3
from .fk import fk, fk_torch
from .modelfile import ModelFileError, read_model_file, robot_from_json_dict, robot_to_dict, write_model_file
from .nets import ResidualNet, count_parameters, make_net
from .robot import Robot, load_robot, robot_to_toml_string
from .train import Recipe, get_recipe, train_net

__all__ = ["HybridModel", "OutOfRangeWarning", "HybridError", "classical_fk", "classical_fk_torch"]

_SUPPORT_POINTS = 4000
_GAP_FACTOR = 2.0


class HybridError(ValueError):
    """Bad input to a hybrid model (shape, NaN, unfitted model...)."""


class OutOfRangeWarning(UserWarning):
    """Queries outside the joint range the networks were trained on."""


def classical_fk(robot: Robot, q: np.ndarray) -> np.ndarray:
    """Classical prediction ``(N, 4, 4)``: FK of the (calibrated) robot, with joint compliance when
    the robot has finite stiffness."""
    if robot.has_compliance:
        from .compliance import compliant_fk

        return compliant_fk(robot, q)
    return fk(robot, q)


def classical_fk_torch(robot: Robot, q):
    """Differentiable twin of :func:`classical_fk` (float64 tensor ``(N, n)`` -> ``(N, 4, 4)``)."""
    if robot.has_compliance:
        from .compliance import compliant_fk_torch

        return compliant_fk_torch(robot, q)
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
        from .dataset import dataset_hash

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
    calibrate: run :func:`hykin.calibrate.calibrate` first (``calibrate_kw`` passed on).
    normalise: ``"data"`` (min-max over the training joints) or ``"full"`` (joint limits).
    fade: True / "range", "full" or False (module docstring); fade_width in units of the range.
    device: "cpu" or "cuda". seed: training seed. max_seconds: training time budget per network.
    val_fraction: share of the training set held out for validation when ``fit`` gets no ``val``.
    recipe_kw: overrides of recipe fields (e.g. ``{"max_epochs": 50}``).
    """

    def __init__(self, robot, arch: str = "default", recipe: str | Recipe = "default", calibrate: bool = True,
                 calibrate_kw: dict | None = None, normalise: str = "data", fade: bool | str = True,
                 fade_width: float = 0.1, device: str = "cpu", seed: int = 0, max_seconds: float | None = None,
                 val_fraction: float | None = None, recipe_kw: dict | None = None):
        self.robot = load_robot(robot)
        self.arch = arch
        self.recipe = get_recipe(recipe, **(recipe_kw or {}))
        self.calibrate = bool(calibrate)
        self.calibrate_kw = dict(calibrate_kw or {})
        if normalise not in ("data", "full"):
            raise HybridError(f"normalise must be 'data' or 'full', got {normalise!r}")
        self.normalise = normalise
        if fade not in (True, False, "range", "full"):
            raise HybridError(f"fade must be True, False, 'range' or 'full', got {fade!r}")
        self.fade = fade
        if not (fade_width > 0):
            raise HybridError(f"fade_width must be > 0, got {fade_width}")
        self.fade_width = float(fade_width)
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
        # Rigid frames around the model, set by hykin.register for a new measurement series:
        # pose = frame_pre · T_model(q) · frame_post (identity for the series the model was trained on).
        self.frame_pre = np.eye(4)
        self.frame_post = np.eye(4)

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
        T_hat = classical_fk(robot, ds.q)
        dp = ds.xyz_m - T_hat[:, :3, 3]
        dr = None
        if ds.has_orientation:
            dr = se3.rotation_difference_rotvec(ds.rotations() if hasattr(ds, "rotations") else ds.poses()[:, :3, :3],
                                                T_hat[:, :3, :3])
        return dp, dr, T_hat

    def fit(self, train, val=None, progress: bool = True) -> "HybridModel":
        """Calibrate (unless disabled), then train the residual networks on ``train`` (a Dataset).

        ``val``: validation Dataset for early stopping / best-epoch selection; by default
        ``val_fraction`` of ``train`` is held out (the calibration still uses all of ``train``).
        """
        t0 = time.perf_counter()
        q = np.asarray(train.q, dtype=np.float64)
        n = self.robot.dof
        if q.ndim != 2 or q.shape[1] != n:
            raise HybridError(f"training joints must be (N, {n}), got {q.shape}")
        if len(q) < 2:
            raise HybridError("training set needs at least 2 samples")
        if not (np.isfinite(q).all() and np.isfinite(train.xyz_m).all()):
            raise HybridError("training data contain NaN/inf")
        timings = {}
        calib = None
        if self.calibrate:
            from .calibrate import calibrate as _calibrate

            res = _calibrate(self.robot, train, **self.calibrate_kw)
            self.robot_ = res.robot
            self.calibration_ = res
            try:
                calib = _json_safe(res.to_dict())
            except Exception:  # noqa: BLE001 - keep fitting; metadata is informative only
                calib = {"report": str(res.report())}
        else:
            self.robot_ = self.robot.copy()
        timings["calibrate_s"] = time.perf_counter() - t0

        dp, dr, T_hat = self._targets(self.robot_, train)
        if val is None:
            rng = np.random.default_rng(self.seed)
            perm = rng.permutation(len(q))
            nv = int(round(self.val_fraction * len(q))) if len(q) >= 20 else 0
            iv, it = perm[:nv], perm[nv:]
            qv, dpv, drv = q[iv], dp[iv], None if dr is None else dr[iv]
            qt, dpt, drt = q[it], dp[it], None if dr is None else dr[it]
        else:
            qt, dpt, drt = q, dp, dr
            qv = np.asarray(val.q, dtype=np.float64)
            dpv, drv, _ = self._targets(self.robot_, val)  # drv None for position-only val data
        # Support of the training data (always the data range, whatever the normalisation).
        lo_d, hi_d = q.min(0), q.max(0)
        self.support_lower_, self.support_upper_ = lo_d, hi_d
        span = np.maximum(hi_d - lo_d, 1e-6)
        sub = np.random.default_rng(self.seed).permutation(len(q))[:_SUPPORT_POINTS]
        self.support_points_ = (q[sub] - lo_d) / span
        self._build_support_tree()
        if len(self.support_points_) > 1:
            dd, _ = self._tree.query(self.support_points_, k=2)
            self.support_spacing_ = float(np.percentile(dd[:, 1], 95))
        else:
            self.support_spacing_ = 1.0
        if self.normalise == "data":
            lo_n, hi_n = lo_d, hi_d
        else:
            lo_n, hi_n = self.robot.lower, self.robot.upper
        dt = torch.float64 if self.recipe.dtype == "float64" else torch.float32
        results = {}
        cb_ctx = _Progress(progress)
        with cb_ctx:
            for key, yt, yv in (("pos", dpt, dpv), ("rot", drt, drv)):
                if yt is None:
                    continue
                torch.manual_seed(self.seed + (0 if key == "pos" else 1))
                net = make_net(self.arch, n, 3, dtype=dt)
                net.set_input_range(lo_n, hi_n)
                t1 = time.perf_counter()
                use_val = len(qv) > 0 and yv is not None
                r = train_net(net, qt, yt, qv if use_val else None, yv if use_val else None, self.recipe,
                              seed=self.seed, device=self.device, max_seconds=self.max_seconds,
                              callback=cb_ctx.callback(key))
                timings[f"train_{key}_s"] = time.perf_counter() - t1
                results[key] = r
                setattr(self, f"net_{key}_", net)
        if dr is None:
            self.net_rot_ = None
        timings["fit_s"] = time.perf_counter() - t0
        self.meta_ = {
            "data_hash": _hash(train),
            "val_hash": _hash(val) if val is not None else None,
            "n_train": int(len(qt)), "n_val": int(len(qv)), "n_total": int(len(q)),
            "has_orientation": dr is not None,
            "seed": self.seed, "timings": timings, "versions": _versions(),
            "train_results": {k: {kk: vv for kk, vv in v.to_dict().items() if kk != "history"} | {
                "history": v.history[-50:]} for k, v in results.items()},
            "params": {k: count_parameters(getattr(self, f"net_{k}_")) for k in results},
            "calibration": calib,
            "metrics": {},
        }
        self.meta_["metrics"]["train"] = self._metrics(train, progress_warn=False)
        if val is not None:
            self.meta_["metrics"]["val"] = self._metrics(val, progress_warn=False)
        return self

    def _metrics(self, ds, progress_warn: bool = True) -> dict:
        """Mean/max position (mm) and orientation (deg) errors of classical and hybrid on ``ds``."""
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            T_c = self.predict_classical(ds.q)
            T_h = self.predict(ds.q)
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

    # ------------------------------------------------------------------ support

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
        """``(N, n)`` per-joint excess beyond the trained ``[min, max]``, in units of that range (0 inside)."""
        self._check_fitted()
        q2, _ = self._q(q)
        span = np.maximum(self.support_upper_ - self.support_lower_, 1e-6)
        return np.maximum(0.0, np.maximum(self.support_lower_ - q2, q2 - self.support_upper_)) / span

    def support_distance(self, q) -> np.ndarray:
        """``(N,)`` distance outside the training data in units of the trained joint range (0 inside):
        ``max(max_j range_excess_j, gap)``, gap = nearest-training-sample distance in normalised joint
        space beyond ``2 ×`` the training set's 95th-percentile nearest-neighbour spacing."""
        self._check_fitted()
        q2, _ = self._q(q)
        ex = self.range_excess(q2).max(1)
        span = np.maximum(self.support_upper_ - self.support_lower_, 1e-6)
        nn, _ = self._tree.query((q2 - self.support_lower_) / span, k=1, workers=-1)
        gap = np.maximum(0.0, nn - _GAP_FACTOR * self.support_spacing_)
        return np.maximum(ex, gap)

    def fade_weight(self, q) -> np.ndarray:
        """``(N,)`` weight in [0, 1] applied to the network correction (module docstring)."""
        q2, _ = self._q(q)
        if self.fade is False:
            return np.ones(len(q2))
        d = self.support_distance(q2) if self.fade == "full" else self.range_excess(q2).max(1)
        return _fade_np(d, self.fade_width)

    # ------------------------------------------------------------------ prediction

    def predict_classical(self, q) -> np.ndarray:
        """Calibrated classical poses ``(N, 4, 4)`` (or ``(4, 4)`` for one ``(n,)`` query)."""
        self._check_fitted()
        q2, single = self._q(q)
        T = classical_fk(self.robot_, q2)
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

    def predict(self, q) -> np.ndarray:
        """Hybrid poses ``(N, 4, 4)`` float64 (``(4, 4)`` for one ``(n,)`` query), world frame, m.

        Warns once (:class:`OutOfRangeWarning`) with counts when queries leave the trained joint range.
        """
        self._check_fitted()
        q2, single = self._q(q)
        T = classical_fk(self.robot_, q2)
        ex = self.range_excess(q2)
        out_rows = ex.max(1) > 0
        if out_rows.any():
            per = ", ".join(f"q{j + 1}: {int(c)}" for j, c in enumerate((ex > 0).sum(0)) if c)
            warnings.warn(
                f"{int(out_rows.sum())} of {len(q2)} queries are outside the joint range the networks were "
                f"trained on ({per}); " + ("the correction fades to the calibrated model there" if self.fade else
                                          "network corrections there are extrapolations"),
                OutOfRangeWarning, stacklevel=2)
        if self.fade is False:
            w = None
        elif self.fade == "full":
            w = _fade_np(self.support_distance(q2), self.fade_width)
        else:
            w = _fade_np(ex.max(1), self.fade_width) if out_rows.any() else None
        dp = self._net_np(self.net_pos_, q2)
        if w is not None:
            dp *= w[:, None]
        T[:, :3, 3] += dp
        if self.net_rot_ is not None:
            dr = self._net_np(self.net_rot_, q2)
            if w is not None:
                dr *= w[:, None]
            T[:, :3, :3] = _rodrigues(dr) @ T[:, :3, :3]
        T = self._framed(T)
        return T[0] if single else T

    def predict_torch(self, q):
        """Differentiable hybrid poses: float64 tensor ``(N, n)`` -> ``(N, 4, 4)`` (autograd w.r.t. q).

        Same numbers as :meth:`predict` (the ``"range"`` fade is applied smoothly; ``fade="full"``
        is treated as ``"range"`` here, the nearest-neighbour gap not being differentiable)."""
        self._check_fitted()
        if q.ndim != 2 or q.shape[1] != self.robot.dof:
            raise HybridError(f"joints must have shape (N, {self.robot.dof}), got {tuple(q.shape)}")
        q = q.to(torch.float64)
        T_hat = classical_fk_torch(self.robot_, q)
        dev = next(self.net_pos_.parameters()).device
        qd = q.to(dev)
        w = None
        if self.fade is not False:
            lo = torch.as_tensor(self.support_lower_, dtype=torch.float64, device=q.device)
            hi = torch.as_tensor(self.support_upper_, dtype=torch.float64, device=q.device)
            span = torch.clamp(hi - lo, min=1e-6)
            ex = torch.clamp(torch.maximum(lo - q, q - hi), min=0.0) / span
            t = torch.clamp(ex.max(1).values / self.fade_width, 0.0, 1.0)
            w = (0.5 * (1 + torch.cos(math.pi * t)))[:, None]
        dp = self.net_pos_(qd).to(device=q.device, dtype=torch.float64)
        if w is not None:
            dp = dp * w
        p = T_hat[:, :3, 3] + dp
        R = T_hat[:, :3, :3]
        if self.net_rot_ is not None:
            dr = self.net_rot_(qd).to(device=q.device, dtype=torch.float64)
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
                "max_seconds": self.max_seconds, "val_fraction": self.val_fraction}

    def save(self, path: str | Path) -> None:
        """Write the model to ONE safetensors file (no pickle); see :mod:`hykin.modelfile`."""
        self._check_fitted()
        tensors = {f"pos.{k}": v for k, v in self.net_pos_.state_dict().items()}
        if self.net_rot_ is not None:
            tensors.update({f"rot.{k}": v for k, v in self.net_rot_.state_dict().items()})
        tensors["support.points"] = torch.from_numpy(np.ascontiguousarray(self.support_points_))
        meta = {
            "robot": robot_to_dict(self.robot_),
            "robot_nominal": robot_to_dict(self.robot),
            "robot_toml": robot_to_toml_string(self.robot_) if self.robot_.convention in ("dh", "mdh") else None,
            "config": self.config(),
            "support": {"lower": self.support_lower_.tolist(), "upper": self.support_upper_.tolist(),
                        "spacing": self.support_spacing_, "gap_factor": _GAP_FACTOR},
            "has_rot_net": self.net_rot_ is not None,
            "frames": {"pre": self.frame_pre.tolist(), "post": self.frame_post.tolist()},
            "training": _json_safe(self.meta_),
        }
        write_model_file(path, tensors, meta)

    @classmethod
    def load(cls, path: str | Path, device: str = "cpu") -> "HybridModel":
        """Read a model written by :meth:`save`. :class:`hykin.modelfile.ModelFileError` if it is not one."""
        tensors, meta = read_model_file(path)
        try:
            cfg = meta["config"]
            nominal = robot_from_json_dict(meta["robot_nominal"], f"{path}: robot_nominal")
            m = cls(nominal, arch=cfg["arch"], recipe=Recipe(**cfg["recipe"]), calibrate=cfg["calibrate"],
                    calibrate_kw=cfg.get("calibrate_kw"), normalise=cfg["normalise"], fade=cfg["fade"],
                    fade_width=cfg["fade_width"], device=device, seed=cfg["seed"], max_seconds=cfg.get("max_seconds"),
                    val_fraction=cfg.get("val_fraction"))
            m.robot_ = robot_from_json_dict(meta["robot"], f"{path}: robot")
            dt = torch.float64 if m.recipe.dtype == "float64" else torch.float32
            for key in ("pos", "rot") if meta["has_rot_net"] else ("pos",):
                net = make_net(m.arch, nominal.dof, 3, dtype=dt)
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
            m.meta_ = meta.get("training", {})
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
                from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

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
