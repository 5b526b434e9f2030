"""What the residual networks see: joints mapped to network coordinates, the payload input and the
frame the residuals are learnt in (:mod:`hykin.hybrid.model`, "Input representation").

Network coordinates ``qn`` ``(N, n)``: revolute joints wrapped onto ``[c - π, c + π)`` around the
per-joint centre ``c`` (``wrap_centre``, NaN = not wrapped) and joints that are not network inputs
(``mask`` False, e.g. ``q1`` with ``joint1="frame"``) zeroed. Radians for revolute joints, metres for
prismatic ones.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..io.payload import payload_column
from .rotations import rotate_about

__all__ = ["TWO_PI", "from_net_frame", "net_coordinates", "net_input", "seam_centres", "to_net_frame"]

TWO_PI = 2.0 * math.pi


def seam_centres(q: np.ndarray, revolute: np.ndarray) -> np.ndarray:
    """Per joint the centre ``c`` (rad) of the wrapping window ``[c - π, c + π)`` (NaN: not wrapped).

    ``q`` ``(N, n)`` training joints, ``revolute`` ``(n,)`` bool. The seam ``c ± π`` sits in the middle
    of the widest gap between the training angles on the circle; of the equivalent centres ``c + 2πk``
    the one nearest the median raw angle is kept, so wrapped training angles equal the raw ones
    whenever the data do not straddle the seam."""
    c = np.full(q.shape[1], np.nan)
    for j in np.flatnonzero(revolute):
        a = np.sort(np.mod(q[:, j], TWO_PI))
        gaps = np.diff(np.r_[a, a[0] + TWO_PI])
        k = int(np.argmax(gaps))
        cj = a[k] + 0.5 * gaps[k] + math.pi
        c[j] = cj + TWO_PI * np.round((np.median(q[:, j]) - cj) / TWO_PI)
    return c


def net_coordinates(q, wrap_centre: np.ndarray, mask: np.ndarray):
    """Joints as the networks see them (numpy or torch ``(N, n)``, same type out): revolute joints
    with a finite ``wrap_centre`` ``(n,)`` wrapped, joints with ``mask`` ``(n,)`` False zeroed."""
    c = wrap_centre
    wrapped = np.isfinite(c)
    if isinstance(q, torch.Tensor):
        out = q
        if wrapped.any():
            ct = torch.as_tensor(np.where(wrapped, c, 0.0), dtype=q.dtype, device=q.device)
            mt = torch.as_tensor(wrapped, device=q.device)
            out = torch.where(mt, ct - math.pi + torch.remainder(q - (ct - math.pi), TWO_PI), q)
        if not mask.all():
            out = out * torch.as_tensor(mask, dtype=out.dtype, device=out.device)
        return out
    out = q
    if wrapped.any():
        cc = np.where(wrapped, c, 0.0)
        out = np.where(wrapped, cc - math.pi + np.mod(q - (cc - math.pi), TWO_PI), q)
    if not mask.all():
        out = out * mask
    return out


def net_input(qn, payload_active: bool, payload_kg, payload_range):
    """Network input: ``qn`` ``(N, n)``, plus the payload column (kg) when ``payload_active``, clamped
    to ``payload_range`` (beyond it the networks' payload dependence is held, the physics
    extrapolates). ``payload_kg``: scalar or ``(N,)`` (the caller resolves the default)."""
    if not payload_active:
        return qn
    return payload_column(qn, payload_kg, payload_range)


def to_net_frame(j1_axis: np.ndarray | None, q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Base-frame residual vectors ``v`` ``(N, 3)`` -> the frame the networks learn in (turned by
    ``-q1`` about the joint-1 axis ``j1_axis`` ``(3,)``; unchanged when it is None)."""
    return v if j1_axis is None else rotate_about(j1_axis, -q[:, 0], v)


def from_net_frame(j1_axis: np.ndarray | None, q, v):
    """Inverse of :func:`to_net_frame` (numpy or torch)."""
    return v if j1_axis is None else rotate_about(j1_axis, q[:, 0], v)
