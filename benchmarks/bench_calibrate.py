"""Benchmark: parametric calibration (hykin.calibrate) on a virtual robot, 10k and 100k samples.

For each size: wall time of :func:`hykin.calibration.calibrate.calibrate` (analytic Jacobian, relinearising LM)
and accuracy on 2000 held-out samples against the noise-free truth, next to the peer measured in the
same run: ``scipy.optimize.least_squares`` (trf, 2-point finite-difference Jacobian) on the same
residual and the same identifiable parameters (the textbook way to write it).

Usage: ``python benchmarks/bench_calibrate.py [--preset rx160-geometric] [--sizes 10000 100000]
[--peer-max 10000] [--noise]``
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import scipy.optimize

from hykin.calibration.calibrate import apply_deviations, calibrate, calibrated_fk
from hykin.geometry import se3
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate, true_poses


def peer_least_squares(nominal, ds, names):
    """Same problem with scipy least_squares and a finite-difference Jacobian."""
    q = ds.q
    xyz = ds.xyz_m
    R = se3.quat_to_matrix(ds.quat_wxyz)
    scale = np.array([1e-6 if n[0] == "c" and n[1:].isdigit() else 1e-3 for n in names])

    def fun(x):
        r = apply_deviations(nominal, dict(zip(names, x)))
        T = calibrated_fk(r, q)
        rp = xyz - T[:, :3, 3]
        ro = se3.rotation_difference_rotvec(R, T[:, :3, :3])
        return np.concatenate([rp.ravel(), ro.ravel()])

    t = time.perf_counter()
    sol = scipy.optimize.least_squares(fun, np.zeros(len(names)), method="trf", x_scale=scale, jac="2-point",
                                       xtol=1e-12, ftol=1e-12, gtol=1e-12, max_nfev=200)
    return apply_deviations(nominal, dict(zip(names, sol.x))), time.perf_counter() - t, sol.nfev


def held_out(vr, robot, qt, Tt):
    pe, ae = se3.pose_error(calibrated_fk(robot, qt), Tt)
    return pe.mean(), pe.max(), ae.mean(), ae.max()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rx160-geometric")
    ap.add_argument("--sizes", type=int, nargs="+", default=[10_000, 100_000])
    ap.add_argument("--peer-max", type=int, default=10_000, help="run the scipy peer up to this many samples")
    ap.add_argument("--noise", action="store_true", help="simulate with the preset's measurement noise")
    args = ap.parse_args()

    vr = virtual_preset(args.preset)
    rng = np.random.default_rng(0)
    qt = vr.nominal.random_joints(2000, rng)
    Tt = true_poses(vr, qt)
    m0 = held_out(vr, vr.nominal, qt, Tt)
    print(f"preset {args.preset}: nominal model error on held-out {m0[0]:.4f} mm mean, {m0[2]:.4f} deg mean")
    # warm-up (numba kernels, torch import) so that timings measure the work
    calibrate(vr.nominal, simulate(vr, vr.nominal.random_joints(200, rng), noise=args.noise, rng=1))
    hdr = f"{'method':<34} {'N':>7} {'time s':>8} {'cpu s':>7} {'iters':>6} {'pos mean mm':>12} {'pos max mm':>11} {'rot mean deg':>13} {'rot max deg':>12} {'speed-up':>9}"
    print(hdr)
    print("-" * len(hdr))
    for n in args.sizes:
        ds = simulate(vr, vr.nominal.random_joints(n, rng), noise=args.noise, rng=2)
        t, c = time.perf_counter(), time.process_time()
        res = calibrate(vr.nominal, ds)
        t_h, c_h = time.perf_counter() - t, time.process_time() - c
        m = held_out(vr, res.robot, qt, Tt)
        row_h = f"{'hykin.calibrate (analytic J, LM)':<34} {n:>7} {t_h:8.2f} {c_h:7.2f} {res.iterations:>6} {m[0]:12.2e} {m[1]:11.2e} {m[2]:13.2e} {m[3]:12.2e}"
        if n <= args.peer_max:
            names = res.identified_names
            c = time.process_time()
            r_p, t_p, nfev = peer_least_squares(vr.nominal, ds, names)
            c_p = time.process_time() - c
            mp = held_out(vr, r_p, qt, Tt)
            print(row_h + f" {t_p / t_h:8.1f}x")
            print(f"{'scipy least_squares (trf, FD J)':<34} {n:>7} {t_p:8.2f} {c_p:7.2f} {nfev:>6} {mp[0]:12.2e} {mp[1]:11.2e} {mp[2]:13.2e} {mp[3]:12.2e} {'1.0x':>9}")
        else:
            print(row_h + f" {'-':>9}")
    print("speed-up = peer time / hykin time (same data, same identifiable parameters, same machine, same run);")
    print("cpu s = process CPU time (all threads): the load-independent figure on a shared machine.")


if __name__ == "__main__":
    main()
