"""The generated battery (issue #24): random robots x random measurement campaigns through the CLI.

Each draw writes a robot file and data to disk (:mod:`hykin.sim.random_campaigns`), runs
``hykin fit ROBOT train.csv -o model.hykin`` and ``hykin evaluate model.hykin test.csv --json`` in
process, exactly as a user's shell would, and judges the result (:mod:`hykin.sim.battery`): a correct
input must give a model within ``FLOOR_FACTOR x`` the truth's noise floor (+ slack) on held-out poses,
a mistake must be refused with one line naming its cause. Prints the pass rate per family and every
failure with its family, seed, cause and the command that reproduces it.

    python benchmarks/bench_battery.py --draws 500 --seed 0
    python benchmarks/bench_battery.py --families tracker,urdf --draws 40
    python benchmarks/bench_battery.py --families slip-mm --seed 17 --draws 1   # one draw
    python benchmarks/bench_battery.py --draws 2000 --jobs 16                    # a many-core machine

Draws are spread round-robin over the families; draw ``k`` of a family uses seed ``SEED + k``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shlex
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

for _v in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ.setdefault(_v, "1")


def run_draw(family: str, seed: int, folder: Path, extra_fit_args: tuple = ()):
    """Draw and run one campaign -> Verdict; a failure to even draw it is a crash of the generator.
    ``extra_fit_args``: further ``hykin fit`` options for every draw (e.g. ``--prior ...``)."""
    import warnings

    from hykin.sim.battery import Verdict, run_campaign
    from hykin.sim.random_campaigns import draw_campaign
    from tests.cli_run import run_captured

    warnings.simplefilter("ignore")
    try:
        c = draw_campaign(family, seed)
    except Exception as e:
        return Verdict(family, seed, False, "crash", f"generator failed: {type(e).__name__}: {e}")
    c.fit_args = [*c.fit_args, *extra_fit_args]
    return run_campaign(c, folder, run_captured)


def main(argv=None) -> int:
    import warnings

    from hykin.sim.random_campaigns import FAMILIES

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--draws", type=int, default=500, help="total number of draws, spread over the families")
    ap.add_argument("--seed", type=int, default=0, help="first seed; draw k of a family uses seed + k")
    ap.add_argument("--families", default="all", help="comma-separated families (default all): " + ", ".join(FAMILIES))
    ap.add_argument("--keep", type=Path, default=None, help="keep each draw's files under this folder")
    ap.add_argument("--verbose", action="store_true", help="print every draw's verdict")
    ap.add_argument("--jobs", type=int, default=1, help="draws run in this many processes (same verdicts)")
    ap.add_argument("--fit-args", default="", help="further hykin fit options for every draw, e.g. "
                    "'--prior excitation_residual=1'")
    a = ap.parse_args(argv)
    fams = list(FAMILIES) if a.families == "all" else [f.strip() for f in a.families.split(",") if f.strip()]
    bad = [f for f in fams if f not in FAMILIES]
    if bad:
        ap.error(f"unknown families {bad}; choose from {', '.join(FAMILIES)}")
    warnings.simplefilter("ignore")
    results = defaultdict(list)
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        root = a.keep or Path(tmp)
        todo = [(fams[k % len(fams)], a.seed + k // len(fams)) for k in range(a.draws)]
        extra = tuple(shlex.split(a.fit_args))
        todo = [(f, s, root / f"{f}-{s}", extra) for f, s in todo]
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max(a.jobs, 1)) if a.jobs > 1 else contextlib.nullcontext() as pool:
            verdicts = pool.map(run_draw, *zip(*todo)) if pool else (run_draw(*t) for t in todo)
            for v in verdicts:
                results[v.family].append(v)
                if a.verbose or not v.ok:
                    print(v.summary(), flush=True)
    dt = time.perf_counter() - t0
    total = sum(len(v) for v in results.values())
    passed = sum(x.ok for v in results.values() for x in v)
    print(f"\n{total} draws in {dt:.0f} s ({dt / max(total, 1):.2f} s per draw), seeds from {a.seed}")
    print(f"{'family':22s} {'pass':>9s}  {'models':>6s} {'max err/floor':>13s}  (failures below: seed: cause)")
    for fam in fams:
        vs = results.get(fam, [])
        if not vs:
            continue
        ok = sum(v.ok for v in vs)
        ratios = [v.error_mm / v.floor_mm for v in vs if v.error_mm == v.error_mm and v.floor_mm > 0]
        worst = f"{max(ratios):13.2f}" if ratios else f"{'-':>13s}"
        print(f"{fam:22s} {ok:4d}/{len(vs):<4d}  {len(ratios):6d} {worst}  {FAMILIES[fam]}")
        for v in vs:
            if not v.ok:
                print(f"{'':28s} seed {v.seed}: {v.cause}")
    print(f"{'all':22s} {passed:4d}/{total:<4d}")
    failed = [x for v in results.values() for x in v if not x.ok]
    if failed:
        print("\nreproduce a failure:\n" + failed[0].reproduce())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
