"""Inverse-kinematics benchmark: hykin vs peers measured in the same run (DESIGN.md §5).

Closed form, all branches, batched: µs per target (amortised over N targets) for rx160 (spherical
wrist) and ur10 (three parallel axes), with the fraction of targets whose generating joints are
among the solutions. Peers: ik-geo (Rust, per-target Python calls) and ur-analytic-ik (C++, UR only).

Numerical IK: ms per target and success rate at 1e-6 m / 1e-6 rad on random reachable targets (LM
from the middle of the limits plus random restarts; ``method="numeric"``, closed form not used),
for rx160, ur10 and franka-panda (7 dof). Peer: roboticstoolbox-python's C++ ``ETS.ik_LM``.

Peers that are not installed are skipped (``pip install ik-geo ur-analytic-ik roboticstoolbox-python``).

    python benchmarks/bench_ik.py [--n 10000] [--n-peer 2000] [--threads 2]
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from _timing import best_of


def _mod2pi(a, b):
    return np.abs((a - b + np.pi) % (2 * np.pi) - np.pi).max(axis=-1)


def _contains(qs_list, q, tol=1e-6):
    """Fraction of targets whose generating joints are among the returned solutions."""
    hits = 0
    for sols, qi in zip(qs_list, q):
        sols = np.asarray(sols, dtype=float).reshape(-1, q.shape[1])
        sols = sols[np.all(np.isfinite(sols), axis=1)]
        hits += bool(len(sols)) and bool(np.min(_mod2pi(sols, qi)) < tol)
    return hits / len(q)


def bench_closed_form(name, n, n_peer, rows):
    from hykin.io.robot_file import load_robot
    from hykin.kinematics.fk import fk
    from hykin.kinematics.ik import ik_closed_form
    from hykin.kinematics.poe import poe_model

    r = load_robot(name)
    rng = np.random.default_rng(0)
    q = r.random_joints(n, rng)
    T = fk(r, q)
    ik_closed_form(r, T[:10])  # compile
    dt, sol = best_of(lambda: ik_closed_form(r, T))
    ours = dt / n * 1e6
    qs = [s.q[i][s.valid[i]] for s in [sol] for i in range(n)]
    rows.append((f"closed form all branches, {name}", "hykin", f"{ours:.2f} µs", f"{_contains(qs, q):.4f}",
                 f"{sol.n_solutions.mean():.2f} sol/target", "1.00"))
    m = poe_model(r)
    R0 = m.T0[:3, :3]
    Tp, qp = T[:n_peer], q[:n_peer]
    try:
        import ik_geo

        h = m.h
        pts = m.p.copy()
        pts[3:] = m.wc if m.family == "opw" else pts[3:]
        if m.family == "ur":
            pts[4:] = m.wc  # axes 5, 6 meet: IK-Geo wants p56 = 0
        p = np.vstack([pts[0], np.diff(pts, axis=0), m.T0[:3, 3] - pts[5]])
        ctor = ik_geo.Robot.spherical_two_parallel if m.family == "opw" else ik_geo.Robot.three_parallel_two_intersecting
        rob = ctor(h.tolist(), p.tolist())
        # ik-geo's Python binding reads/writes 3x3 matrices transposed (nalgebra column-major), as
        # its own forward_kinematics shows: pass R^T
        Rl = [(Ti[:3, :3] @ R0.T).T.tolist() for Ti in Tp]
        tl = [Ti[:3, 3].tolist() for Ti in Tp]

        def run():
            return [rob.get_ik(R, t) for R, t in zip(Rl, tl)]

        rob.get_ik(Rl[0], tl[0])
        dt, out = best_of(run)
        us = dt / len(Tp) * 1e6
        qs = [[s[0] for s in o if not s[1]] for o in out]  # exact (not least-squares) solutions
        nsol = np.mean([len(x) for x in qs])
        rows.append((f"closed form all branches, {name}", "ik-geo (Rust, per call)", f"{us:.2f} µs",
                     f"{_contains(qs, qp):.4f}", f"{nsol:.2f} sol/target (no limits)", f"{us / ours:.2f}"))
    except ImportError:
        rows.append((f"closed form all branches, {name}", "ik-geo", "not installed", "", "", ""))
    if m.family == "ur":
        try:
            import ur_analytic_ik

            mod = getattr(ur_analytic_ik, name)
            Tc = [np.ascontiguousarray(Ti) for Ti in Tp]

            def run():
                return [mod.inverse_kinematics(Ti) for Ti in Tc]

            dt, out = best_of(run)
            us = dt / len(Tp) * 1e6
            nsol = np.mean([len(x) for x in out])
            rows.append((f"closed form all branches, {name}", "ur-analytic-ik (C++, per call)", f"{us:.2f} µs",
                         f"{_contains(out, qp):.4f}", f"{nsol:.2f} sol/target (no limits)", f"{us / ours:.2f}"))
        except ImportError:
            rows.append((f"closed form all branches, {name}", "ur-analytic-ik", "not installed", "", "", ""))


def _rtb_ets(robot):
    """roboticstoolbox ETS of a DH robot; theta offsets are folded into the joint variable (the
    C++ solver rejects offsets), so rtb joints = hykin joints + offset."""
    import roboticstoolbox as rtb
    from spatialmath import SE3

    link = rtb.RevoluteDH if robot.convention == "dh" else rtb.RevoluteMDH
    links = []
    for i in range(robot.dof):
        off = robot.theta_rad[i]
        links.append(link(d=robot.d_m[i], a=robot.a_m[i], alpha=robot.alpha_rad[i],
                          qlim=[robot.lower[i] + off, robot.upper[i] + off]))
    return rtb.DHRobot(links, name=robot.name, tool=SE3(robot.tool, check=False)).ets()


def bench_numeric(name, n, n_peer, rows, tol=1e-6):
    from hykin.geometry import se3
    from hykin.io.robot_file import load_robot
    from hykin.kinematics.fk import fk
    from hykin.kinematics.ik import ik

    r = load_robot(name)
    rng = np.random.default_rng(1)
    q = r.random_joints(n, rng)
    T = fk(r, q)
    ik(r, T[:10], method="numeric")  # compile
    t = time.perf_counter()
    res = ik(r, T, method="numeric", tol_m=tol, tol_rad=tol)
    dt = time.perf_counter() - t
    ours = dt / n * 1e3
    rows.append((f"numerical IK (tol {tol:g}), {name}", "hykin LM (numba)", f"{ours:.4f} ms",
                 f"{res.success.mean():.4f}", f"max err {res.pos_err_m[res.success].max():.1e} m", "1.00"))
    t = time.perf_counter()
    res = ik(r, T, method="numeric")
    dt10 = time.perf_counter() - t
    rows.append((f"numerical IK (tol 1e-10), {name}", "hykin LM (numba)", f"{dt10 / n * 1e3:.4f} ms",
                 f"{res.success.mean():.4f}", f"max err {res.pos_err_m[res.success].max():.1e} m", ""))
    if r.convention not in ("dh", "mdh") or np.any(r.base != np.eye(4)) or np.any(r.beta_rad != 0):
        rows.append((f"numerical IK (tol {tol:g}), {name}", "roboticstoolbox ik_LM", "skipped (URDF/base)", "", "", ""))
        return
    try:
        ets = _rtb_ets(r)
    except Exception as e:  # ImportError or rtb construction problem
        rows.append((f"numerical IK (tol {tol:g}), {name}", "roboticstoolbox ik_LM", f"unavailable ({type(e).__name__})",
                     "", "", ""))
        return
    Tp = T[:n_peer]
    q_chk = r.random_joints(5, rng)
    Te = np.array([np.asarray(ets.eval(qq + r.theta_rad)) for qq in q_chk])
    if np.abs(Te - fk(r, q_chk)).max() > 1e-9:
        rows.append((f"numerical IK (tol {tol:g}), {name}", "roboticstoolbox ik_LM", "skipped (model mismatch)", "", "", ""))
        return
    tol_rtb = 0.5 * tol**2  # rtb's tol bounds E = 1/2 e^T e, not |e|
    ets.ik_LM(Tp[0], tol=tol_rtb)

    def run():
        return [ets.ik_LM(Ti, tol=tol_rtb, ilimit=30, slimit=100, joint_limits=True) for Ti in Tp]

    t = time.perf_counter()
    out = run()
    dt = time.perf_counter() - t
    qs = np.array([np.asarray(o.q, dtype=float).reshape(-1) for o in out]) - r.theta_rad
    ok_flag = np.array([bool(o.success) for o in out])
    mm, deg = se3.pose_error(fk(r, qs), Tp)
    ok = ok_flag & (mm * 1e-3 <= tol * 1.001) & (np.radians(deg) <= tol * 1.001) & r.within_limits(qs)
    us = dt / len(Tp) * 1e3
    rows.append((f"numerical IK (tol {tol:g}), {name}", "roboticstoolbox ik_LM (C++, per call)", f"{us:.4f} ms",
                 f"{ok.mean():.4f}", f"max err {mm[ok].max() * 1e-3 if ok.any() else np.nan:.1e} m",
                 f"{us / ours:.2f}"))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--n-peer", type=int, default=2_000, help="targets for per-call peers")
    ap.add_argument("--threads", type=int, default=None, help="os.sched_setaffinity to this many cores")
    a = ap.parse_args()
    if a.threads:
        os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[: a.threads]))
    cores = len(os.sched_getaffinity(0))
    rows: list[tuple] = []
    for name in ("rx160", "ur10"):
        bench_closed_form(name, a.n, a.n_peer, rows)
    for name in ("rx160", "ur10", "franka-panda"):
        bench_numeric(name, a.n, a.n_peer, rows)
    print(f"\n## IK benchmark ({a.n} targets for hykin, {a.n_peer} for per-call peers, {cores} cores, "
          f"load {os.getloadavg()[0]:.1f})\n")
    print("| task | solver | time / target | recovered / success | notes | ratio vs hykin |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
