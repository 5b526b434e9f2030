"""The compensation service of ``hykin serve``: fk, ik and compensate over HTTP, JSON in and out.

FastAPI app (:func:`create_app`); the model is loaded once. Endpoints (all batches; SI units: m, rad):

* ``GET /health`` → ``{"status": "ok", "model": name, "dof": n, "version": ...}``
* ``POST /fk`` ``{"q": [[q1..qn], ...]}`` → ``{"poses": [[x,y,z,qw,qx,qy,qz], ...], "in_support": [...]}``
* ``POST /ik`` ``{"targets": [[x,y,z,qw,qx,qy,qz] or [x,y,z], ...], "q_current": [[..]] or [..]}`` →
  per target the hybrid-IK solution nearest ``q_current`` (default zero): ``q`` (null when
  unreachable), ``success``, ``pos_err_mm``, ``ang_err_deg``, ``reason``.
* ``POST /compensate`` ``{"targets": ..., "q_current": optional, "frame": "measurement"|"base"|"auto"}``
  → ``commands`` (controller base frame, null when unreachable), ``q``, ``success``, ``pos_err_mm``,
  ``ang_err_deg``, ``shift_mm``, ``status`` (:func:`hykin.compensation.compensate`; without
  ``q_current`` each target's branch is the nominal solution nearest the previous target's).

Bad requests (malformed JSON, wrong shapes, NaN/inf, unknown fields, too many targets) get 400/422
with ``{"detail": reason}`` and never stop the server; model calls are serialised by a lock (the
model is not re-entrant). FastAPI is imported only here.

(No ``from __future__ import annotations``: FastAPI reads the endpoints' ``Request`` annotations at
run time, and ``Request`` is imported inside :func:`create_app`.)
"""

import json
import math
import threading

import numpy as np

__all__ = ["MAX_TARGETS", "RequestError", "create_app"]

MAX_TARGETS = 10_000


class RequestError(ValueError):
    """A request the service cannot answer: ``status`` (400/422) and a one-line reason."""

    def __init__(self, reason: str, status: int = 422):
        super().__init__(reason)
        self.status = status


def _matrix(body: dict, key: str, widths: tuple, required: bool = True):
    """``body[key]`` as a finite float64 ``(N, w)`` array, ``w`` in ``widths`` (one row may be flat)."""
    if key not in body or body[key] is None:
        if required:
            raise RequestError(f"missing field '{key}'")
        return None
    v = body[key]
    if not isinstance(v, list) or not v:
        raise RequestError(f"'{key}' must be a non-empty list of rows")
    if not isinstance(v[0], list):
        v = [v]
    if len(v) > MAX_TARGETS:
        raise RequestError(f"'{key}': {len(v)} rows, at most {MAX_TARGETS} per request")
    for i, row in enumerate(v):
        if not isinstance(row, list) or any(isinstance(x, bool) or not isinstance(x, (int, float)) for x in row):
            raise RequestError(f"'{key}' row {i}: expected a list of numbers")
    lens = {len(r) for r in v}
    if len(lens) != 1 or next(iter(lens)) not in widths:
        raise RequestError(f"'{key}': every row must have {' or '.join(map(str, widths))} numbers, got lengths {sorted(lens)}")
    a = np.asarray(v, dtype=np.float64)
    bad = ~np.isfinite(a)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise RequestError(f"'{key}' row {i}, column {j}: not a finite number")
    return a


def _poses(a: np.ndarray) -> np.ndarray:
    """``(N, 7)`` rows ``x,y,z,qw,qx,qy,qz`` -> ``(N, 4, 4)``; ``(N, 3)`` positions kept."""
    from ..geometry import se3

    if a.shape[1] == 3:
        return a
    n = np.linalg.norm(a[:, 3:], axis=1)
    if np.any(np.abs(n - 1) > 1e-3):
        i = int(np.argmax(np.abs(n - 1) > 1e-3))
        raise RequestError(f"'targets' row {i}: quaternion norm {n[i]:.6f}, expected 1")
    return se3.pose_to_transform(a[:, :3], a[:, 3:] / n[:, None])


def _pose_rows(T: np.ndarray, ok: np.ndarray) -> list:
    from ..geometry import se3

    xyz, quat = se3.transform_to_pose(np.where(np.isfinite(T), T, np.eye(4)))
    rows = np.concatenate([xyz, quat], 1).tolist()
    return [r if k else None for r, k in zip(rows, ok.tolist())]


def _floats(a) -> list:
    return [float(x) if math.isfinite(x) else None for x in np.asarray(a, dtype=np.float64).tolist()]


def _check_keys(body, allowed: set) -> dict:
    if not isinstance(body, dict):
        raise RequestError("the body must be a JSON object")
    extra = set(body) - allowed
    if extra:
        raise RequestError(f"unknown field(s): {', '.join(sorted(extra))}; allowed: {', '.join(sorted(allowed))}")
    return body


class Handlers:
    """The computations behind the endpoints (plain functions of parsed JSON; testable without HTTP)."""

    def __init__(self, model):
        self.model = model
        self.dof = model.nominal.dof
        self.lock = threading.Lock()

    def _q(self, body, key, required=True):
        q = _matrix(body, key, (self.dof,), required)
        return q

    def fk(self, body) -> dict:
        body = _check_keys(body, {"q"})
        q = self._q(body, "q")
        import warnings

        with self.lock, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            T = self.model.predict(q)
            sup = self.model.support_distance(q) if hasattr(self.model, "support_distance") else np.zeros(len(q))
        return {"poses": _pose_rows(T, np.ones(len(q), bool)), "in_support": (np.asarray(sup) <= 0).tolist()}

    def ik(self, body) -> dict:
        from ..hybrid.ik import hybrid_ik
        from .targets import first_row_per_target

        body = _check_keys(body, {"targets", "q_current"})
        a = _matrix(body, "targets", (3, 7))
        qc = self._q(body, "q_current", required=False)
        if qc is not None and len(qc) not in (1, len(a)):
            raise RequestError(f"'q_current': {len(qc)} rows, expected 1 or {len(a)}")
        T = _poses(a)
        nom = self.model.nominal
        qc = np.broadcast_to(np.clip(np.zeros(self.dof), nom.lower, nom.upper) if qc is None else qc, (len(a), self.dof))
        import warnings

        with self.lock, warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = hybrid_ik(self.model, T, all_branches=True, q_current=np.ascontiguousarray(qc), nearest=True)
        N = len(a)
        q = np.full((N, self.dof), np.nan)
        ok = np.zeros(N, bool)
        pe, ae = np.full(N, np.nan), np.full(N, np.nan)
        reason = np.array(["unreachable"] * N, dtype=object)
        k = first_row_per_target(res)
        t = res.target[k]
        q[t], ok[t], pe[t], ae[t], reason[t] = res.q[k], res.success[k], res.pos_err_mm[k], res.ang_err_deg[k], res.reason[k]
        return {"q": [r if k else None for r, k in zip(q.tolist(), ok.tolist())], "success": ok.tolist(),
                "pos_err_mm": _floats(pe), "ang_err_deg": _floats(ae), "reason": ["" if k else str(r) for r, k in zip(reason.tolist(), ok.tolist())]}

    def compensate(self, body) -> dict:
        from .targets import FRAMES, compensate

        body = _check_keys(body, {"targets", "q_current", "frame"})
        a = _matrix(body, "targets", (3, 7))
        qc = self._q(body, "q_current", required=False)
        if qc is not None and len(qc) not in (1, len(a)):
            raise RequestError(f"'q_current': {len(qc)} rows, expected 1 or {len(a)}")
        frame = body.get("frame", "measurement")
        if frame not in FRAMES:
            raise RequestError(f"'frame' must be one of {', '.join(FRAMES)}, got {frame!r}")
        T = _poses(a)
        with self.lock:
            c = compensate(self.model, T, q_branch=qc, frame=frame)
        return {"commands": _pose_rows(c.command, c.success), "q": [r if k else None for r, k in zip(c.q.tolist(), c.success.tolist())],
                "success": c.success.tolist(), "pos_err_mm": _floats(c.pos_err_mm), "ang_err_deg": _floats(c.ang_err_deg),
                "shift_mm": _floats(c.shift_mm), "status": ["ok" if k else r for r, k in zip(c.reason.tolist(), c.success.tolist())],
                "frame": c.frame}


def create_app(model):
    """The FastAPI app serving ``model`` (a fitted :class:`hykin.hybrid.model.HybridModel`)."""
    from fastapi import FastAPI, Request
    from fastapi.responses import JSONResponse
    from starlette.concurrency import run_in_threadpool

    from .. import __version__

    h = Handlers(model)
    app = FastAPI(title="hykin compensation service", version=__version__)

    async def _run(request: Request, fn):
        raw = await request.body()
        try:
            body = json.loads(raw)
        except (ValueError, UnicodeDecodeError) as e:
            return JSONResponse({"detail": f"malformed JSON: {e}"}, status_code=400)
        try:
            return JSONResponse(await run_in_threadpool(fn, body))
        except RequestError as e:
            return JSONResponse({"detail": str(e)}, status_code=e.status)
        except ValueError as e:  # the model's own input checks (one line)
            return JSONResponse({"detail": str(e).splitlines()[0] if str(e) else type(e).__name__}, status_code=422)

    @app.get("/health")
    async def health():
        return {"status": "ok", "model": model.nominal.name, "dof": h.dof, "version": __version__}

    @app.post("/fk")
    async def fk(request: Request):
        return await _run(request, h.fk)

    @app.post("/ik")
    async def ik(request: Request):
        return await _run(request, h.ik)

    @app.post("/compensate")
    async def comp(request: Request):
        return await _run(request, h.compensate)

    return app
