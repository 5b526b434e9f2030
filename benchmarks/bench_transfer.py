"""Transfer benchmark (issue 13): does accuracy carry over to a new day, set-up and region?

* ``ur10``: UR10 series A -> series B (tracker moved, months later). A hykin model fitted on A
  (``--model``, e.g. ``hykin fit ur10.toml ur10_A_train.csv -o ur10.hykin``) is registered to B from
  30 of B's poses (``hykin.measure.register.register_model``: frames, plus joint zeros / thermal state where
  identifiable and significant), evaluated on the other 1,465. Peer, measured in the same run: a
  plain geometric calibration of the same A rows written here independently of hykin (own numpy
  DH FK, scipy least_squares over the 24 DH deviations + base + tool), registered to B on the SAME
  30 poses the same way (base + tool; and base + tool + the joint zeros hykin chose). Then a
  diagnosis (:func:`diagnose_b`): calibrated vs unfaded networks vs the hybrid as registered, how
  much of B the networks' support reaches, the 30-pose draw's spread, and two floors of any
  classical model on B (frames from all of B; a calibration on half of B itself).
* ``beside``: the same virtual robot trained on a Cartesian region (y above a cut, full joint ranges)
  and tested on the band beside it: calibrated vs unfaded networks vs the default fade vs the fade
  measured by leave-one-region-out (``HybridModel(fade_cv=4)``, :mod:`hykin.hybrid.fade`), per region.
* ``days``: a virtual robot of this benchmark's own (scaled RX160 geometry, own seed, transmission
  errors, thermal drift, noise) measured on two days: day 2 has the tracker moved, the tool
  re-mounted (0.5 mm / 0.05 deg) and the joint zeros drifted (0.01 deg). Day-1 model; day 2
  registered from 30 poses; its error on the rest of day 2 vs day 1's own held-out error.

Usage: python benchmarks/bench_transfer.py [--data ../shared/data] [--model ur10.hykin] [--skip ur10 days beside] [--device cuda]
       [--check-case] [--harmonics]
       [--beside-n 2000] [--robot ur10-virtual --seed 3] [--draws 3]
       [--min-steps N]
Prints markdown tables.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from pathlib import Path

import numpy as np
import tomllib
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hykin.calibration.thermal import temperature_of
from hykin.geometry import se3
from hykin.hybrid.model import HybridModel, OutOfRangeWarning
from hykin.io.dataset import split
from hykin.measure.register import register_model

# --------------------------------------------------------------------------- plain reference (independent of hykin)


def ref_fk(dh: np.ndarray, q: np.ndarray, base: np.ndarray, tool: np.ndarray, h: np.ndarray | None = None) -> np.ndarray:
    """Standard DH FK written here (numpy): dh ``(n, 4)`` rows (a, alpha, d, theta), q ``(N, n)``.
    ``h`` ``(n, K, 2)`` rad: per-joint angle errors ``Σ_k h[j,k-1,0] sin(k q_j) + h[j,k-1,1] cos(k q_j)``
    added to each joint (transmission / encoder errors as a Fourier series of the joint's own angle)."""
    N = len(q)
    if h is not None and h.size:
        k = np.arange(1, h.shape[1] + 1)
        kq = q[:, :, None] * k
        q = q + (np.sin(kq) * h[None, :, :, 0] + np.cos(kq) * h[None, :, :, 1]).sum(-1)
    T = np.broadcast_to(base, (N, 4, 4)).copy()
    for i, (a, al, d, th) in enumerate(dh):
        t = q[:, i] + th
        ct, st, ca, sa = np.cos(t), np.sin(t), np.cos(al), np.sin(al)
        A = np.zeros((N, 4, 4))
        A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca, st * sa, a * ct
        A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca, -ct * sa, a * st
        A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa, ca, d
        A[:, 3, 3] = 1.0
        T = T @ A
    return T @ tool


def twist(x: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec(x[:3]).as_matrix()
    T[:3, 3] = x[3:6]
    return T


def ref_resid(T: np.ndarray, P: np.ndarray, R: np.ndarray) -> np.ndarray:
    rp = T[:, :3, 3] - P
    ro = Rotation.from_matrix(np.einsum("nij,nkj->nik", T[:, :3, :3], R)).as_rotvec()
    return np.concatenate([rp, ro], 1).ravel()  # 1 m per rad, as hykin's registration


def ref_calibrate(dh0, tool0, q, P, R, harmonics: int = 0):
    """Plain geometric calibration: DH deviations (a, alpha, d, theta) + base + tool twists, with the
    parameters a full base / tool frame explains left out (d1, theta1; all of joint n's) and, for
    consecutive parallel axes (alpha = 0), the d of all but the last of them (only their sum acts).
    ``harmonics`` K > 0 adds per-joint angle errors of orders 1..K (``ref_fk``'s ``h``, 2K per joint).
    Returns ``(dh, base, tool, h)``; ``h`` is ``(n, 0, 2)`` (no effect in ``ref_fk``) without harmonics."""
    n = len(dh0)
    free = np.ones((n, 4), bool)
    free[0, 2] = free[0, 3] = False  # d1, theta1: redundant with the base frame
    free[n - 1, :] = False  # a, alpha, d, theta of the last joint: redundant with the tool frame
    for i in range(1, n - 1):
        if abs(np.sin(dh0[i, 1])) < 1e-6:  # axis i+1 parallel to axis i: d_i and d_(i+1) act along one axis
            free[i, 2] = False
    k = int(free.sum())
    nh = 2 * harmonics * n

    def unpack(x):
        dh = dh0.copy()
        dh[free] += x[:k]
        return dh, twist(x[k:k + 6]), tool0 @ twist(x[k + 6:k + 12]), x[k + 12:].reshape(n, harmonics, 2)

    def resid(x):
        dh, b, t, h = unpack(x)
        return ref_resid(ref_fk(dh, q, b, t, h), P, R)

    sol = least_squares(resid, np.zeros(k + 12 + nh), method="lm")
    return unpack(sol.x)


def ref_register(dh, base, tool, q, P, R, zero_joints=(), h=None):
    """Re-fit base + tool (and the joint zeros ``zero_joints``, 0-based) on new poses (``h``: the
    calibration's joint-angle harmonics, kept as they are)."""
    z = list(zero_joints)

    def unpack(x):
        d = dh.copy()
        d[z, 3] += x[12:]
        return d, twist(x[:6]) @ base, tool @ twist(x[6:12])

    x0 = np.zeros(12 + len(z))
    # coarse start for a moved tracker: Kabsch on positions
    Tm = ref_fk(dh, q, base, tool, h)
    a, b = Tm[:, :3, 3], P
    H = (a - a.mean(0)).T @ (b - b.mean(0))
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1, 1, np.sign(np.linalg.det(Vt.T @ U.T))])
    Rb = Vt.T @ D @ U.T
    x0[:3] = Rotation.from_matrix(Rb).as_rotvec()
    x0[3:6] = b.mean(0) - Rb @ a.mean(0)

    def resid(x):
        d, b, t = unpack(x)
        return ref_resid(ref_fk(d, q, b, t, h), P, R)

    sol = least_squares(resid, x0, method="lm")
    return unpack(sol.x)


def errors(T, P, R):
    p = np.linalg.norm(T[:, :3, 3] - P, axis=1) * 1e3
    a = np.degrees(np.linalg.norm(Rotation.from_matrix(np.einsum("nij,nkj->nik", T[:, :3, :3], R)).as_rotvec(), axis=1))
    return p, a


def read_toml_dh(path: Path):
    d = tomllib.loads(path.read_text())
    dh = np.array([[j["a"], np.radians(j["alpha"]), j["d"], np.radians(j["theta"])] for j in d["joints"]])
    t = d.get("tool", {})
    tool = np.eye(4)
    tool[:3, :3] = Rotation.from_euler("xyz", np.radians(t.get("rpy", [0, 0, 0]))).as_matrix()
    tool[:3, 3] = t.get("xyz", [0, 0, 0])
    return dh, tool


# --------------------------------------------------------------------------- UR10 A -> B


def rcv_kwargs(robot, name):
    """calibrate() keyword arguments of region_cv candidate ``name``."""
    from hykin.hybrid.region_cv import CANDIDATES, candidate_kwargs

    return candidate_kwargs(robot, CANDIDATES[name])



def ur10(root: Path, model_path: Path | None, min_steps: int | None, work: Path, check_case: bool = False,
         harmonics: bool = False) -> None:
    from hykin.io.robot_toml import save_robot_toml
    from hykin.measure.importers import import_ipa_series, ipa_nominal_robot

    d = root / "ipa-robot-accuracy"
    if not (d / "Series_B").is_dir():
        print(f"(UR10 data not found under {d}: skipped)")
        return
    rob = ipa_nominal_robot()
    A = import_ipa_series(d / "Series_A", register_to=rob)
    tr, te = split(A, (0.8, 0.2), seed=0)  # = hykin split ur10_A.csv --test 0.2 (the README's training rows)
    if model_path is not None and model_path.exists():
        m = HybridModel.load(model_path)
        print(f"model: {model_path} (loaded)")
    else:
        t0 = time.perf_counter()
        kw = {} if min_steps is None else {"recipe_kw": {"min_steps": min_steps}}
        m = HybridModel(rob, seed=0, **kw).fit(tr, progress=False)
        print(f"model: fitted on {len(tr)} rows of A in {time.perf_counter() - t0:.0f} s (min_steps {min_steps or 'default'})")
        if model_path is not None:
            m.save(model_path)
    B = import_ipa_series(d / "Series_B")
    PB, RB = B.xyz_m, B.poses()[:, :3, :3]
    m2, info = register_model(m, B, n_poses=30)
    idx = info.used_index
    rest = np.setdiff1d(np.arange(len(B)), idx)
    m2f, _ = register_model(m, B, n_poses=30, refit="frames")
    m2all, info_all = register_model(m, B, n_poses=len(B))  # floor: every pose of B registers (and is evaluated)
    print("\n### UR10: model from series A, series B registered from 30 poses, error on the other "
          f"{len(rest)}\n")
    print(info.report())
    rows = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        for nm, mm in (("hykin hybrid, frames + chosen parameters", m2), ("hykin hybrid, frames only", m2f)):
            rows[nm] = errors(mm.predict(B.q[rest]), PB[rest], RB[rest])
        rows["hykin calibrated, frames + chosen parameters"] = errors(m2.predict_classical(B.q[rest]), PB[rest], RB[rest])
        pa, aa = errors(m2all.predict(B.q), PB, RB)
    print(f"\nfloor, registered from all {len(B)} poses (auto: {[p.name for p in info_all.parameters[12:]]}): "
          f"{pa.mean():.4f} mm / {aa.mean():.4f} deg on all of B")
    # plain reference calibration of the same A rows (A's model frame = the nominal robot's base)
    tom = work / "ur10_nominal.toml"
    save_robot_toml(rob, tom)
    dh0, tool0 = read_toml_dh(tom)
    t0 = time.perf_counter()
    dh, base, tool, _ = ref_calibrate(dh0, tool0, tr.q, tr.xyz_m, tr.poses()[:, :3, :3])
    ts = time.perf_counter() - t0
    zj = [int(p.name[1:].split(".")[0]) - 1 for p in info.parameters if p.name.endswith(".zero")]
    zj = zj or list(range(1, len(dh0) - 1))  # hykin chose none: give the peer the zeros of joints 2..n-1 anyway
    for nm, zz in (("plain reference calibration, base + tool", ()),
                   (f"plain reference calibration, base + tool + joint zeros {[j + 1 for j in zj]}", zj)):
        dhr, br, tl = ref_register(dh, base, tool, B.q[idx], PB[idx], RB[idx], zz)
        rows[nm] = errors(ref_fk(dhr, B.q[rest], br, tl), PB[rest], RB[rest])
    peer = rows["plain reference calibration, base + tool"][0].mean()
    print(f"\n(plain reference calibration fitted in {ts:.0f} s; timings inflated by a shared machine)\n")
    print("| model (B, 30 poses used, rest evaluated) | pos mean mm | pos p95 mm | ang mean deg | vs plain ref (base + tool) |")
    print("|---|---|---|---|---|")
    for nm, (p, a) in rows.items():
        print(f"| {nm} | {p.mean():.4f} | {np.percentile(p, 95):.4f} | {a.mean():.4f} | {p.mean() / peer:.3f} |")
    diagnose_b(m, m2, B, idx, rest)
    if harmonics:
        harmonics_study(dh0, tool0, tr, te, B, idx, rest)
    if check_case:
        network_check_case(rob, tr, B)
    # calibration parameter sets: region-blocked validation on A vs what transfers to B
    from hykin.calibration.calibrate import calibrate
    from hykin.calibration.frames import fit_frames
    from hykin.hybrid.region_cv import CANDIDATES, select_calibration
    from hykin.kinematics.classical import classical_fk

    t0 = time.perf_counter()
    rcv = select_calibration(rob, tr, n_blocks=4)
    print(f"\n{rcv.table()}\n({time.perf_counter() - t0:.0f} s)\n")
    print("| calibration parameter set (on A) | region-CV on A: pos mm / ang deg | B rest, base + tool from the 30 poses: pos mm / ang deg |")
    print("|---|---|---|")
    for name in CANDIDATES:
        res = calibrate(rob, tr, **rcv_kwargs(rob, name))
        T = classical_fk(res.robot, B.q)
        Bf, Ef = fit_frames(T[idx], B.poses()[idx])
        p, a = errors(Bf @ T[rest] @ Ef, PB[rest], RB[rest])
        print(f"| {name}{' (chosen)' if name == rcv.best else ''} | {np.mean(rcv.pos_mm[name]):.4f} / {np.mean(rcv.ang_deg[name]):.4f} | "
              f"{p.mean():.4f} / {a.mean():.4f} |")


def harmonics_study(dh0, tool0, tr, te, B, idx, rest, orders=(0, 2, 4)) -> None:
    """Would a physical model of joint-angle errors carry A's accuracy to B? The plain reference
    calibration with per-joint Fourier angle errors of orders 1..K (transmission / encoder errors,
    :func:`ref_fk`'s ``h``), written here without hykin code: (a) fitted on half of B itself, scored
    on the other half (what such a model can explain of B at all); (b) fitted on A's training rows,
    scored on A's held-out 20 %, and registered to B on the same 30 poses (base + tool), scored on
    B's rest (what carries over)."""
    PB, RB = B.xyz_m, B.poses()[:, :3, :3]
    perm = np.random.default_rng(0).permutation(len(B))
    h1, h2 = perm[: len(B) // 2], perm[len(B) // 2:]
    # B into the robot frame, and its tool (the T-Mac sits turned by 180 deg on B): the fits start near
    _, b0, tool_b = ref_register(dh0, np.eye(4), tool0, B.q, PB, RB)
    TB = np.linalg.inv(b0) @ B.poses()
    print("\n#### Joint-angle harmonics: what they explain of B, and what carries over from A\n")
    print("| orders 1..K | B half -> other half: pos mm / ang deg | A train -> A held-out | A -> B (30 poses: base + tool) -> rest |")
    print("|---|---|---|---|")
    for K in orders:
        t0 = time.perf_counter()
        fit_b = ref_calibrate(dh0, tool_b, B.q[h1], TB[h1, :3, 3], TB[h1, :3, :3], harmonics=K)
        pb, ab = errors(ref_fk(fit_b[0], B.q[h2], *fit_b[1:]), TB[h2, :3, 3], TB[h2, :3, :3])
        fit_a = ref_calibrate(dh0, tool0, tr.q, tr.xyz_m, tr.poses()[:, :3, :3], harmonics=K)
        ha = fit_a[3]
        pa, aa = errors(ref_fk(fit_a[0], te.q, *fit_a[1:]), te.xyz_m, te.poses()[:, :3, :3])
        d, b, t = ref_register(fit_a[0], fit_a[1], fit_a[2], B.q[idx], PB[idx], RB[idx], (), ha)
        pr, ar = errors(ref_fk(d, B.q[rest], b, t, ha), PB[rest], RB[rest])
        print(f"| {K} | {pb.mean():.4f} / {ab.mean():.4f} | {pa.mean():.4f} / {aa.mean():.4f} | {pr.mean():.4f} / {ar.mean():.4f} |"
              f" ({time.perf_counter() - t0:.0f} s)", flush=True)


def network_check_case(rob, tr, B, joints=(2, 3), n_draws: int = 6) -> None:
    """The case the registration's network check (:func:`hykin.register._networks_transfer`) was decided
    on: networks that see only ``joints`` of series A extrapolate into series B (most of B under their
    correction, which does not carry over). B registered from ``n_draws`` draws of 30 poses, with the
    check and with the correction forced on; error on the rest."""
    t0 = time.perf_counter()
    m = HybridModel(rob, seed=0, input_joints=joints).fit(tr, progress=False)
    print(f"\n#### Network check: networks on joints {list(joints)} of A (fit {time.perf_counter() - t0:.0f} s)\n")
    TB = B.poses()
    print("| draw | check | decision | hybrid rest mm / deg | calibrated rest mm / deg |\n|---|---|---|---|---|")
    for seed in range(n_draws):
        for chk in (True, False):
            m2, info = register_model(m, B, n_poses=30, seed=seed, check_networks=chk)
            rest = np.setdiff1d(np.arange(len(B)), info.used_index)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", OutOfRangeWarning)
                ph, ah = errors(m2.predict(B.q[rest]), TB[rest, :3, 3], TB[rest, :3, :3])
                pc, ac = errors(m2.predict_classical(B.q[rest]), TB[rest, :3, 3], TB[rest, :3, :3])
            dec = info.network_check.split(";")[0].split(":")[1].strip() if chk else "forced on"
            print(f"| {seed} | {chk} | {dec} | {ph.mean():.4f} / {ah.mean():.4f} | {pc.mean():.4f} / {ac.mean():.4f} |")


def diagnose_b(m, m2, B, idx, rest) -> None:
    """Why the hybrid equals the calibrated model on B, and what bounds any registration: (a) the
    calibrated model, (b) the networks unfaded, (c) the hybrid as registered (fade ``"full"``), all with
    the frames of the 30-pose registration; how many B poses the networks' support reaches; the
    correlation of the unfaded network correction with the calibrated model's residual; the
    registration's dependence on the 30-pose draw; and two floors of any classical model on B: frames
    re-fitted on all of B, and a calibration fitted on half of B itself, scored on the other half."""
    import copy

    from hykin.calibration.calibrate import calibrate
    from hykin.calibration.frames import fit_frames, select_representative
    from hykin.kinematics.classical import classical_fk

    TB = B.poses()
    PB, RB = TB[:, :3, 3], TB[:, :3, :3]
    mu = copy.deepcopy(m2)
    mu.fade = False
    ms = copy.deepcopy(m2)
    ms.fade = True
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        Tc, Tu, Th = m2.predict_classical(B.q), mu.predict(B.q), m2.predict(B.q)
        n_full, n_sup = int((m2.fade_weight(B.q) > 0).sum()), int((ms.fade_weight(B.q) > 0).sum())
        d = m.support_distance(B.q)
    print(f"\n#### Diagnosis on B (frames of the 30-pose registration; rest {len(rest)})\n")
    print("| B rest | pos mean mm | ang mean deg |\n|---|---|---|")
    for nm, T in (("(a) calibrated", Tc), ("(b) hybrid, networks unfaded", Tu), ("(c) hybrid as registered (fade full)", Th)):
        p, a = errors(T[rest], PB[rest], RB[rest])
        print(f"| {nm} | {p.mean():.4f} | {a.mean():.4f} |")
    r, c = PB - Tc[:, :3, 3], Tu[:, :3, 3] - Tc[:, :3, 3]
    print(f"\nB poses with network weight > 0: {n_full} of {len(B)} (fade full), {n_sup} (fade support); support distance "
          f"to A's training poses (fraction of the joint range) min {d.min():.3f}, median {np.median(d):.3f}; "
          f"corr(calibrated residual, unfaded correction) {float((r * c).sum() / np.sqrt((r * r).sum() * (c * c).sum())):+.3f} "
          f"(position, all of B); unfaded correction {np.linalg.norm(c, axis=1).mean() * 1e3:.3f} mm mean")
    draws = []
    for seed in range(4):
        j = select_representative(TB, 30, seed)
        rj = np.setdiff1d(np.arange(len(B)), j)
        Bf, Ef = fit_frames(Tc[j], TB[j])
        draws.append(errors(Bf @ Tc[rj] @ Ef, PB[rj], RB[rj])[0].mean())
    Bf, Ef = fit_frames(Tc, TB)
    p_all = errors(Bf @ Tc @ Ef, PB, RB)[0].mean()
    h = np.random.default_rng(0).permutation(len(B))
    h1, h2 = h[: len(B) // 2], h[len(B) // 2:]
    res = calibrate(m.nominal, B.subset(h1))
    p_self = errors(classical_fk(res.robot, B.q[h2]), PB[h2], RB[h2])[0].mean()
    print(f"calibrated model, frames from 30 poses, draws (seed 0-3) of select_representative: "
          f"{' '.join(f'{v:.4f}' for v in draws)} mm (mean {np.mean(draws):.4f})")
    print(f"floors of a classical model on B: frames re-fitted on all {len(B)} poses {p_all:.4f} mm; "
          f"calibration fitted on {len(h1)} poses of B itself, other {len(h2)}: {p_self:.4f} mm")


# --------------------------------------------------------------------------- two days of a virtual robot


def two_day_robot(seed: int = 11, preset: str | None = None):
    """Own virtual robot: rx160-nongeo's error model on an RX160 scaled to 0.8 of its lengths,
    drawn with another seed, and its day-2 variant (tracker moved, tool re-mounted by 0.5 mm /
    0.05 deg, joint zeros drifted by 0.01 deg). Returns ``(vr_day1, vr_day2, tracker2 (4, 4), drift_rad)``.
    With ``preset`` (a virtual preset name, e.g. ``ur10-virtual``): that robot as it is (unscaled),
    drawn with ``seed``, and the same day-2 changes: a held-out robot for the same protocol."""
    import dataclasses

    from hykin.sim.presets import virtual_preset

    if preset is not None:
        return day_two(virtual_preset(preset, seed=seed), seed)
    vr = virtual_preset("rx160-nongeo", seed=seed)

    def scaled(r):
        b, t = r.base.copy(), r.tool.copy()
        b[:3, 3] *= 0.8
        t[:3, 3] *= 0.8
        return r.copy(a_m=r.a_m * 0.8, d_m=r.d_m * 0.8, base=b, tool=t, com_m=r.com_m * 0.8, name=r.name + "-0.8")

    vr1 = dataclasses.replace(vr, nominal=scaled(vr.nominal), truth=scaled(vr.truth), name="two-day-robot")
    return day_two(vr1, seed)


def day_two(vr1, seed: int):
    """``vr1`` and its day-2 variant: tool re-mounted by 0.5 mm / 0.05 deg (random directions), joint
    zeros drifted by ±0.01 deg, tracker moved. Returns ``(vr_day1, vr_day2, tracker2 (4, 4), drift_rad)``."""
    import dataclasses

    rng = np.random.default_rng(seed + 100)
    drift = np.radians(0.01) * rng.choice([-1.0, 1.0], vr1.truth.dof)
    u = rng.normal(size=3)
    v = rng.normal(size=3)
    remount = se3.make_transform(se3.rotvec_to_matrix(np.radians(0.05) * v / np.linalg.norm(v)), 0.5e-3 * u / np.linalg.norm(u))
    truth2 = vr1.truth.copy(theta_rad=vr1.truth.theta_rad + drift, tool=vr1.truth.tool @ remount)
    vr2 = dataclasses.replace(vr1, truth=truth2)
    tracker2 = se3.make_transform(se3.rotvec_to_matrix(np.array([0.2, -0.4, 1.1])), np.array([1.8, -0.6, 0.4]))
    return vr1, vr2, tracker2, drift


def day_series(vr, q, tracker, seed, start_index=0):
    """Simulated series in the tracker frame ``tracker`` (4, 4)."""
    from hykin.sim.simulate import simulate

    ds = simulate(vr, q, rng=seed, start_index=start_index)
    T = tracker @ ds.poses()
    import dataclasses

    return dataclasses.replace(ds, xyz_m=T[:, :3, 3], quat_wxyz=se3.matrix_to_quat(T[:, :3, :3]))


def days(min_steps: int | None, n_train: int = 6000, device: str = "cpu", preset: str | None = None, seed: int = 11,
         draws: int = 1) -> None:
    from hykin.sim.sampling import sample

    vr1, vr2, tracker2, drift = two_day_robot(seed, preset)
    q1 = sample("uniform", vr1.nominal, n_train, 0)
    qt = sample("random", vr1.nominal, 1500, 1)
    q2 = sample("random", vr1.nominal, 1500, 2)
    d1 = day_series(vr1, q1, np.eye(4), 3)
    t1 = day_series(vr1, qt, np.eye(4), 4, start_index=n_train)
    d2 = day_series(vr2, q2, tracker2, 5, start_index=3000)
    t0 = time.perf_counter()
    kw = {} if min_steps is None else {"recipe_kw": {"min_steps": min_steps}}
    m = HybridModel(vr1.nominal, seed=0, device=device, **kw).fit(d1, progress=False)
    print(f"\n### Virtual two-day robot {vr1.name}, seed {seed} (fit on {n_train} day-1 poses in "
          f"{time.perf_counter() - t0:.0f} s, min_steps {min_steps or 'default'})\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        p1, a1 = errors(m.predict(t1.q, temperature_c=temperature_of(t1)), t1.xyz_m, t1.poses()[:, :3, :3])
        print(f"true joint-zero drift (deg): {np.round(np.degrees(drift), 4).tolist()}")
        print("| case | pos mean mm | ang mean deg | pos ratio vs day 1 | ang ratio vs day 1 |")
        print("|---|---|---|---|---|")
        print(f"| day 1 held-out ({len(t1)}) | {p1.mean():.4f} | {a1.mean():.4f} | 1.000 | 1.000 |")
        temp2 = temperature_of(d2)
        reports = []
        for draw in range(draws):
            for refit in ("auto", "frames"):
                m2, info = register_model(m, d2, n_poses=30, refit=refit, seed=draw)
                rest = np.setdiff1d(np.arange(len(d2)), info.used_index)
                p2, a2 = errors(m2.predict(d2.q[rest], temperature_c=None if temp2 is None else temp2[rest]),
                                d2.xyz_m[rest], d2.poses()[rest][:, :3, :3])
                print(f"| day 2 registered from 30 ({refit}, draw {draw}), rest {len(rest)} | {p2.mean():.4f} | "
                      f"{a2.mean():.4f} | {p2.mean() / p1.mean():.3f} | {a2.mean() / a1.mean():.3f} |")
                if refit == "auto":
                    reports.append(info.report())
        print("\n" + reports[0] + "\n")


# --------------------------------------------------------------------------- beside the training region


def beside(min_steps: int | None, device: str, n: int = 8000, n_blocks: int = 4, preset: str | None = None,
           seed: int = 11) -> None:
    """Own virtual robot (the two-day robot of :func:`two_day_robot`, day 1), joints uniform over the
    full ranges; trained where the TCP has y > y_cut, tested on the adjacent band below it (same joint
    ranges, another Cartesian region). Per test region (quartiles of y): calibrated, unfaded
    networks, default fade, fade measured by leave-one-region-out (``fade_cv``)."""
    import copy

    from hykin.sim.sampling import sample

    vr1, _, _, _ = two_day_robot(seed, preset)
    q = sample("uniform", vr1.nominal, n, 7)
    ds = day_series(vr1, q, np.eye(4), 8)
    y = ds.xyz_m[:, 1]
    y_cut = float(np.quantile(y, 0.4))
    band = float(np.quantile(y, 0.1))
    tr, te = ds.subset(y > y_cut), ds.subset((y <= y_cut) & (y > band))
    kw = {} if min_steps is None else {"recipe_kw": {"min_steps": min_steps}}
    t0 = time.perf_counter()
    m = HybridModel(vr1.nominal, seed=0, device=device, fade_cv=n_blocks, **kw).fit(tr, progress=False)
    fs = time.perf_counter() - t0
    md = copy.deepcopy(m)
    md.fade_offset_, md.fade_width_ = 0.0, 0.1  # the fixed default fade
    mu = copy.deepcopy(m)
    mu.fade = False
    print(f"\n### Beside the training region ({vr1.name}, seed {seed}): train y > {y_cut:.3f} m ({len(tr)} poses), test {band:.3f} < y <= {y_cut:.3f} "
          f"({len(te)} poses), same joint ranges (fit incl. fade calibration {fs:.0f} s, min_steps {min_steps or 'default'}, {device})\n")
    print(m.fade_calibration_.summary())
    print("evidence (support distance bin, n, optimal weight): " + "; ".join(
        f"[{lo:.3f}, {hi:.3f}] {k} {w:.2f}" for lo, hi, k, w in m.fade_calibration_.bins))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OutOfRangeWarning)
        tt = temperature_of(te)
        R = te.poses()[:, :3, :3]
        res = {nm: errors(mm.predict(te.q, temperature_c=tt), te.xyz_m, R) for nm, mm in
               (("unfaded", mu), ("default fade", md), ("calibrated fade", m))}
        res["calibrated"] = errors(m.predict_classical(te.q, temperature_c=tt), te.xyz_m, R)
        n_out = int(np.sum(md.fade_weight(te.q) < 1))
    print(f"\n{n_out} of {len(te)} test poses have default fade weight < 1\n")
    yq = np.quantile(te.xyz_m[:, 1], [0, 0.25, 0.5, 0.75, 1.0])
    lab = np.clip(np.searchsorted(yq, te.xyz_m[:, 1], side="right") - 1, 0, 3)
    print("| region (y quartile of test) | n | calibrated mm / deg | unfaded | default fade | calibrated fade | gain kept (pos) |")
    print("|---|---|---|---|---|---|---|")
    for k in list(range(4)) + ["all"]:
        sel = np.ones(len(te), bool) if k == "all" else lab == k
        c, u, d, f = (res[x] for x in ("calibrated", "unfaded", "default fade", "calibrated fade"))
        g = (c[0][sel].mean() - f[0][sel].mean()) / max(c[0][sel].mean() - u[0][sel].mean(), 1e-12)
        print(f"| {k} | {int(sel.sum())} | {c[0][sel].mean():.4f} / {c[1][sel].mean():.4f} | {u[0][sel].mean():.4f} / "
              f"{u[1][sel].mean():.4f} | {d[0][sel].mean():.4f} / {d[1][sel].mean():.4f} | {f[0][sel].mean():.4f} / "
              f"{f[1][sel].mean():.4f} | {g:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--data", default=str(Path(__file__).resolve().parents[2] / "shared" / "data"))
    ap.add_argument("--model", default=None, help="UR10 series-A model file (loaded if present, else fitted and saved)")
    ap.add_argument("--min-steps", type=int, default=None)
    ap.add_argument("--skip", nargs="*", default=[], choices=["ur10", "days", "beside"])
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--beside-n", type=int, default=8000, help="joint samples of the beside-region case (60 %% train)")
    ap.add_argument("--work", default="/tmp")
    ap.add_argument("--robot", default=None,
                    help="virtual preset for the days/beside cases instead of the scaled rx160-nongeo (held-out robots)")
    ap.add_argument("--seed", type=int, default=11, help="draw of the days/beside robot")
    ap.add_argument("--draws", type=int, default=1, help="draws of the 30 registration poses in the days case")
    ap.add_argument("--harmonics", action="store_true",
                    help="also fit the plain reference with per-joint angle harmonics (orders 1-2, 1-4) on B and on A -> B (~1 min more)")
    ap.add_argument("--check-case", action="store_true",
                    help="also fit networks on joints 2-3 of A and register B with / without the network check (~5 min)")
    args = ap.parse_args()
    warnings.simplefilter("ignore", OutOfRangeWarning)
    if "ur10" not in args.skip:
        ur10(Path(args.data), None if args.model is None else Path(args.model), args.min_steps, Path(args.work),
             check_case=args.check_case, harmonics=args.harmonics)
    if "days" not in args.skip:
        days(args.min_steps, device=args.device, preset=args.robot, seed=args.seed, draws=args.draws)
    if "beside" not in args.skip:
        beside(args.min_steps, args.device, n=args.beside_n, preset=args.robot, seed=args.seed)


if __name__ == "__main__":
    main()
