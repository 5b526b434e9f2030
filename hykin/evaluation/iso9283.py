"""ISO 9283 pose accuracy (AP) and pose repeatability (RP), per test pose (P1 ... P5).

For each pose, with ``n`` attained poses ``(x_j, y_j, z_j, a_j, b_j, c_j)`` (j = 1..n, from ``n``
cycles, e.g. 30 around the ISO cube) and the commanded pose ``(x_c, y_c, z_c, a_c, b_c, c_c)``
(ISO 9283:1998, §7.2.1 and §7.2.2):

* barycentre ``x̄ = (1/n) Σ x_j`` (same for y, z, a, b, c);
* position accuracy ``AP_P = sqrt((x̄ − x_c)² + (ȳ − y_c)² + (z̄ − z_c)²)`` with components
  ``AP_x = x̄ − x_c``, ``AP_y = ȳ − y_c``, ``AP_z = z̄ − z_c``;
* orientation accuracy ``AP_a = ā − a_c``, ``AP_b = b̄ − b_c``, ``AP_c = c̄ − c_c``;
* position repeatability ``RP_l = l̄ + 3 S_l`` with ``l_j = sqrt((x_j − x̄)² + (y_j − ȳ)² + (z_j − z̄)²)``,
  ``l̄ = (1/n) Σ l_j``, ``S_l = sqrt(Σ (l_j − l̄)² / (n − 1))``;
* orientation repeatability ``RP_a = ±3 S_a``, ``S_a = sqrt(Σ (a_j − ā)² / (n − 1))`` (same for b, c).

The angles ``a, b, c`` are rotations about the base ``x, y, z`` axes. With ``orientation="euler"``
(default, the standard's wording) they are the fixed-axis x-y-z (roll-pitch-yaw) angles of each
pose; angle differences are wrapped to (−180°, 180°], and every angle is taken relative to the
commanded one before averaging, so wrapping at ±180° cannot corrupt a mean. Near pitch ±90° these
angles are singular; ``orientation="rotvec"`` instead uses the components of
``log(R_j R_cᵀ)`` (small deviations about the base axes), which agrees with the Euler
differences to first order and has no singularity.

Positions come in metres and are reported in mm, angles in degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry.se3 import matrix_to_rpy, rotation_difference_rotvec

__all__ = ["ISOError", "ISOResult", "iso9283_pose"]


class ISOError(ValueError):
    """Bad input to the ISO 9283 evaluation (shapes, inconsistent commanded poses, too few cycles)."""


@dataclass(frozen=True)
class ISOResult:
    """Per-pose ISO 9283 results (arrays over the ``P`` poses, in ``pose_ids`` order).

    n: cycles per pose; ap_mm: AP_P; ap_xyz_mm ``(P, 3)``: AP_x, AP_y, AP_z; ap_abc_deg ``(P, 3)``:
    AP_a, AP_b, AP_c; rp_mm: RP_l; rp_abc_deg ``(P, 3)``: 3 S_a, 3 S_b, 3 S_c (the ± values);
    l_mean_mm, s_l_mm: l̄ and S_l; s_abc_deg ``(P, 3)``: S_a, S_b, S_c.
    """

    pose_ids: list
    n: np.ndarray
    ap_mm: np.ndarray
    ap_xyz_mm: np.ndarray
    ap_abc_deg: np.ndarray
    rp_mm: np.ndarray
    rp_abc_deg: np.ndarray
    l_mean_mm: np.ndarray
    s_l_mm: np.ndarray
    s_abc_deg: np.ndarray
    orientation: str = "euler"

    def to_dict(self) -> dict:
        """JSON-friendly dict: one entry per pose."""
        out = {}
        for i, pid in enumerate(self.pose_ids):
            out[str(pid)] = dict(
                n=int(self.n[i]), AP_P_mm=float(self.ap_mm[i]),
                AP_x_mm=float(self.ap_xyz_mm[i, 0]), AP_y_mm=float(self.ap_xyz_mm[i, 1]),
                AP_z_mm=float(self.ap_xyz_mm[i, 2]),
                AP_a_deg=float(self.ap_abc_deg[i, 0]), AP_b_deg=float(self.ap_abc_deg[i, 1]),
                AP_c_deg=float(self.ap_abc_deg[i, 2]),
                RP_l_mm=float(self.rp_mm[i]), RP_a_deg=float(self.rp_abc_deg[i, 0]),
                RP_b_deg=float(self.rp_abc_deg[i, 1]), RP_c_deg=float(self.rp_abc_deg[i, 2]),
            )
        return out

    def format(self) -> str:
        """Markdown table, one row per pose."""
        head = ["pose", "n", "AP_P (mm)", "AP_x", "AP_y", "AP_z", "AP_a (deg)", "AP_b", "AP_c",
                "RP_l (mm)", "RP_a (±deg)", "RP_b", "RP_c"]
        rows = []
        for i, pid in enumerate(self.pose_ids):
            rows.append([str(pid), str(int(self.n[i])), f"{self.ap_mm[i]:.4f}",
                         *(f"{v:+.4f}" for v in self.ap_xyz_mm[i]), *(f"{v:+.5f}" for v in self.ap_abc_deg[i]),
                         f"{self.rp_mm[i]:.4f}", *(f"{v:.5f}" for v in self.rp_abc_deg[i])])
        w = [max(len(head[k]), *(len(r[k]) for r in rows)) for k in range(len(head))]
        line = lambda cells: "| " + " | ".join(c.rjust(x) for c, x in zip(cells, w)) + " |"
        return "\n".join([line(head), "|" + "|".join("-" * (x + 2) for x in w) + "|"] + [line(r) for r in rows])


def _wrap(a):
    return (a + np.pi) % (2 * np.pi) - np.pi


def iso9283_pose(commanded, attained, pose_id, *, orientation: str = "euler", tol_m: float = 1e-6,
                 tol_rad: float = 1e-6) -> ISOResult:
    """ISO 9283 AP and RP per pose from cycle data (formulas in the module docstring).

    ``commanded``, ``attained``: ``(M, 4, 4)`` poses (m) of M measurements; ``pose_id``: ``(M,)``
    labels (e.g. ``"P1"`` ... ``"P5"`` or 1 ... 5), each pose measured ``n >= 2`` times. All rows of
    one pose must share its commanded pose (within ``tol_m`` / ``tol_rad``). Poses are reported in
    order of first appearance.
    """
    if orientation not in ("euler", "rotvec"):
        raise ISOError(f"orientation must be 'euler' or 'rotvec', got {orientation!r}")
    C = np.asarray(commanded, dtype=np.float64)
    A = np.asarray(attained, dtype=np.float64)
    ids = np.asarray(pose_id)
    if C.ndim != 3 or C.shape[1:] != (4, 4) or A.shape != C.shape:
        raise ISOError(f"commanded and attained must both be (M, 4, 4); got {C.shape} and {A.shape}")
    if ids.shape != (C.shape[0],):
        raise ISOError(f"pose_id must have shape ({C.shape[0]},), got {ids.shape}")
    for nm, X in (("commanded", C), ("attained", A)):
        bad = ~np.isfinite(X).all(axis=(1, 2))
        if bad.any():
            raise ISOError(f"{nm}: non-finite pose in row(s) {np.flatnonzero(bad)[:10].tolist()}")
    _, first = np.unique(ids, return_index=True)
    order = ids[np.sort(first)]
    P = len(order)
    n = np.zeros(P, int)
    ap_xyz = np.zeros((P, 3))
    ap_abc = np.zeros((P, 3))
    l_mean = np.zeros(P)
    s_l = np.zeros(P)
    s_abc = np.zeros((P, 3))
    for k, pid in enumerate(order):
        rows = np.flatnonzero(ids == pid)
        if rows.size < 2:
            raise ISOError(f"pose {str(pid)!r}: needs at least 2 cycles for repeatability, got {rows.size}")
        Cc = C[rows[0]].copy()
        Cc[:3, 3] = C[rows, :3, 3].mean(0)  # cycles within the tolerance: their mean commanded position
        dev_p = np.abs(C[rows, :3, 3] - Cc[:3, 3]).max()
        dev_r = np.linalg.norm(rotation_difference_rotvec(C[rows, :3, :3], Cc[:3, :3]), axis=-1).max()
        if dev_p > tol_m or dev_r > tol_rad:
            raise ISOError(f"pose {str(pid)!r}: commanded poses differ between cycles by up to {dev_p * 1e3:.3g} mm / "
                           f"{np.degrees(dev_r):.3g} deg (tolerance {tol_m * 1e3:.3g} mm / {np.degrees(tol_rad):.3g} deg; "
                           f"rows {rows[:5].tolist()}...)")
        x = A[rows, :3, 3]
        bar = x.mean(0)
        ap_xyz[k] = (bar - Cc[:3, 3]) * 1e3
        if orientation == "euler":
            d_ang = _wrap(matrix_to_rpy(A[rows, :3, :3]) - matrix_to_rpy(Cc[:3, :3]))
        else:
            d_ang = rotation_difference_rotvec(A[rows, :3, :3], Cc[:3, :3])
        ap_abc[k] = np.degrees(d_ang.mean(0))
        s_abc[k] = np.degrees(d_ang.std(0, ddof=1))
        lj = np.linalg.norm(x - bar, axis=1) * 1e3
        l_mean[k] = lj.mean()
        s_l[k] = lj.std(ddof=1)
        n[k] = rows.size
    return ISOResult(
        pose_ids=order.tolist(), n=n, ap_mm=np.linalg.norm(ap_xyz, axis=1), ap_xyz_mm=ap_xyz, ap_abc_deg=ap_abc,
        rp_mm=l_mean + 3 * s_l, rp_abc_deg=3 * s_abc, l_mean_mm=l_mean, s_l_mm=s_l, s_abc_deg=s_abc,
        orientation=orientation,
    )
