"""Residual networks of the hybrid model, selectable by name (DESIGN.md §1.2).

Every network maps raw joints ``q`` ``(N, n_in)`` (rad / m) to a residual ``(N, n_out)`` in SI units
(m for position, rad rotation vector for orientation). Each net carries its own input normalisation
(buffers ``lower``/``upper``: min-max over the full joint range or the training-data range) and output
scaling (buffers ``out_bias``/``out_scale``), so a saved state dict is the whole function.

Paper architectures (Ojer et al. 2024, appendix; ReLU, linear output, inputs min-max to [0, 1]):

====  =======================================================
D1    dense 5000
D4    dense 3500-2500-1500-750
D4w   dense 5000-3000-1000-500
D4W   dense 6000-3000-1500-1000
Rw    ResNet, 3 components of widths 700, 500, 200
Rd    ResNet, 5 components of widths 500, 200, 100, 70, 30
====  =======================================================

ResNet component (Chen et al. 2020): one dense block then two identity blocks of width ``u``.
Identity block: ``3 x (Dense(u) -> BatchNorm -> ReLU)``, the last ReLU after adding the input.
Dense block: same main path, shortcut ``Dense(u) -> BatchNorm`` before the add.

Baselines (the papers do not publish exact sizes; these are documented approximations):

* ``B1`` Theofanidis et al. 2018, dense MLP for FK: 3 hidden ReLU layers of 100.
* ``B2`` Chen et al. 2020 ResNet for nonlinear regression: 2 components of width 100 (same blocks
  as Rw/Rd).
* ``B3`` Nguyen et al. 2015, calibration + small MLP: 1 hidden layer of 20 sigmoid units (the EKF
  calibration is replaced by hykin's Levenberg-Marquardt calibration in :class:`HybridModel`).
* ``B4`` Chen et al. 2020 GA-DNN: the genetic search is not reproduced; a fixed 4 x 200 ReLU MLP
  of the size such a search typically returns.

Ours (``default``): inputs ``[x, sin q, cos q]`` (x = q min-max scaled to [-1, 1]), 3 hidden layers
of 64 SiLU units, linear output. Smooth activations suit smooth kinematic residuals, the periodic
features make joint-angle harmonics (gear and encoder errors) cheap to represent, and the small
width keeps hybrid prediction above 200 k poses/s on two CPU cores. Chosen by measurement
(benchmarks/bench_hybrid.py): accuracy per CPU-minute against wider SiLU/GELU nets and the paper
dense nets. ``default-wide`` (3 x 128) is the bigger sibling.
"""

from __future__ import annotations

import torch
from torch import nn

__all__ = ["ARCHITECTURES", "ResidualNet", "count_parameters", "list_architectures", "make_net"]


# --------------------------------------------------------------------------- blocks


def _dbn(n_in: int, u: int) -> list[nn.Module]:
    return [nn.Linear(n_in, u), nn.BatchNorm1d(u)]


class IdentityBlock(nn.Module):
    """Chen 2020 identity block: 3 x (Dense -> BN -> ReLU), the last ReLU after adding the input."""

    def __init__(self, u: int):
        super().__init__()
        self.main = nn.Sequential(*_dbn(u, u), nn.ReLU(), *_dbn(u, u), nn.ReLU(), *_dbn(u, u))
        self.act = nn.ReLU()

    def forward(self, x):
        return self.act(self.main(x) + x)


class DenseBlock(nn.Module):
    """Chen 2020 dense block: identity-block main path from ``n_in`` to ``u``, shortcut Dense -> BN."""

    def __init__(self, n_in: int, u: int):
        super().__init__()
        self.main = nn.Sequential(*_dbn(n_in, u), nn.ReLU(), *_dbn(u, u), nn.ReLU(), *_dbn(u, u))
        self.shortcut = nn.Sequential(*_dbn(n_in, u))
        self.act = nn.ReLU()

    def forward(self, x):
        return self.act(self.main(x) + self.shortcut(x))


def resnet_body(n_in: int, widths: list[int], n_out: int) -> nn.Sequential:
    """Components (dense block + 2 identity blocks) of the given widths, then a linear output."""
    layers: list[nn.Module] = []
    prev = n_in
    for u in widths:
        layers += [DenseBlock(prev, u), IdentityBlock(u), IdentityBlock(u)]
        prev = u
    layers.append(nn.Linear(prev, n_out))
    return nn.Sequential(*layers)


_ACTS = {"relu": nn.ReLU, "silu": nn.SiLU, "gelu": nn.GELU, "tanh": nn.Tanh, "sigmoid": nn.Sigmoid}


def mlp_body(n_in: int, widths: list[int], n_out: int, act: str = "relu") -> nn.Sequential:
    """Dense layers of the given widths with activation ``act``, linear output of ``n_out``."""
    layers: list[nn.Module] = []
    prev = n_in
    for w in widths:
        layers += [nn.Linear(prev, w), _ACTS[act]()]
        prev = w
    layers.append(nn.Linear(prev, n_out))
    return nn.Sequential(*layers)


# --------------------------------------------------------------------------- registry

#: name -> config. kind "mlp" or "resnet"; features "minmax01" (paper) or "trig" (ours).
ARCHITECTURES: dict[str, dict] = {
    "D1": dict(kind="mlp", widths=[5000], act="relu", features="minmax01", ref="Ojer 2024 appendix"),
    "D4": dict(kind="mlp", widths=[3500, 2500, 1500, 750], act="relu", features="minmax01", ref="Ojer 2024 appendix"),
    "D4w": dict(kind="mlp", widths=[5000, 3000, 1000, 500], act="relu", features="minmax01", ref="Ojer 2024 appendix"),
    "D4W": dict(kind="mlp", widths=[6000, 3000, 1500, 1000], act="relu", features="minmax01", ref="Ojer 2024 appendix"),
    "Rw": dict(kind="resnet", widths=[700, 500, 200], features="minmax01", ref="Ojer 2024 appendix, Chen 2020 blocks"),
    "Rd": dict(kind="resnet", widths=[500, 200, 100, 70, 30], features="minmax01", ref="Ojer 2024 appendix, Chen 2020 blocks"),
    "B1": dict(kind="mlp", widths=[100, 100, 100], act="relu", features="minmax01", ref="approx. Theofanidis 2018"),
    "B2": dict(kind="resnet", widths=[100, 100], features="minmax01", ref="approx. Chen 2020 ResNet"),
    "B3": dict(kind="mlp", widths=[20], act="sigmoid", features="minmax01", ref="approx. Nguyen 2015 (calibration + small MLP)"),
    "B4": dict(kind="mlp", widths=[200, 200, 200, 200], act="relu", features="minmax01", ref="approx. Chen 2020 GA-DNN"),
    "default": dict(kind="mlp", widths=[64, 64, 64], act="silu", features="trig", ref="hykin (ours)"),
    "default-wide": dict(kind="mlp", widths=[128, 128, 128], act="silu", features="trig", ref="hykin (ours)"),
}


def list_architectures() -> list[str]:
    """Names accepted by :func:`make_net`."""
    return list(ARCHITECTURES)


class ResidualNet(nn.Module):
    """Joints -> residual with built-in input normalisation and output scaling.

    ``forward(q)``: ``q`` ``(N, n_in)`` raw joints (any float dtype; cast to the net's dtype) ->
    ``(N, n_out)`` residual in SI units, ``out_bias + out_scale * body(features(q))``.
    Buffers: ``lower``, ``upper`` ``(n_in,)`` normalisation range; ``out_bias`` ``(n_out,)``,
    ``out_scale`` ``()`` (isotropic, so a Euclidean-norm loss keeps its meaning).
    """

    def __init__(self, name: str, n_in: int, n_out: int, features: str, body: nn.Module):
        super().__init__()
        self.arch = name
        self.features = features
        self.n_in, self.n_out = n_in, n_out
        self.body = body
        self.register_buffer("lower", torch.zeros(n_in))
        self.register_buffer("upper", torch.ones(n_in))
        self.register_buffer("out_bias", torch.zeros(n_out))
        self.register_buffer("out_scale", torch.ones(()))

    def set_input_range(self, lower, upper) -> None:
        """Min-max normalisation range per joint (rad / m). Zero-width ranges are widened to 1e-6."""
        lo = torch.as_tensor(lower, dtype=self.lower.dtype)
        hi = torch.as_tensor(upper, dtype=self.upper.dtype)
        hi = torch.where(hi - lo < 1e-6, lo + 1e-6, hi)
        self.lower.copy_(lo)
        self.upper.copy_(hi)

    def set_output_scale(self, bias, scale) -> None:
        """Residual = ``bias + scale * body``; set from the training targets."""
        self.out_bias.copy_(torch.as_tensor(bias, dtype=self.out_bias.dtype))
        self.out_scale.copy_(torch.as_tensor(scale, dtype=self.out_scale.dtype))

    def featurize(self, q):
        q = q.to(self.lower.dtype)
        x = (q - self.lower) / (self.upper - self.lower)
        if self.features == "minmax01":
            return x
        return torch.cat([2 * x - 1, torch.sin(q), torch.cos(q)], -1)

    def body_forward(self, q):
        """Unscaled network output (what the training loss sees, up to ``out_scale``)."""
        return self.body(self.featurize(q))

    def forward(self, q):
        return self.out_bias + self.out_scale * self.body_forward(q)


def make_net(name: str, n_in: int, n_out: int = 3, dtype: torch.dtype = torch.float32) -> ResidualNet:
    """Build architecture ``name`` (see :func:`list_architectures`) for ``n_in`` joints."""
    if name not in ARCHITECTURES:
        raise ValueError(f"unknown architecture {name!r}; choose from {', '.join(ARCHITECTURES)}")
    if n_in < 1 or n_out < 1:
        raise ValueError(f"make_net: n_in and n_out must be >= 1, got {n_in}, {n_out}")
    cfg = ARCHITECTURES[name]
    width_in = n_in if cfg["features"] == "minmax01" else 3 * n_in
    if cfg["kind"] == "resnet":
        body = resnet_body(width_in, cfg["widths"], n_out)
    else:
        body = mlp_body(width_in, cfg["widths"], n_out, cfg.get("act", "relu"))
    return ResidualNet(name, n_in, n_out, cfg["features"], body).to(dtype)


def count_parameters(net: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in net.parameters() if p.requires_grad)
