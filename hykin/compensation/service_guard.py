"""What keeps ``hykin serve`` answering when a client is slow, wrong or hostile.

* :class:`ServiceLimits` — every limit of the service (each one a ``hykin serve`` option).
* :class:`ModelWorker` — ONE thread runs every model call, streaming steps before HTTP batches,
  with at most ``queue`` batches waiting or running (a full queue is refused at once, not waited on).
  Streaming steps are not counted against ``queue``: each stream has at most one step in flight, so
  they are bounded by ``max_connections``, and batches can never crowd a stream out.
* :func:`read_body` — a request body, refused by its ``Content-Length`` before it is read when it is
  over the limit (and cut off while it streams in when it has none), and refused when it has not
  arrived within ``body_timeout_s``.
* :func:`read_token_file`, :func:`token_ok` — the optional bearer token (constant-time compare).
* :func:`load_served_model`, :func:`model_identity` — the model, loaded from the very bytes whose
  hashes ``/health`` reports, and when it was loaded.

Status codes: 401 (missing or wrong token), 408 (body not received within ``body_timeout_s``),
413 (body over ``max_body_bytes``), 503 (queue full; ``Retry-After: 1``); WebSocket close codes:
1008 (wrong token, sent before the handshake completes, so the client sees HTTP 403), 1009 (one
message over ``max_message_bytes``).
"""

from __future__ import annotations

import asyncio
import hashlib
import hmac
import itertools
import json
import queue
import tempfile
import threading
import warnings
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["BodyTimeout", "BodyTooLarge", "ModelWorker", "QueueFull", "ServiceLimits", "load_served_model",
           "model_identity", "read_body", "read_token_file", "token_ok"]

STREAM, BATCH = 0, 1  # ModelWorker priorities: lower runs first


@dataclass(frozen=True)
class ServiceLimits:
    """Limits of ``hykin serve`` (defaults in brackets; each is a CLI option).

    max_targets: rows in one HTTP request [10,000]. max_body_bytes: one HTTP body [4 MiB, enough for
    10,000 seven-number rows]. max_message_bytes: one WebSocket message [4 KiB: one target]. queue:
    HTTP batches waiting or running at once, all clients together [64] (streamed targets are not
    counted: see :class:`ModelWorker`). max_connections: requests and streams in progress (HTTP and
    WebSocket) before new ones get 503 [64]. refusal_delay_s: every refused HTTP request is answered
    after this delay [0.1 s], so that a client sending bad requests as fast as it is answered sends
    at most ``max_connections / refusal_delay_s`` of them per second and leaves the event loop to the
    others (a waiting refusal costs a timer, not CPU); 0 answers at once. token: the bearer token,
    or None. header_timeout_s: a connection that has not sent a complete request header this long
    after it opened (or after the first byte of its next request) is closed [5 s]
    (:mod:`.service_protocol`). body_timeout_s, body_min_rate_kib_s: a request body not received in
    full within ``body_timeout_s`` after its header, plus one second for every ``body_min_rate_kib_s``
    KiB that did arrive, is refused with 408 and its connection closed [10 s, 64 KiB/s]: a body that
    keeps coming at that rate or faster is never cut off (a 2.7 MB request over a 1.2 Mbit/s link
    takes 18 s), one dribbled in is (a client sending at exactly the minimum rate holds its slot for
    at most ``body_timeout_s + max_body_bytes / rate``, 74 s at the defaults); None: a total deadline
    of ``body_timeout_s``.
    send_timeout_s, send_min_rate_kib_s: a connection whose answer waits for the client to read it (its
    write buffer over 64 KiB) is aborted after ``send_timeout_s`` plus one second per
    ``send_min_rate_kib_s`` KiB that the client took meanwhile [10 s, 16 KiB/s]: a client reading at
    that rate or faster gets every answer (:mod:`.service_protocol`).
    max_step_deg: a streamed answer whose joints move more than this (deg, any revolute joint) from
    the ``q`` the message gave is refused with a reason [None: no limit].
    """

    max_targets: int = 10_000
    max_body_bytes: int = 4 * 1024 * 1024
    max_message_bytes: int = 4096
    queue: int = 64
    max_connections: int = 64
    refusal_delay_s: float = 0.1
    token: str | None = None
    header_timeout_s: float = 5.0
    body_timeout_s: float = 10.0
    body_min_rate_kib_s: float | None = 64.0
    send_timeout_s: float = 10.0
    send_min_rate_kib_s: float = 16.0
    max_step_deg: float | None = None

    def __post_init__(self):
        for name in ("max_targets", "max_body_bytes", "max_message_bytes", "queue", "max_connections"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not 0 <= self.refusal_delay_s <= 60:
            raise ValueError(f"refusal_delay_s must be in [0, 60] s, got {self.refusal_delay_s!r}")
        for name in ("header_timeout_s", "body_timeout_s", "send_timeout_s"):
            v = getattr(self, name)
            if not 0 < v <= 3600:
                raise ValueError(f"{name} must be in (0, 3600] s, got {v!r}")
        if not 0 < self.send_min_rate_kib_s <= 1e6:
            raise ValueError(f"send_min_rate_kib_s must be in (0, 1e6] KiB/s, got {self.send_min_rate_kib_s!r}")
        if self.body_min_rate_kib_s is not None and not 0 < self.body_min_rate_kib_s <= 1e6:
            raise ValueError(f"body_min_rate_kib_s must be in (0, 1e6] KiB/s or None, got {self.body_min_rate_kib_s!r}")
        if self.max_step_deg is not None and not 0 < self.max_step_deg <= 360:
            raise ValueError(f"max_step_deg must be in (0, 360] deg or None, got {self.max_step_deg!r}")

    @property
    def max_waiting(self) -> int:
        """Connections that hold no request (not yet a complete header, or idle between keep-alive
        requests) kept at once; one more closes the oldest of them (:mod:`.service_protocol`)."""
        return 2 * self.max_connections + 16


class QueueFull(RuntimeError):
    """The model queue holds ``ServiceLimits.queue`` batches already."""


class BodyTooLarge(ValueError):
    """A request body over ``ServiceLimits.max_body_bytes``."""


class BodyTimeout(ValueError):
    """A request body not received within ``ServiceLimits.body_timeout_s``."""


class ModelWorker:
    """One thread that runs every model call (the model is not re-entrant), lowest priority number
    first (:data:`STREAM` before :data:`BATCH`), then in arrival order.

    :meth:`submit` returns an awaitable for the call's result (or its exception) and raises
    :class:`QueueFull` when ``capacity`` batches are waiting or running: a flood is refused at once
    instead of growing a queue that delays everybody. :data:`STREAM` calls are never refused: each
    stream awaits its step before it reads its next message, so they are at most one per open stream,
    and a queue full of batches must not turn a streamed target into a "busy" reply (probe AR, C3).
    :meth:`run` runs a short call at once in the caller's thread when the model is idle (no thread
    hand-over: the streaming path), else submits it.
    """

    def __init__(self, capacity: int):
        self.capacity = int(capacity)
        self._q: queue.PriorityQueue = queue.PriorityQueue()
        self._order = itertools.count()
        self._count = 0  # calls waiting or running, streamed ones too
        self._batches = 0  # of which not STREAM: what ``capacity`` bounds
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
        batch = priority != STREAM
        with self._lock:
            if batch and self._batches >= self.capacity:
                raise QueueFull(f"busy: {self._batches} requests queued for the model (limit {self.capacity}, "
                                "hykin serve --queue); retry later")
            self._count += 1
            self._batches += batch
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
            priority, _, fn, args, loop, fut = self._q.get()
            if fn is None:
                return
            try:
                with self._model:
                    out, err = fn(*args), None
            except BaseException as e:  # noqa: BLE001 - handed to the awaiting request
                out, err = None, e
            with self._lock:
                self._count -= 1
                self._batches -= priority != STREAM
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


async def read_body(request, limit: int, timeout_s: float | None = None, min_rate_kib_s: float | None = None) -> bytes:
    """The body of a Starlette ``request``; :class:`BodyTooLarge` when over ``limit`` bytes (by its
    ``Content-Length`` before reading anything, else while it streams in); :class:`BodyTimeout` when
    it has not arrived in full within ``timeout_s`` seconds (None: no limit) plus one second per
    ``min_rate_kib_s`` KiB received (None: a total deadline) (:class:`ServiceLimits`)."""
    cl = request.headers.get("content-length")
    if cl is not None:
        if not cl.strip().isdigit():
            raise ValueError(f"bad Content-Length header {cl!r}")
        if int(cl) > limit:
            raise BodyTooLarge(f"request body of {int(cl)} bytes, at most {limit} (hykin serve --max-body-kb)")
    got = [0]

    async def read(stream, extend=None) -> bytes:
        chunks = []
        async for chunk in stream:
            got[0] += len(chunk)
            if got[0] > limit:
                raise BodyTooLarge(f"request body over {limit} bytes (hykin serve --max-body-kb)")
            chunks.append(chunk)
            if extend is not None:
                extend()
        return b"".join(chunks)

    if timeout_s is None:
        return await read(request.stream())
    loop = asyncio.get_running_loop()
    start = loop.time()
    per_byte = 0.0 if min_rate_kib_s is None else 1.0 / (1024.0 * min_rate_kib_s)

    def deadline() -> float:  # loop time
        return start + timeout_s + got[0] * per_byte

    try:  # a client dribbling its body would hold its --max-connections slot for ever (probe AR, C2)
        if hasattr(asyncio, "timeout"):  # Python >= 3.11: no extra task per request
            async with asyncio.timeout(timeout_s) as cm:
                return await read(request.stream(), None if not per_byte else lambda: cm.reschedule(deadline()))
        return await read(_within(request.stream(), deadline))
    except (asyncio.TimeoutError, TimeoutError):
        rate = "" if not per_byte else f" and 1 s more per {min_rate_kib_s:g} KiB received"
        raise BodyTimeout(f"request body not received within {timeout_s:g} s{rate} ({got[0]} of "
                          f"{cl if cl is not None else '?'} bytes arrived; hykin serve --body-timeout-s, "
                          "--body-min-rate-kib-s)") from None


async def _within(stream, deadline):
    """The chunks of ``stream``, each awaited until ``deadline()`` (loop time, asked again for each):
    :func:`read_body`'s deadline on Python 3.10, which has no ``asyncio.timeout``."""
    loop = asyncio.get_running_loop()
    it = stream.__aiter__()
    while True:
        try:
            chunk = await asyncio.wait_for(it.__anext__(), max(0.0, deadline() - loop.time()))
        except StopAsyncIteration:
            return
        yield chunk


def read_token_file(path: str | Path) -> str:
    """The bearer token in ``path``: its content without surrounding whitespace (ValueError when it is
    empty, holds whitespace or non-ASCII text, or cannot be read)."""
    p = Path(path)
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise ValueError(f"{p}: cannot read the token file ({e.strerror or e})") from None
    if raw.startswith(b"\xef\xbb\xbf"):  # a UTF-8 byte-order mark (Windows editors): not part of the token
        raw = raw[3:]
    try:
        text = raw.decode("ascii")
    except UnicodeDecodeError:
        raise ValueError(f"{p}: cannot read the token: it must be one line of printable ASCII without spaces (the "
                         "file holds other bytes)") from None
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


def _stored_hash(raw: bytes, where) -> str | None:
    """The ``content_sha256`` in the safetensors header of the model file bytes ``raw`` (None when the
    file carries none); :class:`hykin.io.modelfile.ModelFileError` when ``raw`` is not safetensors."""
    from ..io.modelfile import ModelFileError

    n = int.from_bytes(raw[:8], "little") if len(raw) >= 8 else 0
    try:
        if not 0 < n <= len(raw) - 8:
            raise ValueError(f"header length {n} in a file of {len(raw)} bytes")
        md = json.loads(raw[8:8 + n]).get("__metadata__") or {}
    except (ValueError, AttributeError, UnicodeDecodeError) as e:
        raise ModelFileError(f"{where}: not a hykin model file, or a truncated or corrupt copy of one (not readable as "
                             f"safetensors: {e})") from None
    return md.get("content_sha256")


def model_identity(path: str | Path | None, raw: bytes | None = None) -> dict:
    """``/health``'s record of the model: ``model_sha256`` (the integrity hash stored in the model file,
    checked when it was loaded; None for files of hykin 0.1.0), ``file_sha256`` (of the file's bytes),
    ``loaded_at`` (UTC, ISO 8601) and ``model_path``. All None but ``loaded_at`` without a path.

    ``raw``: the file's bytes as they were loaded (:func:`load_served_model`); without them the file is
    read, once, and both hashes come from that one read."""
    now = datetime.now(timezone.utc).isoformat(timespec="milliseconds")
    if path is None:
        return {"model_path": None, "model_sha256": None, "file_sha256": None, "loaded_at": now}
    p = Path(path)
    if raw is None:
        raw = p.read_bytes()
    return {"model_path": str(p.resolve()), "model_sha256": _stored_hash(raw, p),
            "file_sha256": hashlib.sha256(raw).hexdigest(), "loaded_at": now}


def load_served_model(path: str | Path):
    """``(model, identity)``: the hybrid model in the file ``path`` and its :func:`model_identity`, both
    from ONE read of the file. A file replaced between loading and hashing (a deploy script renaming a
    new model over it) made ``/health`` report a model the service was not running (probe AR, A1).

    The bytes are loaded through a private copy, so that every check of
    :meth:`hykin.hybrid.model.HybridModel.load` applies; its errors and warnings name ``path``.
    :class:`hykin.io.modelfile.ModelFileError` when the file is missing, unreadable or not a model."""
    from ..hybrid.model import HybridModel
    from ..io.modelfile import ModelFileError, looks_like_model_file

    p = Path(path)
    try:
        raw = p.read_bytes()
    except FileNotFoundError:
        raise ModelFileError(f"{p}: no such model file") from None
    except OSError as e:
        raise ModelFileError(f"{p}: cannot read the model file ({e.strerror or e})") from None
    with tempfile.TemporaryDirectory(prefix="hykin-serve-") as d:
        copy = Path(d) / (p.name or "model.hykin")
        copy.write_bytes(raw)
        if not looks_like_model_file(copy):
            got = f"a {p.suffix} file" if p.suffix else "another kind of file"
            raise ModelFileError(f"{p}: expected a hykin model file (written by `hykin fit`), got {got}")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                model = HybridModel.load(copy)
            except ModelFileError as e:
                raise ModelFileError(str(e).replace(str(copy), str(p))) from None
    for w in caught:  # e.g. a model file without an integrity hash: said once, naming the served file
        warnings.warn(str(w.message).replace(str(copy), str(p)), w.category, stacklevel=2)
    return model, model_identity(p, raw)
