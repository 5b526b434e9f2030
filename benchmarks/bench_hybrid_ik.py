"""Hybrid inverse kinematics on rx160-virtual (paper Table IV): ours vs Wang et al. (2019).

Round trip: random joints -> hybrid FK -> IK -> hybrid FK, errors against the target.

* Model: a :class:`hykin.hybrid.model.HybridModel` trained here on ``--train`` noise-free simulated samples (default
  recipe), or loaded with ``--model PATH``; ``--standin`` (or no ``hykin.hybrid`` available) uses the
  simulator's ground truth as a perfect "hybrid" model (classical = calibrated RX160, correction =
  joint compliance under gravity, 1.8 mm / 0.17° on average), which tests the IK, not the nets.
* Rows: hybrid IK (all branches, and the nearest solution to the true joints), Wang et al.
  (classical IK -> hybrid FK -> compensated target -> classical IK), and the classical IK of the
  calibrated robot alone (no hybrid correction), all on the same targets in the same run.
* Branch count: distinct hybrid solutions for the first 1,000 targets vs closed-form solutions of the
  nominal robot. Speed: wall time per target and per target x branch (amortised, this machine).

Usage: ``python benchmarks/bench_hybrid_ik.py [-n 5000] [--train 10000] [--model M] [--standin]``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), ".."))

from hykin.geometry import se3
from hykin.hybrid.ik import hybrid_ik, wang_ik
from hykin.hybrid.ik_seeds import classical_seeds, seed_robot_of
from hykin.kinematics.ik import ik_closed_form
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate, true_poses


class TruthModel:
    """The virtual robot's ground truth dressed as a hybrid model (perfect residual)."""

    def __init__(self, vr):
        self.vr, self.robot, self.nominal = vr, vr.nominal, vr.nominal

    def predict(self, q):
        return true_poses(self.vr, np.asarray(q, dtype=np.float64))

    def predict_classical(self, q):
        from hykin.kinematics.compliance import compliant_fk

        return compliant_fk(self.robot, q)

    def predict_torch(self, q):
        from hykin.kinematics.compliance import compliant_fk_torch

        return compliant_fk_torch(self.vr.truth, q)


def build_model(args, vr):
    if args.model:
        from hykin.hybrid.model import HybridModel

        return HybridModel.load(args.model), f"HybridModel loaded from {args.model}"
    if not args.standin:
        try:
            from hykin.hybrid.model import HybridModel
        except ImportError:
            print("hykin.hybrid not available: using the ground-truth stand-in", flush=True)
        else:
            import torch

            from hykin.hybrid.model import HybridModel

            torch.set_num_threads(1)  # small nets, busy 2-core machine: one thread trains fastest
            rng = np.random.default_rng(1)
            tr = simulate(vr, vr.nominal.random_joints(args.train, rng), noise=False)
            va = simulate(vr, vr.nominal.random_joints(max(args.train // 10, 500), rng), noise=False)
            t = time.perf_counter()
            model = HybridModel(vr.nominal, calibrate=not args.no_calibrate).fit(tr, val=va, progress=False)
            m = model.meta_.get("metrics", {}).get("val", {})
            return model, (f"HybridModel (default recipe{', no calibration' if args.no_calibrate else ''}) trained on "
                           f"{args.train} samples in {time.perf_counter() - t:.0f} s; validation: classical "
                           f"{m.get('classical_pos_mean_mm', float('nan')):.3g} mm -> hybrid "
                           f"{m.get('hybrid_pos_mean_mm', float('nan')):.3g} mm")
    return TruthModel(vr), "ground truth stand-in (perfect residual model)"


def summarise(name, pe, ae, solved, n_targets, t_s, n_rows):
    ok = np.isfinite(pe)
    return dict(
        method=name, pos_mean=np.mean(pe[ok]), pos_max=np.max(pe[ok]), ang_mean=np.mean(ae[ok]),
        ang_max=np.max(ae[ok]), success=solved / n_targets, ms_target=1e3 * t_s / n_targets,
        ms_row=1e3 * t_s / max(n_rows, 1),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=5000, help="random joint configurations (targets)")
    ap.add_argument("--train", type=int, default=10000, help="training samples for the HybridModel")
    ap.add_argument("--model", default=None, help="load a trained model instead of training")
    ap.add_argument("--standin", action="store_true", help="use the ground truth as the hybrid model")
    ap.add_argument("--no-calibrate", action="store_true",
                    help="train without parametric calibration: the nets learn the whole 1.8 mm (paper setting)")
    ap.add_argument("--count", type=int, default=1000, help="targets for the branch-count check")
    args = ap.parse_args()
    warnings.simplefilter("ignore")  # out-of-range warnings of predict: in_support is reported instead

    vr = virtual_preset("rx160-virtual")
    model, how = build_model(args, vr)
    print(f"model: {how}")
    robot = model.robot
    rng = np.random.default_rng(2024)
    q_true = robot.random_joints(args.n, rng)
    T = model.predict(q_true)

    # warm-up (numba / torch first calls) on a few targets, not timed
    hybrid_ik(model, T[:8])
    wang_ik(model, T[:8])

    t = time.perf_counter()
    q0, lab, ok0 = classical_seeds(robot, T, seed_robot=seed_robot_of(model, None))
    t_cls = time.perf_counter() - t
    n_seeded = int(np.all(np.isfinite(q0), axis=2).sum())

    t = time.perf_counter()
    res = hybrid_ik(model, T)
    t_ours = time.perf_counter() - t
    s = res.success
    Tq = model.predict(res.q[s])
    pe, ae = se3.pose_error(Tq, T[res.target[s]])  # independent re-check of the reported errors

    t = time.perf_counter()
    near = hybrid_ik(model, T, nearest=True, q_current=q_true)
    t_near = time.perf_counter() - t
    pn, an = se3.pose_error(model.predict(near.q[near.success]), T[near.target[near.success]])
    from hykin.kinematics.ik import nearest_representation

    qn = nearest_representation(near.q[near.success], q_true[near.target[near.success]], robot.lower, robot.upper)
    recovered = np.abs(qn - q_true[near.target[near.success]]).max(1) < 1e-6

    t = time.perf_counter()
    w = wang_ik(model, T)
    t_wang = time.perf_counter() - t
    fin = np.all(np.isfinite(w.q), axis=1)
    pw, aw = se3.pose_error(model.predict(w.q[fin]), T[w.target[fin]])

    fin0 = np.all(np.isfinite(q0), axis=2) & ok0
    qc = q0[fin0]
    pc, ac = se3.pose_error(model.predict(qc), np.repeat(T[:, None], q0.shape[1], 1)[fin0])

    rows = [
        summarise("hybrid IK, all branches (ours)", pe, ae, res.solved_targets.sum(), args.n, t_ours, n_seeded),
        summarise("hybrid IK, nearest (ours)", pn, an, near.solved_targets.sum(), args.n, t_near, n_seeded),
        summarise("Wang et al. 2019", pw, aw, np.unique(w.target[fin]).size, args.n, t_wang, n_seeded),
        summarise("classical IK only (rigid, no corr)", pc, ac, np.unique(np.nonzero(fin0)[0]).size, args.n, t_cls,
                  n_seeded),
    ]
    print(f"\nrx160-virtual, {args.n} random joint configurations: hybrid FK -> IK -> hybrid FK "
          f"({n_seeded} target x branch rows; errors over every returned solution)")
    hdr = f"{'method':34s} {'pos mean mm':>12s} {'pos max mm':>11s} {'ang mean deg':>13s} {'ang max deg':>12s} " \
          f"{'targets ok':>10s} {'ms/target':>9s} {'ms/t·br':>8s}"
    print(hdr)
    print("-" * len(hdr))
    for r in rows:
        print(f"{r['method']:34s} {r['pos_mean']:12.3e} {r['pos_max']:11.3e} {r['ang_mean']:13.3e} {r['ang_max']:12.3e} "
              f"{100 * r['success']:9.2f}% {r['ms_target']:9.3f} {r['ms_row']:8.4f}")
    print(f"{'paper Table IV: ours':34s} {6.0e-6:12.3e} {'':>11s} {4.9e-4:13.3e}")
    print(f"{'paper Table IV: Wang et al.':34s} {4.52:12.3e} {'':>11s} {0.397:13.3e}")
    print(f"\nratio Wang / ours (mean): position {rows[2]['pos_mean'] / max(rows[0]['pos_mean'], 1e-30):.3g}x, "
          f"orientation {rows[2]['ang_mean'] / max(rows[0]['ang_mean'], 1e-30):.3g}x")
    print(f"true joints recovered by the nearest solution: {100 * recovered.mean():.2f}% "
          f"({recovered.size} targets solved of {args.n})")
    print(f"solver iterations (ours): median {np.median(res.iterations[s]):.0f}, "
          f"p99 {np.percentile(res.iterations[s], 99):.0f}, max {res.iterations[s].max()}")

    k = min(args.count, args.n)
    n_nom = ik_closed_form(vr.nominal, T[:k]).n_solutions
    sub = s & (res.target < k)
    n_found = np.bincount(res.target[sub], minlength=k)
    print(f"\nbranch count, first {k} targets: hybrid IK found {n_found.sum()} distinct solutions, closed form on "
          f"the nominal robot {n_nom.sum()}; targets differing: {(n_found != n_nom).sum()} "
          f"(more: {(n_found > n_nom).sum()}, fewer: {(n_found < n_nom).sum()})")
    if (n_found != n_nom).any():
        from hykin.kinematics.fk import jacobian

        d = n_found != n_nom
        sv = np.linalg.svd(jacobian(robot, q_true[:k]), compute_uv=False)[:, -1]
        print(f"  smallest Jacobian singular value at the true joints: differing targets median {np.median(sv[d]):.3g}, "
              f"all targets median {np.median(sv):.3g} (differences: joint limits, singularities, workspace edges)")
    fails = res.reason[~s]
    if fails.size:
        kinds, counts = np.unique([r.split(":")[0] for r in fails], return_counts=True)
        print("unsolved targets: " + "; ".join(f"{c} x {k_}" for k_, c in zip(kinds, counts)))


if __name__ == "__main__":
    main()
