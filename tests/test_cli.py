"""Command line: commands work end to end and bad input gives one line and a non-zero exit."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from cli_run import run

from hykin.geometry.se3 import pose_error
from hykin.io.dataset_files import read_dataset
from hykin.io.robot_file import load_robot
from hykin.kinematics.fk import fk


def write_joints(path, q, header=None):
    header = header or [f"q{i + 1}" for i in range(q.shape[1])]
    with open(path, "w") as f:
        f.write(",".join(header) + "\n")
        f.writelines(",".join(repr(float(v)) for v in row) + "\n" for row in q)


def test_help_for_every_command(capsys):
    for cmd in ("simulate", "fit", "fk", "ik", "evaluate", "register", "demo", "import", "calibrate", "export"):
        code, out, _ = run([cmd, "--help"], capsys)
        assert code == 0 and "Usage" in out, cmd


def test_fk_nominal_matches_library(tmp_path, capsys):
    robot = load_robot("rx160")
    q = robot.random_joints(50, 1)
    write_joints(tmp_path / "j.csv", q)
    code, out, err = run(["fk", "rx160", str(tmp_path / "j.csv"), "-o", str(tmp_path / "p.csv")], capsys)
    assert code == 0, err
    ds = read_dataset(tmp_path / "p.csv")
    p, a = pose_error(ds.poses(), fk(robot, q))
    assert p.max() < 1e-9 and a.max() < 1e-9


def test_fk_degrees_declared(tmp_path, capsys):
    robot = load_robot("ur5")
    q = robot.random_joints(20, 2) * 0.5
    write_joints(tmp_path / "j.csv", np.degrees(q))
    code, _, err = run(["fk", "ur5", str(tmp_path / "j.csv"), "-o", str(tmp_path / "p.csv"), "--angle-unit", "deg"], capsys)
    assert code == 0, err
    ds = read_dataset(tmp_path / "p.csv")
    assert np.allclose(ds.xyz_m, fk(robot, q)[:, :3, 3], atol=1e-12)


@pytest.mark.parametrize(
    "content, expect",
    [
        ("q1,q2,q3,q4,q5,q6\n0,0,0,0,nan,0\n", "row"),  # NaN names the row
        ("q1,q2,q3,q4,q5,q6\n0,0,90,0,45,0\n", "deg"),  # degrees passed as radians
        ("q1,q2,q3\n0,0,0\n", "q4"),  # missing columns
    ],
)
def test_bad_joint_files_one_line_errors(tmp_path, capsys, content, expect):
    f = tmp_path / "bad.csv"
    f.write_text(content)
    code, out, err = run(["fk", "rx160", str(f), "-o", str(tmp_path / "p.csv")], capsys)
    assert code != 0
    lines = [ln for ln in err.strip().splitlines() if ln]
    assert len(lines) == 1 and lines[0].startswith("hykin: error:"), err
    assert str(f) in lines[0] and expect in lines[0], lines[0]
    assert "Traceback" not in err


def test_unknown_robot_one_line(tmp_path, capsys):
    write_joints(tmp_path / "j.csv", np.zeros((1, 6)))
    code, _, err = run(["fk", "no-such-robot", str(tmp_path / "j.csv"), "-o", str(tmp_path / "p.csv")], capsys)
    assert code != 0 and "no-such-robot" in err and len(err.strip().splitlines()) == 1


def test_simulate_writes_data_and_truth(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    code, _, err = run(["simulate", "rx160-virtual", "-n", "300", "-o", str(out), "--seed", "3", "--plan", "random"], capsys)
    assert code == 0, err
    ds = read_dataset(out)
    assert len(ds) == 300 and ds.has_orientation
    assert (tmp_path / "sim.truth.json").exists()
    # the simulated robot differs from the nominal one by about the paper's 1.8 mm
    p, _ = pose_error(fk(load_robot("rx160"), ds.q), ds.poses())
    assert 0.5 < p.mean() < 5.0


def test_calibrate_command_recovers_truth(tmp_path, capsys):
    out = tmp_path / "sim.csv"
    assert run(["simulate", "rx160-virtual", "-n", "1500", "-o", str(out), "--no-noise"], capsys)[0] == 0
    from hykin.sim.simulate import load_truth, simulate

    vr = load_truth(tmp_path / "sim.truth.json")
    code, stdout, err = run(["calibrate", _nominal_file(vr, tmp_path), str(out), "-o", str(tmp_path / "cal.toml")], capsys)
    assert code == 0, err
    cal = load_robot(tmp_path / "cal.toml")
    q = vr.nominal.random_joints(300, 9)
    test = simulate(vr, q, noise=False)
    from hykin.kinematics.compliance import compliant_fk

    p, a = pose_error(compliant_fk(cal, q), test.poses())
    assert p.mean() < 1e-3 and a.mean() < 1e-4  # below 1 µm and 1e-4 deg


def _nominal_file(vr, tmp_path):
    from hykin.io.robot_toml import save_robot_toml

    path = tmp_path / "nominal.toml"
    save_robot_toml(vr.nominal, path)
    return str(path)


def test_console_script_entry_point(tmp_path):
    """The installed module entry point exits non-zero with one line on a missing file."""
    proc = subprocess.run(
        [sys.executable, "-c", "from hykin.cli import main; main()", "fk", "rx160", str(tmp_path / "missing.csv"), "-o", str(tmp_path / "o.csv")],
        capture_output=True, text=True, timeout=120,
    )
    assert proc.returncode != 0
    assert proc.stderr.strip().count("\n") == 0 and "missing.csv" in proc.stderr


def test_fit_then_fk_evaluate_ik_end_to_end(tmp_path, capsys):
    """simulate -> fit (short) -> fk / evaluate / ik on the model file; numbers agree with the API."""
    from hykin.hybrid.model import HybridModel

    data, model = tmp_path / "d.csv", tmp_path / "m.hykin"
    code, _, err = run(["simulate", "rx160-nongeo", "-n", "800", "-o", str(data), "--seed", "2", "--noise"], capsys)
    assert code == 0, err
    code, out, err = run(["fit", "rx160", str(data), "-o", str(model), "--min-steps", "300", "--max-epochs", "40",
                          "--seed", "1"], capsys)
    assert code == 0, err
    assert "thermal expansion:" in out and "hybrid" in out  # the data carry temperature_c
    m = HybridModel.load(model)
    assert m.recipe.min_steps == 300 and m.thermal_ is not None
    ds = read_dataset(data)
    code, _, err = run(["fk", str(model), str(data), "-o", str(tmp_path / "p.csv")], capsys)
    assert code == 0, err
    got = read_dataset(tmp_path / "p.csv")
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        T = m.predict(ds.q, temperature_c=ds.extra["temperature_c"])
    assert np.abs(got.xyz_m - T[:, :3, 3]).max() < 1e-9
    assert {"support_distance", "pos_band95_mm", "ang_band95_deg"} <= set(got.extra)
    code, out, err = run(["evaluate", str(model), str(data), "--json"], capsys)
    assert code == 0, err
    import json

    res = json.loads(out[out.index("{"):])
    assert res["stats"]["hybrid"]["pos_mean_mm"] < res["stats"]["nominal"]["pos_mean_mm"] / 5
    # IK on the first 200 of the 800 poses (each target is solved on its own: 200 show the same as 800)
    for name in ("p.csv", "d.csv"):
        lines = (tmp_path / name).read_text().splitlines(keepends=True)
        (tmp_path / f"head-{name}").write_text("".join(lines[:201]))
    code, out, err = run(["ik", str(model), str(tmp_path / "head-p.csv"), "-o", str(tmp_path / "j.csv"),
                          "--seed-joints", str(tmp_path / "head-d.csv")], capsys)
    assert code == 0, err
    assert "200 targets" in out
    code, _, err = run(["fit", "rx160", str(data), "-o", str(model), "--thermal", "maybe"], capsys)
    assert code != 0 and "--thermal" in err and "\n" not in err.strip()


def test_messages_keep_bracketed_text():
    """Rich drops unknown [tags]: "the robot file's [tool]" printed without "[tool]", and the demo table's
    "[mm]" units vanished (probe report s40). hykin's own style tags still style."""
    import io

    from rich.console import Console

    from hykin.cli.common import plain_markup

    buf = io.StringIO()
    Console(file=buf, soft_wrap=True).print(plain_markup("[yellow]note:[/] the robot file's [tool] in [mm], BASE_DATA[1]"))
    assert buf.getvalue().strip() == "note: the robot file's [tool] in [mm], BASE_DATA[1]"


def test_messages_printed_without_markup_are_not_escaped(capsys):
    """hykin's console escaped every message, also those printed with ``markup=False``: a note showed
    "the robot file's \\[tool]" (stop 42's own run). Those are printed as they are."""
    from hykin.cli.common import console

    console().print("note: the robot file's [tool] in [mm]", markup=False, highlight=False)
    console().print("note: the robot file's [tool] in [mm]", highlight=False)
    assert capsys.readouterr().err.splitlines() == ["note: the robot file's [tool] in [mm]"] * 2


def test_report_directories_are_not_overwritten_without_force(tmp_path, capsys):
    """``report -o DIR``, ``evaluate --report DIR`` and ``demo -o DIR`` overwrote DIR/report.html silently
    (probe report s40); the README promises a refusal without --force."""
    from cli_run import run

    d = tmp_path / "rep"
    d.mkdir()
    (d / "report.html").write_text("earlier report")
    for argv in (["report", "rx160", "-o", d], ["demo", "-o", d, "--quick"]):
        code, _, err = run(argv, capsys)
        assert code == 2 and "output exists; pass --force" in err and len(err.strip().splitlines()) == 1
    assert (d / "report.html").read_text() == "earlier report"
    code, _, err = run(["report", "rx160", "-o", d, "--force"], capsys)
    assert code == 0, err and (d / "report.html").read_text() != "earlier report"
