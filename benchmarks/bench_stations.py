"""Several stations in one dataset (issue #24): the bundle fit against the same fit given the true frames.

A virtual 7R arm of this benchmark's own (its own DH table, geometric deviations, transmission errors
on joints 2 and 3, measurement noise) is measured from two stations (instrument placements). The
dataset carries a ``station`` column and nothing else; ``hykin fit`` fits every station's frame jointly
with the robot. The reference is the same fit on the same rows transformed BY HAND into the robot base
with the true frames. Held-out errors (mean position, mm; test rows from both stations) and their ratio:

1. two stations 5 m apart and turned, ~2-6 m from the robot: positions only and 6-D, through the CLI
   (``hykin fit`` / ``hykin evaluate`` in a subprocess, as a user would);
2. positions only, the robot 12 m from one station and 45 m from the other (a total station), through
   the Python API (``HybridModel(robot).fit``, the path the CLI runs): today's file check refuses
   positions over 10 m as "millimetres passed as metres" (issue #24, being fixed separately), so
   those files cannot be read by the CLI yet.

``--min-steps`` (default 3000) keeps network training short; both fits of a pair use the same settings.
The times (``s``) are not compared: the machine is shared.

``--min-steps 0``: no override at all (``hykin fit ROBOT TRAIN -o MODEL``, the recipe's 30,000 steps).

Usage: ``python benchmarks/bench_stations.py [--min-steps 3000] [--n 1500] [--cases near-pos,near-6d,far]``
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hykin.geometry import se3
from hykin.io.dataset import Dataset
from hykin.io.dataset_files import write_dataset
from hykin.io.robot_toml import save_robot_toml
from hykin.kinematics.robot import Robot
from hykin.sim.simulate import PeriodicError, VirtualRobot, geometric_deviation, simulate

D = np.pi / 180


def arm7() -> Robot:
    """A 7R arm (redundant, offset shoulder), not a preset."""
    return Robot(name="bench-arm7", convention="dh",
                 a_m=[0.08, 0.0, 0.05, -0.05, 0.0, 0.0, 0.0], alpha_rad=np.array([-90, 90, -90, 90, -90, 90, 0]) * D,
                 d_m=[0.40, 0.0, 0.42, 0.0, 0.40, 0.0, 0.12], theta_rad=np.zeros(7),
                 lower=np.array([-170, -110, -170, -120, -170, -120, -175]) * D,
                 upper=np.array([170, 110, 170, 120, 170, 120, 175]) * D, tool=se3.trans(0.0, 0.03, 0.10))


def frames(far: bool) -> dict[str, np.ndarray]:
    """Station -> robot base. Near: 5 m apart, turned 40° / 138°; far: the robot 12 m and 45 m away."""
    if far:
        return {"S12": se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, 0.9])), np.array([11.0, -4.0, 2.5])),
                "S45": se3.make_transform(se3.rotvec_to_matrix(np.array([0.01, 0.02, -2.2])), np.array([-30.0, 33.0, -3.0]))}
    return {"A": se3.make_transform(se3.rotvec_to_matrix(np.array([0.0, 0.0, 0.7])), np.array([2.0, 0.0, 0.5])),
            "B": se3.make_transform(se3.rotvec_to_matrix(np.array([0.05, -0.03, 2.4])), np.array([-1.0, 4.0, 0.7]))}


def campaign(n: int, seed: int, orientation: bool, far: bool, noise_m: float):
    rng = np.random.default_rng(seed)
    nom = arm7()
    truth = geometric_deviation(nom, rng, 0.5e-3, 0.5e-3, 0, 0).copy(base=np.eye(4))
    vr = VirtualRobot("v", nom, truth, transmission=[PeriodicError(2, 2e-4, 2.0), PeriodicError(3, 1.5e-4, 3.0, phase_rad=0.4)],
                      noise_position_m=noise_m, noise_orientation_rad=noise_m / 0.5)
    q = nom.random_joints(n, rng)
    T = simulate(vr, q, rng=rng).poses()
    fr = frames(far)
    labels = np.array(list(fr))[(np.arange(n) % 5 >= 3).astype(int)]  # 60 / 40 % of the rows
    Tm = np.stack([fr[s] for s in labels]) @ T
    data = Dataset.from_poses(q, Tm, extra={"station": labels}, orientation=orientation)
    hand = Dataset.from_poses(q, T, orientation=orientation)  # the true frames applied by hand
    return nom, data, hand


def cli(*args) -> str:
    env = dict(os.environ, OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    r = subprocess.run([sys.executable, "-m", "hykin", *map(str, args)], capture_output=True, text=True, env=env)
    if r.returncode:
        raise SystemExit(f"hykin {' '.join(map(str, args))} failed: {r.stderr.strip()}")
    return r.stdout


def near_case(tmp: Path, orientation: bool, n: int, min_steps: int) -> dict:
    nom, data, hand = campaign(n, 1, orientation, far=False, noise_m=20e-6)
    save_robot_toml(nom, tmp / "arm7.toml")
    ntr = int(0.8 * n)
    out = {}
    for tag, d in (("bundle", data), ("hand", hand)):
        write_dataset(d.subset(np.arange(ntr)), tmp / f"{tag}_train.csv")
        write_dataset(d.subset(np.arange(ntr, n)), tmp / f"{tag}_test.csv")
        t0 = time.perf_counter()
        steps = ["--min-steps", min_steps] if min_steps else []  # 0: no override (the recipe's default)
        cli("fit", tmp / "arm7.toml", tmp / f"{tag}_train.csv", "-o", tmp / f"{tag}.hykin", *steps, "--force")
        ev = json.loads(cli("evaluate", tmp / f"{tag}.hykin", tmp / f"{tag}_test.csv", "--json"))["stats"]
        out[tag] = {k: ev[k]["pos_mean_mm"] for k in ("calibrated", "hybrid")} | {"s": time.perf_counter() - t0}
    return out


def far_case(n: int, min_steps: int) -> dict:
    from hykin.evaluation.evaluate import evaluate_model
    from hykin.hybrid.model import HybridModel

    nom, data, hand = campaign(n, 2, False, far=True, noise_m=0.1e-3)  # total station: 0.1 mm per axis
    ntr = int(0.8 * n)
    out = {}
    for tag, d in (("bundle", data), ("hand", hand)):
        t0 = time.perf_counter()
        m = HybridModel(nom, recipe_kw={"min_steps": min_steps} if min_steps else None).fit(d.subset(np.arange(ntr)), progress=False)
        ev = evaluate_model(m, d.subset(np.arange(ntr, n))).stats
        out[tag] = {k: ev[k].pos_mean_mm for k in ("calibrated", "hybrid")} | {"s": time.perf_counter() - t0}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--min-steps", type=int, default=3000)
    ap.add_argument("--n", type=int, default=1500)
    ap.add_argument("--cases", default="near-pos,near-6d,far", help="Comma-separated: near-pos, near-6d, far.")
    a = ap.parse_args()
    names = {"near-pos": "two stations 5 m apart, positions only (CLI)", "near-6d": "two stations 5 m apart, 6-D (CLI)",
             "far": "positions only, 12 m and 45 m from the stations (API)"}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for c in a.cases.split(","):
            r = far_case(a.n, a.min_steps) if c == "far" else near_case(Path(tmp), c == "near-6d", a.n, a.min_steps)
            rows.append((names[c], r))
    print(f"held-out mean position error (mm), {a.n} rows (80 % train), "
          + (f"--min-steps {a.min_steps}" if a.min_steps else "no training override (recipe default)"))
    print(f"{'case':<56} {'bundle cal':>10} {'bundle hyb':>10} {'hand cal':>9} {'hand hyb':>9} {'hyb ratio':>9}")
    for name, r in rows:
        b, h = r["bundle"], r["hand"]
        print(f"{name:<56} {b['calibrated']:10.4f} {b['hybrid']:10.4f} {h['calibrated']:9.4f} {h['hybrid']:9.4f} "
              f"{b['hybrid'] / h['hybrid']:9.3f}")


if __name__ == "__main__":
    main()
