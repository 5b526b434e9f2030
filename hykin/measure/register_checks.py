"""Evidence for a registration (:func:`hykin.measure.register.register_model`): is the new series
consistent with the model, and is the registered model better than the nominal one?

**Consistency test** (:func:`consistency_test`; refuses with :class:`RegistrationError`). After the
frames (and any re-fitted zeros / thermal state, ``P`` parameters) are fitted on the ``N``
registration poses, each residual component (position m; orientation rotation-vector rad) is
divided by the scale the model expects at that pose:

    sigma_i^2 = (band_i / c)^2 + noise^2,    c = sqrt(chi2_3.ppf(0.95)) = 2.795

``band_i``: the model's 95 % uncertainty band at the pose (:meth:`HybridModel.predict_uncertainty`:
held-out error of the training series inside the networks' support, the calibrated model's band
widened with the joint-range excess outside it), read as an isotropic Gaussian per coordinate;
``noise``: the measurement noise floor (options ``noise_mm`` / ``noise_deg``, default 0.05 mm /
0.005°: a laser tracker several metres away). A model without bands
uses its training residual (mean position error / 1.596, the mean of a chi(3)), a bare robot
``1e-3 x`` its reach and 1 mrad. Under the hypothesis "the series' error per coordinate is at most
``tolerance`` x the expected scale" ``S = sum (r / sigma)^2 / tolerance^2`` is chi-square with
``N m - P`` degrees of freedom; the registration is refused when ``P(chi2 > S) < alpha`` (options
``alpha``, default 1e-3, and ``tolerance``, default 3: a new day may change a robot's error by a
factor of a few, as UR10 series A -> B does, without the series being another robot, tool or unit).
``alpha = 0`` turns the refusal off.

**Nominal comparison** (:func:`nominal_comparison`): a model fitted on a poorly excited region
(one tool orientation, a sub-region of the joints) may extrapolate onto the new series worse than
the robot file itself. On the registration poses the registered model and the nominal model with
frames fitted on the same poses are compared by leave-one-pose-out (frames fitted on the other
poses, the left-out pose predicted; linearised, :func:`loo_errors_linear`). When the registered model's mean
leave-one-out error is larger (beyond a 0.1 µm / 0.1 µrad tie) in position, or in orientation for full-pose data, the registration
falls back to the nominal model with those frames (no networks, no calibration) and says so;
otherwise the registered model is kept. The fallback is tested for consistency too, its expected
scale widened by what the calibration changes at those poses (the calibrated-minus-nominal
difference after a rigid fit), so a series that neither model explains is refused.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..calibration.frames import fit_frames
from ..geometry.se3 import rotation_difference_rotvec

__all__ = ["BAND_TO_SIGMA", "ConsistencyTest", "RegistrationError", "check_extra_plausible", "check_residual_ratio",
           "consistency_test", "distinct_nominal", "expected_sigmas", "fall_back_to_nominal", "loo_errors",
           "loo_errors_linear",
           "networks_transfer", "nominal_comparison"]

#: 95 % quantile of the norm of a 3-vector of unit Gaussians: band radius / this = sigma per coordinate
BAND_TO_SIGMA = float(np.sqrt(7.814727903251178))
_CHI3_MEAN = 2.0 * np.sqrt(2.0 / np.pi)  # mean norm of a 3-vector of unit Gaussians
#: differences of mean leave-one-out error below these are ties (the registered model is kept)
TIE_M, TIE_RAD = 1e-7, 1e-7
#: default measurement noise floor per coordinate: a laser tracker several metres away
NOISE_MM, NOISE_DEG = 0.05, 0.005


class RegistrationError(ValueError):
    """The series does not fit the model (wrong robot, wrong tool, unit slip): one line, nothing written."""


@dataclass
class ConsistencyTest:
    """Result of :func:`consistency_test`."""

    statistic: float  # sum of squared normalised residuals / tolerance^2
    dof: int
    p_value: float
    alpha: float
    tolerance: float
    rms_ratio: float  # RMS of the normalised residuals (1 = as expected)
    sigma_source: str

    @property
    def passed(self) -> bool:
        return not (self.p_value < self.alpha)

    def line(self) -> str:
        return (f"consistency: normalised residual RMS {self.rms_ratio:.2f} x the expected scale ({self.sigma_source}); "
                f"chi-square {self.statistic:.1f} on {self.dof} dof at tolerance {self.tolerance:g}: p = {self.p_value:.3g} "
                f"({'passes' if self.passed else 'fails'} alpha {self.alpha:g})")


def expected_sigmas(model, q: np.ndarray, *, noise_mm: float, noise_deg: float) -> tuple[np.ndarray, np.ndarray, str]:
    """Expected error scale per coordinate at joints ``q`` ``(N, n)``: ``(sigma_pos_m (N,),
    sigma_rot_rad (N,), source)`` (module docstring)."""
    n = len(q)
    src = "model bands"
    sp = sa = None
    unc = getattr(model, "unc_", None)
    if unc is not None and hasattr(model, "predict_uncertainty"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            pos, ang = model.predict_uncertainty(q, level=0.95)
        sp = np.asarray(pos, dtype=np.float64) * 1e-3 / BAND_TO_SIGMA
        sa = None if ang is None else np.radians(np.asarray(ang, dtype=np.float64)) / BAND_TO_SIGMA
    if sp is None:
        tr = (getattr(model, "meta_", None) or {}).get("metrics", {})
        m = tr.get("held_out") or tr.get("val") or tr.get("train") or {}
        p = m.get("hybrid_pos_mean_mm", m.get("classical_pos_mean_mm"))
        a = m.get("hybrid_rot_mean_deg", m.get("classical_rot_mean_deg"))
        if p is not None:
            src = "training residual"
            sp = np.full(n, float(p) * 1e-3 / _CHI3_MEAN)
            if a is not None:
                sa = np.full(n, np.radians(float(a)) / _CHI3_MEAN)
    if sp is None:
        from ..kinematics.robot import robot_reach_m

        src = "robot file: 1e-3 x reach, 1 mrad"
        sp = np.full(n, 1e-3 * robot_reach_m(model.robot_))
        sa = np.full(n, 1e-3)
    if sa is None:
        sa = np.full(n, 1e-3)
    sp = np.sqrt(sp**2 + (noise_mm * 1e-3) ** 2)
    sa = np.sqrt(sa**2 + np.radians(noise_deg) ** 2)
    return sp, sa, src


def consistency_test(T_fit: np.ndarray, T_meas: np.ndarray, sigma_pos_m: np.ndarray, sigma_rot_rad: np.ndarray,
                     n_params: int, *, position_only: bool, alpha: float, tolerance: float,
                     sigma_source: str) -> ConsistencyTest:
    """Chi-square test of registered poses ``T_fit`` against ``T_meas`` ``(N, 4, 4)`` with per-pose
    scales ``(N,)`` (module docstring); ``n_params``: parameters fitted on these poses."""
    from scipy.stats import chi2

    zp = (T_fit[:, :3, 3] - T_meas[:, :3, 3]) / sigma_pos_m[:, None]
    z = [zp.ravel()]
    if not position_only:
        z.append((rotation_difference_rotvec(T_fit[:, :3, :3], T_meas[:, :3, :3]) / sigma_rot_rad[:, None]).ravel())
    z = np.concatenate(z)
    dof = max(int(z.size - n_params), 1)
    S = float(np.sum(z**2))
    stat = S / tolerance**2
    return ConsistencyTest(stat, dof, float(chi2.sf(stat, dof)), float(alpha), float(tolerance),
                           float(np.sqrt(S / dof)), sigma_source)


def loo_errors(T_model: np.ndarray, T_meas: np.ndarray, position_only: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """Leave-one-pose-out errors of a frames-only registration (:func:`fit_frames` on the other poses,
    then the left-out pose predicted): ``(position m (n,), orientation rad (n,) or None)``."""
    n = len(T_model)
    T = np.empty_like(T_meas)
    for i in range(n):  # n <= a few dozen registration poses: n small least-squares fits
        o = np.arange(n) != i
        B, E = fit_frames(T_model[o], T_meas[o], position_only=position_only)
        T[i] = B @ T_model[i] @ E
    p = np.linalg.norm(T[:, :3, 3] - T_meas[:, :3, 3], axis=1)
    a = None if position_only else np.linalg.norm(rotation_difference_rotvec(T[:, :3, :3], T_meas[:, :3, :3]), axis=1)
    return p, a


def loo_errors_linear(T_model: np.ndarray, T_meas: np.ndarray, position_only: bool,
                      orientation_weight_m_per_rad: float = 1.0) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`loo_errors` of the linearised frames fit: one fit on all poses, then each pose's
    left-out residual ``(I - H_ii)^-1 r_i`` from the diagonal block ``H_ii`` of the hat matrix of the
    Jacobian at the solution (exact for a linear model; two fits instead of ``2 n``, which matters
    when the poses fit badly and each fit iterates long). Same returns as :func:`loo_errors`."""
    from ..calibration.frames import fit_frames_solution

    n = len(T_model)
    w = float(orientation_weight_m_per_rad)
    _, _, sol = fit_frames_solution(T_model, T_meas, position_only=position_only, orientation_weight_m_per_rad=w)
    J, r = np.asarray(sol.jac, dtype=np.float64), np.asarray(sol.fun, dtype=np.float64)
    blocks = [np.arange(3 * n).reshape(n, 3)]
    if not position_only:
        blocks.append(3 * n + np.arange(3 * n).reshape(n, 3))
    rows = np.concatenate(blocks, axis=1)  # (n, m): the residual rows of each pose
    G = np.linalg.pinv(J.T @ J)
    Jp = J[rows]  # (n, m, P)
    H = np.einsum("nip,pq,njq->nij", Jp, G, Jp)
    m = rows.shape[1]
    e = np.linalg.solve(np.eye(m)[None] - H + 1e-12 * np.eye(m)[None], r[rows][..., None])[..., 0]
    p = np.linalg.norm(e[:, :3], axis=1)
    a = None if position_only else np.linalg.norm(e[:, 3:], axis=1) / w
    return p, a


#: poses the leave-one-pose-out comparison needs (full poses, positions only): the frames fitted on the
#: others must be determined (12 parameters from 6 values per pose; 9 from 3)
LOO_MIN_POSES = {False: 4, True: 5}


def nominal_comparison(T_reg: np.ndarray, T_nom: np.ndarray, T_meas: np.ndarray,
                       position_only: bool, orientation_weight_m_per_rad: float = 1.0,
                       components: str = "pose") -> tuple[bool, str, dict]:
    """Keep the registered model (predictions ``T_reg`` ``(n, 4, 4)`` in the model frame) or fall back
    to the nominal model (``T_nom``)? Leave-one-pose-out on the registration poses ``T_meas``; the
    registered model is kept unless its mean LOO error is larger in position or (full pose data,
    ``components="pose"``) in orientation; ``components="position"`` judges position only.
    Returns ``(keep, report line, figures)`` (figures: mean LOO mm / deg). Fewer poses than
    :data:`LOO_MIN_POSES` (the frames fitted on the others would be undetermined: metres of LOO error on
    both sides) keep the registered model, saying the check was skipped."""
    need = LOO_MIN_POSES[bool(position_only)]
    if len(T_meas) < need:
        return True, (f"nominal check: skipped ({len(T_meas)} registration poses; leaving one out needs at least "
                      f"{need}); registered model kept"), {}
    pr, ar = loo_errors_linear(T_reg, T_meas, position_only, orientation_weight_m_per_rad)
    pn, an = loo_errors_linear(T_nom, T_meas, position_only, orientation_weight_m_per_rad)
    fig = {"registered_loo_mm": float(pr.mean() * 1e3), "nominal_loo_mm": float(pn.mean() * 1e3)}
    worse = [f"position {fig['registered_loo_mm']:.4f} against {fig['nominal_loo_mm']:.4f} mm"]
    keep = pr.mean() <= pn.mean() + TIE_M
    if ar is not None:
        fig.update(registered_loo_deg=float(np.degrees(ar.mean())), nominal_loo_deg=float(np.degrees(an.mean())))
        worse.append(f"orientation {fig['registered_loo_deg']:.4f} against {fig['nominal_loo_deg']:.4f} deg")
        if components == "pose":
            keep &= ar.mean() <= an.mean() + TIE_RAD
    what = (f"on the {len(T_meas)} registration poses, leave-one-pose-out registered model vs nominal model + frames: "
            + ", ".join(worse))
    if keep:
        return True, f"nominal check: registered model kept; {what}", fig
    return False, (f"nominal check: FALLBACK to the nominal model with frames fitted on these poses (the model "
                   f"extrapolates here worse than the robot file): {what}"), fig


# --------------------------------------------------------------------------- gross mismatches

MAX_THERMAL_SCALE = 2e-3  # |length scale| a thermal state can explain (aluminium, 23e-6 /K, over ~90 K)
MAX_ZERO_RAD = np.radians(2.0)  # a joint zero that moved more than this is not a drift


def check_extra_plausible(series, names: list[str], values: np.ndarray) -> None:
    """Refuse joint zeros or a length scale no thermal state or zero drift can explain: a unit slip
    (a scale of 1000) or joints in another convention would otherwise be absorbed by them."""
    src = getattr(series, "source", "series")
    for nm, v in zip(names, values):
        if nm == "thermal.scale" and abs(v) > MAX_THERMAL_SCALE:
            raise RegistrationError(
                f"{src}: the series is {1 + v:.6g} times the model's size (a thermal state explains at most "
                f"{MAX_THERMAL_SCALE * 1e6:g} ppm): length unit slip or another robot?")
        if nm.endswith(".zero") and abs(v) > MAX_ZERO_RAD:
            raise RegistrationError(
                f"{src}: joint {nm[1:].split('.')[0]} zero would move by {np.degrees(v):.3f} deg (more than "
                f"{np.degrees(MAX_ZERO_RAD):g} deg): joints in another convention, angle unit slip or another robot?")


MISMATCH = ("the series does not fit the model (wrong robot or model file, wrong tool or T-Mac, length/angle unit "
            "slip, or joints in another convention)")


def check_residual_ratio(model, used_pos_mean_mm: float, used_ang_mean_deg: float | None, n_used: int, src: str,
                         ratio: float) -> None:
    """The former fixed rule, kept for callers that pass ``max_residual_ratio``: refuse a mean residual
    above ``ratio`` x the model's calibrated training error (at least 0.1 mm / 0.01 deg)."""
    tr = (getattr(model, "meta_", None) or {}).get("metrics", {}).get("train", {})
    ref_p, ref_a = tr.get("classical_pos_mean_mm"), tr.get("classical_rot_mean_deg")
    lim_p = max(ratio * max(ref_p or 0.0, 0.02), 0.1)
    lim_a = max(ratio * max(ref_a or 0.0, 0.002), 0.01)
    if used_pos_mean_mm > lim_p:
        raise RegistrationError(
            f"{src}: registration residual {used_pos_mean_mm:.3f} mm mean on the {n_used} poses used, above "
            f"{lim_p:.3f} mm ({ratio:g} x the model's calibrated error): {MISMATCH}")
    if used_ang_mean_deg is not None and used_ang_mean_deg > lim_a:
        raise RegistrationError(
            f"{src}: registration residual {used_ang_mean_deg:.4f} deg mean on the {n_used} poses used, above "
            f"{lim_a:.4f} deg ({ratio:g} x the model's calibrated error): {MISMATCH}")


# --------------------------------------------------------------------------- networks and nominal

#: fewer registration poses than this under the networks' correction (w > 0): no evidence, keep it
MIN_CHECK_POSES = 5
#: paired t of (hybrid - calibrated) leave-one-pose-out error above which the correction is switched off
NETWORK_HARM_T = 1.0


def networks_transfer(w: np.ndarray, T_h: np.ndarray, T_c: np.ndarray, T_meas: np.ndarray,
                       position_only: bool) -> tuple[bool, str]:
    """Do the networks' corrections carry over to this series? Leave-one-pose-out on the registration
    poses: the registered hybrid (model predictions ``T_h`` ``(n, 4, 4)``) against the registered
    calibrated model (``T_c``), on the poses where the correction applies (fade weight ``w`` ``(n,)``
    > 0). Per pose the difference of the errors (hybrid - calibrated), position and (full-pose data)
    orientation; the correction is switched off when either difference is significantly positive
    (paired t > :data:`NETWORK_HARM_T`): the networks keep the benefit of the doubt, a tie keeps them.
    Returns ``(keep, report line)``."""
    on = w > 0
    n = int(on.sum())
    if n < MIN_CHECK_POSES:
        if n == 0:
            return True, (f"network correction: none of the {len(w)} registration poses lies inside the training data, "
                          "so whether the learned correction carries over to this series cannot be checked; it is kept "
                          "and applies wherever later poses fall inside the training data")
        return True, (f"network correction: only {n} of {len(w)} registration poses lie inside the training data "
                      f"(at least {MIN_CHECK_POSES} are needed to test whether it carries over): kept unchecked")
    ph, ah = loo_errors(T_h, T_meas, position_only)
    pc, ac = loo_errors(T_c, T_meas, position_only)
    pairs = [("mm", ph[on] * 1e3, pc[on] * 1e3)]
    if not position_only:
        pairs.append(("deg", np.degrees(ah[on]), np.degrees(ac[on])))
    parts, harm = [], False
    for unit, h, c in pairs:
        d = h - c
        t = float(d.mean() / max(d.std(ddof=1) / np.sqrt(n), 1e-300))
        harm |= t > NETWORK_HARM_T
        parts.append(f"{h.mean():.4f} against {c.mean():.4f} {unit} (t {t:+.1f})")
    where = (f"on the {n} of {len(w)} registration poses where it applies, leave-one-pose-out with base and tool "
             "alone re-fitted (before any joint zero or thermal re-fit below), hybrid vs calibrated " + ", ".join(parts))
    if not harm:
        return True, f"network correction: kept; {where}"
    return False, (f"network correction: OFF for this series (the calibrated model everywhere; it does not carry "
                   f"over, t > {NETWORK_HARM_T:g}): {where}")


MISMATCH_SHORT = ("the series does not fit the model (wrong robot or model file, wrong tool, length/angle unit slip, "
                  "or joints in another convention; --alpha / --tolerance set the test)")


def distinct_nominal(model) -> bool:
    """Does ``model`` differ from its nominal robot (calibrated parameters or networks)?"""
    nominal, rob = getattr(model, "robot", None), getattr(model, "robot_", None)
    if nominal is None or rob is None or nominal is rob:
        return False
    if getattr(model, "net_pos_", None) is not None:
        return True
    from ..kinematics.classical import classical_fk

    q = nominal.random_joints(8, np.random.default_rng(0))
    return nominal.dof != rob.dof or not np.allclose(classical_fk(nominal, q), classical_fk(rob, q), rtol=0, atol=1e-12)


def fall_back_to_nominal(new, model, T_model, T_nom, T_meas, idx, pos_only, w, sp, sa, alpha, tolerance, src):  # noqa: PLR0913
    """Turn ``new`` into the nominal model with frames fitted on the poses ``idx`` (networks off, no
    thermal state, no bands); returns its poses ``(N, 4, 4)`` and its consistency test, the expected
    scale widened by the calibrated-minus-nominal difference at those poses (after a rigid fit)."""
    B, E = fit_frames(T_nom[idx], T_meas[idx], position_only=pos_only)  # exactly "nominal + frames on these poses"
    Bc, Ec = fit_frames(T_nom[idx], T_model[idx], position_only=pos_only, orientation_weight_m_per_rad=w)
    T_d = Bc @ T_nom[idx] @ Ec
    dp = np.linalg.norm(T_d[:, :3, 3] - T_model[idx][:, :3, 3], axis=1) / np.sqrt(3.0)
    da = np.linalg.norm(rotation_difference_rotvec(T_d[:, :3, :3], T_model[idx][:, :3, :3]), axis=1) / np.sqrt(3.0)
    new.robot_ = model.robot.copy()
    if getattr(new, "net_pos_", None) is not None:
        if new.fade is False:
            new.fade = "full"
        new.fade_offset_ = -(new.fade_width_ + 1.0)  # weight 0 at every support distance: no network correction
    new.thermal_, new.unc_ = None, None
    new.frame_pre_, new.frame_post_ = B, E
    new.meta_ = dict(getattr(new, "meta_", {}) or {}, registration="nominal fallback")
    T = B @ T_nom @ E
    test = consistency_test(T[idx], T_meas[idx], np.hypot(sp, dp), np.hypot(sa, da), 12 - 3 * pos_only,
                            position_only=pos_only, alpha=alpha, tolerance=tolerance,
                            sigma_source=src + " + calibrated-nominal difference")
    return T, test
