"""Forward-kinematics speed: hykin (numba) vs Pinocchio, roboticstoolbox-python and torch, same run.

    python benchmarks/bench_fk.py [--robot ur5] [--n 1000000] [--single 20000]

Measures, for one 6-DOF arm (TCP pose as a 4x4 float64 matrix):
* batched FK of ``--n`` random configurations: ``hykin.fk`` (numba, all cores), ``fk_torch`` (CPU,
  float64), ``roboticstoolbox`` ``ETS.eval`` on a batch (if installed), a Python loop over Pinocchio;
* single-pose FK latency: ``hykin.fk(robot, q)``, ``pin.forwardKinematics`` (+ frame update) and
  ``ETS.eval(q)``.
Pinocchio is given the same kinematics (DH joint placements as ``pin.SE3``). Prints markdown tables
with ratios against hykin. Timings are best-of-3 wall clock.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _timing import best_of

from hykin.io.robot_file import load_robot
from hykin.kinematics.chain import chain_of
from hykin.kinematics.fk import fk, fk_torch


def best_time(fn, repeat: int = 3) -> float:
    """Best wall time of ``repeat`` calls, seconds."""
    return best_of(fn, repeat)[0]


def pin_model(robot):
    """Pinocchio model with hykin's joint frames as joint placements and the TCP as a frame."""
    import pinocchio as pin

    ch = chain_of(robot)
    model = pin.Model()
    parent, prev = 0, np.eye(4)
    for i in range(robot.dof):
        place = prev @ ch.pre[i] if i else robot.base @ ch.pre[0]
        jm = pin.JointModelPZ() if ch.prismatic[i] else pin.JointModelRZ()
        parent = model.addJoint(parent, jm, pin.SE3(place[:3, :3].copy(), place[:3, 3].copy()), f"j{i}")
        prev = ch.post[i]
    tail = prev @ robot.tool
    fid = model.addFrame(pin.Frame("tcp", parent, 0, pin.SE3(tail[:3, :3].copy(), tail[:3, 3].copy()), pin.FrameType.OP_FRAME))
    return model, fid


def rtb_ets(robot):
    """roboticstoolbox ETS of a standard-DH robot (None if unavailable)."""
    try:
        import roboticstoolbox as rtb
    except Exception:  # noqa: BLE001 - optional peer
        return None
    if robot.convention != "dh" or np.any(robot.beta_rad) or not np.allclose(robot.base, np.eye(4)):
        return None
    links = [
        rtb.RevoluteDH(a=a, alpha=al, d=d, offset=th)
        for a, al, d, th in zip(robot.a_m, robot.alpha_rad, robot.d_m, robot.theta_rad)
    ]
    return rtb.DHRobot(links, tool=robot.tool).ets()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", default="ur5")
    ap.add_argument("--n", type=int, default=1_000_000, help="batch size for batched FK")
    ap.add_argument("--single", type=int, default=20_000, help="calls for single-pose latency")
    args = ap.parse_args()

    robot = load_robot(args.robot)
    rng = np.random.default_rng(0)
    Q = robot.random_joints(args.n, rng)
    q1 = Q[0].copy()
    rows_b, rows_s = [], []  # (name, seconds per pose, note)

    # ---- hykin
    fk(robot, Q[:50_000])  # compile + warm caches
    fk(robot, q1)
    t = best_time(lambda: fk(robot, Q))
    rows_b.append(("hykin `fk` (numba)", t / args.n, f"{args.n:,} poses"))
    ns = args.single
    def hykin_single():
        for _ in range(ns):
            fk(robot, q1)

    t = best_time(hykin_single)
    rows_s.append(("hykin `fk(robot, q)`", t / ns, ""))
    T_ref = fk(robot, Q[:1000])

    # ---- torch
    try:
        import torch

        Qt = torch.as_tensor(Q)
        with torch.no_grad():
            Tt = fk_torch(robot, Qt[:1000]).numpy()
            assert np.abs(Tt - T_ref).max() < 1e-12
            t = best_time(lambda: fk_torch(robot, Qt))
        rows_b.append((f"hykin `fk_torch` (CPU float64, {torch.get_num_threads()} threads)", t / args.n, f"{args.n:,} poses"))
    except ImportError:
        pass

    # ---- Pinocchio
    try:
        import pinocchio as pin

        model, fid = pin_model(robot)
        data = model.createData()
        pin.forwardKinematics(model, data, q1)
        pin.updateFramePlacement(model, data, fid)
        assert np.abs(data.oMf[fid].homogeneous - fk(robot, q1)).max() < 1e-12

        def pin_single():
            for _ in range(ns):
                pin.forwardKinematics(model, data, q1)
                pin.updateFramePlacement(model, data, fid)

        def pin_fk_only():
            for _ in range(ns):
                pin.forwardKinematics(model, data, q1)

        rows_s.append(("Pinocchio `forwardKinematics` + `updateFramePlacement`", best_time(pin_single) / ns, ""))
        rows_s.append(("Pinocchio `forwardKinematics` only (joint placements)", best_time(pin_fk_only) / ns, ""))
        nl = min(args.n, 100_000)
        Ql = Q[:nl]

        def pin_loop():
            out = np.empty((nl, 4, 4))
            for k in range(nl):
                pin.forwardKinematics(model, data, Ql[k])
                out[k] = pin.updateFramePlacement(model, data, fid).homogeneous
            return out

        rows_b.append(("Pinocchio, Python loop", best_time(pin_loop, 2) / nl, f"{nl:,} poses"))
    except ImportError:
        rows_s.append(("Pinocchio", float("nan"), "not installed"))

    # ---- roboticstoolbox
    ets = rtb_ets(robot)
    if ets is not None:
        assert np.abs(ets.eval(q1) - fk(robot, q1)).max() < 1e-12
        nr = min(args.n, 100_000)
        Qr = Q[:nr]
        rows_b.append(("roboticstoolbox `ets.eval` (batched)", best_time(lambda: ets.eval(Qr), 2) / nr, f"{nr:,} poses"))
        def rtb_single():
            for _ in range(ns):
                ets.eval(q1)

        rows_s.append(("roboticstoolbox `ets.eval(q)`", best_time(rtb_single) / ns, ""))
    else:
        rows_b.append(("roboticstoolbox", float("nan"), "not installed (or not a plain DH robot)"))

    try:
        import numba

        threads = numba.get_num_threads()
    except ImportError:
        threads = 1
    print(f"## FK speed — {robot.name} ({robot.dof} DOF), {os.cpu_count()} CPUs, numba threads {threads}\n")
    print("### Batched FK\n")
    print("| method | poses/s | ns/pose | hykin speed-up | batch |")
    print("|---|---:|---:|---:|---|")
    base = rows_b[0][1]
    for name, s, note in rows_b:
        if np.isnan(s):
            print(f"| {name} | – | – | – | {note} |")
        else:
            print(f"| {name} | {1 / s / 1e6:.2f} M | {s * 1e9:.0f} | {s / base:.1f}x | {note} |")
    print("\n### Single-pose FK latency\n")
    print("| method | µs/call | hykin speed-up |")
    print("|---|---:|---:|")
    base = rows_s[0][1]
    for name, s, note in rows_s:
        if np.isnan(s):
            print(f"| {name} | – | {note} |")
        else:
            print(f"| {name} | {s * 1e6:.2f} | {s / base:.2f}x |")


if __name__ == "__main__":
    main()
