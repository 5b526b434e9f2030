"""The model report: its numbers against independent references, the written summary, and the
rendered document in a real headless browser (Chromium: layout, figures, A4 PDF)."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import warnings

import numpy as np
import pytest

from hykin.evaluation.report import Report, error_histograms

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
NO_BROWSER = "chromium not installed (apt-get install -y chromium; .ci/run installs it)"


def _report(tmp_path):
    rng = np.random.default_rng(0)
    rep = Report("test report")
    rep.heading("Errors").text("before/after")
    rep.table(["model", "mean [mm]"], [["nominal", 1.8], ["hybrid", 0.004]])
    rep.figure(
        error_histograms(rng.gamma(4, 0.45, 2000), rng.gamma(4, 0.001, 2000), rng.gamma(4, 0.04, 2000), rng.gamma(4, 1e-3, 2000)),
        caption="histograms",
    )
    return rep.write(tmp_path / "report.html")


def test_report_is_self_contained(tmp_path):
    path = _report(tmp_path)
    text = path.read_text()
    assert text.count("data:image/png;base64,") == 1
    assert "http://" not in text and "https://" not in text  # nothing fetched from elsewhere
    assert "<td>0.004</td>" in text and "<td class='text'>nominal</td>" in text


# --------------------------------------------------------------------------- a small fitted model


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    """A quickly trained hybrid model of rx160-geometric, saved and reloaded, with test data that carry
    a temperature column and ten repeated poses (pose_id)."""
    from hykin.hybrid.model import HybridModel
    from hykin.io.dataset_files import read_dataset, write_dataset
    from hykin.sim.presets import virtual_preset
    from hykin.sim.sampling import sample
    from hykin.sim.simulate import simulate

    d = tmp_path_factory.mktemp("rep")
    vr = virtual_preset("rx160-geometric", seed=0)
    rng = np.random.default_rng(1)
    train = simulate(vr, sample("uniform", vr.nominal, 500, rng), noise=False, rng=rng)
    write_dataset(train, d / "train.csv")
    train = read_dataset(d / "train.csv")
    q = sample("random", vr.nominal, 150, rng)
    q = np.clip(q, train.q.min(0), train.q.max(0))
    q_rep = np.repeat(q[:5], 4, axis=0)  # 5 poses x 4 cycles
    test = simulate(vr, np.vstack([q, q_rep]), noise=False, rng=rng)
    test.extra["pose_id"] = np.r_[np.arange(150) + 100, np.repeat(np.arange(5) + 1, 4)].astype(float)
    test.extra["temperature_c"] = np.linspace(20.0, 30.0, len(test.q))
    write_dataset(test, d / "test.csv")
    test = read_dataset(d / "test.csv")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = HybridModel(vr.nominal, seed=0, recipe_kw={"max_epochs": 3}).fit(train, progress=False)
    m.save(d / "model.hykin")
    return HybridModel.load(d / "model.hykin"), test, d


def test_eval_vectors_are_the_errors(fitted):
    """Per-axis error vectors: their norms are the scalar errors, their signs predicted − measured."""
    from hykin.evaluation.evaluate import evaluate_model

    model, test, _ = fitted
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = evaluate_model(model, test)
    for name, (dp, dr) in res.vectors.items():
        p, a = res.errors[name]
        np.testing.assert_allclose(np.linalg.norm(dp, axis=1), p, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(np.linalg.norm(dr, axis=1), a, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(dp, (res.predicted[name][:, :3, 3] - test.xyz_m) * 1e3, atol=1e-12)


def test_axis_rows_match_numpy():
    from hykin.evaluation.report_accuracy import axis_rows

    rng = np.random.default_rng(3)
    dp, dr = rng.normal(0.1, 1.0, (400, 3)), rng.normal(0, 0.01, (400, 3))
    rows = {(r[0], r[1].strip()): r for r in axis_rows({"m": (dp, dr)})}
    n = np.sqrt((dp**2).sum(1))
    assert rows[("m", "position |e|")][2:6] == pytest.approx([n.mean(), n.std(), np.percentile(n, 95), n.max()])
    y = dp[:, 1]
    assert rows[("m", "y")][2:6] == pytest.approx([y.mean(), y.std(), np.percentile(abs(y), 95), abs(y).max()])
    assert rows[("m", "rz")][2] == pytest.approx(dr[:, 2].mean()) and rows[("m", "rz")][6] == "deg"


def test_joint_hotspot_finds_a_planted_region():
    """Errors 5x larger where joint 2 > 80°: the summary names joint 2 and that range."""
    from hykin.evaluation.report_accuracy import joint_hotspot

    rng = np.random.default_rng(0)
    q = rng.uniform(-np.pi / 2, np.pi / 2, (3000, 6))
    e = np.full(3000, 0.01)
    e[np.degrees(q[:, 1]) > 60] = 0.05
    h = joint_hotspot(q, e, np.ones(6, bool))
    assert h.what == "joint 2" and h.lo >= 59.0 and h.hi == pytest.approx(90.0, abs=0.5)
    assert h.mean_mm == pytest.approx(0.05) and h.overall_mm == pytest.approx(e.mean())


def test_per_temperature_rows_are_bin_means():
    from hykin.evaluation.report_accuracy import per_temperature_rows

    t = np.linspace(20, 40, 100)
    p = t * 0.01
    rows = per_temperature_rows(t, {"m": (p, None)}, n_bins=4)
    assert len(rows) == 4 and sum(r[2] for r in rows) == 100
    assert rows[0][3] == pytest.approx(p[:25].mean()) and rows[-1][5] is None
    assert per_temperature_rows(np.full(10, 20.0), {"m": (p[:10], None)}) == []


def test_calibration_rows_values_and_status():
    """identified = nominal + deviation (geometry), held parameters greyed, a calibration's own status
    (a correlated one naming its partners), the prior tolerance, and extra per-parameter fields shown."""
    from hykin.calibration.params import apply_deviations
    from hykin.evaluation.report_calibration import calibration_rows, calibration_summary
    from hykin.io.robot_file import load_robot

    rob = load_robot("rx160")
    calib = {"n_samples": 100, "parameters": [
        {"name": "a2", "unit": "m", "value": 2e-4, "std": 1e-5, "identifiable": True},
        {"name": "d3", "unit": "m", "value": 0.0, "std": None, "identifiable": False},
        {"name": "theta3", "unit": "rad", "value": 1e-6, "std": 1e-5, "identifiable": True, "status": "held at prior",
         "prior_std": 0.001, "weight": 0.5},
        {"name": "c2", "unit": "c", "value": 2e-6, "std": 1e-8, "identifiable": True},
        {"name": "a3", "unit": "m", "value": 1e-4, "std": 2e-4, "identifiable": True, "status": "correlated",
         "prior_std": 0.005, "correlated_with": [["d4", -0.995]]},
    ], "strong_correlations": [["a2", "theta3", 0.95], ["a3", "d4", -0.995]],
        "before": {"pos_mean_mm": 1.0}, "after": {"pos_mean_mm": 0.01}}
    cal_robot = apply_deviations(rob, {"a2": 2e-4, "theta3": 1e-6, "c2": 2e-6, "a3": 1e-4})
    rows = {r.name: r for r in calibration_rows(calib, rob, cal_robot)}
    assert rows["a2"].nominal == pytest.approx(rob.a_m[1] * 1e3) and rows["a2"].identified == pytest.approx(rob.a_m[1] * 1e3 + 0.2)
    assert rows["a2"].deviation == pytest.approx(0.2) and rows["a2"].unit == "mm" and rows["a2"].status == "identified"
    assert "differs from nominal" in rows["a2"].notes and "theta3 (ρ +0.950)" in rows["a2"].notes
    assert rows["d3"].held and rows["d3"].std is None and "not identifiable" in rows["d3"].status
    assert rows["theta3"].status == "held at prior" and rows["theta3"].held
    assert rows["theta3"].prior == pytest.approx(np.degrees(0.001)) and "weight 0.5" in rows["theta3"].notes
    assert rows["a3"].status == "correlated with d4 (ρ -0.995)" and not rows["a3"].held
    assert "agrees with nominal" in rows["a3"].notes and "d4" not in rows["a3"].notes  # named once, in the status
    assert rows["c2"].identified == pytest.approx(2.0) and rows["c2"].nominal == 0.0 and rows["c2"].prior is None
    text = " ".join(calibration_summary(calib, list(rows.values())))
    assert "2 of 5 parameters identified" in text and "1 correlated" in text and "2 held (d3, theta3)" in text
    assert "a2 +0.2 mm" in text


@pytest.fixture(scope="module")
def built(fitted, tmp_path_factory):
    """The report of the fitted model on its test data (built once for the content and browser tests)."""
    from hykin.evaluation.report_build import build_report, write_report

    model, test, d = fitted
    out = tmp_path_factory.mktemp("built")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rep, res = build_report(model, test, model_path=d / "model.hykin", test_path=d / "test.csv", ik_targets=2)
    return rep, write_report(rep, out, res)


def test_full_report_contents(fitted, built):
    """The one builder on a saved model with test data: every section, the summary's numbers
    recomputed here, ISO 9283 AP against its closed form."""
    from hykin.evaluation.evaluate import evaluate_model

    model, test, d = fitted
    _, path = built
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = evaluate_model(model, test)
    html = path.read_text()
    for h in ("Summary", "Model card", "Accuracy on the test data", "Where the error is", "ISO 9283", "Training support",
              "Per payload and temperature", "Calibration", "Inverse kinematics timing"):
        assert h in html, h
    assert "http://" not in html and "https://" not in html and html.count("data:image/png;base64,") >= 4
    h, n = ref.stats["hybrid"], ref.stats["nominal"]
    removed = 100 * (1 - h.pos_mean_mm / n.pos_mean_mm)
    assert f"removes {removed:.1f} %" in html or f"removes {removed:.4g} %" in html
    assert "train.csv" in html and "test.csv" in html and "content_sha256" in html
    # ISO 9283 AP of pose P1 for the hybrid model: |mean attained - commanded| (closed form, 4 cycles)
    sel = np.asarray(test.extra["pose_id"]).astype(str) == "1"  # labels are read as written
    ap = np.linalg.norm((test.xyz_m[sel] - ref.predicted["hybrid"][sel][:, :3, 3]).mean(0)) * 1e3
    assert re.search(r"<td class='text'>hybrid</td><td class='text'>1</td><td>4</td><td>" + re.escape(f"{ap:.4g}"), html)
    assert json.loads((path.parent / "evaluation.json").read_text())["n"] == len(test.q)


def test_report_without_test_data(fitted, tmp_path):
    from hykin.evaluation.report_build import build_report

    model, _, d = fitted
    rep, res = build_report(model, None, model_path=d / "model.hykin", ik_targets=0)
    html = rep.html()
    assert res is None and "No test data were given" in html and "Calibration" in html
    held = model.metadata["metrics"]["held_out"]["hybrid_pos_mean_mm"]
    assert "rows held out from network training" in html and (f"{held:.3g} mm" in html or f"{held * 1e3:.3g} µm" in html)


# --------------------------------------------------------------------------- the browser

_CHECK_JS = """<script>
window.addEventListener('load', function () {
  var imgs = Array.from(document.images);
  var r = {scrollWidth: document.documentElement.scrollWidth, innerWidth: window.innerWidth,
           images: imgs.length, broken: imgs.filter(function (i) { return !i.complete || i.naturalWidth === 0; }).length,
           tooWide: Array.from(document.querySelectorAll('table, figure, img, pre, p'))
                       .filter(function (e) { return e.getBoundingClientRect().right > window.innerWidth + 1; }).length};
  var p = document.createElement('pre'); p.id = 'hykin-check'; p.textContent = JSON.stringify(r);
  document.body.appendChild(p);
});
</script>"""


def _chromium(tmp_path, *args, timeout=120):
    cmd = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
           "--disable-background-networking", "--disable-component-update", "--disable-sync",
           f"--user-data-dir={tmp_path / 'profile'}", "--hide-scrollbars", *args]
    return subprocess.run(cmd, check=True, timeout=timeout, capture_output=True)


def browser_check(html_path, tmp_path, width: int = 1000) -> dict:
    """Load a copy of the report with a checking script in Chromium at ``width`` px: page width,
    images decoded, elements past the right edge."""
    probe = tmp_path / "probe.html"
    probe.write_text(html_path.read_text().replace("</body>", _CHECK_JS + "</body>"), encoding="utf-8")
    out = _chromium(tmp_path, f"--window-size={width},900", "--virtual-time-budget=15000", "--dump-dom", probe.as_uri())
    m = re.search(r'<pre id="hykin-check">(.*?)</pre>', out.stdout.decode())
    assert m, "the check script did not run"
    return json.loads(m.group(1).replace("&quot;", '"'))


def pdf_pages(pdf: bytes) -> list[tuple[float, float]]:
    """Page sizes (points) of a PDF from its MediaBox entries."""
    boxes = re.findall(rb"/MediaBox\s*\[\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s*\]", pdf)
    return [(float(c) - float(a), float(d) - float(b)) for a, b, c, d in boxes]


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason=NO_BROWSER)
def test_report_renders_in_headless_chromium(tmp_path):
    import matplotlib.image as mpimg

    path = _report(tmp_path)
    shot = tmp_path / "shot.png"
    _chromium(tmp_path, "--window-size=1200,1400", f"--screenshot={shot}", path.as_uri())
    img = mpimg.imread(shot)[..., :3]
    # matplotlib's first two default colours (C0 blue, C1 orange), blended at alpha 0.6 on white.
    c0 = np.array([31, 119, 180]) / 255 * 0.6 + 0.4
    c1 = np.array([255, 127, 14]) / 255 * 0.6 + 0.4
    near = lambda c: np.all(np.abs(img - c) < 0.06, axis=-1).sum()
    # The histogram bars are only present if the embedded PNG was decoded and drawn.
    assert near(c0) > 500, "no histogram bars (C0) rendered"
    assert near(c1) > 500, "no histogram bars (C1) rendered"


@pytest.mark.slow  # test_report_renders_in_headless_chromium renders the report in the default suite
@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason=NO_BROWSER)
def test_model_report_in_chromium_fits_loads_and_prints_a4(built, tmp_path):
    """The full model report: no horizontal overflow at 1000 px, every figure decoded, a screenshot
    with content, and an A4 PDF."""
    import matplotlib.image as mpimg

    rep, path = built
    chk = browser_check(path, tmp_path)
    assert chk["images"] == rep.n_figures >= 4 and chk["broken"] == 0, chk
    assert chk["scrollWidth"] <= chk["innerWidth"] and chk["tooWide"] == 0, chk

    shot = tmp_path / "shot.png"
    _chromium(tmp_path, "--window-size=1000,3000", f"--screenshot={shot}", path.as_uri())
    img = mpimg.imread(shot)[..., :3]
    assert img.shape[1] == 1000 and (img.min(axis=-1) < 0.5).mean() > 0.01  # text and figures, not a blank page

    pdf = tmp_path / "report.pdf"
    _chromium(tmp_path, "--no-pdf-header-footer", f"--print-to-pdf={pdf}", path.as_uri())
    data = pdf.read_bytes()
    pages = pdf_pages(data)
    assert data[:5] == b"%PDF-" and len(pages) >= 3
    assert all(abs(w - 595.3) < 2 and abs(h - 841.9) < 2 for w, h in pages), pages  # A4 portrait


@pytest.mark.slow  # four reports (about 20 s); the builder itself is covered by the default tests above
def test_cli_report_and_evaluate_report(fitted, tmp_path, capsys):
    """`hykin report` (a model with test data; a preset robot: classical only) and `hykin evaluate --report`
    write the same kind of report; a file given as -o is refused with one line."""
    from hykin.cli import main

    model, test, d = fitted

    def run(*args):
        with pytest.raises(SystemExit) as e:
            main(list(args))
        return e.value.code or 0

    assert run("report", str(d / "model.hykin"), str(d / "test.csv"), "-o", str(tmp_path / "r1"), "--ik-targets", "0") == 0
    html = (tmp_path / "r1" / "report.html").read_text()
    assert "Calibration" in html and "ISO 9283" in html and "removes" in html
    assert run("report", "rx160", str(d / "test.csv"), "-o", str(tmp_path / "r2"), "--ik-targets", "0") == 0
    html = (tmp_path / "r2" / "report.html").read_text()
    assert "On 170 test poses the nominal model" in html and "Calibration" not in html
    assert run("evaluate", str(d / "model.hykin"), str(d / "test.csv"), "--report", str(tmp_path / "r3")) == 0
    assert "Where the error is" in (tmp_path / "r3" / "report.html").read_text()
    (tmp_path / "f").write_text("x")
    capsys.readouterr()
    assert run("report", str(d / "model.hykin"), "-o", str(tmp_path / "f")) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "must name a directory" in err[0]
