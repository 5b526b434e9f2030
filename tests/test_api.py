"""Every name the package re-exports resolves, and importing hykin does not import torch."""

import subprocess
import sys

import hykin


def test_all_exports_resolve():
    for name in hykin.__all__:
        assert getattr(hykin, name) is not None, name


def test_public_functions_are_not_shadowed_by_submodules():
    """Public functions whose names were once module names stay functions after their modules load."""
    import importlib
    import types

    for name, mod in (("fk", "kinematics.fk"), ("ik", "kinematics.ik"), ("simulate", "sim.simulate"),
                      ("calibrate", "calibration.calibrate"), ("hybrid_ik", "hybrid.ik")):
        importlib.import_module(f"hykin.{mod}")
        assert callable(getattr(hykin, name)) and not isinstance(getattr(hykin, name), types.ModuleType), name
    from hykin.kinematics.fk import (
        jacobian,  # submodules stay importable by their full name
    )

    assert callable(jacobian)


def test_import_is_light():
    code = "import sys, hykin; hykin.fk; assert 'torch' not in sys.modules, 'torch imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
