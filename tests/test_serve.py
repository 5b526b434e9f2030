"""``hykin serve``: a real uvicorn server in a subprocess on 127.0.0.1, hit with httpx.

Health, fk/ik/compensate answers checked against the model called in-process, malformed bodies
(4xx with a reason), unreachable targets, and a bounded load loop after which the server still
answers. The 2,000-request loop is marked slow; the default suite runs 200.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from shared_fixtures import free_port, start_server, pose_rows
from comp_models import tiny_model_file

from hykin import fk
from hykin.geometry import se3

# the model's own out-of-range warning is expected here: the queries are random joints
pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")

httpx = pytest.importorskip("httpx")
ROOT = Path(__file__).resolve().parents[1]


_free_port = free_port


@pytest.fixture(scope="module")
def server():
    mp = tiny_model_file()
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])), OMP_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-c", "from hykin.cli import main; main()", "serve", str(mp), "--port", str(port)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
    t0 = time.time()
    while True:
        try:
            if client.get("/health").status_code == 200:
                break
        except httpx.TransportError:
            pass
        if proc.poll() is not None or time.time() - t0 > 120:
            proc.kill()
            pytest.fail(f"server did not start: {proc.stderr.read().decode()[-500:]}")
        time.sleep(0.2)
    from hykin.hybrid.model import HybridModel

    yield client, HybridModel.load(mp), proc
    client.close()
    proc.terminate()
    try:
        proc.wait(60)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait(10)


def test_health_fk_ik_compensate(server):
    c, m, _ = server
    h = c.get("/health").json()
    assert h["status"] == "ok" and h["dof"] == 6
    q = m.nominal.random_joints(5, 3, margin=0.2)
    r = c.post("/fk", json={"q": q.tolist()})
    assert r.status_code == 200
    P = np.array(r.json()["poses"])
    T = m.predict(q)
    assert np.abs(P[:, :3] - T[:, :3, 3]).max() < 1e-12
    r = c.post("/ik", json={"targets": pose_rows(T), "q_current": q.tolist()}).json()
    assert all(r["success"]) and se3.pose_error(m.predict(np.array(r["q"])), T)[0].max() < 1e-6
    far = pose_rows(T)
    far[1][:3] = [5.0, 0.0, 0.0]
    r = c.post("/compensate", json={"targets": far, "q_current": q.tolist()})
    assert r.status_code == 200
    j = r.json()
    assert j["success"] == [True, False, True, True, True]
    assert j["commands"][1] is None and j["q"][1] is None and j["status"][1] != "ok"
    qa = np.array([j["q"][k] for k in (0, 2, 3, 4)])
    cmd = np.array([j["commands"][k] for k in (0, 2, 3, 4)])
    assert np.abs(cmd[:, :3] - fk(m.nominal, qa)[:, :3, 3]).max() < 1e-12
    assert se3.pose_error(m.predict(qa), T[[0, 2, 3, 4]])[0].max() < 1e-6
    one = c.post("/compensate", json={"targets": pose_rows(T)[0][:3]})  # one flat position-only row
    assert one.status_code == 200 and one.json()["success"] == [True]


@pytest.mark.parametrize("path, body, status, word", [
    ("/fk", b"{not json", 400, "malformed JSON"),
    ("/fk", b"[1, 2]", 422, "JSON object"),
    ("/fk", b'{"q": [[1, 2, 3]]}', 422, "6 numbers"),
    ("/fk", b'{"q": [[0, 0, 0, 0, 0, NaN]]}', 422, "finite"),
    ("/fk", b'{"q": [[0, 0, 0, 0, 0, "a"]]}', 422, "numbers"),
    ("/fk", b'{"joints": []}', 422, "unknown field"),
    ("/ik", b'{"targets": [[0.5, 0, 0.5, 2, 0, 0, 0]]}', 422, "quaternion"),
    ("/ik", b'{"targets": []}', 422, "non-empty"),
    ("/compensate", b'{"targets": [[0.5, 0, 0.5]], "frame": "tool"}', 422, "frame"),
    ("/compensate", b'{"targets": [[0.5, 0, 0.5], [0.5, 0, 0.6]], "q_current": [[0,0,0,0,0,0],[0,0,0,0,0,0],[0,0,0,0,0,0]]}', 422, "q_current"),
    ("/compensate", b'{"targets": [[0.5, 0, 0.5, 1]]}', 422, "3 or 7"),
])
def test_bad_requests_get_4xx_with_a_reason(server, path, body, status, word):
    c, _, proc = server
    r = c.post(path, content=body, headers={"content-type": "application/json"})
    assert r.status_code == status and word in r.json()["detail"]
    assert proc.poll() is None


def _load(c, m, n_requests: int, budget_s: float):
    q = m.nominal.random_joints(8, 5, margin=0.2)
    good = {"q": q[:1].tolist()}
    t0 = time.perf_counter()
    codes = []
    for i in range(n_requests):
        if i % 10 == 9:
            codes.append(c.post("/fk", content=b'{"q": [[1, 2]]}').status_code)
        else:
            codes.append(c.post("/fk", json=good).status_code)
        assert time.perf_counter() - t0 < budget_s, "load loop over its time budget"
    assert codes.count(422) == n_requests // 10 and codes.count(200) == n_requests - n_requests // 10
    assert c.get("/health").status_code == 200


def test_load_loop_server_survives(server):
    c, m, proc = server
    _load(c, m, 200, 60)
    assert proc.poll() is None


@pytest.mark.slow
def test_load_loop_2000(server):
    c, m, proc = server
    _load(c, m, 2000, 300)
    assert proc.poll() is None


# --------------------------------------------------------------------------- streaming, token, limits, health
# An in-process server (uvicorn in a thread, the model already loaded) with a token and small limits.

TOKEN = "s3cret-Token_42"
DELAY_S = 0.05


@pytest.fixture(scope="module")
def guarded():
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    mp = tiny_model_file()
    m = HybridModel.load(mp)
    port = _free_port()
    limits = ServiceLimits(max_body_bytes=64 * 1024, max_message_bytes=1024, token=TOKEN, refusal_delay_s=DELAY_S)
    t_load = time.time()
    srv, th = start_server(m, port, limits, model_identity(mp))
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
    yield client, m, mp, port, t_load
    client.close()
    srv.should_exit = True
    th.join(10)


def _auth(token=TOKEN):
    return {"Authorization": f"Bearer {token}"}


def test_health_reports_the_model_files_hash_and_load_time(guarded):
    import hashlib
    from datetime import datetime

    from safetensors import safe_open

    c, m, mp, _, t_load = guarded
    h = c.get("/health").json()  # open without the token
    with safe_open(str(mp), framework="pt") as f:
        assert h["model_sha256"] == f.metadata()["content_sha256"]
    assert h["file_sha256"] == hashlib.sha256(Path(mp).read_bytes()).hexdigest()
    loaded = datetime.fromisoformat(h["loaded_at"]).timestamp()
    assert t_load - 1 <= loaded <= time.time() and h["dof"] == 6 and h["model"] == m.nominal.name


def test_bearer_token_and_body_limit(guarded):
    c, m, *_ = guarded
    body = {"q": m.nominal.random_joints(2, 1, margin=0.2).tolist()}
    t = time.perf_counter()
    r = c.post("/fk", json=body)
    assert time.perf_counter() - t >= DELAY_S  # refusals are answered after the refusal delay
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer" and "token" in r.json()["detail"]
    assert c.post("/fk", json=body, headers=_auth("wrong")).status_code == 401
    assert c.post("/fk", json=body, headers={"Authorization": TOKEN}).status_code == 401  # no scheme
    assert c.post("/fk", json=body, headers=_auth()).status_code == 200
    big = b'{"q": [' + b",".join([b"[0,0,0,0,0,0]"] * 6000) + b"]}"  # 84 KB > 64 KiB
    r = httpx.post(f"{str(c.base_url).rstrip('/')}/fk", content=big, headers={**_auth(), "content-type": "application/json"})
    assert r.status_code == 413 and "65536" in r.json()["detail"]
    counts = c.get("/health").json()["counts"]
    assert counts["refused_auth"] == 3 and counts["refused_size"] == 1
    assert c.post("/fk", json=body, headers=_auth()).status_code == 200  # still answering


def _stream_url(port, frame=None):
    return f"ws://127.0.0.1:{port}/stream" + (f"?frame={frame}" if frame else "")


def test_stream_replies_in_order_and_survives_bad_messages(guarded):
    import json

    from websockets.sync.client import connect

    _, m, _, port, _ = guarded
    nom = m.nominal
    q = nom.random_joints(5, 11, margin=0.3)
    T = m.predict(q)
    rows = pose_rows(T)
    msgs = [json.dumps({"target": rows[0], "id": "first"}),  # no q yet: refused
            json.dumps({"target": rows[0], "q": q[0].tolist(), "id": 0}),
            "{not json",
            json.dumps({"target": rows[1], "id": 1}),  # q from the last answer
            json.dumps({"target": rows[2], "q": q[2].tolist(), "id": 2, "extra": 1}),
            json.dumps({"target": [4.0, 0, 0, 1, 0, 0, 0], "q": q[2].tolist(), "id": "far"}),
            json.dumps({"target": rows[3][:3], "q": q[3].tolist()}),
            json.dumps({"target": rows[4], "q": q[4].tolist(), "id": 4})]
    with connect(_stream_url(port), additional_headers=_auth(), open_timeout=30) as ws:
        for s in msgs:  # pipelined: all sent before the first reply is read
            ws.send(s)
        replies = [json.loads(ws.recv(timeout=60)) for _ in msgs]
    assert [r["seq"] for r in replies] == list(range(1, len(msgs) + 1))
    assert [r.get("id") for r in replies] == ["first", 0, None, 1, 2, "far", None, 4]
    assert "'q'" in replies[0]["error"] and "malformed" in replies[2]["error"]
    assert "unknown field" in replies[4]["error"] and "7 numbers" in replies[6]["error"]
    assert replies[5]["success"] is False and replies[5]["command"] is None and replies[5]["reason"]
    for r, k in zip((replies[1], replies[3], replies[7]), (0, 1, 4)):
        assert r["success"] is True and r["reason"] == ""
        qa = np.array(r["q"])
        assert se3.pose_error(m.predict(qa[None]), T[k:k + 1])[0][0] < 1e-6  # the model reaches the target
        cmd = np.array(r["command"])
        ref = np.linalg.inv(nom.base) @ fk(nom, qa[None])[0]  # what a nominal controller is asked for
        assert np.abs(cmd[:3] - ref[:3, 3]).max() < 1e-12
        assert se3.pose_error(se3.pose_to_transform(cmd[None, :3], cmd[None, 3:]), ref[None])[1][0] < 1e-9


def test_stream_refusals_close_codes(guarded):
    import json

    from websockets.exceptions import ConnectionClosed, InvalidStatus
    from websockets.sync.client import connect

    c, m, _, port, _ = guarded
    for headers, frame in ((None, None), (_auth("nope"), None), (_auth(), "tool")):
        with pytest.raises(InvalidStatus) as e:
            connect(_stream_url(port, frame), additional_headers=headers, open_timeout=30)
        assert e.value.response.status_code == 403
    with connect(_stream_url(port), additional_headers=_auth(), open_timeout=30) as ws:
        ws.send(json.dumps({"target": [0.5, 0, 0.5, 1, 0, 0, 0], "q": [0.0] * 6, "pad": "x" * 2000}))
        with pytest.raises(ConnectionClosed) as e:
            ws.recv(timeout=30)
        assert e.value.rcvd.code == 1009
    assert c.get("/health").status_code == 200


def test_model_worker_bounded_queue_and_stream_priority():
    import asyncio
    import threading

    from hykin.compensation.service_guard import BATCH, STREAM, ModelWorker, QueueFull

    gate, order = threading.Event(), []

    async def main():
        w = ModelWorker(2)
        first = w.submit(BATCH, gate.wait, 30)  # holds the thread
        a = w.submit(BATCH, order.append, "batch")
        with pytest.raises(QueueFull, match="limit 2"):
            w.submit(BATCH, order.append, "refused")
        b = w.submit(STREAM, order.append, "stream")  # batches fill the queue; a streamed step still goes in
        assert w.pending == 3
        gate.set()
        await asyncio.wait_for(asyncio.gather(first, a, b), 30)
        bad = w.submit(STREAM, int, "x")  # an exception reaches the awaiting caller, the thread goes on
        with pytest.raises(ValueError):
            await asyncio.wait_for(bad, 30)
        assert await asyncio.wait_for(w.submit(BATCH, sum, [1, 2]), 30) == 3 and w.pending == 0
        w.close()

    asyncio.run(main())
    assert order == ["stream", "batch"]


@pytest.mark.parametrize("text, word", [("", "empty"), ("two words", "spaces"), ("tøken", "read")])
def test_cli_serve_refuses_a_bad_token_file(tmp_path, text, word):
    from typer.testing import CliRunner

    from hykin.cli import app

    p = tmp_path / "token.txt"
    p.write_bytes(text.encode())
    r = CliRunner().invoke(app, ["serve", str(tiny_model_file()), "--token-file", str(p)])
    msg = str(r.exception or r.output)
    assert r.exit_code != 0 and str(p) in msg and word in msg


def test_cli_serve_refuses_a_zero_limit():
    from typer.testing import CliRunner

    from hykin.cli import app

    r = CliRunner().invoke(app, ["serve", str(tiny_model_file()), "--queue", "0"])
    assert r.exit_code != 0 and "--queue" in str(r.exception or r.output)
    r = CliRunner().invoke(app, ["serve", str(tiny_model_file()), "--rt-priority", "120"])
    assert r.exit_code != 0 and "--rt-priority" in str(r.exception or r.output)


def test_row_checks_fast_path_agrees_with_the_per_number_checks():
    """Valid rows take one C pass (:func:`_fast_rows`, :func:`_one_row`) and give the same arrays as the
    per-number checks (a reference written here); every invalid row still gets the reason naming it."""
    from hykin.compensation.service_requests import RequestError, _fast_rows, _one_row, matrix

    rng = np.random.default_rng(3)
    rows = rng.normal(size=(5, 7)).tolist()
    rows[2][1] = 3  # a JSON integer
    ref = np.array([[float(x) for x in r] for r in rows])
    assert np.array_equal(_fast_rows(rows, (7,), 10), ref) and np.array_equal(matrix({"t": rows}, "t", (7,), 10), ref)
    assert np.array_equal(_fast_rows(rows[0], (7,), 1), ref[:1]) and _one_row(rows[2], 7) == ref[2].tolist()
    for bad, word in (([1.0, True, 2.0], "list of numbers"), ([1.0, "2", 3.0], "list of numbers"),
                      ([1.0, float("nan"), 3.0], "column 1: not a finite"), ([1.0, 10**400, 3.0], "column 1: not a finite"),
                      ([[1.0, 2.0, 3.0], [1.0, 2.0]], "every row must have 3"), ([], "non-empty")):
        assert _fast_rows(bad, (3,), 5) is None and _one_row(bad, 3) is None
        with pytest.raises(RequestError, match=word):
            matrix({"t": bad}, "t", (3,), 5)
