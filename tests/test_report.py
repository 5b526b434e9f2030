"""The HTML report is self-contained and renders with its images in a real headless browser."""

from __future__ import annotations

import shutil
import subprocess

import numpy as np
import pytest

from hykin.evaluation.report import Report, error_histograms

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")


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
    assert "<td>0.004</td>" in text and "<td>nominal</td>" in text


@pytest.mark.browser
@pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (apt-get install chromium)")
def test_report_renders_in_headless_chromium(tmp_path):
    import matplotlib.image as mpimg

    path = _report(tmp_path)
    shot = tmp_path / "shot.png"
    cmd = [
        CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        f"--user-data-dir={tmp_path / 'profile'}", "--hide-scrollbars", "--window-size=1200,1400",
        f"--screenshot={shot}", path.as_uri(),
    ]
    subprocess.run(cmd, check=True, timeout=120, capture_output=True)
    img = mpimg.imread(shot)[..., :3]
    # matplotlib's first two default colours (C0 blue, C1 orange), blended at alpha 0.6 on white.
    c0 = np.array([31, 119, 180]) / 255 * 0.6 + 0.4
    c1 = np.array([255, 127, 14]) / 255 * 0.6 + 0.4
    near = lambda c: np.all(np.abs(img - c) < 0.06, axis=-1).sum()
    # The histogram bars are only present if the embedded PNG was decoded and drawn.
    assert near(c0) > 500, "no histogram bars (C0) rendered"
    assert near(c1) > 500, "no histogram bars (C1) rendered"
