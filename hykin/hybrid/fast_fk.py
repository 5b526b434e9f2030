"""Hybrid FK compiled: the whole prediction of :meth:`hykin.HybridModel.predict` for one pose in one
numba function (joint deflection under gravity, chain walk, network coordinates, fade, both residual
networks, the correction and the registration frames), with no per-call Python or numpy overhead.

:func:`kernel_of` packs a fitted model into plain arrays once (:class:`HybridKernel`, cached on the
model and rebuilt when its weights, robot, frames or fade change). ``hybrid_one`` is the compiled
per-pose function that :mod:`hykin.hybrid.fast_ik` (hybrid LM) calls; :func:`predict_fast` the
batched one that ``HybridModel.predict`` (and so ``hykin fk``, ``hykin ik``, hybrid IK and the
compensation) uses for batches under :data:`COMPILED_MAX` poses.

Same operations and numbers as the numpy path: deflection with
:func:`hykin.kinematics.compliance.deflect_one`, the chain walk of :mod:`hykin.kinematics.walk`, the
pair gap of :func:`hykin.hybrid.support.pair_gap_row`, the rotation of
:func:`hykin.hybrid.rotations.rotate_top`, and the networks as :mod:`hykin.hybrid.fast_nets` does them
(float32 weights in float64 arithmetic; dense nets and Chen ResNets, BatchNorm folded). Differences
to the numpy path are rounding of the summation order (tested within 1e-9 mm).

Not compiled (``kernel_of`` returns None and callers use the numpy path): numba missing, ``fade="full"``
(nearest-neighbour gap over a k-d tree), an explicit payload or temperature (per-call arguments).
"""

from __future__ import annotations

import operator
from dataclasses import dataclass

import numpy as np

from ..kinematics.chunks import run_chunked
from ..kinematics.fk import HAVE_NUMBA
from . import fast_nets
from .fast_act import ACT_CODES as _ACT

__all__ = ["COMPILED_MAX", "HybridKernel", "P_KINDS", "kernel_of", "pack_args", "pack_net", "predict_fast", "prepare"]

#: batches at least this large predict through the numpy path (the networks as BLAS matrix products
#: of :mod:`hykin.hybrid.fast_nets` beat per-pose matrix-vector products there; same numbers to rounding)
COMPILED_MAX = 64

_DENSE, _ADD, _ACTOP, _COPY = 0, 1, 2, 3


def pack_net(fn: fast_nets.FastNet) -> tuple:
    """A :class:`~hykin.hybrid.fast_nets.FastNet` as ``(ops (K, 7) int64, weights (W,), lower, upper,
    out_bias, meta [out_scale, features (0 minmax01, 1 trig), widest layer])``. ops rows
    ``[code, src, dst, offset, n_in, n_out, act]`` over 4 buffers (0 = layer input x)."""
    ops, chunks, off, widest = [], [], 0, 3 * len(fn.lower)

    def dense(W, b, src, dst, act):
        nonlocal off
        ops.append([_DENSE, src, dst, off, W.shape[0], W.shape[1], _ACT[act]])
        chunks.extend([W.reshape(-1), b])
        off += W.size + b.size
        return W.shape[1]

    width = widest
    for L in fn.layers:
        cur, nxt = 0, 1
        for W, b, act in L.main:
            width = dense(W, b, cur, nxt, act)
            widest = max(widest, width)
            cur, nxt = nxt, (2 if nxt == 1 else 1)
        if isinstance(L.shortcut, str):
            ops.append([_ADD, 0, cur, 0, 0, width, 0])
        elif L.shortcut is not None:
            dense(L.shortcut[0], L.shortcut[1], 0, 3, None)
            ops.append([_ADD, 3, cur, 0, 0, width, 0])
        if L.act is not None:
            ops.append([_ACTOP, cur, cur, 0, 0, width, _ACT[L.act]])
        ops.append([_COPY, cur, 0, 0, 0, width, 0])
    meta = np.array([fn.out_scale, 0.0 if fn.features == "minmax01" else 1.0, float(widest)])
    return (np.array(ops, dtype=np.int64).reshape(-1, 7), np.concatenate(chunks), fn.lower.copy(),
            fn.upper.copy(), fn.out_bias.copy(), meta)


@dataclass
class HybridKernel:
    """A fitted model packed for the compiled kernels. ``P``: the tuple ``hybrid_one`` takes; ``args``:
    the same packed into three flat arrays (:func:`pack_args`: what the Python-called kernels take, as
    numba's dispatch types a 43-item tuple in ~5 µs, three arrays in well under 1); ``dof``;
    ``refs``/``vals``/``tensors``/``versions``: what it was built from (:func:`kernel_of`; the cache check
    compares ``refs`` by identity, ``vals`` by value, ``versions`` with the tensors' version counters)."""

    P: tuple
    dof: int
    refs: tuple
    vals: tuple
    tensors: list
    versions: tuple
    args: tuple = ()


#: the kind of each item of ``HybridKernel.P`` (in order): f/i/b = float64/int64/bool array of that many
#: dimensions, "fs"/"is"/"bs" = float/int/bool scalar. ``unpack`` rebuilds the tuple in this order.
P_KINDS = ("f3", "b1", "bs", "f3", "f3", "f1", "b1", "f2", "f1", "fs", "f1", "f1", "f1", "f1", "bs", "f1", "is",
           "f1", "f1", "f1", "fs", "fs", "i1", "i1", "f3", "bs", "f1",
           "i2", "f1", "f1", "f1", "f1", "f1", "bs", "i2", "f1", "f1", "f1", "f1", "f1",
           "bs", "f2", "f2")


def pack_args(P: tuple) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``P`` (items of :data:`P_KINDS`) as ``(F float64, G int64, B bool)`` flat arrays: ``G`` starts with
    a header of 4 ints per item (offset into its array, up to 3 dimensions), then the int items."""
    if len(P) != len(P_KINDS):
        raise ValueError(f"kernel tuple has {len(P)} items, the layout {len(P_KINDS)}")
    head = np.zeros((len(P), 4), dtype=np.int64)
    F, G, B = [], [], []
    nf, ng, nb = 0, head.size, 0  # next free offset in F, G (after the header), B
    for i, (kind, v) in enumerate(zip(P_KINDS, P)):
        a = np.asarray(v)
        if kind[1] == "s":
            a = a.reshape(1)
        elif a.ndim != int(kind[1]):
            raise ValueError(f"kernel item {i} has {a.ndim} dimensions, the layout {kind[1]}")
        dims = a.shape if kind[1] != "s" else ()
        if kind[0] == "f":
            head[i, 0], nf = nf, nf + a.size
            F.append(a.astype(np.float64).ravel())
        elif kind[0] == "i":
            head[i, 0], ng = ng, ng + a.size
            G.append(a.astype(np.int64).ravel())
        else:
            head[i, 0], nb = nb, nb + a.size
            B.append(a.astype(np.bool_).ravel())
        head[i, 1:1 + len(dims)] = dims
    cat = lambda parts, dt: np.ascontiguousarray(np.concatenate(parts) if parts else np.zeros(0), dtype=dt)
    return cat(F, np.float64), cat([head.ravel(), *G], np.int64), cat(B, np.bool_)


#: what a kernel is built from: these attributes' objects (compared by identity) ...
_refs = operator.attrgetter("net_pos_", "net_rot_", "robot_", "frame_pre_", "frame_post_", "pair_gap_", "wrap_centre_",
                            "support_lower_", "support_upper_", "j1_axis_", "payload_range_")


def _vals(model) -> tuple:
    """... and these settings (compared by value)."""
    return (model.fade, model.fade_offset_, model.fade_width_, model.payload_input_,
            getattr(model, "payload_default_kg_", None))


_version = operator.attrgetter("_version")


def _current(model, k: HybridKernel) -> bool:
    """Whether the cached kernel ``k`` was built from what ``model`` holds now: the same objects, the
    same fade / payload settings, and no network weight changed in place (torch version counters)."""
    return (all(map(operator.is_, _refs(model), k.refs)) and _vals(model) == k.vals
            and tuple(map(_version, k.tensors)) == k.versions)


def kernel_of(model) -> HybridKernel | None:
    """The :class:`HybridKernel` of a fitted :class:`hykin.HybridModel` (cached on it; rebuilt when one
    of its networks, robot, frames, support or fade settings is replaced or a network's weights change
    in place), or None when the model cannot run compiled (module docstring)."""
    k = model.__dict__.get("_fast_kernel")
    if k is not None and _current(model, k):
        return k
    if not HAVE_NUMBA or model.fade == "full" or getattr(model, "net_pos_", None) is None:
        return None
    if model.robot_.n_chain != model.robot_.dof:  # <mimic> joints: the kernel walks independent joints only
        return None
    from ..kinematics.chain import chain_of
    from ..kinematics.compliance import compliance_of, kernel_args

    rob = model.robot_
    n = rob.dof
    ch = chain_of(rob)
    comp = bool(rob.has_compliance)
    kf, kpost, ppt, kpr, com, mass, kg, g = kernel_args(rob, 1)
    C = compliance_of(rob) if comp else np.zeros(n)
    wrap = np.asarray(model.wrap_centre_, dtype=np.float64)
    mask = np.asarray(model.input_mask_, dtype=np.float64)
    pin = np.zeros(1)
    if model.payload_input_:
        from ..io.payload import payload_column

        kgd = rob.payload_kg if model.payload_default_kg_ is None else model.payload_default_kg_
        pin = payload_column(np.zeros((1, 0)), kgd, model.payload_range_)[0]  # the clamped default payload
    s = model.support
    mode = 0 if model.fade is False else (1 if model.fade == "range" else 2)
    pairs = np.asarray(s.pair_index, dtype=np.int64).reshape(-1, 2)
    field = np.ascontiguousarray(s.pair_gap, dtype=np.float64)
    if field.ndim != 3:
        field = np.zeros((0, 2, 2))
    j1 = np.zeros(3) if model.j1_axis_ is None else np.asarray(model.j1_axis_, dtype=np.float64)
    pos = pack_net(fast_nets.cached(model, model.net_pos_).fast)
    has_rot = model.net_rot_ is not None
    rot = pack_net(fast_nets.cached(model, model.net_rot_).fast) if has_rot else pos
    framed = not (np.array_equal(model.frame_pre_, np.eye(4)) and np.array_equal(model.frame_post_, np.eye(4)))
    c = lambda x: np.ascontiguousarray(x, dtype=np.float64)
    P = (
        c(ch.fixed), np.ascontiguousarray(ch.prismatic, dtype=np.bool_), comp, c(kf), c(kpost), c(ppt[0]),
        np.ascontiguousarray(kpr, dtype=np.bool_), c(com), c(mass), float(kg[0]), c(g), c(C),
        c(wrap), c(mask), bool(model.payload_input_), c(pin),
        int(mode), c(s.lower), c(s.upper), c(s.span), float(model.fade_offset_), float(model.fade_width_),
        np.ascontiguousarray(pairs[:, 0]), np.ascontiguousarray(pairs[:, 1]), field,
        model.j1_axis_ is not None, j1,
        *pos, has_rot, *rot,
        framed, c(model.frame_pre_), c(model.frame_post_),
    )
    tensors = [t for net in (model.net_pos_, model.net_rot_) if net is not None for t in (*net.parameters(), *net.buffers())]
    refs = _refs(model)
    k = HybridKernel(P=P, dof=n, refs=refs, vals=_vals(model), tensors=tensors,
                     versions=tuple(map(_version, tensors)), args=pack_args(P))
    model.__dict__["_fast_kernel"] = k
    return k


if HAVE_NUMBA:
    import math

    import numba

    from ..kinematics.compliance import MAX_ITER, TOL_RAD, deflect_one
    from ..kinematics.walk import fk_one
    from .fast_act import act_vec
    from .rotations import rotate_top
    from .support import pair_gap_row

    _DEFLECT_MIN_IT = 4  # hykin.kinematics.compliance.deflected_joints' default ``iterations``

    @numba.njit(cache=True, nogil=True, inline="always")
    def _dense(Wf, off, ni, no, a, x, y, f, nb):  # pragma: no cover - compiled
        """``y[:no] = act(x[:ni] @ W + b)`` (``f``, ``nb``: the activation's scratch)."""
        boff = off + ni * no
        h = np.dot(x[:ni], Wf[off:boff].reshape((ni, no)))  # BLAS gemv
        for o in range(no):
            y[o] = h[o] + Wf[boff + o]
        if a != 0:
            act_vec(a, y, no, f, nb)

    @numba.njit(cache=True, nogil=True, inline="always")
    def _pick(k, b0, b1, b2, b3):  # pragma: no cover - compiled
        if k == 0:
            return b0
        if k == 1:
            return b1
        if k == 2:
            return b2
        return b3

    @numba.njit(cache=True, nogil=True)
    def net_one(ops, Wf, lower, upper, out_bias, meta, x_in, n_in, buf, out):  # pragma: no cover - compiled
        """One network evaluation: inputs ``x_in[:n_in]`` -> ``out`` (3,); ``buf`` (6, widest) scratch
        (separate rows, so that the compiler sees no aliasing; rows 4-5 the activations')."""
        b0, b1, b2, b3 = buf[0], buf[1], buf[2], buf[3]
        f, nb = buf[4], buf[5].view(np.int64)
        if meta[1] == 0.0:
            for i in range(n_in):
                b0[i] = (x_in[i] - lower[i]) / (upper[i] - lower[i])
        else:
            for i in range(n_in):
                b0[i] = 2.0 * ((x_in[i] - lower[i]) / (upper[i] - lower[i])) - 1.0
                b0[n_in + i] = math.sin(x_in[i])
                b0[2 * n_in + i] = math.cos(x_in[i])
        for k in range(ops.shape[0]):
            code, src, dst, off, ni, no, a = ops[k, 0], ops[k, 1], ops[k, 2], ops[k, 3], ops[k, 4], ops[k, 5], ops[k, 6]
            xs = _pick(src, b0, b1, b2, b3)
            yd = _pick(dst, b0, b1, b2, b3)
            if code == 0:
                _dense(Wf, off, ni, no, a, xs, yd, f, nb)
            elif code == 1:
                for o in range(no):
                    yd[o] += xs[o]
            elif code == 2:
                act_vec(a, yd, no, f, nb)
            else:
                for o in range(no):
                    yd[o] = xs[o]
        s = meta[0]
        for o in range(3):
            out[o] = out_bias[o] + s * b0[o]

    @numba.njit(cache=True, nogil=True)
    def _from_net_frame(has_j1, u, q0, v):  # pragma: no cover - compiled
        if not has_j1:
            return
        c, s = math.cos(q0), math.sin(q0)
        x, y, z = v[0], v[1], v[2]
        cx, cy, cz = u[1] * z - u[2] * y, u[2] * x - u[0] * z, u[0] * y - u[1] * x
        d = (x * u[0] + y * u[1] + z * u[2]) * (1.0 - c)
        v[0], v[1], v[2] = x * c + cx * s + u[0] * d, y * c + cy * s + u[1] * d, z * c + cz * s + u[2] * d

    @numba.njit(cache=True, nogil=True, inline="always")
    def _top_rows(A, B, out):  # pragma: no cover - compiled
        """``out[:3] = (A @ B)[:3]`` for (4, 4) ``A``, ``B`` (only rows 0-2 of ``A`` are read; ``out`` is
        not ``A`` or ``B``)."""
        for r in range(3):
            for cc in range(4):
                s = 0.0
                for k in range(4):
                    s += A[r, k] * B[k, cc]
                out[r, cc] = s

    @numba.njit(cache=True, nogil=True, inline="always")
    def support_row(P, q, x, ex):  # pragma: no cover - compiled
        """The networks' input of joints ``q`` (n,) into ``x`` (n + 1,) (wrapped revolute joints, masked
        inputs, the payload column), the range excess into ``ex`` (n,); returns ``(pair gap, fade weight,
        number of inputs)`` (the operations of :func:`hykin.hybrid.inputs.net_coordinates`,
        :func:`hykin.hybrid.support.range_excess`, ``pair_gap`` and ``fade_weight``)."""
        wrap, mask, pin_on, pin, mode, slo, shi, span, f_off, f_w, I, J, field = (
            P[12], P[13], P[14], P[15], P[16], P[17], P[18], P[19], P[20], P[21], P[22], P[23], P[24])
        n = q.shape[0]
        for i in range(n):
            v = q[i]
            c = wrap[i]
            if not math.isnan(c):
                a = c - math.pi
                v = a + (v - a) % (2.0 * math.pi)
            x[i] = v * mask[i]
        n_in = n
        if pin_on:
            x[n] = pin[0]
            n_in = n + 1
        d = 0.0
        for i in range(n):
            e = max(0.0, max(slo[i] - x[i], x[i] - shi[i])) / span[i]
            ex[i] = e
            d = max(d, e)
        gap = pair_gap_row(x, slo, span, field, I, J) if I.shape[0] > 0 else 0.0
        w = 1.0
        if mode == 2:
            d = max(d, gap)
        if mode != 0:
            t = min(max((d - f_off) / f_w, 0.0), 1.0)
            w = 0.5 * (1.0 + math.cos(math.pi * t))
        return gap, w, n_in

    @numba.njit(cache=True, nogil=True)
    def _prepare_packed(F, G, B, q, X, ex, gap, w, k0, k1):  # pragma: no cover - compiled
        """Rows ``k0:k1`` of :func:`support_row` into ``X`` (N, n_in), ``ex``, ``gap``, ``w``."""
        P = unpack(F, G, B)
        x = np.empty(q.shape[1] + 1)
        for k in range(k0, k1):
            gap[k], w[k], n_in = support_row(P, q[k], x, ex[k])
            for i in range(n_in):
                X[k, i] = x[i]

    @numba.njit(cache=True, nogil=True)
    def hybrid_one(P, q, T, ex, framed_out):  # pragma: no cover - compiled
        """Hybrid pose of joints ``q`` (n,) into ``T`` (4, 4) at the reference temperature, the range
        excess into ``ex`` (n,); returns the pair gap. ``framed_out``: apply the registration frames."""
        (fixed, prism, comp, kf, kpost, ppt, kpr, com, mass, kg, g, C, wrap, mask, pin_on, pin, mode, slo, shi, span,
         f_off, f_w, I, J, field, has_j1, j1,
         p_ops, p_W, p_lo, p_hi, p_b, p_meta, has_rot, r_ops, r_W, r_lo, r_hi, r_b, r_meta,
         framed, pre, post) = P
        n = q.shape[0]
        qe = np.empty(n)
        if comp:
            tau = np.empty(n)
            z = np.empty((n, 3))
            o = np.empty((n, 3))
            cm = np.empty((n, 3))
            # iteration counts as int64, not literals: deflect_one is then compiled once for this caller and
            # for compliance's own kernels (each literal argument value is a separate ~1 s compilation)
            zero = n - n
            deflect_one(kf, kpost, ppt, kpr, com, mass, kg, g, C, q, zero + _DEFLECT_MIN_IT, zero + MAX_ITER, TOL_RAD, qe, tau,
                        z, o, cm)
            fk_one(fixed, prism, qe, T)
        else:
            fk_one(fixed, prism, q, T)
        x = np.empty(n + 1)
        gap, w, n_in = support_row(P, q, x, ex)
        widest = int(max(p_meta[2], r_meta[2]))
        buf = np.empty((6, widest))
        dv = np.empty(3)
        if w != 0.0:
            net_one(p_ops, p_W, p_lo, p_hi, p_b, p_meta, x, n_in, buf, dv)
            _from_net_frame(has_j1, j1, q[0], dv)
            for r in range(3):
                T[r, 3] += w * dv[r] if w != 1.0 else dv[r]
            if has_rot:
                net_one(r_ops, r_W, r_lo, r_hi, r_b, r_meta, x, n_in, buf, dv)
                _from_net_frame(has_j1, j1, q[0], dv)
                if w != 1.0:
                    for r in range(3):
                        dv[r] *= w
                rotate_top(dv[0], dv[1], dv[2], T)
        if framed and framed_out:
            M = np.empty((4, 4))
            _top_rows(pre, T, M)
            _top_rows(M, post, T)
        return gap

    # item i of pack_args' arrays: ``A`` is F, G or B (numba compiles each for its dtype); G's header row i
    # holds the item's offset into A and its dimensions
    @numba.njit(cache=True, nogil=True, inline="always")
    def _v1(A, G, i):  # pragma: no cover - compiled
        o = G[4 * i]
        return A[o:o + G[4 * i + 1]]

    @numba.njit(cache=True, nogil=True, inline="always")
    def _v2(A, G, i):  # pragma: no cover - compiled
        o, a, b = G[4 * i], G[4 * i + 1], G[4 * i + 2]
        return A[o:o + a * b].reshape((a, b))

    @numba.njit(cache=True, nogil=True, inline="always")
    def _v3(A, G, i):  # pragma: no cover - compiled
        o, a, b, c = G[4 * i], G[4 * i + 1], G[4 * i + 2], G[4 * i + 3]
        return A[o:o + a * b * c].reshape((a, b, c))

    @numba.njit(cache=True, nogil=True, inline="always")
    def _s(A, G, i):  # pragma: no cover - compiled
        return A[G[4 * i]]

    @numba.njit(cache=True, nogil=True)
    def unpack(F, G, B):  # pragma: no cover - compiled
        """The ``P`` tuple of :func:`pack_args`'s arrays: views into them, in :data:`P_KINDS` order."""
        return (_v3(F, G, 0), _v1(B, G, 1), _s(B, G, 2), _v3(F, G, 3), _v3(F, G, 4), _v1(F, G, 5), _v1(B, G, 6),
                _v2(F, G, 7), _v1(F, G, 8), _s(F, G, 9), _v1(F, G, 10), _v1(F, G, 11), _v1(F, G, 12), _v1(F, G, 13),
                _s(B, G, 14), _v1(F, G, 15), _s(G, G, 16), _v1(F, G, 17), _v1(F, G, 18), _v1(F, G, 19), _s(F, G, 20),
                _s(F, G, 21), _v1(G, G, 22), _v1(G, G, 23), _v3(F, G, 24), _s(B, G, 25), _v1(F, G, 26),
                _v2(G, G, 27), _v1(F, G, 28), _v1(F, G, 29), _v1(F, G, 30), _v1(F, G, 31), _v1(F, G, 32), _s(B, G, 33),
                _v2(G, G, 34), _v1(F, G, 35), _v1(F, G, 36), _v1(F, G, 37), _v1(F, G, 38), _v1(F, G, 39),
                _s(B, G, 40), _v2(F, G, 41), _v2(F, G, 42))

    @numba.njit(cache=True, nogil=True)
    def _predict_range(P, q, T, ex, gap, framed_out, k0, k1):  # pragma: no cover - compiled
        """Rows ``k0:k1``; returns whether any of them is outside the support (range excess or pair gap)."""
        outside = False
        for k in range(k0, k1):
            gap[k] = hybrid_one(P, q[k], T[k], ex[k], framed_out)
            if gap[k] > 0.0:
                outside = True
            for i in range(ex.shape[1]):
                if ex[k, i] > 0.0:
                    outside = True
        return outside

    @numba.njit(cache=True, nogil=True)
    def _predict_packed(F, G, B, q, T, ex, gap, framed_out, k0, k1):  # pragma: no cover - compiled
        return _predict_range(unpack(F, G, B), q, T, ex, gap, framed_out, k0, k1)


_PARALLEL_MIN = 512


def prepare(kernel: HybridKernel, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The networks' side of a large batch before the networks (``HybridModel.predict`` above
    :data:`COMPILED_MAX` poses): of checked joints ``q`` ``(N, n)``, the networks' input ``(N, n_in)``,
    the range excess ``(N, n)``, the pair gap ``(N,)`` and the fade weight ``(N,)``, in one compiled pass
    over the rows (the per-pose kernel's own code) instead of numpy's ~20 passes."""
    q = np.ascontiguousarray(q, dtype=np.float64)
    N, n = q.shape
    X = np.empty((N, n + int(bool(kernel.P[14]))))
    ex, gap, w = np.empty((N, n)), np.empty(N), np.empty(N)
    run_chunked(_prepare_packed, (*kernel.args, q, X, ex, gap, w), N, min_chunk=4096)
    return X, ex, gap, w


def predict_fast(kernel: HybridKernel, q: np.ndarray, framed: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                                       bool]:
    """Hybrid poses ``(N, 4, 4)`` of checked joints ``q`` ``(N, n)`` at the reference temperature (with the
    registration frames when ``framed``), range excess ``(N, n)``, pair gap ``(N,)`` and whether any row
    is outside the support (range excess or pair gap > 0)."""
    q = np.ascontiguousarray(q, dtype=np.float64)
    N = q.shape[0]
    T = np.empty((N, 4, 4))
    ex = np.empty((N, kernel.dof))
    gap = np.empty(N)
    args = (*kernel.args, q, T, ex, gap, framed)
    if N >= _PARALLEL_MIN:  # threads over the one serial kernel (no parallel compile: numba's prange cost ~13 s)
        run_chunked(_predict_packed, args, N, min_chunk=_PARALLEL_MIN // 2)
        outside = bool((gap > 0.0).any() or (ex > 0.0).any())
    else:
        outside = _predict_packed(*args, 0, N)
    return T, ex, gap, bool(outside)
