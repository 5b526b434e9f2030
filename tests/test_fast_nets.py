"""Float64 numpy inference of the residual networks (hykin.hybrid.fast_nets) against torch.

Reference: the same torch network evaluated in float64 (``net.double()``), with random weights and
random BatchNorm running statistics (eval mode); the Jacobian against central differences."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hykin.hybrid.fast_nets import fast_net, net_float64
from hykin.hybrid.nets import make_net


def _randomised(name: str, n_in: int, seed: int):
    torch.manual_seed(seed)
    net = make_net(name, n_in, 3)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for mod in net.modules():
            if isinstance(mod, torch.nn.BatchNorm1d):  # non-trivial running statistics and affine terms
                mod.running_mean.copy_(torch.randn(mod.num_features, generator=g) * 0.3)
                mod.running_var.copy_(torch.rand(mod.num_features, generator=g) + 0.5)
                mod.weight.copy_(torch.rand(mod.num_features, generator=g) + 0.5)
                mod.bias.copy_(torch.randn(mod.num_features, generator=g) * 0.1)
    net.set_input_range(-np.pi * np.ones(n_in), np.pi * np.ones(n_in))
    net.set_output_scale(np.array([1e-3, -2e-3, 5e-4]), 2e-3)  # a mm-sized residual, in m
    return net.eval()


@pytest.mark.parametrize("name", ["default", "default-wide", "B1", "B2", "B3", "B4", "Rd"])
def test_fast_net_equals_torch_float64(name):
    net = _randomised(name, 6, 1)
    fn = fast_net(net)
    q = np.random.default_rng(0).uniform(-4, 4, (257, 6))
    with torch.inference_mode():
        ref = net_float64(net)(torch.from_numpy(q)).numpy()
        ref32 = net(torch.from_numpy(q)).double().numpy()
    out = fn(q)
    assert out.dtype == np.float64 and out.shape == (257, 3)
    assert np.abs(out - ref).max() * 1e3 < 1e-9  # mm
    # the float32 torch path differs only by float32 rounding of a mm-sized residual: a few dozen
    # float32 ulps of the output after 3-4 layers, the summation order depending on the CPU's kernels
    # (an AVX-512 host gave 1.1e-6 of the output on B2)
    assert np.abs(out - ref32).max() < 1e-5 * np.abs(ref).max() + 1e-12
    # one row at a time is the same function
    assert np.abs(fn(q[:1]) - out[:1]).max() < 1e-15


@pytest.mark.parametrize("name", ["default", "B1", "B2", "Rd"])
def test_fast_net_chunks_and_threads_are_the_same_function(name, monkeypatch):
    """Large batches run in chunks with reused scratch buffers over a thread pool: small chunks and
    three workers here (rows split unevenly, ResNet shortcuts reading a block's input while its output
    is written) give the torch float64 numbers, and the one-chunk single-thread evaluation's."""
    from hykin.hybrid import fast_nets

    net = _randomised(name, 6, 5)
    fn = fast_net(net)
    q = np.random.default_rng(4).uniform(-4, 4, (101, 6))
    with torch.inference_mode():
        ref = net_float64(net)(torch.from_numpy(q)).numpy()
    whole = fn(q)  # 101 rows < CHUNK_ROWS: one chunk, one thread
    monkeypatch.setattr(fast_nets, "CHUNK_ROWS", 7)
    monkeypatch.setattr(fast_nets, "PARALLEL_ROWS", 20)
    monkeypatch.setattr(fast_nets, "threads", lambda: 3)
    out = fn(q)
    assert np.abs(out - ref).max() * 1e3 < 1e-9  # mm
    assert np.abs(out - whole).max() <= 1e-15 * np.abs(whole).max()
    assert fn(q[:0]).shape == (0, 3)


@pytest.mark.parametrize("name", ["default", "B2", "B3"])
def test_fast_net_jacobian_matches_differences(name):
    net = _randomised(name, 6, 2)
    fn = fast_net(net)
    q = np.random.default_rng(1).uniform(-3, 3, (5, 6))
    out, J = fn.jacobian(q)
    assert np.abs(out - fn(q)).max() < 1e-15
    h = 1e-6
    Jfd = np.stack([(fn(q + h * e) - fn(q - h * e)) / (2 * h) for e in np.eye(6)], axis=2)
    assert np.abs(J - Jfd).max() < 1e-7 * max(1.0, np.abs(J).max())


@pytest.mark.slow
@pytest.mark.parametrize("name", ["D1", "D4", "D4w", "D4W", "Rw"])
def test_fast_net_paper_sizes(name):
    net = _randomised(name, 6, 3)
    q = np.random.default_rng(2).uniform(-3, 3, (16, 6))
    with torch.inference_mode():
        ref = net_float64(net)(torch.from_numpy(q)).numpy()
    assert np.abs(fast_net(net)(q) - ref).max() * 1e3 < 1e-9


@pytest.mark.parametrize("name", ["default", "B2", "B3"])
def test_compiled_network_equals_fast_net(name):
    from hykin.hybrid import fast_fk

    if not fast_fk.HAVE_NUMBA:
        pytest.skip("numba not installed")
    net = _randomised(name, 6, 4)
    fn = fast_net(net)
    packed = fast_fk.pack_net(fn)
    q = np.random.default_rng(3).uniform(-3, 3, (20, 6))
    buf = np.empty((6, int(packed[5][2])))
    out = np.empty(3)
    ref = fn(q)
    for k in range(len(q)):
        fast_fk.net_one(*packed, q[k], 6, buf, out)
        assert np.abs(out - ref[k]).max() * 1e3 < 1e-9


def test_compiled_hybrid_fk_equals_numpy_path():
    """HybridModel.predict: the compiled path (small batches) against the numpy path (the same model with
    the compiled kernel switched off), with and without registration frames."""
    import copy
    import warnings

    from comp_models import tiny_model_file

    from hykin.geometry import se3
    from hykin.hybrid import fast_fk
    from hykin.hybrid.model import HybridModel

    if not fast_fk.HAVE_NUMBA:
        pytest.skip("numba not installed")
    m = HybridModel.load(tiny_model_file())
    q = m.nominal.random_joints(40, 9, margin=-0.3)  # partly outside the trained range: the fade acts
    m2 = copy.deepcopy(m)
    m2.frame_pre_ = se3.trans(0.1, -0.2, 0.3) @ se3.rotz(0.3)
    m2.frame_post_ = se3.trans(0, 0, 0.05)
    for mm in (m, m2):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fast = mm.predict(q)  # 40 < COMPILED_MAX: compiled
            ref = mm.predict(np.repeat(q, 2, axis=0))[::2]  # 80 rows: the numpy path
        assert np.abs(fast - ref).max() < 1e-12  # m and dimensionless: 1e-9 mm
        tt = mm.predict_torch(torch.from_numpy(q)).numpy()  # the torch path: float64 copies of the nets
        assert np.abs(tt - fast).max() < 1e-12
        assert fast_fk.kernel_of(mm) is not None
    k = fast_fk.kernel_of(m)
    T, ex, gap, outside = fast_fk.predict_fast(k, q)
    assert outside == bool(ex.any() or gap.max() > 0)
    assert np.allclose(ex, m.range_excess(q), atol=1e-15) and np.allclose(gap, m.pair_gap(q), atol=1e-15)
    qb = m.nominal.random_joints(1100, 5, margin=-0.3)  # over _PARALLEL_MIN: threads over chunks of the kernel
    Tb, exb, gapb, outb = fast_fk.predict_fast(k, qb)
    parts = [fast_fk.predict_fast(k, qb[i:i + 100]) for i in range(0, 1100, 100)]  # one thread each
    assert np.array_equal(Tb, np.concatenate([p[0] for p in parts]))
    assert np.array_equal(gapb, np.concatenate([p[2] for p in parts]))
    assert outb == any(p[3] for p in parts) == bool(exb.any() or gapb.max() > 0)


def test_compiled_kernel_cache_follows_the_model():
    """The compiled kernel cached on a model is rebuilt when a network's weights change in place, a
    frame is replaced or the fade changes; reference: the numpy path of the changed model."""
    import warnings

    from comp_models import tiny_model_file

    from hykin.geometry import se3
    from hykin.hybrid import fast_fk
    from hykin.hybrid.model import HybridModel

    if not fast_fk.HAVE_NUMBA:
        pytest.skip("numba not installed")
    m = HybridModel.load(tiny_model_file())
    q = m.nominal.random_joints(300, 1, margin=0.1)[:8]  # training joints (comp_models): fade weight 1
    assert np.all(m.fade_weight(q) == 1.0)

    def agree():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fast, ref = m.predict(q), m.predict(np.repeat(q, 10, axis=0))[::10]  # compiled / numpy path
        assert np.abs(fast - ref).max() < 1e-12
        return fast

    T0 = agree()
    k0 = fast_fk.kernel_of(m)
    assert fast_fk.kernel_of(m) is k0  # unchanged model: the cached kernel
    with torch.no_grad():  # a buffer and a weight changed in place (the tiny model's output scale is ~0)
        m.net_pos_.out_scale.fill_(1e-3)
        next(m.net_pos_.parameters()).mul_(1.5)
    T1 = agree()
    assert np.abs(T1 - T0)[:, :3, 3].max() > 1e-6
    m.frame_pre_ = se3.trans(0.01, 0.0, 0.0) @ m.frame_pre_  # a frame replaced
    T2 = agree()
    assert np.allclose(T2[:, 0, 3] - T1[:, 0, 3], 0.01, atol=1e-12)
    m.fade = "range" if m.fade != "range" else "pairs"
    agree()
    assert fast_fk.kernel_of(m) is not k0


def _max_diff_in_child(args):
    fn, q, ref = args
    return float(np.abs(fn(q) - ref).max())


def test_fast_net_thread_pool_survives_fork(monkeypatch):
    """A process forked after a large batch ran on the thread pool evaluates large batches too (the
    parent's pool threads do not exist in the child: it makes its own) with the same numbers."""
    import multiprocessing as mp
    import sys

    from hykin.hybrid import fast_nets

    if sys.platform != "linux":
        pytest.skip("fork start method")
    monkeypatch.setattr(fast_nets, "PARALLEL_ROWS", 500)
    monkeypatch.setattr(fast_nets, "threads", lambda: 2)
    fn = fast_net(_randomised("default", 6, 6))
    q = np.random.default_rng(6).uniform(-3, 3, (2000, 6))
    ref = fn(q)  # the parent's pool exists now
    with mp.get_context("fork").Pool(1) as pool:
        assert pool.map_async(_max_diff_in_child, [(fn, q, ref)]).get(timeout=60) == [0.0]


def test_pooled_batches_run_blas_one_thread_each_and_restore_it():
    """The networks' thread pool and the chunked kernels run under ``one_blas_thread``: inside, every
    loaded BLAS has one thread (else workers x BLAS threads oversubscribe the cores), entered from the
    main thread or another, nested or not; blocks from several threads at once neither fail nor wait,
    and the counts afterwards are those before."""
    import threading

    from threadpoolctl import threadpool_info

    from hykin.kinematics.chunks import one_blas_thread

    def blas():
        return [i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"]

    before = blas()
    assert before, "numpy's BLAS is not visible to threadpoolctl"
    with one_blas_thread():
        assert set(blas()) == {1}
        with one_blas_thread():
            assert set(blas()) == {1}
        assert set(blas()) == {1}
    assert blas() == before
    seen = []

    def inside():
        with one_blas_thread():
            seen.append(blas())

    t = threading.Thread(target=inside)
    t.start()
    t.join()
    assert seen == [[1] * len(before)] and blas() == before
    go = threading.Barrier(4)

    def together():
        go.wait()
        for _ in range(20):
            with one_blas_thread():
                with one_blas_thread():
                    pass

    ts = [threading.Thread(target=together) for _ in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    assert blas() == before


def test_one_cpu_trial_limits_blas_too():
    """``trial_threads(1)`` holds BLAS to one thread inside the trial (a one-CPU trial beside another
    must not spread its calibration over both cores) and gives the previous count back."""
    from threadpoolctl import threadpool_info, threadpool_limits

    from hykin.distributed.trials import trial_threads

    def blas():
        return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    with threadpool_limits(limits=2, user_api="blas"):
        with trial_threads(1):
            assert blas() == {1}
        assert blas() == {2}


@pytest.mark.parametrize("act", ["silu", "sigmoid"])
def test_compiled_activations_match_numpy_to_rounding(act):
    """The vectorised exp of :mod:`hykin.hybrid.fast_act` against numpy's: within 1e-15 relative over
    the whole float range the networks meet (and at the reduction's boundaries, t ln2 ± ln2/2), finite
    and of the right limit where numpy's exp overflows."""
    from hykin.hybrid import fast_act

    if not fast_act.HAVE_NUMBA:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(8)
    ln2 = np.log(2.0)
    x = np.concatenate([rng.normal(0, 3, 5000), rng.uniform(-700, 700, 2000), np.arange(-60, 61) * ln2 / 2,
                        [0.0, -0.0, 1e-300, -1e-300, 5e-324, 1e-8, -1e-8, 36.7, -36.7, 700.0, -700.0]])
    ref = x / (1.0 + np.exp(-x)) if act == "silu" else 1.0 / (1.0 + np.exp(-x))
    h = x.reshape(-1, 1).copy()
    assert fast_act.act_rows(act, h, {})
    rel = np.abs(h[:, 0] - ref) / np.maximum(np.abs(ref), 1e-300)
    assert rel.max() < 1e-15
    big = np.array([-710.0, -1e5, -800.0, 710.0, 1e5])  # numpy's exp(-x) overflows on the first three
    hb = big.reshape(1, -1).copy()
    fast_act.act_rows(act, hb, {})
    want = [0.0, 0.0, 0.0, 710.0, 1e5] if act == "silu" else [0.0, 0.0, 0.0, 1.0, 1.0]
    assert np.all(np.isfinite(hb)) and np.allclose(hb[0], want, rtol=1e-15, atol=1e-290)
    assert not fast_act.act_rows("tanh", h, {})  # others stay with numpy


def test_packed_kernel_arguments_are_the_tuple():
    """The three flat arrays the Python-called kernels take (``pack_args``; one array instead of a
    43-item tuple makes numba's dispatch ~5 µs shorter) unpack to exactly the kernel tuple, item by
    item, with its types; a tuple of another layout is refused."""
    from hykin.hybrid import fast_fk

    if not fast_fk.HAVE_NUMBA:
        pytest.skip("numba not installed")
    from comp_models import tiny_model_file

    from hykin.hybrid.model import HybridModel

    k = fast_fk.kernel_of(HybridModel.load(tiny_model_file()))
    back = fast_fk.unpack(*k.args)
    assert len(back) == len(k.P) == len(fast_fk.P_KINDS)
    for i, (a, b, kind) in enumerate(zip(back, k.P, fast_fk.P_KINDS)):
        a, b = np.asarray(a), np.asarray(b)
        assert a.shape == b.shape and np.array_equal(a, b), i
        assert a.dtype.kind == {"f": "f", "i": "i", "b": "b"}[kind[0]], i
    with pytest.raises(ValueError, match="43"):
        fast_fk.pack_args(k.P[:-1])
