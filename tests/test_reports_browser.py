"""The reports in a real headless browser (Debian's Chromium, driven by Playwright).

Each page is opened from file:// with every http(s) request aborted: it must load with no console
error and request nothing, show every section and figure, show result.json's numbers, and draw
its 3-D view (the plot area's pixels are not uniform).
"""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

pytest_plugins = ["report_fixtures"]

SECTIONS = {
    "run": ["scenario", "table5", "convergence", "validation", "residuals", "scene", "details"],
    "campaign": ["campaign", "summary", "trends", "spread", "pose-choice", "details"],
    "diagnosis": ["noise-floor", "detection", "candidates", "named", "gap", "scene", "details"],
    "discovery": ["summary", "rounds", "proposed", "gap", "diagnoses", "details"],
}
FIGURES = {
    "run": ["fig-convergence", "fig-validation", "fig-residuals"],
    "campaign": ["fig-error-vs-noise", "fig-error-vs-tests", "fig-spread"],
    "diagnosis": ["fig-patterns", "fig-gap", "fig-effect"],
    "discovery": ["fig-discover-gap"],
}


@pytest.fixture(scope="module")
def opened(browser, pages):
    """Each kind's page, opened offline: (page, console errors, aborted requests)."""
    from vtestbed.reports.browser import block_network, draw_3d, open_report

    aborted = block_network(browser)
    out = {}
    for kind, path in pages.items():
        page, errors, _ = open_report(browser, path)
        draw_3d(page)
        out[kind] = (page, errors, aborted)
    return out


@pytest.mark.parametrize("kind", list(SECTIONS))
def test_page_loads_offline_with_every_section_and_figure(opened, kind):
    page, errors, aborted = opened[kind]
    assert errors == [], errors
    assert aborted == [], aborted  # the page asked the network for nothing
    shown = page.eval_on_selector_all("section[data-section]", "els => els.map(e => e.id)")
    assert shown == SECTIONS[kind]
    for fig in FIGURES[kind]:
        width = page.eval_on_selector(f"#{fig} img", "img => img.complete ? img.naturalWidth : 0")
        assert width > 300, (fig, width)  # the embedded PNG decoded


def test_run_numbers_in_the_browser_equal_result_json(opened, run_folder):
    page = opened["run"][0]
    result = json.loads((run_folder / "result.json").read_text())
    rows = page.eval_on_selector_all(
        "#table5 tbody tr", "trs => trs.map(tr => Array.from(tr.cells).map(td => td.innerText))"
    )
    assert len(rows) == len(result["joints"])
    for row, j in zip(rows, result["joints"]):
        assert row[0] == j["name"]
        assert float(row[2]) == pytest.approx(j["k_est"] * 1e3, rel=5.1e-5)
        assert float(row[4]) == pytest.approx(j["rel_err"] * 100, abs=5.1e-4)


@pytest.mark.parametrize("kind", ["run", "diagnosis"])
def test_3d_view_renders(opened, kind):
    from PIL import Image

    page = opened[kind][0]
    assert page.locator("#scene-3d").get_attribute("data-drawn") == "1"
    assert page.locator("#scene-3d canvas").count() >= 1  # the WebGL layer exists
    png = page.locator("#scene-3d").screenshot()
    pixels = np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=float)
    h, w, _ = pixels.shape
    plot = pixels[h // 5 : 4 * h // 5, w // 4 : 3 * w // 4]  # the middle of the plot, off the legend
    colours = len(np.unique(plot.reshape(-1, 3), axis=0))
    print(f"\n{kind} 3-D view: {w}x{h} px, {colours} colours, pixel std {plot.std():.1f}")
    assert colours > 50 and plot.std() > 10.0
