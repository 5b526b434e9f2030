"""Probe AG, without starting Ray: the fleet checks [robot.fit] with the sweep's checker (types, names) before Ray
starts; a sweep checks [random] values and devices up front too; the plot never averages over differing options;
data in mm / deg can be declared (length_unit / angle_unit) in a fleet entry and at a sweep's top level; the
help keeps [grid] / [[robot]]; a resumed fleet counts the robots it runs; Ctrl-C prints one line."""

from __future__ import annotations

import contextlib

import numpy as np
import pytest
from shared_fixtures import fake_sweep_ray, sweep_files, write_text

from cli_run import run
from hykin.distributed.files import SpecError, inputs_sha256
from hykin.distributed.fleet_file import read_fleet
from hykin.distributed.sweep_file import read_sweep, sweep_inputs_hash
from hykin.distributed.trials import ERROR_COLUMNS

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """rx160 train / test / day2 in SI, and the train and test sets again in mm / deg."""
    from hykin.io.dataset_files import read_dataset, write_dataset

    d = sweep_files(tmp_path_factory.mktemp("s41"), 12)
    for name in ("train", "test"):
        write_dataset(read_dataset(d / f"{name}.csv"), d / f"{name}_mmdeg.csv", length_unit="mm", angle_unit="deg")
    return d


def _no_ray(monkeypatch):
    """Any start of Ray by the fleet or the sweep fails the test (the refusals come before it)."""
    import hykin.distributed.fleet as fleet_mod
    import hykin.distributed.sweep as sweep_mod

    def boom(*a, **k):
        raise AssertionError("Ray was started")

    monkeypatch.setattr(fleet_mod, "ray_session", boom)
    monkeypatch.setattr(sweep_mod, "ray_session", boom)


def _fleet(files, fit: str = "", entry: str = "", name: str = "fl.toml"):
    return write_text(files / name, '[[robot]]\nname = "cellA"\nrobot = "rx160"\ntrain = "train.csv"\n'
                      + entry + ("[robot.fit]\n" + fit if fit else ""))


def _sweep(files, body: str, top: str = "", name: str = "sw.toml"):
    return write_text(files / name, 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n' + top + body)


# --------------------------------------------------------------------------- 1: fleet [robot.fit] checked as a sweep's


@pytest.mark.parametrize("fit, key, why", [
    ('calibrate = "false"\n', "calibrate", "expected bool"),      # bool("false") is True: calibrated anyway
    ("seed = 1.9\n", "seed", "expected int"),                      # int(1.9) == 1
    ("min_steps = 200.7\n", "min_steps", "expected int"),
    ('max_epochs = "3"\n', "max_epochs", "expected int"),
    ('arch = "D9"\n', "arch", "unknown architecture"),             # found by the robot's task after Ray started
    ('recipe = "papr"\n', "recipe", "unknown recipe"),
    ('device = "cdua"\n', "device", "unknown device"),
    ('thermal = "maybe"\n', "thermal", "--thermal must be"),
    ("region_cv = 1\n", "region_cv", "expected bool"),
    ('prior = "length=3"\n', "prior", "expected list"),
])
def test_fleet_fit_options_are_checked_by_the_sweeps_checker_naming_file_robot_and_key(files, fit, key, why):
    p = _fleet(files, fit)
    with pytest.raises(SpecError) as e:
        read_fleet(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg and "'cellA'" in msg and f"[robot.fit] {key} = " in msg and why in msg, msg


def test_the_fleet_and_the_sweep_refuse_the_same_value_with_the_same_words(files):
    fleet = str(pytest.raises(SpecError, read_fleet, _fleet(files, 'calibrate = "false"\n')).value)
    sweep = str(pytest.raises(SpecError, read_sweep, _sweep(files, '[grid]\ncalibrate = ["false"]\n')).value)
    assert fleet.split("calibrate = ")[1] == sweep.split("calibrate = ")[1] == "'false': expected bool"


def test_valid_fleet_fit_options_are_kept_as_written(files):
    spec = read_fleet(_fleet(files, 'calibrate = false\nseed = 2\nmax_minutes = 1\norientation_weight = 0.5\n'
                                    'prior = ["length_mm=3"]\noutliers = "warn"\ndevice = "cuda:1"\n'))
    assert spec.robots[0].fit == {"calibrate": False, "seed": 2, "max_minutes": 1, "orientation_weight": 0.5,
                                  "prior": ["length_mm=3"], "outliers": "warn", "device": "cuda:1"}


def test_fleet_cli_refuses_a_string_calibrate_before_ray_in_one_line(files, tmp_path, monkeypatch, capsys):
    _no_ray(monkeypatch)
    code, _, err = run(["fleet", _fleet(files, 'calibrate = "false"\n', name="cli.toml"), "-o", tmp_path / "o"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "calibrate = 'false': expected bool" in err, err
    assert not (tmp_path / "o").exists()


# --------------------------------------------------------------------------- 4: sweep [random] and device up front


@pytest.mark.parametrize("body, where, why", [
    ('[random]\narch = ["D7"]\n', "[random] arch = 'D7'", "unknown architecture"),
    ('[random]\nthermal = ["maybe"]\n', "[random] thermal = 'maybe'", "--thermal must be"),
    ('[random]\nrecipe = ["papr"]\n', "[random] recipe = 'papr'", "unknown recipe"),
    ('[grid]\ndevice = ["cdua"]\n', "[grid] device = 'cdua'", "unknown device"),
    ('[random]\ndevice = ["cdua"]\n', "[random] device = 'cdua'", "unknown device"),
    ("[random]\nmin_steps = {uniform = [-50, 10]}\n", "[random] min_steps = -50", "must be >= 0"),
    ('[random]\nmax_epochs = {uniform = [1, "9"]}\n', "[random] max_epochs", "two numbers"),
])
def test_sweep_random_values_and_devices_are_checked_before_any_trial(files, body, where, why):
    p = _sweep(files, body)
    with pytest.raises(SpecError) as e:
        read_sweep(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg and where in msg and why in msg, msg


def test_sweep_cli_refuses_a_random_architecture_before_ray(files, tmp_path, monkeypatch, capsys):
    _no_ray(monkeypatch)
    code, _, err = run(["sweep", _sweep(files, '[random]\narch = ["D7"]\n', name="cli_sw.toml"), "-o", tmp_path / "o"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "[random] arch = 'D7'" in err, err


def test_sweep_accepts_every_fit_option_in_its_grid(files):
    """outliers / outlier_ratio are `hykin fit` options too (a grid of them raised KeyError before)."""
    spec = read_sweep(_sweep(files, '[grid]\noutliers = ["drop", "warn"]\noutlier_ratio = [8, 12.5]\ndevice = ["cpu"]\n'))
    assert len(spec.trials()) == 4


# --------------------------------------------------------------------------- 2: the plot


def _rows():
    """Probe AG's sweep: arch x seed x calibrate x n_train; calibrated trials ~0.16 mm, uncalibrated ~3.6 mm."""
    rows = []
    for arch in ("default", "D1"):
        for seed in (0, 1):
            for cal in (True, False):
                for n in (150, 300):
                    hyb = (0.16 if cal else 3.6) + 0.01 * seed - 0.005 * (n == 300) + 0.002 * (arch == "D1")
                    rows.append({"status": "ok", "arch": arch, "seed": seed, "calibrate": cal, "n_train": n,
                                 "hybrid_pos_mean_mm": hyb, "calibrated_pos_mean_mm": 0.167 if cal else float("nan")})
    rows.append({"status": "error", "arch": "D1", "seed": 2, "calibrate": True, "n_train": 150,
                 "hybrid_pos_mean_mm": float("nan"), "calibrated_pos_mean_mm": float("nan")})
    return rows


def test_plot_never_averages_calibrated_with_uncalibrated_trials(tmp_path, monkeypatch):
    """Before: one line per architecture, the mean over calibrate true and false (~1.88 mm), an error no trial had."""
    import matplotlib.axes

    from hykin.distributed.sweep import plot_results

    drawn = []
    orig = matplotlib.axes.Axes.plot

    def record(self, *args, **kw):
        drawn.append((kw.get("label"), list(args[1])))
        return orig(self, *args, **kw)

    monkeypatch.setattr(matplotlib.axes.Axes, "plot", record)
    titles = []
    orig_title = matplotlib.axes.Axes.set_title
    monkeypatch.setattr(matplotlib.axes.Axes, "set_title",
                        lambda self, t, *a, **k: (titles.append(t), orig_title(self, t, *a, **k))[1])
    assert plot_results(_rows(), tmp_path / "p.png").is_file()
    ys = [y for _, line in drawn for y in line]
    assert all(0.15 < y < 0.18 or 3.5 < y < 3.7 for y in ys), drawn  # every point near an error some trial had
    labels = [label for label, _ in drawn]
    assert "arch=D1, calibrate=False" in labels and "arch=default, calibrate=True" in labels, labels
    assert "calibrated only (calibrate=True)" in labels and len(labels) == 5, labels
    assert titles and "mean over seed 0, 1" in titles[0], titles


def test_plot_lines_average_only_over_seeds():
    from hykin.distributed.sweep import plot_lines

    lines, title = plot_lines(_rows())
    by = {label: (ns, ys) for label, ns, ys, _ in lines}
    ns, ys = by["arch=D1, calibrate=False"]
    assert ns == [150, 300] and np.allclose(ys, [3.6 + 0.005 + 0.002, 3.6 + 0.005 - 0.005 + 0.002])
    assert by["calibrated only (calibrate=True)"] == ([150, 300], [0.167, 0.167])
    one = [r for r in _rows() if r["seed"] == 0 and r["arch"] == "default" and r["calibrate"]]
    lines, title = plot_lines(one)
    assert [(label, cal) for label, _, _, cal in lines] == [("hybrid", False), ("calibrated only", True)]
    assert title == "each point: one trial"


# --------------------------------------------------------------------------- 3: units


def _same(a, b):
    return np.allclose(a.q, b.q, atol=1e-12) and np.allclose(a.xyz_m, b.xyz_m, atol=1e-12)


def test_fleet_entry_declares_the_units_of_its_data_files(files, monkeypatch):
    """Before: `angle_unit` was an unknown key, so mm/deg data could not be used (the unit-slip message told
    the user to declare it)."""
    import hykin.distributed.fleet as fleet_mod
    from hykin.io.dataset_files import read_dataset

    spec = read_fleet(write_text(files / "mm.toml", '[[robot]]\nname = "cellA"\nrobot = "rx160"\ntrain = "train_mmdeg.csv"\n'
                                                    'test = "test_mmdeg.csv"\nlength_unit = "mm"\nangle_unit = "deg"\n'))
    r = spec.robots[0]
    assert (r.length_unit, r.angle_unit) == ("mm", "deg")
    seen = []

    class Stop(Exception):
        pass

    def fake_fit(robot, train, options):
        seen.append(train)
        raise Stop("stop after the read")

    monkeypatch.setattr(fleet_mod, "fit_model", fake_fit)
    row = fleet_mod.robot_job(r)
    assert row["status"] == "failed" and "stop after the read" in row["error"] and _same(seen[0], read_dataset(files / "train.csv"))


def test_fleet_units_are_checked_and_belong_to_the_entry_not_fit(files):
    e = pytest.raises(SpecError, read_fleet, _fleet(files, entry='length_unit = "inch"\n')).value
    assert "'cellA' length_unit = 'inch'" in str(e) and "m, mm" in str(e), e
    e = pytest.raises(SpecError, read_fleet, _fleet(files, 'angle_unit = "deg"\n')).value
    assert "[robot.fit] angle_unit" in str(e) and "[[robot]] entry" in str(e), e


def test_fleet_hash_follows_units_but_keeps_earlier_hashes(files):
    from hykin.distributed.fleet import inputs_hash

    si = read_fleet(_fleet(files)).robots[0]
    old = inputs_sha256((si.robot, si.train, si.test, si.register), {"poses": si.poses, "fit": si.fit})
    mm = read_fleet(_fleet(files, entry='length_unit = "mm"\n', name="fl_mm.toml")).robots[0]
    assert inputs_hash(si) == old != inputs_hash(mm)


def test_sweep_declares_the_units_of_its_data_files(files, tmp_path, monkeypatch):
    import hykin.distributed.sweep as sweep_mod
    from hykin.io.dataset_files import read_dataset

    p = write_text(files / "sw_mm.toml", 'robot = "rx160"\ntrain = "train_mmdeg.csv"\ntest = "test_mmdeg.csv"\n'
                                        'length_unit = "mm"\nangle_unit = "deg"\n[grid]\nseed = [0]\n')
    spec = read_sweep(p)
    assert (spec.length_unit, spec.angle_unit) == ("mm", "deg")
    got = []
    sweep_mod, _ = fake_sweep_ray(monkeypatch, got)
    sweep_mod.run_sweep(spec, tmp_path / "o", log=lambda m: None)
    _, train, test = got[0]
    assert _same(train, read_dataset(files / "train.csv")) and _same(test, read_dataset(files / "test.csv"))
    si = read_sweep(_sweep(files, "[grid]\nseed = [0]\n"))
    assert sweep_inputs_hash(si) == inputs_sha256((si.robot, si.train, si.test), {"subsample_seed": 0})  # unchanged
    assert sweep_inputs_hash(spec) != sweep_inputs_hash(read_sweep(_sweep(files, "[grid]\nseed = [0]\n", 'angle_unit = "deg"\n')))


def test_sweep_refuses_an_unknown_unit(files):
    e = pytest.raises(SpecError, read_sweep, _sweep(files, "[grid]\nseed = [0]\n", 'angle_unit = "grad"\n')).value
    assert "angle_unit = 'grad'" in str(e) and "rad, deg" in str(e), e


# --------------------------------------------------------------------------- 5: help text


@pytest.mark.parametrize("cmd, words", [("sweep", ["[grid]", "[random]", "[resources]"]),
                                        ("fleet", ["[[robot]]", "[robot.fit]"])])
def test_help_keeps_the_bracketed_table_names(capsys, monkeypatch, cmd, words):
    monkeypatch.setenv("COLUMNS", "200")
    monkeypatch.setenv("TERMINAL_WIDTH", "200")
    code, out, _ = run([cmd, "--help"], capsys)
    assert code == 0 and all(w in out for w in words), out
    assert ", , ." not in out and "one [] entry" not in out


# --------------------------------------------------------------------------- 6: resume count, Ctrl-C


class _FakeRay:
    """Ray core as the fleet uses it, run in this process (tasks run when submitted)."""

    class Ref:
        def __init__(self, value):
            self.value = value

    def remote(self, **kw):
        return lambda fn: type("Task", (), {"remote": staticmethod(lambda *a: _FakeRay.Ref(fn(*a)))})

    def wait(self, refs, num_returns=1):
        return refs[:1], refs[1:]

    def get(self, ref):
        return ref.value


def test_resumed_fleet_counts_the_robots_it_runs(files, tmp_path, monkeypatch):
    """Before: "robot 3/3 c" when only robot c ran again."""
    import hykin.distributed.fleet as fleet_mod

    monkeypatch.setattr(fleet_mod, "ray_session", lambda address, num_cpus: contextlib.nullcontext(_FakeRay()))
    monkeypatch.setattr(fleet_mod, "check_resources", lambda *a, **k: None)
    monkeypatch.setattr(fleet_mod, "robot_job", lambda e: {"name": e.name, "status": "ok", "error": "", "model": f"{e.name}.hykin",
                                                           "files": {f"{e.name}.hykin": b"m"}, **dict.fromkeys(ERROR_COLUMNS, 0.2)})
    def fleet(seed_c):
        body = "".join(f'[[robot]]\nname = "{n}"\nrobot = "rx160"\ntrain = "train.csv"\n[robot.fit]\nseed = {s}\n'
                       for n, s in (("a", 0), ("b", 0), ("c", seed_c)))
        return read_fleet(write_text(files / "three.toml", body))

    out, logs = tmp_path / "o", []
    fleet_mod.run_fleet(fleet(0), out, log=logs.append)
    assert [m.split(" ")[2] for m in logs] == ["1/3", "2/3", "3/3"], logs
    logs.clear()
    fleet_mod.run_fleet(fleet(1), out, log=logs.append, resume=True)  # only c's fit options changed
    assert logs[0].startswith("fleet: 2 of 3 robots kept") and logs[1].startswith("fleet: robot 1/1 "), logs


@pytest.mark.parametrize("cmd", ["sweep", "fleet"])
def test_ctrl_c_prints_one_line_naming_resume(files, tmp_path, monkeypatch, capsys, cmd):
    """Before: exit 130 and nothing printed (Typer turns KeyboardInterrupt into a silent Exit(130))."""
    import hykin.distributed.fleet as fleet_mod
    import hykin.distributed.sweep as sweep_mod

    def interrupted(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(sweep_mod, "run_sweep", interrupted)
    monkeypatch.setattr(fleet_mod, "run_fleet", interrupted)
    p = _sweep(files, "[grid]\nseed = [0]\n", name="ki.toml") if cmd == "sweep" else _fleet(files, name="ki.toml")
    code, _, err = run([cmd, p, "-o", tmp_path / "o"], capsys)
    lines = err.strip().splitlines()
    assert code == 130 and len(lines) == 1 and "interrupted" in lines[0] and "--resume" in lines[0], err


@pytest.mark.parametrize("opts, why", [({"seed": 1.9}, "seed must be an integer"), ({"max_epochs": "3"}, "max_epochs must"),
                                       ({"calibrate": "false"}, "calibrate must be true or false"),
                                       ({"device": "cdua"}, "device must be"), ({"seed": True}, "seed must")])
def test_python_fit_options_refuse_what_they_would_have_converted(opts, why):
    """The Python path under `hykin fit`, the fleet and the sweep: 1.9 became seed 1 and "false" calibrated."""
    from hykin.hybrid.fit_options import model_kwargs

    with pytest.raises(ValueError, match=why):
        model_kwargs(**opts)
    assert model_kwargs(seed=3, calibrate=False, device="cpu")["seed"] == 3
