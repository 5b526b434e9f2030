"""The report's accuracy tables, computed from an :class:`hykin.evaluation.evaluate.EvalResult` and
its dataset: statistics per model for position and orientation and per base axis, where the error
is largest (joint ranges, reach), ISO 9283 pose accuracy and repeatability, the training support,
and per-payload / per-temperature tables. Errors in mm and degrees; joints shown in degrees
(revolute) or mm (prismatic).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .evaluate import distinct_poses
from .report import mm
from .report_figures import joint_bins

__all__ = ["FEW_FIT_POSES", "BaseFrame", "Hotspot", "axis_rows", "base_frame", "distinct_poses", "display_name",
           "fold_gaps", "gap_words", "iso_rows", "outside_split", "joint_hotspot", "nominal_words", "per_payload_rows", "support_note",
           "per_temperature_rows", "reach_hotspot", "support_rows"]

#: the rows of one ISO 9283 pose id are visits of one pose when the model places them within this of
#: each other (m, rad): measured joints of repeated visits differ by encoder noise (~1e-5 rad, 0.01 mm)
ISO_SAME_POSE_M = 1e-4
ISO_SAME_POSE_RAD = np.radians(0.01)

#: a nominal row whose base and tool were fitted to fewer distinct test poses than this is not a
#: meaningful reference (the rigid fit of 12 frame parameters absorbs much of the nominal error)
FEW_FIT_POSES = 20


@dataclass
class BaseFrame:
    """The robot's base frame in the measurement frame: ``T`` ``(4, 4)`` maps base-frame coordinates to
    the frame the model predicts in (the test data's frame, a station model's reference station).
    ``words``: what it is, for the report ("the calibrated robot base", ...); ``is_base``: False when no
    base is known and the figures stay in the measurement frame."""

    T: np.ndarray
    words: str
    is_base: bool = True

    @property
    def name(self) -> str:
        """The frame's name for a caption: "base frame" or "measurement frame"."""
        return "base frame" if self.is_base else "measurement frame"

    def points(self, xyz_m: np.ndarray) -> np.ndarray:
        """Positions ``(N, 3)`` (m) in the measurement frame -> the base frame."""
        xyz = np.asarray(xyz_m, float)
        return (xyz - self.T[:3, 3]) @ self.T[:3, :3]

    def vectors(self, v: np.ndarray | None) -> np.ndarray | None:
        """Free vectors ``(N, 3)`` (position errors, rotation vectors) -> base-frame components."""
        return None if v is None else np.asarray(v, float) @ self.T[:3, :3]

    def poses(self, T: np.ndarray) -> np.ndarray:
        """Poses ``(N, 4, 4)`` in the measurement frame -> the base frame."""
        from ..geometry import se3

        return se3.invert(self.T) @ np.asarray(T, float)


def base_frame(model, data=None, labels: dict | None = None) -> BaseFrame:
    """The base frame the report's base-frame figures use. A fitted model (``robot_``): its calibrated
    robot base, behind its registration frame (``frame_pre_ · robot_.base``). A :class:`Robot`: its
    file's base, or, when the evaluation fitted the nominal row's frames to ``data`` (``labels``
    ``"nominal"`` is :data:`hykin.evaluation.evaluate.NOMINAL_FITTED`), that fitted base. Otherwise
    the identity (figures stay in the measurement frame)."""
    from .evaluate import NOMINAL_FITTED

    rob = getattr(model, "robot_", None)
    if rob is not None:
        pre = np.asarray(getattr(model, "frame_pre_", np.eye(4)), float)
        reg = not np.array_equal(pre, np.eye(4))
        return BaseFrame(pre @ np.asarray(rob.base, float),
                         "the calibrated robot base" + (" (through the model's registration frame)" if reg else ""))
    base = getattr(model, "base", None)
    if base is None:
        return BaseFrame(np.eye(4), "the measurement frame (no robot base known)", False)
    if (labels or {}).get("nominal") == NOMINAL_FITTED and data is not None and len(data) >= 4:
        from ..calibration.frames import fit_frames
        from ..kinematics.classical import classical_fk

        B, _ = fit_frames(classical_fk(model, data.q), data.poses(), position_only=not data.has_orientation)
        return BaseFrame(B @ np.asarray(base, float), "the robot base fitted to these poses")
    return BaseFrame(np.asarray(base, float), "the robot file's base")


def display_name(res, key: str) -> str:
    """A row's name for a reader: the evaluation's label (e.g. "nominal + fitted frames"), else its key."""
    return (getattr(res, "labels", None) or {}).get(key, key)


def nominal_words(res) -> str:
    """What the nominal row is, in words."""
    from .evaluate import NOMINAL_FITTED

    if display_name(res, "nominal") == NOMINAL_FITTED:
        return "nominal kinematics with base and tool fitted to these poses"
    return "nominal kinematics (the robot file's base and tool)"

AXIS_HEADER = ["model", "quantity", "mean", "std", "p95 of |·|", "max of |·|", "unit"]


def _stat_row(name: str, what: str, v: np.ndarray, unit: str, signed: bool) -> list:
    a = np.abs(v)
    return [name, what, float(v.mean() if signed else a.mean()), float(v.std()), float(np.percentile(a, 95)), float(a.max()), unit]


def axis_rows(vectors: dict, frame: BaseFrame | None = None, labels: dict | None = None) -> list[list]:
    """Rows of :data:`AXIS_HEADER` per model (``vectors``: name -> ``(dp_mm (N, 3), dr_deg (N, 3) or None)``,
    in the measurement frame): position |e| and its x, y, z components, then orientation |e| and rx, ry,
    rz. ``frame``: the components are taken along its axes (the robot's base frame; default the
    measurement frame's). ``labels``: name -> the name shown. For a component the mean is signed (a
    bias), the std its spread; for |e| the mean is of the norm."""
    rows = []
    for key, (dp, dr) in vectors.items():
        name = (labels or {}).get(key, key)
        if frame is not None:
            dp, dr = frame.vectors(dp), frame.vectors(dr)
        rows.append(_stat_row(name, "position |e|", np.linalg.norm(dp, axis=1), "mm", False))
        rows += [_stat_row(name, f"  {ax}", dp[:, k], "mm", True) for k, ax in enumerate("xyz")]
        if dr is not None:
            rows.append(_stat_row(name, "orientation |e|", np.linalg.norm(dr, axis=1), "deg", False))
            rows += [_stat_row(name, f"  r{ax}", dr[:, k], "deg", True) for k, ax in enumerate("xyz")]
    return rows


@dataclass
class Hotspot:
    """Where the error is largest: ``what`` (e.g. "joint 2") between ``lo`` and ``hi`` (``unit``), with
    mean error ``mean_mm`` there against ``overall_mm`` on all rows; ``n`` rows in that bin."""

    what: str
    lo: float
    hi: float
    unit: str
    mean_mm: float
    overall_mm: float
    n: int

    def words(self) -> str:
        return (f"{self.what} between {self.lo:.3g} and {self.hi:.3g} {self.unit} "
                f"(mean {mm(self.mean_mm)} there against {mm(self.overall_mm)} overall, {self.n} poses)")


def _hot(x: np.ndarray, e: np.ndarray, what: str, unit: str, n_bins: int, min_share: float) -> Hotspot | None:
    if len(x) < 2 * n_bins or np.ptp(x) <= 0:
        return None
    c, m, cnt = joint_bins(x, e, n_bins)
    ok = cnt >= max(min_share * len(x), 3)
    if not ok.any():
        return None
    k = int(np.nanargmax(np.where(ok, m, -np.inf)))
    w = (c[1] - c[0]) / 2 if len(c) > 1 else 0.0
    return Hotspot(what, float(c[k] - w), float(c[k] + w), unit, float(m[k]), float(e.mean()), int(cnt[k]))


def joint_hotspot(q: np.ndarray, err_mm: np.ndarray, revolute, n_bins: int = 6, min_share: float = 0.05) -> Hotspot | None:
    """The joint bin (``n_bins`` equal-width bins per joint, at least ``min_share`` of the rows) with the
    highest mean error relative to the mean error of all rows."""
    best = None
    for j in range(q.shape[1]):
        x = np.degrees(q[:, j]) if revolute[j] else q[:, j] * 1e3
        h = _hot(x, err_mm, f"joint {j + 1}", "deg" if revolute[j] else "mm", n_bins, min_share)
        if h is not None and (best is None or h.mean_mm > best.mean_mm):
            best = h
    return best


def reach_hotspot(xyz_m: np.ndarray, err_mm: np.ndarray, n_bins: int = 6, frame: BaseFrame | None = None) -> Hotspot | None:
    """The bin of horizontal reach ``sqrt(x² + y²)`` (m) with the highest mean error. ``xyz_m``: positions
    in the robot's base frame, or, with ``frame``, in the measurement frame (mapped into ``frame``).
    Reach from the measurement frame's origin means nothing: callers pass base-frame positions."""
    xyz_m = np.asarray(xyz_m, float) if frame is None else frame.points(xyz_m)
    r = np.hypot(xyz_m[:, 0], xyz_m[:, 1])
    return _hot(r, err_mm, "horizontal reach", "m", n_bins, 0.05)


def iso_rows(data, predicted: dict, frame: BaseFrame | None = None, labels: dict | None = None) -> tuple[list[list], str]:
    """ISO 9283 AP per model and RP, when ``data`` carries a ``pose_id`` (or ``pose``) column: the poses
    whose id occurs at least twice (blank / NaN ids: ordinary test poses) must share their joints. Returns ``(rows, note)``; no rows and the reason otherwise.
    Commanded pose: each model's prediction at the pose's joints; attained: the measurement (both in
    the frame the model predicts in). ``frame``: AP_x/y/z and AP_a/b/c along its axes (the robot's base
    frame; default the measurement frame's). ``labels``: name -> the name shown."""
    from .iso9283 import ISOError, iso9283_pose

    extra = getattr(data, "extra", None) or {}
    col = "pose_id" if "pose_id" in extra else "pose"
    ids = extra.get(col)  # `hykin simulate --plan iso-cube` labels its poses in "pose"
    if ids is None:
        return [], ("not computed: the test data have no pose_id column (ISO 9283 needs each test pose "
                    "approached repeatedly, e.g. 30 cycles of the poses P1 … P5, labelled in a pose_id column).")
    ids = np.asarray(ids)
    if ids.dtype.kind == "f":
        ok = np.isfinite(ids)
    else:  # text: blank (and "nan") cells are ordinary test poses too
        ids = np.char.strip(ids.astype(str))
        ok = (ids != "") & (np.char.lower(ids) != "nan")
    uniq, inv, cnt = np.unique(np.where(ok, ids, ids[ok][0] if ok.any() else 0), return_inverse=True, return_counts=True)
    sel = ok & (cnt[inv] >= 2)  # poses measured once are ordinary test poses, not ISO cycles
    if not sel.any():
        return [], "not computed: no pose_id in the test data occurs more than once (ISO 9283 needs repeated cycles)."
    T_meas = data.poses()[sel]
    to = (lambda T: T) if frame is None else frame.poses
    T_meas = to(T_meas)
    rows = []
    try:
        for key, T in predicted.items():
            name = (labels or {}).get(key, key)
            r = iso9283_pose(to(np.asarray(T)[sel]), T_meas, ids[sel], tol_m=ISO_SAME_POSE_M, tol_rad=ISO_SAME_POSE_RAD)
            for i, pid in enumerate(r.pose_ids):
                pid = int(pid) if isinstance(pid, float) and pid.is_integer() else pid
                ang = [None] * 3 if not data.has_orientation else list(map(float, r.ap_abc_deg[i]))  # position-only data
                rows.append([name, str(pid), int(r.n[i]), float(r.ap_mm[i]), *map(float, r.ap_xyz_mm[i]),
                             *ang, float(r.rp_mm[i])])
    except ISOError as e:
        return [], (f"not computed: {getattr(data, 'source', '') or 'test data'}, column '{col}': {e}; the rows of one "
                    f"pose id must be visits of one pose (their joints may differ by encoder noise, up to "
                    f"{ISO_SAME_POSE_M * 1e3:g} mm / {np.degrees(ISO_SAME_POSE_RAD):g} deg at the TCP)")
    ax = "base" if frame is None or frame.is_base else "measurement-frame"
    return rows, ("AP: distance of the mean attained position from the commanded one (the model's prediction); "
                  f"AP_x/y/z: its components along {ax} x/y/z; AP_a/b/c: mean angle deviations about {ax} x/y/z; RP: ISO 9283 position repeatability "
                  "l̄ + 3 S_l (a property of the robot, the same for every model).")


ISO_HEADER = ["model", "pose", "cycles", "AP_P [mm]", "AP_x", "AP_y", "AP_z", "AP_a [deg]", "AP_b", "AP_c", "RP_l [mm]"]


def support_rows(model, q: np.ndarray, revolute) -> tuple[list[list], int]:
    """Per joint the training range and the test range (deg / mm, in the networks' joint coordinates)
    and the test rows outside it; with the number of rows outside the training support as a whole
    (:meth:`HybridModel.support_distance` > 0). ``([], 0)`` for a model without a support."""
    lo, hi = getattr(model, "support_lower_", None), getattr(model, "support_upper_", None)
    if lo is None or not hasattr(model, "support_distance"):
        return [], 0
    from ..hybrid.inputs import net_coordinates

    qn = net_coordinates(np.asarray(q, float), model.wrap_centre_, model.input_mask_)
    rows = []
    for j in range(q.shape[1]):
        if not model.input_mask_[j]:
            rows.append([f"joint {j + 1}", "not a network input", None, None, None, 0])
            continue
        f, unit = (np.degrees, "deg") if revolute[j] else ((lambda v: v * 1e3), "mm")
        if revolute[j] and np.isfinite(model.wrap_centre_[j]):
            unit = "deg, folded"  # whole turns folded (support_note)
        out = int(np.sum((qn[:, j] < lo[j]) | (qn[:, j] > hi[j])))
        rows.append([f"joint {j + 1}", unit, f(float(lo[j])), f(float(hi[j])),
                     f"{f(float(qn[:, j].min())):.4g} … {f(float(qn[:, j].max())):.4g}", out])
    n_out = int(np.sum(np.asarray(model.support_distance(q)) > 0))
    return rows, n_out


def support_note(model) -> str:
    """What the "deg, folded" joints of :func:`support_rows` mean ("" when no joint is folded)."""
    c = np.asarray(getattr(model, "wrap_centre_", None) if getattr(model, "wrap_centre_", None) is not None else [], float)
    mask = np.asarray(getattr(model, "input_mask_", np.ones(c.shape, bool)), bool)
    folded = [j for j in range(c.size) if np.isfinite(c[j]) and mask[j]]
    if not folded:
        return ""
    parts = ", ".join(f"joint {j + 1} into {np.degrees(c[j]) - 180:.4g} … {np.degrees(c[j]) + 180:.4g}°" for j in folded)
    gaps = gap_words(model)
    return ("Folded joints are shown as the networks see them: q and q ± 360° are one input, so their angles are "
            f"moved by whole turns ({parts}); a trained range there may lie outside the joint limits"
            + (f". {gaps[0].upper() + gaps[1:]}: its trained range is that turn cut at the gap, and a test pose beyond "
               "it lies in the gap, not outside the joint range the robot was measured over." if gaps else "."))


SUPPORT_HEADER = ["joint", "unit", "trained from", "trained to", "test range", "test rows outside"]

#: a folded joint whose training data leave at most this much of its turn uncovered (deg) has a gap in its
#: training data, not a trained range: a test pose there is "in a gap", not outside the range
FOLD_GAP_DEG = 30.0


def fold_gaps(model) -> dict[int, tuple[float, float]]:
    """Folded joints (whole turns folded into one, ``wrap_centre_``) whose training data cover the turn
    except a gap of at most :data:`FOLD_GAP_DEG`: 0-based joint -> ``(gap from, gap to)`` in deg, as the
    networks see the joint (the trained range ``lo … hi`` leaves ``hi − 360 … lo`` uncovered)."""
    c = getattr(model, "wrap_centre_", None)
    lo, hi = getattr(model, "support_lower_", None), getattr(model, "support_upper_", None)
    if c is None or lo is None:
        return {}
    mask = np.asarray(getattr(model, "input_mask_", np.ones(len(c), bool)), bool)
    robot = getattr(model, "robot_", None)
    if robot is not None:  # a joint of less than a turn is not folded (probe s41 AN: a ±175° joint's "gap")
        from ..hybrid.support import circular_joints

        mask = mask & circular_joints(robot, c)
    out = {}
    for j in np.flatnonzero(np.isfinite(np.asarray(c, float)) & mask):
        a, b = np.degrees(float(lo[j])), np.degrees(float(hi[j]))
        if 0 < 360.0 - (b - a) <= FOLD_GAP_DEG:
            # said as the turn nearest zero (probe s41 AP: "-285.4 to -277.1°" for test poses at +75 … +80°)
            k = 360.0 * np.round(((b - 360.0 + a) / 2) / 360.0)
            out[int(j)] = (b - 360.0 - k, a - k)
    return out


def outside_split(model, q: np.ndarray, outside: np.ndarray) -> dict[str, np.ndarray]:
    """The test rows outside the training support (``outside`` ``(N,)`` bool) by why: ``"gap"``: beyond the
    trained range only on joints of :func:`fold_gaps` (in a gap of a folded joint's training data);
    ``"range"``: beyond the trained range of another joint; ``"holes"``: inside every range, between
    training poses. Each ``(N,)`` bool."""
    outside = np.asarray(outside, bool)
    if not hasattr(model, "range_excess"):
        return {"gap": np.zeros_like(outside), "range": outside, "holes": np.zeros_like(outside)}
    ex = np.asarray(model.range_excess(q)) > 0
    gap_cols = np.zeros(ex.shape[1], bool)
    gap_cols[list(fold_gaps(model))] = True
    gap = outside & ex[:, gap_cols].any(1) & ~ex[:, ~gap_cols].any(1)
    rng = outside & ex[:, ~gap_cols].any(1)
    return {"gap": gap, "range": rng, "holes": outside & ~gap & ~rng}


def gap_words(model, joints=None) -> str:
    """"joint 6: its training data cover the whole turn except a 2.46° gap from −30.02 to −27.56°" per joint of
    :func:`fold_gaps` (only those in ``joints``, 0-based, when given; "" if none)."""
    return "; ".join(f"joint {j + 1}: its training data cover the whole turn except a {b - a:.3g}° gap "
                     f"from {a:.4g} to {b:.4g}°" for j, (a, b) in fold_gaps(model).items()
                     if joints is None or j in joints)


def per_payload_rows(per_payload: dict | None, labels: dict | None = None) -> list[list]:
    """Rows (payload kg, model, n, position mean / p95 mm, orientation mean deg) of
    :func:`hykin.io.payload.errors_per_payload`; ``labels``: name -> the name shown."""
    rows = []
    for kg, row in (per_payload or {}).items():
        for name, d in row.items():
            rows.append([f"{kg:g}", (labels or {}).get(name, name), d["n"], d["pos_mean_mm"], d["pos_p95_mm"], d.get("rot_mean_deg")])
    return rows


PAYLOAD_HEADER = ["payload [kg]", "model", "n", "position mean [mm]", "position p95 [mm]", "orientation mean [deg]"]


def per_temperature_rows(temp_c, errors: dict, n_bins: int = 4, labels: dict | None = None) -> list[list]:
    """Rows (temperature range °C, model, n, position mean / p95 mm, orientation mean deg) over
    ``n_bins`` equal-count temperature bins; empty when the temperature does not vary."""
    if temp_c is None:
        return []
    t = np.asarray(temp_c, float)
    if np.ptp(t) <= 0:
        return []
    edges = np.unique(np.quantile(t, np.linspace(0, 1, n_bins + 1)))
    k = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, len(edges) - 2)
    rows = []
    dec = max(1, int(np.ceil(-np.log10(np.min(np.diff(edges))))) + 1)  # enough decimals to tell the bins apart
    for b in range(len(edges) - 1):
        sel = k == b
        if not sel.any():
            continue
        for name, (p, a) in errors.items():
            rows.append([f"{edges[b]:.{dec}f} … {edges[b + 1]:.{dec}f}", (labels or {}).get(name, name), int(sel.sum()), float(p[sel].mean()),
                         float(np.percentile(p[sel], 95)), None if a is None else float(a[sel].mean())])
    return rows


TEMPERATURE_HEADER = ["temperature [°C]", "model", "n", "position mean [mm]", "position p95 [mm]", "orientation mean [deg]"]
