"""``hykin demo``: the main job on the embedded default (the virtual RX160 of the paper).

Simulates rx160-virtual, calibrates, trains the hybrid model, evaluates against the paper's
figures, runs hybrid IK and writes a self-contained HTML report.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

__all__ = ["PAPER_TABLE_I", "PAPER_TABLE_IV", "run_demo"]

# Ojer et al., Robotica 2024 — figures as published (mean errors on the virtual RX160).
PAPER_TABLE_I = {
    "dataset error (nominal)": (1.80, 0.170),
    "best network, 400k samples (D4w / Rw)": (0.0226, 0.0368),
}
PAPER_TABLE_IV = {"hybrid IK": (6.0e-6, 4.9e-4), "Wang et al.": (4.52, 0.397)}


def _say(msg: str) -> None:
    from .common import console

    console().print(msg)  # one line also in a log file (soft wrap)


def run_demo(out_dir: str | Path = "hykin-demo", n_train: int = 10_000, quick: bool = False, seed: int = 0) -> Path:
    """Run the whole demo; returns the path of the HTML report."""
    import warnings

    from ..hybrid.model import OutOfRangeWarning

    with warnings.catch_warnings():
        # Test queries a hair outside the Sobol training ranges are expected; the table counts them.
        warnings.simplefilter("ignore", OutOfRangeWarning)
        return _run_demo(out_dir, n_train, quick, seed)


#: the demo fits five models (hybrid and networks-only, plus the learning curve: networks-only at 1k and
#: 3k samples, hybrid at 1k — with calibration it is at the rounding floor from 1k on); it trains
#: each network for 2500 optimiser steps, a twelfth of the default recipe's 30000, so the whole demo
#: stays near 75 s on 2 cores. The report says so; ``hykin fit`` uses the default budget.
DEMO_STEPS = 2500
#: ``--quick`` (smoke tests): 1,500 samples and 600 steps per network
QUICK_STEPS = 600


def _run_demo(out_dir, n_train: int, quick: bool, seed: int) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from ..evaluation.evaluate import evaluate_model
    from ..evaluation.report_build import build_report
    from ..geometry.se3 import pose_error
    from ..hybrid.ik import hybrid_ik, wang_ik
    from ..hybrid.model import HybridModel
    from ..io.dataset_files import write_dataset
    from ..sim.presets import virtual_preset
    from ..sim.sampling import sample
    from ..sim.simulate import save_truth, simulate

    t0 = time.perf_counter()
    steps = QUICK_STEPS if quick else DEMO_STEPS
    recipe_kw = {"max_epochs": 1, "min_steps": steps}  # exactly ``steps`` steps (whole epochs), whatever the size

    def stage(k: int, msg: str) -> None:  # one plain line per stage, also when stderr is not a terminal
        _say(f"[bold]{k}/5[/] {msg} [dim]({time.perf_counter() - t0:.0f} s)[/]")

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if quick:
        n_train = min(n_train, 1500)
    n_val, n_test, n_ik = (300, 500, 30) if quick else (1_000, 5_000, 200)
    rng = np.random.default_rng(seed)

    # 1. the virtual robot and its data (noise-free, as in the paper's virtual experiment)
    vr = virtual_preset("rx160-virtual", seed=seed)
    robot = vr.nominal
    stage(1, f"simulating rx160-virtual: {n_train} train, {n_val} val, {n_test} test samples")
    train = simulate(vr, sample("uniform", robot, n_train, rng), noise=False, rng=rng)
    val = simulate(vr, sample("random", robot, n_val, rng), noise=False, rng=rng)
    test = simulate(vr, sample("random", robot, n_test, rng), noise=False, rng=rng)
    write_dataset(train, out / "train.csv")
    write_dataset(test, out / "test.csv")
    train.source, test.source = str(out / "train.csv"), str(out / "test.csv")  # the model card names the files
    save_truth(vr, out / "truth.json")

    # 2. calibrate + train
    stage(2, f"calibrating the classical model and training the residual networks ({steps} steps per network)")
    t_fit = time.perf_counter()
    model = HybridModel(robot, seed=seed, recipe_kw=recipe_kw).fit(train, val, progress=True)
    t_fit = time.perf_counter() - t_fit
    model.save(out / "model.hykin")

    # the paper's set-up for comparison: networks only, on the nominal model (no calibration). This model and
    # the learning curve's are only scored on the test set: they fit no prediction bands (uncertainty=False)
    side = {"seed": seed, "recipe_kw": recipe_kw, "uncertainty": False}
    nets_only = HybridModel(robot, calibrate=False, **side).fit(train, val, progress=True)

    # 3. evaluate
    stage(3, "evaluating on the test set; learning curve")
    ev = evaluate_model(model, test)
    ev.stats["networks only (no calibration)"] = evaluate_model(nets_only, test).stats["hybrid"]

    # 4. learning curve: error vs training-set size, for the full pipeline and for networks alone
    sizes = [] if quick else [s for s in (1_000, 3_000) if s < n_train]
    curve = []
    for s in sizes:
        sub = train.subset(np.arange(s))
        e_h = None
        if s == sizes[0]:  # with calibration the hybrid is at the rounding floor from the smallest size on
            e_h = evaluate_model(HybridModel(robot, **side).fit(sub, val, progress=False), test).stats["hybrid"]
        e_n = evaluate_model(HybridModel(robot, calibrate=False, **side).fit(sub, val, progress=False), test).stats["hybrid"]
        nan = float("nan")
        curve.append((s, e_h.pos_mean_mm if e_h else nan, e_h.ang_mean_deg if e_h else nan, e_n.pos_mean_mm, e_n.ang_mean_deg))
    h, nn = ev.stats["hybrid"], ev.stats["networks only (no calibration)"]
    curve.append((n_train, h.pos_mean_mm, h.ang_mean_deg, nn.pos_mean_mm, nn.ang_mean_deg))

    # 5. hybrid IK round trip (paper Table IV)
    stage(4, f"hybrid inverse kinematics on {n_ik} targets (all branches)")
    q_ik = sample("random", robot, n_ik, rng)
    T_target = model.predict(q_ik)
    res = hybrid_ik(model, T_target, all_branches=True)
    wres = wang_ik(model, T_target)
    ik_rows = _ik_summary(model, T_target, res, wres, pose_error)

    # trajectory: error along a zig-zag path
    q_traj = sample("zigzag", robot, 400, rng)
    traj = simulate(vr, q_traj, noise=False, rng=rng)
    T_meas = traj.poses()
    e_nom, _ = pose_error(_nominal_fk(model, q_traj), T_meas)
    e_hyb, _ = pose_error(model.predict(q_traj), T_meas)

    # report
    stage(5, "writing the report")
    from ..io.dataset_files import read_dataset

    test_file = read_dataset(out / "test.csv")  # as a reader of the files would see them (source = the file)
    intro = [
        "The demo: a virtual Stäubli RX160. Classical model: the nominal RX160 (DH) carrying a 20 kg payload. Truth: "
        "the same robot with torsional joint springs that bend under gravity and the payload (truth.json). hykin "
        "calibrates geometry, base, tool and joint compliance, then trains position and orientation residual networks. "
        "The data are noise-free, as in the paper's virtual experiment (so errors reach floating-point rounding), and "
        f"the networks train {steps} optimiser steps each (a shortened budget that keeps the demo short; `hykin fit` "
        "trains 30000 by default). The comparison with the paper closes the report."
    ]
    rep, _ = build_report(model, test_file, model_path=out / "model.hykin", test_path=out / "test.csv",
                          title="hykin demo: virtual Stäubli RX160 (rx160-virtual)", ik_targets=0 if quick else 20, seed=seed,
                          intro=intro)
    rep.heading("The demo against the paper (Ojer et al. 2024)")
    rep.table(
        ["set", "samples", "poses drawn", "nominal mean error [mm]", "nominal mean error [deg]"],
        [
            ["train", n_train, "uniform (Sobol)", *_nominal_err(model, train)],
            ["validation", n_val, "random", *_nominal_err(model, val)],
            ["test", n_test, "random", *_nominal_err(model, test)],
        ],
        text_cols={0, 2},
    )
    comp = _comparison_rows(ev)
    rep.table(["model", "position mean [mm]", "orientation mean [deg]"], comp, "Mean errors against the paper's Table I")
    fig, ax = plt.subplots(figsize=(9, 3.2))
    ax.semilogy(e_nom, label="nominal")
    ax.semilogy(np.maximum(e_hyb, 1e-15), label="hybrid")
    ax.set_xlabel("sample along zig-zag trajectory")
    ax.set_ylabel("position error [mm]")
    ax.legend()
    rep.figure(fig, "Position error along a zig-zag trajectory through the workspace.")
    if len(curve) > 1:
        fig, ax = plt.subplots(figsize=(6.5, 3.4))
        c = np.array(curve)
        h_ok = np.isfinite(c[:, 1])  # the hybrid is not refitted at every size (see above)
        ax.loglog(c[h_ok, 0], c[h_ok, 1], "o-", label="hykin hybrid: position [mm]")
        ax.loglog(c[h_ok, 0], c[h_ok, 2], "s-", label="hykin hybrid: orientation [deg]")
        ax.loglog(c[:, 0], c[:, 3], "o--", label="networks only: position [mm]")
        ax.loglog(c[:, 0], c[:, 4], "s--", label="networks only: orientation [deg]")
        ax.set_xlabel("training samples")
        ax.set_ylabel("mean error")
        ax.legend(fontsize=8)
        rep.figure(fig, "Error against training-set size: full pipeline (calibration + networks) and networks alone "
                        "(the paper's set-up).")
        rep.table(
            ["training samples", "hybrid position [mm]", "hybrid orientation [deg]", "networks only position [mm]",
             "networks only orientation [deg]"],
            [[r[0], *(v if v == v else "not refitted" for v in r[1:])] for r in curve],
        )
        rep.note("With calibration the hybrid model is at the rounding floor from the smallest size on, so it is refitted "
                 "only at the smallest size ('not refitted' elsewhere).")
    rep.table(["method", "position mean [mm]", "orientation mean [deg]", "success"], ik_rows,
              "Inverse kinematics against the paper's Table IV", text_cols={0, 3})
    path = rep.write(out / "report.html")

    # terminal summary
    from rich.console import Console
    from rich.table import Table

    tbl = Table(title="hykin demo: virtual RX160 — mean errors on the test set")
    from rich.markup import escape

    for col in ("model", "position [mm]", "orientation [deg]"):
        tbl.add_column(escape(col), justify="right" if col != "model" else "left")  # [mm] is text, not a style
    for r in comp + [[f"IK: {r[0]}", r[1], r[2]] for r in ik_rows]:
        tbl.add_row(str(r[0]), _g(r[1]), _g(r[2]))
    Console().print(tbl)
    _say(f"networks trained {steps} steps each (demo budget; `hykin fit` default 30000)")
    _say(f"done in {time.perf_counter() - t0:.0f} s")
    return path


def _g(v) -> str:
    return f"{v:.3g}" if isinstance(v, (float, np.floating)) else str(v)


def _nominal_fk(model, q):
    from ..kinematics.fk import fk

    return fk(model.nominal, q)


def _nominal_err(model, ds):
    from ..geometry.se3 import pose_error

    p, a = pose_error(_nominal_fk(model, ds.q), ds.poses())
    return [float(p.mean()), float(a.mean())]


def _comparison_rows(ev) -> list[list]:
    rows = [
        ["paper: dataset error (nominal)", *PAPER_TABLE_I["dataset error (nominal)"]],
        ["paper: best nets, 400k samples", *PAPER_TABLE_I["best network, 400k samples (D4w / Rw)"]],
    ]
    for name, s in ev.stats.items():
        rows.append([f"hykin: {name}", s.pos_mean_mm, s.ang_mean_deg])
    return rows


def _ik_summary(model, T_target, res, wres, pose_error) -> list[list]:
    rows = [["paper: hybrid IK", *PAPER_TABLE_IV["hybrid IK"], "100 %"], ["paper: Wang et al.", *PAPER_TABLE_IV["Wang et al."], ""]]
    for name, r in (("hykin: hybrid IK", res), ("hykin: Wang et al.", wres)):
        # Achieved error of every returned solution (successful or not): FK of the joints vs target.
        has_q = np.isfinite(r.q).all(axis=1)
        n_t = int(r.n_targets)
        solved = len(set(np.asarray(r.target)[np.asarray(r.success, bool)].tolist()))
        if has_q.any():
            p, a = pose_error(model.predict(r.q[has_q]), T_target[np.asarray(r.target)[has_q]])
            rows.append([name, float(p.mean()), float(a.mean()), f"{solved}/{n_t} targets within 1e-4 mm"])
        else:
            rows.append([name, float("nan"), float("nan"), f"0/{n_t}"])
    return rows
