"""Training recipes for the residual networks (DESIGN.md §1.1).

Loss: mean Euclidean norm of the remaining residual, ``mean_i ||y_i - net(q_i)||`` (position in m,
orientation as a rotation vector in rad). Early stopping on a validation set restores the best
weights. Training is deterministic for a given seed, device and thread count.

Recipes (:func:`get_recipe`):

* ``"paper"`` — Ojer et al. 2024: Adagrad, lr 0.005, batch 128, <= 300 epochs, early stopping on
  validation (patience 20 epochs), float32.
* ``"default"`` (ours) — AdamW (lr 3e-3, weight decay 0), batch 256, one-cycle schedule over the
  epoch budget of 200 (no early stop; the best validation epoch is kept), float32 (2-4x faster than
  float64 on CPU at no loss: residuals are stored scaled to O(1)). Optional full-batch L-BFGS polish
  (``lbfgs_steps``). Chosen by measurement: accuracy per CPU-minute (benchmarks/bench_hybrid.py).
  Small data sets (real robots: ~1000 measured poses) get smaller batches and more epochs:
  at least ``min_batches_per_epoch = 16`` batches per epoch (batch ``clip(ceil(N/16), 32, 256)``)
  and at least ``min_steps = 30000`` optimiser steps. With 256 x 200 epochs only 800 steps are taken
  on 900 samples, which underfits: 5-fold cross-validation on the UR5 grid (1000 real poses,
  benchmarks/bench_real.py) gives 0.0877 mm with batch 256 / 200 epochs, 0.0805 mm with batch 57 /
  200 epochs, 0.0796 mm with batch 57 / 400 epochs (calibration alone 0.0964 mm). Medium data sets
  underfit too: UR10 series A (9.5k real poses, held-out 20 %) gives 0.120 mm / 0.0247° with 6000
  steps (fit 34 s), 0.103 / 0.0189 with 14000, 0.090 / 0.0154 with 28000 (79 s), 0.080 / 0.0143
  with 56000 (158 s); rx160-nongeo (10k noisy) 1.44x the noise floor at 7200 steps, 1.30x at 14000,
  1.28x at 28000; the UR5 test error is unchanged (0.074-0.075 mm). 30000 is the default (about
  1.5 min for 10k samples on 2 cores); raise it (``recipe_kw={"min_steps": ...}``, ``hykin fit
  --min-steps``) when more CPU time is available. From ~100k samples on the 200 epochs exceed it.
  An explicit ``batch_size`` / ``max_epochs`` override in :func:`get_recipe` switches the
  corresponding rule off.
"""

from __future__ import annotations

import copy
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, replace

import numpy as np
import torch

from .nets import ResidualNet

__all__ = ["RECIPES", "Recipe", "TrainResult", "batch_and_epochs", "get_recipe", "train_net"]


@dataclass(frozen=True)
class Recipe:
    """A training recipe. ``dtype`` is "float32" or "float64"; ``schedule`` "none", "onecycle" or
    "cosine"; ``patience`` in epochs (0 = no early stopping, still keeps the best epoch);
    ``lbfgs_steps``: full-batch L-BFGS iterations after the first-order phase (0 = none);
    ``min_batches_per_epoch``: shrink the batch (not below 32) so an epoch has at least this many
    batches (0 = off); ``min_steps``: raise the epoch count so training takes at least this many
    optimiser steps (0 = off); ``threads``: torch CPU threads while training (0 = auto: 1 for nets
    under 1 M parameters, where per-operation overhead dominates and a second thread mostly adds
    synchronisation (3-5x slower on a busy 2-core machine, measured), else ``torch.get_num_threads()``)."""

    name: str
    optimizer: str = "adamw"
    lr: float = 3e-3
    weight_decay: float = 0.0
    batch_size: int = 256
    max_epochs: int = 300
    patience: int = 0
    schedule: str = "onecycle"
    dtype: str = "float64"
    lbfgs_steps: int = 0
    val_fraction: float = 0.1
    normalise: str = "data"
    threads: int = 0
    min_batches_per_epoch: int = 0
    min_steps: int = 0

    def to_dict(self) -> dict:
        return asdict(self)


RECIPES: dict[str, Recipe] = {
    "paper": Recipe(
        "paper", optimizer="adagrad", lr=0.005, batch_size=128, max_epochs=300, patience=20, schedule="none",
        dtype="float32",
    ),
    "default": Recipe(
        "default", optimizer="adamw", lr=3e-3, batch_size=256, max_epochs=200, patience=0, schedule="onecycle",
        dtype="float32", lbfgs_steps=0, min_batches_per_epoch=16, min_steps=30000,
    ),
}


def get_recipe(recipe: str | Recipe | dict, **overrides) -> Recipe:
    """Recipe by name (``"paper"``, ``"default"``), or a Recipe / dict, with field overrides.

    An explicit ``batch_size`` (``max_epochs``) override means exactly that batch size (epoch budget):
    it sets ``min_batches_per_epoch`` (``min_steps``) to 0 unless that is overridden too."""
    if isinstance(recipe, Recipe):
        r = recipe
    elif isinstance(recipe, dict):
        r = Recipe(**recipe)
    else:
        if recipe not in RECIPES:
            raise ValueError(f"unknown recipe {recipe!r}; choose from {', '.join(RECIPES)}")
        r = RECIPES[recipe]
    bad = set(overrides) - set(Recipe.__dataclass_fields__)
    if bad:
        raise ValueError(f"unknown recipe field(s) {sorted(bad)}")
    overrides = dict(overrides)
    if "batch_size" in overrides:
        overrides.setdefault("min_batches_per_epoch", 0)
    if "max_epochs" in overrides:
        overrides.setdefault("min_steps", 0)
    return replace(r, **overrides) if overrides else r


def batch_and_epochs(recipe: Recipe, n: int) -> tuple[int, int]:
    """Batch size and epoch budget that ``recipe`` uses on ``n`` training samples."""
    bs = min(recipe.batch_size, n)
    if recipe.min_batches_per_epoch > 0:
        bs = min(bs, max(32, math.ceil(n / recipe.min_batches_per_epoch)))
    bs = max(1, min(bs, n))
    epochs = recipe.max_epochs
    if recipe.min_steps > 0:
        epochs = max(epochs, math.ceil(recipe.min_steps / math.ceil(n / bs)))
    return bs, epochs


@dataclass
class TrainResult:
    """What happened in :func:`train_net`. Losses are mean residual norms in SI units."""

    epochs: int
    best_epoch: int
    best_val: float
    final_train: float
    seconds: float
    stopped: str
    history: list = field(default_factory=list)  # (epoch, train_loss, val_loss)
    steps: int = 0  # optimiser steps taken (first-order phase)
    planned_steps: int = 0  # the recipe's budget: epochs x batches per epoch

    def to_dict(self) -> dict:
        d = asdict(self)
        d["history"] = [list(h) for h in self.history]
        return d


def _dtype(name: str) -> torch.dtype:
    return {"float32": torch.float32, "float64": torch.float64}[name]


@torch.no_grad()
def _eval(net: ResidualNet, X, Y, batch: int = 65536) -> float:
    tot = 0.0
    for i in range(0, X.shape[0], batch):
        tot += float(torch.linalg.vector_norm(Y[i : i + batch] - net(X[i : i + batch]), dim=-1).sum())
    return tot / max(X.shape[0], 1)


def train_net(
    net: ResidualNet,
    q_train: np.ndarray,
    y_train: np.ndarray,
    q_val: np.ndarray | None,
    y_val: np.ndarray | None,
    recipe: Recipe,
    seed: int = 0,
    device: str = "cpu",
    max_seconds: float | None = None,
    callback: Callable[[int, int, float, float], None] | None = None,
) -> TrainResult:
    """Train ``net`` in place to map ``q`` ``(N, n)`` to residuals ``y`` ``(N, k)`` (SI units).

    Sets the net's output scaling from ``y_train`` (mean, RMS norm). The weights of the epoch with
    the lowest validation loss (training loss without validation data) are restored at the end.
    ``max_seconds`` stops training early (the best weights so far are kept).
    ``callback(step, total_steps, train_loss, val_loss)`` is called after each epoch (and every 16 steps
    within a longer one, with the epoch's running training loss and the last validation loss) with the
    optimiser steps taken so far and the recipe's budget of steps.
    Initial weights are the caller's: seed torch before :func:`hykin.hybrid.nets.make_net` for full
    reproducibility (:class:`hykin.hybrid.model.HybridModel` does).
    """
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError("device 'cuda' requested but torch.cuda.is_available() is False")
    t0 = time.perf_counter()
    dt = _dtype(recipe.dtype)
    torch.manual_seed(seed)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    prev_det = torch.are_deterministic_algorithms_enabled()
    prev_threads = torch.get_num_threads()
    n_params = sum(p.numel() for p in net.parameters())
    threads = recipe.threads or (1 if (n_params < 1_000_000 and device == "cpu") else prev_threads)
    torch.set_num_threads(threads)
    # Only CUDA has kernels that are not deterministic (atomics); on the CPU every kernel this loop
    # uses is, and setting the flag imports torch's compiler stack (1.6 s per process).
    deterministic = not device.startswith("cpu")
    if deterministic:
        torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        net.to(device=device, dtype=dt)
        X = torch.as_tensor(np.asarray(q_train), dtype=torch.float64, device=device)
        Y = torch.as_tensor(np.asarray(y_train), dtype=dt, device=device)
        if not torch.isfinite(X).all() or not torch.isfinite(Y).all():
            raise ValueError("train_net: training joints or residuals contain NaN/inf")
        bias = Y.mean(0)
        scale = torch.linalg.vector_norm(Y - bias, dim=-1).pow(2).mean().sqrt().clamp_min(1e-12)
        net.set_output_scale(bias, scale)
        has_val = q_val is not None and len(q_val) > 0
        if has_val:
            Xv = torch.as_tensor(np.asarray(q_val), dtype=torch.float64, device=device)
            Yv = torch.as_tensor(np.asarray(y_val), dtype=dt, device=device)
        # Losses are computed on the scaled output: (y - bias)/scale vs body(q).
        Ys = (Y - bias) / scale
        N = X.shape[0]
        bs, max_epochs = batch_and_epochs(recipe, N)
        steps_per_epoch = math.ceil(N / bs)
        params = list(net.parameters())
        if recipe.optimizer == "adagrad":
            opt = torch.optim.Adagrad(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
        elif recipe.optimizer == "adamw":
            opt = torch.optim.AdamW(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
        elif recipe.optimizer == "adam":
            opt = torch.optim.Adam(params, lr=recipe.lr, weight_decay=recipe.weight_decay)
        else:
            raise ValueError(f"unknown optimizer {recipe.optimizer!r}")
        total = max_epochs * steps_per_epoch
        if recipe.schedule == "onecycle":
            sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=recipe.lr, total_steps=total, pct_start=0.15)
        elif recipe.schedule == "cosine":
            sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=total, eta_min=recipe.lr * 1e-3)
        elif recipe.schedule == "none":
            sched = None
        else:
            raise ValueError(f"unknown schedule {recipe.schedule!r}")

        best_val, best_epoch, best_state = math.inf, -1, None
        history, stopped, bad = [], "max_epochs", 0
        epoch = steps = 0
        for epoch in range(1, max_epochs + 1):
            net.train()
            perm = torch.randperm(N, generator=gen).to(device)
            tot, seen = 0.0, 0
            for k in range(steps_per_epoch):
                idx = perm[k * bs : (k + 1) * bs]
                if idx.numel() < 2 and any(isinstance(m, torch.nn.BatchNorm1d) for m in net.modules()):
                    continue  # BatchNorm cannot train on a batch of one
                loss = torch.linalg.vector_norm(Ys[idx] - net.body_forward(X[idx]), dim=-1).mean()
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                steps += 1
                tot += float(loss.detach()) * idx.numel()
                seen += idx.numel()
                if callback is not None and steps % 16 == 0 and k < steps_per_epoch - 1:  # long epochs: progress within
                    callback(steps, total, tot / seen * float(scale), history[-1][2] if history else math.nan)
                if sched is not None:
                    sched.step()
            net.eval()
            train_loss = tot / N * float(scale)
            val_loss = _eval(net, Xv, Yv) if has_val else train_loss
            history.append((epoch, train_loss, val_loss))
            if callback is not None:
                callback(steps, total, train_loss, val_loss)
            if val_loss < best_val:
                best_val, best_epoch, bad = val_loss, epoch, 0
                best_state = copy.deepcopy(net.state_dict())
            else:
                bad += 1
            if recipe.patience and bad >= recipe.patience:
                stopped = "early_stopping"
                break
            if max_seconds is not None and time.perf_counter() - t0 > max_seconds:
                stopped = "max_seconds"
                break
        if recipe.lbfgs_steps > 0:
            net.eval()  # full-batch polish; BatchNorm statistics frozen
            lb = torch.optim.LBFGS(params, lr=1.0, max_iter=recipe.lbfgs_steps, history_size=50,
                                   line_search_fn="strong_wolfe", tolerance_grad=1e-12, tolerance_change=1e-15)

            def closure():
                lb.zero_grad(set_to_none=True)
                ls = torch.linalg.vector_norm(Ys - net.body_forward(X), dim=-1).mean()
                ls.backward()
                return ls

            lb.step(closure)
            val_loss = _eval(net, Xv, Yv) if has_val else _eval(net, X, Y)
            history.append((epoch + 1, _eval(net, X, Y), val_loss))
            if val_loss < best_val:
                best_val, best_epoch = val_loss, epoch + 1
                best_state = copy.deepcopy(net.state_dict())
        if best_state is not None:
            net.load_state_dict(best_state)
        net.eval()
        final_train = _eval(net, X, Y)
    finally:
        if deterministic:
            torch.use_deterministic_algorithms(prev_det)
        torch.set_num_threads(prev_threads)
    return TrainResult(
        epochs=epoch, best_epoch=best_epoch, best_val=float(best_val), final_train=final_train,
        seconds=time.perf_counter() - t0, stopped=stopped, history=history, steps=steps, planned_steps=total,
    )
