"""The hykin model file: ONE safetensors file, no pickle (DESIGN.md §3).

Layout:

* tensors: network state dicts, keys prefixed ``pos.`` / ``rot.`` (weights and buffers, including
  normalisation ranges and output scaling), plus any extra arrays under ``extra.``;
* metadata (str -> str): ``format`` = ``"hykin-model"``, ``format_version``, ``hykin`` = one
  JSON document with the robots (:func:`robot_to_dict`), configuration and training metadata, and
  ``content_sha256`` = :func:`content_hash` over every tensor (name, dtype, shape, bytes) and the
  three entries above.

Integrity: the hash is written at save and checked at load; a file whose content does not match it
(a flipped bit in the weights, an edited number in the metadata, a truncated copy) is refused.
It detects corruption and edits, it does not authenticate: anyone can recompute the hash after an
edit. Files written by hykin 0.1.0 carry no hash; they load with a one-line note
(:class:`UnverifiedModelWarning`).

:func:`write_model_file` / :func:`read_model_file` do the I/O and validation; the model object
itself lives in :mod:`hykin.hybrid`.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..kinematics.robot import Robot
from .robot_codec import (
    REQUIRED_FIELDS,
    ROBOT_ARRAYS,
    RobotDictError,
    robot_from_json,
    robot_to_json,
)

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "ModelFileError",
    "UnverifiedModelWarning",
    "content_hash",
    "looks_like_model_file",
    "model_metrics",
    "read_model_file",
    "robot_from_json_dict",
    "robot_to_dict",
    "stored_content_hash",
    "write_model_file",
]

FORMAT = "hykin-model"
FORMAT_VERSION = 1


class ModelFileError(ValueError):
    """A model file is not a hykin model, is corrupt, or has an unsupported format version."""


class UnverifiedModelWarning(UserWarning):
    """A model file without an integrity hash (written by hykin 0.1.0) was loaded unchecked."""


def content_hash(tensors: dict, md: dict) -> str:
    """sha256 (hex) over the tensors (sorted by name: name, dtype, shape, raw bytes) and the metadata
    entries ``format``, ``format_version`` and ``hykin`` (the JSON text as stored)."""
    import hashlib

    import torch

    h = hashlib.sha256()
    for k in ("format", "format_version", "hykin"):
        v = str(md.get(k, "")).encode("utf-8")
        h.update(k.encode() + b"\0" + len(v).to_bytes(8, "little") + v)
    for name in sorted(tensors):
        t = tensors[name].detach().contiguous().cpu()
        head = f"{name}\0{t.dtype}\0{tuple(t.shape)}\0".encode()
        h.update(len(head).to_bytes(8, "little") + head)
        h.update(t.reshape(-1).view(torch.uint8).numpy().tobytes() if t.numel() else b"")
    return h.hexdigest()


def robot_to_dict(robot: Robot) -> dict:
    """Every field of a :class:`Robot` (any convention, URDF included) as JSON-safe data, SI units,
    as model files store it (``inf`` as the string ``"inf"``; :func:`hykin.io.robot_codec.robot_to_json`).
    Exact: floats round-trip through JSON (repr) without loss."""
    return robot_to_json(robot, inf_as="string")


def robot_from_json_dict(d: dict, where: str = "model file") -> Robot:
    """Inverse of :func:`robot_to_dict`; every field must be present (:class:`ModelFileError` otherwise)."""
    try:
        return robot_from_json(d, required=REQUIRED_FIELDS + ROBOT_ARRAYS + ("joint_type", "payload_kg"))
    except ValueError as e:  # RobotDictError (missing field, bad type) or RobotFileError
        why = str(e) if isinstance(e, RobotDictError) else f"{type(e).__name__}: {e}"
        raise ModelFileError(f"{where}: robot entry is malformed ({why})") from None


def write_model_file(path: str | Path, tensors: dict, meta: dict) -> None:
    """Write ``tensors`` (name -> torch tensor) and JSON ``meta`` to one safetensors file."""
    from safetensors.torch import save_file

    t = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    md = {"format": FORMAT, "format_version": str(FORMAT_VERSION), "hykin": json.dumps(meta, allow_nan=False)}
    md["content_sha256"] = content_hash(t, md)
    save_file(t, str(path), metadata=md)
    import os

    mask = os.umask(0)
    os.umask(mask)
    os.chmod(path, 0o666 & ~mask)  # safetensors writes 0600; a model file is shared like any data file (0644)


def looks_like_model_file(path: str | Path) -> bool:
    """Whether ``path`` starts as a safetensors file does (an 8-byte little-endian header length, then the
    header's ``{``): a model file, whatever its name. Reads 9 bytes; False for anything unreadable."""
    try:
        with open(path, "rb") as f:
            head = f.read(9)
    except OSError:
        return False
    return len(head) == 9 and 0 < int.from_bytes(head[:8], "little") < 100_000_000 and head[8:9] == b"{"


def stored_content_hash(path: str | Path) -> str | None:
    """The ``content_sha256`` a model file carries in its header (None for files written before model files carried one);
    reads the header only. :func:`read_model_file` checks it against the content."""
    from safetensors import SafetensorError, safe_open

    try:
        with safe_open(str(path), framework="pt") as f:
            return (f.metadata() or {}).get("content_sha256")
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        raise ModelFileError(f"{path}: not a hykin model file, or a truncated or corrupt copy of one (not readable as "
                             f"safetensors: {e})") from None


def read_model_file(path: str | Path) -> tuple[dict, dict]:
    """Read a model file -> ``(tensors, meta)``; :class:`ModelFileError` with the reason otherwise."""
    from safetensors import SafetensorError, safe_open

    path = Path(path)
    if not path.is_file():
        raise ModelFileError(f"{path}: no such model file")
    try:
        with safe_open(str(path), framework="pt") as f:
            md = f.metadata() or {}
            tensors = {k: f.get_tensor(k) for k in f.keys()}
    except (SafetensorError, OSError, ValueError, RuntimeError) as e:
        raise ModelFileError(f"{path}: not a hykin model file, or a truncated or corrupt copy of one (not readable as "
                             f"safetensors: {e})") from None
    if md.get("format") != FORMAT:
        raise ModelFileError(f"{path}: not a hykin model file (metadata 'format' is {md.get('format')!r})")
    try:
        ver = int(md.get("format_version", ""))
    except ValueError:
        raise ModelFileError(f"{path}: bad format_version {md.get('format_version')!r}") from None
    if ver > FORMAT_VERSION or ver < 1:
        raise ModelFileError(
            f"{path}: model format version {ver} is not supported by this hykin (supports 1..{FORMAT_VERSION})"
        )
    stored = md.get("content_sha256")
    if stored is None:
        import warnings

        warnings.warn(f"{path}: model file carries no integrity hash (written by hykin 0.1.0); loaded unchecked",
                      UnverifiedModelWarning, stacklevel=2)
    elif content_hash(tensors, md) != stored:
        raise ModelFileError(f"{path}: model file is corrupt or was edited (content hash mismatch: weights or "
                             "metadata differ from what was saved); refit or restore the file")
    try:
        meta = json.loads(md["hykin"])
    except (KeyError, json.JSONDecodeError) as e:
        raise ModelFileError(f"{path}: corrupt hykin metadata ({e})") from None
    return tensors, meta


def model_metrics(model) -> dict:
    """The model's own held-out accuracy from its training metadata (``metrics``: ``val``, else
    ``held_out``, else ``train``; ``{}`` for a model without them). Here, below every package that reads it
    (hybrid IK, compensation, registration)."""
    met = (getattr(model, "metadata", None) or {}).get("metrics", {}) or {}
    return met.get("val") or met.get("held_out") or met.get("train") or {}
