"""A new user's first hour: simulate writes the nominal robot to fit with, the help reads like the
README (no placeholders, every option explained), and the register message says what it means."""

from __future__ import annotations

import re

import numpy as np
import pytest

from hykin.cli import main


def _run(args, capsys):
    with pytest.raises(SystemExit) as e:
        main(args)
    out = capsys.readouterr()
    return e.value.code or 0, out.out, out.err


def test_simulate_writes_the_nominal_robot_beside_the_data(tmp_path, capsys):
    from hykin.io.robot_file import load_robot
    from hykin.sim.presets import virtual_preset

    code, out, err = _run(["simulate", "rx160-virtual", "-n", "40", "--no-noise", "-o", str(tmp_path / "d.csv")], capsys)
    assert code == 0, err
    rob = load_robot(tmp_path / "d.nominal.toml")
    ref = virtual_preset("rx160-virtual").nominal
    assert rob.payload_kg == ref.payload_kg == 20.0 and load_robot("rx160").payload_kg == 0.0
    for f in ("a_m", "alpha_rad", "d_m", "theta_rad", "mass_kg", "com_m", "base", "tool"):
        np.testing.assert_allclose(getattr(rob, f), getattr(ref, f), atol=1e-12, err_msg=f)
    assert f"hykin fit {tmp_path / 'd.nominal.toml'} {tmp_path / 'd.csv'}" in out
    assert "simulating rx160-virtual: done" in err  # stderr is not a terminal: plain progress lines


@pytest.mark.parametrize("cmd", ["fit", "simulate", "evaluate", "report", "demo", "split", "calibrate", "import table",
                                 "compensate", "plan"])
def test_help_has_no_placeholders_and_every_option_is_explained(cmd, capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")
    code, out, _ = _run([*cmd.split(), "--help"], capsys)
    assert code == 0
    assert "<bool>" not in out and not re.search(r"\{[a-z_]+\}", out) and "``" not in out
    assert "<list[" not in out and " range>" not in out and "DESIGN.md" not in out  # Python types; a file not shipped
    usage = next(ln for ln in out.splitlines() if "Usage:" in ln)
    assert not re.search(r" [a-z_]+(\s|$)", usage.split("[OPTIONS]")[-1])  # arguments upper-case
    for ln in out.splitlines():  # an option row: "│ --name ... help text │"; a row with only a type has no help
        m = re.match(r"│\s+\*?\s*(--[\w-]+)(.*)│$", ln)
        if m and m.group(1) != "--help":
            rest = re.sub(r"<[^>]*>|\[[^\]]*\]|-[\w-]+|,", " ", m.group(2)).strip()  # type, default, flag names
            assert rest, f"{cmd} {m.group(1)} has no help text"


def test_model_files_are_readable_by_others(tmp_path):
    import os

    from hykin.io.modelfile import write_model_file

    torch = pytest.importorskip("torch")
    write_model_file(tmp_path / "m.hykin", {"x": torch.zeros(2)}, {"k": 1})
    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "m.hykin").stat().st_mode & 0o777 == 0o666 & ~mask
