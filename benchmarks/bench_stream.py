"""Dynamic collection at scale, end to end through the CLI (issue "From a plan to the robot and back").

A plan-to-model run on a virtual robot:

1. ``hykin plan ROBOT --trajectory`` through ``--waypoints`` safe waypoints (minimum-jerk, joint limits);
2. ``hykin simulate PRESET --trajectory --stream``: robot log at ``--robot-rate`` Hz, tracker stream at
   ``--tracker-rate`` Hz with a clock offset, latency, drift, noise, dropouts and beam loss at speed;
3. ``hykin import stream`` (timed, peak memory from ``/usr/bin/time``): aligned poses and the clock
   offset found, against the truth;
4. ``hykin fit`` on the streamed poses, on the same number of static (noise-only) samples of the same
   virtual robot (``hykin simulate -n``), and on ``--static-small`` static poses; ``hykin evaluate`` of
   all three on one static test set.

Prints the figures and the ratios streamed/static-same-N and streamed/static-small.
``python benchmarks/bench_stream.py`` runs the issue's scale (≥ 250,000 aligned poses, about 40 min of
trajectory); ``--waypoints 150`` is a quick look.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _hykin(args, cwd, timed=False):
    cmd = [sys.executable, "-m", "hykin", *args]
    if timed:
        cmd = ["/usr/bin/time", "-v", *cmd]
    t0 = time.perf_counter()
    r = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    dt = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"hykin {' '.join(args)} failed:\n{r.stderr[-2000:]}")
    rss = None
    if timed:
        m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", r.stderr)
        rss = int(m.group(1)) / 1024**2 if m else None
    return r.stdout + r.stderr, dt, rss


def _mean_mm(report_json: str, row: str) -> float:
    d = json.loads(report_json)
    for k in ("hybrid", "models"):
        if k in d:
            break
    rows = d.get("rows") or d
    for r in rows if isinstance(rows, list) else [rows]:
        if isinstance(r, dict) and r.get("model") == row:
            return float(r["pos_mean_mm"])
    raise KeyError(row)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rx160-virtual")
    ap.add_argument("--robot", default="rx160", help="nominal robot file/preset of the plan and the fits")
    ap.add_argument("--waypoints", type=int, default=900)
    ap.add_argument("--speed", type=float, default=45.0, help="joint speed limit (deg/s)")
    ap.add_argument("--robot-rate", type=float, default=250.0)
    ap.add_argument("--tracker-rate", type=float, default=1000.0)
    ap.add_argument("--max-speed", type=float, default=0.5, help="import: drop samples faster than this (m/s)")
    ap.add_argument("--static-small", type=int, default=12_000)
    ap.add_argument("--min-steps", type=int, default=0, help="fit option (0: hykin's default recipe)")
    ap.add_argument("--no-fit", action="store_true", help="stop after the import")
    ap.add_argument("--dir", default=None, help="work folder (default: a temporary one)")
    a = ap.parse_args()
    work = Path(a.dir or tempfile.mkdtemp(prefix="bench_stream_"))
    work.mkdir(parents=True, exist_ok=True)
    env_note = f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '(unset)')}"
    print(f"bench_stream: {a.preset}, {a.waypoints} waypoints at {a.speed:g} deg/s, robot {a.robot_rate:g} Hz, "
          f"tracker {a.tracker_rate:g} Hz; work folder {work}; {env_note}")
    out, dt, _ = _hykin(["plan", a.robot, "-n", str(a.waypoints), "--trajectory", "--max-joint-speed", str(a.speed),
                         "--floor", "0", "--rate", "250", "-o", "traj.csv", "--force"], work)
    print(f"plan --trajectory: {dt:.0f} s; {out.strip().splitlines()[-1]}")
    out, dt, rss = _hykin(["simulate", a.preset, "--trajectory", "traj.csv", "--stream", "-o", "cell", "--robot-rate",
                           str(a.robot_rate), "--tracker-rate", str(a.tracker_rate), "--force"], work, timed=True)
    print(f"simulate --stream: {dt:.0f} s, {rss:.2f} GB; {[ln for ln in out.splitlines() if ln.startswith('wrote')][0]}")
    truth = json.loads((work / "cell" / "clock_truth.json").read_text())
    out, dt, rss = _hykin(["import", "stream", "cell/robot_log.csv", "cell/tracker.csv", "--robot", a.robot, "-o",
                           "streamed.csv", "--fit-drift", "--max-speed", str(a.max_speed), "--force"], work, timed=True)
    line = [ln for ln in out.splitlines() if ln.startswith("wrote")][0]
    n_al = int(line.split("wrote ")[1].split(" ")[0])
    off_ms = float(line.split("clock offset ")[1].split(" ms")[0])
    print(f"import stream: {dt:.1f} s (limit 120), peak {rss:.2f} GB (limit 4); {n_al} aligned poses; clock offset "
          f"{off_ms:.4f} ms vs truth {truth['offset_s'] * 1e3:.4f} ms: error {abs(off_ms - truth['offset_s'] * 1e3):.4f} ms "
          f"(limit 0.2)")
    if a.no_fit:
        return
    fit_opts = [] if a.min_steps == 0 else ["--min-steps", str(a.min_steps)]
    _hykin(["simulate", a.preset, "-n", str(n_al), "-o", "static_same.csv", "--seed", "11", "--force"], work)
    _hykin(["simulate", a.preset, "-n", str(a.static_small), "-o", "static_small.csv", "--seed", "12", "--force"], work)
    _hykin(["simulate", a.preset, "-n", "5000", "-o", "test.csv", "--seed", "13", "--force"], work)
    res = {}
    for name, data in (("streamed", "streamed.csv"), ("static same N", "static_same.csv"),
                       (f"static {a.static_small}", "static_small.csv")):
        _, dt, _ = _hykin(["fit", a.robot, data, "-o", f"{name.replace(' ', '_')}.hykin", "--force", *fit_opts], work)
        out, _, _ = _hykin(["evaluate", f"{name.replace(' ', '_')}.hykin", "test.csv", "--json"], work)
        res[name] = (out, dt)
        print(f"fit on {name}: {dt:.0f} s")
    print("held-out (5000 static test poses):")
    for name, (js, _) in res.items():
        print(f"  {name:>16}: {js.strip()[:400]}")


if __name__ == "__main__":
    main()
