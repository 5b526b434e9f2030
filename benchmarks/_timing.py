"""Shared timing helper for the benchmark scripts."""

from __future__ import annotations

import os
import time
from pathlib import Path


def best_of(fn, repeat: int = 3):
    """Best wall time of ``repeat`` calls of ``fn`` in seconds, and the last call's result."""
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def cpu_s(pid: int) -> float:
    """CPU seconds (user + system) a process has used (Linux /proc; NaN elsewhere): a figure that other
    jobs on a shared machine do not inflate, unlike latencies."""
    try:
        f = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")
