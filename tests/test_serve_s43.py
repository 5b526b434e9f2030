"""``hykin serve``: the body deadline is a minimum rate, not a total time (stop 43).

Probe s42 AY: a legitimate 2.7 MB request over a 1.2 Mbit/s link got 408, since ``--body-timeout-s``
(10 s) was a total time. Now each KiB that arrives extends the deadline by ``1 / --body-min-rate-kib-s``
seconds: a body arriving at that rate or faster is never cut off; one dribbled in still is.
Reference: bodies sent here at known rates, over a real socket and through a fake request."""

from __future__ import annotations

import asyncio
import json
import socket
import time

import numpy as np
import pytest
from comp_models import tiny_model_file
from shared_fixtures import free_port, pose_rows, start_server

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")
httpx = pytest.importorskip("httpx")


class _Req:
    """A Starlette-like request whose body arrives as ``chunks``, one every ``every_s`` seconds."""

    def __init__(self, chunks: list[bytes], every_s: float, announce: bool = True):
        self.chunks, self.every_s = chunks, every_s
        self.headers = {"content-length": str(sum(map(len, chunks)))} if announce else {}

    async def stream(self):
        for c in self.chunks:
            await asyncio.sleep(self.every_s)
            yield c


def _read(req, timeout_s, rate):
    from hykin.compensation.service_guard import read_body

    return asyncio.run(read_body(req, 10 << 20, timeout_s, rate))


@pytest.mark.parametrize("py310", [False, True])
def test_a_steady_body_longer_than_the_deadline_is_read_and_a_dribbled_one_is_not(py310, monkeypatch):
    from hykin.compensation.service_guard import BodyTimeout

    if py310:  # the loop Python 3.10 runs (no asyncio.timeout)
        monkeypatch.delattr(asyncio, "timeout", raising=False)
    steady = [b"x" * 16384] * 16  # 256 KiB at 16 KiB per 40 ms = 400 KiB/s: 0.64 s against a 0.25 s deadline
    t0 = time.perf_counter()
    assert _read(_Req(steady, 0.04), 0.25, 64.0) == b"".join(steady)
    assert time.perf_counter() - t0 > 0.5
    with pytest.raises(BodyTimeout, match=r"within 0.25 s \(\d+ of 262144 bytes arrived; hykin serve --body-timeout-s"):
        _read(_Req(steady, 0.04), 0.25, None)  # a total deadline, as before
    dribble = [b"{"] * 400  # 1 byte per 10 ms: 0.1 KiB/s
    t0 = time.perf_counter()
    with pytest.raises(BodyTimeout, match=r"and 1 s more per 64 KiB received \(\d+ of 400 bytes arrived"):
        _read(_Req(dribble, 0.01), 0.25, 64.0)
    assert time.perf_counter() - t0 < 1.5
    with pytest.raises(BodyTimeout, match=r"of \? bytes arrived"):  # chunked: no Content-Length
        _read(_Req(dribble, 0.01, announce=False), 0.25, 64.0)


def test_limits_and_cli_check_the_rate():
    from typer.testing import CliRunner

    from hykin.cli import app
    from hykin.compensation.service_guard import ServiceLimits

    assert ServiceLimits().body_min_rate_kib_s == 64.0
    for bad in (0, -1.0, 2e6):
        with pytest.raises(ValueError, match="body_min_rate_kib_s"):
            ServiceLimits(body_min_rate_kib_s=bad)
    r = CliRunner().invoke(app, ["serve", str(tiny_model_file()), "--body-min-rate-kib-s", "-3"])
    assert r.exit_code != 0 and "--body-min-rate-kib-s must be in 0..1e6" in str(r.exception)


def test_a_slow_link_gets_its_answer_over_a_socket():
    """A valid /compensate request of ~300 KiB (padded with JSON whitespace) sent at ~250 KiB/s takes
    ~1.2 s against --body-timeout-s 0.4: answered 200; the same body stalling half-way gets 408."""
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    m = HybridModel.load(tiny_model_file())
    port = free_port()
    limits = ServiceLimits(refusal_delay_s=0, header_timeout_s=2.0, body_timeout_s=0.4)
    server, th = start_server(m, port, limits, model_identity(None))
    try:
        q = m.nominal.random_joints(3, 4, margin=0.3)
        body = json.dumps({"targets": pose_rows(m.predict(q)), "q_current": q.tolist()})
        body = (body[:-1] + " " * (300 * 1024 - len(body)) + "}").encode()
        head = (f"POST /compensate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                f"Content-Length: {len(body)}\r\nConnection: close\r\n\r\n").encode()

        def send(stall_after: int | None) -> bytes:
            with socket.create_connection(("127.0.0.1", port)) as s:
                try:
                    s.sendall(head)
                    for i in range(0, len(body), 8192):
                        if stall_after is not None and i >= stall_after:
                            time.sleep(1.5)
                            break
                        s.sendall(body[i:i + 8192])
                        time.sleep(8192 / (250 * 1024))
                except (ConnectionResetError, BrokenPipeError):  # answered and closed while sending
                    pass
                s.settimeout(30)
                got = b""
                try:
                    while chunk := s.recv(65536):
                        got += chunk
                except (ConnectionResetError, BrokenPipeError):
                    pass
                return got

        t0 = time.perf_counter()
        ok = send(None)
        assert time.perf_counter() - t0 > 1.0
        assert ok.startswith(b"HTTP/1.1 200"), ok[:200]
        assert all(json.loads(ok.split(b"\r\n\r\n", 1)[1])["success"])
        cut = send(100 * 1024)
        assert cut.startswith(b"HTTP/1.1 408") and b"--body-min-rate-kib-s" in cut
    finally:
        server.should_exit = True
        th.join(30)


def test_ik_notes_solutions_far_from_q_current():
    """``POST /ik`` with ``q_current``: a solution more than 90° (a joint) from it is flagged and noted, as
    ``hykin ik --seed-joints`` notes it (probe s42: the service said nothing); without ``q_current``,
    nothing is flagged."""
    from comp_models import ExactModel

    from hykin import load_robot
    from hykin.compensation.service_requests import Handlers
    from hykin.kinematics.fk import fk

    nom = load_robot("ur10")
    h = Handlers(ExactModel(nom, nom))
    q = np.array([[0.3, -1.4, 1.5, -1.7, -1.5, 0.4], [0.1, -1.2, 1.3, -1.6, -1.2, 0.2]])
    targets = pose_rows(fk(nom, q))
    near = h.ik(*h.parse_ik({"targets": targets, "q_current": (q + 0.05).tolist()}))
    assert all(near["success"]) and near["far_from_q_current"] == [False, False] and "note" not in near
    seed = q.copy()
    seed[1, 0] += 2.6  # target 1's q_current far from every solution of it
    far = h.ik(*h.parse_ik({"targets": targets, "q_current": seed.tolist()}))
    assert all(far["success"]) and far["far_from_q_current"] == [False, True]
    assert "1 target (target 1) is solved more than 90° (a joint) from q_current: no solution on the branch of q_current" in far["note"]
    assert abs(far["q"][1][0] - seed[1, 0]) > np.pi / 2
    plain = h.ik(*h.parse_ik({"targets": targets}))
    assert "far_from_q_current" not in plain and "note" not in plain


def test_clients_that_do_not_read_their_answers_lose_their_slots_and_slow_readers_do_not():
    """Before, two clients pipelining requests for large answers and never reading them held both
    --max-connections slots for ever: every other request got 503 (stop 43, 30 s and more). Now a
    write buffer that does not drain for --send-timeout-s aborts the connection; a client reading
    steadily but slowly gets its whole answer."""
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    m = HybridModel.load(tiny_model_file())
    port = free_port()
    limits = ServiceLimits(max_connections=2, refusal_delay_s=0, header_timeout_s=2.0, send_timeout_s=1.0)
    server, th = start_server(m, port, limits, model_identity(None))
    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30)
    q = m.nominal.random_joints(4000, 1).tolist()
    body = json.dumps({"q": q}).encode()
    req = (f"POST /fk HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {len(body)}\r\n\r\n"
           ).encode() + body
    hostile = []
    try:
        for _ in range(2):
            s = socket.socket()
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.connect(("127.0.0.1", port))
            s.settimeout(0.5)
            try:
                for _ in range(8):
                    s.sendall(req)
            except (TimeoutError, socket.timeout, ConnectionResetError, BrokenPipeError):
                pass
            hostile.append(s)
        t0, codes = time.perf_counter(), []
        while time.perf_counter() - t0 < 10:
            codes.append(c.post("/fk", json={"q": q[:2]}).status_code)
            if codes[-1] == 200:
                break
            time.sleep(0.2)
        assert codes[-1] == 200, codes
        while c.get("/health").json()["counts"]["dropped_send_timeout"] < 2:  # the other one's deadline too
            assert time.perf_counter() - t0 < 15
            time.sleep(0.1)
        assert [c.post("/fk", json={"q": q[:2]}).status_code for _ in range(2)] == [200, 200]

        # a slow but steady reader: ~600 KB at ~300 KiB/s through a 4 KiB receive buffer, 1 s deadline
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.connect(("127.0.0.1", port))
            s.sendall(req.replace(b"HTTP/1.1\r\n", b"HTTP/1.1\r\nConnection: close\r\n", 1))
            s.settimeout(10)
            got = b""
            while chunk := s.recv(16384):
                got += chunk
                time.sleep(0.05)
        head, _, payload = got.partition(b"\r\n\r\n")
        assert head.startswith(b"HTTP/1.1 200") and len(payload) > 300_000
        assert len(json.loads(payload)["poses"]) == len(q)
    finally:
        for s in hostile:
            s.close()
        c.close()
        server.should_exit = True
        th.join(30)



def test_a_steady_reader_behind_a_small_send_buffer_gets_its_whole_answer():
    """Probe s43 AZ: with the kernel's send buffer small (as on a real network for a slowly reading
    client; loopback autotunes it to megabytes), the first send rule, drain below the low-water mark
    within --send-timeout-s, cut off a steady reader of one large answer. The rule is now a minimum
    drain rate (--send-min-rate-kib-s): a client reading ~290 KB at ~60 KiB/s over 4-5 s against a
    0.5 s timeout gets all of it; one that stops reading is cut off."""
    import threading

    import uvicorn

    from hykin.compensation.service import uvicorn_config
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    m = HybridModel.load(tiny_model_file())
    port = free_port()
    # a header deadline far shorter than the reading: a connection busy with its answer is not "waiting"
    limits = ServiceLimits(refusal_delay_s=0, header_timeout_s=0.5, send_timeout_s=0.5, send_min_rate_kib_s=16.0)
    lsock = socket.socket()
    lsock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    lsock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 32768)  # accepted connections inherit it
    lsock.bind(("127.0.0.1", port))
    lsock.listen(16)
    server = uvicorn.Server(uvicorn_config(m, "127.0.0.1", port, limits, model_identity(None)))
    th = threading.Thread(target=server.run, kwargs={"sockets": [lsock]}, daemon=True)
    th.start()
    t0 = time.time()
    while not server.started:
        assert th.is_alive() and time.time() - t0 < 60
        time.sleep(0.05)
    q = m.nominal.random_joints(2000, 2).tolist()
    body = json.dumps({"q": q}).encode()
    req = (f"POST /fk HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {len(body)}\r\n"
           "Connection: close\r\n\r\n").encode() + body

    def read(rate_kib_s: float, stop_after: int | None = None) -> bytes:
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.connect(("127.0.0.1", port))
            s.sendall(req)
            s.settimeout(10)
            got = b""
            try:
                while chunk := s.recv(4096):
                    got += chunk
                    if stop_after is not None and len(got) >= stop_after:
                        time.sleep(4.0)
                        stop_after = None
                    time.sleep(len(chunk) / (rate_kib_s * 1024))
            except ConnectionResetError:
                pass
            return got

    try:
        t0 = time.perf_counter()
        got = read(60.0)
        head, _, payload = got.partition(b"\r\n\r\n")
        assert time.perf_counter() - t0 > 2.5
        assert head.startswith(b"HTTP/1.1 200") and len(json.loads(payload)["poses"]) == len(q)
        # two requests pipelined, both answers read slowly: the second request waits unread meanwhile
        small = json.dumps({"q": q[:800]}).encode()
        small = small[:-1] + b" " * 600_000 + b"}"  # a large request (JSON whitespace), a small answer
        one = (f"POST /fk HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: {len(small)}"
               "\r\n\r\n").encode() + small
        with socket.socket() as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
            s.connect(("127.0.0.1", port))
            s.sendall(one + one)
            s.settimeout(10)
            both = b""
            while both.count(b"HTTP/1.1 200") < 2 or not both.endswith(b"]}"):
                chunk = s.recv(4096)
                assert chunk, f"closed after {len(both)} bytes"
                both += chunk
                time.sleep(len(chunk) / (60 * 1024))
        cut = read(60.0, stop_after=20_000)  # then stops for 4 s, beyond 0.5 s + 20 KB / 16 KiB/s: aborted
        assert cut.startswith(b"HTTP/1.1 200") and len(cut) < len(got)
        with httpx.Client(base_url=f"http://127.0.0.1:{port}") as c:
            counts = c.get("/health").json()["counts"]
        # connections busy with their answers are never taken for ones that send no header
        assert counts["dropped_send_timeout"] == 1 and "dropped_header_timeout" not in counts, counts
    finally:
        server.should_exit = True
        th.join(30)


def test_a_client_gone_mid_body_is_counted_not_a_traceback(caplog):
    """Probe s43 AZ: a client closing its connection part-way through its body made the app raise
    Starlette's ClientDisconnect out of the handler (a 60-line "Exception in ASGI application"). It is now
    counted as ``dropped_client_disconnect``; the service goes on answering."""
    import logging

    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    m = HybridModel.load(tiny_model_file())
    port = free_port()
    server, th = start_server(m, port, ServiceLimits(refusal_delay_s=0), model_identity(None))
    try:
        with caplog.at_level(logging.ERROR):
            for _ in range(3):
                with socket.create_connection(("127.0.0.1", port)) as s:
                    s.sendall(b"POST /fk HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\n"
                              b"Content-Length: 10000\r\n\r\n{\"q\": [[0.1, 0.2")
                    time.sleep(0.2)
            time.sleep(0.5)
            with httpx.Client(base_url=f"http://127.0.0.1:{port}") as c:
                assert c.post("/fk", json={"q": [[0.0] * m.nominal.dof]}).status_code == 200
                assert c.get("/health").json()["counts"]["dropped_client_disconnect"] == 3
        assert not [r for r in caplog.records if "Exception in ASGI application" in r.getMessage()]
    finally:
        server.should_exit = True
        th.join(30)
