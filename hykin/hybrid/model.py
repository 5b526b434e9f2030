"""Hybrid forward kinematics: calibrated classical model + residual networks (DESIGN.md §1.1).

``T*(q)``: ``p* = p̂(q) + w(q) Δp(q)``, ``R* = exp(w(q) Δr(q)) · R̂(q)``, where ``T̂`` is the
calibrated classical model (geometry + joint compliance), ``Δp``/``Δr`` the position and orientation
networks (base frame) and ``w`` the support fade (below). When the training data carry a temperature
column, ``T̂`` also expands with temperature (one linear coefficient identified with the calibration,
:mod:`hykin.calibration.thermal`): ``predict(q, temperature_c=...)``; the networks learn at the reference
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

Training-region awareness (networks do not extrapolate): :meth:`HybridModel.range_excess`,
:meth:`HybridModel.pair_gap`, :meth:`HybridModel.support_distance` and the fade of the correction
(``fade``, ``fade_width``, ``fade_offset``, ``fade_cv``) are described, with their measurements, in
:mod:`hykin.hybrid.support`; far outside the training data the hybrid equals the calibrated model.

Payload (:mod:`hykin.io.payload`). Training data may carry a ``payload_kg`` column (and
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
robot (rx160-nongeo): 0.0279 / 0.0279 / 0.0280 / 0.0280 mm with payload as input vs 0.0282 / 0.0278
/ 0.0276 / 0.0276 mm agnostic (equal within seed noise: no harm where physics leaves no payload dependence). With one payload the networks stay payload-agnostic and the physics
carries every other payload. ``predict`` warns (:class:`OutOfRangeWarning`) for payloads outside
the trained ones. Not payload-aware yet: :meth:`predict_uncertainty` (bands of the trained
payloads) and the extrapolation growth of :mod:`hykin.hybrid.uncertainty` (robot file's payload).

Uncertainty (:meth:`HybridModel.predict_uncertainty`): split-conformal bands that widen to the
calibrated model's outside the training data (:mod:`hykin.hybrid.bands`, measured coverage there).
"""

from __future__ import annotations

import math
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from ..calibration.thermal import TEMPERATURE_COLUMNS, temperature_of
from ..geometry import se3
from ..io.modelfile import ModelFileError, read_model_file, robot_from_json_dict
from ..io.payload import payload_kwargs, payload_of, payload_range_of
from ..io.robot_file import load_robot
from ..kinematics.classical import classical_fk, classical_fk_torch
from ..kinematics.robot import Robot
from . import bands, fast_fk, fast_nets, fitting, inputs, persistence, stations, support as sup_
from .errors import HybridError, OutOfRangeWarning
from .optional import optional_step
from .progress import Progress
from .rotations import rotate_poses
from .settings import check_settings, empty_fitted_state
from .support import Support, support_report
from .thermal_fit import apply_thermal, fit_thermal, targets_at_reference, warn_station_temperatures
from .train import Recipe, get_recipe
from .uncertainty import fit_bands

__all__ = ["HybridError", "HybridModel", "OutOfRangeWarning", "classical_fk", "classical_fk_torch", "support_report"]


class HybridModel:
    """Calibrated classical model + residual networks (scikit-learn contract: the constructor stores
    the settings, ``fit`` validates them, learns the ``*_`` attributes and returns self, ``predict`` is
    pure).

    robot: nominal robot (Robot, preset name or file; stored as the loaded :class:`Robot`, the one
    conversion the constructor does, so that ``model.robot`` is always a Robot). arch: network name
    (:mod:`hykin.hybrid.nets`). recipe: training recipe name or :class:`hykin.hybrid.train.Recipe`;
    recipe_kw: overrides of recipe fields (e.g. ``{"max_epochs": 50}``); fitted: ``recipe_``.
    calibrate: run :func:`hykin.calibration.calibrate.calibrate` first (``calibrate_kw`` passed on; with
    ``{"select": "region-cv"}`` the parameter set is chosen by region-blocked validation,
    :func:`hykin.hybrid.region_cv.select_calibration`, result in ``calibration_cv_``).
    normalise: ``"data"`` (min-max over the training joints) or ``"full"`` (joint limits).
    fade: True (= "support": joint ranges and pairwise holes), "range", "full" or False (module
    docstring); fade_width in units of the range; fade_offset: support distance up to which the
    correction is fully applied. fade_cv: number of regions (>= 2) for a fade measured by
    leave-one-region-out at the end of fit (:mod:`hykin.hybrid.fade`; sets the fitted fade_offset_ and fade_width_; 0 = off).
    periodic: "wrap" (revolute joints on the circle) or "none"; joint1: "input" or "frame";
    input_joints: 1-based joints the networks see (default all; module docstring, "Input representation").
    device: "cpu" or "cuda". seed: training seed. max_seconds: training time budget for the networks together.
    val_fraction: share of the training set held out for validation when ``fit`` gets no ``val``
    (default the recipe's).
    thermal: identify a linear thermal expansion coefficient from the training data's temperature
    column (:mod:`hykin.calibration.thermal`): ``"auto"`` (when there is one; kept only if significant and
    plausible), True (required), False (ignore temperatures). Fitted: ``thermal_``.
    payload_input: "auto"/True: payload is a network input when the training data hold several
    payloads (``payload_kg`` column); False: payload-agnostic networks. Fitted: ``payload_range_``
    (None without a payload column), ``payload_input_`` (module docstring, "Payload").
    ``frame_pre_``/``frame_post_`` ``(4, 4)``: fitted rigid frames around the model, set by
    :func:`hykin.measure.register.register_model` on its copy for a new measurement series (pose =
    frame_pre · T_model(q) · frame_post; identity for the series the model was trained on).
    uncertainty: fit the prediction bands of :meth:`predict_uncertainty` (default True). False skips
    that step of ``fit`` (held-out error quantiles and the extrapolation growth, which recalibrates on
    parts of the data: often the costliest step after training) for models whose bands are never used,
    e.g. the fits of a learning curve; :meth:`predict_uncertainty` then refuses.
    """

    def __init__(self, robot, arch: str = "default", recipe: str | Recipe = "default", calibrate: bool = True,
                 calibrate_kw: dict | None = None, normalise: str = "data", fade: bool | str = True,
                 fade_width: float = 0.1, device: str = "cpu", seed: int = 0, max_seconds: float | None = None,
                 val_fraction: float | None = None, recipe_kw: dict | None = None, periodic: str = "wrap",
                 joint1: str = "input", input_joints=None, thermal: bool | str = "auto",
                 payload_input: bool | str = "auto", fade_cv: int = 0, fade_offset: float = 0.0,
                 uncertainty: bool = True):
        self.robot = load_robot(robot)
        self.arch = arch
        self.recipe = recipe
        self.recipe_kw = recipe_kw
        self.calibrate = calibrate
        self.calibrate_kw = calibrate_kw
        self.normalise = normalise
        self.fade = fade
        self.fade_width = fade_width
        self.fade_offset = fade_offset
        self.fade_cv = fade_cv
        self.device = device
        self.seed = seed
        self.max_seconds = max_seconds
        self.val_fraction = val_fraction
        self.periodic = periodic
        self.joint1 = joint1
        self.input_joints = input_joints
        self.thermal = thermal
        self.payload_input = payload_input
        self.uncertainty = uncertainty

    # ------------------------------------------------------------------ settings

    def resolved_recipe(self) -> Recipe:
        """The training recipe: ``recipe`` with the ``recipe_kw`` overrides (ValueError if unknown)."""
        return get_recipe(self.recipe, **(self.recipe_kw or {}))

    def resolved_val_fraction(self) -> float:
        """``val_fraction``, or the recipe's when None."""
        return self.resolved_recipe().val_fraction if self.val_fraction is None else float(self.val_fraction)

    def resolved_input_joints(self) -> tuple[int, ...]:
        """``input_joints`` as a tuple of 1-based joints (all joints when None)."""
        n = self.robot.dof
        ij = self.input_joints
        return tuple(range(1, n + 1)) if ij is None else tuple(int(j) for j in ij)

    def _prepare(self) -> None:
        """Validate the settings (:func:`hykin.hybrid.settings.check_settings`), derive ``recipe_`` and
        ``input_mask_`` and empty the fitted state (start of ``fit`` and ``load``)."""
        ij = check_settings(self)
        self.recipe_ = self.resolved_recipe()
        self.input_mask_ = np.array([(j + 1) in ij and not (j == 0 and self.joint1 == "frame")
                                     for j in range(self.robot.dof)])
        self.__dict__.update(empty_fitted_state(self.robot.dof))
        # The fade in use: the settings, unless fit measures it (fade_cv) or registration turns it off.
        self.fade_offset_, self.fade_width_ = float(self.fade_offset), float(self.fade_width)

    # ------------------------------------------------------------------ input representation

    def _netq(self, q):
        """Joints as the networks see them (numpy or torch ``(N, n)``; :func:`hykin.hybrid.inputs.net_coordinates`)."""
        return inputs.net_coordinates(q, self.wrap_centre_, self.input_mask_)

    def _net_in(self, qn, payload_kg=None):
        """Network input of ``qn``: the payload column appended when payload is an input."""
        if self.payload_input_ and payload_kg is None:
            payload_kg = self.robot_.payload_kg if self.payload_default_kg_ is None else self.payload_default_kg_
        return inputs.net_input(qn, self.payload_input_, payload_kg, self.payload_range_)

    @property
    def support(self) -> Support:
        """The fitted support of the networks (:class:`hykin.hybrid.support.Support`, a view of
        ``support_lower_``, ``support_upper_``, ``support_points_``, ``support_spacing_``,
        ``pair_index_``, ``pair_gap_``)."""
        if getattr(self, "_tree", None) is None or self._tree_points is not self.support_points_:
            self._tree, self._tree_points = sup_.support_tree(self.support_points_), self.support_points_
        return Support(self.support_lower_, self.support_upper_, self.support_points_, self.support_spacing_,
                       self._tree, self.pair_index_, self.pair_gap_)

    @property
    def nominal(self) -> Robot:
        """The nominal (uncalibrated) robot the model was built on."""
        return self.robot

    @property
    def calibration(self):
        """The :class:`hykin.calibration.result.CalibrationResult` of the last ``fit`` (None after ``load``)."""
        return getattr(self, "calibration_", None)

    @property
    def metadata(self) -> dict:
        """Training metadata: data hash, sizes, timings, versions, metrics."""
        return getattr(self, "meta_", {})

    def _framed(self, T: np.ndarray) -> np.ndarray:
        if np.array_equal(self.frame_pre_, np.eye(4)) and np.array_equal(self.frame_post_, np.eye(4)):
            return T
        return self.frame_pre_ @ T @ self.frame_post_

    # ------------------------------------------------------------------ fitting

    def fit(self, train, val=None, progress: bool = True) -> HybridModel:
        """Calibrate (unless disabled), then train the residual networks on ``train`` (a Dataset).

        ``val``: validation Dataset for early stopping / best-epoch selection; by default
        ``val_fraction`` of ``train`` is held out (the calibration still uses all of ``train``).
        A path (str / Path) is read as ``hykin fit`` reads it (m, rad; :func:`fitting.as_dataset`).
        Validates the settings first (:class:`HybridError`). Returns self.
        """
        train, val = fitting.as_dataset(train, self.robot, "train"), fitting.as_dataset(val, self.robot, "val")
        self._prepare()
        t0 = time.perf_counter()
        q = np.asarray(train.q, dtype=np.float64)
        n = self.robot.dof
        if q.ndim != 2 or q.shape[1] != n:
            raise HybridError(f"training joints must be (N, {n}), got {q.shape}")
        from ..io.plausibility import check_fit_data

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
        self._skipped = {}  # optional steps that failed (hykin.hybrid.optional): name -> cause
        self._calibrate_on(train, progress=progress)
        train, q, kg_all = fitting.without_outliers(self.calibration_, train, q, kg_all)
        train_in = raw = train
        self.station_frames_ = stations.fit_station_frames(self, train)  # several stations: data in one frame
        train_in, val_in = train, val = tuple(stations.in_model_frame(self, d) for d in (train, val))
        temp = None if self.thermal is False else temperature_of(train)
        if self.thermal is True and temp is None:
            raise HybridError(f"thermal=True but the training data have no temperature column ({', '.join(TEMPERATURE_COLUMNS)})")
        if temp is not None and np.ptp(temp) > 0:
            first = (self.robot_, self.calibration_)
            args = (train, val, temp, self.robot_, self.calibration_, self._calibrate_on if self.calibrate else None)
            tol_k = ((self.calibrate_kw or {}).get("priors") or {}).get("thermal_per_k")
            got = fit_thermal(*args, tolerance_per_k=tol_k) if self.thermal is True else optional_step(
                "thermal expansion", self._skipped, fit_thermal, *args, tolerance_per_k=tol_k)
            if got is None:  # failed (auto): the calibration at the measured temperatures
                self.robot_, self.calibration_ = first
            else:
                self.robot_, self.calibration_, self.thermal_, train, val = got
                warn_station_temperatures(self.thermal_, raw, temp)
        calib = None
        if self.calibration_ is not None:
            try:
                calib = persistence.json_safe(self.calibration_.to_dict())
            except Exception:  # noqa: BLE001 - keep fitting; metadata is informative only
                calib = {"report": str(self.calibration_.report())}
        timings["calibrate_s"] = time.perf_counter() - t0

        dp, dr, _ = fitting.residual_targets(self.robot_, train)
        revolute = self.robot.revolute
        self.wrap_centre_ = inputs.seam_centres(q, revolute) if self.periodic == "wrap" else np.full(n, np.nan)
        if self.joint1 == "frame":
            if not revolute[0]:
                raise HybridError("joint1='frame' needs a revolute joint 1")
            from ..kinematics.chain import chain_of

            ch = chain_of(self.robot_)
            u = (ch.base @ ch.pre[0])[:3, 2]
            self.j1_axis_ = u / np.linalg.norm(u)
            dp = inputs.to_net_frame(self.j1_axis_, q, dp)
            dr = None if dr is None else inputs.to_net_frame(self.j1_axis_, q, dr)
        qn = self._netq(q)
        sp = fitting.split_validation(q, dp, dr, kg_all, val, robot=self.robot_, seed=int(self.seed),
                              val_fraction=self.resolved_val_fraction(), j1_axis=self.j1_axis_)
        # Support of the training data in the networks' coordinates (always the data range,
        # whatever the normalisation).
        s = sup_.fit_support(qn, self.input_mask_, int(self.seed))
        self.support_lower_, self.support_upper_ = s.lower, s.upper
        self.support_points_, self.support_spacing_ = s.points, s.spacing
        self.pair_index_, self.pair_gap_ = s.pair_index, s.pair_gap
        self._tree, self._tree_points = s.tree, s.points
        lo_n, hi_n = fitting.input_range(self.normalise, s.lower, s.upper, self.robot, self._netq, self.wrap_centre_)
        if self.payload_input_:
            lo_n, hi_n = np.r_[lo_n, self.payload_range_.lower_kg], np.r_[hi_n, self.payload_range_.upper_kg]
        qt, qv = sp["qt"], sp["qv"]
        nets, results, t_train = fitting.train_networks(
            {"pos": (sp["dpt"], sp["dpv"]), "rot": (sp["drt"], sp["drv"])}, self._net_in(self._netq(qt), sp["kt"]),
            self._net_in(self._netq(qv), sp["kv"]) if len(qv) > 0 else None, arch=self.arch,
            n_in=n + int(self.payload_input_), in_lower=lo_n, in_upper=hi_n, recipe=self.recipe_, seed=int(self.seed),
            device=self.device, max_seconds=self.max_seconds, progress=progress)
        self.net_pos_, self.net_rot_ = nets["pos"], nets.get("rot")
        timings.update(t_train)
        timings["fit_s"] = time.perf_counter() - t0
        self.meta_ = fitting.training_metadata(self, train_in, val_in, n_split=(len(qt), len(qv), len(q)),
                                       has_orientation=dr is not None, timings=timings, results=results, calib=calib)
        iv, iv_cal, val_cal, cal_rows = sp["iv"], sp["iv_cal"], sp["val_cal"], sp["cal_rows"]
        # optional from here on (hykin.hybrid.optional): a failure warns once and keeps the model
        if self.uncertainty:  # the prediction bands of predict_uncertainty (False: not fitted, e.g. learning curves)
            bands_stage = Progress(progress).stage("prediction bands (held-out errors, extrapolation growth)")
            if val is None:
                rows = iv_cal if iv_cal is not None else iv
                raw = train_in.subset(np.asarray(rows)) if len(rows) >= 10 else train_in
                self.unc_ = optional_step("uncertainty bands", self._skipped, fit_bands, self, train, None, rows, raw,
                                          self._skipped)
            else:
                raw = val_in.subset(cal_rows) if cal_rows is not None else val_in
                self.unc_ = optional_step("uncertainty bands", self._skipped, fit_bands, self, train,
                                          val_cal if val_cal is not None else val, None, raw, self._skipped)
            bands_stage.done()
        if int(self.fade_cv) >= 2 and self.fade is not False:  # hykin.hybrid.fade: fade measured by leave-one-region-out
            from .fade import calibrate_fade

            fc = optional_step("fade calibration", self._skipped, calibrate_fade, self, train, n_blocks=int(self.fade_cv),
                               seed=int(self.seed))
            if fc is not None:
                self.fade_calibration_ = fc
                self.fade_offset_, self.fade_width_ = fc.offset, fc.width
                self.meta_["fade_calibration"] = persistence.json_safe(fc.to_dict())
        if self._skipped:
            self.meta_["optional_steps_failed"] = dict(self._skipped)
        held = None if val_in is not None else np.sort(np.concatenate([iv, iv_cal if iv_cal is not None else iv[:0]]))
        self.meta_["metrics"]["train"] = fitting.train_metrics(self, train_in, held, val_in)  # and rows far off the model
        if val_in is not None or len(held):  # rows the networks were not trained on (the calibration saw held-out ones)
            name, ds = ("val", val_in) if val_in is not None else ("held_out", train_in.subset(held))
            self.meta_["metrics"][name] = fitting.held_out_metrics(self, ds, name)
        return self

    def _calibrate_on(self, ds, progress: bool = False) -> tuple[Robot, object]:
        """Set (and return) ``robot_`` and ``calibration_`` from ``ds`` (:func:`fitting.calibrate_on`)."""
        return fitting.calibrate_on(self, ds, progress)

    def targets_at_reference(self, T_target, temperature_c):
        """Targets measured at ``temperature_c`` (°C) mapped to the reference temperature, where
        :meth:`predict_torch` (and so hybrid IK) works: exact inverse of the thermal scaling of
        :meth:`predict`. ``T_target`` ``(N, 4, 4)`` poses or ``(N, 3)`` positions (m); returned as
        given when the model has no thermal coefficient or ``temperature_c`` is None. Registration
        frames are honoured; for positions ``frame_post``'s offset is scaled with the arm (an error of
        ``alpha dT |offset|``: 2 µm for a 2 cm offset at 9 K from the reference)."""
        return targets_at_reference(T_target, temperature_c, self.thermal_, self.robot_.base[:3, 3],
                                    self.frame_pre_, self.frame_post_)

    def _metrics(self, ds) -> dict:
        """Mean/max position (mm) and orientation (deg) errors of classical and hybrid on ``ds``."""
        return fitting.error_metrics(ds, *fitting.predictions(self, ds))

    def score(self, ds) -> dict:
        """Error metrics (mm, deg) of the classical and the hybrid prediction on dataset ``ds``."""
        return self._metrics(ds)

    # ------------------------------------------------------------------ uncertainty

    def _predict_unframed(self, q, payload=None) -> tuple[np.ndarray, np.ndarray]:
        """Calibrated and hybrid poses ``(N, 4, 4)`` of ``q`` in the training series' frame (no
        registration frames, reference temperature, no range warnings); ``payload``: :func:`payload_of`."""
        self._check_fitted()
        q2, _ = self._q(q)
        pkw = payload_kwargs(payload)
        return classical_fk(self.robot_, q2, **pkw), self._hybrid_poses(q2, warn=False, **pkw)

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
            why = (self.metadata.get("optional_steps_failed") or {}).get("uncertainty bands")
            raise HybridError("this model has no uncertainty bands (" + (
                "fitted with uncertainty=False" if not self.uncertainty else f"fit skipped them: {why}" if why else
                "saved by an older hykin") + "): refit it")
        if not (0.5 <= level <= 0.995):
            raise HybridError(f"level must be in [0.5, 0.995], got {level}")
        q2, single = self._q(q)
        s, qn = self.support, self._netq(q2)
        ex = sup_.range_excess(s, qn)
        # support-based whatever the fade mode: without fade, an extrapolating network has no
        # validated band, and the calibrated model's is the best stated guess there
        w = sup_.fade_weight(sup_.support_distance(s, qn, ex), self.fade_offset_, self.fade_width_)
        # the calibrated model extrapolates too: beyond a joint's trained range its band steps up and
        # grows with the excess (in units of that range) as measured in fit (hykin.hybrid.uncertainty)
        pos, ang = bands.band_radii(self.unc_, level, w, ex, temperature_c is not None)
        return tuple(None if r is None else (r[0] if single else r) for r in (pos, ang))

    # ------------------------------------------------------------------ support

    def pair_gap(self, q):
        """``(N,)`` hole gap of queries ``q`` ``(N, n)`` (numpy) or a float64 tensor (torch, differentiable):
        max over joint pairs of the bilinearly interpolated pairwise gap grid (0 where the training
        data cover every 2-D projection of the query; normalised joint units)."""
        if isinstance(q, torch.Tensor):
            return sup_.pair_gap_torch(self.support, self._netq(q))
        return sup_.pair_gap(self.support, self._netq(np.asarray(q, dtype=np.float64)))

    def _check_fitted(self) -> None:
        if getattr(self, "robot_", None) is None or getattr(self, "net_pos_", None) is None:
            raise HybridError("HybridModel is not fitted: call fit() or HybridModel.load()")

    def _q(self, q) -> tuple[np.ndarray, bool]:
        q = np.asarray(q, dtype=np.float64)
        single = q.ndim == 1
        q2 = q.reshape(1, -1) if single else q
        n = self.robot.dof
        if q2.ndim != 2 or q2.shape[1] != n:
            raise HybridError(f"joints must have shape (N, {n}) or ({n},), got {q.shape}")
        # a few values: checked in Python (numpy's isfinite + all costs ~2 µs of a ~30 µs one-pose query)
        finite = all(map(math.isfinite, q2.ravel().tolist())) if q2.size <= 64 else bool(np.isfinite(q2).all())
        if not finite:
            row = int(np.argwhere(~np.isfinite(q2))[0, 0])
            raise HybridError(f"joints contain NaN/inf (row {row})")
        return np.ascontiguousarray(q2), single

    def range_excess(self, q) -> np.ndarray:
        """``(N, n)`` per-joint excess beyond the trained ``[min, max]``, in units of that range (0 inside).

        In the networks' coordinates: wrapped revolute joints (``periodic="wrap"``); the column of
        ``q1`` is 0 with ``joint1="frame"`` (not a network input)."""
        self._check_fitted()
        return sup_.range_excess(self.support, self._netq(self._q(q)[0]))

    def support_distance(self, q) -> np.ndarray:
        """``(N,)`` distance outside the training data in units of the trained joint range (0 inside):
        ``max(max_j range_excess_j, gap, pair_gap)``, gap = nearest-training-sample distance in normalised
        joint space beyond ``2 ×`` the training set's 95th-percentile nearest-neighbour spacing."""
        self._check_fitted()
        return sup_.support_distance(self.support, self._netq(self._q(q)[0]))

    def fade_distance(self, q, mode=None) -> np.ndarray:
        """``(N,)`` the support distance fade ``mode`` (default ``self.fade``) uses: ``"range"`` range
        excess, ``"full"`` :meth:`support_distance`, otherwise range excess and pairwise holes."""
        self._check_fitted()
        return sup_.fade_distance(self.support, self._netq(self._q(q)[0]), self.fade if mode is None else mode)

    def fade_weight(self, q) -> np.ndarray:
        """``(N,)`` weight in [0, 1] applied to the network correction (module docstring)."""
        q2, _ = self._q(q)
        if self.fade is False:
            return np.ones(len(q2))
        return sup_.fade_weight(self.fade_distance(q2), self.fade_offset_, self.fade_width_)

    # ------------------------------------------------------------------ prediction

    def predict_classical(self, q, temperature_c=None, payload_kg=None, payload_com_m=None) -> np.ndarray:
        """Calibrated classical poses ``(N, 4, 4)`` (or ``(4, 4)`` for one ``(n,)`` query).
        ``temperature_c``, ``payload_kg``, ``payload_com_m``: as in :meth:`predict`."""
        self._check_fitted()
        q2, single = self._q(q)
        T = classical_fk(self.robot_, q2, payload_kg, payload_com_m)
        T = self._framed(apply_thermal(T, self.thermal_, self.robot_.base[:3, 3], temperature_c))
        return T[0] if single else T

    def predict(self, q, temperature_c=None, payload_kg=None, payload_com_m=None) -> np.ndarray:
        """Hybrid poses ``(N, 4, 4)`` float64 (``(4, 4)`` for one ``(n,)`` query), world frame, m.

        ``temperature_c``: arm temperature (°C, scalar or ``(N,)``) for a model that identified thermal
        expansion (``thermal_``, :mod:`hykin.calibration.thermal`); ``None`` gives the poses at the training
        reference temperature (also for models without a thermal coefficient, which ignore it).
        Warns once (:class:`OutOfRangeWarning`) with counts when queries leave the trained joint range
        or fall in holes of the training data (pairwise hole grids).
        ``payload_kg`` (scalar or ``(N,)`` kg) / ``payload_com_m`` (``(3,)`` or ``(N, 3)`` m, tool frame):
        the payload carried (default: the robot file's); the calibrated compliance model deflects
        the joints under it, the networks are payload-agnostic (module docstring, "Payload").
        """
        self._check_fitted()
        q2, single = self._q(q)
        fr = temperature_c is None or self.thermal_ is None  # no thermal scaling: frame the poses at once
        T = self._hybrid_poses(q2, payload_kg, payload_com_m, warn=True, framed=fr)
        T = T if fr else self._framed(apply_thermal(T, self.thermal_, self.robot_.base[:3, 3], temperature_c))
        return T[0] if single else T

    def _hybrid_poses(self, q2: np.ndarray, payload_kg=None, payload_com_m=None, warn: bool = True,
                      framed: bool = False) -> np.ndarray:
        """Hybrid poses ``(N, 4, 4)`` of checked joints ``q2`` ``(N, n)`` at the reference temperature, with
        the registration frames when ``framed``; ``warn``: :class:`OutOfRangeWarning` for queries outside.
        Small batches run compiled (:mod:`hykin.hybrid.fast_fk`) unless a payload is given; large ones BLAS."""
        kern = fast_fk.kernel_of(self) if payload_kg is None is payload_com_m else None
        if kern is not None and len(q2) < fast_fk.COMPILED_MAX:
            T, ex, gap, outside = fast_fk.predict_fast(kern, q2, framed)
            if warn and outside:
                sup_.warn_outside(ex, gap, bool(self.fade), self.payload_range_, payload_kg, stacklevel=3,
                                  circular=sup_.circular_joints(self.robot_, self.wrap_centre_), sup=self.support)
            return T
        T = classical_fk(self.robot_, q2, payload_kg, payload_com_m)
        if kern is not None:  # the networks' input, support and fade in one compiled pass
            qin, ex, gap, w = fast_fk.prepare(kern, q2)
        else:
            s, qn = self.support, self._netq(q2)
            ex, gap = sup_.range_excess(s, qn), sup_.pair_gap(s, qn)
            w = None if self.fade is False else sup_.fade_weight(sup_.fade_distance(s, qn, self.fade, ex, gap),
                                                                 self.fade_offset_, self.fade_width_)
            qin = self._net_in(qn, payload_kg)
        if warn:
            sup_.warn_outside(ex, gap, bool(self.fade), self.payload_range_, payload_kg, stacklevel=3,
                              circular=sup_.circular_joints(self.robot_, self.wrap_centre_), sup=self.support)
        w = None if w is None or np.all(w == 1.0) else w
        nets = [fast_nets.cached(self, n).fast for n in (self.net_pos_, self.net_rot_) if n is not None]
        res = fast_nets.evaluate(nets, qin)  # both nets in one pass: shared features, one thread dispatch
        dp = inputs.from_net_frame(self.j1_axis_, q2, res[0])
        if w is not None:
            dp *= w[:, None]
        T[:, :3, 3] += dp
        if self.net_rot_ is not None:
            dr = inputs.from_net_frame(self.j1_axis_, q2, res[1])
            if w is not None:
                dr *= w[:, None]
            rotate_poses(dr, T)
        return self._framed(T) if framed else T

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
            w = sup_.fade_weight(sup_.fade_distance_torch(self.support, qn, self.fade), self.fade_offset_,
                                 self.fade_width_)[:, None]
        net_p, net_r = (None if n is None else fast_nets.torch64(self, n) for n in (self.net_pos_, self.net_rot_))
        dp = inputs.from_net_frame(self.j1_axis_, q, net_p(qd).to(device=q.device, dtype=torch.float64))
        if w is not None:
            dp = dp * w
        p = T_hat[:, :3, 3] + dp
        R = T_hat[:, :3, :3]
        if self.net_rot_ is not None:
            dr = inputs.from_net_frame(self.j1_axis_, q, net_r(qd).to(device=q.device, dtype=torch.float64))
            if w is not None:
                dr = dr * w
            R = se3.so3_exp_torch(dr) @ R
        bottom = T_hat[:, 3:4, :]
        top = torch.cat([R, p[:, :, None]], dim=2)
        T = torch.cat([top, bottom], dim=1)
        if not (np.array_equal(self.frame_pre_, np.eye(4)) and np.array_equal(self.frame_post_, np.eye(4))):
            pre = torch.as_tensor(self.frame_pre_, dtype=T.dtype, device=T.device)
            post = torch.as_tensor(self.frame_post_, dtype=T.dtype, device=T.device)
            T = pre @ T @ post
        return T

    # ------------------------------------------------------------------ files

    def config(self) -> dict:
        """The settings as saved in the model file (:func:`hykin.hybrid.persistence.model_config`)."""
        return persistence.model_config(self)

    def save(self, path: str | Path) -> None:
        """Write the model to ONE safetensors file (no pickle); see :mod:`hykin.hybrid.persistence`."""
        self._check_fitted()
        persistence.save_model(self, path)

    @classmethod
    def load(cls, path: str | Path, device: str = "cpu") -> HybridModel:
        """Read a model written by :meth:`save`. :class:`hykin.io.modelfile.ModelFileError` if it is not one."""
        tensors, meta = read_model_file(path)
        try:
            nominal = robot_from_json_dict(meta["robot_nominal"], f"{path}: robot_nominal")
            m = cls(nominal, **persistence.settings_from_config(meta["config"], device))
            m._prepare()
            persistence.restore_fitted(m, tensors, meta, path, device)
        except ModelFileError:
            raise
        except (KeyError, TypeError, ValueError, RuntimeError) as e:
            raise ModelFileError(f"{path}: corrupt hykin model ({type(e).__name__}: {e})") from None
        return m
