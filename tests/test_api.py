"""Every name the package re-exports resolves, and importing hykin does not import torch."""

import subprocess
import sys

import hykin


def test_all_exports_resolve():
    for name in hykin.__all__:
        assert getattr(hykin, name) is not None, name


def test_functions_named_like_their_modules_stay_functions():
    """Importing a submodule must not replace the public function of the same name."""
    import importlib
    import types

    for name in ("fk", "ik", "simulate", "calibrate", "hybrid_ik"):
        importlib.import_module(f"hykin.{name}")
        assert callable(getattr(hykin, name)) and not isinstance(getattr(hykin, name), types.ModuleType), name
    from hykin.fk import jacobian  # submodules stay importable by their full name

    assert callable(jacobian)


def test_import_is_light():
    code = "import sys, hykin; hykin.fk; assert 'torch' not in sys.modules, 'torch imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
