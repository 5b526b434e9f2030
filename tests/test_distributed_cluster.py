"""hykin sweep / hykin fleet on a multi-node Ray cluster on this machine (issue #29, slow): a head and a
worker node started as separate ``ray start`` processes on 127.0.0.1 (1 CPU each, their own ports and
temp dir), the CLI run as a separate driver with ``--address``, and both nodes stopped at the end --
by the process ids this test started, also when it fails."""

from __future__ import annotations

import csv
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from procs import alive, descendants, proc_table

from hykin.io.dataset_files import read_dataset, write_dataset
from hykin.io.robot_file import load_robot

pytestmark = [pytest.mark.slow,
              pytest.mark.skipif(not sys.platform.startswith("linux"), reason="finds the nodes' processes in /proc (Linux)")]

ROOT = Path(__file__).resolve().parents[1]


def _free_ports(n: int) -> list[int]:
    socks = [socket.socket() for _ in range(n)]
    for s in socks:
        s.bind(("127.0.0.1", 0))
    ports = [s.getsockname()[1] for s in socks]
    for s in socks:
        s.close()
    return ports


def _cluster_pids(temp_dir: str) -> list[int]:
    """The processes of the nodes started with ``temp_dir`` (its path is in their command lines) and all
    their descendants (the workers)."""
    table = proc_table()
    ours = [p for p, row in table.items() if temp_dir in row[1] and p != os.getpid()]
    return ours + [p for p in descendants(ours, table) if p not in ours]


def _stop(temp_dir: str) -> None:
    """SIGTERM, then SIGKILL, to this cluster's processes only (never `ray stop`: it stops every Ray
    on the machine)."""
    for sig, wait in ((signal.SIGTERM, 5.0), (signal.SIGKILL, 2.0)):
        pids = _cluster_pids(temp_dir)
        for p in pids:
            try:
                os.kill(p, sig)
            except ProcessLookupError:
                pass
        t_end = time.time() + wait
        while pids and time.time() < t_end:
            pids = [p for p in pids if alive(p)]
            time.sleep(0.2)


_TOKEN = secrets.token_hex(32)  # Ray >= 2.5x authenticates nodes and drivers: one token for this cluster


def _env() -> dict:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])), OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1",
               RAY_USAGE_STATS_ENABLED="0", RAY_AUTH_MODE="token", RAY_AUTH_TOKEN=_TOKEN)
    env.pop("RAY_AUTH_TOKEN_PATH", None)
    env.pop("RAY_ADDRESS", None)
    return env


@pytest.fixture(scope="module")
def cluster():
    """``127.0.0.1:PORT`` of a head (1 CPU) + one worker node (1 CPU); stopped at the end."""
    ray_bin = Path(sys.executable).parent / "ray"
    if not ray_bin.is_file():
        pytest.skip(f"Ray's `ray` command not next to {sys.executable} (pip install 'hykin[distributed]')")
    temp_dir = tempfile.mkdtemp(prefix="hkray-", dir="/tmp")  # short: Ray's socket paths have a length limit
    p = _free_ports(14)
    common = ["--num-cpus", "1", "--num-gpus", "0", "--disable-usage-stats", "--node-ip-address", "127.0.0.1"]
    head = [str(ray_bin), "start", "--head", "--port", str(p[0]),
            "--include-dashboard", "false", "--temp-dir", temp_dir, "--node-manager-port", str(p[2]),
            "--object-manager-port", str(p[3]), "--dashboard-agent-listen-port", str(p[4]),
            "--dashboard-agent-grpc-port", str(p[5]), "--runtime-env-agent-port", str(p[6]),
            "--metrics-export-port", str(p[7]), *common]
    worker = [str(ray_bin), "start", "--address", f"127.0.0.1:{p[0]}", "--node-manager-port", str(p[8]),
              "--object-manager-port", str(p[9]), "--dashboard-agent-listen-port", str(p[10]),
              "--dashboard-agent-grpc-port", str(p[11]), "--runtime-env-agent-port", str(p[12]),
              "--metrics-export-port", str(p[13]), *common]
    try:
        for cmd in (head, worker):
            r = subprocess.run(cmd, env=_env(), capture_output=True, text=True, timeout=300)
            assert r.returncode == 0, f"{' '.join(cmd[:3])} failed:\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
        yield f"127.0.0.1:{p[0]}"
    finally:
        _stop(temp_dir)
        shutil.rmtree(temp_dir, ignore_errors=True)


def _hykin(args, timeout=900):
    r = subprocess.run([sys.executable, "-m", "hykin", *map(str, args)], env=_env(), capture_output=True, text=True,
                       timeout=timeout)
    return r.returncode, r.stdout, r.stderr


def _csv(path):
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    from test_distributed import _data

    d = tmp_path_factory.mktemp("cluster")
    rob = load_robot("rx160")
    for name, n, seed in (("train.csv", 200, 1), ("test.csv", 60, 2), ("day2.csv", 40, 3)):
        write_dataset(_data(rob, n, seed), d / name)
    return d


def test_sweep_and_fleet_on_a_two_node_cluster(cluster, files):
    from hykin.distributed.trials import run_trial

    (files / "s.toml").write_text('robot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n[grid]\nseed = [0, 1]\n'
                                  "max_epochs = [3]\nmin_steps = [0]\n", encoding="utf-8")
    code, out, err = _hykin(["sweep", files / "s.toml", "-o", files / "sweep-out", "--address", cluster])
    assert code == 0, out + err
    rows = _csv(files / "sweep-out" / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "ok"]
    # the same trials in this process (no Ray): the same numbers, to the last digit written
    rob = load_robot("rx160")
    train, test = read_dataset(files / "train.csv", robot=rob), read_dataset(files / "test.csv", robot=rob)
    for r, seed in zip(rows, (0, 1)):
        ref = run_trial(rob, train, test, {"seed": seed, "max_epochs": 3, "min_steps": 0}, threads=1)
        np.testing.assert_allclose(float(r["hybrid_pos_mean_mm"]), ref["hybrid_pos_mean_mm"], rtol=1e-12)
        np.testing.assert_allclose(float(r["calibrated_pos_mean_mm"]), ref["calibrated_pos_mean_mm"], rtol=1e-12)
    # both nodes ran a trial (one CPU each, two trials at once)
    import json

    recs = [json.loads(line)["row"]["timing"] for line in (files / "sweep-out" / "trials.jsonl").read_text().splitlines()]
    assert len({t["node"] for t in recs}) == 2, recs

    fleet = "".join(f'[[robot]]\nname = "cell-{i}"\nrobot = "rx160"\ntrain = "train.csv"\ntest = "test.csv"\n'
                    + ('register = "day2.csv"\nposes = 20\n' if i == 1 else "")
                    + f"[robot.fit]\nmin_steps = 0\nmax_epochs = 2\nseed = {i}\n" for i in (1, 2, 3))
    (files / "f.toml").write_text(fleet, encoding="utf-8")
    code, out, err = _hykin(["fleet", files / "f.toml", "-o", files / "fleet-out", "--address", cluster])
    assert code == 0, out + err
    summ = _csv(files / "fleet-out" / "summary.csv")
    assert [(r["name"], r["status"]) for r in summ] == [("cell-1", "ok"), ("cell-2", "ok"), ("cell-3", "ok")]
    assert all(float(r["hybrid_pos_mean_mm"]) < float(r["nominal_pos_mean_mm"]) for r in summ)
    assert all((files / "fleet-out" / f"cell-{i}.hykin").is_file() for i in (1, 2, 3))
    assert (files / "fleet-out" / "cell-1-registered.hykin").is_file()
