"""The sections of a run's report (``vtestbed run`` / ``demo``: ``result.json`` and ``dataset/``).

Stiffness is shown in N*mm/rad as in the paper's Table 5 (``result.json`` holds N*m/rad),
displacements in mm and mrad, residuals in um and urad.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import VtestbedError
from ..researcher.discrepancy import COMPONENTS
from . import figures
from .blocks import Figure, KeyValues, Num, Plot3D, Section, Table, Text, versions
from .loader import ReportError, ResultFolder

SCENARIOS_DIR = Path(__file__).resolve().parents[2] / "scenarios"


def measured_from(reference: str | None) -> str:
    """What the displacements were measured from, for a report's facts (scenario ``reference``)."""
    if reference is None:
        return "not recorded (results written before 2026-11-27)"
    return (
        "the mean of each test's scans"
        if reference == "mean"
        else "one unloaded and one loaded scan (the paper's)"
    )


def _tests(folder: ResultFolder) -> list:
    from ..dataset import read_tests

    if folder.dataset is None:
        return []
    if "tests" not in folder.extra:
        folder.extra["tests"] = read_tests(folder.dataset, check_files=False)
    return folder.extra["tests"]


def _truth(folder: ResultFolder) -> dict | None:
    """The dataset's truth.json (what the world recorded when it simulated), or None if absent;
    the keys this report reads (fingerprint, effects) checked as on resume
    (:func:`vtestbed.truth_file.check_recorded`). The true stiffness is not read here."""
    from ..dataset import TRUTH_FILE
    from ..files import read_json
    from ..truth_file import check_recorded

    path = (folder.dataset or folder.root / "dataset") / TRUTH_FILE
    if "truth" not in folder.extra:
        truth = read_json(path, "truth file", ReportError) if path.is_file() else None
        if truth is not None:
            check_recorded(truth, path)
        folder.extra["truth"] = truth
    return folder.extra["truth"]


def _scenario_file(name: str) -> tuple[Path, object, str]:
    """``(path, scenario or None, why not)`` for the scenario of that name under scenarios/."""
    from ..scenario import load_scenario

    path = SCENARIOS_DIR / f"{name}.toml"
    if not path.is_file():
        return path, None, f"{path} is not on this machine"
    try:
        scenario = load_scenario(path)
    except VtestbedError as exc:
        return path, None, f"{path} cannot be read ({exc})"
    if scenario.name != name:
        return path, None, f"{path} names another scenario ({scenario.name!r})"
    return path, scenario, ""


def _matching_scenario(folder: ResultFolder) -> tuple[object, str]:
    """The scenario file the run was made from, checked by its fingerprint against the one the
    dataset's truth.json records; ``(scenario, "")``, or ``(None, why it is not shown)``."""
    name = folder.data["scenario"]
    path, sc, why = _scenario_file(name)
    if sc is None:
        return None, why
    truth = _truth(folder)
    recorded = None if truth is None else truth.get("scenario_fingerprint")
    if recorded is None:
        return None, (f"The dataset records no scenario fingerprint (no truth.json), so {path} cannot be checked "
                      "against the run")  # fmt: skip
    if sc.fingerprint != recorded:
        return None, (f"The scenario file {path} no longer matches the run: its fingerprint {sc.fingerprint} differs "
                      f"from the {recorded} recorded in the dataset's truth.json (the file changed after the run)")  # fmt: skip
    return sc, ""


def scenario(folder: ResultFolder) -> Section:
    """Robot, lab, noise and tests: from the dataset, and from the scenario file when it is the one
    the run was made from (same fingerprint as the dataset records)."""
    from ..dataset import read_setup

    r = folder.data
    items = [("scenario", r["scenario"]), ("seed", str(r["seed"])), ("method", r["method"]),
             ("displacements measured from", measured_from(r.get("reference", "scan"))),
             ("identification tests", str(r["n_tests"])), ("validation tests", str(len(r["validation"])))]  # fmt: skip
    if folder.dataset is not None:
        setup = read_setup(folder.dataset)
        items += [("robot", setup.robot), ("block edge [mm]", Num(setup.block_edge, ".4g", 1e3)),
                  ("force sensor", setup.sensor_name),
                  ("F/T range [N, N*m]", ", ".join(f"{v:g}" for v in setup.sensor_range))]  # fmt: skip
    blocks = [KeyValues(items, id="scenario-facts")]
    sc, why = _matching_scenario(folder)
    if sc is not None:
        noise = sc.scanner.noise_model
        facts = [("scenario file", str(sc.source)), ("scenario fingerprint", sc.fingerprint + " (as the dataset records)"),
                 ("description", sc.description or "-"),
                 ("scanner distance [m]", Num(sc.scanner.distance, ".3g")),
                 ("scanner noise", "off" if noise is None else
                  f"{noise.range_std_m * 1e6:g} um per point, drift {noise.drift_translation_std_m * 1e6:g} um / "
                  f"{noise.drift_rotation_std_rad * 1e6:g} urad per scan, {noise.outlier_fraction * 100:g} % outliers"),
                 ("repeat scans per test (unloaded, loaded)", f"{sc.scanner.repeats}, {sc.scanner.loaded_repeats}"),
                 ("F/T noise std [N, N*m]", ", ".join(f"{v:g}" for v in sc.force_sensor.noise_std)),
                 ("F/T bias [N, N*m]", ", ".join(f"{v:g}" for v in sc.force_sensor.bias)),
                 ("wire tension [N]", ", ".join(f"{v:g}" for v in sorted(set(sc.load.tensions)))),
                 ("hidden effects", ", ".join(e.name for e in sc.effects if not e.is_null) or "none")]  # fmt: skip
        blocks.append(KeyValues(facts, id="scenario-file"))
    else:
        blocks.append(Text([f"{why}: the scenario file's noise, tension and effects are not shown; the facts "
                            "here are only those the dataset and result.json record."], id="scenario-file-note"))  # fmt: skip
        truth = _truth(folder)
        if truth is not None:
            effects = [
                e.get("name", "?") if isinstance(e, dict) else str(e) for e in truth.get("effects") or []
            ]
            recorded = [("scenario fingerprint", str(truth.get("scenario_fingerprint", "not recorded"))),
                        ("hidden effects (truth.json)", ", ".join(effects) or "none")]  # fmt: skip
            blocks.append(KeyValues(recorded, id="scenario-recorded"))
    tests = _tests(folder)
    if tests:
        rows = [[t.test_id, t.group, *[Num(v, ".2f") for v in t.q_deg],
                 Num(float(np.linalg.norm(t.wrench_loaded[:3] - t.wrench_unloaded[:3])), ".1f")] for t in tests]  # fmt: skip
        blocks.append(Table(["test", "group", *[f"q{j + 1} [deg]" for j in range(6)], "|dF| measured [N]"],
                            rows, id="tests", caption="The tests as recorded in tests.csv (angles in the dataset's convention)"))  # fmt: skip
    return Section("scenario", "Scenario", blocks)


def table5(folder: ResultFolder) -> Section:
    """Paper Table 5: truth, estimate, std, error, z-score, and the error range over n = 6..N."""
    r = folder.data
    t5 = r["table5"]
    rows = []
    for i, j in enumerate(r["joints"]):
        z = (j["k_est"] - j["k_true"]) / j["k_std"] if j["k_std"] and j["k_est"] is not None else None
        rows.append([j["name"], Num(j["k_true"], ".4e", 1e3), Num(j["k_est"], ".4e", 1e3),
                     Num(j["k_std"], ".2e", 1e3), Num(j["rel_err"], ".3f", 100), Num(z, ".2f"),
                     Num(t5["min"][i], ".2f", 100), Num(t5["max"][i], ".2f", 100), Num(t5["mean"][i], ".3f", 100)])  # fmt: skip
    cols = ["joint", "k_true [N*mm/rad]", "k_est [N*mm/rad]", "k_std [N*mm/rad]", "error [%]", "z-score",
            f"error min n={t5['first_n']}..{r['n_tests']} [%]", "error max [%]", "mean [%]"]  # fmt: skip
    text = Text([f"{r['n_tests']} identification tests, {r['method'].upper()}; error = k_est / k_true - 1, "
                 "z-score = (k_est - k_true) / k_std (about 1 in size when the reported std is honest)."])  # fmt: skip
    return Section("table5", "Table 5: identified stiffness", [text, Table(cols, rows, id="table5")])


def convergence(folder: ResultFolder) -> Section:
    caption = "Each joint's estimate from the first n tests, relative to the truth, with +-1 estimated std (paper Fig. 10)"
    return Section(
        "convergence",
        "Convergence",
        [Figure(figures.convergence(folder.data, folder.root), caption, "fig-convergence")],
    )


def validation(folder: ResultFolder) -> Section | None:
    """Calculated against measured displacement on the validation poses (paper Fig. 11, Table 6)."""
    rows_v = folder.data["validation"]
    if not rows_v:
        return None
    poses = {t.test_id: t.q_deg for t in _tests(folder)}
    rows = []
    for v in rows_v:
        q = poses.get(v["test_id"], [None] * 6)
        rows.append([v["test_id"], *[Num(a, ".2f") for a in q],
                     Num(float(np.linalg.norm(v["measured"][:3])), ".4f", 1e3),
                     Num(float(np.linalg.norm(v["predicted"][:3])), ".4f", 1e3),
                     Num(v["rel_err_translation"], ".2f", 100),
                     Num(float(np.linalg.norm(v["measured"][3:])), ".4f", 1e3),
                     Num(float(np.linalg.norm(v["predicted"][3:])), ".4f", 1e3),
                     Num(v["rel_err_rotation"], ".2f", 100)])  # fmt: skip
    cols = ["test", *[f"q{j + 1} [deg]" for j in range(6)], "|d| measured [mm]", "|d| calculated [mm]",
            "error [%]", "|rot| measured [mrad]", "|rot| calculated [mrad]", "error [%]"]  # fmt: skip
    fig = figures.validation(folder.data, folder.root)
    return Section("validation", "Validation (Table 6 poses)", [
        Table(cols, rows, id="validation-table", caption="Validation poses and the displacement the identified model predicts"),
        Figure(fig, "Calculated against measured displacement per validation test (paper Fig. 11)", "fig-validation")])  # fmt: skip


def residuals(folder: ResultFolder) -> Section:
    ident = folder.data["identification"]
    rows = [[c, Num(s, ".3f", 1e6)] for c, s in zip(COMPONENTS, ident["component_std"])]
    facts = KeyValues([("condition number", Num(ident["condition_number"], ".4g")),
                       ("reduced chi^2", Num(ident["chi2_reduced"], ".4g"))], id="fit-facts")  # fmt: skip
    return Section("residuals", "Residuals per component", [
        Table(["component", "residual std [um | urad]"], rows, id="component-residuals"), facts,
        Figure(figures.residuals(folder.data), "Residual std per displacement component, and each validation "
               "test's measured minus predicted displacement", "fig-residuals")])  # fmt: skip


def scene(folder: ResultFolder) -> Section | None:
    from .scene import one_test_scene

    if folder.dataset is None:
        return None
    view = one_test_scene(folder.dataset)
    caption = (f"Test {view['test_id']}: the robot (nominal kinematics, commanded pose), the block at its fitted "
               f"unloaded frame, the wire along the measured force ({view['hook']}), the unloaded and loaded clouds "
               f"({view['points'][0]} and {view['points'][1]} points drawn) and their fitted faces. Drag to rotate; "
               "'block close-up' zooms to the block.")  # fmt: skip
    return Section("scene", "3-D view of one test", [Plot3D(view["figure_json"], caption, "scene-3d")])


def details(folder: ResultFolder) -> Section:
    r = folder.data
    warnings = r["identification"].get("warnings") or []
    timings = [[k, Num(v, ".3f")] for k, v in r.get("timings_s", {}).items()]
    return Section("details", "Warnings, timings, versions", [
        Text([f"warning: {w}" for w in warnings] or ["No warnings from the identification."]),
        Table(["phase", "time [s]"], timings, id="timings"),
        KeyValues([("seed", str(r["seed"]))] + versions(r, "result.json"), id="versions")])  # fmt: skip


SECTIONS = [scenario, table5, convergence, validation, residuals, scene, details]
