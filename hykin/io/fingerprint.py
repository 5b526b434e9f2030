"""Fingerprint of a file for provenance records: its path, size and SHA-256 (model cards, training
metadata). A source that is not an existing file (a preset name, free text) has no fingerprint."""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["file_fingerprint"]


def file_fingerprint(source) -> dict | None:
    """``{"path", "bytes", "sha256"}`` of the file ``source`` (path as given, resolved to absolute),
    or None when ``source`` is empty or not an existing regular file."""
    if not source:
        return None
    p = Path(str(source))
    try:
        if not p.is_file():
            return None
        h = hashlib.sha256()
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
        return {"path": str(p.resolve()), "bytes": p.stat().st_size, "sha256": h.hexdigest()}
    except OSError:
        return None
