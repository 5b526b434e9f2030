"""Ray, imported lazily (hykin imports without it), and a session for one sweep or fleet run.

* :func:`import_ray` — the ``ray`` module, or ImportError (one line naming the ``distributed`` extra).
* :func:`ray_session` — context manager: joins ``address`` (a cluster) or starts a small local Ray
  (CPUs of this machine, no dashboard); reuses a session already started in this process and shuts
  down only what it started.
"""

from __future__ import annotations

import contextlib
import os

__all__ = ["import_ray", "ray_session"]

_MISSING = "Ray is not installed: pip install 'hykin[distributed]' (or pip install 'ray>=2.9')"


def import_ray():
    """``ray``; ImportError naming the extra when missing."""
    try:
        import ray
    except ImportError:
        raise ImportError(_MISSING) from None
    return ray


@contextlib.contextmanager
def ray_session(address: str | None = None, num_cpus: int | None = None):
    """A Ray session: ``address`` (e.g. ``"ray://head:10001"`` or ``"auto"``) joins a cluster; None
    starts a local one with ``num_cpus`` CPUs (default: this machine's). Yields ``ray``."""
    ray = import_ray()
    started = False
    if not ray.is_initialized():
        kw = dict(include_dashboard=False, log_to_driver=True, logging_level="warning")
        if address is None:
            kw["num_cpus"] = num_cpus or os.cpu_count() or 1
        ray.init(address=address, **kw)
        started = True
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def check_resources(ray, where: str, need: dict, address: str | None) -> None:
    """ValueError (one line) when a local Ray has fewer CPUs/GPUs than one trial needs (the trials would wait
    for them forever); ``need``: e.g. ``{"cpus_per_trial": 1, "gpus_per_trial": 0}``; ``where``: the
    file. A cluster (``address``) may add nodes, so it is not checked."""
    if address is not None:
        return
    have = ray.cluster_resources()
    for key, n in need.items():
        kind = "GPU" if key.startswith("gpus") else "CPU"
        if n > have.get(kind, 0):
            raise ValueError(f"{where}: [resources] {key} = {n:g} but this machine's Ray has {have.get(kind, 0):g} "
                             f"{kind}s (lower it, or join a cluster with --address)")
