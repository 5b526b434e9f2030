"""hykin sweep / hykin fleet (issue #29): file formats (one-line errors), the one trial path (= `hykin
fit`), nested subsets, and end to end on a local Ray (slow: Ray's start-up alone takes 5-25 s)."""

from __future__ import annotations

import csv
import json
import sys
import warnings

import numpy as np
import pytest
from shared_fixtures import residual_data, sweep_files, write_text

from cli_run import run
from procs import descendants
from hykin.distributed.fleet_file import read_fleet
from hykin.distributed.files import SpecError
from hykin.distributed.sweep_file import read_sweep, trial_key
from hykin.distributed.trials import ERROR_COLUMNS, fit_model, nested_subset, run_trial
from hykin.io.robot_file import load_robot

# the model's own out-of-range warning is expected here: the queries are random joints
pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")


_data = residual_data


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return sweep_files(tmp_path_factory.mktemp("dist"), 60)


_write = write_text


GOOD_SWEEP = 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n'
FAST = "max_epochs = [2]\nmin_steps = [0]\n"


# --------------------------------------------------------------------------- sweep file


def test_sweep_file_every_combination_is_a_trial(files):
    p = _write(files / "s.toml", GOOD_SWEEP + '[grid]\narch = ["default", "D1"]\nseed = [0, 1, 2]\nn_train = [100]\n'
               "[resources]\ncpus_per_trial = 2\n")
    spec = read_sweep(p)
    trials = spec.trials()
    assert len(trials) == 6 and spec.cpus_per_trial == 2.0 and spec.gpus_per_trial == 0.0
    assert trials[1] == {"arch": "default", "seed": 1, "n_train": 100}  # last key fastest
    assert len({trial_key(t) for t in trials}) == 6
    assert spec.train == (files / "train.csv").resolve()


def test_sweep_file_random_samples_are_reproducible(files):
    p = _write(files / "r.toml", GOOD_SWEEP + '[grid]\narch = ["default", "D1"]\n'
               '[random]\nsamples = 3\nseed = 7\nmin_steps = {loguniform = [100, 10000]}\nrecipe = ["paper", "default"]\n')
    a, b = read_sweep(p).trials(), read_sweep(p).trials()
    assert a == b and len(a) == 6
    assert all(100 <= t["min_steps"] <= 10000 and isinstance(t["min_steps"], int) for t in a)
    assert {t["arch"] for t in a} == {"default", "D1"}


@pytest.mark.parametrize("text, key", [
    (GOOD_SWEEP + "[grid]\nbogus = [1]\n", "bogus"),
    (GOOD_SWEEP + '[grid]\narch = ["D9"]\n', "arch"),
    (GOOD_SWEEP + "[grid]\nmin_steps = [-5]\n", "min_steps"),
    (GOOD_SWEEP + '[grid]\nseed = ["a"]\n', "seed"),
    (GOOD_SWEEP + "[grid]\nn_train = [0]\n", "n_train"),
    (GOOD_SWEEP + '[grid]\nthermal = ["maybe"]\n', "thermal"),
    (GOOD_SWEEP.replace("test.csv", "missing.csv"), "test"),
    (GOOD_SWEEP.replace('"rx160"', '"no-such-robot"'), "robot"),
    (GOOD_SWEEP + "[resources]\ncpus_per_trial = -1\n", "cpus_per_trial"),
    (GOOD_SWEEP + "[resources]\ngpu = 1\n", "gpu"),
    ('robot = "rx160"\ntrain = "train.csv"\n', "test"),
    (GOOD_SWEEP + "[grid\n", "TOML"),
])
def test_sweep_file_mistakes_are_one_line_naming_file_and_key(files, text, key):
    _refused_in_one_line(read_sweep, files / "bad.toml", text, key)


def _refused_in_one_line(reader, path, text, key):
    """``reader`` refuses the file ``text`` with one line naming the file and ``key``."""
    _write(path, text)
    with pytest.raises(SpecError) as e:
        reader(path)
    msg = str(e.value)
    assert "\n" not in msg and str(path) in msg and key in msg, msg


def test_sweep_cli_refuses_a_bad_file_in_one_line_and_writes_nothing(files, capsys):
    p = _write(files / "bad2.toml", GOOD_SWEEP + "[grid]\nmax_epochs = [0]\n")
    code, out, err = run(["sweep", p, "-o", files / "never"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "max_epochs" in err and str(p) in err
    assert not (files / "never").exists()


def test_nested_subsets_are_nested_and_seeded():
    a, b = nested_subset(1000, 100, 3), nested_subset(1000, 400, 3)
    assert len(a) == 100 and len(np.unique(a)) == 100 and set(a) <= set(b)
    assert not np.array_equal(a, nested_subset(1000, 100, 4))
    with pytest.raises(ValueError, match="n_train"):
        nested_subset(10, 11, 0)


# --------------------------------------------------------------------------- fleet file


GOOD_FLEET = '[[robot]]\nname = "cell-1"\nrobot = "rx160"\ntrain = "train.csv"\n'


def test_fleet_file_parses(files):
    p = _write(files / "f.toml", GOOD_FLEET + 'test = "test.csv"\nregister = "day2.csv"\nposes = 20\n'
               "[robot.fit]\nmin_steps = 0\nmax_epochs = 2\n"
               '[[robot]]\nname = "cell-2"\nrobot = "rx160"\ntrain = "train.csv"\n')
    spec = read_fleet(p)
    assert [r.name for r in spec.robots] == ["cell-1", "cell-2"]
    a, b = spec.robots
    assert a.poses == 20 and a.fit == {"min_steps": 0, "max_epochs": 2} and a.register == (files / "day2.csv").resolve()
    assert b.test is None and b.register is None and b.poses == 30


@pytest.mark.parametrize("text, key", [
    (GOOD_FLEET + GOOD_FLEET, "name"),
    (GOOD_FLEET.replace("cell-1", "cell 1"), "name"),
    (GOOD_FLEET + 'test = "nope.csv"\n', "test"),
    (GOOD_FLEET + "poses = 1\n", "poses"),
    (GOOD_FLEET + "[robot.fit]\nfade_cv = 1\n", "fade-cv"),
    (GOOD_FLEET + "[robot.fit]\nlearning = 1\n", "learning"),
    (GOOD_FLEET + "colour = 1\n", "colour"),
    ("[resources]\ncpus_per_robot = 1\n", "[[robot]]"),
])
def test_fleet_file_mistakes_are_one_line_naming_file_and_key(files, text, key):
    _refused_in_one_line(read_fleet, files / "badf.toml", text, key)


# --------------------------------------------------------------------------- one path with `hykin fit`


def test_a_trial_is_hykin_fit_with_the_same_options(files, capsys):
    """`hykin fit` and the trial's fit give the same predictions; the trial's errors are the test errors
    of that model (reference computed here from the poses)."""
    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset_files import read_dataset

    code, _, err = run(["fit", "rx160", files / "train.csv", "-o", files / "cli.hykin", "--seed", 3, "--max-epochs", 2,
                        "--min-steps", 0, "--arch", "default", "--no-calibrate", "--force"], capsys)
    assert code == 0, err
    cli = HybridModel.load(files / "cli.hykin")
    rob = load_robot("rx160")
    train, test = read_dataset(files / "train.csv", robot=rob), read_dataset(files / "test.csv", robot=rob)
    opts = {"seed": 3, "max_epochs": 2, "min_steps": 0, "arch": "default", "calibrate": False}
    mine = fit_model(rob, train, opts)
    np.testing.assert_array_equal(mine.predict(test.q), cli.predict(test.q))
    row = run_trial(rob, train, test, opts)
    ref = np.linalg.norm(cli.predict(test.q)[:, :3, 3] - test.xyz_m, axis=1).mean() * 1e3
    assert row["hybrid_pos_mean_mm"] == pytest.approx(ref, rel=1e-12)
    assert row["n_train"] == 240 and row["epochs"] >= 1 and row["steps"] >= row["epochs"] and row["fit_s"] > 0
    assert np.isnan(row["calibrated_pos_mean_mm"])


def test_a_trials_out_of_range_warning_goes_into_its_row(files):
    """A trial fitted on a small subset sees test poses outside its training range: the evaluation's
    warning is the row's test_note (the same text evaluate_model warns with), not a warning."""
    from hykin.evaluation.evaluate import evaluate_model
    from hykin.hybrid.errors import OutOfRangeWarning
    from hykin.io.dataset_files import read_dataset

    rob = load_robot("rx160")
    train, test = read_dataset(files / "train.csv", robot=rob), read_dataset(files / "test.csv", robot=rob)
    opts = {"seed": 1, "max_epochs": 1, "min_steps": 0, "calibrate": False}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        row = run_trial(rob, train, test, {**opts, "n_train": 40})
    assert not [w for w in caught if issubclass(w.category, OutOfRangeWarning)]
    model = fit_model(rob, train.subset(nested_subset(len(train), 40, 0)), opts)
    with pytest.warns(OutOfRangeWarning) as ref:
        evaluate_model(model, test)
    assert row["test_note"] == str(ref[0].message) and "outside" in row["test_note"]


def test_missing_ray_is_one_line_naming_the_extra(monkeypatch):
    from hykin.distributed.ray_session import import_ray

    monkeypatch.setitem(sys.modules, "ray", None)
    with pytest.raises(ImportError, match=r"hykin\[distributed\]"):
        import_ray()


# --------------------------------------------------------------------------- end to end on local Ray (slow)


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray for the module (2 CPUs, no dashboard); the CLI reuses it."""
    ray = pytest.importorskip("ray", reason="Ray not installed (pip install 'hykin[distributed]')")
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, logging_level="warning")
    yield ray
    ray.shutdown()


def _csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.mark.slow
def test_sweep_end_to_end_failure_retry_and_resume(files, local_ray, capsys):
    p = _write(files / "sweep.toml", GOOD_SWEEP + "[grid]\nn_train = [150]\n" + FAST +
               'max_deviation = ["residual_mm=0.00001", "residual_mm=3"]\n')
    out = files / "sweep-out"
    code, o, err = run(["sweep", p, "-o", out], capsys)
    assert code == 1, err
    assert [line for line in err.splitlines() if line.startswith("hykin: error:")] == [
        line for line in err.splitlines() if "trial 0 failed: CalibrationError" in line]
    assert "trial 2/2 done" in o and "ETA" in o
    rows = _csv(out / "results.csv")
    assert [r["status"] for r in rows] == ["error", "ok"]
    assert rows[0]["attempts"] == "2" and "CalibrationError" in rows[0]["error"]  # retried once, then recorded
    assert rows[1]["n_train"] == "150" and float(rows[1]["hybrid_pos_mean_mm"]) > 0 and float(rows[1]["fit_s"]) > 0
    assert (out / "error_vs_n_train.png").stat().st_size > 1000
    # --resume reruns only the failed trial; the finished one is kept as it was
    code, o, err = run(["sweep", p, "-o", out, "--resume"], capsys)
    assert code == 1 and "1 of 2 trials kept" in o and "1 to run" in o
    again = _csv(out / "results.csv")
    assert again[1] == rows[1] and again[0]["status"] == "error"
    # an interrupted sweep (the finished record lost) resumed gives the same numbers for the same seed
    recs = (out / "trials.jsonl").read_text().splitlines()
    (out / "trials.jsonl").write_text("\n".join(r for r in recs if json.loads(r)["row"]["status"] != "ok") + "\n")
    code, o, err = run(["sweep", p, "-o", out, "--resume"], capsys)
    assert "0 of 2 trials kept" in o
    third = _csv(out / "results.csv")
    assert third[1]["hybrid_pos_mean_mm"] == rows[1]["hybrid_pos_mean_mm"]
    # without --resume an earlier sweep is not overwritten
    code, o, err = run(["sweep", p, "-o", out], capsys)
    assert code == 2 and "--resume" in err


@pytest.mark.slow
def test_fleet_end_to_end_one_robot_fails(files, local_ray, capsys):
    p = _write(files / "fleet.toml",
               GOOD_FLEET + 'test = "test.csv"\nregister = "day2.csv"\nposes = 20\n[robot.fit]\nmin_steps = 0\nmax_epochs = 2\n'
               '[[robot]]\nname = "cell-2"\nrobot = "rx160"\ntrain = "train.csv"\n'
               '[robot.fit]\nmin_steps = 0\nmax_epochs = 2\nmax_deviation = "residual_mm=0.00001"\n')
    out = files / "fleet-out"
    code, o, err = run(["fleet", p, "-o", out], capsys)
    assert code == 1
    fails = [line for line in err.splitlines() if line.startswith("hykin: error:")]
    assert len(fails) == 1 and "cell-2" in fails[0] and "CalibrationError" in fails[0]
    assert (out / "cell-1.hykin").is_file() and (out / "cell-1-registered.hykin").is_file()
    assert not (out / "cell-2.hykin").exists()
    rows = _csv(out / "summary.csv")
    assert [(r["name"], r["status"]) for r in rows] == [("cell-1", "ok"), ("cell-2", "failed")]
    ok = rows[0]
    assert float(ok["hybrid_pos_mean_mm"]) < float(ok["nominal_pos_mean_mm"])
    assert float(ok["registered_hybrid_pos_mean_mm"]) > 0
    assert int(ok["n_registered_held_out"]) == 60 - 20  # evaluated on the series' poses not used to register
    md = (out / "summary.md").read_text()
    assert "| cell-1 | ok |" in md and "cell-2: CalibrationError" in md
    # --resume: the finished robot is kept as it was (its model untouched), the failed one runs again
    before = (out / "cell-1.hykin").stat().st_mtime_ns
    code, o, err = run(["fleet", p, "-o", out, "--resume"], capsys)
    assert code == 1 and "1 of 2 robots kept" in o and "1 to run" in o
    assert _csv(out / "summary.csv")[0] == ok and (out / "cell-1.hykin").stat().st_mtime_ns == before


def test_shipped_paper_table1_sweep_parses(files, tmp_path):
    """examples/sweeps/paper-table1.toml: the paper's six architectures with its recipe, networks alone,
    plus hykin's default, at two training-set sizes (two [[grid]] tables)."""
    import shutil
    from pathlib import Path

    src = Path(__file__).resolve().parents[1] / "examples" / "sweeps" / "paper-table1.toml"
    shutil.copy(src, tmp_path)
    for name in ("rx160-train.csv", "rx160-test.csv"):
        shutil.copy(files / "train.csv", tmp_path / name)
    from hykin.io.robot_toml import save_robot_toml
    from hykin.sim.presets import virtual_preset

    save_robot_toml(virtual_preset("rx160-virtual").nominal, tmp_path / "rx160-train.nominal.toml")  # as simulate writes
    sw = read_sweep(tmp_path / "paper-table1.toml")
    assert Path(sw.robot).name == "rx160-train.nominal.toml"  # the virtual robot's nominal file, not the preset
    trials = sw.trials()
    paper = [t for t in trials if t["recipe"] == "paper"]
    assert sorted({t["arch"] for t in paper}) == sorted(["D1", "D4", "D4w", "D4W", "Rw", "Rd"])
    assert all(t["calibrate"] is False for t in paper) and len(paper) == 12
    assert [t for t in trials if t["recipe"] == "default"] == [
        {"arch": "default", "recipe": "default", "calibrate": True, "max_minutes": 10, "n_train": n, "seed": 0}
        for n in (5000, 20000)]


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the trial's worker in /proc (Linux)")
def test_a_worker_killed_mid_trial_is_retried_and_the_sweep_completes(files, local_ray):
    """Fault injection: the worker process of the running trial (one this test's Ray started) is killed
    with SIGKILL; Ray restarts the worker, the trial is run once more and it finishes."""
    import os
    import signal
    import threading
    import time

    from hykin.distributed.sweep import run_sweep

    p = _write(files / "kill.toml", GOOD_SWEEP + "[grid]\nmax_epochs = [40]\nmin_steps = [0]\ncalibrate = [false]\n")
    killed = []

    def killer():
        t_end = time.time() + 300
        while not killed and time.time() < t_end:
            for pid in descendants(os.getpid()):
                try:
                    cmd = open(f"/proc/{pid}/cmdline", "rb").read()
                except OSError:
                    continue
                if b"TrialWorker.run" in cmd:
                    time.sleep(1.0)  # mid-trial
                    os.kill(pid, signal.SIGKILL)
                    killed.append(pid)
                    return
            time.sleep(0.1)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    res = run_sweep(read_sweep(p), files / "kill-out", log=print)
    th.join(timeout=1)
    assert killed, "no trial worker was found to kill"
    (row,) = res.rows
    assert row["status"] == "ok" and row["attempts"] == 2, row


@pytest.mark.slow
def test_more_gpus_per_trial_than_the_local_ray_has_is_refused_in_one_line(files, local_ray, capsys):
    p = _write(files / "gpu.toml", GOOD_SWEEP + "[grid]\nseed = [0]\n[resources]\ngpus_per_trial = 64\n")
    code, _, err = run(["sweep", p, "-o", files / "gpu-out"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "gpus_per_trial" in err and str(p) in err
    assert not (files / "gpu-out").exists()


# --------------------------------------------------------------------------- fleet --resume (no Ray needed)


def test_fleet_resume_keeps_only_complete_rows_with_unchanged_inputs(files, tmp_path):
    """kept_rows: an ``ok`` summary row whose model file is there and whose inputs' hash is unchanged is
    kept; a failed row, a missing model, or a changed data file / fit option means the robot runs again."""
    import shutil

    from hykin.distributed.fleet import SUMMARY_COLUMNS, _write_summary, inputs_hash, kept_rows

    for n in ("train.csv", "test.csv"):
        shutil.copy(files / n, tmp_path / n)
    text = "".join(f'[[robot]]\nname = "c{i}"\nrobot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n'
                   f"[robot.fit]\nseed = {i}\n" for i in (1, 2, 3))
    spec = read_fleet(_write(tmp_path / "f.toml", text))
    out = tmp_path / "out"
    out.mkdir()
    rows = [{"name": e.name, "status": "ok" if e.name != "c2" else "failed", "hybrid_pos_mean_mm": 0.5, "n_train": 240,
             "inputs_sha256": inputs_hash(e), "model": f"{e.name}.hykin"} for e in spec.robots]
    _write_summary(out / "summary.csv", rows)
    for e in spec.robots:
        (out / f"{e.name}.hykin").write_bytes(b"model")
    kept = kept_rows(spec, out)
    assert sorted(kept) == ["c1", "c3"] and kept["c1"]["hybrid_pos_mean_mm"] == 0.5 and kept["c1"]["n_train"] == 240
    assert set(kept["c1"]) == set(SUMMARY_COLUMNS)
    (out / "c3.hykin").unlink()
    assert sorted(kept_rows(spec, out)) == ["c1"]
    # the hash follows the data and the options: a changed training file or seed reruns the robot
    with open(tmp_path / "train.csv", "a", encoding="utf-8") as fh:
        fh.write("\n")
    assert kept_rows(spec, out) == {}
    spec2 = read_fleet(_write(tmp_path / "f.toml", text.replace("seed = 1", "seed = 9")))
    assert inputs_hash(spec2.robots[0]) != rows[0]["inputs_sha256"]
    assert kept_rows(read_fleet(tmp_path / "f.toml"), tmp_path / "nothing-here") == {}


@pytest.mark.slow
def test_an_interrupted_sweep_resumed_reruns_only_the_rest_and_matches_an_uninterrupted_one(files, local_ray):
    """The sweep is interrupted (KeyboardInterrupt in the driver) after its first finished trial; --resume
    runs only the two others, and every number equals that of the same sweep run without interruption."""
    from hykin.distributed.sweep import run_sweep

    spec = read_sweep(_write(files / "int.toml", GOOD_SWEEP + "[grid]\nseed = [0, 1, 2]\n" + FAST))
    full = run_sweep(spec, files / "int-full", log=lambda s: None)

    def stop_after_first(line):
        if "trial 1/3 done" in line:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, files / "int-out", log=stop_after_first)
    assert len((files / "int-out" / "trials.jsonl").read_text().splitlines()) == 1
    lines = []
    res = run_sweep(spec, files / "int-out", resume=True, log=lines.append)
    assert "1 of 3 trials kept" in lines[0] and "2 to run" in lines[0] and res.ran == 2
    cols = ("n_train", "steps", "epochs", *ERROR_COLUMNS)
    assert [r["status"] for r in res.rows] == ["ok"] * 3
    assert [[r[c] for c in cols] for r in res.rows] == [[r[c] for c in cols] for r in full.rows]
    assert _csv(files / "int-out" / "results.csv")[0]["hybrid_pos_mean_mm"] == \
        _csv(files / "int-full" / "results.csv")[0]["hybrid_pos_mean_mm"]


def test_trial_slots_follow_the_clusters_cpus_and_gpus():
    from hykin.distributed.trial_pool import n_workers

    class FakeRay:
        def __init__(self, res):
            self.res = res

        def cluster_resources(self):
            return self.res

    two = FakeRay({"CPU": 2.0})
    assert [n_workers(two, 8, c, 0) for c in (1, 0.5, 2, 3, 0)] == [2, 4, 1, 1, 2]
    assert n_workers(two, 1, 0.5, 0) == 1  # never more workers than trials
    gpu = FakeRay({"CPU": 16.0, "GPU": 1.0})
    assert [n_workers(gpu, 8, 1, g) for g in (1, 0.5, 0.25, 0)] == [1, 2, 4, 8]


def test_gpus_per_trial_makes_trials_that_name_no_device_fit_on_cuda(files, monkeypatch):
    """With gpus_per_trial > 0 a trial whose grid names no device is run with device "cuda"; one that
    names a device keeps it; results.csv records the options as written (no Ray: its session and the
    trial runner are stand-ins that record what they were given)."""
    import contextlib

    import hykin.distributed.sweep as sweep_mod

    given = {}

    def fake_run_trials(ray, trials, data, cpus, gpus, subsample_seed, on_done):
        given.update(trials)
        for i in trials:
            on_done(i, {"status": "ok", "error": "", "attempts": 1, "n_train": 240, **dict.fromkeys(ERROR_COLUMNS, 0.1),
                        "fit_s": 1.0, "eval_s": 0.1, "steps": 4, "epochs": 2})

    monkeypatch.setattr(sweep_mod, "ray_session", lambda address, num_cpus: contextlib.nullcontext(None))
    monkeypatch.setattr(sweep_mod, "check_resources", lambda *a, **k: None)
    monkeypatch.setattr(sweep_mod, "run_trials", fake_run_trials)
    text = (GOOD_SWEEP + "[[grid]]\nseed = [0]\n" + FAST + '[[grid]]\nseed = [1]\ndevice = ["cpu"]\n' + FAST
            + "[resources]\ngpus_per_trial = 0.5\n")
    res = sweep_mod.run_sweep(read_sweep(_write(files / "gpu-default.toml", text)), files / "gpu-default", log=lambda s: None)
    assert given[0]["device"] == "cuda" and given[1]["device"] == "cpu"
    assert "device" not in res.rows[0] and res.rows[1]["device"] == "cpu"
    given.clear()
    text0 = text.replace("gpus_per_trial = 0.5", "gpus_per_trial = 0")
    sweep_mod.run_sweep(read_sweep(_write(files / "cpu-default.toml", text0)), files / "cpu-default", log=lambda s: None)
    assert "device" not in given[0] and given[1]["device"] == "cpu"


def test_a_one_thread_trial_keeps_batch_work_to_one_thread():
    """trial_threads(1) sets numba's thread count; the chunked IK and the networks' batch pool follow it."""
    from hykin.distributed.trials import trial_threads
    from hykin.hybrid import fast_nets
    from hykin.kinematics.chunks import run_chunked, worker_count

    calls = []
    with trial_threads(1):
        assert worker_count() == 1 and fast_nets.threads() == 1
        run_chunked(lambda a, b: calls.append((a, b)), (), 100_000, min_chunk=200)
    assert calls == [(0, 100_000)]
