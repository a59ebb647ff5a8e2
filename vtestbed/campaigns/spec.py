"""Monte Carlo campaigns: a base scenario, sweep axes, trials per cell, one seed.

A campaign lives in a scenario file as the ``[campaign]`` table (the rest of the file is the
base scenario)::

    [campaign]
    seed = 7          # root of every seed (default: the scenario's seed)
    trials = 20       # trials per cell
    paired = true     # common random numbers: trial t draws the same seed in every cell

    [campaign.axes]   # the cells are the Cartesian product of the axes
    scanner_noise_scale = [0.5, 1.0, 2.0]   # x the scanner's range std and drifts
    ft_noise_scale = [1.0]                  # x the F/T sensor's noise std
    n_tests = [5, 10, 20]                   # tests per identification
    pose_set = ["kappa_regions", "random", "design_optimal", "scenario"]
    method = ["fgls"]                       # "ols" (the paper's), "fgls" or "gls_floor" (repeats >= 2)

    [campaign.pose_sets]   # optional: how generated pose sets are drawn (see posesets.py)
    pool = 40

An axis that is not given stays at the base scenario's value (pose set ``scenario``, its test
count, noise scales 1, its method). :func:`parse_campaign` validates everything before any
work starts and raises :class:`~vtestbed.errors.ScenarioError` naming the field.

Seeds: trial ``t`` of a cell gets ``SeedSequence(seed, spawn_key=(0, t))`` when ``paired``
(the same noise draws in every cell: noise levels and test counts are compared on common
random numbers) or ``spawn_key=(0, t, *hash(cell))`` otherwise; pose set ``p`` is drawn from
``spawn_key=(1, id(p))``. No seed depends on scheduling, batching or the order of the axes.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..design.priors import NAMED_PRIORS, PAPER_TABLE5
from ..errors import OutOfRangeError
from ..lab import DEFAULT_TENSION_N, LabSetup
from ..scenario import FT_NOISE_STD_MAX, Scenario, parse_scenario, read_scenario_file
from ..schema import Fields
from ..world.scan_noise import ScanNoise, scaled_noise

POSE_SETS = ("scenario", "kappa_regions", "random", "design_optimal")
POSE_SET_IDS = {name: i for i, name in enumerate(POSE_SETS)}
NESTED_POSE_SETS = ("scenario", "kappa_regions", "random")  # n tests = the first n of one list
# "wls" needs a stated displacement covariance: not a campaign axis; "gls_floor" needs repeats
METHODS = ("ols", "fgls", "gls_floor")
AXES = ("pose_set", "n_tests", "scanner_noise_scale", "ft_noise_scale", "method")  # canonical order
CAMPAIGN_KEYS = ("seed", "trials", "paired", "axes", "pose_sets", "description")
DESIGN_CRITERIA = ("D", "A", "E", "minimax")
DESIGN_POOLS = ("kappa_regions", "random")
MAX_TRIALS = 100_000
MAX_NOISE_SCALE = 1000.0
TRIAL_STREAM, POSE_SET_STREAM = 0, 1


@dataclass(frozen=True)
class PoseSetOptions:
    """How the generated pose sets are drawn (``[campaign.pose_sets]``), SI except angles.

    ``pool``: poses drawn from the kappa regions (the candidates of ``kappa_regions`` and of
    ``design_optimal``); ``tension_N`` [N]: wire tension of generated tests; ``threshold``:
    lowest criterion inv_kappa of a region pose; ``min_height_m`` [m] and ``box_m``
    (xmin, ymin, zmin, xmax, ymax, zmax) [m]: where the block may be (lab constraints, also for
    ``random``); ``wrist_jitter_deg`` [deg]: spread of joints 4, 5 around the optimum;
    ``criterion``: D, A, E or minimax (the worst joint's relative std) for ``design_optimal``; ``design_pool``: the poses it chooses from;
    ``stiffness_prior``: a prior's name (:data:`vtestbed.design.priors.NAMED_PRIORS`) or the
    researcher's own values [N*m/rad]; the D criterion does not depend on it, A and E do.
    The defaults here are the paper's lab; a campaign's come from its scenario's lab
    (:func:`pose_set_defaults`).
    """

    pool: int = 40
    tension_N: float = DEFAULT_TENSION_N
    threshold: float = 0.7
    min_height_m: float = 0.8
    box_m: tuple[float, ...] = (0.3, -1.0, 0.0, 2.3, 1.0, 2.2)
    wrist_jitter_deg: float = 30.0
    criterion: str = "D"
    design_pool: str = "kappa_regions"
    stiffness_prior: str | tuple[float, ...] = PAPER_TABLE5.name


def pose_set_defaults(lab: LabSetup) -> PoseSetOptions:
    """The ``[campaign.pose_sets]`` defaults in ``lab``: its default wire tension and block zone
    (:func:`vtestbed.robot_lab.lab_for_robot`; exactly the class defaults in the paper's lab)."""
    return PoseSetOptions(
        tension_N=lab.default_tension_N, min_height_m=lab.zone.min_height, box_m=tuple(lab.zone.box)
    )


@dataclass(frozen=True)
class Cell:
    """One point of the sweep grid (every axis has a value, swept or not)."""

    pose_set: str
    n_tests: int
    scanner_noise_scale: float
    ft_noise_scale: float
    method: str

    @property
    def key(self) -> str:
        """Stable text key, e.g. ``pose_set=random;n_tests=5;scanner_noise_scale=1.0;...``."""
        return ";".join(f"{a}={getattr(self, a)!r}".replace("'", "") for a in AXES)

    def params(self) -> dict:
        return dataclasses.asdict(self)

    def hash_words(self) -> tuple[int, ...]:
        """Four 32-bit words of the key's SHA-256 (the cell's part of an unpaired seed)."""
        digest = hashlib.sha256(self.key.encode()).digest()
        return tuple(int.from_bytes(digest[4 * i : 4 * i + 4], "little") for i in range(4))


@dataclass(frozen=True)
class Campaign:
    """A validated campaign: base scenario, axes (canonical order), trials per cell, seeds."""

    scenario: Scenario
    seed: int
    trials: int
    paired: bool
    axes: tuple[tuple[str, tuple], ...]  # swept axes only, in AXES order
    pose_sets: PoseSetOptions
    description: str = ""
    source: Path | None = None

    @property
    def swept(self) -> tuple[str, ...]:
        return tuple(name for name, _ in self.axes)

    def values(self, axis: str) -> tuple:
        """The values of ``axis`` in this campaign (the base value if it is not swept)."""
        return dict(self.axes).get(axis, (self.default(axis),))

    def default(self, axis: str):
        sc = self.scenario
        return {"pose_set": "scenario", "n_tests": sc.n_tests, "scanner_noise_scale": 1.0,
                "ft_noise_scale": 1.0, "method": sc.method}[axis]  # fmt: skip

    def cells(self) -> tuple[Cell, ...]:
        """Every cell, in a fixed order (the product of the axes in AXES order)."""
        return tuple(Cell(*combo) for combo in itertools.product(*(self.values(a) for a in AXES)))

    @property
    def n_trials(self) -> int:
        return len(self.cells()) * self.trials

    def trial_seed(self, cell: Cell, trial: int) -> int:
        """The integer seed of trial ``trial`` of ``cell`` (< 2**63, independent of scheduling)."""
        key = (TRIAL_STREAM, int(trial)) + (() if self.paired else cell.hash_words())
        state = np.random.SeedSequence(self.seed, spawn_key=key).generate_state(1, np.uint64)
        return int(state[0]) >> 1

    def pose_set_rng(self, pose_set: str) -> np.random.Generator:
        """The generator a pose set is drawn with (one per pose set and campaign seed)."""
        return np.random.default_rng(
            np.random.SeedSequence(self.seed, spawn_key=(POSE_SET_STREAM, POSE_SET_IDS[pose_set]))
        )

    def plan_key(self, cell: Cell) -> str:
        """The test list a cell runs on: nested pose sets share one list of the largest size."""
        n = max(self.values("n_tests")) if cell.pose_set in NESTED_POSE_SETS else cell.n_tests
        return f"{cell.pose_set}:{n}"

    def scan_noise(self, cell: Cell) -> ScanNoise | None:
        """The scanner noise of a cell: range std and drifts of the base scaled by the cell's factor."""
        base = self.scenario.scanner.noise_model
        return None if base is None else scaled_noise(base, cell.scanner_noise_scale)

    def ft_noise_std(self, cell: Cell) -> tuple[float, ...]:
        """(6,) F/T noise std of a cell [N, N*m]."""
        return tuple(float(s) * cell.ft_noise_scale for s in self.scenario.force_sensor.noise_std)

    @property
    def fingerprint(self) -> str:
        """Hash of everything that shapes a trial's numbers (not the axes or the trial count:
        a rerun with more trials or axis values adds trials to the same results folder)."""
        raw = {k: v for k, v in self.scenario.raw.items() if k != "campaign"}
        data = {"scenario": raw, "seed": self.seed, "paired": self.paired,
                "pose_sets": dataclasses.asdict(self.pose_sets)}  # fmt: skip
        return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        return {"scenario": self.scenario.name, "seed": self.seed, "trials": self.trials,
                "paired": self.paired, "axes": {a: list(v) for a, v in self.axes},
                "pose_sets": dataclasses.asdict(self.pose_sets), "cells": len(self.cells()),
                "fingerprint": self.fingerprint}  # fmt: skip


def _axis_values(name: str, values, scenario: Scenario, f: Fields) -> tuple:
    field = f"campaign.axes.{name}"
    if not isinstance(values, list):
        raise f.error(field, f"must be a list of values, got {values!r}")
    if not values:
        raise f.error(field, "is empty: give at least one value (or leave the axis out)")
    out = []
    for i, v in enumerate(values):
        item = f"{field}[{i}]"
        if name == "pose_set":
            out.append(f.choice(v, item, POSE_SETS))
        elif name == "method":
            out.append(f.choice(v, item, METHODS))
            if out[-1] == "gls_floor" and scenario.scanner.repeats < 2:
                raise f.error(
                    item, "'gls_floor' needs repeat scans: set [scanner] repeats >= 2 in the scenario"
                )
        elif name == "n_tests":
            out.append(f.integer(v, item, 2, 500))
        elif name == "scanner_noise_scale":
            s = f.number(v, item, 0.0, MAX_NOISE_SCALE)
            if scenario.scanner.noise_model is None:
                raise f.error(field, "the base scenario has scanner.noise = false: nothing to scale")
            try:
                scaled_noise(scenario.scanner.noise_model, s)
            except OutOfRangeError as exc:
                raise f.error(item, f"scale {s:g} puts the scanner noise out of range: {exc}") from None
            out.append(s)
        else:  # ft_noise_scale
            s = f.number(v, item, 0.0, MAX_NOISE_SCALE)
            if not any(scenario.force_sensor.noise_std):
                raise f.error(field, "the base scenario's force_sensor.noise_std is zero: nothing to scale")
            if max(scenario.force_sensor.noise_std) * s > FT_NOISE_STD_MAX:
                raise f.error(item, f"scale {s:g} puts the F/T noise std above {FT_NOISE_STD_MAX:g} N (N*m)")
            out.append(s)
    if len(set(out)) != len(out):
        dup = next(v for v in out if out.count(v) > 1)
        raise f.error(field, f"value {dup!r} appears twice")
    return tuple(out)


def _pose_set_options(table, scenario: Scenario, f: Fields) -> PoseSetOptions:
    prefix = "campaign.pose_sets."
    f.table(table, "campaign.pose_sets", tuple(fld.name for fld in dataclasses.fields(PoseSetOptions)))
    d = pose_set_defaults(scenario.lab)
    box = table.get("box_m", list(d.box_m))
    if not isinstance(box, list) or len(box) != 6:
        raise f.error(
            prefix + "box_m", f"must be 6 numbers xmin, ymin, zmin, xmax, ymax, zmax [m], got {box!r}"
        )
    box = f.vector(box, prefix + "box_m", 6, -10.0, 10.0)
    if not all(box[i] < box[i + 3] for i in range(3)):
        raise f.error(prefix + "box_m", f"the minimum must be below the maximum on every axis, got {box}")
    threshold = f.number(table.get("threshold", d.threshold), prefix + "threshold", 0.0, 1.0)
    if not 0.0 < threshold < 1.0:
        raise f.error(prefix + "threshold", f"must be in (0, 1), got {threshold:g}")
    low, high = scenario.lab.tension_range_N
    prior = table.get("stiffness_prior", d.stiffness_prior)
    if isinstance(prior, list):
        prior = f.vector(prior, prefix + "stiffness_prior", scenario.robot.dof, 1.0, 1e12)
    else:
        f.choice(prior, prefix + "stiffness_prior", tuple(NAMED_PRIORS))
    return PoseSetOptions(
        pool=f.integer(table.get("pool", d.pool), prefix + "pool", 5, 2000),
        tension_N=f.number(table.get("tension_N", d.tension_N), prefix + "tension_N", low, high),
        threshold=threshold,
        min_height_m=f.number(table.get("min_height_m", d.min_height_m), prefix + "min_height_m", 0.0, 3.0),
        box_m=box,
        wrist_jitter_deg=f.number(table.get("wrist_jitter_deg", d.wrist_jitter_deg), prefix + "wrist_jitter_deg",
                                  0.0, 180.0),
        criterion=f.choice(table.get("criterion", d.criterion), prefix + "criterion", DESIGN_CRITERIA),
        design_pool=f.choice(table.get("design_pool", d.design_pool), prefix + "design_pool", DESIGN_POOLS),
        stiffness_prior=prior,
    )  # fmt: skip


def parse_campaign(data: dict, source: Path | str | None = None) -> Campaign:
    """Validate a scenario mapping with a ``[campaign]`` table and build a :class:`Campaign`."""
    scenario = parse_scenario(data, source)
    f = Fields(source)
    table = data.get("campaign")
    if not isinstance(table, dict):
        raise f.error("campaign", "is required for a sweep: a table with trials and [campaign.axes]")
    f.table(table, "campaign", CAMPAIGN_KEYS)
    if "trials" not in table:
        raise f.error("campaign.trials", "is required (trials per cell)")
    trials = f.integer(table["trials"], "campaign.trials", 1, MAX_TRIALS)
    seed = f.seed(table.get("seed", scenario.seed), "campaign.seed")
    paired = f.boolean(table.get("paired", True), "campaign.paired")
    axes_table = table.get("axes")
    if not isinstance(axes_table, dict) or not axes_table:
        raise f.error("campaign.axes", f"must be a non-empty table of axes; valid axes: {', '.join(AXES)}")
    unknown = sorted(set(axes_table) - set(AXES))
    if unknown:
        raise f.error(f"campaign.axes.{unknown[0]}", f"unknown axis; valid axes: {', '.join(AXES)}")
    axes = tuple((a, _axis_values(a, axes_table[a], scenario, f)) for a in AXES if a in axes_table)
    options = _pose_set_options(table.get("pose_sets", {}), scenario, f)
    description = f.string(table.get("description", ""), "campaign.description")
    campaign = Campaign(scenario, seed, trials, paired, axes, options, description,
                        Path(source) if source else None)  # fmt: skip
    for cell in campaign.cells():
        if cell.pose_set == "scenario" and cell.n_tests > scenario.n_tests:
            raise f.error(
                "campaign.axes.n_tests",
                f"{cell.n_tests} tests exceed the base scenario's {scenario.n_tests} (pose_set 'scenario' "
                "uses the scenario's own tests)",
            )
        repeats = scenario.scanner.repeats
        if cell.method == "gls_floor" and repeats * cell.n_tests < (need := _min_floor_samples()):
            raise f.error(
                "campaign.axes.n_tests",
                f"{cell.n_tests} tests with [scanner] repeats = {repeats} give {cell.n_tests * repeats} "
                f"repeat-scan samples; method 'gls_floor' needs at least {need} for its 6 x 6 noise-floor "
                f"covariance: valid: n_tests >= {-(-need // repeats)} with it, more repeats, or method 'fgls'",
            )
        if cell.pose_set == "kappa_regions" and cell.n_tests > options.pool:
            raise f.error(
                "campaign.axes.n_tests",
                f"{cell.n_tests} tests exceed campaign.pose_sets.pool = {options.pool} ({cell.pose_set} "
                "draws its tests from that pool)",
            )
    return campaign


def _min_floor_samples() -> int:
    from ..researcher.measure import MIN_FLOOR_SAMPLES  # here: the researcher side loads only for it

    return MIN_FLOOR_SAMPLES


def load_campaign(path: str | Path) -> Campaign:
    """Read and validate a campaign (a scenario TOML file with a ``[campaign]`` table)."""
    return parse_campaign(read_scenario_file(path, "campaign"), Path(path))
