"""Dynamic collection at scale, end to end through the CLI (issue "From a plan to the robot and back").

A plan-to-model run on one virtual robot:

1. ``hykin plan ROBOT --trajectory`` through ``--waypoints`` safe waypoints (minimum-jerk, joint limits,
   floor at z = 0, body checks);
2. ``hykin simulate TRUTH --trajectory --stream``: robot log at ``--robot-rate`` Hz, tracker stream at
   ``--tracker-rate`` Hz with a clock offset, latency, drift, tracker noise, dropouts and beam loss at speed;
3. ``hykin import stream`` in two passes (docs/dynamic-collection.md): pass 1 with the robot file keeps the samples
   up to ``--first-pass-speed`` (0.1 m/s), a fit on them, pass 2 with that model file (its hybrid
   positions time the clock) keeps those up to ``--max-speed``. Each import is timed (peak memory of that
   process from ``os.wait4``'s rusage, the per-child form of ``resource.getrusage(RUSAGE_CHILDREN)``, so
   no ``/usr/bin/time`` is needed); aligned poses, clock offset and drift found, against the truth.
   ``--one-pass``: one import with the robot file (what an earlier version did);
4. the static sets, all measured on the SAME virtual robot (the truth file the stream was recorded from),
   position only like the stream, with the same tracker noise and nothing else (noise-only):
   * ``static_same``: the streamed poses' own joints (same N, same region, same order), measured standing
     still -- the only difference to the streamed set is what dynamic collection adds (robot log
     interpolation, clock offset/drift estimate, latency, motion during a sample);
   * ``static_small``: ``--static-small`` (12,000) of those joints drawn at random (the paper's static
     campaign, Table III, in the same region);
   * ``test``: ``--test-poses`` independent poses from a second ``hykin plan`` (other seed, same robot, same
     floor and body constraints, so the same region), measured WITHOUT noise: errors are against the true
     pose, not against a noisy reading;
5. ``hykin fit`` on the three sets with the same options (``--device``, ``--fit-args``), ``hykin evaluate``
   of each on the test set; prints the figures and a MET / NOT MET line for the issue's two conditions
   (streamed hybrid <= 1.2 x the static same-N hybrid; streamed hybrid < the 12,000-pose hybrid).

``--dir DIR`` keeps every file (and ``results.json``) there; ``--reuse`` skips plan and simulate when
``DIR`` holds the recorded cell (``cell/``), ``robot.truth.json``, ``traj.csv`` and the test poses; the
imports and fits run again.

**Fit options for the paper's scale on a GPU**: ``--device cuda --fit-args "--max-epochs 8 --max-minutes 1.5"
--small-fit-args "--max-minutes 1.5"``. hykin's default recipe trains each network for max(200 epochs,
30,000 steps) at batch 256; position-only data train one network per fit. On 374k training rows (415k
aligned poses, 10 % held out) 200 epochs are 292,000 steps per fit -- far too long for three fits in ~5
minutes. The training time is steps x (time per step), and a step at batch 256 of the 9.7k-parameter
default MLP is launch/sync-bound on a GPU (the loop reads the loss back every step), so it hardly depends
on N or the batch. Measured here (CPU, 1 thread, on the shared 2-core machine at load ~12): 43 ms per step
in the reduced-scale fit (1,278 steps in 55 s), 25 ms in a bare loop; an H100 step is estimated at
<= 1.5 ms (kernel launches + one sync; NOT measured). ``--max-epochs 8``: 8 x 1,460 = 11,680 steps per large
fit (~18 s at 1.5 ms); the 12k fit keeps hykin's default recipe (30,000 steps, ~45 s): at the large sets'
8 epochs it would get only 344 steps, so the small set is given its best, not the large sets' budget.
(At the present planner's 43.2-min trajectory the import gives 492,735 poses: 1,733 steps per epoch, 13,864
steps at 8 epochs, ~21 s.) ``--max-minutes 1.5`` caps each network's training whatever the step time turns out to be (the best
weights so far are kept; the fit says how far it got). The other costs are on the CPU cores: the float64
calibration (121k positions: 2 min 55 s here at load ~12, 1 thread; 415k: ~3.4x that single-threaded)
and the prediction bands (52 s here). Estimated total for the three fits on the 16-core H100 machine:
3-5 minutes, dominated by the two large calibrations -- the first run will tell; the script prints each
fit's seconds.

Reduced scale (proves the chain; not the issue's figure): ``--waypoints 150 --static-small 3000
--test-poses 300 --fit-args "--max-epochs 3" --small-fit-args "--max-epochs 40"``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def _hykin(args, cwd):
    """Run ``python -m hykin ARGS`` in ``cwd`` -> (output, seconds, peak RSS GB of that process or None)."""
    cmd = [sys.executable, "-m", "hykin", *args]
    t0 = time.perf_counter()
    with tempfile.TemporaryFile() as fo:
        p = subprocess.Popen(cmd, cwd=cwd, stdout=fo, stderr=subprocess.STDOUT)
        rss = None
        if hasattr(os, "wait4"):
            _, status, ru = os.wait4(p.pid, 0)
            p.returncode = os.waitstatus_to_exitcode(status)
            rss = ru.ru_maxrss / 1024**2 if sys.platform.startswith("linux") else ru.ru_maxrss / 1024**3  # KB / B
        else:  # pragma: no cover - no wait4 (Windows): no per-process peak
            p.wait()
        fo.seek(0)
        out = fo.read().decode("utf-8", "replace")
    dt = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"hykin {' '.join(args)} failed (exit {p.returncode}):\n{out[-3000:]}")
    return out, dt, rss


def _line(out: str, start: str) -> str:
    lines = [ln for ln in out.splitlines() if ln.strip().startswith(start)]
    return lines[-1].strip() if lines else out.strip().splitlines()[-1]


def _hybrid_mean_mm(report: str) -> float:
    """Mean position error (mm) of the model's hybrid row of ``hykin evaluate --json`` (after any warning lines)."""
    d = json.loads(report[report.index("{"):])
    return float(d["stats"]["hybrid"]["pos_mean_mm"])


def _import(work: Path, a, robot: str, out_name: str, max_speed: float, label: str) -> dict:
    """``hykin import stream`` of the recorded cell with ``--robot robot`` -> its figures (printed)."""
    truth = json.loads((work / "cell" / "clock_truth.json").read_text())
    out, dt, rss = _hykin(["import", "stream", "cell/robot_log.csv", "cell/tracker.csv", "--robot", robot, "-o",
                           out_name, "--fit-drift", "--max-speed", str(max_speed), "--force"], work)
    line = _line(out, "wrote")
    n_al = int(line.split("wrote ")[1].split(" ")[0])
    off_ms = float(line.split("clock offset ")[1].split(" ms")[0])
    drift_ppm = float(line.split("drift ")[1].split(" ppm")[0])
    err = abs(off_ms - truth["offset_s"] * 1e3)
    print(f"import stream, {label}: {dt:.1f} s (limit 120), peak {rss:.2f} GB (limit 4); {n_al} aligned poses "
          f"(<= {max_speed:g} m/s); clock offset {off_ms:.4f} ms vs truth {truth['offset_s'] * 1e3:.4f} ms: error "
          f"{err:.4f} ms (limit 0.2); drift {drift_ppm:.4f} ppm vs {truth['drift'] * 1e6:.4f}", flush=True)
    return {"seconds": dt, "peak_gb": rss, "aligned": n_al, "offset_ms": off_ms, "offset_truth_ms": truth["offset_s"] * 1e3,
            "offset_error_ms": err, "drift_ppm": drift_ppm, "drift_truth_ppm": truth["drift"] * 1e6,
            "n_robot": truth["n_robot"], "n_tracker": truth["n_tracker"], "max_speed_m_s": max_speed}


def _two_pass_import(work: Path, a) -> dict:
    """The streamed campaign's import as docs/dynamic-collection.md describes it: pass 1 with the robot file, keeping
    only slow samples (``--first-pass-speed``), whose timing error cannot matter; a fit on them
    (``--fit-args``); pass 2 with that model (its hybrid positions time the clock, method positions)
    keeping samples up to ``--max-speed``. ``--one-pass``: only an import with the robot file."""
    if a.one_pass:
        return _import(work, a, a.robot, "streamed.parquet", a.max_speed, "one pass (robot file)")
    first = _import(work, a, a.robot, "first_pass.parquet", a.first_pass_speed, "pass 1 (robot file)")
    out, dt, rss = _hykin(["fit", a.robot, "first_pass.parquet", "-o", "first_pass.hykin", "--force", "--device", a.device,
                           *shlex.split(a.fit_args)], work)
    (work / "first_pass.fit.log").write_text(out)
    print(f"fit on pass 1: {dt:.0f} s, peak {rss:.2f} GB; {_line(out, 'held_out')}", flush=True)
    second = _import(work, a, "first_pass.hykin", "streamed.parquet", a.max_speed, "pass 2 (the pass-1 model)")
    return {**second, "first_pass": first, "first_pass_fit_seconds": dt}


def _static_sets(work: Path, a, rows_streamed: int) -> None:
    """Noise-only static sets on the stream's robot (``robot.truth.json``, recorded from): same joints, a random subset, test."""
    from hykin.io.dataset import Dataset
    from hykin.io.dataset_files import read_dataset, read_joints, write_dataset
    from hykin.sim.simulate import load_truth, simulate

    vr = load_truth(work / "robot.truth.json")
    streamed = read_dataset(work / "streamed.parquet", dof=vr.truth.dof)
    assert len(streamed) == rows_streamed, (len(streamed), rows_streamed)

    def measure(q, seed, noise=True):
        ds = simulate(vr, q, noise=noise, rng=np.random.default_rng(seed))
        return Dataset(q=ds.q, xyz_m=ds.xyz_m, quat_wxyz=None, source=f"bench_stream static, seed {seed}")

    write_dataset(measure(streamed.q, 11), work / "static_same.parquet")
    pick = np.sort(np.random.default_rng(12).choice(len(streamed), min(a.static_small, len(streamed)), replace=False))
    write_dataset(measure(streamed.q[pick], 12), work / "static_small.parquet")
    q_test, _ = read_joints(work / "test_q.csv", dof=vr.truth.dof)
    write_dataset(measure(q_test, 13, noise=a.test_noise), work / "test.parquet")
    if (work / "test_traj_q.csv").exists():
        q_tr, _ = read_joints(work / "test_traj_q.csv", dof=vr.truth.dof)
        write_dataset(measure(q_tr, 14, noise=a.test_noise), work / "test_traj.parquet")


def _region_note(work: Path, dof: int) -> str:
    """Joint ranges (deg) of the streamed poses and of the test poses, and the share of test poses inside."""
    from hykin.io.dataset_files import read_dataset, read_joints

    qs = read_dataset(work / "streamed.parquet", dof=dof).q
    qt, _ = read_joints(work / "test_q.csv", dof=dof)
    lo, hi = qs.min(0), qs.max(0)
    inside = np.all((qt >= lo) & (qt <= hi), axis=1).mean()
    rng = ", ".join(f"q{j + 1} {np.degrees(lo[j]):.0f}..{np.degrees(hi[j]):.0f}" for j in range(dof))
    return f"streamed joints span {rng} deg; {100 * inside:.1f} % of the test poses lie inside that box"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--preset", default="rx160-virtual", help="virtual robot (hykin presets)")
    ap.add_argument("--robot", default="rx160", help="nominal robot file/preset of the plans, the import and the fits")
    ap.add_argument("--noise-um", type=float, default=10.0,
                    help="tracker position noise per axis (µm) of the stream AND the static training sets")
    ap.add_argument("--waypoints", type=int, default=900)
    ap.add_argument("--speed", type=float, default=45.0, help="joint speed limit (deg/s)")
    ap.add_argument("--robot-rate", type=float, default=250.0)
    ap.add_argument("--tracker-rate", type=float, default=1000.0)
    ap.add_argument("--max-speed", type=float, default=0.5, help="import: drop samples faster than this (m/s)")
    ap.add_argument("--first-pass-speed", type=float, default=0.1, help="pass 1 of the import keeps samples up to this (m/s)")
    ap.add_argument("--one-pass", action="store_true", help="one import with the robot file (no second pass)")
    ap.add_argument("--static-small", type=int, default=12_000)
    ap.add_argument("--test-poses", type=int, default=1000, help="independent planned test poses")
    ap.add_argument("--test-noise", action="store_true", help="measure the test set with noise (default: true poses)")
    ap.add_argument("--device", default="cpu", help="hykin fit --device (cpu, cuda, auto)")
    ap.add_argument("--fit-args", default="", help="more `hykin fit` options for the streamed and same-N fits, "
                    "e.g. \"--max-epochs 6\"")
    ap.add_argument("--small-fit-args", default=None,
                    help="`hykin fit` options for the static-small fit (default: none = hykin's default recipe)")
    ap.add_argument("--no-fit", action="store_true", help="stop after the import")
    ap.add_argument("--dir", "--out-dir", dest="dir", default=None, help="work/output folder (default: a temporary one)")
    ap.add_argument("--reuse", action="store_true", help="skip plan and simulate when DIR holds the recorded cell and test poses")
    a = ap.parse_args()
    work = Path(a.dir or tempfile.mkdtemp(prefix="bench_stream_")).resolve()
    work.mkdir(parents=True, exist_ok=True)
    res: dict = {"args": vars(a)}
    print(f"bench_stream: {a.preset} (tracker noise {a.noise_um:g} µm), {a.waypoints} waypoints at {a.speed:g} deg/s, "
          f"robot {a.robot_rate:g} Hz, tracker {a.tracker_rate:g} Hz; folder {work}; "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', '(unset)')}, cores {os.cpu_count()}", flush=True)

    if not (a.reuse and (work / "cell" / "clock_truth.json").exists() and (work / "test_q.csv").exists()):
        from hykin.sim.presets import virtual_preset
        from hykin.sim.simulate import save_truth

        vr = virtual_preset(a.preset, seed=0)
        save_truth(dataclasses.replace(vr, noise_position_m=a.noise_um * 1e-6), work / "robot.truth.json")
        out, dt, _ = _hykin(["plan", a.robot, "-n", str(a.waypoints), "--trajectory", "--max-joint-speed", str(a.speed),
                             "--floor", "0", "--rate", "250", "-o", "traj.csv", "--force"], work)
        print(f"plan --trajectory: {dt:.0f} s; {_line(out, 'wrote')}", flush=True)
        out, dt, rss = _hykin(["simulate", "robot.truth.json", "--trajectory", "traj.csv", "--stream", "-o", "cell",
                               "--robot-rate", str(a.robot_rate), "--tracker-rate", str(a.tracker_rate), "--force"], work)
        print(f"simulate --stream: {dt:.0f} s, peak {rss:.2f} GB; {_line(out, 'wrote')}", flush=True)
        out, dt, _ = _hykin(["plan", a.robot, "-n", str(a.test_poses), "--floor", "0", "--seed", "1", "--angle-unit",
                             "rad", "-o", "test_q.csv", "--force"], work)
        print(f"plan (test poses, seed 1): {dt:.0f} s; {_line(out, 'wrote')}", flush=True)
        from hykin.io.csv_writer import write_csv
        from hykin.io.dataset_files import read_joints

        q_traj, _ = read_joints(work / "traj.csv", dof=vr.truth.dof)  # second test set: on the trajectory
        pick = np.sort(np.random.default_rng(14).choice(len(q_traj), min(a.test_poses, len(q_traj)), replace=False))
        write_csv(work / "test_traj_q.csv", {f"q{j + 1}": q_traj[pick, j] for j in range(q_traj.shape[1])})
    else:
        print(f"reusing the recorded cell {work / 'cell'}, the trajectory and the test poses", flush=True)
    res["import"] = _two_pass_import(work, a)
    (work / "data.json").write_text(json.dumps(res["import"], indent=2) + "\n")
    if a.no_fit:
        (work / "results.json").write_text(json.dumps(res, indent=2) + "\n")
        return

    t0 = time.perf_counter()
    _static_sets(work, a, res["import"]["aligned"])
    from hykin.sim.simulate import load_truth

    note = _region_note(work, load_truth(work / "robot.truth.json").truth.dof)
    print(f"static sets (same robot, noise-only, position only): {time.perf_counter() - t0:.0f} s; {note}", flush=True)
    res["region"] = note
    big = ["--device", a.device, *shlex.split(a.fit_args)]
    small = ["--device", a.device, *shlex.split(a.small_fit_args or "")]
    fits = {}
    for name, data, opts in (("streamed", "streamed.parquet", big), ("static_same_N", "static_same.parquet", big),
                             (f"static_{a.static_small}", "static_small.parquet", small)):
        out, dt, rss = _hykin(["fit", a.robot, data, "-o", f"{name}.hykin", "--force", *opts], work)
        (work / f"{name}.fit.log").write_text(out)
        rep, _, _ = _hykin(["evaluate", f"{name}.hykin", "test.parquet", "--json"], work)
        (work / f"{name}.eval.json").write_text(rep)
        mm = _hybrid_mean_mm(rep)
        fits[name] = {"fit_seconds": dt, "fit_peak_gb": rss, "test_mean_mm": mm, "options": opts}
        traj = ""
        if (work / "test_traj.parquet").exists():
            rep, _, _ = _hykin(["evaluate", f"{name}.hykin", "test_traj.parquet", "--json"], work)
            (work / f"{name}.eval_traj.json").write_text(rep)
            fits[name]["test_traj_mean_mm"] = _hybrid_mean_mm(rep)
            traj = f"; on the trajectory {fits[name]['test_traj_mean_mm']:.4f} mm"
        print(f"fit on {name}: {dt:.0f} s, peak {rss:.2f} GB; hybrid test error {mm:.4f} mm mean (planned poses){traj}",
              flush=True)
    res["fits"] = fits
    s, same, sm = (fits[k]["test_mean_mm"] for k in fits)
    r_same, r_small = s / same, s / sm
    ok1, ok2 = r_same <= 1.2, s < sm
    res["ratios"] = {"streamed_over_same_N": r_same, "streamed_over_small": r_small, "within_1_2x": ok1,
                     "better_than_small": ok2}
    (work / "results.json").write_text(json.dumps(res, indent=2) + "\n")
    print(f"held-out ({a.test_poses} independent static poses, {'noisy' if a.test_noise else 'true'} positions): "
          f"streamed {s:.4f} mm, static same N {same:.4f} mm, static {a.static_small} {sm:.4f} mm")
    print(f"streamed / static same N = {r_same:.3f} (limit 1.2): {'MET' if ok1 else 'NOT MET'}")
    print(f"streamed / static {a.static_small} = {r_small:.3f} (must be < 1): {'MET' if ok2 else 'NOT MET'}")
    if all("test_traj_mean_mm" in f for f in fits.values()):
        ts, tsame, tsm = (fits[k]["test_traj_mean_mm"] for k in fits)
        res["ratios_trajectory"] = {"streamed_over_same_N": ts / tsame, "streamed_over_small": ts / tsm}
        (work / "results.json").write_text(json.dumps(res, indent=2) + "\n")
        print(f"secondary, {a.test_poses} static poses at random times on the trajectory (between training samples): "
              f"streamed {ts:.4f}, same N {tsame:.4f}, static {a.static_small} {tsm:.4f} mm; ratios {ts / tsame:.3f} "
              f"(limit 1.2: {'MET' if ts / tsame <= 1.2 else 'NOT MET'}), {ts / tsm:.3f} (< 1: "
              f"{'MET' if ts < tsm else 'NOT MET'})")
    print(f"{'MET' if ok1 and ok2 else 'NOT MET'} (planned test poses): hybrid on {res['import']['aligned']} streamed poses within 1.2x of "
          f"same-N static and better than {a.static_small} static poses")


if __name__ == "__main__":
    main()
