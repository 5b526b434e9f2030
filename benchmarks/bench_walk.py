"""The compensator's default walk (no joints given: each target on the nominal branch nearest the
previous one), compiled against its Python row loop, in the same run.

    python benchmarks/bench_walk.py [--n 10000] [--repeats 3]

UR-like robot of ``bench_compensator.py`` (its model fitted on 1,000 noisy poses, 3 epochs), a smooth
path of ``--n`` targets; ``Compensator(model)(T)`` with ``hykin.compensation.branches._walk`` as
compiled and set to None (the Python loop over ``Candidates.nearest``), alternately. Prints targets/s
of each and their ratio; the joints of both are checked equal.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_compensator as bc  # noqa: E402

import hykin  # noqa: E402
from hykin.compensation import branches  # noqa: E402
from hykin.hybrid.model import HybridModel  # noqa: E402
from hykin.sim.simulate import simulate, true_poses  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=10_000)
    ap.add_argument("--repeats", type=int, default=3)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    vr = bc.robots()[0]
    nom = vr.nominal
    m = HybridModel(nom, recipe_kw={"max_epochs": 3}, seed=0).fit(
        simulate(vr, nom.random_joints(1000, 1, margin=0.05), noise=True, rng=1), progress=False)
    t = np.linspace(0, 1, a.n)[:, None]
    q0, amp = np.array([0.3, -1.4, 1.5, -1.7, -1.5, 0.4]), np.array([0.8, 0.3, 0.4, 0.6, 0.5, 1.0])
    T = true_poses(vr, q0 + amp * np.sin(2 * np.pi * t * np.array([1.0, 2.0, 1.5, 3.0, 2.5, 4.0])))
    C = hykin.Compensator(m)
    C(T[:10])
    compiled = branches._walk
    if compiled is None:
        raise SystemExit("numba missing: no compiled walk to compare")
    rates = {"compiled": [], "python": []}
    qs = {}
    try:
        for _ in range(a.repeats):
            for name, fn in (("compiled", compiled), ("python", None)):
                branches._walk = fn
                s = time.perf_counter()
                c = C(T)
                rates[name].append(a.n / (time.perf_counter() - s))
                qs[name] = c.q
    finally:
        branches._walk = compiled
    same = np.array_equal(qs["compiled"], qs["python"], equal_nan=True)
    for name, r in rates.items():
        print(f"{name} walk: {min(r):,.0f}-{max(r):,.0f} targets/s ({a.n} targets, {a.repeats} runs)")
    print(f"compiled / python: {np.median(rates['compiled']) / np.median(rates['python']):.2f}x (medians); joints equal: {same}")


if __name__ == "__main__":
    main()
