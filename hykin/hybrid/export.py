"""ONNX export of a hybrid model, so a controller can run it without Python.

The exported graph maps joints ``q`` ``(N, dof)`` float64 (rad) to TCP poses ``(N, 4, 4)`` float64
(m): the calibrated classical chain (with joint compliance), the position and orientation networks
and the smooth joint-range fade, exactly as :meth:`HybridModel.predict_torch`. The export is checked
against hykin with ONNX Runtime before it is reported done. A model with a thermal coefficient
(:mod:`hykin.calibration.thermal`) is exported at its reference temperature; the returned info carries what the
controller needs to apply the expansion: ``p = b + (1 + alpha (t - t_ref)) (p - b)``.
"""

from __future__ import annotations

import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["MIN_ORT", "export_onnx"]

#: the oldest ONNX Runtime that runs the float64 graph (double Sin/Cos kernels; 1.28 has float only)
MIN_ORT = "1.29"


@contextmanager
def _silu_as_division(*nets):
    """Trace SiLU as ``x / (1 + exp(-x))`` instead of ``x * sigmoid(x)`` while exporting.

    ONNX Runtime fuses ``Mul(x, Sigmoid(x))`` into its QuickGelu kernel, which some releases (1.30,
    seen on a GPU machine) have for float32 alone: a float64 graph with that pattern then fails to
    load with the default options, in our check and on the controller. The division has no fused
    form and equals SiLU to float64 rounding (exp overflow at very negative x gives -0). The modules
    are swapped in place and put back afterwards."""
    import torch

    class _SiLUDiv(torch.nn.Module):
        def forward(self, x):
            return x / (1.0 + torch.exp(-x))

    swapped = []
    for net in nets:
        if net is None:
            continue
        for mod in list(net.modules()):
            for name, child in list(mod.named_children()):
                if isinstance(child, torch.nn.SiLU):
                    setattr(mod, name, _SiLUDiv())
                    swapped.append((mod, name, child))
    try:
        yield
    finally:
        for mod, name, child in swapped:
            setattr(mod, name, child)


def export_onnx(model, path: str | Path, n_check: int = 2000, opset: int = 17, seed: int = 0) -> dict:
    """Write ``model`` to ``path`` as ONNX and check it with ONNX Runtime.

    Returns ``{"max_pos_diff_mm", "max_ang_diff_deg", "n_check"}`` measured on ``n_check`` joint
    configurations drawn inside the training range. Raises ``RuntimeError``, and writes nothing, if
    the exported model differs from hykin by more than 1e-6 mm / 1e-6 deg or if the installed ONNX
    Runtime cannot run it (float64 Sin/Cos need onnxruntime >= :data:`MIN_ORT`).
    """
    import torch

    from .fast_nets import torch64

    class _Wrapper(torch.nn.Module):
        def __init__(self, m):
            super().__init__()
            self.m = m
            # register the nets predict_torch runs (float64 copies, hykin.hybrid.fast_nets) so that
            # their weights are graph initialisers
            self.net_pos = torch64(m, m.net_pos_)
            self.net_rot = None if m.net_rot_ is None else torch64(m, m.net_rot_)

        def forward(self, q):
            return self.m.predict_torch(q)

    lo = np.asarray(model.support_lower_)
    hi = np.asarray(model.support_upper_)
    rng = np.random.default_rng(seed)
    q = lo + rng.random((n_check, len(lo))) * (hi - lo)
    wrapper = _Wrapper(model).eval()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # written beside the target and moved there only once checked: a failed export leaves nothing
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        info = _export_checked(model, wrapper, q, tmp, opset)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return info


def _export_checked(model, wrapper, q: np.ndarray, tmp: Path, opset: int) -> dict:
    """Trace ``wrapper`` to ``tmp`` and compare ONNX Runtime's poses there with ``model.predict`` at
    the joints ``q`` ``(n, dof)`` rad."""
    import torch

    from ..geometry.se3 import pose_error

    with warnings.catch_warnings(), torch.no_grad(), _silu_as_division(wrapper.net_pos, wrapper.net_rot):
        # The tracer warns about Python-side control flow (fixed-point iterations, fade branches);
        # the result is verified numerically below.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            wrapper, (torch.from_numpy(q[:8]),), str(tmp), dynamo=False, input_names=["q"], output_names=["pose"],
            dynamic_axes={"q": {0: "N"}, "pose": {0: "N"}}, opset_version=opset,
        )
    import onnxruntime as ort

    try:
        sess = ort.InferenceSession(str(tmp), providers=["CPUExecutionProvider"])
    except Exception as e:  # onnxruntime raises its own NotImplemented / Fail types
        raise RuntimeError(
            f"ONNX Runtime {ort.__version__} cannot run the exported float64 graph "
            f"({str(e).splitlines()[0][:160]}); the export is checked with onnxruntime >= {MIN_ORT} "
            f"(float64 Sin/Cos): pip install -U 'onnxruntime>={MIN_ORT}'. Nothing was written."
        ) from e
    T_onnx = sess.run(None, {"q": q})[0]
    with warnings.catch_warnings():
        # Check points are drawn over the whole trained box, holes included: no need to warn here.
        warnings.simplefilter("ignore")
        T_ref = model.predict(q)
    p, a = pose_error(T_onnx, T_ref)
    info = {"max_pos_diff_mm": float(p.max()), "max_ang_diff_deg": float(a.max()), "n_check": len(q)}
    th = getattr(model, "thermal_", None)
    if th is not None and th.coefficient_per_k != 0.0:
        b = model.frame_pre_ @ np.r_[model.robot_.base[:3, 3], 1.0]
        info.update(thermal_coefficient_per_k=th.coefficient_per_k, thermal_reference_c=th.reference_c,
                    thermal_origin_m=b[:3].tolist())
    if info["max_pos_diff_mm"] > 1e-6 or info["max_ang_diff_deg"] > 1e-6:
        raise RuntimeError(
            f"ONNX export differs from hykin by {info['max_pos_diff_mm']:.2e} mm / "
            f"{info['max_ang_diff_deg']:.2e} deg (limit 1e-6); nothing was written"
        )
    return info
