"""``vtestbed report``: the pages' numbers parsed back against the result files, self-containment,
the 3-D view against the world's record, and bad input (no browser here: test_reports_browser.py)."""

from __future__ import annotations

import base64
import json
import re
from html.parser import HTMLParser
from importlib import resources

import numpy as np
import pytest

from vtestbed.cli.main import main as cli_main
from vtestbed.reports import ReportError, detect_kind, load_result, one_test_scene, write_report

pytest_plugins = ["report_fixtures"]


class Tables(HTMLParser):
    """Every <table id=...> of a page as rows of cell texts, and every element id."""

    def __init__(self):
        super().__init__()
        self.tables, self.ids, self._table, self._cell = {}, [], None, None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if "id" in attrs:
            self.ids.append(attrs["id"])
        if tag == "table" and attrs.get("id"):
            self._table = self.tables.setdefault(attrs["id"], [])
        elif tag == "tr" and self._table is not None:
            self._table.append([])
        elif tag in ("td", "th") and self._table is not None:
            self._cell = []

    def handle_endtag(self, tag):
        if tag in ("td", "th") and self._cell is not None:
            self._table[-1].append("".join(self._cell).strip())
            self._cell = None
        elif tag == "table":
            self._table = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell.append(data)


def parse(path) -> Tables:
    t = Tables()
    t.feed(path.read_text(encoding="utf-8"))
    return t


def close(shown: str, value: float, digits: int):
    """The shown text equals ``value`` to the printed precision (half a unit in the last digit)."""
    got = float(shown)
    assert got == pytest.approx(value, rel=0.51 * 10.0 ** (1 - digits), abs=1e-12), (shown, value)


def test_each_folder_is_detected_as_its_kind(run_folder, campaign_folder, diagnosis_folder):
    assert [detect_kind(f) for f in (run_folder, campaign_folder, diagnosis_folder)] == [
        "run", "campaign", "diagnosis"]  # fmt: skip


def test_run_page_shows_result_json_numbers(pages, run_folder):
    result = json.loads((run_folder / "result.json").read_text())
    t = parse(pages["run"])
    rows = t.tables["table5"][1:]
    assert [r[0] for r in rows] == [j["name"] for j in result["joints"]]
    for row, j in zip(rows, result["joints"]):
        close(row[1], j["k_true"] * 1e3, 5)
        close(row[2], j["k_est"] * 1e3, 5)
        close(row[3], j["k_std"] * 1e3, 3)
        assert float(row[4]) == pytest.approx(j["rel_err"] * 100, abs=0.0005 + 1e-9)
        assert float(row[5]) == pytest.approx((j["k_est"] - j["k_true"]) / j["k_std"], abs=0.005 + 1e-9)
    val = t.tables["validation-table"][1:]
    assert [r[0] for r in val] == [v["test_id"] for v in result["validation"]]
    for row, v in zip(val, result["validation"]):
        assert float(row[7]) == pytest.approx(np.linalg.norm(v["measured"][:3]) * 1e3, abs=5e-5 + 1e-12)
        assert float(row[9]) == pytest.approx(v["rel_err_translation"] * 100, abs=0.005 + 1e-12)
    res = t.tables["component-residuals"][1:]
    for row, s in zip(res, result["identification"]["component_std"]):
        assert float(row[1]) == pytest.approx(s * 1e6, abs=5e-4 + 1e-12)
    assert dict(t.tables["versions"])["seed"] == str(result["seed"])
    for section in ("scenario", "table5", "convergence", "validation", "residuals", "scene", "details"):
        assert section in t.ids
    for fig in ("fig-convergence", "fig-validation", "fig-residuals", "scene-3d"):
        assert fig in t.ids


def test_campaign_page_shows_the_parquet_stores_numbers(pages, campaign_folder):
    from vtestbed.campaigns.store import read_results

    df = read_results(campaign_folder)  # the reference: RMS per cell recomputed from the store
    t = parse(pages["campaign"])
    head, *rows = t.tables["campaign-summary"]
    assert head[:2] == ["n_tests", "scanner_noise_scale"]
    assert len(rows) == df["cell_key"].nunique() == 4
    for row in rows:
        cell = df[(df["n_tests"] == int(row[0])) & (df["scanner_noise_scale"] == float(row[1]))]
        assert int(row[2]) == len(cell) == 3
        for j in range(6):
            e = cell[f"err_joint{j + 1}"].to_numpy()
            close(row[3 + j], 100 * np.sqrt(np.mean(e**2)), 3)
    assert "campaign-facts" in t.ids and "spread-check" in t.ids
    manifest = json.loads((campaign_folder / "campaign.json").read_text())
    facts = dict(row[:2] for row in t.tables["campaign-facts"])
    assert manifest["reference"] == "scan"  # the fixture's scenario measures as the paper does
    assert facts["displacements measured from"] == "one unloaded and one loaded scan (the paper's)"
    assert "fig-error-vs-noise" in t.ids and "fig-error-vs-tests" in t.ids and "fig-spread" in t.ids


def test_diagnosis_page_shows_report_json_numbers(pages, diagnosis_folder):
    report = json.loads((diagnosis_folder / "report.json").read_text())
    t = parse(pages["diagnosis"])
    det = dict(t.tables["detection"])
    close(det["p-value"], report["detect"]["p_value"], 3)
    assert float(det["chi^2"]) == pytest.approx(report["detect"]["chi2"], abs=0.05 + 1e-9)
    assert int(det["degrees of freedom"]) == report["detect"]["dof"]
    floor = t.tables["noise-floor"][1:]
    for row, s in zip(floor, report["noise_floor"]["component_std"]):
        assert float(row[1]) == pytest.approx(s * 1e6, abs=5e-4 + 1e-12)
    # the F/T readings' noise the model is tested with besides the scans', as report.json has it
    reading = ", ".join(
        f"{c} {s * 1e6:.3f}" for c, s in zip("x y z rx ry rz".split(), report["noise_floor"]["reading_std"])
    )
    assert (
        "reading-noise" in t.ids
        and f"in its prediction, std {reading} (um, urad)" in pages["diagnosis"].read_text()
    )
    cands = t.tables["candidates-round-1"][1:]
    by_label = {c["label"]: c for c in report["rounds"][0]["tests"]}
    assert {r[0] for r in cands} == set(by_label)
    for row in cands:
        assert float(row[1]) == pytest.approx(by_label[row[0]]["lr"], abs=0.005 + 1e-9)
        assert float(row[4]) == pytest.approx(by_label[row[0]]["press"], abs=0.005 + 1e-9)
        assert float(row[5]) == pytest.approx(by_label[row[0]]["bic"], abs=0.005 + 1e-9)
        overlap = by_label[row[0]]["overlap"]  # the chosen term's own row has none
        assert row[7] == "-" if overlap is None else float(row[7]) == pytest.approx(overlap, abs=0.005 + 1e-9)
    assert sum(row[7] == "-" for row in cands) == 1
    k = t.tables["stiffness-before-after"][1:]
    for row, k1 in zip(k, report["model"]["stiffness_Nm_per_rad"]):
        close(row[3], k1 * 1e3, 5)
    assert "link_compliance(link 2)" in report["named"]  # the hidden link is found, as in the README
    scale = report["scale_check"]  # the block's size as a length standard: shown as measured
    lo, hi = scale["interval_ppm"]
    assert "scale-check" in t.ids and not scale["beyond"]
    assert (
        f"at {scale['scale_ppm']:+.0f} ppm (95 % interval {lo:+.0f} to {hi:+.0f} ppm"
        in pages["diagnosis"].read_text()
    )
    # ... and within the tolerance it rules the scale out of the candidates, beyond the interval's
    # far end plus the tolerance (researcher/scale_term.py)
    assert report["scale_term"]["action"] == "ruled_out" and "scanner_scale" not in by_label
    bound = max(abs(lo), abs(hi)) + scale["tolerance_ppm"]
    assert f"larger than {bound:.0f} ppm is ruled out" in pages["diagnosis"].read_text()
    assert f"not name a scale below {bound:.0f} ppm" in pages["diagnosis"].read_text()
    assert "fig-gap" in t.ids and "fig-effect" in t.ids and "scene-3d" in t.ids


def test_a_confusable_round_shows_the_runner_ups_shares(diagnosis_folder, tmp_path):
    """A confusable round's table adds the shares of the runner-up's pattern (runner_overlap)."""
    import shutil

    folder = shutil.copytree(diagnosis_folder, tmp_path / "diagnose")
    report = json.loads((folder / "report.json").read_text())
    rnd = report["rounds"][0]
    labels = [t["label"] for t in rnd["tests"]]
    rnd["runner_up"] = labels[1]
    for k, test in enumerate(rnd["tests"]):
        test["runner_overlap"] = None if k == 1 else (k * 0.137) % 1.0
    (folder / "report.json").write_text(json.dumps(report))
    head, *rows = parse(write_report(folder)).tables["candidates-round-1"]
    assert head[-1] == f"share of {labels[1]}'s pattern" and len(head) == 9
    by_label = {t["label"]: t["runner_overlap"] for t in rnd["tests"]}
    for row in rows:
        share = by_label[row[0]]
        assert row[8] == "-" if share is None else float(row[8]) == pytest.approx(share, abs=0.005 + 1e-9)
    assert [row[0] for row in rows if row[8] == "-"] == [labels[1]]


def test_discovery_page_shows_each_stages_gap(pages, discovery_folder):
    """The command wrote every stage's diagnosis page; the discovery page lists them, and its gap
    table holds each stage's validation ratios as that stage's own report.json records them."""
    result = json.loads((discovery_folder / "discover.json").read_text())
    stages = [discovery_folder / f"round{k}" / "diagnose" for k in range(len(result["rounds"]) + 1)]
    assert len(stages) == 2 and all((s / "report.html").is_file() for s in stages)
    t = parse(pages["discovery"])
    assert [row[2] for row in t.tables["discover-diagnoses"][1:]] == [str(s / "report.html") for s in stages]
    rows = t.tables["discover-gap"][1:]
    assert [row[0] for row in rows] == ["the scenario's tests", "after round 1"]
    for row, stage in zip(rows, stages, strict=True):
        val = json.loads((stage / "report.json").read_text())["validation"]
        close(row[1], val["before"]["ratio_to_floor"], 4)
        close(row[2], val["after"]["ratio_to_floor"], 4)
    summary = dict(t.tables["discover-summary"])
    assert summary["named after"] == (", ".join(result["named_after"]) or "nothing")
    shown = dict(t.tables["versions"])  # as discover.json records them, not those installed now
    assert shown["versions"].startswith("recorded in discover.json")
    assert shown["numpy"] == result["versions"]["numpy"] and shown["mujoco"] == result["versions"]["mujoco"]


def test_pages_are_self_contained_and_small(pages):
    for kind, page in pages.items():
        html = page.read_text(encoding="utf-8")
        assert page.stat().st_size < 10e6, kind
        # nothing to fetch: no external script, stylesheet, image or frame
        assert not re.search(r'<(script|img|link|iframe)[^>]+(src|href)="(https?:)?//', html), kind
        assert not re.search(r"<link\b", html), kind
        imgs = re.findall(r'<img src="([^"]*)"', html)
        assert imgs and all(s.startswith("data:image/png;base64,") for s in imgs), kind
    run_html = pages["run"].read_text(encoding="utf-8")
    assert 'id="plotly-js"' in run_html and "Plotly" in run_html  # plotly.js inline


def typed(value) -> np.ndarray:
    """A plotly JSON array: a list, or a typed array ``{"dtype", "bdata"}`` (base64)."""
    if isinstance(value, dict):
        return np.frombuffer(base64.b64decode(value["bdata"]), dtype=value["dtype"])
    return np.asarray(value, dtype=float)


def test_scene_matches_the_worlds_record(run_folder):
    """The 3-D view's hook and block, from the dataset alone, against truth.json (the world's)."""
    truth = json.loads((run_folder / "dataset" / "truth.json").read_text())
    view = one_test_scene(run_folder / "dataset", "T002", max_points=500)
    assert view["hook"] == truth["tests"]["T002"]["hook"]
    assert view["points"] == [500, 500]
    fig = json.loads(view["figure_json"])
    block = next(tr for tr in fig["data"] if tr["name"].startswith("block"))
    verts = np.column_stack([typed(block[a]) for a in "xyz"])
    corner = np.array(truth["tests"]["T002"]["block_pose_unloaded"])[:3, 3]
    assert np.min(np.linalg.norm(verts - corner, axis=1)) < 0.5e-3  # the fitted corner, within 0.5 mm
    assert {tr["type"] for tr in fig["data"]} == {"scatter3d", "mesh3d"}


def test_template_ships_as_package_data():
    template = resources.files("vtestbed.reports") / "templates" / "report.html.j2"
    assert template.is_file() and "{% for s in sections %}" in template.read_text()


def test_cli_writes_the_page_and_refuses_a_folder_without_result(run_folder, tmp_path, capsys):
    out = tmp_path / "new" / "sub" / "page.html"  # a missing folder is created, as for other --out
    assert cli_main(["report", str(run_folder), "--out", str(out)]) == 0
    assert out.stat().st_size > 1e6 and "Table 5" in out.read_text(encoding="utf-8")
    capsys.readouterr()
    assert cli_main(["report", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("vtestbed: error:") and "Traceback" not in err
    for name in ("result.json", "campaign.json", "report.json"):
        assert name in err


def test_malformed_results_name_the_file_and_field(tmp_path, run_folder):
    bad = tmp_path / "bad"
    bad.mkdir()
    data = json.loads((run_folder / "result.json").read_text())
    del data["joints"]
    (bad / "result.json").write_text(json.dumps(data))
    with pytest.raises(ReportError, match=r"result\.json: missing field 'joints'"):
        load_result(bad)
    (bad / "result.json").write_text("{not json")
    with pytest.raises(ReportError, match=r"result\.json: not valid JSON"):
        load_result(bad)
    empty = tmp_path / "campaign"
    (empty / "trials").mkdir(parents=True)
    (empty / "campaign.json").write_text(json.dumps({"scenario": "x", "joint_names": [], "campaign": {}}))
    with pytest.raises(ReportError, match="no finished trial"):
        load_result(empty)
    with pytest.raises(ReportError, match="not a folder"):
        load_result(tmp_path / "missing")


def broken_result(tmp_path, run_folder, edit) -> str:
    """A folder holding run_folder's result.json changed by ``edit(data)``."""
    bad = tmp_path / "bad"
    bad.mkdir()
    data = json.loads((run_folder / "result.json").read_text())
    edit(data)
    (bad / "result.json").write_text(json.dumps(data))
    return str(bad)


def refused(argv, capsys) -> str:
    """The one-line error of the real CLI entry for ``argv`` (exit code 2, no traceback)."""
    capsys.readouterr()
    assert cli_main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    err = captured.err.strip()
    assert err.startswith("vtestbed: error:") and "\n" not in err and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("field", ["method", "n_tests"])
def test_cli_refuses_a_result_without_a_field_the_page_reads(tmp_path, run_folder, capsys, field):
    folder = broken_result(tmp_path, run_folder, lambda d: d.pop(field))
    err = refused(["report", folder], capsys)
    assert "result.json: missing field" in err and repr(field) in err


@pytest.mark.parametrize(
    ("edit", "named"),
    [
        (lambda d: d["joints"].__setitem__(1, "joint2"), "joints[1]"),
        (lambda d: d["joints"][2].pop("k_est"), "joints[2].k_est"),
        (lambda d: d["joints"][0].__setitem__("k_true", "big"), "joints[0].k_true"),
        (lambda d: d["table5"]["min"].pop(), "table5.min"),
    ],
    ids=["not-a-table", "missing-k_est", "k_true-not-a-number", "table5-short"],
)
def test_cli_refuses_a_malformed_joint_row(tmp_path, run_folder, capsys, edit, named):
    folder = broken_result(tmp_path, run_folder, edit)
    err = refused(["report", folder], capsys)
    assert "result.json" in err and named in err, err


def toml_value(value) -> str:
    """A TOML value (inline tables and arrays) of JSON-like data: enough to write a scenario file."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(toml_value(v) for v in value) + "]"
    return "{" + ", ".join(f"{json.dumps(k)} = {toml_value(v)}" for k, v in value.items()) + "}"


def write_scenario(folder, data: dict):
    import tomllib

    path = folder / f"{data['name']}.toml"
    path.write_text("".join(f"{json.dumps(k)} = {toml_value(v)}\n" for k, v in data.items()))
    assert tomllib.loads(path.read_text()) == data
    return path


@pytest.fixture
def scenarios_dir(tmp_path, monkeypatch):
    from vtestbed.reports import sections_run

    folder = tmp_path / "scenarios"
    folder.mkdir()
    monkeypatch.setattr(sections_run, "SCENARIOS_DIR", folder)
    return folder


def scenario_section(run_folder, tmp_path):
    page = write_report(run_folder, tmp_path / "page.html")
    html = page.read_text(encoding="utf-8")
    return parse(page), html[html.index('id="scenario"') : html.index('id="table5"')]


def test_scenario_file_is_shown_when_its_fingerprint_is_the_runs(run_folder, scenarios_dir, tmp_path):
    from report_fixtures import small_paper

    from vtestbed.scenario import load_scenario

    path = write_scenario(scenarios_dir, small_paper() | {"name": "report_run"})  # what the run was made of
    recorded = json.loads((run_folder / "dataset" / "truth.json").read_text())["scenario_fingerprint"]
    assert load_scenario(path).fingerprint == recorded
    t, section = scenario_section(run_folder, tmp_path)
    assert "scenario-file" in t.ids and "scenario-file-note" not in t.ids
    facts = dict(t.tables["scenario-file"])
    assert facts["scenario file"] == str(path) and facts["wire tension [N]"] == "200"


def test_a_changed_scenario_file_is_not_shown_as_the_runs(run_folder, scenarios_dir, tmp_path):
    from report_fixtures import small_paper

    data = small_paper() | {"name": "report_run"}
    data["load"]["tension_N"] = 350.0  # edited after the run
    write_scenario(scenarios_dir, data)
    t, section = scenario_section(run_folder, tmp_path)
    assert "scenario-file" not in t.ids and "scenario-file-note" in t.ids
    assert "no longer matches the run" in section
    assert "wire tension" not in section and "scanner noise" not in section  # nothing of the changed file
    recorded = json.loads((run_folder / "dataset" / "truth.json").read_text())["scenario_fingerprint"]
    assert "scenario-recorded" in t.ids and recorded in section
    assert "scenario-facts" in t.ids and "method" in section  # what result.json and the dataset record


def test_a_malformed_truth_file_is_refused_by_name_not_a_traceback(run_folder, scenarios_dir, tmp_path):
    """The scenario section reads truth.json's effects when the scenario file changed; an
    ``effects`` that is not a list of named effects raised TypeError there (2026-11-29)."""
    import shutil

    from report_fixtures import small_paper

    from vtestbed.errors import DatasetError

    data = small_paper() | {"name": "report_run"}
    data["load"]["tension_N"] = 350.0  # the changed-file branch, which shows the recorded effects
    write_scenario(scenarios_dir, data)
    copy = tmp_path / "run"
    shutil.copytree(run_folder, copy)
    truth_path = copy / "dataset" / "truth.json"
    truth = json.loads(truth_path.read_text())
    truth_path.write_text(json.dumps(truth | {"effects": 5}))
    with pytest.raises(
        DatasetError, match=r"truth.json: effects must be a list of the hidden effects.*got 5"
    ):
        write_report(copy, tmp_path / "page.html")


def test_versions_are_the_recorded_ones_or_labelled_as_installed_now(run_folder):
    from vtestbed.reports import sections_run

    folder = load_result(run_folder)
    folder.data.pop("versions", None)  # a result.json of a vtestbed that recorded none
    rows = dict(sections_run.details(folder).blocks[-1].items)
    assert "installed when this report was written" in rows["versions"]
    assert "numpy" in rows and "recorded" not in rows["versions"]
    folder.data["versions"] = {"vtestbed": "0.1.9", "numpy": "1.26.4"}  # as a run records them
    rows = dict(sections_run.details(folder).blocks[-1].items)
    assert "recorded in result.json" in rows["versions"]
    assert rows["vtestbed"] == "0.1.9" and rows["numpy"] == "1.26.4" and "scipy" not in rows
    assert "scipy (installed when this report was written)" in rows  # the others, labelled as now


def test_run_page_shows_the_versions_result_json_records(pages, run_folder):
    recorded = json.loads((run_folder / "result.json").read_text()).get("versions")
    if not recorded:
        pytest.skip("this vtestbed's result.json records no versions")
    shown = dict(parse(pages["run"]).tables["versions"])
    assert "recorded in result.json" in shown["versions"]
    assert all(shown[k] == str(v) for k, v in recorded.items())


def test_missing_apt_get_is_browser_unavailable(tmp_path, monkeypatch):
    from vtestbed.reports import browser

    monkeypatch.setenv("PATH", str(tmp_path))  # no apt-get on it
    monkeypatch.setattr(browser.os, "geteuid", lambda: 0)
    with pytest.raises(browser.BrowserUnavailable, match="cannot be installed here"):
        browser.ensure_chromium(tmp_path / "chromium")
    assert "--disable-dev-shm-usage" in browser.FLAGS


def test_a_second_installer_waits_for_the_first_and_installs_nothing(tmp_path, monkeypatch):
    """Two processes of ``pytest -n 2`` on a fresh machine: the one that finds the install lock
    held waits, then sees the first one's Chromium and returns it (no apt-get on PATH here: had it
    not waited, it would raise)."""
    import fcntl
    import threading

    from vtestbed.reports import browser

    monkeypatch.setenv("PATH", str(tmp_path))
    monkeypatch.setattr(browser.os, "geteuid", lambda: 0)
    path, result = tmp_path / "chromium", []
    with browser.INSTALL_LOCK.open("a") as first:
        fcntl.flock(first, fcntl.LOCK_EX)  # the first installer, at work
        waiting = threading.Thread(target=lambda: result.append(browser.ensure_chromium(path)))
        waiting.start()
        waiting.join(0.5)
        assert waiting.is_alive() and result == []  # it waits on the lock
        path.write_text("#!/bin/sh\n")  # the first one's install lands, then it lets go
    waiting.join(10)
    assert result == [path]


def test_a_run_page_embeds_the_figures_the_run_wrote(tmp_path):
    """The PNG the run recorded in result.json is embedded byte for byte (no second drawing); a
    result that records none (``--no-figures``) gets them drawn from its numbers."""
    import base64

    from vtestbed.reports import figures

    png = b"\x89PNG\r\n\x1a\n" + bytes(range(256))
    (tmp_path / "convergence.png").write_bytes(png)
    result = {"figures": {"convergence": "/elsewhere/runs/demo/convergence.png"}}
    uri = figures.recorded(result, tmp_path, "convergence")
    assert base64.b64decode(uri.split(",", 1)[1]) == png
    assert figures.recorded({"figures": {}}, tmp_path, "convergence") is None
    assert figures.recorded(result, tmp_path, "validation") is None
