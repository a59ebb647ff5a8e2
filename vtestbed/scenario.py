"""Scenario files (TOML): what to simulate, validated with errors that name the field.

A scenario says which robot, which test poses (DH or KUKA controller angles, in degrees), which
wire hook, ring and tension per test, the lab around the robot (``[lab]``; defaults: the paper's
lab scaled to the robot, :func:`vtestbed.robot_lab.lab_for_robot`),
where the scanner stands and how noisy it is, how noisy the force sensor is, which estimator to
use and the seed. A parsed :class:`Scenario` owns its robot description, its lab and its noise
models, each built once. See ``scenarios/*.toml`` and the README's field table.

Units: SI in the object (rad, m, N); degrees in the file where the key says ``_deg``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .dataset_repeats import REPEATS_RANGE
from .errors import OutOfRangeError, ScenarioError, VtestbedError
from .files import read_toml
from .lab import DEFAULT_SCANNER_DISTANCE_M, LabSetup, parse_lab
from .robots import DEFAULT_ROBOT, RobotDescription, available_robots, load_robot
from .schema import Fields
from .world.effects import parse_effects
from .world.scan_noise import NOISE_PARAM_RANGES, ScanNoise
from .world.sensors import DEFAULT_NOISE_STD, NO_BIAS

CONVENTIONS = ("dh", "controller")
# "wls" needs a stated displacement covariance, which a scenario has not; "fgls_pooled": docs/uncertainty.md
METHODS = ("ols", "fgls", "fgls_pooled", "gls_floor")  # "gls_floor" needs [scanner] repeats >= 2
DEFAULT_METHOD = "fgls"
# what each displacement is measured against (vtestbed.researcher.scan_mean.REFERENCES, written out
# so that a scenario does not load the researcher side; a test keeps them equal): "mean" needs repeats
REFERENCES = ("scan", "mean")
DEFAULT_REFERENCE = "scan"  # the paper's: the test's own unloaded scan
DEFAULT_HOOK, DEFAULT_ANCHOR = "hook_x", "ring_5"
POINT_SPACING_RANGE_M = (2e-5, 5e-3)
FT_NOISE_STD_MAX, FT_BIAS_MAX = 50.0, 100.0  # N (N*m)
TOP_LEVEL = (
    "name",
    "description",
    "robot",
    "seed",
    "lab",
    "poses",
    "load",
    "scanner",
    "force_sensor",
    "identification",
    "validation",
    "campaign",
    "world",
    "target",
)
TARGET_KEYS = ("mesh", "units", "density_kg_m3", "mass_kg")


@dataclass(frozen=True)
class LoadPlan:
    """Per test: block hook, table ring and wire tension [N]."""

    hooks: tuple[str, ...]
    anchors: tuple[str, ...]
    tensions: tuple[float, ...]


@dataclass(frozen=True)
class ScannerPlan:
    """Where the scanner stands, how it errs, and how often the unloaded block is scanned again.

    ``noise_params`` are the file's overrides of :class:`ScanNoise`; ``noise_model`` is the
    model they give (None for a perfect scanner, ``noise = false``). ``repeats`` is the number
    of further scans of the unloaded block per test (``repeats.csv`` in the dataset), from which
    the researcher estimates a model-free noise floor (:mod:`vtestbed.researcher.noise_floor`);
    ``loaded_repeats`` the number of further scans of the loaded block (``loaded_repeats.csv``),
    which the mean-scan displacements average (:mod:`vtestbed.researcher.scan_mean`).
    """

    distance: float = DEFAULT_SCANNER_DISTANCE_M  # m, scanner to block centre
    noise: bool = True
    noise_params: dict = field(default_factory=dict)
    spacing: float | None = None  # m, point spacing on the block; None: the scanner's default
    noise_model: ScanNoise | None = field(default_factory=ScanNoise)
    repeats: int = 0  # repeat scans of the unloaded block per test, REPEATS_RANGE
    loaded_repeats: int = 0  # repeat scans of the loaded block per test, REPEATS_RANGE

    @property
    def placement(self) -> dict:
        """Keyword arguments of ``Scanner.place`` that the scenario sets."""
        return {} if self.spacing is None else {"point_spacing_m": self.spacing}


@dataclass(frozen=True)
class ForceSensorPlan:
    """The force sensor's noise std and bias (Fx..Tz) [N, N*m]."""

    noise_std: tuple[float, ...] = DEFAULT_NOISE_STD
    bias: tuple[float, ...] = NO_BIAS


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    robot: RobotDescription
    seed: int
    poses: np.ndarray  # (n_tests, n) DH angles [rad]
    load: LoadPlan
    scanner: ScannerPlan
    force_sensor: ForceSensorPlan
    method: str
    validation_poses: np.ndarray  # (n_val, n) DH [rad], may be empty
    validation_load: LoadPlan
    lab: LabSetup = field(default_factory=LabSetup)
    effects: tuple = ()  # hidden world effects (vtestbed.world.effects): truth, never in the dataset
    reference: str = DEFAULT_REFERENCE  # identification.reference: the unloaded scan(s) of a displacement
    source: Path | None = None
    raw: dict = field(default_factory=dict, repr=False)

    @property
    def robot_name(self) -> str:
        return self.robot.name

    @property
    def n_tests(self) -> int:
        return int(self.poses.shape[0])

    @property
    def fingerprint(self) -> str:
        """A hash of everything that shapes the simulated data (for resuming safely)."""
        text = json.dumps(self.raw, sort_keys=True, default=str)
        if self.lab.block.mesh is not None:  # the mesh file's content, not only its name
            text += self.lab.block.mesh.sha256
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _poses(table, robot: RobotDescription, f: Fields, prefix: str, lab: LabSetup) -> np.ndarray:
    f.table(table, prefix.rstrip("."), ("convention", "angles_deg"))
    convention = f.choice(table.get("convention", "dh"), f"{prefix}convention", CONVENTIONS)
    rows = table.get("angles_deg")
    if not isinstance(rows, list) or not rows:
        raise f.error(f"{prefix}angles_deg", "must be a non-empty list of poses (lists of angles in deg)")
    poses = []
    for i, row in enumerate(rows):
        angles = np.radians(f.vector(row, f"{prefix}angles_deg[{i}]", robot.dof, -720.0, 720.0))
        q = robot.controller_to_dh(angles) if convention == "controller" else angles
        name = f"{prefix}angles_deg[{i}]"
        try:
            robot.check_pose(q, field=name)
            # refused here, not later by identify: a singular pose gives no usable test
            robot.check_not_singular(q, lab.block_in_flange[:3, 3], field=name)
        except VtestbedError as exc:
            raise f.error(name, str(exc).removeprefix(f"{name}: ")) from None
        poses.append(q)
    return np.array(poses)


def pose_field(group: str, index: int) -> str:
    """The scenario-file field of a test's pose: ``poses.angles_deg[i]`` (identification) or
    ``validation.angles_deg[i]``, as errors and warnings name it."""
    return f"{'poses' if group == 'identification' else 'validation'}.angles_deg[{index}]"


def load_field(group: str, index: int, key: str, raw: dict) -> str:
    """The scenario-file field of a test's ``hook``, ``anchor`` or ``tension_N`` (``raw``: the
    scenario's mapping): ``load.tension_N[i]`` when the file gives a list (one value per test, or
    one for all), ``load.tension_N`` for a single value or the default; ``validation.`` for a
    validation test."""
    table = "load" if group == "identification" else "validation"
    value = raw.get(table, {}).get(key) if isinstance(raw.get(table), dict) else None
    return f"{table}.{key}[{index % len(value)}]" if isinstance(value, list) and value else f"{table}.{key}"


def _per_test(value, count: int, f: Fields, name: str, check) -> tuple:
    """One value per test: a single value for all, or a list whose length is 1 or ``count``."""
    values = value if isinstance(value, list) else [value]
    if not values:
        raise f.error(name, "must not be empty")
    if len(values) not in (1, count):
        raise f.error(name, f"has {len(values)} values for {count} tests: give one value, or one per test")
    return tuple(check(values[i % len(values)], f"{name}[{i % len(values)}]") for i in range(count))


def _load_plan(table, count: int, lab: LabSetup, f: Fields, prefix: str) -> LoadPlan:
    f.table(table, prefix.rstrip("."), ("hook", "anchor", "tension_N"))

    def tension(value, name):  # the lab's one rule, whose message names the limit that binds
        try:
            return lab.check_tension(value, name)
        except OutOfRangeError as exc:
            raise f.error(name, str(exc).removeprefix(name).lstrip()) from None

    return LoadPlan(
        hooks=_per_test(table.get("hook", DEFAULT_HOOK), count, f, f"{prefix}hook",
                        lambda v, n: f.choice(v, n, sorted(lab.block.hooks))),
        anchors=_per_test(table.get("anchor", DEFAULT_ANCHOR), count, f, f"{prefix}anchor",
                          lambda v, n: f.choice(v, n, sorted(lab.table.anchors))),
        tensions=_per_test(table.get("tension_N", lab.default_tension_N), count, f, f"{prefix}tension_N",
                           tension),
    )  # fmt: skip


def _scanner_plan(table, lab: LabSetup, f: Fields) -> ScannerPlan:
    f.table(
        table, "scanner", ("distance_m", "noise", "noise_params", "spacing_m", "repeats", "loaded_repeats")
    )
    noise = f.boolean(table.get("noise", True), "scanner.noise")
    params = f.table(
        table.get("noise_params", {}), "scanner.noise_params", tuple(ScanNoise.__dataclass_fields__)
    )
    for key, value in params.items():  # each parameter's own range (stated once, in scan_noise)
        f.number(value, f"scanner.noise_params.{key}", *NOISE_PARAM_RANGES[key])
    try:
        model = ScanNoise(**params)
    except OutOfRangeError as exc:
        raise f.error("scanner.noise_params", str(exc)) from None
    spacing = table.get("spacing_m")
    return ScannerPlan(
        distance=_scanner_distance(table, lab, f),
        noise=noise,
        noise_params=dict(params),
        spacing=None if spacing is None else f.number(spacing, "scanner.spacing_m", *POINT_SPACING_RANGE_M),
        noise_model=model if noise else None,
        repeats=f.integer(table.get("repeats", 0), "scanner.repeats", *REPEATS_RANGE),
        loaded_repeats=f.integer(table.get("loaded_repeats", 0), "scanner.loaded_repeats", *REPEATS_RANGE),
    )  # fmt: skip


def _scanner_distance(table, lab: LabSetup, f: Fields) -> float:
    """``[scanner] distance_m`` (default: the lab's stand-off), checked by the lab's one rule
    (:meth:`LabSetup.check_scanner_distance`: every corner of the block in the scanner's measuring
    depth), so that a stand-off at which no test can scan the block is refused here, not at the
    first test's scan; a block that no stand-off can scan is refused by its own field."""
    name = "scanner.distance_m"
    value = table.get("distance_m", lab.scanner_distance)
    try:
        return lab.check_scanner_distance(value, name)
    except OutOfRangeError as exc:
        if lab.scanner_distance_range_m() is None:
            raise f.error("lab.block.edge_m" if lab.block.mesh is None else "target.mesh", str(exc)) from None
        default = "" if "distance_m" in table else " (the lab's default stand-off)"
        message = str(exc).removeprefix(name).lstrip()
        raise f.error(name, message.replace(" m is outside", f" m{default} is outside", 1)) from None


def _force_sensor_plan(table, f: Fields) -> ForceSensorPlan:
    f.table(table, "force_sensor", ("noise_std", "bias"))
    return ForceSensorPlan(
        noise_std=f.vector(table.get("noise_std", list(DEFAULT_NOISE_STD)), "force_sensor.noise_std", 6, 0.0,
                           FT_NOISE_STD_MAX),
        bias=f.vector(table.get("bias", list(NO_BIAS)), "force_sensor.bias", 6, -FT_BIAS_MAX, FT_BIAS_MAX),
    )  # fmt: skip


def _target(table, lab: LabSetup, robot: RobotDescription, f: Fields) -> LabSetup:
    """The lab with the ``[target]`` mesh as its block (:mod:`vtestbed.target_mesh`, docs/targets.md).

    ``mesh`` is relative to the scenario file's folder; ``units`` "mm" (default) or "m"; the mass
    from ``density_kg_m3`` (default: the lab block's) or ``mass_kg``. The lab is checked again
    (the hooks moved onto the mesh).
    """
    from .robot_lab import check_lab
    from .target_mesh import load_mesh_target

    f.table(table, "target", TARGET_KEYS)
    if "mesh" not in table:
        raise f.error("target.mesh", "is required (an STL, OBJ or PLY file, relative to the scenario file)")
    path = Path(f.string(table["mesh"], "target.mesh", allow_empty=False))
    if not path.is_absolute() and f.source is not None:
        path = Path(f.source).parent / path
    units = f.string(table.get("units", "mm"), "target.units")
    density = table.get("density_kg_m3", None if "mass_kg" in table else lab.block.density)
    target = load_mesh_target(path, units, density, table.get("mass_kg"), fields=f)
    block = replace(lab.block, edge=target.edge, density=target.density, mesh=target)
    return check_lab(replace(lab, block=block), robot, f)


def parse_scenario(data: dict, source: Path | str | None = None) -> Scenario:
    """Validate a scenario mapping (as read from TOML) and build a :class:`Scenario`."""
    f = Fields(source)
    f.table(data, "", TOP_LEVEL)
    for key in ("name", "poses"):
        if key not in data:
            raise f.error(key, "is required")
    name = f.string(data["name"], "name", allow_empty=False)
    robot_name = data.get("robot", DEFAULT_ROBOT)
    if not isinstance(robot_name, str) or not robot_name:
        raise f.error("robot", f"must be the name of a robot vtestbed describes ({', '.join(available_robots())}), "
                               f"got {robot_name!r}")  # fmt: skip
    try:
        robot = load_robot(robot_name)
    except VtestbedError as exc:
        raise f.error("robot", str(exc)) from None
    lab = parse_lab(data.get("lab", {}), f, robot)
    if "target" in data:
        if "edge_m" in data.get("lab", {}).get("block", {}):
            raise f.error(
                "lab.block.edge_m", "must not be given with [target]: the mesh sets the block's size"
            )
        lab = _target(data["target"], lab, robot, f)
    seed = f.seed(data.get("seed", 0), "seed")
    poses = _poses(data["poses"], robot, f, "poses.", lab)
    load = _load_plan(data.get("load", {}), len(poses), lab, f, "load.")
    scanner = _scanner_plan(data.get("scanner", {}), lab, f)
    force = _force_sensor_plan(data.get("force_sensor", {}), f)
    world = f.table(data.get("world", {}), "world", ("effects",))
    effects = parse_effects(world.get("effects", []), f)
    ident = f.table(data.get("identification", {}), "identification", ("method", "reference"))
    method = f.choice(ident.get("method", DEFAULT_METHOD), "identification.method", METHODS)
    reference = f.choice(ident.get("reference", DEFAULT_REFERENCE), "identification.reference", REFERENCES)
    val = f.table(
        data.get("validation", {}), "validation", ("convention", "angles_deg", "hook", "anchor", "tension_N")
    )
    if val:
        val_poses = _poses(
            {k: val[k] for k in ("convention", "angles_deg") if k in val}, robot, f, "validation.", lab
        )
        load_part = {k: val[k] for k in ("hook", "anchor", "tension_N") if k in val}
        val_load = _load_plan(load_part, len(val_poses), lab, f, "validation.")
    else:
        val_poses, val_load = np.zeros((0, robot.dof)), LoadPlan((), (), ())
    if method == "gls_floor":
        _check_floor_samples(scanner.repeats, len(poses) + len(val_poses), f)
    if reference == "mean" and scanner.repeats < 1:
        raise f.error(
            "identification.reference",
            "'mean' measures each displacement against the mean of the test's unloaded scans and needs "
            f"[scanner] repeats >= 1 (got {scanner.repeats}); 'scan' (the paper's) needs none",
        )
    return Scenario(
        name=name,
        description=str(data.get("description", "")),
        robot=robot,
        seed=seed,
        poses=poses,
        load=load,
        scanner=scanner,
        force_sensor=force,
        method=method,
        validation_poses=val_poses,
        validation_load=val_load,
        lab=lab,
        effects=effects,
        reference=reference,
        source=Path(source) if source else None,
        raw=data,
    )


def _check_floor_samples(repeats: int, n_tests: int, f: Fields) -> None:
    """``gls_floor`` needs repeat scans, at least 2 per test, and a noise floor of at least
    ``MIN_FLOOR_SAMPLES`` repeat-scan samples (``repeats`` per test, every test): refused here,
    not after the whole simulation."""
    if repeats < 2:
        raise f.error(
            "identification.method",
            f"'gls_floor' weights with the repeat-scan noise floor and needs [scanner] repeats >= 2 "
            f"(got {repeats}); 'fgls' needs none",
        )
    from .researcher.measure import MIN_FLOOR_SAMPLES  # here: the researcher side loads only for it

    if repeats * n_tests < MIN_FLOOR_SAMPLES:
        least = -(-MIN_FLOOR_SAMPLES // n_tests)
        raise f.error(
            "scanner.repeats",
            f"= {repeats} gives {repeats * n_tests} repeat-scan samples over {n_tests} test"
            f"{'s' * (n_tests != 1)}; identification.method 'gls_floor' needs at least {MIN_FLOOR_SAMPLES} "
            f"for its 6 x 6 noise-floor covariance: valid: repeats >= {least}, or method 'fgls'",
        )


def read_scenario_file(path: str | Path, what: str = "scenario") -> dict:
    """The mapping in a scenario (or campaign) TOML file, or a :class:`ScenarioError` naming it."""
    return read_toml(path, f"{what} file", ScenarioError)


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file."""
    return parse_scenario(read_scenario_file(path), Path(path))
