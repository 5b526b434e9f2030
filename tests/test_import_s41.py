"""Probe s41 AK (items 1-4): ``import table --suggest`` maps ``rx, ry, rz`` rotation vectors and guesses the
Euler unit by the import's own unit rule; an import that leaves orientation columns out says the data are
position only; kept ids keep their zero padding; ``fk``'s missing-joint message names only joints.
Every orientation is checked against quaternions computed here by hand (numpy)."""

from __future__ import annotations

import numpy as np
import pytest
from cli_run import run

from hykin.io.dataset import DatasetError
from hykin.io.dataset_files import read_joints
from hykin.io.toml_compat import tomllib
from hykin.measure.table_import import import_table, kept_cells

N = 40


def _qmul(a, b):
    """Hamilton product of ``(N, 4)`` scalar-first quaternions."""
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], 1)


def _axis_quat(angle, axis):
    q = np.zeros((len(angle), 4))
    q[:, 0], q[:, 1 + axis] = np.cos(angle / 2), np.sin(angle / 2)
    return q


def _rotvec_quat(r):
    th = np.linalg.norm(r, axis=1)
    return np.column_stack([np.cos(th / 2), np.sin(th / 2)[:, None] * r / th[:, None]])


def _same_rotation(qa, qb):
    return np.abs(np.abs(np.sum(qa * qb, axis=1)) - 1.0).max()


def _write(path, header, cols, fmt="{:.12f}", sep=","):
    lines = [sep.join(header)] + [sep.join(c if isinstance(c, str) else fmt.format(c) for c in row)
                                  for row in zip(*cols)]
    path.write_text("\n".join(lines) + "\n")
    return path


def _base(rng):
    return [*rng.uniform(-2, 2, (6, N))], [*rng.uniform(-1.5, 1.5, (3, N))]


def _suggest(path, capsys):
    code, so, se = run(["import", "table", path, "--suggest"], capsys)
    assert code == 0, se
    return so, tomllib.loads(so)


def _imported_quat(path, map_text, tmp_path, capsys):
    mp = tmp_path / "m.toml"
    mp.write_text(map_text)
    out = tmp_path / "o.csv"
    code, so, se = run(["import", "table", path, "--map", mp, "-o", out], capsys)
    assert code == 0, se
    d = np.genfromtxt(out, delimiter=",", names=True)
    return np.stack([d[k] for k in ("qw", "qx", "qy", "qz")], 1), so + se


@pytest.mark.parametrize("names, deg", [(["rx", "ry", "rz"], False), (["RX", "RY", "RZ"], True), (["Rx", "Ry", "Rz"], False)])
def test_suggest_maps_a_rotation_vector_and_its_unit(tmp_path, capsys, names, deg):
    """Before: rx, ry, rz beside x, y, z were printed commented out only: imported as printed, position only."""
    rng = np.random.default_rng(3)
    j, p = _base(rng)
    ax = rng.normal(size=(N, 3))
    r = ax / np.linalg.norm(ax, axis=1, keepdims=True) * rng.uniform(0.05, np.pi - 1e-3, (N, 1))
    shown = np.degrees(r) if deg else r
    path = _write(tmp_path / "v3.csv", [f"joint_{i}" for i in range(1, 7)] + ["x", "y", "z"] + names, j + p + [*shown.T])
    text, sug = _suggest(path, capsys)
    assert sug["rotvec"] == names and sug["rotvec_unit"] == ("deg" if deg else "rad")
    quat, _ = _imported_quat(path, text, tmp_path, capsys)
    assert _same_rotation(quat, _rotvec_quat(r)) < 1e-9


def test_euler_like_rotation_columns_are_named_not_mapped_and_the_import_says_position_only(tmp_path, capsys):
    rng = np.random.default_rng(5)
    j, p = _base(rng)
    e = rng.uniform(-np.pi, np.pi, (N, 3))
    assert (np.linalg.norm(e, axis=1) > np.pi).any()  # not a rotation vector
    path = _write(tmp_path / "e.csv", [f"q{i}" for i in range(1, 7)] + ["x", "y", "z", "rx", "ry", "rz"], j + p + [*e.T])
    text, sug = _suggest(path, capsys)
    assert "rotvec" not in sug and "euler" not in sug
    assert "# NOT MAPPED: rx, ry, rz look like an orientation; as printed the import is position only" in text
    assert '# euler_unit = "rad"' in text
    mp = tmp_path / "m.toml"
    mp.write_text(text)
    code, so, se = run(["import", "table", path, "--map", mp, "-o", tmp_path / "o.csv"], capsys)
    assert code == 0, se
    assert "position only" in so
    notes = [ln for ln in se.splitlines() if "look like an orientation" in ln]
    assert len(notes) == 1 and "rx, ry, rz" in notes[0] and "the dataset is position only" in notes[0]
    # mapped, nothing is said
    code, so, se = run(["import", "table", path, "--map", mp, "-o", tmp_path / "o2.csv", "--euler", "rx,ry,rz",
                        "--euler-convention", "xyz"], capsys)
    assert code == 0 and "look like an orientation" not in se


@pytest.mark.parametrize("deg", [True, False])
def test_suggest_guesses_the_euler_unit_as_the_unit_check_does(tmp_path, capsys, deg):
    """Before: roll/pitch/yaw in degrees got euler_unit = "rad", which the import then refused."""
    rng = np.random.default_rng(7)
    j, p = _base(rng)
    e = rng.uniform(-np.pi, np.pi, (N, 3))
    e[0, 0] = 0.98 * np.pi  # as the probe: up to ±180°
    path = _write(tmp_path / "v4.csv", [f"q{i}" for i in range(1, 7)] + ["x", "y", "z", "roll", "pitch", "yaw"],
                  j + p + [*(np.degrees(e) if deg else e).T])
    text, sug = _suggest(path, capsys)
    assert sug["euler"] == ["roll", "pitch", "yaw"] and sug["euler_convention"] == "rpy"
    assert sug["euler_unit"] == ("deg" if deg else "rad")
    quat, _ = _imported_quat(path, text, tmp_path, capsys)
    # extrinsic x, y, z: R = Rz(yaw) Ry(pitch) Rx(roll)
    want = _qmul(_qmul(_axis_quat(e[:, 2], 2), _axis_quat(e[:, 1], 1)), _axis_quat(e[:, 0], 0))
    assert _same_rotation(quat, want) < 1e-9


def test_kept_ids_keep_their_zero_padding(tmp_path, capsys):
    """Before: --keep id turned 0000, 0001 into 0, 1. Numbers stay numbers (a decimal comma read)."""
    rng = np.random.default_rng(11)
    j, p = _base(rng)
    ids = [f"{i:04d}" for i in range(N)]
    std = rng.uniform(0.01, 0.5, N)
    std_txt = [f"{v:.6f}".replace(".", ",") for v in std]
    path = _write(tmp_path / "v2.tsv", ["id"] + [f"J{i}" for i in range(1, 7)] + ["X", "Y", "Z", "Std"],
                  [ids] + [[f"{v:.12f}".replace(".", ",") for v in c] for c in j + p] + [std_txt], sep="\t")
    out = tmp_path / "o.csv"
    code, so, se = run(["import", "table", path, "-o", out, "--joints", "J1..J6", "--position", "X,Y,Z", "--decimal", ",",
                        "--keep", "id,Std"], capsys)
    assert code == 0, se
    lines = out.read_text().splitlines()
    head = lines[0].split(",")
    col = [ln.split(",")[head.index("id")] for ln in lines[1:]]
    assert col == ids
    np.testing.assert_allclose([float(ln.split(",")[head.index("Std")]) for ln in lines[1:]], np.round(std, 6), atol=1e-12)
    ds = import_table(path, {"joints": "J1..J6", "position": ["X", "Y", "Z"], "decimal": ",", "keep": ["id", "Std"]})
    assert ds.extra["id"].dtype.kind == "U" and list(ds.extra["id"]) == ids
    assert ds.extra["Std"].dtype == np.float64
    np.testing.assert_allclose(ds.q[:, 0], np.round(j[0], 12), atol=1e-12)
    # the rule, cell by cell
    assert list(kept_cells(["007", "8"])) == ["007", "8"] and kept_cells(["1", "2.5"]).tolist() == [1.0, 2.5]
    assert kept_cells(["0.5", "-0.25"]).tolist() == [0.5, -0.25] and list(kept_cells(["-01", "2"])) == ["-01", "2"]
    assert list(kept_cells([" 1 ", "2"], label=True)) == ["1", "2"]


def test_fk_missing_joints_message_names_only_joints(tmp_path, capsys):
    """Before: "missing column(s) q4, q5, q6; expected q1, ..., q6, x, y, z and optionally qw, ..." for fk,
    which reads joints only."""
    f = tmp_path / "j.csv"
    f.write_text("q1,q2,q3\n0,0,0\n")
    code, _, err = run(["fk", "rx160", f, "-o", tmp_path / "p.csv"], capsys)
    assert code != 0
    assert "missing column(s) q4, q5, q6; expected the joint columns q1, q2, q3, q4, q5, q6 (found: q1, q2, q3)" in err
    assert "x, y, z" not in err and "qw" not in err
    g = tmp_path / "none.csv"
    g.write_text("a,b\n0,0\n")
    with pytest.raises(DatasetError, match=r"no joint columns; expected q1\.\.qN \(found: a, b\)$"):
        read_joints(g)
