"""Connections of ``hykin serve`` before they hold a request: uvicorn's HTTP protocol with a deadline
for the request header and a cap on the connections that hold no request.

uvicorn (0.54) times out an idle connection only *after* a response (``timeout_keep_alive``): one that
sends nothing, or dribbles its header, is kept for ever (it has no request-start timeout, uvicorn issue
#157), and its ``limit_concurrency`` counts such connections, so 2N + 16 silent sockets answered every
request, ``GET /health`` included, with a bare 503 for as long as they stayed open (probe AR, C1).
:func:`http_protocol` subclasses the protocol uvicorn would pick (httptools, else h11):

* a connection must send a complete request header within ``header_timeout_s`` of opening, or of the
  first byte of its next request on a kept-alive connection; otherwise it is closed (after a one-line
  408 when it had sent part of a header), counted in ``/health`` as ``dropped_header_timeout``;
* the connections that hold no request (no complete header yet, or idle between keep-alive requests)
  are at most ``cap`` (:class:`WaitingConnections`): one more closes the oldest of them, counted as
  ``dropped_waiting``. A client that sends its request as soon as it connects (every real client) is
  never the oldest, so silent sockets can neither lock it out nor make ``/health`` look down.

* a response the client does not read: while the connection's write buffer is over its high-water mark
  (64 KiB), it must drain at ``send_min_rate_kib_s`` at least after a grace of ``send_timeout_s``:
  the connection is aborted once it has been over the mark for ``send_timeout_s`` plus one second per
  ``send_min_rate_kib_s`` KiB that left the buffer meanwhile, counted as ``dropped_send_timeout``.
  Before, a client that sent requests for large answers and never read them held its
  ``--max-connections`` slot for ever: two such clients answered every other request 503 for as long
  as they liked (stop 43). A client reading at that rate or faster gets every answer, however large
  (probe s43 AZ: a first rule, a deadline to drain below the low-water mark, cut off a steady reader of
  a 1.45 MB answer at 50-100 KiB/s whenever the kernel's send buffer was small, as on a real network).

Requests and streams in progress are the app's to bound
(:class:`hykin.compensation.service.ConnectionLimit`, ``--max-connections``), and a body that is slow
to arrive is the app's too (:func:`hykin.compensation.service_guard.read_body`); uvicorn's own
``limit_concurrency`` is then left off.
"""

from __future__ import annotations

import collections

__all__ = ["WaitingConnections", "http_protocol"]


class WaitingConnections:
    """The open connections that hold no request, oldest first; at most ``cap`` of them.

    ``counts``: the service's counter (``/health``), which gets ``dropped_waiting`` for each
    connection closed to make room."""

    def __init__(self, cap: int, counts: collections.Counter | None = None):
        self.cap = int(cap)
        self.counts = counts if counts is not None else collections.Counter()
        # insertion-ordered, the first key the oldest: connections that never sent a request, and kept-alive
        # ones idle between requests (closed only when no fresh one is left: probe s42 AY, a keep-alive client
        # idle between requests was the oldest and was reset as it sent its next one while silent sockets came)
        self._fresh: dict = {}
        self._kept: dict = {}

    def __len__(self) -> int:
        return len(self._fresh) + len(self._kept)

    def add(self, conn, kept: bool = False) -> None:
        """``conn`` waits for a request now (``kept``: after answering one); while over ``cap`` the oldest
        waiting connection that never sent a request is closed, else the oldest kept-alive one."""
        self.discard(conn)
        (self._kept if kept else self._fresh)[conn] = None
        while len(self) > self.cap:
            pool = self._fresh if self._fresh else self._kept
            old = next(iter(pool))
            del pool[old]
            self.counts["dropped_waiting"] += 1
            old.drop(None)

    def discard(self, conn) -> None:
        """``conn`` holds a request now, or is gone."""
        self._fresh.pop(conn, None)
        self._kept.pop(conn, None)


class _Transport:
    """A connection's transport that drops writes once it is closing (aborted after the send deadline,
    or the client gone): a request handler may still answer then, since uvicorn marks its
    requests disconnected only later, in ``connection_lost`` (and not a pipelined one's), and uvloop
    raises on a write to a closed handle where asyncio's own transports drop it. Everything else is
    the transport's own."""

    __slots__ = ("_t",)

    def __init__(self, transport):
        self._t = transport

    def __getattr__(self, name):
        return getattr(self._t, name)

    def write(self, data) -> None:
        if not self._t.is_closing():  # closing from abort() on, with uvloop and asyncio alike
            self._t.write(data)


def _base_protocol():
    from uvicorn.protocols.http.auto import AutoHTTPProtocol

    return AutoHTTPProtocol


def http_protocol(header_timeout_s: float, waiting: WaitingConnections, base=None, send_timeout_s: float | None = None,
                  send_min_rate_kib_s: float = 16.0):
    """uvicorn's HTTP protocol class ``base`` (default: the one uvicorn picks, httptools or h11) with
    a ``header_timeout_s`` (s) deadline for each request header, the connections that hold no request
    kept in ``waiting``, and a paused write buffer aborted unless it drains at ``send_min_rate_kib_s``
    (KiB/s) after a grace of ``send_timeout_s`` (s; None: never aborted). Pass the class as
    ``uvicorn.Config(http=...)``."""
    per_byte = 1.0 / (1024.0 * send_min_rate_kib_s)
    base = base or _base_protocol()
    detail = (b'{"detail":"request header not complete within %g s (hykin serve --header-timeout-s)"}'
              % header_timeout_s)
    timeout_408 = (b"HTTP/1.1 408 Request Timeout\r\ncontent-type: application/json\r\ncontent-length: %d\r\n"
                   b"connection: close\r\n\r\n%s" % (len(detail), detail))

    class HeaderDeadlineProtocol(base):
        """``base`` with a request-header deadline; see :mod:`hykin.compensation.service_protocol`."""

        _deadline = None  # the timer of the awaited header, or None
        _waiting = False  # no request in progress: in ``waiting``
        _partial = False  # bytes of the awaited request arrived

        def connection_made(self, transport) -> None:
            super().connection_made(_Transport(transport) if send_timeout_s is not None else transport)
            self._await_request()
            self._deadline = self.loop.call_later(header_timeout_s, self._expire)

        _send_timer = None  # the timer of a paused write buffer, or None
        _paused_at = (0.0, 0)  # loop time and buffer size when writing paused

        def connection_lost(self, exc) -> None:
            self._settle()
            self._stop_send_timer()
            super().connection_lost(exc)

        def pause_writing(self) -> None:
            super().pause_writing()
            if send_timeout_s is not None and self._send_timer is None:
                self._paused_at = (self.loop.time(), self.transport.get_write_buffer_size())
                self._send_timer = self.loop.call_later(send_timeout_s, self._send_check)

        def resume_writing(self) -> None:
            self._stop_send_timer()
            super().resume_writing()

        def _stop_send_timer(self) -> None:
            if self._send_timer is not None:
                self._send_timer.cancel()
                self._send_timer = None

        def _send_check(self) -> None:
            """Over the high-water mark since ``_paused_at``: abort the connection unless what left the
            buffer meanwhile extends its deadline past now (the buffer only shrinks while paused: the app
            waits for it before writing more); a graceful close would wait for the buffer to drain."""
            self._send_timer = None
            t0, size0 = self._paused_at
            left = self.transport.get_write_buffer_size()
            deadline = t0 + send_timeout_s + max(0, size0 - left) * per_byte
            now = self.loop.time()
            if not left:  # drained (resume_writing comes with it)
                return
            if deadline > now + 1e-3:
                self._send_timer = self.loop.call_later(deadline - now, self._send_check)
                return
            waiting.counts["dropped_send_timeout"] += 1
            self.transport.abort()  # the _Transport: the handlers' writes are dropped from now on

        def data_received(self, data: bytes) -> None:
            super().data_received(data)
            if not self._waiting:
                return
            if self._in_request():
                self._settle()
            elif not self.transport.is_closing():
                self._partial = True
                if self._deadline is None:  # the first byte of the next request on a kept-alive connection
                    self._deadline = self.loop.call_later(header_timeout_s, self._expire)

        def on_response_complete(self) -> None:
            super().on_response_complete()
            # idle between requests: uvicorn's keep-alive timer covers silence, the first byte arms ours
            if not self.transport.is_closing() and not self._in_request():
                self._await_request(kept=True)

        def handle_websocket_upgrade(self, *args) -> None:
            self._settle()  # the WebSocket protocol takes the connection over: the app bounds streams
            self._stop_send_timer()
            if isinstance(self.transport, _Transport):  # the stream protocol gets the transport itself
                self.transport = self.transport._t
            super().handle_websocket_upgrade(*args)

        def drop(self, response: bytes | None) -> None:
            """Close the connection (after ``response``, when given) without waiting any longer."""
            self._settle()
            if not self.transport.is_closing():
                if response:
                    self.transport.write(response)
                self.transport.close()

        def _in_request(self) -> bool:
            c = self.cycle
            return c is not None and not c.response_complete

        def _await_request(self, kept: bool = False) -> None:
            self._waiting, self._partial = True, False
            waiting.add(self, kept)

        def _settle(self) -> None:
            if self._deadline is not None:
                self._deadline.cancel()
                self._deadline = None
            if self._waiting:
                self._waiting = False
                waiting.discard(self)

        def _expire(self) -> None:
            self._deadline = None
            if self._waiting:
                waiting.counts["dropped_header_timeout"] += 1
                self.drop(timeout_408 if self._partial else None)

    return HeaderDeadlineProtocol
