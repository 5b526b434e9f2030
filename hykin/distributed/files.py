"""What the sweep and fleet files share: reading TOML, paths relative to the file, one-line errors.

* :class:`SpecError` — a mistake in a sweep/fleet file; the message names the file and the key.
* :func:`read_toml` — the file's table (SpecError on a missing file or bad TOML).
* :func:`rel_path` — a path key resolved against the file's folder (SpecError when missing).
* :func:`robot_spec` — a robot key: a file next to the spec, else a preset name (checked by loading it).
* :func:`inputs_sha256` — SHA-256 over input files' bytes and options (what `--resume` compares).
"""

from __future__ import annotations

from pathlib import Path

from ..io.toml_compat import tomllib

__all__ = ["SpecError", "check_keys", "inputs_sha256", "read_toml", "rel_path", "robot_spec"]


class SpecError(ValueError):
    """A sweep or fleet file is wrong; ``str(e)`` is one line naming the file and the key."""


def read_toml(path: str | Path) -> tuple[Path, dict]:
    """``(absolute path, table)`` of the TOML file ``path``."""
    p = Path(path)
    if not p.is_file():
        raise SpecError(f"{p}: no such file")
    try:
        return p.resolve(), tomllib.loads(p.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise SpecError(f"{p}: not valid TOML ({str(e).splitlines()[0]})") from None


def check_keys(path: Path, where: str, table: dict, known) -> None:
    """SpecError naming the first key of ``table`` not in ``known`` (``where``: e.g. ``[resources]``)."""
    for k in table:
        if k not in known:
            raise SpecError(f"{path}: {where}unknown key {k!r} (known: {', '.join(known)})")


def rel_path(path: Path, key: str, value, optional: bool = False) -> Path | None:
    """``value`` (a path relative to ``path``'s folder) as an absolute existing file."""
    if value is None:
        if optional:
            return None
        raise SpecError(f"{path}: missing key {key!r} (a file path relative to {path.parent})")
    if not isinstance(value, str):
        raise SpecError(f"{path}: {key} must be a path string, got {value!r}")
    p = (path.parent / value).resolve()
    if not p.is_file():
        raise SpecError(f"{path}: {key} = {value!r}: no such file {p}")
    return p


def robot_spec(path: Path, key: str, value) -> str:
    """A robot key: a file relative to ``path`` (as an absolute path) or a preset name; loaded once to
    check it (SpecError with the loader's reason)."""
    from ..io.robot_file import load_robot

    if not isinstance(value, str) or not value:
        raise SpecError(f"{path}: {key} must be a robot file or preset name, got {value!r}")
    p = (path.parent / value)
    spec = str(p.resolve()) if p.exists() else value
    try:
        load_robot(spec)
    except Exception as e:  # noqa: BLE001 - any loader failure is this key's mistake
        msg = str(e).strip().splitlines()
        raise SpecError(f"{path}: {key} = {value!r}: {msg[0] if msg else type(e).__name__}") from None
    return spec


def inputs_sha256(sources, options: dict) -> str:
    """SHA-256 over what a run's results depend on (the one implementation for sweep and fleet
    ``--resume``): each of ``sources`` (a file: its bytes' SHA-256; a preset name or None: its repr),
    then ``options`` as sorted JSON."""
    import hashlib
    import json

    from ..io.fingerprint import file_fingerprint

    h = hashlib.sha256()
    for src in sources:
        fp = file_fingerprint(src)
        h.update((fp["sha256"] if fp else repr(src)).encode() + b"\0")
    h.update(json.dumps(options, sort_keys=True, default=str).encode())
    return h.hexdigest()
