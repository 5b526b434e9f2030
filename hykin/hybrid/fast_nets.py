"""The residual networks as plain float64 arrays: inference without torch (no autograd, no per-call
graph), for the small batches of compensation and hybrid FK (:mod:`hykin.hybrid.nets` stays the
training path).

:func:`fast_net` turns a :class:`hykin.hybrid.nets.ResidualNet` (any architecture of
:data:`hykin.hybrid.nets.ARCHITECTURES`: dense nets and the Chen 2020 ResNets, BatchNorm folded into
the preceding dense layer in eval mode) into a :class:`FastNet`, whose :meth:`FastNet.__call__` maps
joints ``(N, n_in)`` to residuals ``(N, n_out)`` (m / rad) with numpy.

Precision. The networks are trained and stored in float32. The model's function is these float32
weights evaluated in float64 arithmetic: every weight is widened exactly, and the features, layers
and output scaling run in float64 — here, and in the torch inference path of the model
(:func:`net_float64`, used by :meth:`hykin.HybridModel.predict_torch`). Both then compute the same
function to rounding (measured ~1e-16 m; tested within 1e-9 mm); evaluating in float32 would leave
differences of the order of float32 rounding of the residual (~1e-10 m) between any two evaluation
orders. :meth:`FastNet.jacobian` gives ``∂out/∂q`` analytically (forward mode through the layers).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from ..kinematics.chunks import one_blas_thread, thread_pool, worker_count
from .fast_act import act_rows

__all__ = ["FastNet", "Layer", "evaluate", "fast_net", "net_float64"]


def _silu(x):
    return x / (1.0 + np.exp(-x))


def _silu_d(x):
    s = 1.0 / (1.0 + np.exp(-x))
    return s * (1.0 + x * (1.0 - s))


def _gelu(x):
    from scipy.special import erf

    return 0.5 * x * (1.0 + erf(x / np.sqrt(2.0)))


def _gelu_d(x):
    from scipy.special import erf

    return 0.5 * (1.0 + erf(x / np.sqrt(2.0))) + x * np.exp(-0.5 * x * x) / np.sqrt(2.0 * np.pi)


def _sigmoid(x):
    return 1.0 / (1.0 + np.exp(-x))


def _sigmoid_d(x):
    s = _sigmoid(x)
    return s * (1.0 - s)


def _act_inplace(act: str, h: np.ndarray, scratch: dict) -> None:
    """``h = act(h)`` in place: the same operations as :data:`ACTS` (same numbers to rounding), no
    temporaries for SiLU / sigmoid / ReLU / tanh; SiLU and sigmoid compiled (:mod:`.fast_act`)."""
    if act_rows(act, h, scratch):
        return
    if act in ("silu", "sigmoid"):
        t = np.negative(h, out=_buf(scratch, 0, *h.shape))
        np.exp(t, out=t)
        t += 1.0
        if act == "silu":
            np.divide(h, t, out=h)
        else:
            np.divide(1.0, t, out=h)
    elif act == "relu":
        np.maximum(h, 0.0, out=h)
    elif act == "tanh":
        np.tanh(h, out=h)
    else:
        h[...] = ACTS[act][0](h)


def _buf(scratch: dict, slot: int, rows: int, width: int) -> np.ndarray:
    """A reusable ``(rows, width)`` scratch array (C-contiguous) of ``scratch``."""
    key = (slot, width)
    a = scratch.get(key)
    if a is None or a.shape[0] < rows:
        a = scratch[key] = np.empty((max(rows, CHUNK_ROWS), width))
    return a[:rows]


#: rows per chunk of the batched evaluation (a 512 x 64 float64 activation is 256 KiB: stays in L2)
CHUNK_ROWS = 512
#: rows per worker below which a batch is not split over threads
PARALLEL_ROWS = 512


def threads() -> int:
    """Workers for large batches: :func:`hykin.kinematics.chunks.worker_count` (numba's current thread
    count, so that the classical and the network parts use the same cores and a 1-CPU sweep trial one)."""
    return worker_count()


#: activation name -> (f, f')
ACTS = {
    "relu": (lambda x: np.maximum(x, 0.0), lambda x: (x > 0).astype(np.float64)),
    "silu": (_silu, _silu_d),
    "gelu": (_gelu, _gelu_d),
    "tanh": (np.tanh, lambda x: 1.0 - np.tanh(x) ** 2),
    "sigmoid": (_sigmoid, _sigmoid_d),
    None: (None, None),
}


@dataclass
class Layer:
    """``y = act(main(x) + shortcut(x))``. main: list of ``(W (in, out), b (out,), act)`` applied in
    turn (BatchNorm folded in); shortcut: None (no residual add), ``"identity"`` or ``(W, b)``;
    act: activation after the add (None: linear)."""

    main: list
    shortcut: object = None
    act: str | None = None


@dataclass
class FastNet:
    """A :class:`~hykin.hybrid.nets.ResidualNet` as float64 arrays (module docstring).
    features: ``"minmax01"`` or ``"trig"``; lower/upper ``(n_in,)`` normalisation range;
    out_bias ``(n_out,)``, out_scale float; layers: :class:`Layer` list."""

    features: str
    lower: np.ndarray
    upper: np.ndarray
    out_bias: np.ndarray
    out_scale: float
    layers: list = field(default_factory=list)

    def featurize(self, q: np.ndarray) -> np.ndarray:
        x = (q - self.lower) / (self.upper - self.lower)
        if self.features == "minmax01":
            return x
        return np.concatenate([2.0 * x - 1.0, np.sin(q), np.cos(q)], axis=1)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        """Residuals ``(N, n_out)`` of joints ``q`` ``(N, n_in)`` float64 (:func:`evaluate` of this net)."""
        return evaluate([self], q)[0]

    @staticmethod
    def _layer(L: Layer, x: np.ndarray, xs: int, scratch: dict) -> tuple[np.ndarray, int]:
        """One layer on a chunk ``x`` (rows, in) held in scratch slot ``xs`` (-1: not a scratch buffer) ->
        ``(output, its slot)``. Outputs go to ``scratch`` buffers (slot 0: activation temporary, 3:
        shortcut; the main path alternates between two of slots 1, 2, 4 that are not ``xs``)."""
        rows = len(x)
        h, slot = x, xs
        free = [k for k in (1, 2, 4) if k != xs][:2]
        for W, b, act in L.main:
            slot = free[0] if slot != free[0] else free[1]
            h = np.matmul(h, W, out=_buf(scratch, slot, rows, W.shape[1]))
            h += b
            if act is not None:
                _act_inplace(act, h, scratch)
        if L.shortcut is not None:
            if isinstance(L.shortcut, str):
                h += x
            else:
                s = np.matmul(x, L.shortcut[0], out=_buf(scratch, 3, rows, L.shortcut[0].shape[1]))
                s += L.shortcut[1]
                h += s
        if L.act is not None:
            _act_inplace(L.act, h, scratch)
        return h, slot

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(out (N, n_out), ∂out/∂q (N, n_out, n_in))`` by forward-mode differentiation."""
        N, n = q.shape
        s = 1.0 / (self.upper - self.lower)
        x = (q - self.lower) * s
        if self.features == "minmax01":
            dx = np.broadcast_to(np.diag(s), (N, n, n)).copy()  # (N, features, n_in)
        else:
            x = np.concatenate([2.0 * x - 1.0, np.sin(q), np.cos(q)], axis=1)
            eye = np.eye(n)
            dx = np.concatenate([np.broadcast_to(2.0 * np.diag(s), (N, n, n)), np.cos(q)[:, :, None] * eye,
                                 -np.sin(q)[:, :, None] * eye], axis=1)
        for L in self.layers:
            h, dh = x, dx
            for W, b, act in L.main:
                h = h @ W + b
                dh = np.einsum("nfi,fo->noi", dh, W)
                if act is not None:
                    f, fd = ACTS[act]
                    dh = dh * fd(h)[:, :, None]
                    h = f(h)
            if L.shortcut is not None:
                if isinstance(L.shortcut, str):
                    h, dh = h + x, dh + dx
                else:
                    h = h + x @ L.shortcut[0] + L.shortcut[1]
                    dh = dh + np.einsum("nfi,fo->noi", dx, L.shortcut[0])
            if L.act is not None:
                f, fd = ACTS[L.act]
                dh = dh * fd(h)[:, :, None]
                h = f(h)
            x, dx = h, dh
        return self.out_bias + self.out_scale * x, self.out_scale * dx


def evaluate(nets: list[FastNet], q: np.ndarray) -> list[np.ndarray]:
    """Residuals ``[(N, n_out)]`` of each of ``nets`` for joints ``q`` ``(N, n_in)`` float64, in one pass.

    Rows are evaluated in chunks of :data:`CHUNK_ROWS` (activations stay in cache; in-place ufuncs, no
    temporaries), every net on a chunk before the next, spread over :func:`threads` workers for large
    batches (numpy releases the GIL). Nets with the same input features and normalisation (the hybrid
    model's position and orientation nets) share one computation of them. Each row's arithmetic is
    the same whatever the chunking and grouping."""
    q = np.asarray(q, dtype=np.float64)
    N = len(q)
    outs = [np.empty((N, len(f.out_bias))) for f in nets]
    if N == 0:
        return outs
    # net k takes the features of net share[k] (itself, or an earlier net featurising alike)
    share = []
    for k, f in enumerate(nets):
        share.append(next(j for j, g in enumerate(nets[: k + 1]) if g.features == f.features
                          and np.array_equal(g.lower, f.lower) and np.array_equal(g.upper, f.upper)))
    nt = min(threads(), -(-N // PARALLEL_ROWS))
    if nt <= 1:
        _rows(nets, share, q, outs, 0, N)
        return outs
    bounds = np.linspace(0, N, nt + 1).astype(int)
    with one_blas_thread():  # the workers' matrix products: one BLAS thread each, not threads x BLAS's
        list(thread_pool(nt).map(lambda k: _rows(nets, share, q, outs, bounds[k], bounds[k + 1]), range(nt)))
    return outs


def _rows(nets: list[FastNet], share: list[int], q: np.ndarray, outs: list[np.ndarray], a: int, b: int) -> None:
    """``outs[k][a:b]`` = residuals of net ``k`` for ``q[a:b]``, chunk by chunk with scratch buffers
    reused; net ``k`` starts from the features of net ``share[k]``. The nets share the scratch
    buffers (each finishes a chunk before the next starts): one set stays in cache."""
    scratch = {}
    with np.errstate(over="ignore"):  # exp overflow in sigmoid/SiLU saturates correctly
        for s in range(a, b, CHUNK_ROWS):
            e = min(b, s + CHUNK_ROWS)
            feats = []
            for k, f in enumerate(nets):
                feats.append(f.featurize(q[s:e]) if share[k] == k else feats[share[k]])
                x, xs = feats[k], -1
                for L in f.layers:
                    x, xs = f._layer(L, x, xs, scratch)
                np.multiply(x, f.out_scale, out=outs[k][s:e])
                outs[k][s:e] += f.out_bias


def _f64(t) -> np.ndarray:
    return t.detach().to("cpu").double().numpy().copy()


def _linear(lin, bn=None) -> tuple[np.ndarray, np.ndarray]:
    """``(W (in, out), b)`` of a ``Linear`` (followed by an eval-mode ``BatchNorm1d``, folded)."""
    W, b = _f64(lin.weight).T, _f64(lin.bias)
    if bn is not None:
        g = _f64(bn.weight) / np.sqrt(_f64(bn.running_var) + bn.eps)
        W, b = W * g, (b - _f64(bn.running_mean)) * g + _f64(bn.bias)
    return np.ascontiguousarray(W), b


def _act_name(mod) -> str | None:
    from torch import nn

    for name, cls in (("relu", nn.ReLU), ("silu", nn.SiLU), ("gelu", nn.GELU), ("tanh", nn.Tanh),
                      ("sigmoid", nn.Sigmoid)):
        if isinstance(mod, cls):
            if name == "gelu" and getattr(mod, "approximate", "none") != "none":
                raise ValueError("fast_net: tanh-approximated GELU is not supported")
            return name
    return None


def _sequence(mods: list) -> list:
    """Dense(+BN)(+act) triples of a flat module list."""
    from torch import nn

    out, i = [], 0
    while i < len(mods):
        m = mods[i]
        if not isinstance(m, nn.Linear):
            raise ValueError(f"fast_net: unexpected module {type(m).__name__}")
        bn = mods[i + 1] if i + 1 < len(mods) and isinstance(mods[i + 1], nn.BatchNorm1d) else None
        i += 1 + (bn is not None)
        act = _act_name(mods[i]) if i < len(mods) else None
        i += act is not None
        out.append((*_linear(m, bn), act))
    return out


def fast_net(net) -> FastNet:
    """The :class:`FastNet` of a :class:`~hykin.hybrid.nets.ResidualNet` (eval-mode BatchNorm folded).
    ValueError for a body that is not a sequence of dense layers and Chen 2020 blocks."""
    from .nets import DenseBlock, IdentityBlock

    layers: list[Layer] = []
    pending: list = []
    for m in net.body:
        if isinstance(m, (DenseBlock, IdentityBlock)):
            if pending:
                layers.append(Layer(_sequence(pending)))
                pending = []
            sc = "identity" if isinstance(m, IdentityBlock) else _linear(m.shortcut[0], m.shortcut[1])
            layers.append(Layer(_sequence(list(m.main)), sc, _act_name(m.act)))
        else:
            pending.append(m)
    if pending:
        layers.append(Layer(_sequence(pending)))
    return FastNet(features=net.features, lower=_f64(net.lower), upper=_f64(net.upper), out_bias=_f64(net.out_bias),
                   out_scale=float(_f64(net.out_scale)), layers=layers)


def net_float64(net):
    """A float64 eval-mode copy of a torch network (the torch inference path at the precision of
    :class:`FastNet`; module docstring)."""
    c = copy.deepcopy(net).double().eval()
    for p in c.parameters():  # inference only (gradients with respect to the inputs still flow)
        p.requires_grad_(False)
    return c


@dataclass
class _Cached:
    net: object
    tensors: list
    versions: tuple
    fast: FastNet
    torch64: object = None


def cached(owner, net) -> _Cached:
    """The float64 forms of ``net`` (``.fast``: :class:`FastNet`, ``.torch64``: :func:`net_float64`),
    cached on ``owner`` (a model) and rebuilt when the network's weights change in place (training)."""
    cache = owner.__dict__.setdefault("_fast_nets_cache", {})
    c = cache.get(id(net))
    if c is not None and c.net is net and all(t._version == v for t, v in zip(c.tensors, c.versions)):
        return c
    tensors = [*net.parameters(), *net.buffers()]
    c = cache[id(net)] = _Cached(net, tensors, tuple(t._version for t in tensors), fast_net(net))
    return c


def torch64(owner, net):
    """The float64 torch copy of ``net`` (cached as :func:`cached`), on the network's device."""
    c = cached(owner, net)
    if c.torch64 is None:
        c.torch64 = net_float64(net)
    return c.torch64
