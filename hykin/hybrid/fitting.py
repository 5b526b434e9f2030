"""Steps of :meth:`hykin.hybrid.model.HybridModel.fit` as functions over data: residual targets,
the training/validation split of the networks, their input range and their training."""

from __future__ import annotations

import math
import time

import numpy as np
import torch

from ..geometry import se3
from ..io.fingerprint import file_fingerprint
from ..io.payload import payload_kwargs, payload_of
from ..kinematics.classical import classical_fk
from .inputs import TWO_PI, to_net_frame
from .nets import count_parameters, make_net
from .persistence import data_hash, json_safe, versions
from .progress import Progress
from .train import train_net

__all__ = ["calibrate_on", "error_metrics", "input_range", "residual_targets", "split_validation", "train_networks",
           "predictions", "train_metrics", "training_metadata", "without_outliers"]


def residual_targets(robot, ds) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """Residual targets of Dataset ``ds`` against the classical model of ``robot`` (its payloads):
    position ``(N, 3)`` m, rotation vector ``(N, 3)`` rad (None without orientations) and the
    classical poses ``(N, 4, 4)``."""
    T_hat = classical_fk(robot, ds.q, **payload_kwargs(payload_of(ds)))
    dp = ds.xyz_m - T_hat[:, :3, 3]
    dr = None
    if ds.has_orientation:
        dr = se3.rotation_difference_rotvec(ds.rotations() if hasattr(ds, "rotations") else ds.poses()[:, :3, :3],
                                            T_hat[:, :3, :3])
    return dp, dr, T_hat


def split_validation(q, dp, dr, kg_all, val, *, robot, seed: int, val_fraction: float, j1_axis) -> dict:
    """Training and validation rows of the networks.

    ``q`` ``(N, n)``, ``dp``/``dr`` ``(N, 3)`` (network frame; ``dr`` may be None), ``kg_all`` ``(N,)``:
    the training set; ``val``: validation Dataset or None; ``robot``: calibrated robot (targets of
    ``val``; its payload is the default). Returns ``qt``/``qv``, ``dpt``/``drt``, ``dpv``/``drv``,
    ``kt``/``kv`` and either ``iv``/``iv_cal`` (held-out rows of the training set, the second half
    calibrating the bands) or ``val_cal``/``cal_rows`` (half of ``val``).

    The validation data are split in two: one half selects the best epoch, the other calibrates
    the uncertainty bands. Calibrating on the half that picked the epoch would make the bands
    too narrow: the selected epoch is the one that happens to fit those samples best (virtual
    in-range coverage 88.5 % instead of 95 % at 30000 steps)."""
    rng = np.random.default_rng(seed)
    out = {"iv": None, "iv_cal": None, "val_cal": None, "cal_rows": None}
    if val is None:
        perm = rng.permutation(len(q))
        nv = round(val_fraction * len(q)) if len(q) >= 20 else 0
        iv, it = perm[:nv], perm[nv:]
        if nv >= 40:
            iv, out["iv_cal"] = iv[: nv // 2], iv[nv // 2 :]
        out.update(iv=iv, qv=q[iv], dpv=dp[iv], drv=None if dr is None else dr[iv], qt=q[it], dpt=dp[it],
                   drt=None if dr is None else dr[it], kv=kg_all[iv], kt=kg_all[it])
        return out
    val_sel = val
    if len(val) >= 40:
        pv = rng.permutation(len(val))
        out["cal_rows"] = np.sort(pv[len(val) // 2 :])
        val_sel, out["val_cal"] = val.subset(np.sort(pv[: len(val) // 2])), val.subset(out["cal_rows"])
    qv = np.asarray(val_sel.q, dtype=np.float64)
    pl_v = payload_of(val_sel)
    dpv, drv, _ = residual_targets(robot, val_sel)  # drv None for position-only val data
    out.update(qt=q, dpt=dp, drt=dr, kt=kg_all, qv=qv, kv=np.full(len(qv), robot.payload_kg) if pl_v is None else pl_v[0],
               dpv=to_net_frame(j1_axis, qv, dpv), drv=None if drv is None else to_net_frame(j1_axis, qv, drv))
    return out


def input_range(normalise: str, lo_d: np.ndarray, hi_d: np.ndarray, robot, netq, wrap_centre: np.ndarray):
    """Range ``(lo, hi)`` (each ``(n,)``) the networks normalise their joint inputs by: the data range
    ``lo_d``/``hi_d`` (``normalise="data"``) or the joint limits of the nominal ``robot`` in network
    coordinates (``netq``), a full turn around the wrap centre for joints with a full-turn range."""
    if normalise == "data":
        return lo_d, hi_d
    lo_n, hi_n = netq(robot.lower[None])[0], netq(robot.upper[None])[0]
    lo_n, hi_n = np.minimum(lo_n, hi_n), np.maximum(lo_n, hi_n)
    full = np.isfinite(wrap_centre) & (robot.upper - robot.lower >= TWO_PI - 1e-9)
    lo_n = np.where(full, wrap_centre - math.pi, lo_n)
    hi_n = np.where(full, wrap_centre + math.pi, hi_n)
    return lo_n, hi_n


def train_networks(targets: dict, Xt, Xv, *, arch: str, n_in: int, in_lower, in_upper, recipe, seed: int,
                   device: str, max_seconds, progress: bool) -> tuple[dict, dict, dict]:
    """Train one residual network per entry of ``targets`` (key ``"pos"``/``"rot"`` -> ``(yt (N, 3),
    yv (M, 3) or None)``; a None ``yt`` is skipped) on inputs ``Xt`` ``(N, n_in)``, validated on ``Xv``
    (``(M, n_in)`` or None). Inputs are normalised by ``in_lower``/``in_upper`` ``(n_in,)``. Torch seed
    ``seed`` (+1 for ``"rot"``). ``max_seconds``: for all networks together (each gets an even share of
    what is left when it starts). Returns ``(nets, results, timings)`` keyed by network."""
    dt = torch.float64 if recipe.dtype == "float64" else torch.float32
    nets, results, timings = {}, {}, {}
    cb_ctx = Progress(progress)
    todo = [k for k, (yt, _) in targets.items() if yt is not None]
    t_end = None if max_seconds is None else time.perf_counter() + float(max_seconds)
    with cb_ctx:
        for key, (yt, yv) in targets.items():
            if yt is None:
                continue
            budget = None  # max_seconds is for all networks: each gets an even share of what is left
            if t_end is not None:
                budget = max(t_end - time.perf_counter(), 0.0) / (len(todo) - todo.index(key))
            torch.manual_seed(seed + (0 if key == "pos" else 1))
            net = make_net(arch, n_in, 3, dtype=dt)
            net.set_input_range(in_lower, in_upper)
            t1 = time.perf_counter()
            use_val = Xv is not None and yv is not None
            results[key] = train_net(net, Xt, yt, Xv if use_val else None, yv if use_val else None, recipe,
                                     seed=seed, device=device, max_seconds=budget, callback=cb_ctx.callback(key))
            cb_ctx.stage_done(f"training {key}", f"{results[key].steps:,} steps")
            cb_ctx.budget_cut(key, results[key])
            timings[f"train_{key}_s"] = time.perf_counter() - t1
            nets[key] = net
    return nets, results, timings


def error_metrics(ds, T_c: np.ndarray, T_h: np.ndarray) -> dict:
    """Mean/max position (mm) and orientation (deg) errors of classical ``T_c`` and hybrid ``T_h``
    poses ``(N, 4, 4)`` against Dataset ``ds``."""
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


def training_metadata(model, train, val, *, n_split: tuple[int, int, int], has_orientation: bool, timings: dict,
                      results: dict, calib) -> dict:
    """The training metadata ``meta_`` of a just fitted ``model`` (saved in the file): data hashes of
    ``train``/``val``, ``n_split`` = (training, validation, total) rows, timings, versions, per-network
    training results and sizes, calibration summary ``calib``; ``metrics`` filled in afterwards."""
    return {
        "data_hash": data_hash(train),
        "val_hash": data_hash(val) if val is not None else None,
        "train_file": file_fingerprint(getattr(train, "source", "")),
        "val_file": None if val is None else file_fingerprint(getattr(val, "source", "")),
        "n_train": n_split[0], "n_val": n_split[1], "n_total": n_split[2],
        "has_orientation": has_orientation,
        "seed": int(model.seed), "timings": timings, "versions": versions(),
        "train_results": {k: {kk: vv for kk, vv in v.to_dict().items() if kk != "history"} | {
            "history": v.history[-50:]} for k, v in results.items()},
        "params": {k: count_parameters(getattr(model, f"net_{k}_")) for k in results},
        "calibration": calib,
        "calibration_cv": None if model.calibration_cv_ is None else json_safe(model.calibration_cv_.to_dict()),
        "metrics": {},
        "inputs": {"periodic": model.periodic, "joint1": model.joint1},
        "thermal": None if model.thermal_ is None else model.thermal_.to_dict(),
    }


def without_outliers(calibration, train, q: np.ndarray, kg: np.ndarray):
    """``(train, q (N, dof), kg (N,))`` without the rows the calibration left out as outliers
    (:mod:`hykin.calibration.outliers`): the networks do not learn a lost beam either."""
    out = getattr(calibration, "outliers", None)
    if out is None or not out.dropped:
        return train, q, kg
    keep = np.setdiff1d(np.arange(len(q)), out.rows)
    return train.subset(keep), q[keep], kg[keep]


def calibrate_on(model, ds, progress: bool = False):
    """Set (and return) ``model.robot_`` and ``model.calibration_`` from ``ds``: calibrated (with
    region-blocked parameter selection when asked, an optional step), or the nominal robot.
    ``progress``: report the calibration as a stage (:mod:`hykin.hybrid.progress`)."""
    if model.calibrate:
        from ..calibration.calibrate import calibrate as _calibrate
        from .optional import optional_step

        kw = dict(model.calibrate_kw or {})
        if kw.pop("select", None) == "region-cv":  # parameter set by region-blocked validation
            from .region_cv import select_calibration

            model.calibration_cv_ = optional_step("region-blocked parameter selection", getattr(model, "_skipped", {}),
                                                  select_calibration, model.robot, ds, base_kw=kw)
            if model.calibration_cv_ is not None:
                kw.update(model.calibration_cv_.kwargs)
        prog = Progress(bool(progress))
        res = _calibrate(model.robot, ds, **{"progress": prog.calibration(len(ds.q)), **kw})
        prog.stage_done("calibration", f"{int(np.sum(res.identifiable))} parameters identified")
        model.robot_, model.calibration_ = res.robot, res
    else:
        model.robot_, model.calibration_ = model.robot.copy(), None
    return model.robot_, model.calibration_


def predictions(model, ds) -> tuple[np.ndarray, np.ndarray]:
    """``(T_classical, T_hybrid)`` ``(N, 4, 4)`` of a fitted ``model`` at the rows of ``ds`` (their temperature
    and payload columns), out-of-range warnings silenced (the metrics' own business)."""
    import warnings

    from ..calibration.thermal import temperature_of
    from ..io.payload import payload_kwargs, payload_of
    from .errors import OutOfRangeWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        t = temperature_of(ds)
        pkw = payload_kwargs(payload_of(ds))
        return model.predict_classical(ds.q, temperature_c=t, **pkw), model.predict(ds.q, temperature_c=t, **pkw)


def train_metrics(model, train) -> dict:
    """:func:`error_metrics` of the training rows, and an :class:`~hykin.calibration.outliers.OutlierWarning`
    naming training rows far off the fitted hybrid model (:func:`hykin.calibration.outliers.find_outliers`,
    the calibration's ``outliers`` / ``outlier_ratio``): a lost beam of 1 mm hides under a calibrated model
    that leaves 0.15 mm, not under a hybrid one that leaves 0.02 mm. Named only (they were trained on):
    measured on real data the hybrid's largest training row lay 4.6 (UR5 grid) and 9.9 (ipa series B)
    typical errors off, under the 12 of the test."""
    import warnings

    from ..calibration.outliers import DEFAULT_RATIO, OutlierWarning, find_outliers, row_errors

    T_c, T_h = predictions(model, train)
    metrics = error_metrics(train, T_c, T_h)
    kw = model.calibrate_kw or {}
    if not model.calibrate or kw.get("outliers", "drop") == "keep":
        return metrics
    found = find_outliers(*row_errors(T_h, train.xyz_m, train.poses()[:, :3, :3] if train.has_orientation else None,
                                      None), float(kw.get("outlier_ratio", DEFAULT_RATIO)))
    if found is not None and found.droppable:
        cal = getattr(model.calibration_, "outliers", None)
        if cal is not None and cal.dropped:  # row numbers of the file: the rows the calibration left out come back
            keep = np.setdiff1d(np.arange(cal.n_rows), cal.rows)
            found.rows, found.n_rows = keep[found.rows], cal.n_rows
        warnings.warn(OutlierWarning(found.message(
            getattr(train, "source", None) or None, "the fitted hybrid model",
            "lost beams that the calibrated model's larger error hid? They were trained on: leave them out of the "
            "file (hykin import table --where) and fit again")), stacklevel=2)
    return metrics
