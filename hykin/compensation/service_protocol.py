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


def _base_protocol():
    from uvicorn.protocols.http.auto import AutoHTTPProtocol

    return AutoHTTPProtocol


def http_protocol(header_timeout_s: float, waiting: WaitingConnections, base=None):
    """uvicorn's HTTP protocol class ``base`` (default: the one uvicorn picks, httptools or h11) with
    a ``header_timeout_s`` (s) deadline for each request header and the connections that hold no
    request kept in ``waiting``. Pass the class as ``uvicorn.Config(http=...)``."""
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
            super().connection_made(transport)
            self._await_request()
            self._deadline = self.loop.call_later(header_timeout_s, self._expire)

        def connection_lost(self, exc) -> None:
            self._settle()
            super().connection_lost(exc)

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
