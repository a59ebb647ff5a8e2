"""Session fixtures shared by the report tests (loaded with ``pytest_plugins``): one small result
folder of each kind, made by the real commands' code, and Debian's Chromium for the browser tests.

The folders are small versions of the README's examples: a run of 8 + 2 tests of the paper's
scenario, a tiny campaign (3 trials x 4 cells), a diagnosis of 8 + 2 tests with a hidden
compliant link and 2 repeat scans per test, and ``vtestbed discover`` on the same scenario.
"""

from __future__ import annotations

import copy
import re
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "scenarios" / "kr60_paper.toml"


def small_paper(n_tests: int = 8, n_val: int = 2) -> dict:
    """The paper's scenario cut to its first tests (a scenario table)."""
    data = copy.deepcopy(tomllib.loads(PAPER.read_text()))
    data["poses"]["angles_deg"] = data["poses"]["angles_deg"][:n_tests]
    data["validation"]["angles_deg"] = data["validation"]["angles_deg"][:n_val]
    for table, n in (("load", n_tests), ("validation", n_val)):
        for key in ("hook", "anchor"):
            if isinstance(data[table].get(key), list):
                data[table][key] = data[table][key][:n]
    return data


@pytest.fixture(scope="session")
def run_folder(tmp_path_factory) -> Path:
    from vtestbed.experiment import run
    from vtestbed.scenario import parse_scenario

    data = small_paper() | {"name": "report_run"}
    out = tmp_path_factory.mktemp("report_run")
    run(parse_scenario(data, "report_run.toml"), out, figures=False)
    return out


@pytest.fixture(scope="session")
def campaign_folder(tmp_path_factory) -> Path:
    from quick_campaign import tiny

    from vtestbed.campaigns.runner import sweep

    out = tmp_path_factory.mktemp("report_campaign")
    sweep(tiny(trials=3), out, workers=1, progress=False)
    return out


@pytest.fixture(scope="session")
def diagnosis_folder(tmp_path_factory) -> Path:
    from vtestbed.experiment import simulate
    from vtestbed.researcher.discrepancy import diagnose
    from vtestbed.scenario import parse_scenario

    root = tmp_path_factory.mktemp("report_diagnosis")
    dataset = root / "dataset"
    simulate(parse_scenario(hidden_link_scenario(), "hidden.toml"), dataset)
    names = ("link_compliance", "joint_coupling", "scanner_scale")  # the scale: settled by the block
    diagnose(dataset, names=names, out=dataset / "diagnose")
    return dataset / "diagnose"


def hidden_link_scenario(repeats: int = 2) -> dict:
    """8 + 2 of the paper's tests with link 2 compliant in the world and ``repeats`` repeat scans."""
    text = PAPER.read_text()
    text = re.sub(r"\[scanner\]\n", f"[scanner]\nrepeats = {repeats}\n", text, count=1)
    text += '\n[[world.effects]]\nname = "link_compliance"\n'
    data = tomllib.loads(text)
    cut = small_paper()
    data["poses"], data["validation"], data["load"] = cut["poses"], cut["validation"], cut["load"]
    return data


@pytest.fixture(scope="session")
def discovery_folder(tmp_path_factory) -> Path:
    """``vtestbed discover --always`` on the hidden-link scenario: one round of 2 tests; the
    command writes every page (the discovery page and each stage's diagnosis page)."""
    from vtestbed.cli.main import main
    from vtestbed.scenario_writer import toml_text

    root = tmp_path_factory.mktemp("report_discovery")
    (root / "hidden.toml").write_text(toml_text(hidden_link_scenario() | {"name": "report_discovery"}))
    argv = ["discover", str(root / "hidden.toml"), "--out", str(root / "out"), "--extra-tests", "2",
            "--n-poses", "10", "--always", "--quiet"]  # fmt: skip
    assert main(argv) == 0
    return root / "out"


@pytest.fixture(scope="session")
def pages(run_folder, campaign_folder, diagnosis_folder, discovery_folder) -> dict:
    """Each kind's report.html, written once for both report test modules."""
    from vtestbed.reports import write_report

    return {kind: write_report(folder) for kind, folder in
            (("run", run_folder), ("campaign", campaign_folder), ("diagnosis", diagnosis_folder),
             ("discovery", discovery_folder))}  # fmt: skip


@pytest.fixture(scope="session")
def browser():
    """Playwright on Debian's Chromium (installed here if missing and root; a clear failure otherwise)."""
    from vtestbed.reports.browser import BrowserUnavailable, chromium

    try:
        with chromium() as context:
            yield context
    except BrowserUnavailable as exc:
        pytest.fail(f"the report's browser tests need Chromium and Playwright: {exc}")
