"""The orientation-conflict bound (:mod:`hykin.calibration.consistency`) on the generated battery's campaigns.

For each draw: the campaign's files are written and read back as ``hykin fit`` reads them, and calibrated
with the checks on. Prints per family how many were refused by the orientation-conflict check, by another
check, or passed, and the largest ratio (6-D position RMS / positions-alone RMS) among the draws that
passed: the margin of the bound (3) on correct data. The calibration only (no networks), so hundreds of
draws take minutes.

    python benchmarks/bench_orientation_conflict.py --families dh,mdh,slip-xyzw --draws 40 --seed 1000
"""

from __future__ import annotations

import argparse
import tempfile
from collections import defaultdict
from pathlib import Path

CORRECT_6D = ["dh", "mdh", "prismatic", "data-units", "tracker", "noise", "payload", "thermal", "subregion",
              "few-poses", "urdf", "urdf-prismatic", "sweeps"]


def _opt(args: list[str], name: str, default: str) -> str:
    return args[args.index(name) + 1] if name in args else default


def main() -> None:
    from hykin.calibration.calibrate import calibrate
    from hykin.calibration.result import CalibrationError
    from hykin.io.dataset_files import read_dataset
    from hykin.io.robot_file import load_robot
    from hykin.sim.random_campaigns import draw_campaign

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--families", default=",".join(CORRECT_6D + ["slip-xyzw"]))
    ap.add_argument("--draws", type=int, default=10, help="draws per family")
    ap.add_argument("--seed", type=int, default=1000)
    a = ap.parse_args()
    stats: dict = defaultdict(lambda: {"conflict": 0, "other": 0, "pass": 0, "ratios": [], "msgs": []})
    for fam in a.families.split(","):
        for k in range(a.draws):
            seed = a.seed + k
            c = draw_campaign(fam, seed)
            st = stats[fam]
            with tempfile.TemporaryDirectory() as d:
                p = c.write(Path(d))
                try:
                    rob = load_robot(p["robot"])
                    ds = read_dataset(p["train"], robot=rob, length_unit=_opt(c.fit_args, "--length-unit", "m"),
                                      angle_unit=_opt(c.fit_args, "--angle-unit", "rad"))
                    res = calibrate(rob, ds)
                except (CalibrationError, ValueError) as e:
                    kind = "conflict" if "contradict the positions" in str(e) else "other"
                    st[kind] += 1
                    st["msgs"].append(f"seed {seed} {kind}: {str(e)[:300]}")
                    continue
                st["pass"] += 1
                po = getattr(res, "position_only_rms_mm", None)
                if po:
                    st["ratios"].append((res.after["pos_rms_mm"] / po, seed))
        st = stats[fam]
        worst = max(st["ratios"]) if st["ratios"] else (float("nan"), -1)
        print(f"{fam:>16}: {st['pass']} calibrated, {st['conflict']} refused (orientation conflict), {st['other']} refused "
              f"(other); largest 6-D / positions-alone RMS ratio among the calibrated {worst[0]:.3f} (seed {worst[1]})",
              flush=True)
        for m in st["msgs"]:
            print("    " + m)


if __name__ == "__main__":
    main()
