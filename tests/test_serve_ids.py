"""``hykin serve``: stream ids that orjson cannot write back, and unknown fields named by a lone
surrogate (an in-process uvicorn server on 127.0.0.1).

* An id that cannot be written as JSON (a lone surrogate ``"\\ud800"``) gets an error reply without an
  id, and the stream stays open (docs/serve.md: a bad message never closes the stream).
* Ids orjson cannot write but JSON can (integers beyond 64 bits, nesting past orjson's 254) are
  echoed exactly: checked against the standard library's reading of the id's own text.
* ``{"\\ud800": 1}`` on /compensate, /fk, /ik: 422 naming the field escaped, counted as a refusal.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from shared_fixtures import free_port, start_server
from comp_models import tiny_model_file

from hykin.geometry import se3

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")
httpx = pytest.importorskip("httpx")


_free_port = free_port


@pytest.fixture(scope="module")
def server():
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    mp = tiny_model_file()
    m = HybridModel.load(mp)
    port = _free_port()
    srv, th = start_server(m, port, ServiceLimits(refusal_delay_s=0.0), model_identity(mp))
    client = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
    yield client, m, port
    client.close()
    srv.should_exit = True
    th.join(10)


def _row(T):
    xyz, quat = se3.transform_to_pose(T[None])
    return np.concatenate([xyz[0], quat[0]]).tolist()


def _check_answer(r, m, T):
    assert r["success"] is True and r["reason"] == ""
    qa = np.array(r["q"])
    assert se3.pose_error(m.predict(qa[None]), T[None])[0][0] < 1e-6  # the model reaches the target


# id as JSON text, whether it is echoed (else: an error reply without id)
IDS = [('"\\ud800"', False), ('{"k": ["a\\udfff"]}', False), ('"\\ud83d\\ude00 ok"', True),
       ("[" * 300 + "]" * 300, True), ("[" * 254 + "7" + "]" * 254, True),
       (str(2**64), True), (str(2**64 - 1), True), (str(-(2**63) - 1), True), (str(10**40), True),
       ('[1, 2.5, {"n": 123456789012345678901234567890}]', True), ("1.5", True), ('"plain"', True), ("null", True)]


def test_stream_ids_echoed_exactly_or_refused_without_closing(server):
    from websockets.sync.client import connect

    c, m, port = server
    q = m.nominal.random_joints(len(IDS) + 1, 5, margin=0.3)
    T = m.predict(q)
    before = c.get("/health").json()["counts"]
    with connect(f"ws://127.0.0.1:{port}/stream", open_timeout=30) as ws:
        for i, (idtext, echoed) in enumerate(IDS):
            ws.send('{"target": %s, "q": %s, "id": %s}' % (json.dumps(_row(T[i])), json.dumps(q[i].tolist()), idtext))
            r = json.loads(ws.recv(timeout=60))  # the standard library: exact big integers
            assert r["seq"] == 2 * i + 1
            if echoed:
                assert r["id"] == json.loads(idtext) and type(r["id"]) is type(json.loads(idtext)), idtext[:40]
                _check_answer(r, m, T[i])
            else:
                assert "id" not in r and "'id' cannot be echoed" in r["error"] and "no 'id'" in r["error"]
                assert "success" not in r
            # the stream is still open and answers the next message (q from the last answer or given)
            ws.send(json.dumps({"target": _row(T[i + 1]), "q": q[i + 1].tolist(), "id": i}))
            r2 = json.loads(ws.recv(timeout=60))
            assert r2["seq"] == 2 * i + 2 and r2["id"] == i
            _check_answer(r2, m, T[i + 1])
    after = c.get("/health").json()["counts"]
    n_bad = sum(not e for _, e in IDS)
    assert after.get("refused_stream_message", 0) - before.get("refused_stream_message", 0) == n_bad
    assert after["answered_stream"] - before.get("answered_stream", 0) == 2 * len(IDS) - n_bad


def test_big_integer_id_text_is_exact(server):
    """The digits themselves come back (not a float's rounding), also with an error reply."""
    from websockets.sync.client import connect

    _, _, port = server
    big = 2**64 + 1
    with connect(f"ws://127.0.0.1:{port}/stream", open_timeout=30) as ws:
        ws.send('{"target": [1, 2], "id": %d}' % big)  # invalid target: error reply with the id
        text = ws.recv(timeout=60)
    assert f'"id":{big}' in text.replace(" ", "") and "error" in json.loads(text)


@pytest.mark.parametrize("path", ["/compensate", "/fk", "/ik"])
def test_unknown_field_named_by_a_lone_surrogate_is_422(server, path):
    c, _, _ = server
    before = c.get("/health").json()["counts"].get("refused_invalid", 0)
    r = c.post(path, content=b'{"\\ud800": 1}', headers={"Content-Type": "application/json"})
    assert r.status_code == 422
    d = r.json()["detail"]
    assert "unknown field" in d and "\\ud800" in d  # the name, escaped
    assert c.get("/health").json()["counts"]["refused_invalid"] == before + 1
    r = c.post(path, content=b'{"a\\udc00b": 1, "zz": 2}', headers={"Content-Type": "application/json"})
    assert r.status_code == 422 and "a\\udc00b" in r.json()["detail"] and "zz" in r.json()["detail"]
