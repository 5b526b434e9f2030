"""The TOML reader of this Python: :mod:`tomllib` from 3.11, its backport ``tomli`` on 3.10 (a
dependency there). Every TOML file hykin reads (robot, map, nest, sweep and fleet files, ``plan``'s
angle unit) goes through ``from hykin.io.toml_compat import tomllib``."""

from __future__ import annotations

import sys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["tomllib"]
