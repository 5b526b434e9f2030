"""Training-region awareness of the hybrid model (issue 8): per-region errors, fade, uncertainty.

Real data (UR10, ipa-robot-accuracy): train on series A, register series B (tracker frame) from 30
spread poses, evaluate on the rest of B per joint region, for input representations
(``periodic`` x ``joint1``) and fade modes, against the calibrated model alone (registered on the
same 30 poses). Virtual (ur10-virtual / rx160-nongeo): train on a restricted working range, query
the full range. Coverage of the 95 % band of ``predict_uncertainty`` on held-out data.

    python benchmarks/bench_region.py ur10 [--variants wrap:input,none:input,...]
    python benchmarks/bench_region.py virtual [--preset rx160-nongeo] [--n 6000]
    python benchmarks/bench_region.py speed
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import numpy as np

from hykin.calibration.frames import fit_frames
from hykin.geometry import se3
from hykin.hybrid.model import HybridModel, OutOfRangeWarning
from hykin.measure.register import register_model

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "ipa-robot-accuracy"


def _err(T, ds):
    p, a = se3.pose_error(T, ds.poses())
    return p, a


def _row(name, mask, pc, ph, ac, ah, bands=None):
    n = int(mask.sum())
    if n == 0:
        return f"{name:<28} {0:>5}"
    s = (f"{name:<28} {n:>5} {pc[mask].mean():9.3f} {ph[mask].mean():9.3f} {ph[mask].mean() / pc[mask].mean():6.2f}"
         f" {ac[mask].mean():9.4f} {ah[mask].mean():9.4f}")
    if bands is not None:
        bp, ba = bands
        s += f" {np.mean(ph[mask] <= bp[mask]) * 100:6.1f} {np.mean(ah[mask] <= ba[mask]) * 100:6.1f}"
    return s


HEAD = (f"{'region':<28} {'n':>5} {'calib mm':>9} {'hybrid mm':>9} {'ratio':>6} {'calib deg':>9} {'hybr deg':>9}"
        f" {'cov95p':>6} {'cov95a':>6}")


def _overlap_series(m, A_te, n_reg, seed):
    """Series B does not overlap series A. The overlap case: A's held-out poses as a new series,
    seen by a tracker placed elsewhere (unknown rigid frame: 1.2 m, 25 deg) and registered from
    ``n_reg`` poses; calibrated model registered on the same poses; per joint-quartile region."""
    import dataclasses

    rng = np.random.default_rng(seed + 100)
    F = se3.xyzrpy_to_transform(rng.uniform(-1, 1, (1, 3)) * 0.7, np.radians(rng.uniform(-25, 25, (1, 3))))[0]
    Tm = F @ A_te.poses()
    S = dataclasses.replace(A_te, xyz_m=Tm[:, :3, 3], quat_wxyz=se3.matrix_to_quat(Tm[:, :3, :3]),
                            source="A held-out, moved tracker")
    mr, info, rest, St, (pc, ph, ac, ah) = _registered_errors(m, S, n_reg)
    print(f"-- overlap case: series A held-out as a new series (tracker moved, unknown frame), {info.summary()}")
    print(HEAD)
    print(_row("all (rest of it)", np.ones(len(St), bool), pc, ph, ac, ah, mr.predict_uncertainty(St.q, 0.95)))
    ratios = _quartile_ratios(St.q, ph, pc)
    print(f"   hybrid/calib ratio over the quartiles of every joint (24 regions): best {min(ratios):.3f}, "
          f"worst {max(ratios):.3f}")


def _registered_errors(m, S, n_reg):
    """Register ``m`` to series ``S`` from ``n_reg`` poses, and the calibrated model alone on the same
    poses; errors of both on the other poses: ``(model, info, rest, S_rest, (pc, ph, ac, ah))``."""
    mr, info = register_model(m, S, n_poses=n_reg)
    rest = np.setdiff1d(np.arange(len(S)), info.used_index)
    St = S.subset(rest)
    Tc_all = m.predict_classical(S.q)
    Bc, Ec = fit_frames(Tc_all[info.used_index], S.poses()[info.used_index])
    pc, ac = _err(Bc @ Tc_all[rest] @ Ec, St)
    ph, ah = _err(mr.predict(St.q), St)
    return mr, info, rest, St, (pc, ph, ac, ah)


def _quartile_ratios(q, ph, pc) -> list[float]:
    """Hybrid / calibrated mean error in each quartile of every joint (6 x 4 regions)."""
    ratios = []
    for j in range(q.shape[1]):
        edges = np.quantile(q[:, j], [0, 0.25, 0.5, 0.75, 1])
        for k in range(4):
            msk = (q[:, j] >= edges[k]) & (q[:, j] <= edges[k + 1])
            ratios.append(ph[msk].mean() / pc[msk].mean())
    return ratios


def ur10(variants, n_reg=30, fades=(True, "range", False), seed=0):
    from hykin.measure.importers import import_ipa_series, ipa_nominal_robot

    A = import_ipa_series(DATA / "Series_A", register_to=ipa_nominal_robot())
    B = import_ipa_series(DATA / "Series_B")  # tracker frame
    perm = np.random.default_rng(seed).permutation(len(A))
    k1, k2 = int(0.7 * len(A)), int(0.85 * len(A))
    A_tr, A_val, A_te = A.subset(perm[:k1]), A.subset(perm[k1:k2]), A.subset(perm[k2:])
    loA, hiA = A.q.min(0), A.q.max(0)
    outj = (B.q < loA) | (B.q > hiA)
    print(f"series A {len(A)} poses: train {len(A_tr)} / val {len(A_val)} / held-out test {len(A_te)}; series B "
          f"{len(B)} poses (tracker frame), B rows with a joint outside A's raw range: {int(outj.any(1).sum())} "
          f"(per joint {outj.sum(0).tolist()})")
    for var in variants:
        periodic, joint1 = var.split(":")
        t0 = time.perf_counter()
        m = HybridModel(ipa_nominal_robot(), periodic=periodic, joint1=joint1, seed=seed).fit(A_tr, A_val, progress=False)
        t_fit = time.perf_counter() - t0
        print(f"\n== variant periodic={periodic} joint1={joint1}: fit {t_fit:.0f} s")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", OutOfRangeWarning)
            print(HEAD)
            pc, ac = _err(m.predict_classical(A_te.q), A_te)
            ph, ah = _err(m.predict(A_te.q), A_te)
            print(_row("A held-out test (same series)", np.ones(len(A_te), bool), pc, ph, ac, ah,
                       m.predict_uncertainty(A_te.q, 0.95)))
            _overlap_series(m, A_te, n_reg, seed)
            for fade in fades:
                m.fade = fade
                # registered with this fade; calibration alone registered on the same poses
                mr, info, rest, Bt, (pc, ph, ac, ah) = _registered_errors(m, B, n_reg)
                bands = mr.predict_uncertainty(Bt.q, 0.95)
                d = mr.support_distance(Bt.q)
                w = mr.fade_weight(Bt.q)
                print(f"-- series B, fade={fade}: {info.summary()}")
                print(HEAD)
                print(_row("all (rest of B)", np.ones(len(Bt), bool), pc, ph, ac, ah, bands))
                oj = outj[rest]
                print(_row("inside A raw joint box", ~oj.any(1), pc, ph, ac, ah, bands))
                print(_row("outside A raw joint box", oj.any(1), pc, ph, ac, ah, bands))
                for j in range(6):
                    if oj[:, j].any():
                        print(_row(f"  q{j + 1} outside A raw range", oj[:, j], pc, ph, ac, ah, bands))
                print(_row("support_distance = 0", d == 0, pc, ph, ac, ah, bands))
                print(_row("0 < support_distance <= 0.1", (d > 0) & (d <= 0.1), pc, ph, ac, ah, bands))
                print(_row("support_distance > 0.1", d > 0.1, pc, ph, ac, ah, bands))
                print(_row("fade weight w = 1", w == 1, pc, ph, ac, ah, bands))
                print(_row("0 < w < 1", (w > 0) & (w < 1), pc, ph, ac, ah, bands))
                print(_row("w = 0 (calibrated model)", w == 0, pc, ph, ac, ah, bands))
                worst = max(_quartile_ratios(Bt.q, ph, pc))
                print(f"   worst hybrid/calib ratio over the quartiles of every joint (24 regions): {worst:.3f}")
        m.fade = True


def virtual(preset="rx160-nongeo", n=6000, fraction=0.5, seed=0, max_epochs=None):
    from hykin.sim.presets import virtual_preset
    from hykin.sim.sampling import restricted
    from hykin.sim.simulate import simulate

    vr = virtual_preset(preset)
    rob = vr.nominal
    q_tr = restricted(rob, n, seed, fraction=fraction, method="random")
    q_te_in = restricted(rob, 3000, seed + 1, fraction=fraction, method="random")
    q_te_full = rob.random_joints(6000, seed + 2)
    tr = simulate(vr, q_tr, rng=seed)
    te_in = simulate(vr, q_te_in, rng=seed + 1)
    te_full = simulate(vr, q_te_full, rng=seed + 2)
    kw = {} if max_epochs is None else {"recipe_kw": {"max_epochs": max_epochs}}
    t0 = time.perf_counter()
    m = HybridModel(rob, seed=seed, **kw).fit(tr, progress=False)
    print(f"\n== virtual {preset}: train {n} poses in the middle {fraction:.0%} of every joint range; fit "
          f"{time.perf_counter() - t0:.0f} s")
    print(HEAD)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        for name, ds in (("held-out, training range", te_in), ("full range", te_full)):
            for fade in (True, False):
                m.fade = fade
                pc, ac = _err(m.predict_classical(ds.q), ds)
                ph, ah = _err(m.predict(ds.q), ds)
                bands = m.predict_uncertainty(ds.q, 0.95)
                d = m.support_distance(ds.q)
                print(_row(f"{name[:14]} fade={fade}", np.ones(len(ds), bool), pc, ph, ac, ah, bands))
                if name == "full range":
                    print(_row("  inside (d = 0)", d == 0, pc, ph, ac, ah, bands))
                    print(_row("  0 < d <= 0.1", (d > 0) & (d <= 0.1), pc, ph, ac, ah, bands))
                    print(_row("  outside (d > 0.1)", d > 0.1, pc, ph, ac, ah, bands))
        m.fade = True


def speed(n=200_000, threads=2):
    """Throughput (poses/s) of predict per fade mode, support_distance, pair_gap and predict_uncertainty."""
    import torch

    from hykin.sim.presets import virtual_preset
    from hykin.sim.simulate import simulate

    torch.set_num_threads(threads)
    vr = virtual_preset("rx160-nongeo")
    rob = vr.nominal
    m = HybridModel(rob, seed=0, recipe_kw={"max_epochs": 5}).fit(simulate(vr, rob.random_joints(4000, 0)), progress=False)
    q = rob.random_joints(n, 1)
    print(f"\n== speed: {n} queries, default net, torch threads {threads}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        rows = []
        for name, fn in (("predict_classical", m.predict_classical),
                         ("predict fade=False", lambda x: (setattr(m, "fade", False), m.predict(x))),
                         ("predict fade='range'", lambda x: (setattr(m, "fade", "range"), m.predict(x))),
                         ("predict fade=True (support)", lambda x: (setattr(m, "fade", True), m.predict(x))),
                         ("pair_gap", m.pair_gap),
                         ("support_distance", m.support_distance),
                         ("predict_uncertainty", m.predict_uncertainty)):
            fn(q[:1000])
            t = time.perf_counter()
            fn(q)
            rows.append((name, n / (time.perf_counter() - t)))
        m.fade = True
    ref = rows[1][1]
    for name, r in rows:
        print(f"{name:<30} {r / 1e3:9.0f} k/s   x{r / ref:5.2f} vs predict fade=False")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("what", choices=["ur10", "virtual", "speed", "all"])
    ap.add_argument("--variants", default="wrap:input")
    ap.add_argument("--fades", default="support,range,off", help="fade modes for series B: support, range, full, off")
    ap.add_argument("--preset", default="rx160-nongeo")
    ap.add_argument("--n", type=int, default=6000)
    ap.add_argument("--max-epochs", type=int, default=None)
    a = ap.parse_args()
    if a.what in ("ur10", "all"):
        if not DATA.is_dir():
            print(f"skipped: {DATA} not found")
        else:
            fades = [{"support": True, "off": False}.get(f, f) for f in a.fades.split(",")]
            ur10(a.variants.split(","), fades=fades)
    if a.what in ("virtual", "all"):
        virtual(a.preset, a.n, max_epochs=a.max_epochs)
    if a.what in ("speed", "all"):
        speed()


if __name__ == "__main__":
    main()
