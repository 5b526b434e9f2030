"""ONNX export of a hybrid model, so a controller can run it without Python.

The exported graph maps joints ``q`` ``(N, dof)`` float64 (rad) to TCP poses ``pose`` ``(N, 4, 4)``
float64 (m): the calibrated classical chain (with joint compliance), the position and orientation
networks and the smooth joint-range fade, exactly as :meth:`HybridModel.predict_torch`. A model whose
poses depend on the payload (joint compliance deflecting under it, or networks with the payload as an
input: training data with several ``payload_kg`` values) has payload inputs too (:func:`payload_inputs`):
``payload_kg`` (kg, ``(N,)`` one per row, or ``(1,)`` for all rows) and, with joint compliance,
``payload_com_m`` (m, tool frame, ``(N, 3)`` or ``(1, 3)``; zeros: at the TCP). They are required: the
controller feeds the payload the robot carries (the robot file's, for :meth:`HybridModel.predict`
without payload arguments, is in the returned info). A model whose poses do not depend on the payload
has the input ``q`` alone. The export is checked against hykin with ONNX Runtime before it is reported
done, at several payloads (0 kg, each trained payload, the file's, one beyond the trained ones) and
centres of mass. A model with a thermal coefficient
(:mod:`hykin.calibration.thermal`) is exported at its reference temperature; the returned info carries what the
controller needs to apply the expansion: ``p = b + (1 + alpha (t - t_ref)) (p - b)``.
"""

from __future__ import annotations

import os
import warnings
from contextlib import contextmanager
from pathlib import Path

import numpy as np

__all__ = ["MIN_ORT", "export_onnx", "payload_inputs"]

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


def payload_inputs(model) -> tuple:
    """The payload inputs of ``model``'s graph, in order: ``()`` when its poses do not depend on the
    payload; ``("payload_kg",)`` when only its networks take the payload as an input;
    ``("payload_kg", "payload_com_m")`` when its calibrated joint compliance deflects under the payload
    (the deflection depends on the payload's mass and centre of mass)."""
    if model.robot_.has_compliance:
        return ("payload_kg", "payload_com_m")
    return ("payload_kg",) if getattr(model, "payload_input_", False) else ()


def default_payload_kg(model) -> float:
    """The payload (kg) the model's ``predict`` assumes when given none (the robot file's)."""
    d = getattr(model, "payload_default_kg_", None)
    return float(model.robot_.payload_kg if d is None else d)


def check_payloads_kg(model) -> list:
    """Payloads (kg) the export is checked at: 0, the robot file's, each trained payload (up to 32) and
    one beyond all of them (where the networks hold their nearest trained payload and the physics goes on)."""
    rng = getattr(model, "payload_range_", None)
    vals = [0.0, default_payload_kg(model)] + ([] if rng is None else [float(v) for v in rng.values_kg]
                                               + [rng.lower_kg, rng.upper_kg])
    vals.append(1.25 * max(vals) + 1.0)
    return sorted(set(round(v, 9) for v in vals))


@contextmanager
def _full_fixed_point():
    """Trace the compliance's fixed-point iteration with all its steps (:data:`MAX_ITER`): the loop stops
    early in Python when the update is below ``TOL_RAD``, and the tracer records only the steps it ran
    on the trace's rows. With every step in the graph, any payload and pose converges as far as
    ``predict`` does (further steps of a converged fixed point change nothing)."""
    from ..kinematics import compliance

    tol = compliance.TOL_RAD
    compliance.TOL_RAD = -1.0
    try:
        yield
    finally:
        compliance.TOL_RAD = tol


def export_onnx(model, path: str | Path, n_check: int = 2000, opset: int = 17, seed: int = 0) -> dict:
    """Write ``model`` to ``path`` as ONNX and check it with ONNX Runtime.

    Returns ``{"max_pos_diff_mm", "max_ang_diff_deg", "n_check", "inputs", "payload_default_kg",
    "payloads_checked_kg"}`` measured on ``n_check`` joint configurations drawn inside the training
    range, each row at one of :func:`check_payloads_kg` (with centres of mass up to 0.2 m from the TCP
    on every other row when the graph takes one); ``inputs`` names the graph's inputs
    (:func:`payload_inputs`), ``payload_default_kg`` the robot file's payload (None without payload inputs). Raises ``RuntimeError``, and writes nothing, if the exported model
    differs from hykin by more than 1e-6 mm / 1e-6 deg or if the installed ONNX Runtime cannot run it
    (float64 Sin/Cos need onnxruntime >= :data:`MIN_ORT`).
    """
    import torch

    from .fast_nets import torch64

    names = payload_inputs(model)

    class _Wrapper(torch.nn.Module):
        def __init__(self, m):
            super().__init__()
            self.m = m
            # register the nets predict_torch runs (float64 copies, hykin.hybrid.fast_nets) so that
            # their weights are graph initialisers
            self.net_pos = torch64(m, m.net_pos_)
            self.net_rot = None if m.net_rot_ is None else torch64(m, m.net_rot_)

        def forward(self, q, payload_kg=None, payload_com_m=None):
            if payload_kg is None:
                return self.m.predict_torch(q)
            n = q.shape[0]  # (1,) / (1, 3) broadcast to every row, (N,) / (N, 3) taken as they are
            kg = payload_kg.reshape(-1).expand(n)
            com = None if payload_com_m is None else payload_com_m.reshape(-1, 3).expand(n, 3)
            return self.m.predict_torch(q, kg, com)

    lo = np.asarray(model.support_lower_)
    hi = np.asarray(model.support_upper_)
    rng = np.random.default_rng(seed)
    q = lo + rng.random((n_check, len(lo))) * (hi - lo)
    payload = None
    if names:
        kgs = np.array(check_payloads_kg(model))
        kg = kgs[np.arange(n_check) % len(kgs)]
        com = None
        if "payload_com_m" in names:  # half the rows at the TCP, half up to 0.2 m from it
            com = rng.uniform(-0.2, 0.2, (n_check, 3)) * (np.arange(n_check) % 2 == 1)[:, None]
        payload = (kg, com)
    wrapper = _Wrapper(model).eval()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # written beside the target and moved there only once checked: a failed export leaves nothing
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        info = _export_checked(model, wrapper, q, payload, names, tmp, opset)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return info


def _export_checked(model, wrapper, q: np.ndarray, payload, names, tmp: Path, opset: int) -> dict:
    """Trace ``wrapper`` to ``tmp`` and compare ONNX Runtime's poses there with ``model.predict`` at
    the joints ``q`` ``(n, dof)`` rad, each row with its payload ``payload`` (``(kg (n,), com (n, 3) or
    None)``, or None for a graph with no payload ``names``)."""
    import torch

    from ..geometry.se3 import pose_error

    args = (torch.from_numpy(q[:8]),)
    dyn = {"q": {0: "N"}, "pose": {0: "N"}}
    if names:
        args += (torch.from_numpy(np.ascontiguousarray(payload[0][:8])),)
        dyn["payload_kg"] = {0: "N_payload"}
        if "payload_com_m" in names:
            com = np.zeros((len(q), 3)) if payload[1] is None else payload[1]
            args += (torch.from_numpy(np.ascontiguousarray(com[:8])),)
            dyn["payload_com_m"] = {0: "N_payload"}
    with warnings.catch_warnings(), torch.no_grad(), _silu_as_division(wrapper.net_pos, wrapper.net_rot), \
            _full_fixed_point():
        # The tracer warns about Python-side control flow (fixed-point iterations, fade branches);
        # the result is verified numerically below.
        warnings.simplefilter("ignore")
        torch.onnx.export(
            wrapper, args, str(tmp), dynamo=False, input_names=["q", *names], output_names=["pose"],
            dynamic_axes=dyn, opset_version=opset,
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
    feeds, kw = {"q": q}, {}
    if names:
        kg, com = payload
        feeds["payload_kg"], kw["payload_kg"] = kg, kg
        if "payload_com_m" in names:
            feeds["payload_com_m"] = np.zeros((len(q), 3)) if com is None else com
            kw["payload_com_m"] = com
    T_onnx = sess.run(None, feeds)[0]
    with warnings.catch_warnings():
        # Check points are drawn over the whole trained box, holes included (and payloads beyond the
        # trained ones): no need to warn here.
        warnings.simplefilter("ignore")
        T_ref = model.predict(q, **kw)
    p, a = pose_error(T_onnx, T_ref)
    info = {"max_pos_diff_mm": float(p.max()), "max_ang_diff_deg": float(a.max()), "n_check": len(q),
            "inputs": ["q", *names], "payload_default_kg": default_payload_kg(model) if names else None,
            "payloads_checked_kg": check_payloads_kg(model) if names else []}
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
