"""Test configuration: property tests are reproducible (fixed example sequence, no example database),
so a CI run fails or passes the same way every time. Under pytest-xdist (``-n auto`` in pyproject's
addopts) each worker computes with one thread (torch, BLAS, numba), so the workers share the cores
instead of oversubscribing them."""

import os

if os.environ.get("PYTEST_XDIST_WORKER"):  # set by xdist before this file loads, before torch/numba import
    for _var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ.setdefault(_var, "1")

from hypothesis import settings  # noqa: E402

settings.register_profile("hykin", derandomize=True, database=None, deadline=None)
settings.load_profile("hykin")
