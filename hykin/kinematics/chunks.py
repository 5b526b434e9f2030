"""Running a per-target compiled kernel over a batch in chunks on a thread pool."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["run_chunked"]


def run_chunked(kernel, args, N: int, min_chunk: int = 2000) -> None:
    """Run ``kernel(*args, start, stop)`` over ``range(N)`` in chunks on a thread pool (the kernels
    release the GIL); a single call when ``N`` is small. Threads instead of numba ``prange`` keep the
    first-call compile time short."""
    workers = min(os.cpu_count() or 1, max(1, N // min_chunk))
    if workers <= 1:
        kernel(*args, 0, N)
        return
    edges = np.linspace(0, N, workers + 1).astype(int)
    with ThreadPoolExecutor(workers) as ex:
        list(ex.map(lambda i: kernel(*args, int(edges[i]), int(edges[i + 1])), range(workers)))
