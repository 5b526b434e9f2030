"""hykin fleet / sweep output rules and Ray start-up, without starting Ray: an output file that is an
input is refused (fleet and sweep, even with --force / --resume); an output folder that holds an earlier
fleet is refused without --resume / --force, as a sweep is (both take --force); a Ray that fails to start
is tried once more, then one line naming the cause and what to do (no traceback)."""

from __future__ import annotations

import hashlib
import shutil

import pytest
from shared_fixtures import fake_sweep_ray, sweep_files, write_text

from cli_run import run
from hykin.distributed.trials import ERROR_COLUMNS

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    return sweep_files(tmp_path_factory.mktemp("s39fleet"), 12)


def _no_ray(monkeypatch):
    """Any start of Ray by the fleet or the sweep fails the test loudly (the refusals come before it)."""
    import hykin.distributed.fleet as fleet_mod
    import hykin.distributed.sweep as sweep_mod

    def boom(*a, **k):
        raise AssertionError("Ray was started")

    monkeypatch.setattr(fleet_mod, "ray_session", boom)
    monkeypatch.setattr(sweep_mod, "ray_session", boom)
    return fleet_mod


def _fake_robots(monkeypatch, fleet_mod, calls):
    """The fleet's Ray part as a stand-in: every robot 'fits' and writes its model file."""

    def fake(spec, todo, out, rows, address, num_cpus, log):
        calls.append([r.name for r in todo])
        out.mkdir(parents=True, exist_ok=True)
        for r in todo:
            (out / f"{r.name}.hykin").write_bytes(b"new model")
            rows[r.name] = {"name": r.name, "status": "ok", "error": "", "model": f"{r.name}.hykin",
                            **dict.fromkeys(ERROR_COLUMNS, 0.5)}

    monkeypatch.setattr(fleet_mod, "_run_robots", fake)


def _md5(p):
    return hashlib.md5(p.read_bytes()).hexdigest()


@pytest.mark.parametrize("extra", [[], ["--force"], ["--resume"]])
def test_fleet_refuses_to_write_its_summary_over_a_test_set_in_the_output_folder(files, tmp_path, monkeypatch, capsys,
                                                                                 extra):
    """probeR #2: the test set saved as OUT/summary.csv was replaced by the fleet summary."""
    _no_ray(monkeypatch)
    out = tmp_path / "ovr_out"
    out.mkdir()
    shutil.copy(files / "test.csv", out / "summary.csv")
    before = _md5(out / "summary.csv")
    shutil.copy(files / "train.csv", tmp_path / "train.csv")
    p = write_text(tmp_path / "ovr.toml", '[[robot]]\nname = "cellC"\nrobot = "rx160"\ntrain = "train.csv"\n'
                                          'test = "ovr_out/summary.csv"\n')
    code, o, err = run(["fleet", p, "-o", out, *extra], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "refusing to write the output over the input file" in err and "summary.csv" in err
    assert _md5(out / "summary.csv") == before and sorted(x.name for x in out.iterdir()) == ["summary.csv"]


def test_fleet_refuses_a_model_file_named_like_an_input(files, tmp_path, monkeypatch, capsys):
    """A robot's train set saved as OUT/NAME.hykin's name (any output the fleet writes) is refused too."""
    _no_ray(monkeypatch)
    out = tmp_path / "o"
    out.mkdir()
    shutil.copy(files / "train.csv", out / "cellC.hykin")
    p = write_text(tmp_path / "f.toml", '[[robot]]\nname = "cellC"\nrobot = "rx160"\ntrain = "o/cellC.hykin"\n')
    code, _, err = run(["fleet", p, "-o", out, "--force"], capsys)
    assert code == 2 and "over the input file" in err and "cellC.hykin" in err


def test_fleet_into_an_earlier_fleet_is_refused_without_resume_or_force(files, tmp_path, monkeypatch, capsys):
    """probeR #3: a rerun without --resume replaced every model and summary; now one line naming
    --resume and --force, nothing touched; --force fits every robot again over it."""
    fleet_mod = _no_ray(monkeypatch)
    for n in ("train.csv", "test.csv"):
        shutil.copy(files / n, tmp_path / n)
    p = write_text(tmp_path / "f.toml", '[[robot]]\nname = "armA"\nrobot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n'
                                        '[[robot]]\nname = "cellC"\nrobot = "rx160"\ntrain = "train.csv"\n')
    out = tmp_path / "fleet_out"
    out.mkdir()
    (out / "armA.hykin").write_bytes(b"kept model")  # an earlier fleet's model (summary lost)
    code, _, err = run(["fleet", p, "-o", out], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "holds an earlier fleet (armA.hykin)" in err and "--resume" in err and "--force" in err
    assert (out / "armA.hykin").read_bytes() == b"kept model" and sorted(x.name for x in out.iterdir()) == ["armA.hykin"]
    calls = []
    _fake_robots(monkeypatch, fleet_mod, calls)
    code, o, err = run(["fleet", p, "-o", out, "--force"], capsys)
    assert code == 0, err
    assert calls == [["armA", "cellC"]] and (out / "armA.hykin").read_bytes() == b"new model"
    assert "2 of 2 robots ok" in o and (out / "summary.csv").is_file()
    # the same folder again: its summary is an earlier fleet now
    code, _, err = run(["fleet", p, "-o", out], capsys)
    assert code == 2 and "holds an earlier fleet (summary.csv, summary.md, armA.hykin and 1 more)" in err
    # an empty or new folder is no earlier fleet
    code, _, err = run(["fleet", p, "-o", tmp_path / "new"], capsys)
    assert code == 0 and calls[-1] == ["armA", "cellC"]


def _fake_sweep(monkeypatch):
    """run_sweep without Ray: the trials each run got (:func:`shared_fixtures.fake_sweep_ray`)."""
    return fake_sweep_ray(monkeypatch)[1]


def test_sweep_force_starts_over_and_an_input_in_the_output_folder_is_refused(files, tmp_path, monkeypatch, capsys):
    """--force on the sweep (consistent with the fleet): an earlier sweep is started over, its records
    dropped; a test set saved as OUT/results.csv is refused, with --force and --resume too."""
    for n in ("train.csv", "test.csv"):
        shutil.copy(files / n, tmp_path / n)
    p = write_text(tmp_path / "s.toml", 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nseed = [0, 1]\n')
    out = tmp_path / "sweep_out"
    calls = _fake_sweep(monkeypatch)
    assert run(["sweep", p, "-o", out], capsys)[0] == 0
    code, _, err = run(["sweep", p, "-o", out], capsys)
    assert code == 2 and "--resume" in err and "--force" in err and len(err.strip().splitlines()) == 1
    (out / "trials.jsonl").write_text((out / "trials.jsonl").read_text() + '{"key": "stale", "row": {}}\n')
    code, o, err = run(["sweep", p, "-o", out, "--force"], capsys)
    assert code == 0, err
    assert calls == [[0, 1], [0, 1]] and "stale" not in (out / "trials.jsonl").read_text()
    assert len((out / "trials.jsonl").read_text().splitlines()) == 2
    # a test set in the output folder, named as an output
    _no_ray(monkeypatch)
    o2 = tmp_path / "o2"
    o2.mkdir()
    shutil.copy(files / "test.csv", o2 / "results.csv")
    before = _md5(o2 / "results.csv")
    p2 = write_text(tmp_path / "s2.toml", 'robot = "rx160"\ntrain = "train.csv"\ntest = "o2/results.csv"\n[grid]\nseed = [0]\n')
    for extra in ([], ["--force"], ["--resume"]):
        code, _, err = run(["sweep", p2, "-o", o2, *extra], capsys)
        assert code == 2 and "over the input file" in err and len(err.strip().splitlines()) == 1, err
    assert _md5(o2 / "results.csv") == before


# --------------------------------------------------------------------------- Ray start-up


class _FakeRay:
    """``ray`` as far as :func:`ray_session` uses it; ``init`` fails its first ``fails`` calls."""

    def __init__(self, fails):
        self.fails, self.inits, self.shutdowns, self.up = fails, [], 0, False

    def is_initialized(self):
        return self.up

    def init(self, address=None, **kw):
        self.inits.append((address, kw))
        if len(self.inits) <= self.fails:
            raise Exception("The current node timed out during startup. This could happen because some of the raylet "
                            "failed to startup or the GCS has become overloaded.\nmore lines\nof Ray's traceback")
        self.up = True

    def shutdown(self):
        self.shutdowns += 1
        self.up = False


def _patch_ray(monkeypatch, fake):
    import hykin.distributed.ray_session as rs

    monkeypatch.setattr(rs, "import_ray", lambda: fake)
    monkeypatch.setattr(rs, "RETRY_WAIT_S", 0.0)
    return rs


def test_a_ray_start_that_times_out_once_is_retried(monkeypatch):
    fake = _FakeRay(fails=1)
    rs = _patch_ray(monkeypatch, fake)
    with rs.ray_session(None, 2) as ray:
        assert ray is fake and fake.up
    assert len(fake.inits) == 2 and fake.inits[1][1]["num_cpus"] == 2
    assert fake.shutdowns == 2  # the half-started one, then the session's own at the end


@pytest.mark.parametrize("address, words", [(None, ["load average", "--num-cpus", "ray start --head", "--address auto"]),
                                            ("10.0.0.9:6379", ["--address 10.0.0.9:6379", "ray status"])])
def test_a_ray_that_does_not_start_twice_is_one_line_naming_cause_and_remedy(files, tmp_path, monkeypatch, capsys,
                                                                             address, words):
    """probeR #4: a 40-line traceback, exit 1; now one line (exit 2), after one retry, nothing written."""
    fake = _FakeRay(fails=2)
    _patch_ray(monkeypatch, fake)
    shutil.copy(files / "train.csv", tmp_path / "train.csv")
    p = write_text(tmp_path / "f.toml", '[[robot]]\nname = "r"\nrobot = "rx160"\ntrain = "train.csv"\n')
    out = tmp_path / "out"
    argv = ["fleet", p, "-o", out, "--num-cpus", "2"] + (["--address", address] if address else [])
    code, o, err = run(argv, capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "Traceback" not in err and "timed out during startup" in err and "tried twice" in err
    assert all(w in err for w in words), err
    assert len(fake.inits) == 2 and not out.exists()
    # the sweep goes through the same session
    fake.inits.clear()
    for n in ("train.csv",):
        shutil.copy(files / n, tmp_path / "test.csv")
    ps = write_text(tmp_path / "s.toml", 'robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nseed = [0]\n')
    code, _, err = run(["sweep", ps, "-o", tmp_path / "sw"] + (["--address", address] if address else []), capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1 and "tried twice" in err and len(fake.inits) == 2
