"""Checks of sweep / fleet files and of what `--resume` keeps, without starting Ray: colliding fleet output
names are refused; a sweep's resume key follows its inputs (robot file, data, subsample_seed); [random] seed
must be the draw seed; a fleet robot whose series is all used to register has no held-out registered error."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
from shared_fixtures import fake_sweep_ray, residual_data, sweep_files, write_text

from cli_run import run
from hykin.distributed.files import SpecError
from hykin.distributed.fleet_file import read_fleet
from hykin.distributed.sweep_file import read_sweep, sweep_inputs_hash
from hykin.distributed.trials import ERROR_COLUMNS
from hykin.io.robot_file import load_robot

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")


_data = residual_data


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return sweep_files(tmp_path_factory.mktemp("checks"), 12)


_write = write_text


def _robot(name, register=False):
    return (f'[[robot]]\nname = "{name}"\nrobot = "rx160"\ntrain = "train.csv"\n'
            + ('register = "day2.csv"\n' if register else ""))


# --------------------------------------------------------------------------- D3: fleet output names


@pytest.mark.parametrize("text, first, second, fname", [
    (_robot("cellA", True) + _robot("cellA-registered"), "cellA", "cellA-registered", "cellA-registered.hykin"),
    (_robot("cellA-registered") + _robot("cellA", True), "cellA-registered", "cellA", "cellA-registered.hykin"),
    (_robot("cellA") + _robot("CELLA"), "cellA", "CELLA", "CELLA.hykin"),
    (_robot("cellA") + _robot("cellA"), "cellA", "cellA", "cellA.hykin"),
    (_robot("cell") + _robot("Cell-Registered"), "cell", "Cell-Registered", "Cell-Registered.hykin"),
])
def test_fleet_names_whose_output_files_collide_are_refused_naming_both(files, text, first, second, fname):
    p = _write(files / "collide.toml", text)
    with pytest.raises(SpecError) as e:
        read_fleet(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg and fname in msg, msg
    assert f"#2 name = {second!r}" in msg and f"#1 name = {first!r}" in msg, msg


def test_fleet_names_that_do_not_collide_are_accepted(files):
    spec = read_fleet(_write(files / "fine.toml", _robot("cellA", True) + _robot("cellA-2") + _robot("cellAregistered")))
    assert [r.name for r in spec.robots] == ["cellA", "cellA-2", "cellAregistered"]


def test_fleet_cli_refuses_a_colliding_file_in_one_line_and_writes_nothing(files, capsys):
    p = _write(files / "collide-cli.toml", _robot("cellA", True) + _robot("cellA-registered"))
    out = files / "collide-out"
    code, _, err = run(["fleet", p, "-o", out], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "'cellA'" in err and "'cellA-registered'" in err and "cellA-registered.hykin" in err
    assert not out.exists()


# --------------------------------------------------------------------------- D4: sweep resume and inputs


SWEEP = 'robot = "{robot}"\ntrain = "train.csv"\ntest = "test.csv"\nsubsample_seed = {sseed}\n[grid]\nseed = [0, 1]\n'


def _sweep_dir(files, tmp_path, robot_file=True):
    for n in ("train.csv", "test.csv"):
        shutil.copy(files / n, tmp_path / n)
    if robot_file:
        from hykin.io.robot_toml import robot_to_toml_string

        _write(tmp_path / "rob.toml", robot_to_toml_string(load_robot("rx160")))
    return tmp_path


def test_sweep_inputs_hash_follows_robot_file_data_and_subsample_seed(files, tmp_path):
    d = _sweep_dir(files, tmp_path)
    p = d / "s.toml"
    h0 = sweep_inputs_hash(read_sweep(_write(p, SWEEP.format(robot="rob.toml", sseed=0))))
    assert sweep_inputs_hash(read_sweep(p)) == h0  # unchanged inputs: the same hash
    assert sweep_inputs_hash(read_sweep(_write(p, SWEEP.format(robot="rob.toml", sseed=1)))) != h0
    _write(p, SWEEP.format(robot="rob.toml", sseed=0))
    seen = {h0}
    for name in ("train.csv", "test.csv", "rob.toml"):
        with open(d / name, "a", encoding="utf-8") as fh:
            fh.write("\n")  # the bytes change (the content read may not): a new hash
        h = sweep_inputs_hash(read_sweep(p))
        assert h not in seen, name
        seen.add(h)


def _fake_ray(monkeypatch):
    """run_sweep without Ray (:func:`shared_fixtures.fake_sweep_ray`)."""
    return fake_sweep_ray(monkeypatch)


def test_sweep_resume_reruns_trials_whose_inputs_changed_and_keeps_the_others(files, tmp_path, monkeypatch):
    sweep_mod, calls = _fake_ray(monkeypatch)
    d = _sweep_dir(files, tmp_path)
    p = _write(d / "s.toml", SWEEP.format(robot="rob.toml", sseed=0))
    out = d / "out"
    sweep_mod.run_sweep(read_sweep(p), out, log=lambda s: None)
    recs = [json.loads(x) for x in (out / "trials.jsonl").read_text().splitlines()]
    assert [r["inputs_sha256"] for r in recs] == [sweep_inputs_hash(read_sweep(p))] * 2

    def resume():
        lines = []
        res = sweep_mod.run_sweep(read_sweep(p), out, resume=True, log=lines.append)
        return res, lines

    res, lines = resume()  # nothing changed: both kept, nothing run
    assert res.ran == 0 and calls == [[0, 1]] and "2 of 2 trials kept" in lines[-1] and len(lines) == 1
    assert not any("other inputs" in s for s in lines)
    for change in ("train", "test", "robot", "subsample_seed"):
        if change == "subsample_seed":
            _write(p, SWEEP.format(robot="rob.toml", sseed=5))
        else:
            with open(d / {"train": "train.csv", "test": "test.csv", "robot": "rob.toml"}[change], "a") as fh:
                fh.write("\n")
        res, lines = resume()
        assert res.ran == 2 and calls[-1] == [0, 1], change
        assert any("2 recorded trials" in s and "run again" in s for s in lines), (change, lines)
        assert any("0 of 2 trials kept" in s and "2 to run" in s for s in lines), (change, lines)
        res, lines = resume()  # rerun with the new inputs: now kept
        assert res.ran == 0 and "2 of 2 trials kept" in lines[-1], change


def test_sweep_records_without_an_inputs_hash_are_run_again(files, tmp_path, monkeypatch):
    """trials.jsonl written before inputs were recorded: the inputs are unknown, so the trials rerun."""
    from hykin.distributed.sweep import kept_records

    path = tmp_path / "trials.jsonl"
    path.write_text(json.dumps({"key": "a", "row": {"status": "ok"}}) + "\n"
                    + json.dumps({"key": "b", "inputs_sha256": "h1", "row": {"status": "ok"}}) + "\n"
                    + json.dumps({"key": "c", "inputs_sha256": "h2", "row": {"status": "ok"}}) + "\n")
    assert kept_records(path, "h1") == ({"b": {"status": "ok"}}, 2)
    assert kept_records(tmp_path / "none.jsonl", "h1") == ({}, 0)


def test_fleet_and_sweep_share_one_inputs_hash(files, tmp_path):
    """The fleet's inputs_hash is the shared helper (its values unchanged by the refactor: same layout)."""
    import hashlib

    from hykin.distributed.files import inputs_sha256
    from hykin.distributed.fleet import inputs_hash

    spec = read_fleet(_write(files / "one.toml", _robot("c1", True) + "poses = 5\n[robot.fit]\nseed = 3\n"))
    e = spec.robots[0]
    h = hashlib.sha256()
    for src in (e.robot, e.train, e.test, e.register):
        h.update((hashlib.sha256(src.read_bytes()).hexdigest() if src is not None and src != "rx160" else repr(src)).encode()
                 + b"\0")
    h.update(json.dumps({"poses": 5, "fit": {"seed": 3}}, sort_keys=True).encode())
    assert inputs_hash(e) == h.hexdigest() == inputs_sha256((e.robot, e.train, e.test, e.register),
                                                            {"poses": 5, "fit": {"seed": 3}})


# --------------------------------------------------------------------------- D5: [random] seed


@pytest.mark.parametrize("bad", ["seed = [0, 1]", 'seed = "0"', "seed = 1.5", "seed = true"])
def test_a_random_seed_that_is_not_one_integer_is_refused_saying_where_fit_seeds_go(files, bad):
    p = _write(files / "rs.toml", 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nmin_steps = [0]\n'
               f"[random]\nsamples = 2\n{bad}\nmax_epochs = [1, 2]\n")
    with pytest.raises(SpecError) as e:
        read_sweep(p)
    msg = str(e.value)
    assert "\n" not in msg and str(p) in msg and "[random] seed" in msg and "[grid] seed = [" in msg, msg


def test_sweep_cli_refuses_a_random_seed_list_in_one_line_without_a_traceback(files, capsys):
    p = _write(files / "rs-cli.toml", 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nmin_steps = [200]\n'
               "[random]\nsamples = 2\nseed = [0, 1]\n")
    code, _, err = run(["sweep", p, "-o", files / "rs-out"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "[random] seed" in err and "Traceback" not in err, err
    assert not (files / "rs-out").exists()


def test_a_random_samples_that_is_not_an_integer_is_refused(files):
    p = _write(files / "rsamp.toml", 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n'
               '[random]\nsamples = "x"\nmax_epochs = [1, 2]\n')
    with pytest.raises(SpecError, match=r"\[random\] samples"):
        read_sweep(p)


# --------------------------------------------------------------------------- D7: held-out registered error


def test_a_series_all_used_to_register_has_no_held_out_error_and_summary_shows_the_count(files, tmp_path, monkeypatch):
    """poses = the series' length (12): nothing is held out, so the registered model is not evaluated on
    the series (its error would be in-sample): NaN, blank in summary.md, held-out count 0 shown; with
    poses = 8 it is evaluated on exactly the 4 rows not used. The fit, registration and evaluation are
    stand-ins (no training: only robot_job's held-out logic is under test); the data files are real."""
    import hykin.distributed.fleet as fleet_mod
    import hykin.measure.register as register_mod
    from hykin.distributed.fleet import _write_summary, registered_note, robot_job, summary_markdown

    evaluated = []

    class Info:
        def __init__(self, used):
            self.used_index = used

    def fake_register(model, series, n_poses):
        return "registered", Info(np.arange(min(n_poses, len(series))))

    def fake_evaluate(model, data):
        evaluated.append((model, len(data)))
        return 0.25, ""

    monkeypatch.setattr(fleet_mod, "fit_model", lambda robot, train, options: "fitted")
    monkeypatch.setattr(fleet_mod, "_model_bytes", lambda model: model.encode())
    monkeypatch.setattr(fleet_mod, "evaluate_noted", fake_evaluate)
    monkeypatch.setattr(fleet_mod, "error_columns", lambda res: dict.fromkeys(ERROR_COLUMNS, res))
    monkeypatch.setattr(register_mod, "register_model", fake_register)
    text = _robot("r", True) + "poses = {n}\n"
    rows = {}
    for n in (12, 8):
        evaluated.clear()
        e = read_fleet(_write(files / f"p{n}.toml", text.format(n=n))).robots[0]
        row = robot_job(e)
        assert row["status"] == "ok", row["error"]
        assert row.pop("files") == {"r.hykin": b"fitted", "r-registered.hykin": b"registered"}
        rows[n] = (row, list(evaluated))
    (full, ev_full), (part, ev_part) = rows[12], rows[8]
    assert ev_full == [] and ev_part == [("registered", 4)]
    assert full["n_registered_held_out"] == 0
    assert math.isnan(full["registered_hybrid_pos_mean_mm"]) and math.isnan(full["registered_hybrid_ang_mean_deg"])
    assert part["n_registered_held_out"] == 4 and part["registered_hybrid_pos_mean_mm"] == 0.25
    assert "no held-out" in registered_note(full) and "on 4 held-out poses" in registered_note(part)
    full["name"], part["name"] = "all-used", "four-out"
    md = summary_markdown([full, part]).splitlines()
    assert "registered held-out poses" in md[2]
    cells = {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[1:-1]] for ln in md[4:6]}
    assert cells["all-used"][5] == "" and cells["all-used"][6] == "0"
    assert cells["four-out"][5] == "0.2500" and cells["four-out"][6] == "4"
    _write_summary(tmp_path / "summary.csv", [full, part])  # the CSV cell is no in-sample number either
    import csv

    with open(tmp_path / "summary.csv", newline="") as fh:
        got = list(csv.DictReader(fh))
    assert got[0]["n_registered_held_out"] == "0" and got[0]["registered_hybrid_pos_mean_mm"].lower() in ("", "nan")
