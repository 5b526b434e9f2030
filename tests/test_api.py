"""Every name the package re-exports resolves, and importing hykin does not import torch."""

import subprocess
import sys

import hykin


def test_all_exports_resolve():
    for name in hykin.__all__:
        assert getattr(hykin, name) is not None, name


def test_import_is_light():
    code = "import sys, hykin; hykin.fk; assert 'torch' not in sys.modules, 'torch imported eagerly'"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)
