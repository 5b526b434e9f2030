"""Shared timing helper for the benchmark scripts."""

from __future__ import annotations

import time


def best_of(fn, repeat: int = 3):
    """Best wall time of ``repeat`` calls of ``fn`` in seconds, and the last call's result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out
