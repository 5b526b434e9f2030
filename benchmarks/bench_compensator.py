"""Compensator benchmark (issue #25): reachable targets are compensated, land within 0.05 mm, and
``Compensator.step`` keeps controller rate; hybrid FK speed against the calibrated classical model.

Robots (our own virtual robots; hykin.sim with perturbations drawn here):

* ``ur-like``: the ``ur10-virtual`` preset drawn with seed 25 (geometry 0.6 mm / 0.12°, soft joints,
  2 kg tool + 5 kg payload, tracker noise 20 µm / 100 µrad);
* ``kuka-like``: nominal ``kuka-kr6-r900`` with link masses added here, truth = our geometric
  deviations (0.5 mm, 0.06°) + mass deviations + joint springs (compliance);
* ``7-dof``: nominal ``kuka-iiwa14`` with link masses and a 2 kg payload added here, truth = our
  geometric deviations (0.5 mm, 0.06°) + mass deviations + joint springs.

Each gets a HybridModel fitted on 2,000 simulated poses (noise as the robot has; few epochs).
Targets: TRUE poses at 1,200 joint configurations — uniform over the whole joint range, one joint
within 1° of a limit, near the wrist and elbow singularities, at the workspace edge (stretched elbow,
0.3–2° from straight). Compensated with the joints as branch hint; a stand-in controller running the
NOMINAL model (nominal IK of the command, the solution nearest the compensated joints) executes the
command on the TRUE robot; the error is the true pose to the target. Peer in the same run: the same
controller given the uncompensated targets.

Step latency: ``Compensator.step`` along a smooth path of 10,000 targets (warm start from the previous
joints), the batch path on the same targets, and the previous implementation (hybrid IK of
hykin.hybrid.ik per call, forced with an IK keyword) on 50 targets as a peer.

Wall times are on whatever machine runs this; on the shared 2-core development machine they are
inflated (load average ~10 while measured: other jobs).

    python benchmarks/bench_compensator.py [--n 1200] [--path 10000]
"""

from __future__ import annotations

import argparse
import gc
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import hykin  # noqa: E402
from hykin import load_robot  # noqa: E402
from hykin.geometry import se3  # noqa: E402
from hykin.hybrid.model import HybridModel  # noqa: E402
from hykin.kinematics.ik import ik  # noqa: E402
from hykin.sim.presets import virtual_preset  # noqa: E402
from hykin.sim.simulate import VirtualRobot, geometric_deviation, mass_deviation, simulate, true_poses  # noqa: E402


def robots() -> list[VirtualRobot]:
    ur = virtual_preset("ur10-virtual", 25)
    rng = np.random.default_rng(7)
    kr = load_robot("kuka-kr6-r900").copy(
        mass_kg=[20.0, 12.0, 8.0, 3.0, 2.0, 0.5], payload_kg=3.0,
        com_m=[[0, 0, 0], [0.2, 0, 0], [0.05, 0, 0], [0, 0, 0.1], [0, 0, 0], [0, 0, 0]])
    kt = mass_deviation(geometric_deviation(kr, rng, 5e-4, np.radians(0.06), 5e-4, np.radians(0.06)), rng)
    kt = kt.copy(stiffness_nm_per_rad=[3e5, 2e5, 1.5e5, 4e4, 4e4, 3e4], name="kuka-like-truth")
    iiwa = load_robot("kuka-iiwa14").copy(
        mass_kg=[4.0, 4.0, 3.0, 2.7, 1.7, 1.8, 0.3], com_m=[[0, -0.03, 0.12], [0, 0.06, 0.02], [0, 0.03, 0.13],
                 [0, 0.07, 0.03], [0, 0.02, 0.08], [0, 0.0, 0.0], [0, 0, 0.02]], payload_kg=2.0)
    rng8 = np.random.default_rng(8)
    it = mass_deviation(geometric_deviation(iiwa, rng8, 5e-4, np.radians(0.06), 5e-4, np.radians(0.06)), rng8)
    it = it.copy(stiffness_nm_per_rad=[3e5, 3e5, 2e5, 2e5, 1e5, 1e5, 1e5])
    return [VirtualRobot("ur-like", ur.nominal, ur.truth, noise_position_m=20e-6, noise_orientation_rad=100e-6),
            VirtualRobot("kuka-like", kr, kt), VirtualRobot("7-dof", iiwa, it.copy(name="7-dof-truth"))]


def hard_joints(nom, n: int, rng) -> np.ndarray:
    """Uniform over the whole range, within 1° of a limit, near wrist / elbow singularities, at the edge."""
    lo, hi = nom.lower, nom.upper
    q = nom.random_joints(n, int(rng.integers(1 << 30)), margin=0.0)
    k = n // 6
    for i in range(k):  # one joint within 1 degree of a limit (0.02 .. 1 deg inside)
        j = i % nom.dof
        d = np.radians(rng.uniform(0.02, 1.0))
        q[i, j] = lo[j] + d if i % 2 else hi[j] - d
    wrist, elbow = (4, 2) if nom.dof == 6 else (5, 3)
    q[k:2 * k, wrist] = np.radians(rng.uniform(-0.5, 0.5, k))  # wrist singularity
    q[2 * k:3 * k, elbow] = np.radians(rng.uniform(-2.0, 2.0, k))  # elbow singularity
    s = np.radians(rng.uniform(0.3, 2.0, k)) * rng.choice([-1, 1], k)  # stretched elbow: workspace edge
    q[3 * k:4 * k, elbow] = s
    return np.clip(q, lo, hi)


def controller(nom, T_cmd, q_ref) -> np.ndarray:
    """Stand-in controller running the nominal model: nominal IK of base-frame commands nearest ``q_ref``."""
    good = np.isfinite(T_cmd).all((1, 2))
    out = np.full(q_ref.shape, np.nan)
    if nom.dof == 6:
        r = ik(nom, nom.base @ T_cmd[good], all_branches=True).nearest_to(q_ref[good], nom.lower, nom.upper)
    else:
        r = ik(nom, nom.base @ T_cmd[good], q_seed=q_ref[good])
    out[good] = np.where(np.asarray(r.success)[:, None], np.asarray(r.q).reshape(-1, nom.dof), np.nan)
    return out


def timeit(fn, reps: int) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t) / reps


def reachability(vr, m, n, rng) -> None:
    q = hard_joints(vr.nominal, n, rng)
    T = true_poses(vr, q)
    inside = np.all((q >= vr.truth.lower) & (q <= vr.truth.upper), axis=1)
    C = hykin.Compensator(m)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        C(T[:200], q_branch=q[:200])  # warm-up: numba loads (or compiles) its kernels
        t = time.perf_counter()
        c = C(T, q_branch=q)
        wall = time.perf_counter() - t
    miss = inside & ~c.success
    qc = controller(vr.nominal, c.command, c.q)
    landed = np.isfinite(qc).all(1)
    err = se3.pose_error(true_poses(vr, qc[landed]), T[landed])[0]
    qu = controller(vr.nominal, se3.invert(vr.nominal.base) @ T, q)
    okq = np.isfinite(qu).all(1)
    err_u = se3.pose_error(true_poses(vr, qu[okq]), T[okq])[0]
    held = m.metadata["metrics"].get("val") or m.metadata["metrics"].get("held_out") or {}
    mmax = held.get("hybrid_pos_max_mm", np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        own = se3.pose_error(m.predict(c.q[landed]), true_poses(vr, c.q[landed]))[0]  # the model's error there
    excess = err - own
    print(f"  {vr.name}: {n} targets reached by the true robot ({inside.sum()} within its limits): compensated "
          f"{c.success.sum()}, refused {miss.sum()}" + (f" ({'; '.join(sorted(set(c.reason[miss])))[:200]})" if miss.any() else "")
          + f"; tolerance {C.tolerance_mm:.2g} mm; batch {n / wall:,.0f} targets/s")
    print(f"    executed by the nominal controller: {landed.sum()} landed, mean {err.mean():.4f} mm, p99 "
          f"{np.percentile(err, 99):.4f} mm, max {err.max():.4f} mm | the model's own error at those joints: max "
          f"{own.max():.4f} mm, landing minus it at most {excess.max():.1e} mm | held-out max {mmax:.4f} mm | "
          f"uncompensated: mean {err_u.mean():.3f} mm, max {err_u.max():.3f} mm (x{err_u.mean() / max(err.mean(), 1e-12):.0f})")
    verdict = c.success[inside].all() and err.mean() <= 0.05 and err.max() <= max(own.max(), mmax) + 1e-6
    print(f"    -> {'MET' if verdict else 'NOT MET'} (all compensated, mean <= 0.05 mm, no target worse than the "
          f"model's own max error; IK residual max {c.pos_err_mm[c.success].max():.1e} mm)")


def latency(vr, m, n_path: int) -> None:
    nom = vr.nominal
    t = np.linspace(0, 1, n_path)[:, None]
    q0 = np.array([0.3, -1.4, 1.5, -1.7, -1.5, 0.4])[: nom.dof]
    amp = np.array([0.8, 0.3, 0.4, 0.6, 0.5, 1.0])[: nom.dof]
    q_path = q0 + amp * np.sin(2 * np.pi * t * np.array([1.0, 2.0, 1.5, 3.0, 2.5, 4.0])[: nom.dof])
    T = true_poses(vr, q_path)  # 10,000 targets along a smooth path (~0.3 mm apart)
    C = hykin.Compensator(m)
    C.step(T[0], q_path[0])
    gc.collect()
    gc.freeze()  # as a real-time loop does once before it starts (docs/realtime.md, the ur-rtde example)
    load_probe(nom)
    lat = np.empty(n_path)
    Q = np.empty((n_path, nom.dof))
    cmd = np.empty((n_path, 4, 4))
    qp = q_path[0]
    ok = 0
    for k in range(n_path):
        s = time.perf_counter()
        r = C.step(T[k], qp)
        lat[k] = time.perf_counter() - s
        ok += r.success
        qp = r.q if r.success else qp
        Q[k], cmd[k] = r.q, r.command
    gc.unfreeze()
    us = lat * 1e6
    hints = np.vstack([q_path[:1], Q[:-1]])
    s = time.perf_counter()
    c = C(T, q_branch=hints)
    tb = time.perf_counter() - s
    s = time.perf_counter()
    cw = C(T)
    tw = time.perf_counter() - s
    d = np.abs(c.command[:, :3, 3] - cmd[:, :3, 3]).max() * 1e3
    gen = hykin.Compensator(m, jacobian_mode="frozen-fd")  # previous implementation: hybrid IK of hykin.hybrid.ik
    k = 50
    s = time.perf_counter()
    for i in range(k):
        gen.step(T[i], hints[i])
    tg = (time.perf_counter() - s) / k
    print(f"  {vr.name}: step over a smooth path of {n_path} targets: {ok} compensated; p50 {np.percentile(us, 50):.0f} µs, "
          f"p99 {np.percentile(us, 99):.0f} µs, max {us.max():.0f} µs per target | previous implementation "
          f"{tg * 1e3:.1f} ms per target (x{tg / np.percentile(lat, 50):.0f} slower than step's p50)")
    print(f"    batch (same hints): {n_path / tb:,.0f} targets/s, max |command step - batch| {d:.2e} mm; batch with "
          f"the default walk: {n_path / tw:,.0f} targets/s, {cw.success.sum()} compensated")


def load_probe(robot) -> None:
    """Single-pose classical FK here vs on the idle machine: how inflated the timings around it are."""
    q0 = robot.random_joints(1, 0)[0]
    probe = timeit(lambda: hykin.fk(robot, q0), 5000)
    print(f"  machine load probe: single-pose classical fk {probe * 1e6:.2f} µs now vs 1.48 µs on the idle machine "
          f"(benchmarks/RESULTS.md): timings here inflated ~x{probe / 1.48e-6:.1f}")


def median_time(fn, n_rows: int) -> float:
    """Median seconds per call of 7 rounds, each of enough calls for ~100,000 rows (load spikes of the
    shared machine fall outside the median)."""
    fn()
    reps = max(2, 100_000 // n_rows)
    rounds = []
    for _ in range(7):
        t = time.perf_counter()
        for _ in range(reps):
            fn()
        rounds.append((time.perf_counter() - t) / reps)
    return float(np.median(rounds))


def fk_speed(m) -> None:
    load_probe(m.robot)
    q = m.robot.random_joints(100_000, 3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        one_h = timeit(lambda: m.predict(q[0]), 2000)
        one_c = timeit(lambda: m.predict_classical(q[0]), 2000)
        print(f"  hybrid FK one pose {one_h * 1e6:.1f} µs (calibrated classical {one_c * 1e6:.1f} µs)")
        for n in (10, 100, 1_000, 10_000, 100_000):
            b_h = median_time(lambda: m.predict(q[:n]), n)
            b_c = median_time(lambda: m.predict_classical(q[:n]), n)
            print(f"  batch {n:>7,}: hybrid {n / b_h:>9,.0f} poses/s, calibrated classical {n / b_c:>9,.0f} poses/s, "
                  f"ratio {b_c / b_h:.2f}")
    floor = matmul_floor(m, len(q))
    print(f"    the networks' matrix products and features alone (every activation removed; the model's own path) take "
          f"{floor * 1e3:.1f} ms for 100,000 poses against {b_c * 1e3:.1f} ms for the calibrated classical model: with "
          f"this float64 arithmetic the ratio cannot exceed {b_c / (b_c + floor):.2f} here (the activations cost "
          f"{(b_h - b_c - floor) * 1e3:.1f} ms more)")
    arithmetic_bound(m, len(q), b_c)


def arithmetic_bound(m, n: int, t_classical: float) -> None:
    """What the networks' multiply-adds cost at this machine's matrix-product peak, measured now (a
    2,000 x 2,000 product on all cores, float64 and float32): the least time any implementation of
    these networks can take, activations, features and everything else left out."""
    from hykin.hybrid import fast_nets
    from hykin.kinematics.chunks import worker_count

    macs = 0
    for net in (m.net_pos_, m.net_rot_):
        if net is not None:
            for L in fast_nets.cached(m, net).fast.layers:
                macs += sum(W.size for W, _, _ in L.main) + (0 if L.shortcut in (None, "identity") else L.shortcut[0].size)
    budget = t_classical / 0.8 - t_classical
    print(f"    the networks' {macs:,} multiply-adds per pose at this machine's matrix-product peak, measured now "
          f"({worker_count()} threads; 0.8x leaves them {budget * 1e3:.1f} ms per {n:,} poses):")
    rng = np.random.default_rng(0)
    for dt in (np.float64, np.float32):
        A, B = rng.random((2000, 2000)).astype(dt), rng.random((2000, 2000)).astype(dt)
        peak = 2000 ** 3 / min(timeit(lambda: A @ B, 3) for _ in range(3))  # multiply-adds per second
        t = macs * n / peak
        print(f"      {np.dtype(dt).name}: {2 * peak / 1e9:.0f} GFLOP/s -> at least {t * 1e3:.1f} ms, ratio at most "
              f"{t_classical / (t_classical + t):.2f}")


def matmul_floor(m, n: int) -> float:
    """Seconds for both residual networks on ``n`` rows with every activation removed (the same float64
    inference path, chunks and threads as the model's: :mod:`hykin.hybrid.fast_nets`): the dense layers'
    matrix products and the features alone, what the networks add to the classical model's time at least
    with this arithmetic."""
    import copy

    from hykin.hybrid import fast_nets

    nets = []
    for net in (m.net_pos_, m.net_rot_):
        if net is None:
            continue
        f = copy.deepcopy(fast_nets.cached(m, net).fast)
        for L in f.layers:
            L.main = [(W, b, None) for W, b, _ in L.main]
            L.act = None
        nets.append(f)
    x = m.robot.random_joints(n, 5)
    return timeit(lambda: [f(x) for f in nets], 3)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1200)
    ap.add_argument("--path", type=int, default=10_000)
    ap.add_argument("--train", type=int, default=2000)
    a = ap.parse_args()
    rng = np.random.default_rng(25)
    for i, vr in enumerate(robots()):
        s = time.perf_counter()
        q = vr.nominal.random_joints(a.train, 100 + i, margin=0.0)
        m = HybridModel(vr.nominal, recipe_kw={"max_epochs": 4}, seed=0).fit(simulate(vr, q), progress=False)
        print(f"{vr.name}: fitted on {a.train} poses in {time.perf_counter() - s:.0f} s")
        reachability(vr, m, a.n, rng)
        if i == 0:
            latency(vr, m, a.path)
            fk_speed(m)


if __name__ == "__main__":
    main()
