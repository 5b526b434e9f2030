"""Benchmark of ``hykin plan`` (issue #17) on a virtual industrial robot of our own.

The robot ("bench-6r", not a shipped preset): a 6R arm with its own DH table, link masses and
payload; the truth has geometric deviations (σ 0.3 mm, 0.03°, base/tool frame errors), joint
compliance under gravity (k = 4e5, 3e5, 2e5, 3e4, 2e4, 2e4 N·m/rad), periodic transmission errors
(orders 1-3 on every joint), a mass model off by 5 % / 1 cm, and tracker noise 10 µm / 50 µrad.

Measured in the same run, same joint region, same fit recipe, one common noise-free test set of
uniform random poses in the region:

1. hybrid (calibration + networks) fitted on 1,000 planned poses vs on 1,000 uniform random poses:
   ratio of mean position errors (target ≤ 0.75);
2. calibration alone from 60 planned poses vs from 10,000 uniform random poses (target ≤ 1.15);
3. forecast validation: predicted (``hykin.planning.forecast``) vs measured mean position error of
   the calibrated model at several N, and of the hybrid at 1,000;
4. ``--active``: active selection (``hykin plan --for-model``): a model fitted on 400 poses (uniform
   over the region, or over the lower 60 % of joint 1's range only) gets 200 more poses chosen by
   ``active_poses``, by a fresh passive plan, or uniformly at random; the refitted hybrids' errors;
5. ``--curve``: the networks' learning curve (hybrid / calibrated error at N = 250 ... 2000 planned
   poses) and its power-law fit (the constants of ``hykin.planning.forecast``), on robot seed 100
   (the report in 1-3 uses other seeds).

1. also says where the hybrid's error is: its calibrated part, the share of test poses where the
networks fade (weight < 0.999) and the error there, and the error near the ends of the bounded joint
ranges (within 5 %) vs the interior.

``--robot ur-like``: a second, different 6R arm (:func:`bench_robot`) as a held-out check; the
planner's settings were decided on bench-6r (robot seed 2, docs/planning.md).

Run: ``PYTHONPATH=. python benchmarks/bench_plan.py [--seeds 0 1] [--min-steps 10000] [--robot ur-like]
[--hybrid-only] [--curve] [--active [--no-main]]``.
Timings are wall-clock on a shared machine and are not the point of this benchmark.
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from hykin.calibration.calibrate import (
    apply_deviations,
    calibrate,
    calibrated_fk,
    parameter_names,
)
from hykin.hybrid.model import HybridModel
from hykin.kinematics.robot import Robot
from hykin.io.dataset import concat
from hykin.planning import Constraints, active_poses, plan_poses
from hykin.planning.forecast import forecast_accuracy
from hykin.sim.sampling import random as random_joints
from hykin.sim.simulate import PeriodicError, VirtualRobot, simulate, true_poses

DEG = np.pi / 180


def bench_robot(seed: int = 0, geometry: str = "bench-6r") -> VirtualRobot:
    """The benchmark's own virtual industrial robot (module docstring).

    geometry: ``"bench-6r"`` (the robot of the report) or ``"ur-like"``, a held-out check of a
    different 6R arm (parallel shoulder/elbow/wrist-1 axes as on a UR, shorter links, 5-10x lighter
    links, softer joints, 3 kg payload, transmission orders 1, 2 and 4): settings of ``hykin plan``
    are not decided on it."""
    if geometry == "bench-6r":
        nominal = Robot(
            name="bench-6r", convention="dh",
            a_m=np.array([0.20, 0.70, 0.12, 0.0, 0.0, 0.0]),
            alpha_rad=np.array([-90, 0, -90, 90, -90, 0]) * DEG,
            d_m=np.array([0.48, 0.0, 0.0, 0.72, 0.0, 0.13]),
            theta_rad=np.array([0, -90, 0, 0, 0, 0]) * DEG,
            lower=np.array([-170, -95, -140, -200, -120, -270]) * DEG,
            upper=np.array([170, 150, 70, 200, 120, 270]) * DEG,
            mass_kg=np.array([55.0, 38.0, 24.0, 9.0, 3.5, 1.2]),
            com_m=np.array([[-0.1, 0.0, 0.05], [-0.35, 0.0, 0.12], [-0.03, 0.02, 0.0], [0.0, -0.1, 0.0],
                            [0.0, 0.0, 0.02], [0.0, 0.0, -0.02]]),
            payload_kg=15.0,
        )
        nominal = nominal.copy(tool=np.array([[1, 0, 0, 0.04], [0, 1, 0, 0.0], [0, 0, 1, 0.16], [0, 0, 0, 1.0]]))
        stiffness = np.array([4e5, 3e5, 2e5, 3e4, 2e4, 2e4])
        harmonics = ((1, 1.2e-4), (2, 6e-5), (3, 3e-5))
    elif geometry == "ur-like":
        nominal = Robot(
            name="ur-like", convention="dh",
            a_m=np.array([0.0, -0.425, -0.392, 0.0, 0.0, 0.0]),
            alpha_rad=np.array([90, 0, 0, 90, -90, 0]) * DEG,
            d_m=np.array([0.163, 0.0, 0.0, 0.134, 0.100, 0.100]),
            theta_rad=np.zeros(6),
            lower=np.full(6, -360.0) * DEG,
            upper=np.full(6, 360.0) * DEG,
            mass_kg=np.array([3.7, 8.4, 2.3, 1.2, 1.2, 0.25]),
            com_m=np.array([[0.0, -0.02, 0.0], [0.21, 0.0, 0.12], [0.19, 0.0, 0.01], [0.0, 0.0, 0.0],
                            [0.0, 0.0, 0.0], [0.0, 0.0, -0.02]]),
            payload_kg=3.0,
        )
        nominal = nominal.copy(tool=np.array([[1, 0, 0, 0.0], [0, 1, 0, 0.03], [0, 0, 1, 0.12], [0, 0, 0, 1.0]]))
        stiffness = np.array([6e4, 5e4, 3e4, 8e3, 6e3, 6e3])
        harmonics = ((1, 9e-5), (2, 5e-5), (4, 2e-5))
    else:
        raise ValueError(f"unknown geometry {geometry!r}")
    rng = np.random.default_rng([seed, 6, 17])
    names = parameter_names(nominal, compliance=False)
    dev = {}
    for nm in names:
        length = nm.split(".")[-1] in ("x", "y", "z") or nm[0] in "ad" and nm[:5] != "alpha"
        frame = "." in nm
        sig = (5e-4 if frame else 3e-4) if length else (0.05 if frame else 0.03) * DEG
        dev[nm] = float(rng.normal(0, sig))
    truth = apply_deviations(nominal, dev)
    truth = truth.copy(
        stiffness_nm_per_rad=stiffness,
        mass_kg=nominal.mass_kg * np.clip(1 + rng.normal(0, 0.05, 6), 0.5, 1.5),
        com_m=nominal.com_m + rng.normal(0, 0.01, (6, 3)),
        payload_kg=nominal.payload_kg * float(np.clip(1 + rng.normal(0, 0.05), 0.5, 1.5)),
        name=f"{geometry}-truth",
    )
    trans = []
    for j in range(1, 7):
        for order, amp in harmonics:
            trans.append(PeriodicError(j, float(amp * rng.uniform(0.7, 1.3)), float(order), 1.0, float(rng.uniform(0, 2 * np.pi))))
    return VirtualRobot(name=geometry, nominal=nominal, truth=truth, transmission=trans, noise_position_m=10e-6,
                        noise_orientation_rad=50e-6, seed=seed, description="issue #17 benchmark robot")


REGIONS_DEG = {
    "bench-6r": np.array([[-120, 120], [-60, 110], [-120, 50], [-180, 180], [-100, 100], [-180, 180]]),
    "ur-like": np.array([[-150, 150], [-160, -20], [-150, 150], [-180, 180], [-120, 120], [-180, 180]]),
}
REGION_DEG = REGIONS_DEG["bench-6r"]


def pos_err_mm(T_pred: np.ndarray, T_true: np.ndarray) -> float:
    return float(np.linalg.norm(T_pred[:, :3, 3] - T_true[:, :3, 3], axis=1).mean() * 1e3)


def fit_hybrid(vr, q, rng_noise, min_steps, seed):
    ds = simulate(vr, q, rng=rng_noise)
    m = HybridModel(vr.nominal, recipe_kw=None if min_steps is None else {"min_steps": min_steps}, seed=seed)
    m.fit(ds, progress=False)
    return m


def run(seed: int, min_steps, lo, hi, log, geometry: str = "bench-6r", hybrid_only: bool = False) -> dict:
    vr = bench_robot(seed, geometry)
    rob = vr.nominal
    c = Constraints(lower=lo, upper=hi)
    q_test = random_joints(rob, 4000, np.random.default_rng([seed, 99]), lower=lo, upper=hi)
    T_test = true_poses(vr, q_test)
    out = {"seed": seed}
    t0 = time.perf_counter()
    plan = plan_poses(rob, 1000, c, seed=seed, position_only=False)
    plan60 = plan_poses(rob, 60, c, seed=seed, position_only=False)
    out["plan_s"] = time.perf_counter() - t0
    q_rand = random_joints(rob, 1000, np.random.default_rng([seed, 3]), lower=lo, upper=hi)
    q_rand10k = random_joints(rob, 10_000, np.random.default_rng([seed, 4]), lower=lo, upper=hi)
    if hybrid_only:
        out["cal_ratio_60_vs_10k"] = float("nan")
        return _run_hybrid(vr, seed, min_steps, q_test, T_test, plan, q_rand, out, log)
    log(f"[seed {seed}] plan 1000 + 60 poses: {out['plan_s']:.1f} s; core {plan.info['core_size']} of "
        f"{plan.info['n_params']} parameters; path {plan.travel['joint_rad']:.0f} rad, {plan.travel['move_s'] / 60:.0f} min moves")
    # 2. calibration only
    cal = {}
    for name, q in (("planned60", plan60.q), ("random10k", q_rand10k), ("random60", q_rand10k[:60]),
                    ("planned1000", plan.q), ("random1000", q_rand)):
        ds = simulate(vr, q, rng=np.random.default_rng([seed, 5, len(q)]))
        res = calibrate(rob, ds)
        cal[name] = pos_err_mm(calibrated_fk(res.robot, q_test), T_test)
    out["cal"] = cal
    out["cal_ratio_60_vs_10k"] = cal["planned60"] / cal["random10k"]
    log(f"[seed {seed}] calibration mean position error on test: " + ", ".join(f"{k} {v:.4f} mm" for k, v in cal.items())
        + f"; planned60/random10k = {out['cal_ratio_60_vs_10k']:.3f}")
    # 3. forecast of the calibrated model (unmodelled error = what the 10k calibration leaves)
    nested = plan.nested()
    ns = [60, 250, 1000]
    pred = forecast_accuracy(plan.id_model, nested, q_test[:2000], ns, noise_mm=0.01,
                             unmodelled_mm=cal["random10k"] / 0.921)
    meas = []
    for n in ns:
        ds = simulate(vr, nested[:n], rng=np.random.default_rng([seed, 8, n]))
        res = calibrate(rob, ds)
        meas.append(pos_err_mm(calibrated_fk(res.robot, q_test), T_test))
    out["forecast_cal"] = {"n": ns, "predicted_mm": pred.calibrated_mm.tolist(), "measured_mm": meas}
    log(f"[seed {seed}] forecast (calibrated, nested planned prefixes): "
        + ", ".join(f"N={n}: predicted {p:.4f} / measured {m:.4f} mm" for n, p, m in zip(ns, pred.calibrated_mm, meas)))
    out = _run_hybrid(vr, seed, min_steps, q_test, T_test, plan, q_rand, out, log)
    out["hybrid_forecast_mm"] = float(forecast_accuracy(plan.id_model, nested, q_test[:2000], [1000], noise_mm=0.01,
                                                        unmodelled_mm=cal["random10k"] / 0.921).hybrid_mm[0])
    log(f"[seed {seed}] forecast for the hybrid on 1000 planned poses: {out['hybrid_forecast_mm']:.4f} mm")
    return out


def _run_hybrid(vr, seed, min_steps, q_test, T_test, plan, q_rand, out, log) -> dict:
    """1. hybrid on 1000 planned vs 1000 random poses, with where the error comes from: the calibrated
    part, the share of test poses where the networks fade (outside their support), the error on the
    test poses within 5 % of an edge of a bounded joint range vs the interior."""
    lo, hi = plan.lower, plan.upper
    u = (q_test - lo) / (hi - lo)
    bounded = (hi - lo) < 2 * np.pi - 1e-9
    edge = np.any((np.minimum(u, 1 - u) < 0.05) & bounded, axis=1)
    hy = {}
    for name, q in (("planned", plan.q), ("random", q_rand)):
        t1 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = fit_hybrid(vr, q, np.random.default_rng([seed, 6]), min_steps, seed)
            e = np.linalg.norm(m.predict(q_test)[:, :3, 3] - T_test[:, :3, 3], axis=1) * 1e3
            hy[name] = float(e.mean())
            hy[name + "_calibrated"] = pos_err_mm(m.predict_classical(q_test), T_test)
            faded = m.fade_weight(q_test) < 0.999
            hy[name + "_faded_pct"] = float(100 * np.mean(faded))
            hy[name + "_faded_mm"] = float(e[faded].mean()) if faded.any() else float("nan")
            hy[name + "_edge_mm"], hy[name + "_interior_mm"] = float(e[edge].mean()), float(e[~edge].mean())
        hy[name + "_s"] = time.perf_counter() - t1
    out["hybrid"] = hy
    out["hybrid_ratio"] = hy["planned"] / hy["random"]
    for name in ("planned", "random"):
        log(f"[seed {seed}] hybrid on 1000 {name}: {hy[name]:.4f} mm (calibrated part {hy[name + '_calibrated']:.4f}; "
            f"faded on {hy[name + '_faded_pct']:.1f} % of the test poses, {hy[name + '_faded_mm']:.4f} mm there; "
            f"edge ({100 * edge.mean():.0f} % of test) {hy[name + '_edge_mm']:.4f}, interior {hy[name + '_interior_mm']:.4f} mm)"
            f" [fit {hy[name + '_s']:.0f} s]")
    log(f"[seed {seed}] hybrid planned / random = {out['hybrid_ratio']:.3f}")
    return out


def learning_curve(min_steps, lo, hi, log, seed: int = 100, ns=(250, 500, 1000, 2000)) -> tuple[float, float]:
    vr = bench_robot(seed)
    rob = vr.nominal
    q_test = random_joints(rob, 3000, np.random.default_rng([seed, 99]), lower=lo, upper=hi)
    T_test = true_poses(vr, q_test)
    plan = plan_poses(rob, max(ns), Constraints(lower=lo, upper=hi), seed=seed, position_only=False)
    nested = plan.nested()
    ratios, errs = [], []
    for n in ns:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = fit_hybrid(vr, nested[:n], np.random.default_rng([seed, 6, n]), min_steps, 0)
            h, cl = pos_err_mm(m.predict(q_test), T_test), pos_err_mm(m.predict_classical(q_test), T_test)
        ratios.append(h / cl)
        errs.append(h)
        log(f"[curve seed {seed}] N={n}: hybrid {h:.4f} mm, calibrated {cl:.4f} mm, ratio {h / cl:.3f}")
    b, loga = np.polyfit(np.log(ns), np.log(ratios), 1)
    log(f"[curve] power law ratio = {np.exp(loga):.3f} * N^{b:.3f}")
    b, loga = np.polyfit(np.log(ns), np.log(errs), 1)
    log(f"[curve] power law hybrid error = {np.exp(loga):.4f} mm * N^{b:.3f} (hykin.planning.forecast.LEARNING_A/B)")
    return float(np.exp(loga)), float(-b)


def active_vs_passive(seed: int, min_steps, lo, hi, log, geometry: str = "bench-6r", n0: int = 400, n_add: int = 200) -> dict:
    """4. Which ``n_add`` poses improve a fitted model most: ``active_poses`` (``--for-model``), a
    passive plan of the region, or uniform random poses. Two starts: ``n0`` uniform poses of the
    region, and ``n0`` poses with joint 1 in the lower 60 % of its range only (a model to extend).
    Every refit sees the same first ``n0`` measurements (same noise) plus the added ones."""
    vr = bench_robot(seed, geometry)
    rob = vr.nominal
    c = Constraints(lower=lo, upper=hi)
    q_test = random_joints(rob, 4000, np.random.default_rng([seed, 99]), lower=lo, upper=hi)
    T_test = true_poses(vr, q_test)
    hi_part = hi.copy()
    hi_part[0] = lo[0] + 0.6 * (hi[0] - lo[0])
    out = {}

    def fit_err(ds):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            m = HybridModel(rob, recipe_kw=None if min_steps is None else {"min_steps": min_steps}, seed=seed).fit(ds, progress=False)
            return m, pos_err_mm(m.predict(q_test), T_test)

    for start, upper in (("uniform", hi), ("joint 1 in lower 60 %", hi_part)):
        q0 = random_joints(rob, n0, np.random.default_rng([seed, 21]), lower=lo, upper=upper)
        d0 = simulate(vr, q0, rng=np.random.default_rng([seed, 22]))
        m0, e0 = fit_err(d0)
        adds = {"active (--for-model)": active_poses(m0, n_add, c, seed=seed).q,
                "passive plan": plan_poses(rob, n_add, c, seed=seed + 1, position_only=False).q,
                "uniform random": random_joints(rob, n_add, np.random.default_rng([seed, 23]), lower=lo, upper=hi)}
        res = {"start": e0}
        for name, qa in adds.items():
            da = simulate(vr, qa, rng=np.random.default_rng([seed, 24]))
            res[name] = fit_err(concat([d0, da]))[1]
        out[start] = res
        log(f"[seed {seed}] start {start} ({n0} poses): {e0:.4f} mm; + {n_add}: " + ", ".join(
            f"{k} {v:.4f} mm" for k, v in res.items() if k != "start")
            + f"; active / random = {res['active (--for-model)'] / res['uniform random']:.3f}")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--min-steps", type=int, default=None, help="network training steps (default: the default recipe)")
    ap.add_argument("--curve", action="store_true", help="measure the learning curve (robot seed 100)")
    ap.add_argument("--no-main", action="store_true", help="skip the planned-vs-random comparison")
    ap.add_argument("--robot", default="bench-6r", choices=sorted(REGIONS_DEG), help="robot geometry (ur-like: held-out check)")
    ap.add_argument("--hybrid-only", action="store_true", help="only the hybrid comparison (1.; faster)")
    ap.add_argument("--active", action="store_true", help="active selection vs passive additions (4.)")
    a = ap.parse_args()
    region = REGIONS_DEG[a.robot]
    lo, hi = region[:, 0] * DEG, region[:, 1] * DEG
    log = lambda s: print(s, flush=True)
    log(f"bench_plan: robot {a.robot} (own DH, compliance, transmission errors), region {region.tolist()} deg, "
        f"recipe default{'' if a.min_steps is None else f' with min_steps={a.min_steps}'}")
    if a.curve:
        learning_curve(a.min_steps, lo, hi, log)
    if a.active:
        ratios = []
        for sd in a.seeds:
            r = active_vs_passive(sd, a.min_steps, lo, hi, log, a.robot)
            ratios += [v["active (--for-model)"] / v["uniform random"] for v in r.values()]
        log(f"SUMMARY active / random additions: {', '.join(f'{x:.3f}' for x in ratios)}")
    if a.no_main:
        return
    res = [run(s, a.min_steps, lo, hi, log, a.robot, a.hybrid_only) for s in a.seeds]
    hr = [r["hybrid_ratio"] for r in res]
    cr = [r["cal_ratio_60_vs_10k"] for r in res]
    log(f"SUMMARY hybrid 1000 planned / 1000 random: {', '.join(f'{x:.3f}' for x in hr)} (mean {np.mean(hr):.3f}; target <= 0.75)")
    log(f"SUMMARY calibration 60 planned / 10000 random: {', '.join(f'{x:.3f}' for x in cr)} (mean {np.mean(cr):.3f}; target <= 1.15)")


if __name__ == "__main__":
    main()
