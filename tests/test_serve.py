"""``hykin serve``: a real uvicorn server in a subprocess on 127.0.0.1, hit with httpx.

Health, fk/ik/compensate answers checked against the model called in-process, malformed bodies
(4xx with a reason), unreachable targets, and a bounded load loop after which the server still
answers. The 2,000-request loop is marked slow; the default suite runs 200.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from comp_models import tiny_model_file

from hykin import fk
from hykin.geometry import se3

httpx = pytest.importorskip("httpx")
ROOT = Path(__file__).resolve().parents[1]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server():
    mp = tiny_model_file()
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_NUM_THREADS="1")
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
    proc.wait(10)


def _rows(T):
    xyz, quat = se3.transform_to_pose(T)
    return np.column_stack([xyz, quat]).tolist()


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
    r = c.post("/ik", json={"targets": _rows(T), "q_current": q.tolist()}).json()
    assert all(r["success"]) and se3.pose_error(m.predict(np.array(r["q"])), T)[0].max() < 1e-6
    far = _rows(T)
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
    one = c.post("/compensate", json={"targets": _rows(T)[0][:3]})  # one flat position-only row
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
