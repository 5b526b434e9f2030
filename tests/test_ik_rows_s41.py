"""2π copies of IK solutions (probe s41 AK, item 5): on an arm with two ±400° joints every solution has up
to 3 · 3 = 9 representations within the limits, more than ``MAX_TURN_COPIES = 8``, so ``ik --all-branches``
listed each once and said nothing. Now the rows can say how many they left out (:func:`turn_copies_note`),
and ``max_copies`` (classical rows) / :func:`expand_turn_copies` (any rows, e.g. hybrid IK's) list them all.
Every count and pose is checked against a brute-force enumeration and a DH forward kinematics in numpy."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from shared_fixtures import dh_robot_toml, write_text

from hykin import load_robot
from hykin.kinematics.ik_rows import (
    MAX_TURN_COPIES,
    TURN_COPIES_CAP,
    classical_ik_rows,
    expand_turn_copies,
    representations_per_solution,
    turn_copies_left_out,
    turn_copies_note,
    turn_copy_counts,
)

# the probe's "tiny" arm in metres: J4 and J6 turn ±400°
DH = [(0.0, 90.0, 0.06128, 0.0, -170.0, 120.0), (0.0766, 0.0, 0.0, 90.0, 20.0, 150.0),
      (0.0, 90.0, 0.0, 0.0, -120.0, 100.0), (0.0, -90.0, 0.0766, 0.0, -400.0, 400.0),
      (0.0, 90.0, 0.0, 0.0, -115.0, 115.0), (0.0, 0.0, 0.02298, 0.0, -400.0, 400.0)]
TOOL_Z = 0.01532


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    path = tmp_path_factory.mktemp("tiny") / "tiny.toml"
    write_text(path, dh_robot_toml("tiny", DH, f"\n[tool]\nxyz = [0.0, 0.0, {TOOL_Z}]\nrpy = [0.0, 0.0, 0.0]\n"))
    return load_robot(str(path))


def _dh_fk(q: np.ndarray) -> np.ndarray:
    """``(M, 4, 4)`` flange·tool poses of joints ``q`` ``(M, 6)`` rad, standard DH, by hand."""
    out = np.tile(np.eye(4), (len(q), 1, 1))
    for j, (a, al, d, th, _, _) in enumerate(DH):
        t = q[:, j] + np.radians(th)
        ca, sa = np.cos(np.radians(al)), np.sin(np.radians(al))
        A = np.zeros((len(q), 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = np.cos(t), -np.sin(t) * ca, np.sin(t) * sa, a * np.cos(t)
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = np.sin(t), np.cos(t) * ca, -np.cos(t) * sa, a * np.sin(t)
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3], A[:, 3, 3] = sa, ca, d, 1.0
        out = out @ A
    tool = np.eye(4)
    tool[2, 3] = TOOL_Z
    return out @ tool


def _lim():
    return np.radians([r[4] for r in DH]), np.radians([r[5] for r in DH])


def _brute_representations(q: np.ndarray) -> set:
    """Every ``q + 2π(k4 e4 + k6 e6)`` within the limits (k in -3..3), rounded: by enumeration."""
    lo, hi = _lim()
    out = set()
    for k4, k6 in itertools.product(range(-3, 4), repeat=2):
        c = q.copy()
        c[3] += 2 * np.pi * k4
        c[5] += 2 * np.pi * k6
        if np.all(c >= lo - 1e-12) and np.all(c <= hi + 1e-12):
            out.add(tuple(np.round(c, 7)))
    return out


def _q(rows) -> np.ndarray:
    return np.stack([np.asarray(rows[f"q{j + 1}"], dtype=np.float64) for j in range(6)], axis=1)


def _targets(n=30, seed=4):
    lo, hi = _lim()
    q = np.random.default_rng(seed).uniform(lo + 0.05, hi - 0.05, (n, 6))
    return q, _dh_fk(q)


def test_every_representation_is_counted_listed_on_request_and_reaches_the_target(tiny):
    q_true, T = _targets()
    assert representations_per_solution(tiny) == 9 > MAX_TURN_COPIES
    rows = classical_ik_rows(tiny, T)
    Q, tg = _q(rows), np.asarray(rows["target"], dtype=int)
    ok = np.isfinite(Q).all(1)
    assert ok.sum() >= len(T)
    # brute force: the distinct representations of the solutions the default rows list
    want = {t: set() for t in range(len(T))}
    for t, qq in zip(tg[ok], Q[ok]):
        want[t] |= _brute_representations(qq)
    n_all = sum(len(v) for v in want.values())
    np.testing.assert_array_equal(turn_copy_counts(tiny, Q[ok]),
                                  [len(_brute_representations(qq)) for qq in Q[ok]])
    # old behaviour, now said: each solution once, the rest counted in one line
    assert turn_copies_left_out(tiny, tg, Q) == n_all - ok.sum() > 0
    note = turn_copies_note(tiny, rows)
    assert note.startswith(f"note: {n_all - ok.sum()} further 2π representations") and "\n" not in note
    assert "q4, q6" in note and "max_copies=9" in note
    # asked for: all of them, each once, each reaching its target (numpy DH FK)
    full = classical_ik_rows(tiny, T, max_copies=9)
    Qf, tf = _q(full), np.asarray(full["target"], dtype=int)
    assert np.isfinite(Qf).all() and len(Qf) == n_all
    got = {t: {tuple(np.round(qq, 7)) for qq in Qf[tf == t]} for t in range(len(T))}
    assert got == want
    Tf = _dh_fk(Qf)
    assert np.abs(Tf[:, :3, 3] - T[tf, :3, 3]).max() < 1e-9
    assert np.abs(Tf[:, :3, :3] - T[tf, :3, :3]).max() < 1e-9
    assert turn_copies_note(tiny, full, 9) == ""
    # the true joints are among them
    for t in range(len(T)):
        assert tuple(np.round(q_true[t], 7)) in got[t] or any(
            np.abs(np.array(g) - q_true[t]).max() < 1e-6 for g in got[t])


def test_expand_turn_copies_lists_the_copies_of_any_rows_once(tiny):
    """Rows as hybrid IK gives them (each solution once): expanded, the same set as classical max_copies;
    expanding twice adds nothing; the other columns are carried to the copies."""
    _, T = _targets(12, seed=9)
    rows = classical_ik_rows(tiny, T)
    full = classical_ik_rows(tiny, T, max_copies=9)
    ex = expand_turn_copies(tiny, rows, max_copies=9)
    key = lambda r: sorted(zip(np.asarray(r["target"], dtype=int).tolist(), map(tuple, np.round(_q(r), 7).tolist())))
    assert key(ex) == key(full)
    assert len(expand_turn_copies(tiny, ex, max_copies=9)["target"]) == len(ex["target"])
    # a copy keeps its row's branch label and errors; its row comes first
    Q = _q(ex)
    same = np.abs(np.mod(Q[1:] - Q[:-1] + np.pi, 2 * np.pi) - np.pi).max(1) < 1e-9
    assert same.any()
    i = int(np.argmax(same)) + 1
    assert ex["branch"][i] == ex["branch"][i - 1] and ex["pos_err_mm"][i] == ex["pos_err_mm"][i - 1]
    # the default cap leaves them as they were
    assert expand_turn_copies(tiny, rows) is rows


def test_a_robot_without_wide_joints_and_bad_caps(tiny, tmp_path):
    narrow = [r[:4] + (-170.0, 170.0) if abs(r[5]) > 360 else r for r in DH]
    rob = load_robot(str(write_text(tmp_path / "narrow.toml", dh_robot_toml(
        "narrow", narrow, f"\n[tool]\nxyz = [0.0, 0.0, {TOOL_Z}]\nrpy = [0.0, 0.0, 0.0]\n"))))
    assert representations_per_solution(rob) == 1
    lo, hi = np.radians([r[4] for r in narrow]), np.radians([r[5] for r in narrow])
    rows = classical_ik_rows(rob, _dh_fk(np.random.default_rng(2).uniform(lo + 0.05, hi - 0.05, (5, 6))))
    assert np.asarray(rows["success"], dtype=bool).all()
    assert turn_copies_note(rob, rows) == "" and turn_copies_left_out(rob, rows["target"], _q(rows)) == 0
    for bad in (0, TURN_COPIES_CAP + 1):
        with pytest.raises(ValueError, match="max_copies"):
            classical_ik_rows(tiny, _targets(2)[1], max_copies=bad)


def test_cli_all_branches_notes_the_copies_left_out_and_lists_them_on_request(tmp_path, capsys):
    """``hykin ik ROBOT --all-branches``: a note counts the 2π copies left out and names --turn-copies;
    with it every copy is listed (the brute-force count), each reaching its target (DH FK here)."""
    from cli_run import run

    robot = write_text(tmp_path / "tiny.toml", dh_robot_toml("tiny", DH, f"\n[tool]\nxyz = [0.0, 0.0, {TOOL_Z}]\n"
                                                                       "rpy = [0.0, 0.0, 0.0]\n"))
    q, T = _targets(6, seed=7)
    from hykin.geometry import se3

    xyz, quat = se3.transform_to_pose(T)
    tg = tmp_path / "tg.csv"
    np.savetxt(tg, np.hstack([xyz, quat]), delimiter=",", header="x,y,z,qw,qx,qy,qz", comments="")
    code, out, err = run(["ik", robot, tg, "--all-branches", "-o", tmp_path / "a.csv"], capsys)
    assert code == 0 and "--turn-copies 9 lists them" in err, err
    code, out, err = run(["ik", robot, tg, "--all-branches", "--turn-copies", "9", "-o", tmp_path / "b.csv"], capsys)
    assert code == 0 and "further 2π" not in err, err
    got = np.genfromtxt(tmp_path / "b.csv", delimiter=",", names=True, dtype=None, encoding="utf-8")
    Q = np.stack([got[f"q{j + 1}"].astype(float) for j in range(6)], 1)
    ok = np.isfinite(Q).all(1)
    np.testing.assert_allclose(_dh_fk(Q[ok])[:, :3, 3], T[got["target"][ok].astype(int)][:, :3, 3], atol=1e-8)
    for k in range(len(q)):  # every representation of the generating joints is listed
        listed = Q[ok & (got["target"] == k)]
        for r in _brute_representations(q[k]):
            assert np.abs(listed - np.array(r)).max(1).min() < 1e-6, (k, r)
