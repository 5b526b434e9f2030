"""Architectures (shapes, parameter counts against closed forms) and training recipes."""

import numpy as np
import pytest
import torch

from hykin.hybrid.nets import (
    ARCHITECTURES,
    count_parameters,
    list_architectures,
    make_net,
)
from hykin.hybrid.train import get_recipe, train_net


def dense_params(n_in, widths, n_out):
    tot, prev = 0, n_in
    for w in list(widths) + [n_out]:
        tot += prev * w + w
        prev = w
    return tot


def resnet_params(n_in, widths, n_out):
    """Chen 2020 components: dense block (3 Dense+BN main path + Dense+BN shortcut) + 2 identity
    blocks (3 Dense+BN each); BatchNorm has 2 trainable parameters per unit."""
    lin = lambda a, b: a * b + b
    tot, prev = 0, n_in
    for u in widths:
        tot += lin(prev, u) + 2 * lin(u, u) + lin(prev, u) + 4 * 2 * u  # dense block
        tot += 2 * (3 * lin(u, u) + 3 * 2 * u)  # two identity blocks
        prev = u
    return tot + lin(prev, n_out)


PAPER = {
    "D1": [5000], "D4": [3500, 2500, 1500, 750], "D4w": [5000, 3000, 1000, 500], "D4W": [6000, 3000, 1500, 1000],
    "Rw": [700, 500, 200], "Rd": [500, 200, 100, 70, 30],
}


def test_paper_architectures_match_design_table():
    for name, widths in PAPER.items():
        assert ARCHITECTURES[name]["widths"] == widths


@pytest.mark.parametrize("name", list_architectures())
def test_shapes_and_parameter_counts(name):
    n_in = 6
    net = make_net(name, n_in).eval()
    cfg = ARCHITECTURES[name]
    width_in = n_in if cfg["features"] == "minmax01" else 3 * n_in
    expected = (resnet_params if cfg["kind"] == "resnet" else dense_params)(width_in, cfg["widths"], 3)
    assert count_parameters(net) == expected
    q = torch.rand(5, n_in, dtype=torch.float64)
    out = net(q)
    assert out.shape == (5, 3) and torch.isfinite(out).all()


def test_d1_count_closed_form():
    # 6 -> 5000 -> 3: 6*5000 + 5000 + 5000*3 + 3
    assert count_parameters(make_net("D1", 6)) == 50003


def test_resnet_blocks_identity_structure():
    net = make_net("Rw", 6)
    body = list(net.body)
    assert len(body) == 3 * 3 + 1  # 3 components x (dense + 2 identity) + output
    assert type(body[0]).__name__ == "DenseBlock" and type(body[1]).__name__ == "IdentityBlock"
    assert isinstance(body[-1], torch.nn.Linear) and body[-1].out_features == 3


def test_unknown_arch_and_recipe():
    with pytest.raises(ValueError, match="unknown architecture"):
        make_net("D9", 6)
    with pytest.raises(ValueError, match="unknown recipe"):
        get_recipe("magic")
    with pytest.raises(ValueError, match="unknown recipe field"):
        get_recipe("default", learning_rate=1)


def test_normalisation_buffers():
    net = make_net("B1", 2)
    net.set_input_range([-1.0, 0.0], [1.0, 4.0])
    x = net.featurize(torch.tensor([[0.0, 1.0]], dtype=torch.float64))
    assert torch.allclose(x, torch.tensor([[0.5, 0.25]]))
    net2 = make_net("default", 2)
    net2.set_input_range([-1.0, 0.0], [1.0, 4.0])
    f = net2.featurize(torch.tensor([[0.0, 1.0]], dtype=torch.float64))
    assert torch.allclose(f, torch.tensor([[0.0, -0.5, 0.0, np.sin(1.0), 1.0, np.cos(1.0)]], dtype=torch.float32))


def _smooth_problem(n, seed):
    rng = np.random.default_rng(seed)
    q = rng.uniform(-2.5, 2.5, (n, 3))
    y = 1e-4 * np.stack([np.sin(q[:, 0]) + 0.5 * q[:, 1], np.cos(q[:, 1] - q[:, 2]), 0.3 * np.sin(2 * q[:, 2])], 1)
    return q, y


def test_training_reduces_error_tenfold():
    q, y = _smooth_problem(600, 0)
    qv, yv = _smooth_problem(300, 1)
    net = make_net("default", 3)
    net.set_input_range(q.min(0), q.max(0))
    res = train_net(net, q, y, qv, yv, get_recipe("default", max_epochs=40, batch_size=64, lr=1e-2), seed=0)
    with torch.no_grad():
        pred = net(torch.as_tensor(qv)).double().numpy()
    before = np.linalg.norm(yv - y.mean(0), axis=1).mean()
    after = np.linalg.norm(yv - pred, axis=1).mean()
    assert after < before / 10, (before, after)
    assert res.best_val == pytest.approx(after, rel=1e-4)
    assert 1 <= res.best_epoch <= res.epochs == 40


def test_paper_recipe_early_stopping_restores_best():
    q, y = _smooth_problem(200, 2)
    qv, yv = _smooth_problem(100, 3)
    net = make_net("B1", 3)
    res = train_net(net, q, y, qv, yv, get_recipe("paper", max_epochs=40, patience=3), seed=0)
    vals = [h[2] for h in res.history]
    assert res.best_val == pytest.approx(min(vals))
    with torch.no_grad():
        got = np.linalg.norm(yv - net(torch.as_tensor(qv)).double().numpy(), axis=1).mean()
    assert got == pytest.approx(res.best_val, rel=1e-5)
    if res.stopped == "early_stopping":
        assert res.epochs - res.best_epoch == 3


def test_training_is_deterministic():
    q, y = _smooth_problem(200, 4)
    outs = []
    for _ in range(2):
        torch.manual_seed(3)
        net = make_net("default", 3)
        train_net(net, q, y, None, None, get_recipe("default", max_epochs=5), seed=3)
        outs.append(torch.cat([p.detach().flatten() for p in net.parameters()]))
    assert torch.equal(outs[0], outs[1])


def test_bad_training_input():
    q, y = _smooth_problem(50, 5)
    y[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        train_net(make_net("B3", 3), q, y, None, None, get_recipe("default", max_epochs=1))


def test_default_recipe_small_data_batch_and_epochs():
    """Small data sets get >= 16 batches per epoch (batch >= 32) and >= 30000 steps; large ones keep
    batch 256 x 200 epochs; explicit batch_size / max_epochs overrides are taken literally."""
    from hykin.hybrid.train import batch_and_epochs

    r = get_recipe("default")
    assert batch_and_epochs(r, 900) == (57, 1875)  # ceil(900/16) = 57 -> 16 steps/epoch, ceil(30000/16)
    assert batch_and_epochs(r, 9000) == (256, 834)  # 36 steps/epoch -> ceil(30000/36)
    assert batch_and_epochs(r, 100_000) == (256, 200)  # 391 steps x 200 = 78200 >= 30000: unchanged
    assert batch_and_epochs(r, 300) == (32, 3000)  # batch floor 32 -> 10 steps/epoch
    assert batch_and_epochs(get_recipe("default", batch_size=64, max_epochs=8), 900) == (64, 8)
    assert batch_and_epochs(get_recipe("paper"), 900) == (128, 300)
