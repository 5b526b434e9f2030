"""Models shared by the compensation tests (not a test module).

* :class:`ExactModel`: a "perfect" hybrid model whose prediction is the true robot's FK (so tests of
  compensation check against the truth, independent of any training);
* :func:`tiny_model_file`: a real fitted HybridModel file (few steps), built once per test session.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import numpy as np

from hykin import Robot, fk, load_robot
from hykin.sim.simulate import geometric_deviation


def deviate(rob: Robot, seed: int, sigma_m: float = 5e-4, sigma_rad: float = np.radians(0.08)) -> Robot:
    """Robot with random geometric deviations (a, d, alpha, theta, beta, base, tool): a few mm of pose error."""
    return geometric_deviation(rob, np.random.default_rng(seed), sigma_m, sigma_rad, sigma_m, sigma_rad).copy(
        name=rob.name + "-truth")


class ExactModel:
    """Model interface of :class:`hykin.hybrid.model.HybridModel` used by compensation, predicting the truth."""

    def __init__(self, nominal: Robot, truth: Robot, frame_pre=None):
        self.robot = self.nominal = nominal
        self.robot_ = truth
        self.frame_pre_ = np.eye(4) if frame_pre is None else frame_pre
        self.frame_post_ = np.eye(4)

    def predict(self, q):
        return self.frame_pre_ @ fk(self.robot_, q)


def exact(preset: str, seed: int) -> ExactModel:
    nom = load_robot(preset)
    return ExactModel(nom, deviate(nom, seed))


@functools.cache
def tiny_model_file() -> Path:
    """A real model file: UR10 with geometric deviations, 300 noise-free poses, 2 epochs (built once)."""
    from hykin.hybrid.model import HybridModel
    from hykin.sim.simulate import VirtualRobot, simulate

    nom = load_robot("ur10")
    vr = VirtualRobot("ur10-test", nom, deviate(nom, 3))
    ds = simulate(vr, nom.random_joints(300, 1, margin=0.1), noise=False)
    m = HybridModel(nom, recipe_kw={"max_epochs": 2, "min_steps": 0}, seed=0).fit(ds, progress=False)
    path = Path(tempfile.mkdtemp(prefix="hykin-comp-")) / "tiny.hykin"
    m.save(path)
    return path


def real_tcp(m, T_model, D, given=None):
    """Where the real robot's program TCP is when the model's TCP is at ``T_model`` ``(..., 4, 4)``: the
    program's tool ``D`` is given relative to the robot file's TCP (``inv(nominal.tool) · tool``) and is
    fixed to the real flange, whose TCP is the model's: ``T_model · inv(E) · D`` with
    ``E = inv(nominal.tool) · robot_.tool · frame_post_`` (the model's TCP relative to the file's). ``D``
    None or (unless ``given``) the identity: no program tool, the model's TCP."""
    if given is False or D is None or (given is None and np.array_equal(D, np.eye(4))):
        return T_model
    E = np.linalg.inv(m.nominal.tool) @ m.robot_.tool @ np.asarray(getattr(m, "frame_post_", np.eye(4)))
    return T_model @ np.linalg.inv(E) @ D
