"""``hykin serve`` (probe AR fixes): silent or dribbling connections are dropped and cannot lock out
requests or GET /health (C1); a body dribbled in gets 408 and frees its slot (C2); batches filling the
queue never make a streamed target "busy" (C3); /health hashes the bytes that were loaded (A1); no
/docs, /redoc, /openapi.json (D1); an optional limit on how far a streamed answer moves the joints (D4)."""

from __future__ import annotations

import json
import shutil
import socket
import time

import numpy as np
import pytest
from comp_models import tiny_model_file
from shared_fixtures import free_port, start_server, pose_rows

from hykin.geometry import se3

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")
httpx = pytest.importorskip("httpx")

TOKEN = "s42-token"
AUTH = {"Authorization": f"Bearer {TOKEN}"}
HEADER_S, BODY_S, MAX_CONN = 0.5, 0.5, 4


@pytest.fixture(scope="module")
def srv():
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    m = HybridModel.load(tiny_model_file())
    port = free_port()
    limits = ServiceLimits(max_connections=MAX_CONN, queue=1, refusal_delay_s=0, token=TOKEN,
                           header_timeout_s=HEADER_S, body_timeout_s=BODY_S, max_step_deg=20.0)
    server, th = start_server(m, port, limits, model_identity(None))
    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30)
    yield c, m, port
    c.close()
    server.should_exit = True
    th.join(30)


def _read_until_closed(s: socket.socket, budget_s: float) -> bytes | None:
    """What the server sent before it closed ``s``; None when still open after ``budget_s``."""
    s.settimeout(budget_s)
    got = b""
    try:
        while True:
            b = s.recv(4096)
            if not b:
                return got
            got += b
    except (socket.timeout, TimeoutError):
        return None
    except ConnectionResetError:
        return got


def _compensate_body(m):
    q = m.nominal.random_joints(2, 4, margin=0.3)
    return {"targets": pose_rows(m.predict(q)), "q_current": q.tolist()}


def test_silent_connections_neither_lock_out_requests_nor_stay_open(srv):
    """C1: before, 2N + 16 sockets that sent nothing made every request, /health included, a bare 503
    for as long as they stayed open (never closed)."""
    c, m, port = srv
    n_silent = 6 * MAX_CONN + 20  # over the cap of connections without a request (2N + 16)
    silent = [socket.create_connection(("127.0.0.1", port)) for _ in range(n_silent)]
    partial = [socket.create_connection(("127.0.0.1", port)) for _ in range(3)]
    for s in partial:
        s.sendall(b"POST /compensate HTTP/1.1\r\nHost: x\r\n")
    try:
        time.sleep(0.1)
        with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30) as fresh:  # new connections
            assert fresh.get("/health").status_code == 200
            r = fresh.post("/compensate", json=_compensate_body(m), headers=AUTH)
            assert r.status_code == 200 and all(r.json()["success"])
        # every one is closed within the header deadline (the oldest at once, to keep the cap)
        for s in partial:
            got = _read_until_closed(s, HEADER_S + 5)
            assert got is not None and got.startswith(b"HTTP/1.1 408") and b"--header-timeout-s" in got
        assert all(_read_until_closed(s, HEADER_S + 5) == b"" for s in silent)
    finally:
        for s in silent + partial:
            s.close()
    counts = c.get("/health").json()["counts"]
    assert counts["dropped_waiting"] >= n_silent - (2 * MAX_CONN + 16)
    assert counts["dropped_header_timeout"] >= 3


def test_kept_alive_connection_dribbling_its_next_header_is_closed(srv):
    c, _, port = srv
    with socket.create_connection(("127.0.0.1", port)) as s:
        s.sendall(b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n")
        s.settimeout(10)
        assert s.recv(4096).startswith(b"HTTP/1.1 200")
        s.sendall(b"GET /health HTTP/1.1\r\n")  # then nothing: the next header never completes
        t0 = time.monotonic()
        got = _read_until_closed(s, HEADER_S + 5)
        assert got is not None and got.startswith(b"HTTP/1.1 408") and time.monotonic() - t0 >= HEADER_S * 0.9
    assert c.get("/health").status_code == 200


def test_a_body_dribbled_in_gets_408_and_frees_its_slot(srv):
    """C2: before, clients sending valid headers, then one body byte at a time, held every
    --max-connections slot for as long as they liked."""
    c, m, port = srv
    head = (f"POST /compensate HTTP/1.1\r\nHost: x\r\nContent-Type: application/json\r\nContent-Length: 2000\r\n"
            f"Authorization: Bearer {TOKEN}\r\n\r\n{{").encode()
    slow = [socket.create_connection(("127.0.0.1", port)) for _ in range(MAX_CONN)]
    try:
        for s in slow:
            s.sendall(head)
        time.sleep(0.1)
        busy = c.post("/compensate", json=_compensate_body(m), headers=AUTH)
        assert busy.status_code == 503 and "--max-connections" in busy.json()["detail"]
        for s in slow:
            got = _read_until_closed(s, BODY_S + 5)
            assert got is not None and got.startswith(b"HTTP/1.1 408") and b"--body-timeout-s" in got
    finally:
        for s in slow:
            s.close()
    r = c.post("/compensate", json=_compensate_body(m), headers=AUTH)
    assert r.status_code == 200 and all(r.json()["success"])
    assert c.get("/health").json()["counts"]["refused_timeout"] >= MAX_CONN


def test_batches_filling_the_queue_never_make_a_streamed_step_busy():
    """C3: before, with --queue below --max-connections, 93 of 300 streamed targets got "busy"."""
    import asyncio
    import threading

    from hykin.compensation.service_guard import BATCH, STREAM, ModelWorker, QueueFull

    gate, order = threading.Event(), []

    async def main():
        w = ModelWorker(1)
        first = w.submit(BATCH, gate.wait, 30)  # the one batch the queue holds, running
        with pytest.raises(QueueFull, match="--queue"):
            w.submit(BATCH, order.append, "batch")
        steps = [w.submit(STREAM, order.append, f"step{i}") for i in range(5)]  # one per open stream
        assert w.pending == 6
        gate.set()
        await asyncio.wait_for(asyncio.gather(first, *steps), 30)
        assert w.pending == 0
        w.close()

    asyncio.run(main())
    assert order == [f"step{i}" for i in range(5)]


def test_no_docs_or_schema_with_or_without_the_token(srv):
    c, _, _ = srv
    for path in ("/docs", "/redoc", "/openapi.json", "/docs/oauth2-redirect"):
        assert c.get(path).status_code == 404, path
        assert c.get(path, headers=AUTH).status_code == 404, path


def test_stream_refuses_an_answer_that_moves_the_joints_too_far(srv):
    """D4: a target far from the sent q (e.g. a quaternion in the wrong order) was answered with joints
    radians away; with --max-step-deg the reply says so instead, and the stream goes on."""
    from websockets.sync.client import connect

    _, m, port = srv
    q0 = m.nominal.random_joints(1, 8, margin=0.4)[0]
    q1 = q0.copy()
    q1[0] += np.radians(45.0)  # the base turns 45 deg: over the limit of 20 deg
    t0, t1 = pose_rows(m.predict(np.stack([q0, q1])))
    with connect(f"ws://127.0.0.1:{port}/stream", additional_headers=AUTH, open_timeout=30) as ws:
        replies = []
        for msg in ({"target": t0, "q": q0.tolist(), "id": 1}, {"target": t1, "id": 2}, {"target": t0, "id": 3},
                    {"target": t1, "q": q1.tolist(), "id": 4}):
            ws.send(json.dumps(msg))
            replies.append(json.loads(ws.recv(timeout=30)))
    ok0, far, back, near = replies
    assert ok0["success"] and np.abs(np.array(ok0["q"]) - q0).max() < np.radians(1)
    assert far["id"] == 2 and far["success"] is False and far["command"] is None and far["q"] is None
    assert "q1 by 45" in far["reason"] and "--max-step-deg" in far["reason"] and "20 deg" in far["reason"]
    assert back["success"] and near["success"]  # the refused answer did not become the stream's last joints


def test_step_limit_leaves_prismatic_joints_and_small_moves_alone():
    from hykin.compensation.service_requests import _within_step

    class Rob:  # the one attribute of a Robot the check reads
        revolute = np.array([False, True, True])  # a rail, then two revolute joints

    lim = np.radians(10)
    assert _within_step(Rob, np.array([5.0, 0.1, 0.15]), np.zeros(3), lim) == (True, "")  # 5 m on the rail: not limited
    ok, why = _within_step(Rob, np.array([0.0, 0.1, -0.3]), np.zeros(3), lim)
    assert not ok and "q3 by 17.2 deg" in why


def _second_model(src, dst):
    """A valid model file at ``dst`` whose weights differ from ``src``'s (its own content hash)."""
    from hykin.io.modelfile import read_model_file, write_model_file

    tensors, meta = read_model_file(src)
    k = next(k for k, v in sorted(tensors.items()) if v.dtype.is_floating_point and v.numel() > 1)
    tensors = dict(tensors)
    tensors[k] = tensors[k] + 1e-3
    write_model_file(dst, tensors, meta)


def test_health_hashes_the_bytes_that_were_loaded(tmp_path, monkeypatch):
    """A1: the file was read to load it, then again to hash it: a deploy renaming model B over the file
    in between made /health report B while the service ran A."""
    import hashlib

    from safetensors import safe_open

    from hykin.compensation.service_guard import load_served_model
    from hykin.hybrid.model import HybridModel

    a, b, served = tmp_path / "a.hykin", tmp_path / "b.hykin", tmp_path / "served.hykin"
    shutil.copy(tiny_model_file(), a)
    _second_model(a, b)
    shutil.copy(a, served)
    real_load = HybridModel.load.__func__

    def load_after_swap(cls, path, *args, **kw):  # the deploy script's rename, right as the model is loaded
        if served.exists() and b.exists():
            shutil.move(b, served)
        return real_load(cls, path, *args, **kw)

    monkeypatch.setattr(HybridModel, "load", classmethod(load_after_swap))
    model, ident = load_served_model(served)
    monkeypatch.undo()
    sha = lambda p: hashlib.sha256(p.read_bytes()).hexdigest()  # noqa: E731
    with safe_open(str(a), framework="pt") as f:
        a_content = f.metadata()["content_sha256"]
    assert ident["file_sha256"] == sha(a) != sha(served)  # the file now holds B; the service runs A
    assert ident["model_sha256"] == a_content and ident["model_path"] == str(served.resolve())
    q = model.nominal.random_joints(5, 2, margin=0.2)
    assert np.array_equal(model.predict(q), HybridModel.load(a).predict(q))


def test_load_served_model_names_the_file_it_was_given(tmp_path):
    from hykin.compensation.service_guard import load_served_model
    from hykin.io.modelfile import ModelFileError

    csv = tmp_path / "poses.csv"
    csv.write_text("q1,q2\n0,0\n")
    bad = tmp_path / "flipped.hykin"
    raw = bytearray(tiny_model_file().read_bytes())
    raw[-10] ^= 0x01  # one bit of the weights
    bad.write_bytes(bytes(raw))
    for path, word in ((tmp_path / "missing.hykin", "no such model file"), (csv, "expected a hykin model file"),
                       (bad, "corrupt or was edited")):
        with pytest.raises(ModelFileError) as e:
            load_served_model(path)
        msg = str(e.value)
        assert msg.startswith(str(path)) and word in msg and "hykin-serve-" not in msg


def test_cli_serve_loads_once_and_checks_the_new_options(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    import hykin.compensation.service as service
    import hykin.compensation.service_guard as guard
    from hykin.cli import app

    for opt, bad in (("--header-timeout-s", "0"), ("--body-timeout-s", "-1"), ("--max-step-deg", "400")):
        r = CliRunner().invoke(app, ["serve", str(tiny_model_file()), opt, bad])
        assert r.exit_code != 0 and opt in str(r.exception or r.output)
    loads, served = [], []
    real = guard.load_served_model
    monkeypatch.setattr(guard, "load_served_model", lambda p: loads.append(p) or real(p))
    monkeypatch.setattr(service, "serve", lambda *a: served.append(a))
    r = CliRunner().invoke(app, ["serve", str(tiny_model_file()), "--port", str(free_port()), "--header-timeout-s", "2",
                                 "--body-timeout-s", "3", "--max-step-deg", "15"])
    assert r.exit_code == 0, r.output
    _, _, _, limits, ident = served[0]
    assert loads == [str(tiny_model_file())] and (limits.header_timeout_s, limits.body_timeout_s, limits.max_step_deg) == (2, 3, 15)
    import hashlib

    assert ident["file_sha256"] == hashlib.sha256(tiny_model_file().read_bytes()).hexdigest()


def test_requests_without_the_token_hold_no_connection_slot():
    """Probe s42 AY: 100 clients with a wrong token held every ``--max-connections`` slot through their
    refusal delay, and 70 of 76 correct requests got 503. A request without the token is passed to the app
    (which refuses it) without taking a slot; a correct one still finds its slot."""
    import asyncio
    import collections

    from hykin.compensation.service import ConnectionLimit

    gate = asyncio.Event()
    seen = []

    async def app(scope, receive, send):
        seen.append(dict(scope["headers"]).get(b"authorization"))
        await gate.wait()  # every request stays "in progress"
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"{}"})

    async def main():
        mw = ConnectionLimit(app, limit=1, counts=collections.Counter(), token="secret", delay_s=0.0)
        sent = []

        async def send(msg):
            sent.append(msg)

        async def receive():
            return {"type": "http.request", "body": b"", "more_body": False}

        def scope(tok):
            return {"type": "http", "path": "/compensate", "headers": [(b"authorization", f"Bearer {tok}".encode())]}

        bad = [asyncio.create_task(mw(scope("wrong"), receive, send)) for _ in range(5)]
        await asyncio.sleep(0.01)
        good = asyncio.create_task(mw(scope("secret"), receive, send))
        await asyncio.sleep(0.01)
        assert mw.active == 1 and not any(m.get("status") == 503 for m in sent)
        gate.set()
        await asyncio.gather(*bad, good)

    asyncio.run(main())
    assert seen.count(b"Bearer secret") == 1 and seen.count(b"Bearer wrong") == 5


def test_waiting_connections_close_silent_ones_before_kept_alive_ones():
    """Probe s42 AY: with silent sockets coming, a keep-alive client idle between requests was the oldest
    waiting connection and was closed as it sent its next request. Fresh silent ones go first."""
    from hykin.compensation.service_protocol import WaitingConnections

    class Conn:
        dropped = False

        def drop(self, response):
            self.dropped = True

    w = WaitingConnections(cap=3)
    kept = Conn()
    w.add(kept, kept=True)
    silent = [Conn() for _ in range(6)]
    for c in silent:
        w.add(c)
    assert not kept.dropped and sum(c.dropped for c in silent) == 4 and len(w) == 3
    w.discard(kept)
    assert len(w) == 2


def test_token_file_with_a_byte_order_mark_and_bracketed_ipv6_host(tmp_path):
    """Probe s42 AY: a token file saved with a UTF-8 byte-order mark was refused with a raw
    UnicodeDecodeError; ``--host [::1]`` passed the port check and then failed in uvicorn."""
    import subprocess
    import sys

    from hykin.compensation.service_guard import read_token_file

    f = tmp_path / "tok"
    f.write_bytes(b"\xef\xbb\xbfs3cret-token\r\n")
    assert read_token_file(f) == "s3cret-token"
    f.write_bytes("tökén".encode())
    with pytest.raises(ValueError, match="printable ASCII"):
        read_token_file(f)
    if not socket.has_ipv6:
        return
    try:
        with socket.socket(socket.AF_INET6, socket.SOCK_STREAM) as s:
            s.bind(("::1", 0))
    except OSError:
        return  # no IPv6 loopback here
    port = free_port()
    p = subprocess.Popen([sys.executable, "-m", "hykin", "serve", str(tiny_model_file()), "--host", "[::1]", "--port",
                          str(port)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.time() + 60
        import httpx

        while time.time() < deadline:
            try:
                if httpx.get(f"http://[::1]:{port}/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                time.sleep(0.3)
            assert p.poll() is None, p.stdout.read()
        else:
            raise AssertionError("no answer on [::1]")
    finally:
        p.terminate()
        out = p.communicate(timeout=20)[0]
    assert f"http://[::1]:{port}" in out
