"""Running a per-target compiled kernel over a batch in chunks on a thread pool."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["run_chunked", "worker_count"]


def worker_count() -> int:
    """Threads for batch work: numba's current thread count (``numba.set_num_threads``, which a sweep
    trial with ``cpus_per_trial = 1`` sets to 1), so that the compiled kernels, these chunks and the
    networks' batches all keep to it; without numba the CPUs this process may use."""
    try:
        import numba

        return max(1, int(numba.get_num_threads()))
    except ImportError:  # pragma: no cover - numba is a dependency; kept for a stripped install
        return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


def run_chunked(kernel, args, N: int, min_chunk: int = 2000) -> None:
    """Run ``kernel(*args, start, stop)`` over ``range(N)`` in chunks on a thread pool (the kernels
    release the GIL); a single call when ``N`` is small. Threads instead of numba ``prange`` keep the
    first-call compile time short; at most :func:`worker_count` of them."""
    workers = min(worker_count(), max(1, N // min_chunk))
    if workers <= 1:
        kernel(*args, 0, N)
        return
    edges = np.linspace(0, N, workers + 1).astype(int)
    with ThreadPoolExecutor(workers) as ex:
        list(ex.map(lambda i: kernel(*args, int(edges[i]), int(edges[i + 1])), range(workers)))
