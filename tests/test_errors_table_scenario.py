"""docs/errors.md, scenario, campaign and robot rows: each bad file written for real and read by
the library's loader, or given to the real command (``simulate``, ``sweep``, ``robot``), which
refuses it before any simulation."""

from __future__ import annotations

import copy
import json
import math

import pytest
from errors_table import Ctx, cli, refused, run_row, section_rows

from vtestbed.campaigns.spec import load_campaign
from vtestbed.errors import ScenarioError
from vtestbed.scenario import load_scenario

ROWS = section_rows(
    "Scenario and campaign files (`ScenarioError`, `vtestbed/scenario.py`)",
    "Robot descriptions and lab imports",
)
BASE = {
    "name": "bad",
    "robot": "kuka_kr60_3",
    "seed": 1,
    "poses": {"angles_deg": [[0, -60, -20, 30, 50, 45], [20, -40, -30, -40, 60, 45]]},
    "load": {"hook": "hook_x", "anchor": "ring_5", "tension_N": 200.0},
}
CAMPAIGN = {"trials": 2, "seed": 5, "axes": {"n_tests": [2]}}


def _value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float) and not math.isfinite(v):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf")
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k} = {_value(x)}" for k, x in v.items()) + "}"
    return json.dumps(v) if isinstance(v, str) else repr(v)


def toml(data: dict, prefix: str = "") -> str:
    """A small TOML writer (scalars and arrays first, then the tables)."""
    head = [f"{k} = {_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    tables = [f"\n[{prefix}{k}]\n" + toml(v, f"{prefix}{k}.") for k, v in data.items() if isinstance(v, dict)]
    return "\n".join(head) + "\n" + "".join(tables)


def scenario(ctx: Ctx, edit=None, text: bytes | None = None, campaign: dict | None = None):
    """The base scenario (2 tests), changed by ``edit(data)`` (or the file's bytes): its path."""
    data = copy.deepcopy(BASE)
    if campaign is not None:
        data["campaign"] = copy.deepcopy(campaign)
    if edit is not None:
        edit(data)
    path = ctx.tmp / "bad.toml"
    path.write_bytes(text if text is not None else toml(data).encode())
    return path


def load(edit=None, text=None):
    """A case: the scenario file read by ``load_scenario``."""
    return lambda ctx: refused(lambda: load_scenario(scenario(ctx, edit, text)), ScenarioError)


def simulate(edit=None, text=None):
    """A case: the scenario file given to ``vtestbed simulate`` (refused before simulating)."""
    return lambda ctx: cli(ctx, ["simulate", scenario(ctx, edit, text), "--out", ctx.tmp / "out", "--quiet"])


def campaign(edit):
    """A case: a campaign file (the base scenario with a ``[campaign]`` table) read by ``load_campaign``."""
    return lambda ctx: refused(lambda: load_campaign(scenario(ctx, edit, campaign=CAMPAIGN)), ScenarioError)


def setter(path: str, value):
    """``edit(data)`` setting the dotted ``path`` (a ``[i]`` suffix indexes a list) to ``value``."""

    def edit(data):
        *parents, last = path.split(".")
        for key in parents:
            data = data.setdefault(key, {})
        if last.endswith("]"):
            key, index = last[:-1].split("[")
            data[key][int(index)] = value
        elif value is KeyError:
            del data[last]
        else:
            data[last] = value

    return edit


def _gls_floor_two_repeats(data):
    """gls_floor swept over the base scenario's 2 tests with 2 repeats each: 4 floor samples."""
    data["scanner"] = {"repeats": 2}
    data["campaign"]["axes"]["method"] = ["gls_floor"]


def _missing_file(ctx):
    return cli(ctx, ["simulate", ctx.tmp / "none.toml", "--out", ctx.tmp / "out"])


def _sweep_without_campaign(ctx):
    return cli(ctx, ["sweep", scenario(ctx), "--out", ctx.tmp / "out", "--quiet"])


def given(name: str, text: str, *argv):
    """A case: ``vtestbed argv`` with ``{file}`` a file ``name`` holding ``text`` (nothing else is written)."""

    def case(ctx):
        path = ctx.tmp / name
        path.write_text(text)
        line = cli(ctx, [str(a).replace("{file}", str(path)).replace("{tmp}", str(ctx.tmp)) for a in argv])
        assert [p.name for p in ctx.tmp.iterdir()] == [name]
        return line

    return case


# a manifest whose test lists its own unloaded scan as a repeat (refused before any file is read)
REPEAT_OWN_SCAN = """setup = "setup.json"
[units]
cloud = "mm"
[[tests]]
id = "T001"
group = "identification"
q_deg = [0.0, -90.0, 90.0, 0.0, 0.0, 0.0]
scanner_position_m = [0.3, 0.5, 0.8]
scanner_rotvec_rad = [0.0, 0.0, 0.0]
ft_unloaded = "u.csv"
ft_loaded = "l.csv"
cloud_unloaded = "u.pcd"
cloud_loaded = "l.pcd"
repeat_clouds = ["r1.pcd", "u.pcd"]
"""
# two tests whose clouds would share a dataset file: T001's loaded repeat 1 and T001_loaded's repeat 1
NAMES_ALIKE = REPEAT_OWN_SCAN.replace(
    'repeat_clouds = ["r1.pcd", "u.pcd"]', 'loaded_repeat_clouds = ["l1.pcd"]'
) + (
    REPEAT_OWN_SCAN.split("[[tests]]")[1]
    .replace('"T001"', '"T001_loaded"')
    .replace('"u.pcd"', '"u2.pcd"')
    .replace('"l.pcd"', '"l2.pcd"')
    .replace('["r1.pcd", "u2.pcd"]', '["r2.pcd"]')
    .join(["[[tests]]", ""])
)
ONE_LINK = '<robot name="x"><link name="a"/></robot>'


def _cloud_already_there(ctx):
    """A complete manifest whose output folder already holds one of the clouds it would write:
    refused before any stream or cloud is read, the file kept."""
    from test_dataset import _setup

    from vtestbed.dataset import write_setup
    from vtestbed.lab import LabSetup

    write_setup(ctx.tmp, _setup(LabSetup()))
    manifest = ctx.tmp / "lab.toml"
    manifest.write_text(REPEAT_OWN_SCAN.replace('repeat_clouds = ["r1.pcd", "u.pcd"]\n', ""))
    kept = ctx.tmp / "o" / "clouds" / "T001_unloaded.ply"
    kept.parent.mkdir(parents=True)
    kept.write_bytes(b"kept")
    line = cli(ctx, ["dataset", "import", str(manifest), "--out", str(ctx.tmp / "o")])
    assert kept.read_bytes() == b"kept"
    return line


def _import_in_the_way(edit, out_file=None):
    """A case: the complete manifest of :func:`_cloud_already_there` changed by ``edit(text)``,
    imported into ``o`` (holding ``out_file`` when given): refused before any cloud is converted."""

    def case(ctx):
        from test_dataset import _setup

        from vtestbed.dataset import write_setup
        from vtestbed.lab import LabSetup

        write_setup(ctx.tmp, _setup(LabSetup()))
        manifest = ctx.tmp / "lab.toml"
        manifest.write_text(edit(REPEAT_OWN_SCAN.replace('repeat_clouds = ["r1.pcd", "u.pcd"]\n', "")))
        if out_file:
            (ctx.tmp / "o").mkdir()
            (ctx.tmp / "o" / out_file).write_text("{}")
        line = cli(ctx, ["dataset", "import", str(manifest), "--out", str(ctx.tmp / "o")])
        assert not (ctx.tmp / "o" / "clouds").exists()
        return line

    return case


TWICE = [{"name": "link_compliance", "link": 2}, {"name": "link_compliance", "link": 2}]


def _far_stand_off(ctx):
    """D11: the datasheet's far limit, 1.25 m, given to ``simulate``: refused when the file is read,
    before any folder is made."""
    line = cli(ctx, ["simulate", scenario(ctx, setter("scanner.distance_m", 1.25)), "--out", ctx.tmp / "out"])
    assert not (ctx.tmp / "out").exists()
    return line


def _overloaded(ctx):
    """The paper's first two tests, the second (hook_edge to ring_2) at 500 N: its Fx leaves the
    sensor's range when the wire is tightened (the largest tension is checked against the truth
    world in tests/test_world_physics.py)."""
    from conftest import paper_scenario_data

    data = paper_scenario_data(2, 1, "bad", 1)
    data["load"]["tension_N"] = [200.0, 500.0]
    path = ctx.tmp / "bad.toml"
    path.write_text(toml(data))
    return cli(ctx, ["simulate", path, "--out", ctx.tmp / "out", "--quiet"])


CASES = {
    "scen-joint-limit": simulate(setter("poses.angles_deg[1]", [20, -40, -30, -40, 130, 45])),
    "scen-singular": simulate(setter("poses.angles_deg[1]", [20, -40, -30, -40, 0, 45])),
    "scen-near-singular": load(setter("poses.angles_deg[0]", [0, -60, -20, 30, 0.2, 45])),
    "scen-pose-length": load(setter("poses.angles_deg[0]", [0, -60, -20, 30, 50])),
    "scen-pose-nan": load(setter("poses.angles_deg[0]", [0, -60, float("nan"), 30, 50, 45])),
    "scen-poses-empty": load(setter("poses.angles_deg", [])),
    "scen-convention": load(setter("poses.convention", "kuka")),
    "scen-hook-count": simulate(setter("load.hook", ["hook_x", "hook_y", "hook_x"])),
    "scen-hook-nested": load(setter("load.hook", [["hook_x"], "hook_y"])),
    "scen-hook-unknown": load(setter("load.hook", "hook_z")),
    "scen-tension-range": load(setter("load.tension_N", 5000.0)),
    "scen-tension-nan": load(setter("load.tension_N", float("nan"))),
    "scen-unknown-key": simulate(setter("scanner.nosie", 0.1)),
    "scen-unknown-top": load(setter("sead", 1)),
    "scen-table-number": load(setter("scanner", 5)),
    "scen-table-list": load(setter("force_sensor", [])),
    "scen-name-missing": load(setter("name", KeyError)),
    "scen-robot-unknown": load(setter("robot", "kr6")),
    "scen-robot-path": load(setter("robot", "/etc")),
    "scen-seed": load(setter("seed", -1)),
    "scen-distance": load(setter("scanner.distance_m", 5.0)),
    "scen-distance-block": _far_stand_off,
    "scen-block-too-deep": load(setter("lab", {"block": {"edge_m": 0.2}})),
    "scen-scan-at-pose": simulate(setter("scanner.distance_m", 1.18)),
    "scen-overload": _overloaded,
    "scen-effect-twice": load(setter("world.effects", TWICE)),
    "scen-repeats": load(setter("scanner.repeats", 2.5)),
    "scen-ft-noise": load(setter("force_sensor.noise_std", [1, 1, 1, 1, 1, -1])),
    "scen-method": load(setter("identification.method", "wls")),
    "scen-reference-no-repeats": simulate(setter("identification.reference", "mean")),
    "scen-gls-few-repeats": simulate(
        lambda d: (setter("identification.method", "gls_floor")(d), setter("scanner.repeats", 2)(d))
    ),
    "scen-not-utf8": simulate(text=b'name = "kr\xe960"\n'),
    "scen-not-toml": load(text=b"name = kr60\n"),
    "scen-sensor-range-tiny": load(setter("lab.force_sensor", {"range_N_Nm": [0.001] * 6})),
    "scen-robot-number": load(setter("robot", 3)),
    "scen-coupling-indefinite": simulate(
        setter(
            "world", {"effects": [{"name": "joint_coupling", "joints": [5, 6], "stiffness_Nm_per_rad": -1e8}]}
        )
    ),
    "scen-nested-deep": load(text=b"x = " + b"[" * 5000 + b"]" * 5000 + b"\n"),
    "scen-missing": _missing_file,
    "camp-missing": _sweep_without_campaign,
    "camp-trials-missing": campaign(setter("campaign.trials", KeyError)),
    "camp-trials-zero": campaign(setter("campaign.trials", 0)),
    "camp-unknown-axis": campaign(setter("campaign.axes.n_test", [1])),
    "camp-duplicate-value": campaign(setter("campaign.axes.n_tests", [2, 2])),
    "camp-too-many-tests": campaign(setter("campaign.axes.n_tests", [3])),
    "camp-gls-floor-few-samples": campaign(_gls_floor_two_repeats),
    "robot-path": lambda ctx: cli(ctx, ["robot", "--robot", "/etc"]),
    "urdf-not-xml": given("bad.urdf", "not xml", "robot", "import", "{file}", "--name", "zz_bad"),
    "urdf-missing": given("bad.urdf", "", "robot", "import", "{tmp}/none.urdf", "--name", "zz_bad"),
    "urdf-no-arm": given("one.urdf", ONE_LINK, "robot", "import", "{file}", "--name", "zz_bad"),
    "manifest-unknown-key": given(
        "lab.toml", "robot = 5\n", "dataset", "import", "{file}", "--out", "{tmp}/o"
    ),
    "manifest-missing": given("lab.toml", "", "dataset", "import", "{tmp}/none.toml", "--out", "{tmp}/o"),
    "manifest-repeat-own-scan": given(
        "lab.toml", REPEAT_OWN_SCAN, "dataset", "import", "{file}", "--out", "{tmp}/o"
    ),
    "manifest-cloud-names-alike": given(
        "lab.toml", NAMES_ALIKE, "dataset", "import", "{file}", "--out", "{tmp}/o"
    ),
    "import-cloud-exists": _cloud_already_there,
    "import-pose-outside-limits": _import_in_the_way(
        lambda t: t.replace("[0.0, -90.0, 90.0, 0.0, 0.0, 0.0]", "[0.0, -90.0, 90.0, 0.0, 130.0, 0.0]")
    ),
    "import-setup-exists": _import_in_the_way(lambda t: t, out_file="setup.json"),
    "manifest-one-stream-no-windows": given(
        "lab.toml",
        REPEAT_OWN_SCAN.replace('ft_loaded = "l.csv"', 'ft_loaded = "u.csv"'),
        "dataset",
        "import",
        "{file}",
        "--out",
        "{tmp}/o",
    ),
    "diagnose-not-a-dataset": given("notes.txt", "", "diagnose", "{tmp}"),
    "diagnose-candidate-twice": given(
        "notes.txt", "", "diagnose", "{tmp}", "--candidates", "link_compliance,link_compliance"
    ),
    "diagnose-candidate-unknown": given("notes.txt", "", "diagnose", "{tmp}", "--candidates", "wobble"),
    "diagnose-candidate-empty": given(
        "notes.txt", "", "diagnose", "{tmp}", "--candidates", "link_compliance,"
    ),
}


@pytest.mark.parametrize("key", sorted(set(ROWS) | set(CASES)))
def test_documented_message_is_the_codes(key, tmp_path, capsys):
    run_row(CASES, ROWS, key, Ctx(tmp_path, capsys))
