"""Ray, imported lazily (hykin imports without it), and a session for one sweep or fleet run.

* :func:`import_ray` — the ``ray`` module, or ImportError (one line naming the ``distributed`` extra).
* :func:`ray_session` — context manager: joins ``address`` (a cluster) or starts a small local Ray
  (CPUs of this machine, no dashboard); reuses a session already started in this process and shuts
  down only what it started. A start that fails (a local Ray times out on a busy machine, a cluster
  that does not answer) is tried once more after :data:`RETRY_WAIT_S`; then :class:`RayStartError`,
  one line naming the cause and what to do.
"""

from __future__ import annotations

import contextlib
import os
import time

__all__ = ["RETRY_WAIT_S", "RayStartError", "import_ray", "ray_session"]

#: seconds between the two tries to start or join Ray (a busy machine's raylet often starts on the second)
RETRY_WAIT_S = 10.0


class RayStartError(RuntimeError):
    """Ray did not start (or the cluster did not answer) twice; ``str(e)`` is one line: the cause and what to do."""

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
        _init(ray, address, kw)
        started = True
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def _first_line(e: BaseException) -> str:
    msg = [m for m in str(e).strip().splitlines() if m.strip()]
    return f"{type(e).__name__}: {msg[0].strip()}" if msg else type(e).__name__


def _init(ray, address: str | None, kw: dict) -> None:
    """``ray.init``, tried twice :data:`RETRY_WAIT_S` apart (what a half-started Ray left is shut down
    between); :class:`RayStartError` when both fail."""
    for attempt in (1, 2):
        try:
            ray.init(address=address, **kw)
            return
        except Exception as e:  # noqa: BLE001 - Ray raises plain Exception, ConnectionError, TimeoutError, ...
            with contextlib.suppress(Exception):
                ray.shutdown()
            if attempt == 1:
                time.sleep(RETRY_WAIT_S)
                continue
            raise RayStartError(_start_failure(e, address, kw.get("num_cpus"))) from None


def _start_failure(e: BaseException, address: str | None, num_cpus) -> str:
    """The one line of a Ray that did not start twice: Ray's reason and what to do."""
    why = _first_line(e)
    tries = f"tried twice, {RETRY_WAIT_S:g} s apart"
    if address is not None:
        return (f"could not join the Ray cluster at --address {address} ({why}; {tries}): check that it runs "
                "(`ray status` on its head node) and the address, or leave out --address to start a local Ray")
    try:
        load = f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs"
    except (OSError, AttributeError):
        load = "its load"
    return (f"the local Ray did not start ({why}; {tries}): the machine may be too busy ({load}); run again when "
            f"it is quieter or with fewer --num-cpus (asked {num_cpus}), or start Ray once with `ray start --head` "
            "and pass --address auto")


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
