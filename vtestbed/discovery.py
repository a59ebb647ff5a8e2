"""``discover``: the discrepancy loop in the virtual lab, with one round of discrimination tests.

An orchestrator like :mod:`vtestbed.experiment`: it drives the truth world (simulate) and the
researcher's side (diagnose, propose, and a nominal simulator without the hidden effects that
says whether a proposed test can be run, :class:`LabCheck`), and only the files of a dataset
cross between them.

1. **Simulate** the scenario (``DIR/round0/dataset``) and **diagnose** it (``DIR/round0/diagnose``).
2. If the diagnosis is undecided (:func:`vtestbed.design.discriminate.rivals_from_report`:
   confusable top candidates, or marginal evidence), **propose** ``k`` extra tests that separate
   the rival models (T-optimal by default, :mod:`vtestbed.design.discriminate`), from the
   dataset, its noise floor, the lab's layout and a nominal simulator without the hidden effects
   (:class:`LabCheck`) only. ``DIR/proposal.toml`` is that to-do list.
3. **Simulate the extra tests in the same hidden world**: ``DIR/round1/scenario.toml`` is the
   scenario with the extra tests appended to its identification tests (DH angles) and every
   other table, the world's included, copied. Test ``i`` draws from ``SeedSequence(seed,
   spawn_key=(group, i))``, so the first tests of that scenario are those of round 0: their files
   are copied (clouds hard-linked) and only the new ones (``T021``, ... for 20 tests) are
   simulated, as a resumed ``vtestbed simulate`` of the longer scenario would.
4. **Diagnose again** on the combined dataset (``DIR/round1/diagnose``).

``DIR/discover.json`` and ``discover.md`` give the names before and after, and the separation:
predicted (the design's T, in units of the noise floor squared) and measured (the BIC gap between
the best and the next rival refitted to the data). The candidate pool draws from
``SeedSequence(seed, spawn_key=(POOL_STREAM, round))``. Units: SI.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import numpy as np

from .dataset import CLOUD_DIR, TRUTH_FILE
from .design import discriminate as disc
from .errors import DatasetError, OutOfRangeError, VtestbedError
from .files import read_json, write_json_atomic, write_text_atomic
from .researcher import cloud
from .researcher.candidates import CANDIDATE_NAMES, ModelContext, candidates
from .researcher.diagnose import DEFAULT_ALPHA, Whitener, require_floor
from .researcher.discrepancy import diagnose
from .researcher.kinematics import ArmKinematics
from .researcher.measure import load_measurements
from .researcher.noise_floor import estimate_noise_floor
from .researcher.statics import ExactStatics
from .scenario import Scenario, load_scenario
from .transforms import invert

__all__ = ["discover", "proposal_text", "scenario_text", "toml_text"]

POOL_STREAM = 7  # spawn key of the candidate pool's generator (0, 1: the test groups)
EXTRA_TESTS_RANGE = (1, 50)
DEFAULT_EXTRA_TESTS = 10


def _toml_key(k) -> str:
    k = str(k)
    return k if k and all(c.isascii() and (c.isalnum() or c in "_-") for c in k) else json.dumps(k)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))  # shortest exact round trip; inf and nan are valid TOML
    if isinstance(v, str):
        return json.dumps(v)  # ASCII, with TOML's basic-string escapes (\", \\, \n, \uXXXX)
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise OutOfRangeError(f"cannot write {type(v).__name__} {v!r} to a scenario file")


def _toml_table(prefix: str, table: dict) -> list[str]:
    """Lines of one table: its values, then its sub-tables, then its arrays of tables."""
    plain = [(k, v) for k, v in table.items() if not _is_table(v) and not _is_tables(v)]
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in plain]
    out = ([f"[{prefix}]"] if prefix and (lines or not table) else []) + lines
    for k, v in table.items():
        name = f"{prefix}.{_toml_key(k)}" if prefix else _toml_key(k)
        if _is_table(v):
            out += ["", *_toml_table(name, v)]
        elif _is_tables(v):
            for item in v:
                out += ["", f"[[{name}]]", *(f"{_toml_key(a)} = {_toml_value(b)}" for a, b in item.items())]
    return out


def _is_table(v) -> bool:
    return isinstance(v, dict)


def _is_tables(v) -> bool:
    return isinstance(v, list) and bool(v) and all(isinstance(x, dict) for x in v)


def toml_text(mapping: dict) -> str:
    """``mapping`` as a TOML document: the one scenario-file writer of ``discover`` (strings and
    keys quoted with JSON's escapes, which TOML's basic strings share; floats exact)."""
    return "\n".join(_toml_table("", mapping)) + "\n"


def _tests_tables(q, hooks, anchors, tensions) -> dict:
    """The ``[poses]`` (DH degrees) and ``[load]`` tables of a scenario file for these tests."""
    return {"poses": {"convention": "dh", "angles_deg": np.degrees(np.asarray(q, dtype=float)).tolist()},
            "load": {"hook": list(hooks), "anchor": list(anchors), "tension_N": [float(t) for t in tensions]}}  # fmt: skip


def scenario_text(scenario: Scenario, tests, name: str, description: str) -> str:
    """The scenario file of ``scenario`` with ``tests`` (CandidateTest) appended, in DH degrees.

    Every other table of the original file (lab, scanner, force sensor, identification,
    validation and the hidden world) is copied as it was.
    """
    raw = {k: v for k, v in scenario.raw.items() if k not in ("poses", "load", "campaign")}
    tests = list(tests)
    head = {"name": name, "description": description, "robot": scenario.robot_name, "seed": scenario.seed}
    body = _tests_tables(
        np.vstack([scenario.poses, *(t.q[None] for t in tests)]), [*scenario.load.hooks, *(t.hook for t in tests)],
        [*scenario.load.anchors, *(t.anchor for t in tests)], [*scenario.load.tensions, *(t.tension for t in tests)],
    )  # fmt: skip
    rest = {k: v for k, v in raw.items() if k not in head}
    return toml_text(head | body | rest)


def proposal_text(proposal: disc.Proposal, name: str, robot: str) -> str:
    """A scenario file of the extra tests alone (DH angles): the lab's to-do list."""
    c, ts = proposal.choice, proposal.tests
    description = (f"Extra tests that separate {', '.join(proposal.rivals)} ({proposal.reason}; "
                   f"{c.criterion}-optimal, separation {c.separation_before:.3g} -> {c.separation_after:.3g})")  # fmt: skip
    head = {"name": name, "description": description, "robot": robot}
    return toml_text(head | _tests_tables([t.q for t in ts], [t.hook for t in ts], [t.anchor for t in ts],
                                          [t.tension for t in ts]))  # fmt: skip


def _extend_dataset(src: Path, dst: Path, scenario: Scenario) -> None:
    """Copy ``src``'s dataset to ``dst`` as the first tests of ``scenario`` (clouds hard-linked)."""
    if (dst / TRUTH_FILE).exists():
        old = read_json(dst / TRUTH_FILE, "truth file", DatasetError).get("scenario_fingerprint")
        if old == scenario.fingerprint:
            return  # a resumed discover: simulate finishes what is missing
        shutil.rmtree(dst)  # an earlier discover's round with another proposal: ours to replace
    dst.mkdir(parents=True, exist_ok=True)
    for item in src.iterdir():
        if item.name == CLOUD_DIR:
            shutil.copytree(item, dst / CLOUD_DIR, copy_function=_link_or_copy, dirs_exist_ok=True)
        elif item.is_file() and item.name != TRUTH_FILE and not item.name.startswith("."):
            shutil.copy2(item, dst / item.name)  # tests.csv and repeats.csv grow: never linked
    truth = read_json(src / TRUTH_FILE, "truth file", DatasetError)
    truth["scenario"], truth["scenario_fingerprint"] = scenario.name, scenario.fingerprint
    write_json_atomic(dst / TRUTH_FILE, truth)  # the marker that lets simulate resume here


def _link_or_copy(src, dst):
    try:
        os.link(src, dst)
    except OSError:  # another file system, or no hard links: copy
        shutil.copy2(src, dst)
    return dst


SCAN_MARGIN = 0.7  # a proposed test's faces must span this fraction of the edge noise-free (fit: 0.5)
SENSOR_MARGIN = 0.95  # its true F/T load must stay within this fraction of the range: noise and bias


class LabCheck:
    """The answer to "can this test be run?" from a simulator of the researcher's *nominal* lab.

    A MuJoCo rig of the robot's description, the lab's layout, the scanner's stand-off and the
    F/T range, **without** the scenario's hidden effects: what a researcher could build from their
    own nominal model (the world's simulation is never asked). Its joint stiffness is the rig's
    default, ``models/<robot>/truth.toml``, which for the KR60 is the paper's published Table 5
    (the ``paper_table5`` prior a researcher has too). Plus the researcher's cloud fit of both
    noise-free scans with a margin on the faces' extent. Cached.
    """

    def __init__(self, scenario: Scenario):
        from .world.rig import Rig

        self.lab = scenario.lab
        self.rig = Rig(scenario.robot, scenario.lab)  # no effects: the nominal lab
        self.distance, self.placement = scenario.scanner.distance, scenario.scanner.placement
        self.kin = ArmKinematics(scenario.robot, scenario.lab.block_in_flange)
        self.params = cloud.FitParams(edge_m=scenario.lab.block.edge, min_extent_fraction=SCAN_MARGIN)
        self.refused: dict = {}

    def __call__(self, test) -> bool:
        from .world.physics import run_test_physics

        key = (np.asarray(test.q).tobytes(), test.hook, test.anchor, float(test.tension))
        if key in self.refused:
            return self.refused[key] is None
        try:
            phys = run_test_physics(
                self.rig,
                test.q,
                test.hook,
                test.anchor,
                test.tension,
                self.distance,
                self.placement,
                clearance="raise",  # a proposed test must be one a lab can run
            )
            limit = SENSOR_MARGIN * np.asarray(self.lab.sensor.wrench_range)
            if np.any(np.abs(phys.loaded.sensor_wrench) > limit):  # measured 330.9 N on a 330 N axis
                raise OutOfRangeError(f"the F/T load is within {1 - SENSOR_MARGIN:.0%} of the sensor's range")
            nominal = invert(phys.scanner.pose_world) @ self.kin.tool_pose(test.q)
            for hits in (phys.hits_unloaded, phys.hits_loaded):
                cloud.fit_block_frame(hits.points_m, nominal, self.params)
            self.refused[key] = None
        except VtestbedError as exc:
            self.refused[key] = f"{type(exc).__name__}: {exc}"
        return self.refused[key] is None


def _researcher_view(root: Path):
    """(ctx, white, pool): the dataset's identification tests, noise floor and candidate terms."""
    from .robots import load_robot

    setup, ms = load_measurements(root)
    floor = require_floor(estimate_noise_floor(root, ms), root)
    kin = ArmKinematics(load_robot(setup.robot), setup.block_in_flange)
    # the diagnosis's baseline: the clean world's exact statics, so that the rivals' fits are its fits
    ctx = ModelContext([m for m in ms if m.group == "identification"], setup, kin, ExactStatics(kin, setup))
    return ctx, Whitener(floor), candidates(kin, CANDIDATE_NAMES)


def measured_separation(ctx, white, pool, rivals: dict) -> dict:
    """The rivals refitted to the data: chi^2, BIC, the best and the BIC gap to the next one."""
    hyps = disc.fit_hypotheses(ctx, white, rivals["base_terms"], rivals["rivals"], pool)
    n_obs = 6 * ctx.n_tests
    bic = {h.label: float(h.chi2 + len(h.x) * np.log(n_obs)) for h in hyps}
    order = sorted(bic, key=bic.get)
    return {"chi2": {h.label: h.chi2 for h in hyps}, "bic": bic, "best": order[0],
            "delta_bic": bic[order[1]] - bic[order[0]] if len(order) > 1 else None}  # fmt: skip


def discover(
    scenario: Scenario,
    out,
    extra_tests: int = DEFAULT_EXTRA_TESTS,
    alpha: float = DEFAULT_ALPHA,
    criterion: str = "T",
    n_poses: int = 150,
    tensions=disc.DEFAULT_TENSIONS_N,
    progress: bool = False,
    always: bool = False,
) -> dict:
    """Simulate, diagnose, propose extra tests if undecided, simulate them, diagnose again.

    Parameters
    ----------
    scenario : Scenario
        The experiment, hidden world included (it needs ``[scanner] repeats >= 2``).
    out : str or Path
        Output folder: ``round0/``, ``proposal.toml``, ``round1/``, ``discover.json``, ``discover.md``.
    extra_tests : int
        Number of extra tests, in :data:`EXTRA_TESTS_RANGE`.
    alpha : float
        Family-wise false-alarm rate of the diagnosis, in (0, 1).
    criterion : {"T", "difference"}
        The discrimination criterion (:mod:`vtestbed.design.discriminate`).
    n_poses : int
        Random poses of the candidate pool (each with every feasible hook, ring and tension).
    tensions : sequence of float
        Wire tensions of the candidates [N].
    always : bool
        Run the round of extra tests even when the diagnosis is decisive: they confirm the first
        name against its closest rivals, or screen the baseline against the strongest candidates
        (:func:`vtestbed.design.discriminate.confirming_rivals`). Lab time for certainty: a name
        the first round got wrong outside the confusable band, or an effect just below the
        level, is otherwise never questioned.

    Returns
    -------
    dict
        What ``discover.json`` holds.
    """
    from .experiment import simulate

    lo, hi = EXTRA_TESTS_RANGE
    if not (isinstance(extra_tests, (int, np.integer)) and lo <= extra_tests <= hi):
        raise OutOfRangeError(f"extra_tests = {extra_tests!r} is outside the valid range [{lo}, {hi}]")
    if not 0.0 < alpha < 1.0:
        raise OutOfRangeError(f"alpha = {alpha:g} must be in (0, 1)")
    if criterion not in disc.CRITERIA:
        from .errors import UnknownNameError

        raise UnknownNameError("discrimination criterion", criterion, disc.CRITERIA)
    if scenario.scanner.repeats < 2:
        raise OutOfRangeError(
            f"scanner.repeats = {scenario.scanner.repeats}: discover diagnoses against the repeat scans' "
            "noise floor, so the scenario needs [scanner] repeats >= 2"
        )
    out = Path(out)
    ds0 = simulate(scenario, out / "round0" / "dataset", progress=progress)
    rep0 = diagnose(ds0, alpha=alpha, out=out / "round0" / "diagnose")
    result = {"scenario": scenario.name, "seed": scenario.seed, "alpha": alpha, "criterion": criterion,
              "named_before": rep0["named"], "confusable_before": rep0["confusable"],
              "rivals": None, "proposal": None, "named_after": None,
              "validation_gap_before": validation_summary(rep0), "validation_gap_after": None}  # fmt: skip
    rivals = disc.rivals_from_report(rep0, alpha)
    if rivals is None and always:
        rivals = disc.confirming_rivals(rep0)
    if rivals is None:
        result["note"] = "the diagnosis is decisive: no discrimination tests needed"
        return _finish(result, out)
    # The researcher's side: the dataset, its floor, the lab's layout, a nominal rig; never the world.
    ctx, white, pool = _researcher_view(ds0)
    rng = np.random.default_rng(np.random.SeedSequence(scenario.seed, spawn_key=(POOL_STREAM, 0)))
    tests = disc.test_pool(scenario.robot, scenario.lab, rng, n_poses, tensions)
    lab = LabCheck(scenario)  # the nominal lab, no hidden effects: block scannable, sensor in range?
    proposal = disc.propose(
        ctx, white, pool, rivals, tests, scenario.lab, extra_tests, criterion, feasible=lab
    )
    result["rivals"] = rivals
    refused = sum(v is not None for v in lab.refused.values())
    result["proposal"] = proposal.to_dict() | {"tests_refused_by_the_lab": refused}
    result["measured_before"] = measured_separation(ctx, white, pool, rivals)
    write_text_atomic(
        out / "proposal.toml", proposal_text(proposal, f"{scenario.name}_proposal", scenario.robot_name)
    )
    # The world's side: the same hidden world runs the extra tests.
    name = f"{scenario.name}_discover1"
    text = scenario_text(scenario, proposal.tests, name,
                         f"{scenario.name} plus {len(proposal.tests)} discrimination tests (vtestbed discover)")  # fmt: skip
    (out / "round1").mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "round1" / "scenario.toml", text)
    combined = load_scenario(out / "round1" / "scenario.toml")
    _extend_dataset(ds0, out / "round1" / "dataset", combined)
    ds1 = simulate(combined, out / "round1" / "dataset", progress=progress)
    rep1 = diagnose(ds1, alpha=alpha, out=out / "round1" / "diagnose")
    ctx1, white1, pool1 = _researcher_view(ds1)
    result["measured_after"] = measured_separation(ctx1, white1, pool1, rivals)
    result["named_after"] = rep1["named"]
    result["validation_gap_after"] = validation_summary(rep1)
    result["confusable_after"] = rep1["confusable"]
    return _finish(result, out)


def validation_summary(report: dict) -> dict | None:
    """The validation tests' prediction error over the noise floor (1 = the noise), with the paper's
    model ("baseline") and with the terms the diagnosis named ("named"); None without validation tests."""
    val = report.get("validation") or {}
    if not val.get("before"):
        return None
    return {"baseline": val["before"]["ratio_to_floor"], "named": val["after"]["ratio_to_floor"]}


def _finish(result: dict, out: Path) -> dict:
    write_json_atomic(out / "discover.json", json.loads(json.dumps(result, default=float)))
    write_text_atomic(out / "discover.md", markdown(result))
    return result


def markdown(result: dict) -> str:
    """A short report: the names before and after, and the separation before and after."""

    def names(v):
        return ", ".join(f"`{n}`" for n in v) if v else "nothing"

    lines = [f"# discover: {result['scenario']} (seed {result['seed']}, alpha {result['alpha']:g})", "",
             f"**Before**: named {names(result['named_before'])}."]  # fmt: skip
    for c in result["confusable_before"]:
        lines.append(f"- `{c['chosen']}` could also be `{c['runner_up']}` (BIC {c['delta_bic']:.1f} apart)")
    if result["rivals"] is None:
        return "\n".join([*lines, "", result.get("note", ""), ""])
    p, r = result["proposal"], result["rivals"]
    mb, ma = result["measured_before"], result["measured_after"]
    lines += [
        "",
        {"confirm": "**Confirming** (decisive, `--always`)", "screen": "**Screening** (nothing named, `--always`)"}
        .get(r["reason"], f"**Undecided** ({r['reason']})")
        + f": {names(r['rivals'])}"
        + (f" on top of {names(r['base_terms'])}" if r["base_terms"] else "") + ".",
        f"**Proposed** {len(p['tests'])} extra tests ({p['criterion']}-optimal among {p['pool_size']} "
        f"candidates; {p['tests_refused_by_the_lab']} refused by the lab): predicted separation "
        f"(smallest T over the rival pairs, noise floor units) {p['separation_before']:.1f} -> "
        f"{p['separation_after']:.1f}.",
        f"Measured: the best rival `{mb['best']}` leads by BIC {mb['delta_bic']:.1f} before; "
        f"`{ma['best']}` by {ma['delta_bic']:.1f} after.",
        "",
        f"**After**: named {names(result['named_after'])}.",
    ]  # fmt: skip
    vb, va = result.get("validation_gap_before"), result.get("validation_gap_after")
    if vb and va:
        lines.append(f"Validation prediction error over the noise floor: {vb['baseline']:.2f} with the paper's "
                     f"model, {vb['named']:.2f} with the terms named before, {va['named']:.2f} after.")  # fmt: skip
    for c in result["confusable_after"]:
        lines.append(f"- still `{c['chosen']}` or `{c['runner_up']}` (BIC {c['delta_bic']:.1f} apart)")
    return "\n".join(lines) + "\n"
