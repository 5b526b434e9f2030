"""The hybrid model file: ONE safetensors file, tensors plus a JSON header (:mod:`hykin.io.modelfile`).

Tensors: ``pos.*`` / ``rot.*`` network state, ``support.points`` ``(M, n)``, ``support.pair_gap``
``(P, G, G)``, ``support.pair_index`` ``(P, 2)``. Header: calibrated and nominal robot, settings
(``config``), support range and spacing, registration frames, station and tool frames (``stations``:
:class:`hykin.calibration.stations.StationFrames`, several stations / tools), input representation, uncertainty
bands, thermal coefficient, payload range, training metadata. Files of older versions (keys absent)
load with the behaviour of those versions.
"""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import numpy as np
import torch

from ..calibration.stations import StationFrames
from ..calibration.thermal import ThermalFit
from ..io.modelfile import robot_from_json_dict, robot_to_dict, write_model_file
from ..io.payload import PayloadRange
from ..io.robot_toml import robot_to_toml_string
from .nets import make_net
from .support import GAP_FACTOR
from .train import Recipe

__all__ = ["data_hash", "json_safe", "model_config", "restore_fitted", "save_model", "settings_from_config", "versions"]


def versions() -> dict:
    """Versions of hykin and its numerical stack (training metadata)."""
    import platform

    import scipy

    try:
        from importlib.metadata import version

        hv = version("hykin")
    except Exception:  # noqa: BLE001 - not installed as a distribution
        hv = "dev"
    return {"hykin": hv, "torch": torch.__version__, "numpy": np.__version__, "scipy": scipy.__version__,
            "python": platform.python_version()}


def data_hash(ds) -> str:
    """SHA-256 of a Dataset (:func:`hykin.io.dataset.dataset_hash`; duck-typed datasets: of their
    joints, positions and quaternions)."""
    try:
        from ..io.dataset import dataset_hash

        return dataset_hash(ds)
    except Exception:  # noqa: BLE001 - duck-typed dataset
        h = hashlib.sha256()
        for a in (ds.q, ds.xyz_m) + ((ds.quat_wxyz,) if ds.quat_wxyz is not None else ()):
            h.update(np.ascontiguousarray(a, dtype="<f8").tobytes())
        return h.hexdigest()


def json_safe(x):
    """Nested data -> JSON-safe (arrays to lists, non-finite floats to "nan"/"inf"/"-inf", others to str)."""
    if isinstance(x, dict):
        return {str(k): json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    if hasattr(x, "tolist"):
        return json_safe(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return "nan" if x != x else ("inf" if x > 0 else "-inf")
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return str(x)


def _fitted_or_setting(model, name: str):
    """The fitted value ``name_`` of a fitted model (what its predictions use), else the setting."""
    v = getattr(model, name + "_", None)
    return getattr(model, name) if v is None else v


def model_config(model) -> dict:
    """The settings of ``model`` as saved in the file header (``config``), resolved (recipe with its
    overrides, validation fraction, input joints)."""
    return {"arch": model.arch, "recipe": model.resolved_recipe().to_dict(), "calibrate": bool(model.calibrate),
            "calibrate_kw": json_safe(dict(model.calibrate_kw or {})), "normalise": model.normalise,
            "fade": model.fade, "fade_width": float(_fitted_or_setting(model, "fade_width")), "device": model.device, "seed": int(model.seed),
            "max_seconds": model.max_seconds, "val_fraction": model.resolved_val_fraction(),
            "periodic": model.periodic, "joint1": model.joint1, "input_joints": list(model.resolved_input_joints()),
            "thermal": model.thermal, "payload_input": model.payload_input, "fade_offset": float(_fitted_or_setting(model, "fade_offset")),
            "fade_cv": int(model.fade_cv), "uncertainty": bool(model.uncertainty)}


def settings_from_config(cfg: dict, device: str) -> dict:
    """Constructor keyword arguments of a model from a file's ``config`` (defaults of older files)."""
    return {"arch": cfg["arch"], "recipe": Recipe(**cfg["recipe"]), "calibrate": cfg["calibrate"],
            "calibrate_kw": cfg.get("calibrate_kw"), "normalise": cfg["normalise"], "fade": cfg["fade"],
            "fade_width": cfg["fade_width"], "device": device, "seed": cfg["seed"], "max_seconds": cfg.get("max_seconds"),
            "val_fraction": cfg.get("val_fraction"), "periodic": cfg.get("periodic", "none"),
            "joint1": cfg.get("joint1", "input"), "input_joints": cfg.get("input_joints"),
            "thermal": cfg.get("thermal", "auto"), "payload_input": cfg.get("payload_input", False),
            "fade_offset": float(cfg.get("fade_offset", 0.0)), "fade_cv": int(cfg.get("fade_cv", 0)),
            "uncertainty": bool(cfg.get("uncertainty", True))}


def save_model(model, path: str | Path) -> None:
    """Write a fitted ``model`` to ``path`` (module docstring)."""
    tensors = {f"pos.{k}": v for k, v in model.net_pos_.state_dict().items()}
    if model.net_rot_ is not None:
        tensors.update({f"rot.{k}": v for k, v in model.net_rot_.state_dict().items()})
    tensors["support.points"] = torch.from_numpy(np.ascontiguousarray(model.support_points_))
    tensors["support.pair_gap"] = torch.from_numpy(np.ascontiguousarray(model.pair_gap_, dtype=np.float64))
    tensors["support.pair_index"] = torch.from_numpy(np.ascontiguousarray(model.pair_index_, dtype=np.int64))
    meta = {
        "robot": robot_to_dict(model.robot_),
        "robot_nominal": robot_to_dict(model.robot),
        "robot_toml": robot_to_toml_string(model.robot_) if model.robot_.convention in ("dh", "mdh") else None,
        "config": model_config(model),
        "support": {"lower": model.support_lower_.tolist(), "upper": model.support_upper_.tolist(),
                    "spacing": model.support_spacing_, "gap_factor": GAP_FACTOR},
        "has_rot_net": model.net_rot_ is not None,
        "frames": {"pre": model.frame_pre_.tolist(), "post": model.frame_post_.tolist()},
        "stations": None if model.station_frames_ is None else model.station_frames_.to_dict(),
        "inputs": {"wrap_centre": json_safe(model.wrap_centre_),
                   "j1_axis": None if model.j1_axis_ is None else model.j1_axis_.tolist()},
        "uncertainty": json_safe(model.unc_),
        "thermal": None if model.thermal_ is None else json_safe(model.thermal_.to_dict()),
        "payload": None if model.payload_range_ is None else {"range": model.payload_range_.to_dict(),
                                                              "input": bool(model.payload_input_)},
        "training": json_safe(model.meta_),
    }
    write_model_file(path, tensors, meta)


def restore_fitted(m, tensors: dict, meta: dict, path, device: str) -> None:
    """Set the fitted attributes of ``m`` (constructed from the file's settings, fitted state empty)
    from a file's ``tensors`` and header ``meta``. KeyError/ValueError/... on a corrupt file."""
    m.robot_ = robot_from_json_dict(meta["robot"], f"{path}: robot")
    pl = meta.get("payload")  # absent in files before per-row payloads: behave as then
    if pl is not None:
        m.payload_range_ = PayloadRange.from_dict(pl["range"])
        m.payload_input_ = bool(pl.get("input", False))
    dt = torch.float64 if m.recipe_.dtype == "float64" else torch.float32
    for key in ("pos", "rot") if meta["has_rot_net"] else ("pos",):
        net = make_net(m.arch, m.robot.dof + int(m.payload_input_), 3, dtype=dt)
        sd = {k[len(key) + 1 :]: v for k, v in tensors.items() if k.startswith(key + ".")}
        net.load_state_dict(sd, strict=True)
        net.to(device).eval()
        setattr(m, f"net_{key}_", net)
    sup = meta["support"]
    m.support_lower_ = np.array(sup["lower"], dtype=np.float64)
    m.support_upper_ = np.array(sup["upper"], dtype=np.float64)
    m.support_spacing_ = float(sup["spacing"])
    m.support_points_ = tensors["support.points"].numpy().astype(np.float64)
    if "support.pair_gap" in tensors:
        m.pair_gap_ = tensors["support.pair_gap"].numpy().astype(np.float64)
        m.pair_index_ = tensors["support.pair_index"].numpy().astype(np.int64).reshape(-1, 2)
    m.meta_ = meta.get("training", {})
    inp = meta.get("inputs") or {}
    if inp.get("wrap_centre") is not None:
        m.wrap_centre_ = np.array([np.nan if isinstance(v, str) else v for v in inp["wrap_centre"]], dtype=np.float64)
    if inp.get("j1_axis") is not None:
        m.j1_axis_ = np.array(inp["j1_axis"], dtype=np.float64)
    unc = meta.get("uncertainty")
    if unc is not None:
        m.unc_ = {k: (np.array(v, dtype=np.float64) if isinstance(v, list) else v) for k, v in unc.items()}
    th = meta.get("thermal")
    if th is not None:
        m.thermal_ = ThermalFit(float(th["coefficient_per_k"]), float(th["std_per_k"]), float(th["reference_c"]),
                                tuple(float(v) for v in th["range_c"]), str(th["note"]))
    st = meta.get("stations")  # several stations / tools (absent in older files: one frame)
    m.station_frames_ = None if st is None else StationFrames.from_dict(st)
    fr = meta.get("frames")
    if fr is not None:
        m.frame_pre_ = np.array(fr["pre"], dtype=np.float64).reshape(4, 4)
        m.frame_post_ = np.array(fr["post"], dtype=np.float64).reshape(4, 4)
