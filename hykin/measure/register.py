"""Registration of a new measurement series to an existing hybrid model.

When the tracker is moved or the tool is changed, the robot's own error model (calibrated joints,
compliance, residual networks) stays valid; only the rigid frames around it change. A new series
is registered by fitting two rigid transforms, ``T_meas ≈ B · T_model(q) · E`` (B: measurement
frame -> old world frame, E: old TCP -> new TCP), from a few of its poses, without retraining.
Where the poses identify them and they are significant, :func:`register_model` also re-fits what a
new day changes inside the arm: joint zero offsets (an encoder re-referenced, a joint zero drifted)
and a thermal state (a uniform length scale); the choice is made from the data (QR of the
registration Jacobian, then backward elimination by leave-one-pose-out error and t-statistics) and
reported with standard deviations (:meth:`RegistrationInfo.report`). A registration whose residual
is inconsistent with the measurement noise and the model's uncertainty at those poses (a chi-square
test, :mod:`hykin.measure.register_checks`) is refused (:class:`RegistrationError`): the series does
not fit the model; where the nominal robot with frames fitted on the same poses predicts them better
(leave-one-pose-out), the registration falls back to it. A robot file without a model registers
through :class:`hykin.measure.robot_model.RobotModel`. On a virtual robot measured on two days (tracker moved, tool re-mounted by 0.5 mm /
0.05°, joint zeros drifted by 0.01°; benchmarks/bench_transfer.py, default recipe) the 30-pose
registration recovers the drifts of joints 2-5 to within 0.0002-0.0007° and
predicts day 2 at 1.23× (position) / 1.04× (orientation) day 1's own held-out error (0.0216 mm /
0.0068°) with the automatic orientation weight (other draws of the 30 poses: 1.12×, 1.13×), against
1.32× / 1.04× at the former fixed 1 m/rad and 5.8× / 2.2× with base and tool alone (2026-11-23). On UR10 series B (model from series A) no joint zero or
thermal state is significant from 30 poses (stds 0.014-0.05°), and forcing the zeros of joints 2-5
in does not help (0.3947 mm vs 0.3925 mm on the other 1,465 poses); nor does a MAP fit of those
zeros and the thermal scale with prior stds 0.002-1° / 20 ppm (0.4009-0.4086 mm against 0.4009 mm,
mean of 4 draws of the 30 poses).

What bounds a registration on UR10 series B (benchmarks/bench_transfer.py, ``diagnose_b``): every
B pose lies outside the A-trained networks' support (support distance 0.18-0.72 of the joint
range; no pose gets a network weight > 0 with the registered fade), and there the networks'
unfaded correction is anti-correlated with B's error (r = -0.13; 1.25 mm mean error unfaded against
0.39 mm calibrated), so the registered hybrid is the calibrated model on B by design. No classical
model does much better there: base and tool re-fitted on all 1,495 poses leave 0.377 mm, and a
calibration fitted on half of B itself leaves 0.367 mm on the other half; the 30-pose draw alone
moves the result by 0.393-0.409 mm (4 seeds of :func:`select_representative`).

Which poses: :func:`select_representative` (default of :func:`register_model`) clusters the
series' measured poses (k-means on z-scored position and rotation-matrix columns) and takes the
pose nearest each centre: spread over the workspace but typical, not extreme. Measured on UR10
series B against a model trained on series A (benchmarks/bench_real.py), 30 poses chosen this way
leave 3-8 % more mean position error than a registration from all 1495 poses (4 seeds), against
15-24 % for farthest-point sampling in joint space (:func:`select_spread`, which picks the extreme
configurations where the model is least accurate) and 3-10 % for random choice.
"""

from __future__ import annotations

import copy
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from ..calibration.frames import (
    fit_frames_solution,
    pose_from_vector6,
    select_representative,
    select_spread,
)
from ..calibration.outliers import DEFAULT_RATIO, OutlierWarning, find_outliers
from ..calibration.result import orientation_weight_from_sigmas
from ..calibration.stations import add_frames, series_labels
from ..geometry.se3 import (
    pose_error,
    rotation_difference_rotvec,
)
from ..io.dataset import Dataset
from .register_checks import (
    MISMATCH_SHORT,
    NOISE_DEG,
    NOISE_MM,
    RegistrationError,
    distinct_nominal,
    fall_back_to_nominal,
    networks_transfer,
    check_extra_plausible,
    check_residual_ratio,
    consistency_test,
    expected_sigmas,
    nominal_comparison,
)
from .register_fit import MIN_T, RegistrationProblem, candidate_names, parameter_stds, robot_with, select_extra

__all__ = ["RegisteredParameter", "RegistrationError", "RegistrationInfo", "register_model"]


@dataclass
class RegistrationInfo:
    """What a registration did and how well: errors on the poses used and on the rest of the series."""

    n_used: int
    n_total: int
    frame_pre: np.ndarray
    frame_post: np.ndarray
    used_pos_mean_mm: float
    used_ang_mean_deg: float | None
    rest_pos_mean_mm: float | None
    rest_ang_mean_deg: float | None
    used_index: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0, int))
    converged: bool = True  # least-squares solver reached a tolerance (scipy status > 0)
    message: str = ""  # solver message
    nfev: int = 0  # residual evaluations
    n_fade_swapped: int = 0  # selected poses in the model's fade zone (0 < w < 1) replaced by trusted neighbours
    parameters: list = field(default_factory=list)  # RegisteredParameter: every re-fitted value with its std
    not_fitted: dict = field(default_factory=dict)  # candidate name -> why it was not re-fitted
    network_check: str = ""  # whether the networks' correction was kept for this series, and the evidence
    orientation_weight_m_per_rad: float = 1.0  # weight of orientation residuals used (m/rad)
    consistency: str = ""  # the chi-square test of the residual (hykin.measure.register_checks)
    nominal_check: str = ""  # registered model vs nominal + frames, leave-one-pose-out
    nominal_figures: dict = field(default_factory=dict)  # mean LOO errors of both (mm, deg)
    fell_back: bool = False  # the returned model is the nominal robot with fitted frames
    outliers: object | None = None  # rows of the series far off the model (hykin.calibration.outliers.Outliers)
    coverage: str = ""  # a note when joints barely move in the registration poses (:func:`coverage_note`)
    precision: str = ""  # a note when the frames' uncertainty outweighs the model's accuracy (:func:`precision_note`)


    def report(self, robot=None) -> str:
        """The summary, each re-fitted parameter (value ± std), what was left out, the fitted frames.
        ``base.*`` / ``tool.*`` values are changes (rotation vector, translation) of ``frame_pre``
        (new base = ``frame_pre · base``) and ``frame_post`` (new tool = ``tool · frame_post``), not frames;
        ``robot`` (the model's robot before, ``model.robot_``): also the resulting base and tool."""
        from ..calibration.result import frame_text

        lines = [self.summary()]
        if self.used_ang_mean_deg is not None:
            lines.append(f"orientation weight {self.orientation_weight_m_per_rad:.3g} m/rad")
        if self.parameters:
            lines.append("re-fitted (value ± std; base.*, tool.*: changes, frame_pre / frame_post below): " + ", ".join(
                f"{p.name} {p.value:+.4f} ± {p.std:.4f} {p.unit}" for p in self.parameters))
        lines.append(f"frame_pre (measurement frame -> the model's world; new base = frame_pre · base): "
                     f"{frame_text(self.frame_pre)}")
        lines.append(f"frame_post (old TCP -> new TCP; new tool = tool · frame_post): {frame_text(self.frame_post)}")
        if robot is not None:
            lines.append(f"resulting frames (as a robot file writes them): base (measurement frame -> robot base) "
                         f"{frame_text(self.frame_pre @ robot.base)}; tool (flange -> TCP) "
                         f"{frame_text(robot.tool @ self.frame_post)}")
        extra = [p.name for p in self.parameters if p.name.endswith(".zero") or p.name == "thermal.scale"]
        lines.append("joint zeros / thermal state re-fitted: " + (", ".join(extra) if extra else "none"))
        for line in (self.network_check, self.nominal_check, self.consistency, self.coverage, self.precision):
            if line:
                lines.append(line)
        if self.not_fitted:
            groups: dict[str, list[str]] = {}
            for k, v in self.not_fitted.items():
                groups.setdefault(v, []).append(k)
            for why, names in groups.items():
                lines.append(f"not re-fitted: {', '.join(names)}: {why}")
        return "\n".join(lines)

    def summary(self) -> str:
        ang = lambda v: "" if v is None else f", {v:.4f} deg"
        s = (
            f"registered from {self.n_used} of {self.n_total} poses: "
            f"{self.used_pos_mean_mm:.4f} mm{ang(self.used_ang_mean_deg)} mean on those poses"
        )
        if self.rest_pos_mean_mm is not None:
            s += f"; {self.rest_pos_mean_mm:.4f} mm{ang(self.rest_ang_mean_deg)} mean on the other {self.n_total - self.n_used}"
        if self.n_fade_swapped:
            s += f" ({self.n_fade_swapped} selected poses in the fade zone of the network correction replaced by their nearest validated neighbours)"
        if not self.converged:
            s += f" (WARNING: solver did not converge: {self.message})"
        if self.outliers is not None and self.outliers.dropped:
            s += f"; {len(self.outliers.rows)} outlier rows left out"
        return s


#: the frames' uncertainty at the arm's reach above this many times the model's own held-out mean error
#: (and above 0.01 mm) is named by precision_note
PRECISION_FACTOR = 2.0


def precision_note(params: list, robot, model, n_used: int) -> str:
    """A note when the registered frames' standard deviations (``base.*``, ``tool.*`` of ``params``) add
    more TCP error at the arm's reach than :data:`PRECISION_FACTOR` times the model's own held-out mean
    error: ``sqrt(Σ σ_t² + Σ (σ_r · reach)²)``, a rough size of what the frames' uncertainty moves a pose
    (measured: 3 poses of 20 µm noise registered a 2 µm model to 0.068 mm over the workspace); else ``""``."""
    from ..io.modelfile import model_metrics
    from ..kinematics.robot import robot_reach_m

    t = [p.std for p in params if p.name.startswith(("base.", "tool.")) and p.unit == "mm" and np.isfinite(p.std)]
    r = [np.radians(p.std) for p in params if p.name.startswith(("base.", "tool.")) and p.unit == "deg"
         and np.isfinite(p.std)]
    if not t and not r:
        return ""
    reach_mm = float(robot_reach_m(robot)) * 1e3
    x = float(np.sqrt(np.sum(np.square(t)) + np.sum(np.square(np.asarray(r) * reach_mm))))
    own = model_metrics(model).get("hybrid_pos_mean_mm")  # the model's own held-out accuracy
    if own is None or not np.isfinite(own) or x <= max(0.01, PRECISION_FACTOR * float(own)):
        return ""
    return (f"precision: the registered frames' standard deviations move the TCP by about {x:.3g} mm at the arm's "
            f"reach, {x / float(own):.3g}x the model's own accuracy ({float(own):.3g} mm): register from more poses "
            f"(--poses; {n_used} used) for the model's accuracy")


#: a joint moving less than this over the registration poses (deg; prismatic: mm) is named by coverage_note
STILL_JOINT_DEG, STILL_JOINT_MM = 10.0, 20.0


def coverage_note(q_used: np.ndarray, robot) -> str:
    """A note naming the joints that barely move over the registration poses ``q_used`` ``(n, dof)`` (range
    below :data:`STILL_JOINT_DEG` / :data:`STILL_JOINT_MM`), else ``""``: the frames are fitted at those
    joints' values only, and an error of those joints (a zero, a length) is folded into the frames there
    and shows elsewhere (measured: a series moving only joints 5-7 of a 7-joint arm with a 0.05° joint-3
    zero change registered to 0.033 mm on its poses and was 0.54 mm off over the workspace)."""
    q = np.asarray(q_used, dtype=np.float64)
    if len(q) < 2:
        return ""
    rev = robot.revolute
    span = np.where(rev, np.degrees(np.ptp(q, axis=0)), np.ptp(q, axis=0) * 1e3)
    still = np.flatnonzero(span < np.where(rev, STILL_JOINT_DEG, STILL_JOINT_MM))
    if not still.size:
        return ""
    parts = ", ".join(f"q{j + 1} {span[j]:.3g} {'deg' if rev[j] else 'mm'}" for j in still)
    return (f"coverage: joints barely move over the registration poses ({parts}): base and tool are fitted at those "
            "joint values, an error of those joints is folded into them and shows elsewhere; a series that moves "
            "every joint registers the whole workspace")


def _avoid_fade_zone(model, q: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, int]:
    """Replace the selected rows ``idx`` that lie in ``model``'s fade zone (0 < w < 1) by the nearest
    (joint space) unselected rows outside it; returns ``(idx, number replaced)``."""
    if getattr(model, "fade", False) is False or not hasattr(model, "fade_weight"):
        return idx, 0
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wf = np.asarray(model.fade_weight(q))
    ok = (wf == 0.0) | (wf == 1.0)
    bad = idx[~ok[idx]]
    free = np.setdiff1d(np.flatnonzero(ok), idx)
    if bad.size == 0 or free.size < bad.size:
        return idx, 0
    keep = list(idx[ok[idx]])
    for b in bad:
        j = int(np.argmin(np.linalg.norm(q[free] - q[b], axis=1)))
        keep.append(int(free[j]))
        free = np.delete(free, j)
    return np.sort(np.asarray(keep, dtype=np.int64)), int(bad.size)


@dataclass
class RegisteredParameter:
    """One re-fitted quantity: ``value``/``std`` in report units (mm, deg or ppm)."""

    name: str
    value: float
    std: float
    unit: str


def register_model(model, series: Dataset, n_poses: int = 30, seed: int = 0, select: str = "representative",
                   refit: str | tuple = "auto", max_residual_ratio: float | None = None, check_networks: bool = True,
                   orientation_weight: float | str = "auto", alpha: float = 1e-3, tolerance: float = 3.0,
                   noise_mm: float = NOISE_MM, noise_deg: float = NOISE_DEG, check_nominal: bool | str = True,
                   outliers: str = "drop", outlier_ratio: float = DEFAULT_RATIO):
    """Register ``series`` to ``model`` from ``n_poses`` poses; returns ``(new_model, info)``.

    ``outliers`` (``"drop"``, ``"warn"``, ``"keep"``; :mod:`hykin.calibration.outliers`): rows of the
    series more than ``outlier_ratio`` typical errors off the model with frames fitted on the
    registration poses (a lost beam) are left out of the registration and of the figures on the rest
    (``info.outliers``, an :class:`~hykin.calibration.outliers.OutlierWarning` names them).

    ``orientation_weight``: m/rad weight of the orientation residuals, or ``"auto"`` (default):
    ``sigma_pos / sigma_rot`` of a first frames fit at 1 m/rad on the registration poses (the rule of
    the calibration's ``auto``). Measured (benchmarks/bench_transfer.py, three draws of the 30 poses):
    the virtual two-day robot 1.23 / 1.12 / 1.13 × day 1's error with ``auto`` against 1.32 / 1.42 /
    1.28 × at 1 m/rad; UR10 series B (model from A) 0.396 / 0.429 / 0.402 mm against 0.393 / 0.409 /
    0.407 mm.
    ``select``: ``"representative"`` (:func:`select_representative` on the measured poses, default)
    or ``"spread"`` (:func:`select_spread`, farthest-point in joint space).

    What is re-fitted: always the two rigid frames (base = tracker placement, tool = re-mounting);
    with ``refit="auto"`` (default) also, where the poses identify them and they are significant,
    joint zero offsets (DH/MDH robots; ``q<j>.zero``) and a thermal state (``thermal.scale``: a
    uniform length scale of the arm, ppm, e.g. a different temperature of the structure). The
    choice: QR of the scaled registration Jacobian after the frames (a joint zero that a frame
    rotation explains, e.g. joint 1 with a free base, is not identifiable), then
    backward elimination by leave-one-pose-out error of the linearised fit (each kept parameter must
    lower it by >= 3 % and be >= 3 standard deviations from zero). ``refit="frames"``: frames only; a tuple
    of names: exactly those. Offsets and scale go into the copy's calibrated robot; frames into
    ``frame_pre``/``frame_post``; ``info.parameters`` lists every re-fitted value with its standard
    deviation, ``info.not_fitted`` why each other candidate was left out.

    Refusal (:class:`RegistrationError`, one line): a chi-square test of the residuals on the poses
    used, normalised by the measurement noise (``noise_mm`` / ``noise_deg``) and the model's
    uncertainty band at each pose, at significance ``alpha`` with ``tolerance``
    (:mod:`hykin.measure.register_checks`; ``alpha=0`` never refuses). ``max_residual_ratio``
    (default None): the former fixed rule instead (mean residual above that many times the model's
    calibrated training error). Nominal check (``check_nominal``: True / ``"pose"``, ``"position"``
    or False; :func:`nominal_comparison`): when the registered model predicts the registration poses
    worse than the nominal model with frames (leave-one-pose-out; in position or orientation, or in
    position only), the returned model is the nominal one with those frames
    (``info.fell_back``); ``info.consistency`` / ``info.nominal_check`` give the evidence.

    The returned model is a copy (the input model is never changed). Poses are chosen where the model is validated:
    inside the networks' training support (fade weight 1) or beyond the fade (weight 0, the calibrated
    model); a selected pose in between, where the correction is only partly applied and unvalidated,
    is replaced by its nearest validated neighbour in joint space (on UR10 series B, two such poses
    among 30 made the orientation error 9 % worse than calibration alone in one joint region).
    The registered model fades its correction with the nearest-neighbour gap too (``fade="full"``,
    unless the model's fade was off or ``"range"``): a new series samples the joint box differently
    from the training one, and on UR10 series B (random poses, model trained on series A's grid) 35
    poses inside the pairwise grids but far from every training pose were 11 % (position) / 20 %
    (orientation) worse than calibration alone with the default fade. ``info`` reports the error on the poses used
    and on the rest of the series (an honest check of the registration).

    Network check (``check_networks``, default on; ``info.network_check`` says what was decided and
    on what evidence): the networks were validated on the training series only, so where at least
    :data:`MIN_CHECK_POSES` registration poses lie under their correction (fade weight > 0), the
    registered hybrid and the registered calibrated model are compared there by leave-one-pose-out
    (frames fitted on the other poses; per-pose error differences, position and orientation). When
    either difference is positive with paired t > :data:`NETWORK_HARM_T` (1), the correction is
    switched off for this series (``fade_offset = -(fade_width + 1)``: weight 0 at every support
    distance, so every prediction path gives the calibrated model); a tie keeps it. Decided on two
    real cases (not on UR10 A -> B with the default model, where no registration pose is under the
    correction): (1) networks on joints 2-3 only of UR10 series A (``input_joints=(2, 3)``), which
    extrapolate into series B (1,386 of its poses under the correction; forced on, the rest is
    0.445-0.515 mm / 0.058-0.061 deg in 5 draws of 30 poses, against 0.386-0.453 / 0.046-0.050 with
    the calibrated model in 6): switched off in all 6 draws (orientation t +1.1 to +2.2; the position LOO favours the
    hybrid there, t -0.9 to -2.3, although the rest does not: a weak detector); (2) UR5 grid ->
    random series (a tracker move applied to the random series; every random pose under the correction, hybrid 0.059-0.105
    mm against 0.105-0.137 calibrated): kept from 8, 10 and 12 poses (t -1.1 to +0.1). A strict rule
    (off unless the hybrid is better) switched UR5 off at 12 poses (giving back 0.059 -> 0.107 mm);
    t > 2 kept 5 of 6 UR10 draws. Checked on the virtual two-day robot (bench_transfer ``days``) and
    a mirrored-error series (tests/test_transfer.py): kept / switched off.
    """
    if n_poses < 3:
        raise ValueError(f"register: need at least 3 poses, got {n_poses}")
    if len(series) < 3:
        raise ValueError(f"{series.source}: a series needs at least 3 poses to register, got {len(series)}")
    pos_only = not series.has_orientation
    if select not in ("representative", "spread"):
        raise ValueError(f"register: select must be 'representative' or 'spread', got {select!r}")
    if select == "spread":
        idx = select_spread(series.q, n_poses, seed)
    else:
        idx = select_representative(series.poses(), n_poses, seed, position_only=pos_only)
    named = series_labels(series)  # a named station / tool: its frame joins the model's (hykin.calibration.stations)
    new = copy.deepcopy(model)
    new.frame_pre_ = np.eye(4)
    new.frame_post_ = np.eye(4)
    if getattr(new, "fade", False) in (True, "support"):
        new.fade = "full"
    idx, n_swapped = _avoid_fade_zone(new, series.q, idx)
    from ..calibration.thermal import temperature_of
    from ..io.payload import payload_kwargs, payload_of

    temp = temperature_of(series)
    pl_kw = payload_kwargs(payload_of(series))
    T_model = new.predict(series.q, temperature_c=temp, **pl_kw)
    T_meas = series.poses()
    net_line = ""
    if getattr(new, "fade", False) is not False and hasattr(new, "fade_weight") and check_networks:
        # The networks were validated on the training data only: keep their correction for this
        # series only where its own registration poses show that it helps (issue 13).

        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            w_used = np.asarray(new.fade_weight(series.q[idx]))
        T_cls = new.predict_classical(series.q[idx], temperature_c=None if temp is None else np.asarray(temp)[idx],
                                      **payload_kwargs(payload_of(series), idx))
        keep, net_line = networks_transfer(w_used, T_model[idx], T_cls, T_meas[idx], pos_only)
        if not keep:  # every fade mode's support distance is >= 0: weight 0 everywhere
            new.fade_offset_ = -(new.fade_width_ + 1.0)  # w = 0 at every support distance >= 0
            T_model = new.predict(series.q, temperature_c=temp, **pl_kw)
    w = 1.0 if orientation_weight == "auto" else float(orientation_weight)
    if outliers != "keep":  # a lost beam among the series: against frames fitted on the registration poses
        B, E, _ = fit_frames_solution(T_model[idx], T_meas[idx], position_only=pos_only, orientation_weight_m_per_rad=w)
        p0, a0 = pose_error(B @ T_model @ E, T_meas)
        found = find_outliers(p0 * 1e-3, None if pos_only else np.radians(a0), outlier_ratio)
        if found is not None:
            found.dropped = outliers == "drop" and found.droppable
            warnings.warn(OutlierWarning(found.message(getattr(series, "source", None) or None, "the registered model")),
                          stacklevel=2)
        if found is not None and found.dropped:
            new_model, info = register_model(
                model, series.subset(np.setdiff1d(np.arange(len(series)), found.rows)), n_poses, seed, select, refit,
                max_residual_ratio, check_networks, orientation_weight, alpha, tolerance, noise_mm, noise_deg,
                check_nominal, outliers="keep")
            info.outliers = found
            return new_model, info
    B, E, sol = fit_frames_solution(T_model[idx], T_meas[idx], position_only=pos_only, orientation_weight_m_per_rad=w)
    if orientation_weight == "auto" and not pos_only:  # sigma_pos / sigma_rot of this fit, as the calibration's auto
        T_fit = B @ T_model[idx] @ E
        rp = np.sqrt(np.mean(np.sum((T_fit[:, :3, 3] - T_meas[idx][:, :3, 3]) ** 2, 1)))
        ra = np.sqrt(np.mean(np.sum(rotation_difference_rotvec(T_fit[:, :3, :3], T_meas[idx][:, :3, :3]) ** 2, 1)))
        w = orientation_weight_from_sigmas(rp, ra)  # per-pose RMS norms: the same ratio as per coordinate
        B, E, sol = fit_frames_solution(T_model[idx], T_meas[idx], position_only=pos_only, orientation_weight_m_per_rad=w)
    x0 = np.concatenate([rotation_difference_rotvec(B[None, :3, :3], np.eye(3)[None])[0], B[:3, 3],
                         rotation_difference_rotvec(E[None, :3, :3], np.eye(3)[None])[0], E[:3, 3]])
    has_rob = getattr(new, "robot_", None) is not None
    cands = candidate_names(new, temp is not None) if has_rob else []
    not_fitted: dict[str, str] = {}
    if refit == "frames" or not cands:
        extra = []
        not_fitted = {c: "not requested (frames only)" for c in cands}
    elif refit == "auto":
        prob0 = RegistrationProblem(new, series.q[idx], T_model[idx], T_meas[idx], [], pos_only, w)
        extra, not_fitted = select_extra(prob0, x0, cands)
    else:
        extra = [str(c) for c in refit]
        bad = [c for c in extra if c not in cands]
        if bad:
            raise ValueError(f"register: refit names {bad} are not candidates; candidates: {', '.join(cands)}")
    prob = RegistrationProblem(new, series.q[idx], T_model[idx], T_meas[idx], extra, pos_only, w) if has_rob else None
    x = x0
    params: list[RegisteredParameter] = []
    implausible = None  # a zero / scale no drift explains: frames only, the tests below decide
    while extra:
        sol_x = least_squares(lambda v: prob.resid(v).ravel(), np.concatenate([x0, np.zeros(len(extra))]),
                              jac=lambda v: prob.jac(v).reshape(-1, len(v)), method="lm", xtol=1e-15, ftol=1e-15,
                              gtol=1e-15)
        try:
            check_extra_plausible(series, extra, sol_x.x[12:])
        except RegistrationError as e:
            implausible = str(e)
            not_fitted.update({c: "implausible value (" + implausible.split(": ", 1)[-1] + ")" for c in extra})
            extra = []
            prob = RegistrationProblem(new, series.q[idx], T_model[idx], T_meas[idx], [], pos_only, w)
            break
        # significant at the solution too (the selection's test is linearised at the frames-only fit)
        sd = parameter_stds(prob, sol_x.x, pos_only)
        t = np.array([abs(sol_x.x[12 + k]) / max(sd[12 + k], 1e-300) for k in range(len(extra))])
        weak = int(np.argmin(t))
        if t[weak] >= MIN_T:
            break
        not_fitted[extra.pop(weak)] = f"not significant at the solution (|estimate| {t[weak]:.1f} std < {MIN_T:g})"
        prob = RegistrationProblem(new, series.q[idx], T_model[idx], T_meas[idx], extra, pos_only, w)
    # standard deviations of everything fitted, at the solution (before the model takes the re-fitted values)
    std = parameter_stds(prob, x, pos_only) if prob is not None and not extra else {}
    if extra:
        sol, x, std = sol_x, sol_x.x, sd  # the last test's stds: this solution's
        new.robot_ = robot_with(new.robot_, extra, x[12:])
        T_model = new.predict(series.q, temperature_c=temp, **pl_kw)
        B = pose_from_vector6(x[:6])
        E = pose_from_vector6(np.concatenate([np.zeros(3) if pos_only else x[6:9], x[9:12]]))
    if prob is not None:
        cols = list(std)
        labels = ["base.rx", "base.ry", "base.rz", "base.x", "base.y", "base.z",
                  "tool.rx", "tool.ry", "tool.rz", "tool.x", "tool.y", "tool.z"] + extra
        for k in cols:
            nm = labels[k]
            if nm == "thermal.scale":
                f, unit = 1e6, "ppm"
            elif nm.endswith(".zero") or nm.split(".")[1].startswith("r"):
                f, unit = np.degrees(1.0), "deg"
            else:
                f, unit = 1e3, "mm"
            params.append(RegisteredParameter(nm, float(x[k] * f), float(std[k] * f), unit))
    new.frame_pre_, new.frame_post_ = B, E
    T_reg = B @ T_model @ E
    p, a = pose_error(T_reg, T_meas)
    rest = np.setdiff1d(np.arange(len(series)), idx)
    info = RegistrationInfo(
        n_used=len(idx),
        n_total=len(series),
        frame_pre=B,
        frame_post=E,
        used_pos_mean_mm=float(p[idx].mean()),
        used_ang_mean_deg=None if pos_only else float(a[idx].mean()),
        rest_pos_mean_mm=float(p[rest].mean()) if len(rest) else None,
        rest_ang_mean_deg=None if pos_only or not len(rest) else float(a[rest].mean()),
        used_index=idx,
        converged=bool(sol.status > 0),
        message=str(sol.message),
        nfev=int(sol.nfev),
        orientation_weight_m_per_rad=w,
        n_fade_swapped=n_swapped,
        parameters=params,
        not_fitted=not_fitted,
        network_check=net_line,
        coverage=coverage_note(series.q[idx], new.robot_),
    )
    info.precision = precision_note(params, new.robot_, model, len(idx))
    n_par = len(x) - (3 if pos_only else 0)
    if max_residual_ratio is not None:
        check_residual_ratio(model, info.used_pos_mean_mm, info.used_ang_mean_deg, info.n_used,
                             getattr(series, "source", "series"), max_residual_ratio)
        alpha = 0.0
    sp, sa, src = expected_sigmas(new, series.q[idx], noise_mm=noise_mm, noise_deg=noise_deg)
    test = consistency_test(T_reg[idx], T_meas[idx], sp, sa, n_par, position_only=pos_only, alpha=alpha,
                            tolerance=tolerance, sigma_source=src)
    if check_nominal and distinct_nominal(model):
        from ..kinematics.classical import classical_fk

        T_nom = classical_fk(model.robot, series.q, **pl_kw)
        keep, info.nominal_check, info.nominal_figures = nominal_comparison(T_model[idx], T_nom[idx], T_meas[idx],
                                                                            pos_only, w,
                                                                            "position" if check_nominal == "position" else "pose")
        if not keep:
            T_reg, test = fall_back_to_nominal(new, model, T_model, T_nom, T_meas, idx, pos_only, w, sp, sa, alpha, tolerance, src)
            p, a = pose_error(T_reg, T_meas)
            info.fell_back, info.frame_pre, info.frame_post = True, new.frame_pre_, new.frame_post_
            info.parameters, info.network_check = [], ""
            info.not_fitted = {c: "nominal fallback (frames only)" for c in cands}
            info.used_pos_mean_mm = float(p[idx].mean())
            info.used_ang_mean_deg = None if pos_only else float(a[idx].mean())
            info.rest_pos_mean_mm = float(p[rest].mean()) if len(rest) else None
            info.rest_ang_mean_deg = None if pos_only or not len(rest) else float(a[rest].mean())
    info.consistency = test.line()
    if not test.passed:
        raise RegistrationError(implausible or f"{getattr(series, 'source', 'series')}: {MISMATCH_SHORT}: {test.line()}")
    if named != (None, None):  # a series from one named station / tool: its frame joins the model's
        new.station_frames_, new.frame_pre_, new.frame_post_ = add_frames(new.station_frames_, named, B, E, new.robot_)
    return new, info
