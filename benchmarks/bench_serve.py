"""``hykin serve`` benchmark (issue #25, "Service"): streaming, HTTP batches, and streaming under a flood.

The service runs as the CLI does (``hykin serve MODEL --token-file ...`` in a subprocess on
127.0.0.1); every request carries the bearer token. Model: a UR10 with geometric deviations drawn here
(several mm of nominal error), fitted on 1,000 noise-free simulated poses (``max_epochs`` 5), or
``--model PATH``. Targets: the model's poses along a smooth joint path (reachable, on one branch).

1. **Streaming** (WebSocket ``/stream``): one target per message at ``--rate`` Hz (default 250) for
   ``--seconds`` (the issue asks 600); each message carries the joints of the previous answer, as a
   robot streaming its actual joints would. Round-trip latency per target (send → its reply), p50 /
   p99 / max, replies over one period late, and messages lost (no reply, a reply out of order, or an
   error reply). Peer in the same run: ``Compensator.step`` on the same targets in-process (no server).
2. **HTTP batches**: ``POST /compensate`` with 100 targets per request, one client, keep-alive, its
   JSON written and read with orjson (as the service's): targets/s. Peer: the in-process
   ``Compensator`` on the same batches.
3. **Flood**: the streaming client again, in alternating blocks of ``--block-s`` seconds without
   and with a second client (a subprocess, ``--flood-connections`` raw-socket connections sending as
   fast as it is answered: malformed JSON, wrong shapes, no token, and bodies announced at 100 MB).
   p99 of the flood blocks over the p99 of the quiet blocks (alternating blocks, so that the load of
   other jobs on this shared machine hits both alike); the flood's request rate and the server's
   refusal counts (``/health``).

Every loop is bounded and stops by itself (the flood subprocess also stops after its block).
Loopback only. Wall times are on a shared 2-core machine: other jobs inflate them.

    python benchmarks/bench_serve.py [--model PATH] [--seconds 60] [--rate 250] [--http-requests 200]
                                     [--blocks 3] [--block-s 20] [--flood-connections 4]
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import socket
import subprocess
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from _timing import cpu_s  # noqa: E402

TOKEN = "bench-serve-token-0123456789"


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def fit_model(path: Path):
    from hykin import load_robot
    from hykin.hybrid.model import HybridModel
    from hykin.sim.simulate import VirtualRobot, geometric_deviation, simulate

    nom = load_robot("ur10")
    truth = geometric_deviation(nom, np.random.default_rng(25), 5e-4, np.radians(0.08), 5e-4, np.radians(0.08)).copy(name="ur10-truth")
    vr = VirtualRobot("ur10-serve", nom, truth)
    t = time.perf_counter()
    m = HybridModel(nom, recipe_kw={"max_epochs": 5}, seed=0).fit(simulate(vr, nom.random_joints(1000, 1, margin=0.05), noise=False),
                                                                 progress=False)
    print(f"  fitted {vr.name}: 1,000 poses, {time.perf_counter() - t:.0f} s -> {path}")
    m.save(path)
    return m


def smooth_path(m, n: int, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """``(n, dof)`` joints along a smooth path (sinusoids, periods 7..19 s, inside the data range) and
    the model's ``(n, 4, 4)`` poses there (the targets)."""
    nom = m.nominal
    t = np.arange(n) / rate_hz
    mid = np.array([0.3, -1.4, 1.5, -1.6, -1.5, 0.2])[: nom.dof]
    amp = np.array([0.5, 0.25, 0.35, 0.4, 0.4, 0.6])[: nom.dof]
    per = np.array([11.0, 7.0, 13.0, 17.0, 19.0, 9.0])[: nom.dof]
    q = mid + amp * np.sin(2 * np.pi * t[:, None] / per)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return q, m.predict(q)


def _rows(T: np.ndarray) -> list:
    from hykin.geometry import se3

    xyz, quat = se3.transform_to_pose(T)
    return np.column_stack([xyz, quat]).tolist()


def start_server(model_path: Path, tmp: Path, server_args: str = "") -> tuple[subprocess.Popen, int]:
    import httpx

    tok = tmp / "token"
    tok.write_text(TOKEN + "\n")
    port = _free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen([sys.executable, "-m", "hykin", "serve", str(model_path), "--port", str(port), "--token-file", str(tok),
                             *shlex.split(server_args)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    t0 = time.time()
    while True:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/health", timeout=5).status_code == 200:
                return proc, port
        except httpx.TransportError:
            pass
        if time.time() - t0 > 180 or proc.poll() is not None:
            proc.kill()
            raise SystemExit(f"server did not start: {proc.stderr.read().decode()[-800:]}")
        time.sleep(0.2)


def stream(port: int, rows: list, q0: np.ndarray, rate_hz: float) -> dict:
    """Stream ``rows`` at ``rate_hz`` over one WebSocket (one asyncio thread, no helper thread);
    latencies (s) and the failures."""
    import asyncio

    from websockets.asyncio.client import connect

    period = 1.0 / rate_hz
    n = len(rows)
    lat = np.full(n, np.nan)

    async def run():
        lost, errors, q_last = 0, [], q0.tolist()
        async with connect(f"ws://127.0.0.1:{port}/stream", additional_headers={"Authorization": f"Bearer {TOKEN}"},
                           open_timeout=30, max_size=2**20, ping_interval=None, compression=None) as ws:
            await ws.send(json.dumps({"target": rows[0], "q": q_last}))  # warm-up (not counted)
            await asyncio.wait_for(ws.recv(), 30)
            t_start = time.perf_counter() + 0.05
            for k in range(n):
                due = t_start + k * period
                while (now := time.perf_counter()) < due:
                    if due - now > 0.0015:
                        await asyncio.sleep(due - now - 0.001)
                t = time.perf_counter()
                await ws.send(json.dumps({"target": rows[k], "q": q_last, "id": k}))
                try:
                    r = json.loads(await asyncio.wait_for(ws.recv(), 5))
                except TimeoutError:
                    lost += 1
                    continue
                lat[k] = time.perf_counter() - t
                if r.get("id") != k or r.get("seq") != k + 2 or not r.get("success"):
                    lost += 1
                    errors.append(r.get("error") or r.get("reason") or f"id {r.get('id')} for {k}")
                else:
                    q_last = r["q"]
        return lost, errors

    lost, errors = asyncio.run(run())
    return {"lat": lat, "lost": lost, "errors": errors[:3], "period": period}


def _lat_line(name: str, s: dict) -> str:
    ms = s["lat"][np.isfinite(s["lat"])] * 1e3
    late = int((ms > s["period"] * 1e3).sum())
    return (f"  {name}: {len(s['lat'])} targets, p50 {np.percentile(ms, 50):.3f} ms, p99 {np.percentile(ms, 99):.3f} ms, "
            f"max {ms.max():.2f} ms; over one period ({s['period'] * 1e3:.0f} ms): {late}; lost {s['lost']}"
            + (f" ({s['errors']})" if s["errors"] else ""))


def in_process_steps(m, T: np.ndarray, q0: np.ndarray) -> np.ndarray:
    from hykin.compensation.compensator import Compensator

    c = Compensator(m)
    c.step(T[0], q0)
    ts, q = [], q0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for k in range(len(T)):
            t = time.perf_counter()
            r = c.step(T[k], q)
            ts.append(time.perf_counter() - t)
            q = r.q if r.success else q
    return np.array(ts)


def http_batches(port: int, m, T: np.ndarray, q: np.ndarray, n_req: int, batch: int = 100) -> None:
    import httpx

    from hykin.compensation.compensator import Compensator

    import orjson

    rows = _rows(T)
    hdr = {"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"}
    with httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=60, headers=hdr) as c:
        c.post("/compensate", content=orjson.dumps({"targets": rows[:batch], "q_current": q[:batch].tolist()}))
        ok, t0 = 0, time.perf_counter()
        for r in range(n_req):  # the client's JSON with orjson as well: its own costs are not the service's
            sl = slice(r * batch, (r + 1) * batch)
            resp = c.post("/compensate", content=orjson.dumps({"targets": rows[sl], "q_current": q[sl].tolist()}))
            ok += resp.status_code == 200 and all(orjson.loads(resp.content)["success"])
        wall = time.perf_counter() - t0
    comp = Compensator(m)
    reps = min(n_req, 50)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        for r in range(reps):
            sl = slice(r * batch, (r + 1) * batch)
            comp(T[sl], q_branch=q[sl])
        inproc = batch * reps / (time.perf_counter() - t)
    rate = batch * n_req / wall
    print(f"  HTTP /compensate, {batch} targets/request, {n_req} requests: {rate:,.0f} targets/s ({ok}/{n_req} all-success); "
          f"in-process Compensator on the same batches {inproc:,.0f} targets/s (service at {rate / inproc:.2f}x)")
    print(f"  must hold >= 10,000 targets/s: {'MET' if rate >= 10_000 else 'NOT MET'}")


# --------------------------------------------------------------------------- the flood (a subprocess)

def _flood_requests(port: int) -> list[tuple[bytes, bool]]:
    """(raw request, whether the server closes the connection after it)."""
    host = f"127.0.0.1:{port}"
    auth = f"Authorization: Bearer {TOKEN}\r\n"

    def post(path, body: bytes, headers: str = auth, length: int | None = None) -> bytes:
        n = len(body) if length is None else length
        return (f"POST {path} HTTP/1.1\r\nHost: {host}\r\n{headers}Content-Type: application/json\r\nContent-Length: {n}\r\n\r\n"
                ).encode() + body

    return [(post("/compensate", b"{not json"), False),
            (post("/fk", b'{"q": [[1, 2, 3]]}'), False),
            (post("/compensate", b'{"targets": [[0.5, 0, 0.5, 2, 0, 0, 0]]}'), False),
            (post("/fk", b'{"q": [[0, 0, 0, 0, 0, 0]]}', headers=""), False),  # no token
            (post("/compensate", b"[" * 4096, length=100_000_000), True)]  # announced 100 MB


def _read_response(sock: socket.socket) -> int:
    """Read one HTTP response; its status code (0 when the server closed)."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(65536)
        if not chunk:
            return 0
        buf += chunk
    head, _, body = buf.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    n = next((int(h.split(":", 1)[1]) for h in lines[1:] if h.lower().startswith("content-length:")), 0)
    while len(body) < n:
        chunk = sock.recv(65536)
        if not chunk:
            break
        body += chunk
    return int(lines[0].split()[1])


def flood_main(port: int, seconds: float, connections: int) -> None:
    reqs = _flood_requests(port)
    stop = time.perf_counter() + seconds
    counts = [0] * connections
    codes: dict = {}

    def worker(i: int) -> None:
        sock, k = None, i
        while time.perf_counter() < stop:
            raw, closes = reqs[k % len(reqs)]
            k += 1
            try:
                if sock is None:
                    sock = socket.create_connection(("127.0.0.1", port), timeout=5)
                sock.sendall(raw)
                code = _read_response(sock)
                codes[code] = codes.get(code, 0) + 1
                counts[i] += 1
                if closes or code == 0:
                    sock.close()
                    sock = None
            except OSError:
                if sock is not None:
                    sock.close()
                sock = None
        if sock is not None:
            sock.close()

    ths = [threading.Thread(target=worker, args=(i,)) for i in range(connections)]
    for t in ths:
        t.start()
    print("ready", flush=True)
    for t in ths:
        t.join()
    print(json.dumps({"requests": sum(counts), "seconds": seconds, "codes": codes}), flush=True)


def flood_study(port: int, pid: int, rows: list, q0: np.ndarray, a) -> None:
    import httpx

    quiet, flood, rates, cpu = [], [], [], {"quiet": 0.0, "flood": 0.0}
    per = int(a.block_s * a.rate)
    for b in range(a.blocks):
        for kind in ("quiet", "flood"):
            sl = rows[(2 * b + (kind == "flood")) * per % max(len(rows) - per, 1):][:per]
            proc = None
            if kind == "flood":
                proc = subprocess.Popen([sys.executable, __file__, "--flood-port", str(port), "--flood-seconds", str(a.block_s + 2),
                                         "--flood-connections", str(a.flood_connections)], stdout=subprocess.PIPE, text=True)
                assert proc.stdout.readline().strip() == "ready"
                time.sleep(0.5)
            c0 = cpu_s(pid)
            s = stream(port, sl, q0, a.rate)
            cpu[kind] += cpu_s(pid) - c0
            (flood if kind == "flood" else quiet).append(s)
            if proc is not None:
                out = json.loads(proc.stdout.readline())
                proc.wait(30)
                rates.append(out["requests"] / out["seconds"])
                codes = out["codes"]
            print(f"  block {b + 1} {kind}: p99 {np.nanpercentile(s['lat'], 99) * 1e3:.3f} ms, lost {s['lost']}"
                  + (f"; flood {rates[-1]:,.0f} requests/s, status codes {codes}" if proc else ""))
    pool = {k: {"lat": np.concatenate([s["lat"] for s in v]), "lost": sum(s["lost"] for s in v),
                "errors": sum((s["errors"] for s in v), []), "period": 1 / a.rate} for k, v in (("quiet", quiet), ("flood", flood))}
    print(_lat_line("quiet blocks", pool["quiet"]))
    print(_lat_line("flood blocks", pool["flood"]))
    ratio = np.nanpercentile(pool["flood"]["lat"], 99) / np.nanpercentile(pool["quiet"]["lat"], 99)
    h = httpx.get(f"http://127.0.0.1:{port}/health").json()
    secs = a.blocks * a.block_s
    print(f"  flood: {np.mean(rates):,.0f} requests/s on {a.flood_connections} connections; server counts {h['counts']}")
    print(f"  server CPU: {cpu['quiet'] / secs * 100:.1f} % of a core in quiet blocks, {cpu['flood'] / secs * 100:.1f} % in flood blocks")
    print(f"  p99 with flood / without: {ratio:.2f}x; must hold <= 1.2x and none lost: "
          f"{'MET' if ratio <= 1.2 and pool['flood']['lost'] == 0 else 'NOT MET'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", type=Path, help="model file (default: fit one here)")
    ap.add_argument("--seconds", type=float, default=60.0, help="part 1 duration (the issue: 600)")
    ap.add_argument("--rate", type=float, default=250.0, help="streaming rate, Hz")
    ap.add_argument("--http-requests", type=int, default=200)
    ap.add_argument("--blocks", type=int, default=3, help="part 3: quiet/flood block pairs")
    ap.add_argument("--block-s", type=float, default=20.0, help="part 3: seconds per block")
    ap.add_argument("--flood-connections", type=int, default=4)
    ap.add_argument("--parts", default="123")
    ap.add_argument("--server-args", default="", help='more `hykin serve` options, e.g. "--rt-priority 20"')
    ap.add_argument("--flood-port", type=int, help=argparse.SUPPRESS)
    ap.add_argument("--flood-seconds", type=float, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.flood_port:
        flood_main(a.flood_port, a.flood_seconds, a.flood_connections)
        return
    from hykin.hybrid.model import HybridModel

    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        if a.model is None:
            a.model = tmp / "ur10-serve.hykin"
            m = fit_model(a.model)
        else:
            m = HybridModel.load(a.model)
        n = int(a.seconds * a.rate)
        q, T = smooth_path(m, max(n, int(a.block_s * a.rate) * 2 * a.blocks, 100 * a.http_requests), a.rate)
        rows = _rows(T)
        steps = in_process_steps(m, T[: min(n, 2000)], q[0]) * 1e3
        print(f"  in-process Compensator.step, {len(steps)} targets of the path: p50 {np.percentile(steps, 50):.3f} ms, "
              f"p99 {np.percentile(steps, 99):.3f} ms, max {steps.max():.2f} ms")
        proc, port = start_server(a.model, tmp, a.server_args)
        try:
            if "1" in a.parts:
                print(f"1. streaming: WebSocket /stream, {a.rate:.0f} Hz, {a.seconds:.0f} s")
                c0 = cpu_s(proc.pid)
                s = stream(port, rows[:n], q[0], a.rate)
                print(_lat_line("stream", s))
                print(f"  server CPU per streamed target: {(cpu_s(proc.pid) - c0) / n * 1e3:.3f} ms "
                      f"(in-process step p50 {np.percentile(steps, 50):.3f} ms)")
                p99 = np.nanpercentile(s["lat"], 99) * 1e3
                print(f"  must hold p99 <= 2 ms, none lost: {'MET' if p99 <= 2 and s['lost'] == 0 else 'NOT MET'}")
            if "2" in a.parts:
                print("2. HTTP batches")
                http_batches(port, m, T, q, a.http_requests)
            if "3" in a.parts:
                print(f"3. streaming under a flood: {a.blocks} x ({a.block_s:.0f} s quiet, {a.block_s:.0f} s flood)")
                flood_study(port, proc.pid, rows, q[0], a)
        finally:
            proc.terminate()
            proc.wait(10)


if __name__ == "__main__":
    main()
