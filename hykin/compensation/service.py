"""The compensation service of ``hykin serve``: fk, ik and compensate over HTTP (JSON batches) and
a WebSocket stream of single targets. The model is loaded once; ONE warm compensator answers all.

Endpoints (SI units: m, rad; poses as ``[x, y, z, qw, qx, qy, qz]``):

* ``GET /health`` (no token needed) → ``status``, ``model`` (robot name), ``dof``, ``version``,
  ``model_sha256`` (the model file's integrity hash, checked at load), ``file_sha256``,
  ``model_path``, ``loaded_at`` (UTC ISO 8601), ``queued`` (model calls waiting or running),
  ``counts`` (requests answered and refused, by kind).
* ``POST /fk`` ``{"q": [[q1..qn], ...]}`` → ``{"poses": [...], "in_support": [...]}``
* ``POST /ik`` ``{"targets": [[x,y,z,qw,qx,qy,qz] or [x,y,z], ...], "q_current": [[..]] or [..]}`` →
  per target the hybrid-IK solution nearest ``q_current`` (default zero): ``q`` (null when
  unreachable), ``success``, ``pos_err_mm``, ``ang_err_deg``, ``reason`` (the CLI's), ``in_support``,
  ``support_distance``, ``outside_support`` and a ``warning`` when targets lie outside the training support.
* ``POST /compensate`` ``{"targets": ..., "q_current": optional, "frame": "measurement"|"base"|"auto"}``
  → ``commands`` (controller base frame, null when unreachable), ``q``, ``success``, ``pos_err_mm``,
  ``ang_err_deg``, ``shift_mm``, ``status``, ``frame``, and the support fields of ``/ik``.
* Joints (``q``, ``q_current``) get the CLI's checks (degrees passed as radians, joint limits) and
  targets a unit check (over 50 reaches from the base: millimetres): 422 naming field, row, column.
* ``WebSocket /stream[?frame=...]``: one JSON message per target,
  ``{"target": [x,y,z,qw,qx,qy,qz], "q": [..joints..], "id": any}`` (``q``: the robot's current
  joints, which choose the branch; optional after the first answered target, then the last answer's
  joints are used). One reply per message, in order: ``seq`` (1, 2, ... per connection), ``id``
  (echoed), then ``success``, ``command``, ``q``, ``pos_err_mm``, ``ang_err_deg``, ``reason`` — or
  ``error`` (a one-line reason) when the message was not a valid target. A bad message never closes
  the stream, and a streamed target is never refused for a queue full of batches. With
  ``max_step_deg`` an answer whose joints move further than that from the message's ``q`` is refused
  (``success`` false, ``reason`` naming the joint).
* No ``/docs``, ``/redoc`` or ``/openapi.json``: they would answer without the token, load Swagger UI
  from a CDN and show an empty schema; this docstring and docs/serve.md describe the endpoints.

Refusals (:mod:`.service_guard`; limits in :class:`~hykin.compensation.service_guard.ServiceLimits`):
400 malformed JSON or header, 401 missing/wrong bearer token (``WWW-Authenticate: Bearer``), 408 body
not received within ``body_timeout_s`` (the connection is closed), 413 body over the size limit
(refused from its ``Content-Length`` before it is read; the connection is closed), 422 wrong
fields/shapes/values, 503 the batch queue is full (``Retry-After: 1``) or more than
``max_connections`` requests and streams in progress (:class:`ConnectionLimit`, ``Retry-After: 1``,
counted as ``refused_connections``). Every HTTP refusal is a JSON ``{"detail": reason}`` answered
after ``refusal_delay_s`` (0.1 s): a client flooding bad requests is slowed to ``max_connections /
refusal_delay_s`` requests/s. WebSocket: the handshake is refused with 403 and a JSON reason on a
wrong token or ``frame`` parameter; a message over the size limit closes the stream with 1009. Before
a request: a connection that sends no complete header within ``header_timeout_s`` is closed, and
connections without a request are capped (:mod:`.service_protocol`). Checks run on the event loop and
never wait for the model. Model calls run on one thread, streaming steps before queued batches; a
streaming step runs at once on the event loop when the model is idle.

(No ``from __future__ import annotations``: FastAPI reads the endpoints' ``Request`` annotations at
run time, and ``Request`` is imported inside :func:`create_app`.)
"""

import asyncio
import collections
import contextlib
import gc
import json
import logging

import numpy as np
import orjson

from .service_guard import (BATCH, STREAM, BodyTimeout, BodyTooLarge, ModelWorker, QueueFull, ServiceLimits, model_identity,
                            read_body, token_ok)
from .service_requests import Handlers, RequestError

__all__ = ["MAX_TARGETS", "ConnectionLimit", "RequestError", "create_app", "serve", "uvicorn_config"]

MAX_TARGETS = ServiceLimits.max_targets
_INLINE_BYTES = 64 * 1024  # bodies up to this size are parsed on the event loop, larger ones in a thread
_log = logging.getLogger("hykin.serve")


def _dumps(obj) -> bytes:
    """JSON bytes (orjson: a 100-target answer in 0.05 ms against the standard library's 1.7 ms, which
    was a quarter of the request's time; floats in the same shortest form)."""
    return orjson.dumps(obj)


def _loads(raw):
    """The JSON value of ``raw`` (orjson); what orjson refuses goes through the standard library, which
    also reads the ``NaN`` / ``Infinity`` that Python's ``json.dumps`` writes: such a request is then
    refused for its non-finite number (422, naming it), not as malformed JSON."""
    try:
        return orjson.loads(raw)
    except orjson.JSONDecodeError:
        return json.loads(raw)


def _first_line(e: Exception) -> str:
    return _text(str(e).splitlines()[0] if str(e) else type(e).__name__)


def _text(s: str) -> str:
    """``s`` writable as UTF-8 JSON: a lone surrogate (``"\\ud800"`` in a request) becomes its escape
    text ``\\ud800``; any other text is unchanged."""
    try:
        s.encode("utf-8")
        return s
    except UnicodeEncodeError:
        return s.encode("utf-8", "backslashreplace").decode("utf-8")


_ORJSON_INTS = (-(2**63), 2**64 - 1)  # the integers orjson reads and writes exactly


def _has_float(v) -> bool:
    """Whether the JSON value ``v`` holds a float anywhere (no recursion: ids may nest 1024 deep)."""
    todo = [v]
    while todo:
        x = todo.pop()
        if type(x) is float:
            return True
        if type(x) is list:
            todo.extend(x)
        elif type(x) is dict:
            todo.extend(x.values())
    return False


def _echo_id(i, raw):
    """The ``id`` of a stream message as the reply echoes it: the value itself, or its exact JSON text
    (``orjson.Fragment``) where orjson cannot write it (an integer beyond 64 bits, which orjson also reads
    as a float: the message is then read again with the standard library). RequestError when the id
    cannot be written as JSON at all (a lone surrogate in a string, nesting past the writers' depth)."""
    t = type(i)
    if (t is str and i.isascii()) or i is None or t is bool or (t is int and _ORJSON_INTS[0] <= i <= _ORJSON_INTS[1]):
        return i
    try:
        if _has_float(i):  # an integer over 64 bits reads as a float in orjson: take the exact value
            i = json.loads(raw)["id"]
        try:
            _dumps([i])  # as deep as in the reply object
            return i
        except orjson.JSONEncodeError as e:
            if not hasattr(orjson, "Fragment"):
                raise ValueError(_first_line(e)) from None
            return orjson.Fragment(json.dumps(i, ensure_ascii=False, allow_nan=False).encode("utf-8"))
    except (ValueError, TypeError, UnicodeError, RecursionError, KeyError) as e:
        raise RequestError(f"the message's 'id' cannot be echoed ({_first_line(e)}): use an id writable as JSON "
                           f"(no lone surrogate \\ud800-\\udfff); this reply has no 'id' and the target was not computed") from None


def create_app(model, limits: ServiceLimits | None = None, identity: dict | None = None):
    """The FastAPI app serving ``model`` (a fitted :class:`hykin.hybrid.model.HybridModel`).

    ``limits``: :class:`ServiceLimits` (defaults when None). ``identity``: ``/health``'s model record
    (:func:`hykin.compensation.service_guard.model_identity`; built without a file path when None).
    """
    from fastapi import FastAPI, Request, WebSocket
    from fastapi.responses import Response
    from starlette.concurrency import run_in_threadpool
    from starlette.requests import ClientDisconnect
    from starlette.websockets import WebSocketDisconnect

    from .. import __version__

    limits = limits or ServiceLimits()
    identity = identity or model_identity(None)
    h = Handlers(model, limits.max_targets, limits.max_step_deg)
    counts: collections.Counter = collections.Counter()
    worker = ModelWorker(limits.queue)

    @contextlib.asynccontextmanager
    async def lifespan(_app):
        gc.collect()
        gc.freeze()  # the model and libraries are never scanned again: no full-collection pause mid-stream
        yield
        worker.close()

    # no /docs, /redoc, /openapi.json: they answered without the token, /docs loads Swagger UI from a
    # CDN a cell network cannot reach, and the schema is empty (every endpoint reads a raw Request)
    app = FastAPI(title="hykin compensation service", version=__version__, lifespan=lifespan,
                  docs_url=None, redoc_url=None, openapi_url=None)
    app.add_middleware(ConnectionLimit, limit=limits.max_connections, counts=counts, token=limits.token,
                       delay_s=limits.refusal_delay_s)
    app.state.hykin_counts = counts  # the connection layer counts its drops here too (uvicorn_config)

    async def _refuse(status: int, detail: str, kind: str, headers: dict | None = None):
        counts[f"refused_{kind}"] += 1
        if limits.refusal_delay_s:
            await asyncio.sleep(limits.refusal_delay_s)
        return Response(_dumps({"detail": _text(detail)}), status_code=status, media_type="application/json", headers=headers)

    def _parse(raw: bytes, parse):
        return parse(_loads(raw))

    def _compute(fn):
        return lambda *args: _dumps(fn(*args))

    async def _run(request: Request, parse, compute):
        if not token_ok(request.headers, limits.token):
            return await _refuse(401, "missing or wrong bearer token (Authorization: Bearer <token>)", "auth",
                           {"WWW-Authenticate": "Bearer"})
        try:
            raw = await read_body(request, limits.max_body_bytes, limits.body_timeout_s, limits.body_min_rate_kib_s)
        except BodyTooLarge as e:
            return await _refuse(413, str(e), "size", {"Connection": "close"})
        except BodyTimeout as e:
            return await _refuse(408, str(e), "timeout", {"Connection": "close"})
        except ClientDisconnect:  # gone before its body came in full: nobody to answer (probe s43 AZ: a traceback)
            counts["dropped_client_disconnect"] += 1
            return Response(status_code=400)
        except ValueError as e:
            return await _refuse(400, str(e), "malformed", {"Connection": "close"})
        try:
            args = _parse(raw, parse) if len(raw) <= _INLINE_BYTES else await run_in_threadpool(_parse, raw, parse)
        except RequestError as e:
            return await _refuse(e.status, str(e), "invalid")
        except (ValueError, UnicodeDecodeError, RecursionError) as e:  # json's errors are ValueErrors
            return await _refuse(400, f"malformed JSON: {_first_line(e)}", "malformed")
        try:
            out = await worker.submit(BATCH, compute, *args)
        except QueueFull as e:
            return await _refuse(503, str(e), "busy", {"Retry-After": "1"})
        except ValueError as e:  # the model's own input checks (one line)
            return await _refuse(422, _first_line(e), "invalid")
        counts["answered_http"] += 1
        return Response(out, media_type="application/json")

    @app.get("/health")
    async def health():
        return {"status": "ok", "model": model.nominal.name, "dof": h.dof, "version": __version__, **identity,
                "queued": worker.pending, "counts": dict(counts)}

    fk_c, ik_c, comp_c = _compute(h.fk), _compute(h.ik), _compute(h.compensate)

    @app.post("/fk")
    async def fk(request: Request):
        return await _run(request, h.parse_fk, fk_c)

    @app.post("/ik")
    async def ik(request: Request):
        return await _run(request, h.parse_ik, ik_c)

    @app.post("/compensate")
    async def comp(request: Request):
        return await _run(request, h.parse_compensate, comp_c)

    @app.websocket("/stream")
    async def stream(ws: WebSocket):
        frame = ws.query_params.get("frame", "measurement")
        why = None
        if not token_ok(ws.headers, limits.token):
            why = "missing or wrong bearer token (Authorization: Bearer <token>)"
        elif frame not in h.frames:
            why = f"query parameter 'frame' must be one of {', '.join(h.frames)}, got {_text(repr(frame))}"
        if why is not None:  # HTTP 403 with the reason as JSON (the close code 1008 where the server cannot)
            counts["refused_stream_handshake"] += 1
            if limits.refusal_delay_s:
                await asyncio.sleep(limits.refusal_delay_s)
            if "websocket.http.response" in ws.scope.get("extensions", {}):
                await ws.send_denial_response(Response(_dumps({"detail": why}), status_code=403,
                                                       media_type="application/json"))
            else:
                await ws.close(code=1008, reason=why[:120])
            return
        await ws.accept()
        counts["stream_connections"] += 1
        q_last, seq = None, 0
        try:
            while True:
                msg = await ws.receive()
                if msg["type"] == "websocket.disconnect":
                    break
                seq += 1
                reply = {"seq": seq}
                try:
                    raw = msg.get("text") if msg.get("text") is not None else msg.get("bytes")
                    body = _loads(raw)
                    if isinstance(body, dict) and "id" in body:
                        reply["id"] = _echo_id(body["id"], raw)
                    T, q_prev = h.parse_step(body, q_last)
                    out = await worker.run(STREAM, h.step, T, q_prev, frame)
                    reply.update(out)
                    if out["success"]:
                        q_last = np.asarray(out["q"], dtype=np.float64)
                    counts["answered_stream"] += 1
                except RequestError as e:
                    reply["error"] = _text(str(e))
                except (ValueError, TypeError, UnicodeDecodeError, RecursionError) as e:
                    reply["error"] = f"malformed message: {_first_line(e)}"
                if "error" in reply:
                    counts["refused_stream_message"] += 1
                try:
                    text = _dumps(reply).decode()
                except (TypeError, ValueError) as e:  # never expected: still one reply and the stream open
                    counts["refused_stream_message"] += "error" not in reply
                    text = _dumps({"seq": seq, "error": f"the reply cannot be written: {_first_line(e)}"}).decode()
                await ws.send_text(text)
        except WebSocketDisconnect:
            pass

    return app


class _DenialLogFilter(logging.Filter):
    """uvicorn's websockets-sansio logs "ASGI callable returned without completing handshake" after an HTTP
    denial response that it did send (its flag is not set on that path): not an error, so not logged."""

    def filter(self, record):
        return "without completing handshake" not in record.getMessage()


logging.getLogger("uvicorn.error").addFilter(_DenialLogFilter())


class ConnectionLimit:
    """ASGI middleware: at most ``limit`` requests and streams in progress at once (``GET /health`` is
    not counted, nor a request without the bearer ``token``, which the app refuses: probe s42 AY, 100
    clients with a wrong token held every slot through their refusal delay and 70 of 76 correct requests
    got 503); one more is refused after ``delay_s`` (as every refusal) with 503, ``Retry-After: 1`` and a
    JSON reason (a WebSocket handshake: the same as an HTTP denial response), counted as
    ``refused_connections``."""

    def __init__(self, app, limit: int, counts, token: str | None = None, delay_s: float = 0.0):
        self.app, self.limit, self.counts, self.active = app, int(limit), counts, 0
        self.token, self.delay_s = token, float(delay_s)

    async def __call__(self, scope, receive, send):
        if scope["type"] not in ("http", "websocket") or scope.get("path") == "/health":
            return await self.app(scope, receive, send)
        if self.token is not None:
            from starlette.datastructures import Headers

            if not token_ok(Headers(scope=scope), self.token):
                return await self.app(scope, receive, send)  # refused there, after its delay, holding no slot
        if self.active >= self.limit:
            self.counts["refused_connections"] += 1
            if self.delay_s:
                await asyncio.sleep(self.delay_s)
            body = _dumps({"detail": f"busy: {self.active} requests and streams in progress (limit {self.limit}, "
                                     f"hykin serve --max-connections); retry later"})
            headers = [(b"content-type", b"application/json"), (b"retry-after", b"1"),
                       (b"content-length", str(len(body)).encode())]
            if scope["type"] == "http":
                await send({"type": "http.response.start", "status": 503, "headers": headers})
                await send({"type": "http.response.body", "body": body})
            elif "websocket.http.response" in scope.get("extensions", {}):
                await receive()  # websocket.connect
                await send({"type": "websocket.http.response.start", "status": 503, "headers": headers})
                await send({"type": "websocket.http.response.body", "body": body})
            else:
                await receive()
                await send({"type": "websocket.close", "code": 1013, "reason": "busy: too many connections"})
            return
        self.active += 1
        try:
            await self.app(scope, receive, send)
        finally:
            self.active -= 1


def uvicorn_config(model, host: str, port: int, limits: ServiceLimits | None = None, identity: dict | None = None):
    """The ``uvicorn.Config`` of the service: the app, its HTTP protocol (a request-header deadline and a
    cap on connections without a request, :mod:`.service_protocol`) and the WebSocket message size."""
    import uvicorn

    from .service_protocol import WaitingConnections, http_protocol

    limits = limits or ServiceLimits()
    app = create_app(model, limits, identity)
    waiting = WaitingConnections(limits.max_waiting, app.state.hykin_counts)
    # websockets-sansio: uvicorn's WebSocket protocol on websockets' sans-I/O core (uvicorn >= 0.35). Measured
    # on loopback at 250 Hz, one target per message: p50 0.90 / p99 1.86 ms and 0.70 ms of server CPU per
    # message, against 1.19-1.37 / 2.36-6.36 ms and 0.95-1.13 ms with uvicorn's default websockets protocol.
    # limit_concurrency stays off: it counted connections that had sent nothing, so silent sockets made it
    # answer every request with a bare 503 (probe AR, C1). Requests and streams are the app's to bound
    # (ConnectionLimit), connections without a request the protocol's (WaitingConnections).
    return uvicorn.Config(app, host=host, port=port, log_level="warning", limit_concurrency=None,
                          http=http_protocol(limits.header_timeout_s, waiting, send_timeout_s=limits.send_timeout_s,
                                        send_min_rate_kib_s=limits.send_min_rate_kib_s), ws_max_size=limits.max_message_bytes,
                          ws="websockets-sansio")


def serve(model, host: str, port: int, limits: ServiceLimits | None = None, identity: dict | None = None) -> None:
    """Run the service with uvicorn until interrupted (the ``hykin serve`` command)."""
    import uvicorn

    uvicorn.Server(uvicorn_config(model, host, port, limits, identity)).run()
