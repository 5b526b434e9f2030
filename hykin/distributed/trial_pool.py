"""Sweep trials on long-lived Ray actors: one worker process per trial slot, reused for every trial.

Each :class:`TrialWorker` actor holds ``cpus``/``gpus`` of Ray's resources (on any node of the
cluster), imports torch + hykin's fit path once and reads the datasets from Ray's object store once
(one ``ray.put`` on the driver; a reference, not a copy per trial). :func:`run_trials` hands the
trials out to the free workers as they finish (``ray.wait``), so the wall time is about
``sum(trial times) / workers`` plus one worker start.

Failures: a trial that raises is returned as an ``error`` row and run once more; a worker process
that dies (killed, out of memory, node lost) is replaced by a new worker and its trial run once more. After two failed attempts the trial is recorded with its error; the others go on.

Why not Ray Tune's trial runner: measured on this 2-core machine (same load, 8 trials that only import
torch + hykin), Tune took 41 s where these actors took 18-19 s: Tune imports ``ray.tune`` in the driver and in
every worker, creates a placement group per trial and waits on its function thread at each actor reuse.
hykin needs none of Tune's search or schedulers: the grid, the random draws, the records and ``--resume``
are hykin's own (:mod:`hykin.distributed.sweep`).
"""

from __future__ import annotations

import collections
import time

from .trials import run_trial

__all__ = ["TrialWorker", "first_line", "run_trials", "n_workers"]


def first_line(e: BaseException) -> str:
    """``Type: first line of the message`` (the innermost one for Ray's wrapped task errors)."""
    cause = getattr(e, "cause", None)
    if isinstance(cause, BaseException):
        e = cause
    msg = [m for m in str(e).strip().splitlines() if m.strip()]
    return f"{type(e).__name__}: {msg[0].strip()}" if msg else type(e).__name__


class TrialWorker:
    """One trial slot (a Ray actor): the datasets and hykin's fit path loaded once, then trials.

    ``data``: ``[ObjectRef]`` of ``(robot, train, test)``; ``threads``: torch/numba threads per trial."""

    def __init__(self, data: list, subsample_seed: int = 0, threads: int = 1):
        import ray

        t0 = time.perf_counter()
        import torch  # noqa: F401 - once per worker (timed: the first trial's import_s)

        from ..evaluation import evaluate  # noqa: F401
        from ..hybrid import model  # noqa: F401

        t1 = time.perf_counter()
        self.robot, self.train, self.test = ray.get(data[0])
        self.subsample_seed, self.threads = subsample_seed, threads
        self.start = {"import_s": t1 - t0, "transfer_s": time.perf_counter() - t1}

    def run(self, options: dict) -> dict:
        """One trial -> ``{"status": "ok", **row}`` or ``{"status": "error", "error": one line}``; the row's
        ``timing`` (s): ``t_enter`` (unix), ``import_s`` / ``transfer_s`` (this worker's start, on its
        first trial only), ``run_s`` / ``cpu_s`` (wall / CPU seconds of the trial), ``proc_cpu_s`` (CPU seconds of this worker
        process so far), ``pid``, ``node`` (Ray node id)."""
        import os

        import ray

        t_enter, t0, c0 = time.time(), time.perf_counter(), time.process_time()
        try:
            row = {"status": "ok", "error": "", **run_trial(self.robot, self.train, self.test, options,
                                                            self.subsample_seed, threads=self.threads)}
        except Exception as e:  # noqa: BLE001 - recorded by the driver, retried once
            row = {"status": "error", "error": first_line(e)}
        start, self.start = self.start, {"import_s": 0.0, "transfer_s": 0.0}
        row["timing"] = {"t_enter": t_enter, **start, "run_s": time.perf_counter() - t0,
                         "cpu_s": time.process_time() - c0, "proc_cpu_s": time.process_time(), "pid": os.getpid(),
                         "node": ray.get_runtime_context().get_node_id()}
        return row


def n_workers(ray, n_trials: int, cpus: float, gpus: float) -> int:
    """Trial slots: as many as the Ray cluster's CPUs and GPUs hold now (at least 1, at most ``n_trials``;
    trials that ask for no CPU: one slot per CPU)."""
    have = ray.cluster_resources()
    n = min(n_trials, int(have.get("CPU", 0) // cpus) if cpus > 0 else int(have.get("CPU", 1)))
    if gpus > 0:
        n = min(n, int(have.get("GPU", 0) // gpus))
    return max(1, n)


def run_trials(ray, trials: dict, data: tuple, cpus: float, gpus: float, subsample_seed: int, on_done,
               attempts: int = 2) -> None:
    """Run ``trials`` (index -> options) on :func:`n_workers` :class:`TrialWorker` actors; each trial up
    to ``attempts`` times while it fails. ``on_done(index, row)`` is called in the driver as each
    finishes (``row["attempts"]``, and ``timing`` with ``t_launch`` / ``t_done``, unix s)."""
    if not trials:
        return
    ref = [ray.put(data)]  # once: every worker reads it by reference
    actor = ray.remote(TrialWorker).options(num_cpus=cpus, num_gpus=gpus, max_restarts=0, max_task_retries=0)

    def new_worker():
        return actor.remote(ref, subsample_seed, max(1, round(cpus)))

    workers = [new_worker() for _ in range(n_workers(ray, len(trials), cpus, gpus))]
    queue = collections.deque((i, 1) for i in trials)
    free, pending = list(workers), {}
    try:
        while queue or pending:
            while queue and free:
                w, (i, att) = free.pop(), queue.popleft()
                pending[w.run.remote(trials[i])] = (w, i, att, time.time())
            (done,), _ = ray.wait(list(pending), num_returns=1)
            w, i, att, t_launch = pending.pop(done)
            try:
                row = ray.get(done)
            except Exception as e:  # noqa: BLE001 - the worker died: a failed attempt; a new worker in its place
                row = {"status": "error", "error": f"worker died: {first_line(e)}"}
                ray.kill(w)
                workers[workers.index(w)] = w = new_worker()  # its calls wait until it has started
            free.append(w)
            if row["status"] != "ok" and att < attempts:
                queue.appendleft((i, att + 1))
                continue
            row["attempts"] = att
            row.setdefault("timing", {}).update(t_launch=t_launch, t_done=time.time())
            on_done(i, row)
    finally:
        for w in workers:
            ray.kill(w)
