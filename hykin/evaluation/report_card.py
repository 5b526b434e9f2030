"""The report's model card: which robot, which data (paths, sizes, SHA-256), which software versions,
seed, settings, training time and optimiser steps, and the model file's own integrity hash.

Every entry comes from the model's stored training metadata (``model.metadata``), the model file and
the test file; what a model does not record (files fitted before hykin recorded them) is said so.
"""

from __future__ import annotations

from pathlib import Path

from ..io.fingerprint import file_fingerprint

__all__ = ["card_rows", "data_rows", "training_steps"]


def _file_hash_of_model(path) -> str | None:
    """The ``content_sha256`` a hykin model file carries in its safetensors header (None if unreadable)."""
    try:
        from safetensors import safe_open

        with safe_open(str(path), framework="pt") as f:
            return (f.metadata() or {}).get("content_sha256")
    except Exception:  # noqa: BLE001 - informative only: a file that loaded is readable
        return None


def training_steps(meta: dict) -> dict[str, tuple[int | None, int, str]]:
    """Per network: ``(optimiser steps taken or None when not recorded, epochs, why it stopped)``."""
    out = {}
    for key, r in (meta.get("train_results") or {}).items():
        out[key] = (r.get("steps"), int(r.get("epochs", 0)), str(r.get("stopped", "?")))
    return out


def card_rows(model, model_path=None) -> list[list[str]]:
    """``[item, value]`` rows: robot, model file (size, SHA-256, integrity hash), settings, seed,
    versions, training time and steps."""
    meta = getattr(model, "metadata", None) or {}
    rob = getattr(model, "nominal", None) or model
    rows = [["robot", f"{rob.name} ({rob.convention.upper()}, {rob.dof} joints, nominal payload {rob.payload_kg:g} kg)"
             + (f"; from {rob.source}" if getattr(rob, "source", "") else "")]]
    if model_path is not None:
        fp = file_fingerprint(model_path)
        if fp is not None:
            rows.append(["model file", f"{fp['path']} ({fp['bytes']:,} bytes)"])
            rows.append(["model file SHA-256", fp["sha256"]])
        ch = _file_hash_of_model(model_path)
        if ch:
            rows.append(["integrity hash (content_sha256, checked at load)", ch])
    if not meta:
        rows.append(["model", "a robot file (classical model only): no training record"])
        return rows
    settings = []
    for k in ("arch", "recipe", "calibrate", "device"):
        v = getattr(model, k, None)
        if v is not None:
            settings.append(f"{k} {getattr(v, 'name', v)}")
    rows.append(["settings", ", ".join(settings)])
    rows.append(["seed", str(meta.get("seed", "?"))])
    t = meta.get("timings") or {}
    if "fit_s" in t:
        rows.append(["training time", f"{t['fit_s']:.1f} s in total, of which calibration {t.get('calibrate_s', float('nan')):.1f} s"])
    for key, (steps, epochs, stopped) in training_steps(meta).items():
        planned = (meta.get("train_results") or {}).get(key, {}).get("planned_steps")
        s = f"{steps:,} optimiser steps" if steps is not None else "steps not recorded"
        if planned:
            s += f" of {planned:,} planned"
        why = {"max_epochs": "budget complete", "max_seconds": "cut short by the time budget",
               "early_stopping": "early stopping"}.get(stopped, stopped)
        rows.append([f"{key} network", f"{s}, {epochs} epochs ({why})"])
    v = meta.get("versions") or {}
    if v:
        rows.append(["versions", ", ".join(f"{k} {val}" for k, val in v.items())])
    return rows


def data_rows(model, test=None, test_path=None) -> list[list]:
    """``[role, file, rows, bytes, SHA-256 (file) / data hash]`` for the training, validation and test data."""
    meta = getattr(model, "metadata", None) or {}
    rows = []
    for role, fkey, hkey, n in (("training", "train_file", "data_hash", meta.get("n_total")),
                                ("validation", "val_file", "val_hash", None)):
        if hkey not in meta or (meta.get(hkey) is None and meta.get(fkey) is None):
            continue
        fp = meta.get(fkey)
        if role == "training" and meta.get("val_hash") is None and meta.get("n_val"):
            held = int(meta.get("n_total") or 0) - int(meta.get("n_train") or 0)
            rest = held - int(meta.get("n_val"))
            role = (f"training (calibration on all rows; networks on {meta.get('n_train')}; {held} held out from "
                    f"them: {meta.get('n_val')} validate their training"
                    + (f", {rest} fit the prediction bands" if rest > 0 else "") + ")")
        if fp:
            rows.append([role, Path(fp["path"]).name, n, fp["bytes"], f"file {fp['sha256'][:16]}…"])
        else:  # a dataset built in memory, or a model fitted before hykin recorded its files
            rows.append([role, "(in memory, not a file)" if fkey in meta else "(not recorded)", n, None,
                         f"data {str(meta.get(hkey))[:16]}…"])
    if test is not None:
        fp = file_fingerprint(test_path if test_path is not None else getattr(test, "source", ""))
        name = Path(fp["path"]).name if fp else (getattr(test, "source", "") or "(in memory)")
        rows.append(["test", name, len(test), fp["bytes"] if fp else None,
                     f"file {fp['sha256'][:16]}…" if fp else "(not a file)"])
    return rows


DATA_HEADER = ["data", "file", "rows", "bytes", "SHA-256 (first 16 hex digits)"]
