"""Small helpers shared by several test modules (not a test module): free TCP ports, sweep/fleet
datasets and files."""

from __future__ import annotations

import socket

import numpy as np

from hykin.geometry.se3 import rotvec_to_matrix
from hykin.io.dataset import Dataset
from hykin.kinematics.fk import fk


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def residual_data(robot, n: int, seed: int) -> Dataset:
    """Poses with a smooth residual the classical model cannot express (so calibration leaves > 0.01 mm)."""
    q = robot.random_joints(n, seed, margin=0.1)
    T = fk(robot, q)
    T[:, :3, 3] += 2e-4 * np.stack([np.sin(q[:, 0]), np.cos(q[:, 1]), np.sin(q[:, 2] + q[:, 1])], 1)
    T[:, :3, :3] = rotvec_to_matrix(1e-4 * np.stack([np.cos(q[:, 0]), np.sin(q[:, 3]), 0.5 * q[:, 1]], 1)) @ T[:, :3, :3]
    return Dataset.from_poses(q, T, orientation=True)


def dh_robot_toml(name: str, rows, tail: str = "") -> str:
    """A DH robot file (lengths m, angles deg) of ``rows`` ``[(a, alpha, d, theta, min, max)]`` and ``tail``
    (e.g. ``[tool]`` / ``[base]`` tables)."""
    head = f'name = "{name}"\nconvention = "dh"\nlength_unit = "m"\nangle_unit = "deg"\n'
    joints = "".join(f"\n[[joints]]\na = {a}\nalpha = {al}\nd = {d}\ntheta = {th}\nmin = {lo}\nmax = {hi}\n"
                     for a, al, d, th, lo, hi in rows)
    return head + joints + tail


def write_text(path, text: str):
    """Write ``text`` (UTF-8) to ``path``; returns ``path``."""
    path.write_text(text, encoding="utf-8")
    return path


def sweep_files(d, n_day2: int):
    """rx160 train (240), test (80) and day-2 (``n_day2``) datasets of :func:`residual_data` in ``d``."""
    from hykin.io.dataset_files import write_dataset
    from hykin.io.robot_file import load_robot

    rob = load_robot("rx160")
    write_dataset(residual_data(rob, 240, 1), d / "train.csv")
    write_dataset(residual_data(rob, 80, 2), d / "test.csv")
    write_dataset(residual_data(rob, n_day2, 3), d / "day2.csv")
    return d


def start_server(model, port: int, limits, identity):
    """``hykin serve``'s app for ``model`` on 127.0.0.1:``port`` in a thread; returns ``(server, thread)``
    once it has started (``server.should_exit = True`` then ``thread.join()`` stops it)."""
    import threading
    import time

    import uvicorn

    from hykin.compensation.service import uvicorn_config

    srv = uvicorn.Server(uvicorn_config(model, "127.0.0.1", port, limits, identity))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    t0 = time.time()
    while not srv.started:
        assert th.is_alive() and time.time() - t0 < 60, "in-process server did not start"
        time.sleep(0.05)
    return srv, th


def sine_trajectory(seed: int = 1):
    """``t (N,) s -> q (N, 6) rad``: a smooth multi-sine joint trajectory (stream tests)."""
    rng = np.random.default_rng(seed)
    q0 = np.array([0.1, -0.3, 0.6, 0.0, 0.5, 0.0])
    A = np.array([0.5, 0.3, 0.3, 0.6, 0.4, 0.8])
    f = np.array([0.11, 0.07, 0.13, 0.17, 0.19, 0.23])
    ph = rng.uniform(0, 6, 6)
    return lambda t: q0 + A * np.sin(2 * np.pi * f * np.asarray(t)[:, None] + ph)


def fake_sweep_ray(monkeypatch, data: list | None = None):
    """run_sweep without Ray: the session and trial runner are stand-ins (every trial "ok", errors 0.1 mm);
    returns ``(hykin.distributed.sweep, calls)``: the trials each run got, sorted. ``data``: a list the
    datasets each run got are appended to."""
    import contextlib

    import hykin.distributed.sweep as sweep_mod
    from hykin.distributed.trials import ERROR_COLUMNS

    calls = []

    def fake_run_trials(ray, trials, data_, cpus, gpus, subsample_seed, on_done):
        calls.append(sorted(trials))
        if data is not None:
            data.append(data_)
        for i in trials:
            on_done(i, {"status": "ok", "error": "", "attempts": 1, "n_train": 240, **dict.fromkeys(ERROR_COLUMNS, 0.1),
                        "fit_s": 1.0, "eval_s": 0.1, "steps": 4, "epochs": 2})

    monkeypatch.setattr(sweep_mod, "ray_session", lambda address, num_cpus: contextlib.nullcontext(None))
    monkeypatch.setattr(sweep_mod, "check_resources", lambda *a, **k: None)
    monkeypatch.setattr(sweep_mod, "run_trials", fake_run_trials)
    monkeypatch.setattr(sweep_mod, "plot_results", lambda rows, path: None)  # matplotlib: not under test, slow
    return sweep_mod, calls


def pose_rows(T) -> list:
    """Poses ``(N, 4, 4)`` as the service's target rows ``[x, y, z, qw, qx, qy, qz]`` (m)."""
    from hykin.geometry import se3

    xyz, quat = se3.transform_to_pose(T)
    return np.column_stack([xyz, quat]).tolist()
