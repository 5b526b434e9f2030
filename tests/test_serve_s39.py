"""``hykin serve`` (probeQ fixes): joints in degrees / outside the limits get 422 naming field, row,
column and cause; replies carry the training-support columns of the CLI; targets in mm get a unit
reason; served /ik says "out of reach" as the CLI; a bad ?frame= names the parameter; the connection
limit refuses exactly over its count with a JSON reason counted in /health; a taken port fails first."""

from __future__ import annotations

import asyncio
import collections
import json
import socket

import numpy as np
import pytest
from comp_models import tiny_model_file
from shared_fixtures import free_port, start_server, pose_rows

from hykin.geometry import se3

pytestmark = pytest.mark.filterwarnings("ignore::hykin.hybrid.errors.OutOfRangeWarning")
httpx = pytest.importorskip("httpx")


@pytest.fixture(scope="module")
def srv():
    from hykin.compensation.service_guard import ServiceLimits, model_identity
    from hykin.hybrid.model import HybridModel

    m = HybridModel.load(tiny_model_file())
    port = free_port()
    server, th = start_server(m, port, ServiceLimits(refusal_delay_s=0), model_identity(None))
    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60)
    yield c, m, port
    c.close()
    server.should_exit = True
    th.join(30)


def test_joints_in_degrees_or_outside_limits_are_refused_naming_field_row_column(srv):
    c, m, port = srv
    q = m.nominal.random_joints(4, 3, margin=0.3)
    rows = pose_rows(m.predict(q))
    qd = np.degrees(q)
    j = int(np.flatnonzero(np.abs(qd[0]) > 2 * np.pi + 0.5)[0])
    for path, body, key in (("/compensate", {"targets": rows, "q_current": qd.tolist()}, "q_current"),
                            ("/ik", {"targets": rows, "q_current": qd.tolist()}, "q_current"),
                            ("/fk", {"q": qd.tolist()}, "q")):
        r = c.post(path, json=body)
        d = r.json()["detail"]
        assert r.status_code == 422, (path, r.text[:200])
        assert f"'{key}' row 0, column {j} (q{j + 1})" in d and "likely degrees passed as radians" in d
        assert f"{qd[0, j]:.6g}" in d
    # within ±2π but outside the limits of a robot whose limits are narrower: a limits refusal
    lim = np.array(m.nominal.upper, dtype=float)
    qq = q[:1].copy()
    qq[0, 2] = lim[2] + 0.05 if lim[2] + 0.05 <= 2 * np.pi + 0.5 else qq[0, 2]
    if qq[0, 2] != q[0, 2]:
        r = c.post("/compensate", json={"targets": rows[:1], "q_current": qq.tolist()})
        assert r.status_code == 422 and "row 0, column 2 (q3)" in r.json()["detail"]
    assert c.post("/compensate", json={"targets": rows, "q_current": q.tolist()}).status_code == 200
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{port}/stream", open_timeout=30) as ws:
        ws.send(json.dumps({"target": rows[0], "q": qd[0].tolist()}))
        rep = json.loads(ws.recv(timeout=30))
    assert "'q' row 0" in rep["error"] and "likely degrees passed as radians" in rep["error"]


def test_replies_say_where_the_correction_fades(srv):
    c, m, port = srv
    nom = m.nominal
    q = nom.random_joints(400, 7, margin=0.0)
    out = np.asarray(m.support_distance(q)) > 0
    assert out.any() and (~out).any()
    pick = np.r_[np.flatnonzero(out)[:3], np.flatnonzero(~out)[:3]]
    qs = q[pick]
    rows = pose_rows(m.predict(qs))
    r = c.post("/compensate", json={"targets": rows, "q_current": qs.tolist()}).json()
    assert all(r["success"])
    qa = np.array(r["q"])
    # the support at the returned joints, judged by the model's own support query and by /fk
    ref = np.asarray(m.support_distance(qa)) <= 0
    assert r["in_support"] == ref.tolist() and r["outside_support"] == int((~ref).sum()) >= 1
    assert str(int((~ref).sum())) in r["warning"] and "training support" in r["warning"]
    assert c.post("/fk", json={"q": qa.tolist()}).json()["in_support"] == r["in_support"]
    assert all((d > 0) != s for d, s in zip(r["support_distance"], r["in_support"]))
    ik = c.post("/ik", json={"targets": rows, "q_current": qs.tolist()}).json()
    assert ik["in_support"] == (np.asarray(m.support_distance(np.array(ik["q"]))) <= 0).tolist()
    from websockets.sync.client import connect

    with connect(f"ws://127.0.0.1:{port}/stream", open_timeout=30) as ws:
        ws.send(json.dumps({"target": rows[0], "q": qs[0].tolist()}))
        rep = json.loads(ws.recv(timeout=30))
    assert rep["success"] and rep["in_support"] == bool(np.asarray(m.support_distance(np.array([rep["q"]])))[0] <= 0)


def test_targets_in_mm_and_out_of_reach_reasons(srv):
    c, m, port = srv
    nom = m.nominal
    q = nom.random_joints(3, 5, margin=0.3)
    rows = np.array(pose_rows(m.predict(q)))
    mm = rows.copy()
    mm[:, :3] *= 1000
    r = c.post("/compensate", json={"targets": mm.tolist()})
    d = r.json()["detail"]
    assert r.status_code == 422 and "'targets' row 0" in d and "millimetres passed as metres" in d
    # independent reach: UR10's DH lengths (a2, a3 and the offsets along z) bound the reach from above
    far = 3.0  # m, beyond any UR10 reach (about 1.3 m)
    r = c.post("/ik", json={"targets": [[far, 0.0, 0.5]]}).json()
    assert r["success"] == [False] and r["reason"][0].startswith("out of reach: farther from the base than the robot reaches")


def test_bad_stream_frame_names_the_parameter(srv):
    from websockets.exceptions import InvalidStatus
    from websockets.sync.client import connect

    c, _, port = srv
    with pytest.raises(InvalidStatus) as e:
        connect(f"ws://127.0.0.1:{port}/stream?frame=bogus", open_timeout=30)
    assert e.value.response.status_code == 403
    body = json.loads(bytes(e.value.response.body))
    assert "'frame'" in body["detail"] and "bogus" in body["detail"]


def test_connection_limit_lets_exactly_the_limit_through_and_says_why():
    from hykin.compensation.service import ConnectionLimit

    gate = asyncio.Event()
    served = []

    async def app(scope, receive, send):
        await gate.wait()
        served.append(1)
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b"ok"})

    counts = collections.Counter()
    mw = ConnectionLimit(app, limit=3, counts=counts)

    async def one():
        sent = []

        async def send(msg):
            sent.append(msg)

        await mw({"type": "http", "path": "/compensate"}, None, send)
        return sent

    async def main():
        tasks = [asyncio.create_task(one()) for _ in range(6)]
        await asyncio.sleep(0.05)
        gate.set()
        return await asyncio.gather(*tasks)

    res = asyncio.run(main())
    status = [r[0]["status"] for r in res]
    assert status.count(200) == 3 and status.count(503) == 3 and len(served) == 3
    refused = next(r for r in res if r[0]["status"] == 503)
    assert (b"retry-after", b"1") in refused[0]["headers"]
    assert "--max-connections" in json.loads(refused[1]["body"])["detail"]
    assert counts["refused_connections"] == 3 and mw.active == 0


def test_serve_fails_first_when_the_port_is_taken(capsys):
    from hykin.cli import main

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        with pytest.raises(SystemExit) as e:
            main(["serve", "no-model-loaded-before-the-port.hykin", "--port", str(port)])
    cap = capsys.readouterr()
    err = cap.err.strip().splitlines()
    assert e.value.code == 2 and len(err) == 1 and f"--port {port}" in err[0] and "hykin serve:" not in cap.out
