"""Batched kernels on hykin's own thread pool (stop 43).

A hybrid FK batch of 300 poses took 8 ms instead of ~1: the orientation correction ran as a numba
``prange`` loop right after the networks' BLAS calls, and numba's OpenMP workers and OpenBLAS's
threads spin-waited against each other on the two cores. Every batched kernel now runs on
:func:`hykin.kinematics.chunks.run_chunked` (plain threads that sleep when idle), and the two networks
of the hybrid model are evaluated in one pass (:func:`hykin.hybrid.fast_nets.evaluate`).

References: the same kernels on one thread, row by row, and the networks one at a time; the rotation
against :func:`hykin.hybrid.rotations.rodrigues` (numpy); FK against a chain product written here.
"""

from __future__ import annotations

import ast
import pathlib

import numpy as np
import pytest
import torch

import hykin
from hykin.hybrid import fast_nets
from hykin.hybrid.fast_nets import evaluate, fast_net
from hykin.hybrid.nets import make_net
from hykin.kinematics import chunks

ROOT = pathlib.Path(hykin.__file__).resolve().parent


def _net(name: str, seed: int, lo=-np.pi, hi=np.pi, n_out: int = 3):
    torch.manual_seed(seed)
    net = make_net(name, 6, n_out)
    net.set_input_range(lo * np.ones(6), hi * np.ones(6))
    net.set_output_scale(np.linspace(-1e-3, 1e-3, n_out), 2e-3)
    return fast_net(net.eval())


@pytest.fixture
def three_workers(monkeypatch):
    """Small chunks and three workers: rows split unevenly over the pool."""
    monkeypatch.setattr(chunks, "worker_count", lambda: 3)
    monkeypatch.setattr(fast_nets, "threads", lambda: 3)
    monkeypatch.setattr(fast_nets, "CHUNK_ROWS", 37)
    monkeypatch.setattr(fast_nets, "PARALLEL_ROWS", 50)


def test_networks_in_one_pass_equal_each_alone(three_workers):
    """Position and orientation nets of one normalisation share their features; a net of another range
    or another feature kind gets its own. Every output equals that net evaluated alone, bit for bit."""
    q = np.random.default_rng(1).uniform(-4, 4, (431, 6))
    nets = [_net("default", 1), _net("default", 2), _net("default", 3, lo=-2.0, hi=2.5), _net("B1", 4),
            _net("default-wide", 5, n_out=2)]
    alone = [f(q) for f in nets]
    together = evaluate(nets, q)
    for a, b in zip(alone, together):
        assert a.shape == b.shape and np.array_equal(a, b)
    # and the same numbers as one chunk on one thread
    fast_nets.CHUNK_ROWS, fast_nets.PARALLEL_ROWS = 10_000, 10_000
    for a, b in zip(evaluate(nets, q), together):
        assert np.abs(a - b).max() <= 1e-15 * np.abs(a).max()
    assert [o.shape for o in evaluate(nets, q[:0])] == [(0, 3)] * 4 + [(0, 2)]


def test_chunked_kernels_equal_one_thread(three_workers, monkeypatch):
    """FK, gravity torques, joint deflection, pair gaps and the orientation correction over three
    workers in uneven pieces give exactly the one-thread numbers; FK equals the single-pose path
    (another kernel) and the rotation numpy's Rodrigues formula."""
    from hykin.hybrid import rotations, support
    from hykin.hybrid.support import Support
    from hykin.kinematics import compliance
    from hykin.kinematics import fk as fk_mod

    for mod, name in ((fk_mod, "_PARALLEL_MIN"), (compliance, "_PARALLEL_MIN"), (rotations, "_PARALLEL_MIN"),
                      (support, "_PAIR_GAP_PARALLEL_MIN")):
        monkeypatch.setattr(mod, name, 200)  # 2,503 rows: pieces over all three workers
    rob = hykin.load_robot("kuka-kr6-r900").copy(
        mass_kg=[20.0, 12.0, 8.0, 3.0, 2.0, 0.5], payload_kg=3.0, stiffness_nm_per_rad=[3e5, 2e5, 1.5e5, 4e4, 4e4, 3e4],
        com_m=[[0, 0, 0], [0.2, 0, 0], [0.05, 0, 0], [0, 0, 0.1], [0, 0, 0], [0, 0, 0]])
    N = 2_503
    q = rob.random_joints(N, 3)
    rng = np.random.default_rng(5)
    grid = rng.uniform(0, 1, (3, 9, 9))
    sup = Support(np.full(6, -3.0), np.full(6, 3.0), np.zeros((1, 6)), 0.1, None,
                  np.array([[0, 1], [2, 4], [3, 5]]), grid)
    rv = rng.normal(0, 1e-3, (N, 3))
    rv[::7] *= 1e-4  # the small-angle branch too
    R0 = np.tile(np.eye(4), (N, 1, 1))
    R0[:, :3, :3] = rotations.rodrigues(rng.normal(0, 1, (N, 3)))

    def rotated():
        T = R0.copy()
        rotations.rotate_poses(rv, T)
        return T

    kernels = {"fk": lambda: hykin.fk(rob, q), "tau": lambda: compliance.gravity_torques(rob, q),
               "deflect": lambda: compliance.deflected_joints(rob, q), "gap": lambda: support.pair_gap(sup, q),
               "rotate": rotated}
    threaded = {k: f() for k, f in kernels.items()}
    monkeypatch.setattr(chunks, "worker_count", lambda: 1)
    for k, f in kernels.items():
        assert np.array_equal(threaded[k], f()), k
    assert threaded["gap"].max() > 0 and threaded["deflect"].shape == q.shape
    for k in (0, 1234, N - 1):
        assert np.abs(threaded["fk"][k] - hykin.fk(rob, q[k])).max() < 1e-15
    ref = rotations.rodrigues(rv) @ R0[:, :3, :3]
    assert np.abs(threaded["rotate"][:, :3, :3] - ref).max() < 1e-15


def test_no_openmp_prange_in_hykin():
    """numba's ``parallel=True`` / ``prange`` start OpenMP workers that spin after each loop against the
    BLAS and pool threads beside them (the 300-pose FK batch above). hykin's kernels use
    :func:`hykin.kinematics.chunks.run_chunked` instead: none may come back."""
    offenders = []
    for path in ROOT.rglob("*.py"):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if isinstance(node, ast.keyword) and node.arg == "parallel" and getattr(node.value, "value", None) is True:
                offenders.append(f"{path.relative_to(ROOT)}:{node.value.lineno} parallel=True")
            if isinstance(node, ast.Attribute) and node.attr == "prange":
                offenders.append(f"{path.relative_to(ROOT)}:{node.lineno} prange")
    assert not offenders, offenders


def _chunked_in_child(args):
    rob, q, ref = args
    chunks.worker_count = lambda: 2
    return float(np.abs(hykin.fk(rob, q) - ref).max())


def test_pool_serves_a_forked_child():
    """A process forked after the pool ran makes its own pool (the parent's threads do not exist in
    the child) and gets the same numbers."""
    import multiprocessing as mp
    import sys

    if sys.platform != "linux":
        pytest.skip("fork start method")
    rob = hykin.load_robot("ur5")
    q = rob.random_joints(50_000, 4)
    ref = hykin.fk(rob, q)  # the parent's pool exists now (50,000 rows: two workers)
    with mp.get_context("fork").Pool(1) as p:
        assert p.map_async(_chunked_in_child, [(rob, q, ref)]).get(timeout=60) == [0.0]


@pytest.mark.parametrize("fade", [True, "range", False])
def test_large_batches_take_support_and_fade_from_the_compiled_pass(fade):
    """Above COMPILED_MAX poses, the networks' input, range excess, pair gap and fade weight come from one
    compiled pass over the rows (``fast_fk.prepare``, the per-pose kernel's code) instead of numpy's
    passes: the same numbers as the numpy functions, for wrapped and masked joints and each fade mode,
    and predict's rows equal the single-pose kernel's."""
    import copy
    import warnings

    from comp_models import tiny_model_file

    from hykin.hybrid import fast_fk
    from hykin.hybrid import support as sup_
    from hykin.hybrid.model import HybridModel

    m = copy.deepcopy(HybridModel.load(tiny_model_file()))
    m.fade = fade
    m.wrap_centre_ = np.where(np.arange(m.robot.dof) == 5, 0.3, np.asarray(m.wrap_centre_, dtype=np.float64))
    m.input_mask_ = np.arange(m.robot.dof) != 0  # joint 1 not an input (joint1="frame")
    k = fast_fk.kernel_of(m)
    assert k is not None
    q = m.nominal.random_joints(3001, 9, margin=-0.4)  # partly outside the trained range: the fade acts
    q[::5, 5] += 7.0  # a wrist more than a turn away: wrapped
    X, ex, gap, w = fast_fk.prepare(k, q)
    s, qn = m.support, m._netq(q)
    assert np.array_equal(X, m._net_in(qn)) and np.array_equal(ex, sup_.range_excess(s, qn))
    assert np.array_equal(gap, sup_.pair_gap(s, qn)) and (gap > 0).any() and (ex > 0).any()
    w_np = np.ones(len(q)) if fade is False else sup_.fade_weight(sup_.fade_distance(s, qn, fade, ex, gap),
                                                                  m.fade_offset_, m.fade_width_)
    assert np.abs(w - w_np).max() < 1e-15 and (fade is False or (w < 1).any())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        big = m.predict(q)
        small = np.concatenate([m.predict(q[i:i + 50]) for i in range(0, 200, 50)])  # compiled per pose
    assert np.abs(big[:200] - small).max() < 1e-12


def test_payload_and_temperature_messages_name_what_is_wrong():
    """Probe s43 BA: a scalar NaN payload was refused as "row 1", a (3, 2) payload as "got shape (6,)",
    and a temperature array of the wrong length with numpy's raw broadcast error."""
    from hykin.calibration.thermal import ThermalFit
    from hykin.hybrid.errors import HybridError
    from hykin.hybrid.thermal_fit import thermal_factor
    from hykin.kinematics.compliance import ComplianceError, payload_rows

    with pytest.raises(ComplianceError, match=r"^payload_kg: nan is not a finite mass"):
        payload_rows(3, float("nan"))
    with pytest.raises(ComplianceError, match=r"got shape \(3, 2\)"):
        payload_rows(3, np.ones((3, 2)))
    with pytest.raises(ComplianceError, match=r"^payload_kg: row 2: -1.0 is not"):
        payload_rows(3, [1.0, -1.0, 2.0])
    assert np.array_equal(payload_rows(3, np.ones((3, 1)))[0], np.ones(3))  # a column of them: fine
    th = ThermalFit(1.2e-5, 1e-7, 20.0, (18.0, 24.0), "")
    with pytest.raises(HybridError, match=r"temperature_c must be a scalar or one value per query \(100\), got 99"):
        thermal_factor(th, np.full(99, 21.0), 100)
    assert np.allclose(thermal_factor(th, 21.0, 4), 1 + 1.2e-5)
