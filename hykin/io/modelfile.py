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
import math
from pathlib import Path

import numpy as np

from ..kinematics.robot import Robot

__all__ = [
    "FORMAT",
    "FORMAT_VERSION",
    "ModelFileError",
    "UnverifiedModelWarning",
    "content_hash",
    "read_model_file",
    "robot_from_json_dict",
    "robot_to_dict",
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


_ARRAYS = (
    "a_m", "alpha_rad", "d_m", "theta_rad", "beta_rad", "lower", "upper", "origin_xyz_m", "origin_rpy_rad",
    "axis", "mass_kg", "com_m", "stiffness_nm_per_rad", "base", "tool", "gravity_base",
)


def _enc(x):
    """JSON-safe nested lists; inf stays representable as the string "inf"."""
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 0:
        v = float(a)
        return v if math.isfinite(v) else ("inf" if v > 0 else "-inf")
    return [_enc(v) for v in a]


def _dec(x):
    if isinstance(x, list):
        return [_dec(v) for v in x]
    if isinstance(x, str):
        return float(x)
    return x


def robot_to_dict(robot: Robot) -> dict:
    """Every field of a :class:`Robot` (any convention, URDF included) as JSON-safe data, SI units.
    Exact: floats round-trip through JSON (repr) without loss."""
    d = {"name": robot.name, "convention": robot.convention, "joint_type": list(robot.joint_type),
         "payload_kg": float(robot.payload_kg), "source": robot.source}
    for k in _ARRAYS:
        d[k] = _enc(getattr(robot, k))
    return d


def robot_from_json_dict(d: dict, where: str = "model file") -> Robot:
    """Inverse of :func:`robot_to_dict`."""
    try:
        kw = {k: np.array(_dec(d[k]), dtype=np.float64) for k in _ARRAYS}
        return Robot(name=d["name"], convention=d["convention"], joint_type=tuple(d["joint_type"]),
                     payload_kg=float(d["payload_kg"]), source=d.get("source", ""), **kw)
    except (KeyError, TypeError, ValueError) as e:
        raise ModelFileError(f"{where}: robot entry is malformed ({type(e).__name__}: {e})") from None


def write_model_file(path: str | Path, tensors: dict, meta: dict) -> None:
    """Write ``tensors`` (name -> torch tensor) and JSON ``meta`` to one safetensors file."""
    from safetensors.torch import save_file

    t = {k: v.detach().contiguous().cpu() for k, v in tensors.items()}
    md = {"format": FORMAT, "format_version": str(FORMAT_VERSION), "hykin": json.dumps(meta, allow_nan=False)}
    md["content_sha256"] = content_hash(t, md)
    save_file(t, str(path), metadata=md)


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
        raise ModelFileError(f"{path}: not a hykin model file (not readable as safetensors: {e})") from None
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
