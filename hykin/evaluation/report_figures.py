"""The report's figures (matplotlib, Agg backend), one function per figure, each returning a figure:

* :func:`error_histograms` — position / orientation error distributions of two models;
* :func:`joint_error_figure` — error against each joint (binned means per model, samples of the last);
* :func:`spatial_error_figure` — the test positions in three projections, coloured by error;
* :func:`correlation_figure` — the calibration's parameter correlation matrix as a heatmap.

Inputs are errors in mm / deg, joints in rad (shown in deg), positions in m (shown in m).
"""

from __future__ import annotations

import numpy as np

__all__ = ["correlation_figure", "distributions_figure", "error_histograms", "joint_bins", "joint_error_figure", "spatial_error_figure"]


def _plt():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def error_histograms(before_mm, after_mm, before_deg=None, after_deg=None, labels=("before", "after")):
    """Figure with position (and orientation) error distributions before vs after (paper Fig. 4/8 style),
    on log-spaced bins (before and after differ by orders of magnitude)."""
    errors = {labels[0]: (before_mm, before_deg), labels[1]: (after_mm, after_deg)}
    return distributions_figure(errors)


def distributions_figure(errors: dict):
    """Position (and orientation) error distributions of every model in ``errors`` (name -> ``(pos_mm (N,),
    ang_deg (N,) or None)``), overlaid on shared log-spaced bins."""
    plt = _plt()
    names = list(errors)
    ncol = 2 if all(errors[k][1] is not None for k in names) else 1
    fig, axes = plt.subplots(1, ncol, figsize=(5.2 * ncol, 3.4), squeeze=False)
    for c, unit in enumerate(("position error [mm]", "orientation error [deg]")[:ncol]):
        ax = axes[0, c]
        vals = [np.asarray(errors[k][c]) for k in names]
        lo = max(min(v.min() for v in vals), 1e-15)
        hi = max(max(v.max() for v in vals), lo * 10)
        bins = np.geomspace(lo, hi * 1.01, 50)
        for k, v in zip(names, vals):
            ax.hist(np.maximum(v, lo), bins=bins, alpha=0.6 if len(names) <= 2 else 0.5, label=k)
        ax.set_xscale("log")
        ax.set_xlabel(unit)
        ax.set_ylabel("samples")
        ax.legend()
    fig.tight_layout()
    return fig


def joint_bins(qj: np.ndarray, e: np.ndarray, n_bins: int = 8) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Equal-width bins of one joint's values ``qj`` ``(N,)``: ``(centres, mean error, count)``
    (``nan`` mean for an empty bin)."""
    qj, e = np.asarray(qj, float), np.asarray(e, float)
    lo, hi = float(qj.min()), float(qj.max())
    edges = np.linspace(lo, hi if hi > lo else lo + 1e-9, n_bins + 1)
    k = np.clip(np.searchsorted(edges, qj, side="right") - 1, 0, n_bins - 1)
    cnt = np.bincount(k, minlength=n_bins)
    s = np.bincount(k, weights=e, minlength=n_bins)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)
    return 0.5 * (edges[1:] + edges[:-1]), mean, cnt


def joint_error_figure(q: np.ndarray, errors: dict, revolute=None):
    """Position error against each joint: the samples of the last model in ``errors`` (name ->
    ``pos_mm (N,)``) as dots, each model's mean per joint bin as a line. ``q`` ``(N, n)`` rad / m."""
    plt = _plt()
    q = np.asarray(q, float)
    n = q.shape[1]
    revolute = np.ones(n, bool) if revolute is None else np.asarray(revolute, bool)
    ncol = 3 if n > 4 else n
    nrow = -(-n // ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.5 * nrow), squeeze=False, sharey=True)
    names = list(errors)
    floor = max(min(float(np.min(v)) for v in errors.values()), 1e-15)  # log axis: exact zeros drawn at the floor
    for j in range(n):
        ax = axes[j // ncol, j % ncol]
        x = np.degrees(q[:, j]) if revolute[j] else q[:, j] * 1e3
        ax.scatter(x, np.maximum(errors[names[-1]], floor), s=2, alpha=0.25, color="C%d" % (len(names) - 1), rasterized=True)
        for k, name in enumerate(names):
            c, m, _ = joint_bins(x, errors[name])
            ax.plot(c, np.maximum(m, floor), "o-", ms=3, color=f"C{k}", label=name)
        ax.set_yscale("log")
        ax.set_xlabel(f"joint {j + 1} [{'deg' if revolute[j] else 'mm'}]")
        if j % ncol == 0:
            ax.set_ylabel("position error [mm]")
    for j in range(n, nrow * ncol):
        axes[j // ncol, j % ncol].axis("off")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return fig


def spatial_error_figure(xyz_m: np.ndarray, err_mm: np.ndarray, label: str):
    """The positions ``xyz_m`` ``(N, 3)`` projected on XY, XZ and YZ, coloured by ``err_mm`` ``(N,)``
    (largest errors drawn last, on top)."""
    plt = _plt()
    xyz, e = np.asarray(xyz_m, float), np.asarray(err_mm, float)
    order = np.argsort(e)
    xyz, e = xyz[order], e[order]
    fig, axes = plt.subplots(1, 3, figsize=(11.5, 3.8), layout="constrained")
    vmax = float(np.percentile(e, 99)) if len(e) else 1.0
    sc = None
    for ax, (i, j) in zip(axes, ((0, 1), (0, 2), (1, 2))):
        sc = ax.scatter(xyz[:, i], xyz[:, j], c=e, s=5, cmap="viridis", vmin=0, vmax=max(vmax, 1e-12), rasterized=True)
        ax.set_xlabel("xyz"[i] + " [m]")
        ax.set_ylabel("xyz"[j] + " [m]")
        ax.set_aspect("equal", adjustable="datalim")
    cb = fig.colorbar(sc, ax=list(axes), shrink=0.85)
    cb.set_label(f"{label} position error [mm]")
    return fig


def correlation_figure(names: list[str], corr: np.ndarray):
    """Heatmap of a ``(k, k)`` correlation matrix among the parameters ``names`` (−1 … 1)."""
    plt = _plt()
    k = len(names)
    size = min(max(3.0 + 0.16 * k, 4.0), 9.0)
    fig, ax = plt.subplots(figsize=(size + 1.0, size))
    im = ax.imshow(np.asarray(corr, float), cmap="RdBu_r", vmin=-1, vmax=1, interpolation="nearest")
    fs = 8 if k <= 30 else 6
    ax.set_xticks(range(k))
    ax.set_yticks(range(k))
    ax.set_xticklabels(names, rotation=90, fontsize=fs)
    ax.set_yticklabels(names, fontsize=fs)
    cb = fig.colorbar(im, ax=ax, shrink=0.8)
    cb.set_label("correlation")
    fig.tight_layout()
    return fig
