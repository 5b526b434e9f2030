"""Running batch work on a thread pool: a per-target compiled kernel over a batch in chunks, and the
thread budget those pools share with BLAS."""

from __future__ import annotations

import contextlib
import os
import sys
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["one_blas_thread", "run_chunked", "thread_pool", "worker_count"]

_BLAS = {"controller": None, "key": None, "lock": threading.RLock()}
_POOLS: dict = {}


@contextlib.contextmanager
def one_blas_thread():
    """Within the block BLAS (numpy's and scipy's OpenBLAS / MKL, through ``threadpoolctl``) runs one
    thread per call, then as before. For work that is already spread over our own threads: each of
    them calling a multi-threaded BLAS puts threads x BLAS threads on the cores, and OpenBLAS's waiting
    threads spin (measured: the networks' 100,000-row batch on 2 cores took 2.5x longer).

    One block at a time per process (it nests in its thread). A block entered while another thread is
    in one runs without changing the limit rather than wait: OpenBLAS's count is process-wide, and
    that other block has set it. Inside a ``threadpoolctl`` limit held by another thread (a sweep
    trial's) it changes nothing either: that limit stays in force."""
    b = _BLAS
    if not b["lock"].acquire(blocking=False):
        yield
        return
    try:
        from threadpoolctl import ThreadpoolController

        # the libraries found when it was made: made again in a forked child, or after more modules
        # (so maybe another BLAS) were imported; finding them takes ~6 ms, using it ~30 µs
        key = (os.getpid(), len(sys.modules))
        if b["controller"] is None or b["key"] != key:
            b["controller"], b["key"] = ThreadpoolController(), key
        with b["controller"].limit(limits=1, user_api="blas"):
            yield
    finally:
        b["lock"].release()


def worker_count() -> int:
    """Threads for batch work: numba's current thread count (``numba.set_num_threads``, which a sweep
    trial with ``cpus_per_trial = 1`` sets to 1), so that the compiled kernels, these chunks and the
    networks' batches all keep to it; without numba the CPUs this process may use."""
    try:
        import numba

        return max(1, int(numba.get_num_threads()))
    except ImportError:  # pragma: no cover - numba is a dependency; kept for a stripped install
        return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def thread_pool(n: int) -> ThreadPoolExecutor:
    """This process's pool of ``n`` worker threads, made once and kept (a forked child makes its own:
    the parent's worker threads do not exist there). Its idle workers wait on a lock and take no CPU,
    unlike numba's OpenMP workers, which spin after a ``prange`` loop: beside BLAS threads spinning after
    a product, that made a 5 µs loop take 4.8 ms (a 300-row hybrid FK: 8.4 ms instead of 1.2)."""
    key = (os.getpid(), n)
    p = _POOLS.get(key)
    if p is None:
        p = _POOLS[key] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="hykin-batch")
    return p


def run_chunked(kernel, args, N: int, min_chunk: int = 2000) -> None:
    """Run ``kernel(*args, start, stop)`` over ``range(N)`` in chunks on :func:`thread_pool` (the kernels
    release the GIL); a single call when ``N`` is small. At most :func:`worker_count` threads. Every
    batched kernel of hykin runs so, none with numba's ``prange``: its OpenMP workers spin after each
    loop (:func:`thread_pool`), and a ``parallel=True`` function takes seconds more to compile."""
    workers = min(worker_count(), max(1, N // min_chunk))
    if workers <= 1:
        kernel(*args, 0, N)
        return
    # a few pieces per worker, taken as each finishes: rows of unequal cost (iterations) stay balanced
    pieces = min(4 * workers, max(workers, N // min_chunk))
    edges = np.linspace(0, N, pieces + 1).astype(int)
    with one_blas_thread():
        list(thread_pool(workers).map(lambda i: kernel(*args, int(edges[i]), int(edges[i + 1])), range(pieces)))
