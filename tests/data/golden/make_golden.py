"""Regenerates the golden files pinned by tests/test_golden.py. Run only when the model file format
is deliberately changed (and say so in the changelog): the point of the golden files is that a file
saved by an earlier hykin keeps loading and predicting the same.

    python tests/data/golden/make_golden.py
"""

from pathlib import Path

import numpy as np

import hykin
from hykin.sim.presets import virtual_preset
from hykin.sim.simulate import simulate

HERE = Path(__file__).parent


def main() -> None:
    vr = virtual_preset("ur10-virtual", seed=3)
    rng = np.random.default_rng(7)
    q = vr.nominal.random_joints(600, rng=rng)
    ds = simulate(vr, q, noise=True, rng=rng)
    model = hykin.HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 4, "batch_size": 128})
    model.fit(ds, progress=False)
    model.save(HERE / "model_v0.1.0.safetensors")
    q_query = vr.nominal.random_joints(50, rng=np.random.default_rng(11))
    np.savez(HERE / "predictions_v0.1.0.npz", q=q_query, T=model.predict(q_query),
             T_classical=model.predict_classical(q_query))


if __name__ == "__main__":
    main()
