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


import pytest  # noqa: E402


@pytest.fixture(scope="session")
def exact_rx160_model():
    """A hybrid model trained on exact rx160 data in the robot frame (no calibration, no fade): it equals
    the nominal robot (networks ~0). Shared by the registration tests; they must not change it."""
    import numpy as np

    from hykin.geometry import se3
    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset import Dataset
    from hykin.io.robot_file import load_robot
    from hykin.kinematics.fk import fk

    rx160 = load_robot("rx160")
    q = rx160.random_joints(200, np.random.default_rng(5))
    T = fk(rx160, q)
    ds = Dataset(q=q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source="exact")
    return HybridModel(rx160, calibrate=False, recipe_kw={"max_epochs": 1}, fade=False).fit(ds, progress=False)
