"""The package layering of ARCHITECTURE.md holds: every import inside hykin (function-level ones too)
goes to the package's own folder or to a lower layer; no module is longer than 600 lines."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "hykin"
# Lowest first; a package may import only packages of lower layers (and itself).
LAYERS = [
    {"geometry"},
    {"kinematics"},
    {"io"},
    {"calibration"},
    {"sim", "measure", "hybrid"},
    {"evaluation", "planning", "compensation"},
    {"realtime", "distributed"},
    {"cli"},
]
LAYER_OF = {pkg: i for i, layer in enumerate(LAYERS) for pkg in layer}


def _imports():
    """(importing file, line, importing package, imported package) for every relative import in hykin."""
    for path in sorted(ROOT.rglob("*.py")):
        parts = list(path.relative_to(ROOT.parent).with_suffix("").parts)
        here = parts[:-1]
        if len(here) < 2:  # hykin/__init__.py, hykin/__main__.py: the public facade
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and node.level:
                target = here[: len(here) - node.level + 1] + (node.module.split(".") if node.module else [])
                if len(target) >= 2 and target[1] != here[1]:
                    yield path, node.lineno, here[1], target[1]


def test_every_package_has_a_layer():
    packages = {p.parent.name for p in ROOT.glob("*/__init__.py")} - {"presets"}
    assert packages == set(LAYER_OF), packages ^ set(LAYER_OF)


def test_imports_go_down_the_layers_only():
    wrong = [f"{p.relative_to(ROOT.parent)}:{line}: {a} -> {b}" for p, line, a, b in _imports()
             if LAYER_OF[b] >= LAYER_OF[a]]
    assert not wrong, "\n".join(wrong)


def test_the_layer_check_sees_a_violation(tmp_path, monkeypatch):
    """The check is not vacuous: an upward import planted in a copy of a module is reported."""
    src = (ROOT / "geometry" / "lsq.py").read_text(encoding="utf-8")
    fake = tmp_path / "hykin" / "geometry"
    fake.mkdir(parents=True)
    (fake / "lsq.py").write_text(src + "\n\ndef _f():\n    from ..hybrid.model import HybridModel\n", encoding="utf-8")
    monkeypatch.setattr(__import__(__name__), "ROOT", tmp_path / "hykin")
    found = [(a, b) for _, _, a, b in _imports()]
    assert ("geometry", "hybrid") in found


@pytest.mark.parametrize("path", sorted(ROOT.rglob("*.py")), ids=lambda p: str(p.relative_to(ROOT)))
def test_modules_stay_small(path):
    assert len(path.read_text(encoding="utf-8").splitlines()) <= 600
