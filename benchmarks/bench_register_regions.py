"""Registration onto other regions (issue 24): a model fitted on a poorly excited region, registered
from 30 poses onto other regions, against the nominal model with frames fitted on the same 30 poses.

Two training campaigns on a virtual robot (measured in a tracker frame 13 m away, tool re-mounted):
``orientation`` — one tool orientation (spread 0.03 deg) over a 0.6 m box, the issue's case; ``subregion``
— every joint within a small fraction of its range. Each model is registered onto 8 other regions
(30 % of every joint range around random centres, 300 poses, a moved tracker). Printed per region:
the mean error on the 270 poses not used, of the registered model without the nominal check
("before", forced), of the registered model as returned (the check may fall back to nominal +
frames), with the position-only check, and of nominal + frames; then the worst ratio
returned / nominal+frames in position and orientation (<= 1 means "never worse").

    python benchmarks/bench_register_regions.py [--scenario orientation|subregion] [--preset ur10-virtual]
"""

from __future__ import annotations

import argparse
import time
import warnings

import numpy as np

from hykin.calibration.frames import fit_frames
from hykin.geometry import se3
from hykin.hybrid.model import HybridModel
from hykin.io.dataset import Dataset
from hykin.kinematics.fk import fk
from hykin.kinematics.ik import ik_numeric
from hykin.measure.register import RegistrationError, register_model
from hykin.sim.presets import virtual_preset
from hykin.sim.sampling import restricted
from hykin.sim.simulate import simulate

TRACKER_TRAIN = se3.make_transform(se3.rotvec_to_matrix(np.array([0.1, 0.3, -2.0])), np.array([12.0, 5.0, 1.0]))
TRACKER_NEW = se3.make_transform(se3.rotvec_to_matrix(np.array([0.2, -0.4, 1.3])), np.array([3.0, -2.0, 0.5]))


def _in_frame(ds, F, source):
    T = F @ ds.poses()
    return Dataset(q=ds.q, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]), source=source)


def training_joints(rob, scenario: str, rng) -> np.ndarray:
    if scenario == "subregion":
        return restricted(rob, 400, rng, fraction=0.05, method="random")
    q_ref = 0.5 * (rob.lower + rob.upper) + np.radians([10, -40, 60, -20, 60, 10])[: rob.dof]
    T = np.tile(fk(rob, q_ref), (400, 1, 1))
    T[:, :3, 3] += rng.uniform(-0.3, 0.3, (400, 3))
    T[:, :3, :3] = se3.rotvec_to_matrix(rng.normal(0, np.radians(0.03), (400, 3))) @ T[:, :3, :3]
    res = ik_numeric(rob, T, q_seed=q_ref, restarts=0)
    return res.q[res.success]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenario", default="orientation", choices=("orientation", "subregion"))
    ap.add_argument("--preset", default="ur10-virtual")
    ap.add_argument("--regions", type=int, default=8)
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    vr = virtual_preset(a.preset, seed=0)
    rob = vr.nominal
    qtr = training_joints(rob, a.scenario, np.random.default_rng(0))
    train = _in_frame(simulate(vr, qtr, rng=1), TRACKER_TRAIN, "train")
    t0 = time.perf_counter()
    m = HybridModel(rob, recipe_kw={"max_epochs": 30, "min_steps": 0}, seed=0).fit(train, progress=False)
    print(f"{a.preset}, scenario {a.scenario}: {len(qtr)} training poses, fit {time.perf_counter() - t0:.0f} s")
    span = rob.upper - rob.lower
    worst = [0.0, 0.0]
    for k in range(a.regions):
        r = np.random.default_rng(100 + k)
        q = restricted(rob, 300, r, fraction=0.3, center=rob.lower + span * r.uniform(0.15, 0.85, rob.dof), method="random")
        ds = _in_frame(simulate(vr, q, rng=200 + k), TRACKER_NEW, f"region{k}")
        before, binfo = register_model(m, ds, n_poses=30, alpha=0.0, check_nominal=False)
        try:
            new, info = register_model(m, ds, n_poses=30)
            status = "FALLBACK" if info.fell_back else "kept"
        except RegistrationError as e:
            status, new, info = f"REFUSED ({e})", None, binfo
        posm, pinfo = register_model(m, ds, n_poses=30, alpha=0.0, check_nominal="position")
        idx = info.used_index
        rest = np.setdiff1d(np.arange(len(ds)), idx)
        T = ds.poses()
        B, E = fit_frames(fk(rob, q[idx]), T[idx])
        pn, an = (e.mean() for e in se3.pose_error(B @ fk(rob, q[rest]) @ E, T[rest]))
        pb, ab = (e.mean() for e in se3.pose_error(before.predict(q[rest]), T[rest]))
        pp, ap_ = (e.mean() for e in se3.pose_error(posm.predict(q[rest]), T[rest]))
        line = f"region {k}: before {pb:.4f} mm {ab:.4f} deg | "
        if new is not None:
            pr, ar = (e.mean() for e in se3.pose_error(new.predict(q[rest]), T[rest]))
            worst = [max(worst[0], pr / pn), max(worst[1], ar / an)]
            line += f"returned ({status}) {pr:.4f} mm {ar:.4f} deg | "
        else:
            line += f"{status} | "
        line += (f"position-only check ({'FALLBACK' if pinfo.fell_back else 'kept'}) {pp:.4f} mm {ap_:.4f} deg | "
                 f"nominal+frames {pn:.4f} mm {an:.4f} deg")
        print(line, flush=True)
    print(f"worst returned / nominal+frames: position {worst[0]:.3f}, orientation {worst[1]:.3f}")


if __name__ == "__main__":
    main()
