"""The one trial: ``HybridModel(robot, **model_kwargs(options)).fit(train)`` + evaluation on the test set.

The same mapping of options to settings as `hykin fit` (:func:`hykin.hybrid.fit_options.model_kwargs`),
so a trial and `hykin fit` with the same options, data and seed give the same model.

* :func:`nested_subset` — the first ``n`` rows of one fixed permutation (``n_train``: nested subsets).
* :func:`fit_model` — the fitted model for ``options`` (the `hykin fit` path).
* :func:`error_columns` — ``{nominal,calibrated,hybrid}_{pos_mean_mm,pos_p95_mm,ang_mean_deg}`` of an evaluation.
* :func:`evaluate_noted` — the evaluation, with its out-of-range warnings as one line for the row.
* :func:`trial_threads` — context manager: torch and numba use ``n`` threads (one per CPU of the trial).
* :func:`run_trial` — one sweep trial -> one results row (raises on failure; the driver records it).
"""

from __future__ import annotations

import contextlib
import math
import time

import numpy as np

__all__ = ["ERROR_COLUMNS", "error_columns", "evaluate_noted", "fit_model", "gpu_fit_options", "nested_subset", "run_trial", "training_steps",
           "trial_threads"]

#: error columns of a results/summary row, in order (mm, deg; NaN where a row does not apply).
ERROR_COLUMNS = tuple(f"{m}_{s}" for m in ("nominal", "calibrated", "hybrid")
                      for s in ("pos_mean_mm", "pos_p95_mm", "ang_mean_deg"))


def nested_subset(n_total: int, n: int, seed: int) -> np.ndarray:
    """Row indices of a training subset of size ``n``: the first ``n`` of one permutation of
    ``n_total`` rows drawn with ``seed`` (so smaller subsets are inside larger ones), sorted."""
    if not 1 <= n <= n_total:
        raise ValueError(f"n_train = {n} must be between 1 and the {n_total} training rows")
    return np.sort(np.random.default_rng(seed).permutation(n_total)[:n])


def gpu_fit_options(options: dict, gpus: float) -> dict:
    """``options`` with ``device = "cuda"`` added when the trial / robot is given GPUs (``gpus > 0``) and
    its options name no device: resources per trial mean the fits should use them."""
    return {"device": "cuda", **options} if gpus > 0 else options


def fit_model(robot, train, options: dict, progress: bool = False):
    """``HybridModel(robot, **model_kwargs(**options)).fit(train)``: the `hykin fit` path (``options``:
    fit option names of :data:`hykin.hybrid.fit_options.FIT_OPTIONS`)."""
    from ..hybrid.fit_options import model_kwargs
    from ..hybrid.model import HybridModel
    from ..io.plausibility import check_fit_size

    check_fit_size(robot, train)
    return HybridModel(robot, **model_kwargs(**options)).fit(train, None, progress=progress)


def error_columns(res) -> dict:
    """The :data:`ERROR_COLUMNS` of an :class:`hykin.evaluation.evaluate.EvalResult`."""
    out = {}
    for m in ("nominal", "calibrated", "hybrid"):
        s = res.stats.get(m)
        out[f"{m}_pos_mean_mm"] = float("nan") if s is None else s.pos_mean_mm
        out[f"{m}_pos_p95_mm"] = float("nan") if s is None else s.pos_p95_mm
        out[f"{m}_ang_mean_deg"] = float("nan") if s is None or s.ang_mean_deg is None else s.ang_mean_deg
    return out


def evaluate_noted(model, test):
    """``(evaluate_model(model, test), note)``: the evaluation, and its out-of-range warnings (test poses
    outside what the networks were trained on) as one line for the results row instead of a warning in
    the sweep's log from every worker (``""`` when none); other warnings pass on as they are."""
    import warnings

    from ..evaluation.evaluate import evaluate_model
    from ..hybrid.errors import OutOfRangeWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = evaluate_model(model, test)
    notes = []
    for w in caught:
        if issubclass(w.category, OutOfRangeWarning):
            notes.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return res, "; ".join(dict.fromkeys(notes))


def training_steps(model) -> tuple[int, int]:
    """(optimiser steps, epochs) of the position network of a fitted ``model``."""
    from ..hybrid.train import batch_and_epochs

    meta = model.metadata
    epochs = int(meta["train_results"]["pos"]["epochs"])
    bs, _ = batch_and_epochs(model.recipe_, int(meta["n_train"]))
    return epochs * math.ceil(int(meta["n_train"]) / bs), epochs


@contextlib.contextmanager
def trial_threads(n: int | None):
    """Within the block torch, numba's parallel kernels and BLAS (numpy's and scipy's, through
    ``threadpoolctl``) use ``n`` threads (``None``: unchanged), then the previous counts: a trial with
    ``n`` CPUs uses ``n`` threads, in a Ray worker and in one process (where BLAS would otherwise use
    every core: a one-CPU trial's calibration then ran on two)."""
    if n is None:
        yield
        return
    import numba
    import torch
    from threadpoolctl import threadpool_limits

    n = max(1, int(n))
    prev = torch.get_num_threads(), numba.get_num_threads()
    torch.set_num_threads(n)
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    try:
        with threadpool_limits(limits=n, user_api="blas"):
            yield
    finally:
        torch.set_num_threads(prev[0])
        numba.set_num_threads(prev[1])


def run_trial(robot, train, test, options: dict, subsample_seed: int = 0, threads: int | None = None) -> dict:
    """One sweep trial: fit on ``train`` (its nested subset of ``options["n_train"]`` rows when given)
    and evaluate on ``test``, with ``threads`` torch/numba threads (:func:`trial_threads`). Returns the
    row: ``n_train`` (rows used), :data:`ERROR_COLUMNS`, ``fit_s`` and ``eval_s`` (wall seconds of the
    fit and the evaluation), ``steps``, ``epochs``, ``test_note`` (:func:`evaluate_noted`). Exceptions
    propagate."""
    opts = dict(options)
    n = opts.pop("n_train", None)
    tr = train if n is None else train.subset(nested_subset(len(train), int(n), subsample_seed))
    with trial_threads(threads):
        t0 = time.perf_counter()
        model = fit_model(robot, tr, opts)
        fit_s = time.perf_counter() - t0
        steps, epochs = training_steps(model)
        res, note = evaluate_noted(model, test)
        ev = error_columns(res)
        eval_s = time.perf_counter() - t0 - fit_s
    return {"n_train": len(tr), **ev, "fit_s": fit_s, "eval_s": eval_s, "steps": steps, "epochs": epochs,
            "test_note": note}
