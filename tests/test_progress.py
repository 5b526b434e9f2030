"""Progress a log can use: plain lines at least every interval with steps and an ETA (fake clock),
the calibration as its own stage, and what a time budget cut; `hykin fit` with stderr to a file."""

from __future__ import annotations

import numpy as np
import pytest

from hykin.hybrid.progress import LogLines, Progress, format_duration


class FakeClock:
    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


def test_log_lines_every_interval_with_eta():
    clock, lines = FakeClock(), []
    log = LogLines("training pos net", interval_s=10, clock=clock, write=lines.append)
    written_at = []
    for step in range(1, 41):  # 3 s per step, 40 steps of 40
        clock.t += 3.0
        if log.update(step, 40, final=step == 40):
            written_at.append(clock.t - 100.0)
    assert lines[0] == "training pos net: started"
    gaps = np.diff([0.0, *written_at])
    assert gaps.max() <= 12.0 and len(written_at) >= 120 / 12  # a line at least every 10 s (+ one step)
    # the first update writes at once (no rate yet); 12 s later, at step 5 (15 s), the rate since then
    # (4 steps in 12 s) gives ETA = 35 / (4 / 12) = 105 s
    assert "1/40 steps (2 %), 3 s elapsed, ETA estimating" in lines[1]
    assert "5/40 steps (12 %), 15 s elapsed, ETA 1 min 45 s" in lines[2]
    assert lines[-1].endswith("ETA 0 s")


def test_format_duration():
    assert [format_duration(s) for s in (5, 65, 3725)] == ["5 s", "1 min 05 s", "1 h 02 min"]


def test_progress_callbacks_and_budget_cut():
    from hykin.hybrid.train import TrainResult

    clock, lines = FakeClock(), []
    p = Progress(True, tty=False, interval_s=10, clock=clock, write=lines.append)
    cb = p.callback("pos")
    clock.t += 1
    cb(10, 1000, 1e-4, float("nan"))  # before the first validation
    assert lines[-1].endswith("ETA estimating, train 0.1 mm")
    clock.t += 10
    cb(100, 1000, 1e-4, 2e-4)  # losses in m, shown in mm; 90 steps in 10 s
    assert "100/1,000 steps (10 %)" in lines[-1] and "ETA 1 min 40 s" in lines[-1] and "train 0.1 mm, val 0.2 mm" in lines[-1]
    cal = p.calibration(500)
    clock.t += 10
    cal(3, 0.5)
    assert lines[-2] == "calibration (500 poses): started" and "3 LM iterations" in lines[-1]
    p.budget_cut("pos", TrainResult(epochs=7, best_epoch=7, best_val=0, final_train=0, seconds=1, stopped="max_seconds",
                                    steps=250, planned_steps=1000))
    assert lines[-1].startswith("training pos net: time budget reached after 250 of 1,000 steps (25 %)")
    assert Progress(False).callback("pos") is None and Progress(False).calibration(5) is None


@pytest.mark.slow  # a real fit (about 6 s of CPU); the line logic is covered above with a fake clock
def test_fit_cli_logs_stages_and_eta(tmp_path, monkeypatch, capsys):
    """`hykin fit` with stderr not a terminal: a stage line for the calibration and each network, and
    progress lines with steps and an ETA (interval 0 here: a line per callback)."""
    from hykin.cli import main
    from hykin.io.dataset_files import write_dataset
    from hykin.sim.presets import virtual_preset
    from hykin.sim.sampling import sample
    from hykin.sim.simulate import simulate

    vr = virtual_preset("rx160-virtual", seed=0)
    write_dataset(simulate(vr, sample("uniform", vr.nominal, 300, 0), noise=False, rng=0), tmp_path / "train.csv")
    monkeypatch.setenv("HYKIN_PROGRESS_INTERVAL_S", "0")
    with pytest.raises(SystemExit) as e:
        main(["fit", "rx160", str(tmp_path / "train.csv"), "-o", str(tmp_path / "m.hykin"), "--min-steps", "64",
              "--max-epochs", "2"])
    assert e.value.code in (0, None)
    err = capsys.readouterr().err.splitlines()
    assert "calibration (300 poses): started" in err
    assert any(s.startswith("calibration (300 poses): done in") for s in err)
    steps = [s for s in err if s.startswith("training pos net: ") and "steps (" in s]
    assert steps and all("ETA" in s for s in steps)
    assert any(s.startswith("training rot net: done in") for s in err)



def test_terminal_bar_counts_steps():
    """On a terminal: a rich bar per network in optimiser steps with its total from the first update."""
    p = Progress(True, tty=True)
    with p:
        cb = p.callback("rot")
        cb(32, 640, 1e-3, 2e-3)
        task = p.prog.tasks[0]
        assert (task.completed, task.total) == (32, 640) and "train 0.0573 deg" in task.fields["info"]


def test_stage_without_steps():
    clock, lines = FakeClock(), []
    p = Progress(True, tty=False, clock=clock, write=lines.append)
    st = p.stage("prediction bands")
    clock.t += 75
    st.done()
    assert lines == ["prediction bands: started", "prediction bands: done in 1 min 15 s"]
    silent = Progress(False).stage("x")
    silent.done()  # writes nothing, raises nothing
