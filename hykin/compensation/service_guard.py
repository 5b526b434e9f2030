"""What keeps ``hykin serve`` answering when a client is slow, wrong or hostile.

* :class:`ServiceLimits` — every limit of the service (each one a ``hykin serve`` option).
* :class:`ModelWorker` — ONE thread runs every model call, streaming steps before HTTP batches,
  with at most ``queue`` calls waiting or running (a full queue is refused at once, not waited on).
* :func:`read_body` — a request body, refused by its ``Content-Length`` before it is read when it is
  over the limit (and cut off while it streams in when it has none).
* :func:`read_token_file`, :func:`token_ok` — the optional bearer token (constant-time compare).
* :func:`model_identity` — the model file's integrity hash and when it was loaded (``/health``).

Status codes: 401 (missing or wrong token), 413 (body over ``max_body_bytes``), 503 (queue full;
``Retry-After: 1``); WebSocket close codes: 1008 (wrong token, sent before the handshake completes,
so the client sees HTTP 403), 1009 (one message over ``max_message_bytes``).
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import itertools
import queue
import threading
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["BodyTooLarge", "ModelWorker", "QueueFull", "ServiceLimits", "model_identity", "read_body",
           "read_token_file", "token_ok"]

STREAM, BATCH = 0, 1  # ModelWorker priorities: lower runs first


@dataclass(frozen=True)
class ServiceLimits:
    """Limits of ``hykin serve`` (defaults in brackets; each is a CLI option).

    max_targets: rows in one HTTP request [10,000]. max_body_bytes: one HTTP body [4 MiB, enough for
    10,000 seven-number rows]. max_message_bytes: one WebSocket message [4 KiB: one target]. queue:
    model calls waiting or running at once, all clients together [64]. max_connections: open
    connections (HTTP and WebSocket) before new ones get 503 [64]. refusal_delay_s: every refused
    HTTP request is answered after this delay [0.1 s], so that a client sending bad requests as fast
    as it is answered sends at most ``max_connections / refusal_delay_s`` of them per second and
    leaves the event loop to the others (a waiting refusal costs a timer, not CPU); 0 answers at
    once. token: the bearer token, or None.
    """

    max_targets: int = 10_000
    max_body_bytes: int = 4 * 1024 * 1024
    max_message_bytes: int = 4096
    queue: int = 64
    max_connections: int = 64
    refusal_delay_s: float = 0.1
    token: str | None = None

    def __post_init__(self):
        for name in ("max_targets", "max_body_bytes", "max_message_bytes", "queue", "max_connections"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not 0 <= self.refusal_delay_s <= 60:
            raise ValueError(f"refusal_delay_s must be in [0, 60] s, got {self.refusal_delay_s!r}")


class QueueFull(RuntimeError):
    """The model queue holds ``ServiceLimits.queue`` calls already."""


class BodyTooLarge(ValueError):
    """A request body over ``ServiceLimits.max_body_bytes``."""


class ModelWorker:
    """One thread that runs every model call (the model is not re-entrant), lowest priority number
    first (:data:`STREAM` before :data:`BATCH`), then in arrival order.

    :meth:`submit` returns an awaitable for the call's result (or its exception) and raises
    :class:`QueueFull` when ``capacity`` calls are waiting or running: a flood is refused at once
    instead of growing a queue that delays everybody. :meth:`run` runs a short call at once in the
    caller's thread when the model is idle (no thread hand-over: the streaming path), else submits it.
    """

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self._q: queue.PriorityQueue = queue.PriorityQueue()
        self._order = itertools.count()
        self._count = 0
        self._lock = threading.Lock()
        self._model = threading.Lock()  # held while a call runs (on the thread or inline)
        self._thread = threading.Thread(target=self._run, name="hykin-model", daemon=True)
        self._thread.start()

    @property
    def pending(self) -> int:
        """Calls waiting or running now."""
        return self._count

    def submit(self, priority: int, fn, *args) -> asyncio.Future:
        """Queue ``fn(*args)``; an asyncio future of the running loop resolves with its result."""
        with self._lock:
            if self._count >= self.capacity:
                raise QueueFull(f"busy: {self._count} model calls queued (limit {self.capacity}); retry later")
            self._count += 1
        loop = asyncio.get_running_loop()
        fut = loop.create_future()
        self._q.put((priority, next(self._order), fn, args, loop, fut))
        return fut

    async def run(self, priority: int, fn, *args):
        """``fn(*args)`` now, in this thread, when nothing is queued or running; else :meth:`submit`."""
        if self._count == 0 and self._model.acquire(blocking=False):
            try:
                return fn(*args)
            finally:
                self._model.release()
        return await self.submit(priority, fn, *args)

    def close(self) -> None:
        """Stop the thread after the calls already queued."""
        self._q.put((99, next(self._order), None, (), None, None))

    def _run(self) -> None:
        while True:
            _, _, fn, args, loop, fut = self._q.get()
            if fn is None:
                return
            try:
                with self._model:
                    out, err = fn(*args), None
            except BaseException as e:  # noqa: BLE001 - handed to the awaiting request
                out, err = None, e
            with self._lock:
                self._count -= 1
            try:
                loop.call_soon_threadsafe(_settle, fut, out, err)
            except RuntimeError:  # the loop is closed (server shutting down)
                pass


def _settle(fut: asyncio.Future, out, err) -> None:
    if fut.cancelled():
        return
    if err is not None:
        fut.set_exception(err)
    else:
        fut.set_result(out)


async def read_body(request, limit: int) -> bytes:
    """The body of a Starlette ``request``; :class:`BodyTooLarge` when over ``limit`` bytes (by its
    ``Content-Length`` before reading anything, else while it streams in)."""
    cl = request.headers.get("content-length")
    if cl is not None:
        if not cl.strip().isdigit():
            raise ValueError(f"bad Content-Length header {cl!r}")
        if int(cl) > limit:
            raise BodyTooLarge(f"request body of {int(cl)} bytes, at most {limit} (hykin serve --max-body-kb)")
    chunks, n = [], 0
    async for chunk in request.stream():
        n += len(chunk)
        if n > limit:
            raise BodyTooLarge(f"request body over {limit} bytes (hykin serve --max-body-kb)")
        chunks.append(chunk)
    return b"".join(chunks)


def read_token_file(path: str | Path) -> str:
    """The bearer token in ``path``: its content without surrounding whitespace (ValueError when it is
    empty, holds whitespace or non-ASCII text, or cannot be read)."""
    p = Path(path)
    try:
        text = p.read_text(encoding="ascii")
    except (OSError, UnicodeDecodeError) as e:
        raise ValueError(f"{p}: cannot read the token file ({type(e).__name__}: {e})") from None
    tok = text.strip()
    if not tok:
        raise ValueError(f"{p}: the token file is empty")
    if any(c.isspace() or not c.isprintable() for c in tok):
        raise ValueError(f"{p}: the token must be one line of printable ASCII without spaces")
    return tok


def token_ok(headers, token: str | None) -> bool:
    """True when no token is set, or ``headers`` carry ``Authorization: Bearer <token>``."""
    if token is None:
        return True
    got = headers.get("authorization", "")
    scheme, _, value = got.partition(" ")
    return scheme.lower() == "bearer" and hmac.compare_digest(value.strip().encode(), token.encode())


def model_identity(path: str | Path | None) -> dict:
    """``/health``'s record of the model: ``model_sha256`` (the integrity hash stored in the model file,
    checked when it was loaded; None for files of hykin 0.1.0), ``file_sha256`` (of the file's bytes),
    ``loaded_at`` (UTC, ISO 8601) and ``model_path``. All None but ``loaded_at`` without a path."""
    now = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    if path is None:
        return {"model_path": None, "model_sha256": None, "file_sha256": None, "loaded_at": now}
    from ..io.modelfile import stored_content_hash

    p = Path(path)
    h = hashlib.sha256()
    with p.open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return {"model_path": str(p.resolve()), "model_sha256": stored_content_hash(p), "file_sha256": h.hexdigest(),
            "loaded_at": now}
