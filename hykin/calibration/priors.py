"""Priors of the calibration: every candidate parameter starts at the robot file's value with a
stated tolerance, and what the data do not excite stays there (used by :mod:`hykin.calibration.calibrate`).

Tolerances per kind (one standard deviation of the prior; :data:`DEFAULT_PRIORS`, overridable with
``calibrate(..., priors={"length_mm": 2})`` or ``hykin fit|calibrate --prior length_mm=2``):

==================  ==========  ===========================================================
key                 default     applies to
==================  ==========  ===========================================================
length_mm           5           DH/MDH ``a``, ``d``; URDF origin ``x, y, z``
angle_deg           0.5         DH/MDH ``alpha``, ``beta``; URDF origin ``rx, ry, rz``
joint_zero_deg      1.25        DH/MDH ``theta`` (joint zero offsets)
base_mm             inf         base (measurement frame) translation
base_deg            inf         base rotation
tool_mm             100         tool (flange -> TCP) translation, further reflectors' offsets
tool_deg            180         tool rotation
compliance_deg      0.25        joint compliance, as the deflection it causes under the largest
                                gravity torque of that joint in the data
thermal_per_k       3e-5        thermal expansion coefficient (prior mean 0: the file has none)
excitation_mm       0.2         model-error floor of the excitation test (below), positions
excitation_deg      0.01        the same for orientations (6-D data)
excitation_residual 0           c > 0: where ``c`` x the fit's own residual RMS is below those
                                floors, both are scaled down to it and the fit runs once more (below)
refuse_tolerances   4           a parameter the data put further than this many tolerances from
                                the robot file is refused (:mod:`hykin.calibration.checks`)
==================  ==========  ===========================================================

The defaults of length, angle and joint zero are a quarter of the refusal bounds hykin used before
(20 mm, 2 deg, 5 deg), so the same robot files are refused. The base is uninformative (``inf``): a
robot file without ``[base]`` says nothing about where the tracker stands, the base comes from the
data (metres or kilometres away); give ``base_mm``/``base_deg`` to hold a surveyed base (a stated
base or tool tolerance also bounds them, :mod:`hykin.calibration.checks`). The tool
is a guess with a tool-sized tolerance (a reflector on a 100 mm tool); its rotation is free.

**Uninformative parameters the data do not determine.** An infinite tolerance adds no prior row, so
two uninformative parameters along one direction of the data would let the fit walk along it
(``tool_mm=inf`` with the tool at one orientation: the tool translation does to the data what the
base translation does; the tool walked to 2.67 m). :func:`excitation` keeps them in the parameters'
order (base, tool, further frames, joints) and holds one that the earlier ones reproduce but for
:data:`DEPENDENT_REL` of its column; :func:`uninformative_note` says so.

**Excitation (which parameters the data can tell).** Model errors that the classical model does not
represent (non-geometric effects, instrument drift) are not white noise: they do not average out
over thousands of poses. A parameter the data move by ``e`` (RMS over the poses, m, after every
other estimated parameter has absorbed what it can) when it changes by one tolerance can be shifted
by such an error of size ``f`` by ``f / e`` tolerances. :func:`excitation` finds these ``e`` by a
rank-revealing (greedy column-pivoted) QR of the identification Jacobian scaled by the tolerances,
uninformative parameters first; a parameter with ``e < f`` (``f`` = ``excitation_mm``, 0.2 mm, and
``excitation_deg``, 0.01 deg, for orientation rows: what a calibrated classical model of an
industrial arm leaves) is **held at its prior** (not estimated:
its value stays the robot file's, its posterior standard deviation is its tolerance). Example: a
tool offset measured with the tool at one orientation (spread 0.1 deg) moves the points by
``0.1 m x 1.7 mrad ~ 0.1 mm`` per tolerance: held, where a white-noise test would call it
identified to 0.1 mm and a model error of 0.05 mm would move it by 30 mm.

**Floors from the residual (opt-in, ``excitation_residual = c``).** After the fit, the part of any
model error along a held parameter's unexplained column is part of the residual, so it is at most
the residual's RMS ``r`` (per pose, positions; per pose, orientations). A floor above ``c r`` is then
more cautious than these data need: :func:`residual_floors` scales both floors by one factor, ``c``
times the larger of ``r_pos / floor_m`` and ``r_rot / floor_rad`` (``c = 1``: no parameter can be
moved by more than one tolerance by what the fit leaves), and the fit runs once more with them. Measured on the generated battery (``benchmarks/bench_battery.py --draws 540 --seed
7100``): position-only 7-joint arms with 85 poses had ``a6``, ``alpha6`` held (0.084 mm RMS left,
1.9x the noise floor on held-out poses); with ``c = 1`` they are identified (1.12x); 540 of 540 draws
pass against 537. Off by default while the figures measured with the fixed floors stand.

**Estimate.** The estimated parameters are the maximum a posteriori under Gaussian priors: prior
rows ``(σ / τ_k) (δ_k - μ_k)`` (``σ`` the measurement noise per coordinate, m; ``τ_k`` the tolerance;
``μ_k`` the robot file's value, a deviation 0) are added to the normal equations of the one LM
(:func:`hykin.kinematics.lm.normal_equations_step`). Posterior covariance of the estimated ones
(:func:`hykin.calibration.posterior.posterior`): ``A_e⁻¹ + K Σ_h Kᵀ`` with ``A_e = J_eᵀ Σ⁻¹ J_e +
diag(τ_e⁻²)``; the second ("consider") term carries the held parameters' tolerances ``Σ_h = diag(τ_h²)``
through the fit, ``K = A_e⁻¹ J_eᵀ Σ⁻¹ J_h``: a held parameter is not known exactly, and what the
estimated ones absorbed of its error is theirs. Held parameters that the estimated frames (base, tool,
stations) reproduce exactly (``theta1``/``d1`` against the base, the last joint against the tool) are a
convention of those frames and left out. An estimated parameter with ``|ρ| >= 0.99`` to a held one (at
least 98 % of its variance is that tolerance) is reported "correlated with" it, never "identified".
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace

import numpy as np

__all__ = [
    "DEFAULT_PRIORS",
    "GROUP_KIND",
    "PRIOR_HELP",
    "Excitation",
    "excitation",
    "kind_of",
    "label_scales",
    "parse_kind_values",
    "PRECISE_NOTE",
    "parse_priors",
    "precise_data_note",
    "uninformative_note",
    "prior_tolerances",
    "residual_floors",
    "resolve_priors",
]

DEFAULT_PRIORS: dict[str, float] = {
    "length_mm": 5.0,
    "angle_deg": 0.5,
    "joint_zero_deg": 1.25,
    "base_mm": math.inf,
    "base_deg": math.inf,
    "tool_mm": 100.0,
    "tool_deg": 180.0,
    "compliance_deg": 0.25,
    "thermal_per_k": 3e-5,
    "excitation_mm": 0.2,
    "excitation_deg": 0.01,
    "excitation_residual": 0.0,
    "refuse_tolerances": 4.0,
}

#: one line for the CLI's --help
PRIOR_HELP = ("Prior tolerance of the robot file's values, KIND=VALUE (repeatable): length_mm (5), angle_deg (0.5), "
              "joint_zero_deg (1.25), base_mm (inf), base_deg (inf), tool_mm (100), tool_deg (180), compliance_deg "
              "(0.25, deflection under gravity), thermal_per_k (3e-5), excitation_mm (0.2, model-error floor: a "
              "parameter moving the data less per tolerance is held at the file), excitation_residual (0; 1: floors lowered to "
              "the fit's own residual RMS where that is smaller, one more pass), refuse_tolerances (4). inf = "
              "uninformative.")

#: parameter group -> prior kind prefix ("base" / "tool"); groups not listed are geometry (by field/unit).
#: A new frame group (per-station bases, per-tool frames) is a frame by its name (see :func:`kind_of`).
GROUP_KIND = {"base": "base", "tool": "tool", "point": "tool", "comp": "compliance"}


def kind_of(spec) -> str:
    """Prior kind of a :class:`~hykin.calibration.params.ParamSpec`: ``length``, ``angle``, ``joint_zero``,
    ``base_len``/``base_ang``, ``tool_len``/``tool_ang`` or ``compliance`` (from its group, field, unit)."""
    g = GROUP_KIND.get(spec.group)
    if g is None and ("base" in spec.group or "station" in spec.group):
        g = "base"
    elif g is None and "tool" in spec.group:
        g = "tool"
    if g == "compliance" or spec.unit == "c":
        return "compliance"
    if g in ("base", "tool"):
        return g + ("_len" if spec.unit == "m" else "_ang")
    if spec.group == "geom" and spec.field == "theta":
        return "joint_zero"
    return "length" if spec.unit == "m" else "angle"


def resolve_priors(overrides: Mapping[str, float] | None) -> dict[str, float]:
    """:data:`DEFAULT_PRIORS` with ``overrides``; ValueError on unknown keys or values that are not > 0
    (``excitation_mm`` may be 0; ``inf`` makes a kind uninformative)."""
    out = dict(DEFAULT_PRIORS)
    for k, v in dict(overrides or {}).items():
        if k not in DEFAULT_PRIORS:
            raise ValueError(f"priors: unknown kind {k!r}; kinds are {', '.join(DEFAULT_PRIORS)}")
        try:
            v = float(v)
        except (TypeError, ValueError):
            raise ValueError(f"priors: {k}={v!r} is not a number") from None
        floor = k.startswith("excitation")
        ok = v >= 0 if floor else v > 0
        if math.isnan(v) or not ok or ((k == "refuse_tolerances" or floor) and math.isinf(v)):
            raise ValueError(f"priors: {k} must be {'>= 0' if floor else '> 0'} and finite where it is a limit, got {v}")
        out[k] = v
    return out


def parse_kind_values(items: Iterable[str] | str | None, option: str, kinds) -> dict[str, float]:
    """``["a=1,b=2", "c=inf"]`` (or one string) -> ``{"a": 1.0, ...}``; ValueError naming ``option`` on
    an item that is not KIND=VALUE or a value that is not a number (the kinds are checked by the caller)."""
    if isinstance(items, str) or items is None:
        items = [items or ""]
    out: dict[str, float] = {}
    for item in items:
        for part in str(item).split(","):
            part = part.strip()
            if not part:
                continue
            if "=" not in part:
                raise ValueError(f"{option}: {part!r} is not KIND=VALUE (kinds: {', '.join(kinds)})")
            k, v = (s.strip() for s in part.split("=", 1))
            try:
                out[k] = float(v)
            except ValueError:
                raise ValueError(f"{option}: {k}={v!r} is not a number") from None
    return out


def parse_priors(items: Iterable[str] | str | None) -> dict[str, float]:
    """``["length_mm=2", "base_mm=inf"]`` (or one comma-separated string) -> resolved priors (ValueError)."""
    return resolve_priors(parse_kind_values(items, "--prior", DEFAULT_PRIORS))


def prior_tolerances(specs, pri: Mapping[str, float], torque_max_nm=None) -> np.ndarray:
    """``(P,)`` prior standard deviation of each parameter, SI (m, rad, rad/N·m; ``inf``: uninformative).

    torque_max_nm: ``(n,)`` largest gravity torque of each joint over the data (N·m), which turns the
    compliance tolerance (a deflection) into a compliance; None, or below 1e-3 of the largest joint's:
    that compliance is uninformative (inf).
    """
    rad = math.pi / 180
    per = {"length": pri["length_mm"] * 1e-3, "angle": pri["angle_deg"] * rad, "joint_zero": pri["joint_zero_deg"] * rad,
           "base_len": pri["base_mm"] * 1e-3, "base_ang": pri["base_deg"] * rad, "tool_len": pri["tool_mm"] * 1e-3,
           "tool_ang": pri["tool_deg"] * rad}
    out = np.empty(len(specs))
    t_all = 0.0 if torque_max_nm is None or len(torque_max_nm) == 0 else float(np.max(torque_max_nm))
    for k, s in enumerate(specs):
        kind = kind_of(s)
        if kind == "compliance":  # a joint with next to no gravity torque: its compliance has no meaningful prior
            tm = 0.0 if torque_max_nm is None else float(torque_max_nm[s.joint])
            out[k] = pri["compliance_deg"] * rad / tm if tm > 1e-3 * t_all and tm > 0 else math.inf
        else:
            out[k] = per[kind]
    return out


def label_scales(specs, tol_si: np.ndarray, pri: Mapping[str, float]) -> np.ndarray:
    """``(P,)`` SI: the scale a posterior std is judged against ("undetermined" from half of it,
    :func:`hykin.calibration.posterior.statuses`): the tolerance where finite; for an uninformative
    frame or geometry parameter, its kind's geometry tolerance (``length_mm`` for translations,
    ``angle_deg`` / ``joint_zero_deg`` for rotations; the defaults where those are inf too): a base or
    tool known to worse than the robot file's lengths is not identified; compliances: inf (never)."""
    rad = math.pi / 180
    fin = lambda k: pri[k] if math.isfinite(pri[k]) else DEFAULT_PRIORS[k]
    ref = {"length": fin("length_mm") * 1e-3, "angle": fin("angle_deg") * rad, "joint_zero": fin("joint_zero_deg") * rad}
    out = np.asarray(tol_si, dtype=np.float64).copy()
    for k, s in enumerate(specs):
        kind = kind_of(s)
        if not math.isfinite(out[k]) and kind != "compliance":
            out[k] = ref["length" if kind.endswith("_len") else "angle" if kind.endswith("_ang") else kind]
    return out


@dataclass(frozen=True)
class Excitation:
    """Outcome of :func:`excitation`: ``excited`` ``(P,)`` bool (estimated from the data),
    ``effect_m`` ``(P,)`` RMS change of the data per tolerance that no earlier column explains (in
    floors; inf for uninformative parameters), ``floor_m`` the threshold used (1, or 0: rank test),
    ``dependent`` ``(P,)`` bool: uninformative parameters (infinite tolerance) held because earlier
    uninformative ones reproduce their effect (the data do not determine them), ``independent``
    ``(P,)`` bool: columns that pass the rank test (held ones among them are held by the floor alone)."""

    excited: np.ndarray
    effect_m: np.ndarray
    floor_m: float
    dependent: np.ndarray | None = None
    independent: np.ndarray | None = None


#: an uninformative column that the earlier uninformative columns reproduce but for this fraction of its
#: norm is not determined by the data (the tool translation against the base's with the tool at one
#: orientation: its unexplained part is the spread of the flange orientation, ~1e-9 when one orientation
#: is commanded; 1e-4 rad = 0.006 deg of spread still lets a 0.2 mm model error move it by 2 m)
DEPENDENT_REL = 1e-4


def _independent_in_order(J: np.ndarray, rel: float) -> np.ndarray:
    """``(k,)`` bool: columns of ``J`` ``(rows, k)`` whose part unexplained by the earlier kept columns
    exceeds ``rel`` of their norm (Gram–Schmidt in the given order, re-orthogonalised once; a zero
    column is dependent). The order decides which of two dependent columns is kept: the first."""
    keep = np.zeros(J.shape[1], bool)
    Q = np.zeros((J.shape[0], 0))
    for k in range(J.shape[1]):  # a dozen columns at most (base, tool, further frames): in order, not pivoted
        c = J[:, k]
        n = np.linalg.norm(c)
        r = c - Q @ (Q.T @ c)
        r = r - Q @ (Q.T @ r)  # twice is enough (Kahan): the kept basis stays orthonormal to rounding
        nr = np.linalg.norm(r)
        if n > 0 and nr > rel * n:
            keep[k] = True
            Q = np.column_stack([Q, r / nr])
    return keep


def excitation(J: np.ndarray, n_samples: int, tol_si: np.ndarray, scale: np.ndarray, row_floor: np.ndarray,
               negligible_rel: float = 1e-9, rank_tol: float = 1e-6) -> Excitation:
    """Which parameters the data excite beyond the model-error floor (module docstring).

    J: ``(rows, P)`` identification Jacobian in scaled units (column ``k`` = d residual per
    ``scale[k]`` SI) over ``n_samples`` poses; tol_si: ``(P,)`` tolerances (inf: uninformative, always
    first and excited unless its column is negligible or the uninformative columns before it reproduce
    it but for :data:`DEPENDENT_REL` of its norm: then held, ``dependent``); row_floor: ``(rows,)`` the floor of each row in
    its own unit (position rows: ``excitation_mm``; orientation rows, weighted by ``w``: ``w x
    excitation_deg``), so that the test does not depend on the orientation weight; a parameter is
    excited when its unexplained RMS effect per tolerance reaches 1 floor (``effect_m`` is in
    floors then; all-zero floors: the plain rank test); rank_tol: a
    column whose unexplained part is below this fraction of its norm is redundant (held) whatever
    ``f`` (``f = 0`` then gives the plain rank test). Greedy column-pivoted QR (scipy's rank-revealing QR) on the tolerance-scaled columns after the
    uninformative ones are projected out.
    """
    J = np.asarray(J, dtype=np.float64)
    row_floor = np.asarray(row_floor, dtype=np.float64)
    floor_m = 1.0 if np.all(row_floor > 0) else 0.0
    if floor_m:
        J = J / row_floor[:, None]
    P = J.shape[1]
    norms = np.linalg.norm(J, axis=0)
    big = norms.max() if P and norms.size else 0.0
    live = norms > negligible_rel * max(big, 1e-300)
    inf = ~np.isfinite(tol_si)
    effect = np.zeros(P)
    excited = np.zeros(P, bool)
    dependent = np.zeros(P, bool)
    forced = np.flatnonzero(inf & live)
    if forced.size and J.shape[0]:
        # an infinite tolerance puts no prior row on the parameter: two of them along one direction of the
        # data (base and tool translation, the tool at one orientation) would let the fit walk along it to
        # metres. Kept in the parameters' order (base before tool before joints), the later one is held.
        ok = _independent_in_order(J[:, forced], max(DEPENDENT_REL, rank_tol))
        dependent[forced[~ok]] = True
        forced = forced[ok]
    excited[forced] = True
    effect[forced] = np.inf
    rest = np.flatnonzero(~inf & live)
    independent = excited.copy()
    if rest.size == 0 or J.shape[0] == 0:
        return Excitation(excited, effect, floor_m, dependent, independent)
    import scipy.linalg

    Jr = J[:, rest] * (tol_si[rest] / scale[rest])  # per tolerance
    cn = np.linalg.norm(Jr, axis=0) / math.sqrt(max(n_samples, 1))
    if forced.size:  # the kept uninformative columns have full rank (above): their Q spans them
        Q = np.linalg.qr(J[:, forced])[0]
        Jr = Jr - Q @ (Q.T @ Jr)
    _, R, piv = scipy.linalg.qr(Jr, mode="economic", pivoting=True)
    m = min(R.shape)
    rkk = np.abs(np.diag(R[:m, :m]))
    e = np.zeros(rest.size)
    e[piv[:m]] = rkk / math.sqrt(max(n_samples, 1))
    effect[rest] = e
    independent[rest] = e > rank_tol * cn
    excited[rest] = (e >= floor_m) & independent[rest]
    return Excitation(excited, effect, floor_m, dependent, independent)


def residual_floors(pri, after: dict, c: float):
    """``pri`` (a :class:`hykin.calibration.posterior.PriorContext`) with both excitation floors
    ``floor_m``/``floor_rad`` scaled by one factor ``s = c x max(r_pos / floor_m, r_rot / floor_rad)``
    where that is below 1 (``after``: a calibration's residual statistics, ``pos_rms_mm`` and, for 6-D
    data, ``rot_rms_deg``); None when ``c`` is 0 or ``s >= 1`` (module docstring). One factor keeps
    the floors' ratio, so the excitation test ranks the parameters as with the fixed floors (its rank
    test is invariant to it): lowering each floor to its own residual would, with noise-free
    orientations, drop the orientation floor to ~1e-9 deg and let those rows decide alone."""
    if not (c > 0 and pri.floor_m > 0):  # no floors (excitation_mm = 0): the plain rank test, nothing to lower
        return None
    ratio = after["pos_rms_mm"] * 1e-3 / pri.floor_m
    if "rot_rms_deg" in after and pri.floor_rad > 0:
        ratio = max(ratio, math.radians(after["rot_rms_deg"]) / pri.floor_rad)
    s = c * ratio
    return replace(pri, floor_m=s * pri.floor_m, floor_rad=s * pri.floor_rad) if s < 1 else None


#: the note of :func:`precise_data_note` when the fit leaves less than 1 / PRECISE_NOTE of the floors
PRECISE_NOTE = 2.0


def precise_data_note(res, pri) -> str:
    """A note for a fit that leaves less than the excitation floors (module docstring) while it holds
    geometry at the robot file: data that precise (a CMM, a tracker on a well-modelled arm) may
    identify those with ``excitation_residual = 1``. Named are only those that option would excite:
    held geometry whose effect at the solution (``res.effect_floors``, in floors) reaches the floors'
    factor :func:`residual_floors` takes with ``c = 1``; "" when there is none (a joint that never
    moved, a planar campaign: their columns are rank-deficient, no floor excites them)."""
    # compliances, and what the frames reproduce whatever the data (d1 / theta1 against the base)
    last = str(res.robot.n_chain)  # the last joint's parameters against the tool
    par = {n[4:] for n in res.names if n.startswith("beta")}  # joints k (beta k) parallel to the next one
    joint = lambda n: n[len(n.rstrip("0123456789")):]
    parallel_d = lambda n: n.startswith("d") and joint(n).isdigit() and (joint(n) in par or str(int(joint(n)) - 1) in par)
    held = [n for n in res.held_names if not (n[:1] == "c" and n[1:].isdigit()) and n not in ("d1", "theta1")
            and not n.startswith(("tool.", "tool[")) and joint(n) != last and not parallel_d(n)]
    effect = getattr(res, "effect_floors", None)
    if effect is not None:  # only what the lowered floors would excite: rank-deficient ones (a joint never moved, a
        # planar campaign) have no effect whatever the floor, and a rerun would identify none of them
        after, fr = res.after, getattr(pri, "floor_rad", 0.0)
        s = after["pos_rms_mm"] * 1e-3 / pri.floor_m  # the floors' factor of residual_floors(c = 1)
        if "rot_rms_deg" in after and fr > 0:
            s = max(s, math.radians(after["rot_rms_deg"]) / fr)
        by = dict(zip(res.names, effect))
        held = [n for n in held if by.get(n, math.inf) >= s]
    if not held:
        return ""
    r = res.after["pos_rms_mm"]
    return (f"the fit leaves {r:.3g} mm RMS, {pri.floor_m * 1e3 / max(r, 1e-12):.3g}x below the {pri.floor_m * 1e3:.3g} mm "
            f"excitation floor, and holds {', '.join(held)} at the robot file, whose effect on these data exceeds that "
            "residual; with data this precise, --prior excitation_residual=1 identifies them")


#: prior kind of a parameter kind (:func:`kind_of`), for the option named in a note
PRIOR_KEY = {"length": "length_mm", "angle": "angle_deg", "joint_zero": "joint_zero_deg", "base_len": "base_mm",
             "base_ang": "base_deg", "tool_len": "tool_mm", "tool_ang": "tool_deg"}


def uninformative_note(res, specs) -> str:
    """A note naming the parameters given an infinite tolerance (``--prior tool_mm=inf``) that the fit held
    at the robot file all the same: the data do not determine them (their effect is none, or that of
    uninformative parameters before them: the tool translation against the base's with the tool at one
    orientation, :func:`excitation`); "" when there are none (compliances without gravity torque aside)."""
    if res.prior_std is None:
        return ""
    by_key: dict[str, list[str]] = {}
    for s, t, st in zip(specs, res.prior_std, res.status):
        kind = kind_of(s)
        if not math.isfinite(t) and st == "held at prior" and kind != "compliance":
            by_key.setdefault(PRIOR_KEY[kind], []).append(s.name)
    if not by_key:
        return ""
    return ("; ".join(f"{k}=inf (uninformative) cannot be honoured for {', '.join(v)}" for k, v in by_key.items())
            + ": the data do not determine them (what they do to these data, the frames estimated before them do: "
            "e.g. a tool measured at one orientation), so they are held at the robot file's value; give a finite "
            + " / ".join(f"--prior {k}" for k in by_key) + " (or measure more orientations) to estimate them")
