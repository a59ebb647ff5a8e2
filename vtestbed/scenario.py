"""Scenario files (TOML): what to simulate, validated with errors that name the field.

A scenario says which robot, which test poses (DH or KUKA controller angles, in degrees),
which wire hook, ring and tension per test, where the scanner stands and how noisy it is, how
noisy the force sensor is, which estimator to use and the seed. See ``scenarios/*.toml``.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from .errors import OutOfRangeError, ScenarioError
from .lab import LabSetup
from .robots import RobotDescription, load_robot

CONVENTIONS = ("dh", "controller")
METHODS = ("ols", "wls", "fgls")
TOP_LEVEL = (
    "name",
    "description",
    "robot",
    "seed",
    "poses",
    "load",
    "scanner",
    "force_sensor",
    "identification",
    "validation",
    "campaign",
)


@dataclass(frozen=True)
class LoadPlan:
    """Per test: block hook, table ring and wire tension [N]."""

    hooks: tuple[str, ...]
    anchors: tuple[str, ...]
    tensions: tuple[float, ...]


@dataclass(frozen=True)
class ScannerPlan:
    distance: float = 0.6  # m, scanner to block
    noise: bool = True
    noise_params: dict = field(default_factory=dict)  # overrides of the scanner noise model
    spacing: float | None = None  # m, point spacing on the block; None: scanner default


@dataclass(frozen=True)
class ForceSensorPlan:
    noise_std: tuple[float, ...] = (0.0625, 0.0625, 0.0625, 0.0019, 0.0019, 0.0019)  # N, N*m
    bias: tuple[float, ...] = (0.0,) * 6


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    robot_name: str
    seed: int
    poses: np.ndarray  # (n_tests, n) DH angles [rad]
    load: LoadPlan
    scanner: ScannerPlan
    force_sensor: ForceSensorPlan
    method: str
    validation_poses: np.ndarray  # (n_val, n) DH [rad], may be empty
    validation_load: LoadPlan
    source: Path | None = None
    raw: dict = field(default_factory=dict, repr=False)

    @property
    def n_tests(self) -> int:
        return int(self.poses.shape[0])

    @property
    def fingerprint(self) -> str:
        """A hash of everything that shapes the simulated data (for resuming safely)."""
        text = json.dumps(self.raw, sort_keys=True, default=str)
        return hashlib.sha256(text.encode()).hexdigest()[:16]

    def robot(self) -> RobotDescription:
        return load_robot(self.robot_name)


def _err(source, field_name: str, message: str) -> ScenarioError:
    where = f"{source}: " if source else ""
    return ScenarioError(f"{where}{field_name}: {message}")


def _check_keys(table: dict, allowed, source, prefix: str) -> None:
    unknown = sorted(set(table) - set(allowed))
    if unknown:
        raise _err(source, f"{prefix}{unknown[0]}", f"unknown key; valid keys: {', '.join(allowed)}")


def _number(value, source, name: str, low: float, high: float) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _err(source, name, f"must be a number in [{low:g}, {high:g}], got {value!r}")
    if not (low <= value <= high):
        raise _err(source, name, f"= {value:g} is outside the valid range [{low:g}, {high:g}]")
    return float(value)


def _vector(value, source, name: str, length: int, low: float, high: float) -> tuple[float, ...]:
    if not isinstance(value, list) or len(value) != length:
        raise _err(source, name, f"must be a list of {length} numbers, got {value!r}")
    return tuple(_number(v, source, f"{name}[{i}]", low, high) for i, v in enumerate(value))


def _poses(table: dict, robot: RobotDescription, source, prefix: str) -> np.ndarray:
    _check_keys(table, ("convention", "angles_deg"), source, prefix)
    convention = table.get("convention", "dh")
    if convention not in CONVENTIONS:
        raise _err(source, f"{prefix}convention", f"{convention!r} is not one of {', '.join(CONVENTIONS)}")
    rows = table.get("angles_deg")
    if not isinstance(rows, list) or not rows:
        raise _err(
            source, f"{prefix}angles_deg", "must be a non-empty list of poses (lists of angles in deg)"
        )
    poses = []
    for i, row in enumerate(rows):
        angles = np.radians(_vector(row, source, f"{prefix}angles_deg[{i}]", robot.dof, -720.0, 720.0))
        q = robot.controller_to_dh(angles) if convention == "controller" else angles
        try:
            robot.check_pose(q, field=f"{prefix}angles_deg[{i}]")
        except Exception as exc:
            raise _err(source, f"{prefix}angles_deg[{i}]", str(exc)) from None
        poses.append(q)
    return np.array(poses)


def _per_test(value, count: int, source, name: str, check) -> tuple:
    values = value if isinstance(value, list) else [value]
    if not values:
        raise _err(source, name, "must not be empty")
    return tuple(check(values[i % len(values)], f"{name}[{i % len(values)}]") for i in range(count))


def _load_plan(table: dict, count: int, lab: LabSetup, source, prefix: str) -> LoadPlan:
    _check_keys(table, ("hook", "anchor", "tension_N"), source, prefix)
    max_force = max(lab.sensor.wrench_range[:3])

    def name_check(valid):
        def check(value, name):
            if value not in valid:
                raise _err(source, name, f"{value!r} is not one of {', '.join(sorted(valid))}")
            return value

        return check

    return LoadPlan(
        hooks=_per_test(
            table.get("hook", "hook_x"), count, source, f"{prefix}hook", name_check(lab.block.hooks)
        ),
        anchors=_per_test(
            table.get("anchor", "ring_5"), count, source, f"{prefix}anchor", name_check(lab.table.anchors)
        ),
        tensions=_per_test(
            table.get("tension_N", 200.0),
            count,
            source,
            f"{prefix}tension_N",
            lambda v, n: _number(v, source, n, 1.0, max_force),
        ),
    )


def parse_scenario(data: dict, source: Path | str | None = None) -> Scenario:
    """Validate a scenario mapping (as read from TOML) and build a :class:`Scenario`."""
    _check_keys(data, TOP_LEVEL, source, "")
    for key in ("name", "poses"):
        if key not in data:
            raise _err(source, key, "is required")
    try:
        robot = load_robot(data.get("robot", "kuka_kr60_3"))
    except Exception as exc:
        raise _err(source, "robot", str(exc)) from None
    lab = LabSetup()
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise _err(source, "seed", f"must be a non-negative integer, got {seed!r}")
    poses = _poses(data["poses"], robot, source, "poses.")
    load = _load_plan(data.get("load", {}), len(poses), lab, source, "load.")

    sc = data.get("scanner", {})
    _check_keys(sc, ("distance_m", "noise", "noise_params", "spacing_m"), source, "scanner.")
    noise = sc.get("noise", True)
    if not isinstance(noise, bool):
        raise _err(source, "scanner.noise", f"must be true or false, got {noise!r}")
    params = sc.get("noise_params", {})
    if not isinstance(params, dict):
        raise _err(source, "scanner.noise_params", "must be a table of noise-model parameters")
    _check_noise_params(params, source)
    scanner = ScannerPlan(
        distance=_number(sc.get("distance_m", 0.6), source, "scanner.distance_m", 0.1, 1.25),
        noise=noise,
        noise_params=dict(params),
        spacing=None
        if "spacing_m" not in sc
        else _number(sc["spacing_m"], source, "scanner.spacing_m", 2e-5, 5e-3),
    )
    fs = data.get("force_sensor", {})
    _check_keys(fs, ("noise_std", "bias"), source, "force_sensor.")
    force = ForceSensorPlan(
        noise_std=_vector(
            fs.get("noise_std", list(ForceSensorPlan.noise_std)),
            source,
            "force_sensor.noise_std",
            6,
            0.0,
            50.0,
        ),
        bias=_vector(fs.get("bias", [0.0] * 6), source, "force_sensor.bias", 6, -100.0, 100.0),
    )
    ident = data.get("identification", {})
    _check_keys(ident, ("method",), source, "identification.")
    method = ident.get("method", "fgls")
    if method not in METHODS:
        raise _err(source, "identification.method", f"{method!r} is not one of {', '.join(METHODS)}")
    val = data.get("validation", {})
    _check_keys(val, ("convention", "angles_deg", "hook", "anchor", "tension_N"), source, "validation.")
    if val:
        pose_part = {k: val[k] for k in ("convention", "angles_deg") if k in val}
        val_poses = _poses(pose_part, robot, source, "validation.")
        load_part = {k: val[k] for k in ("hook", "anchor", "tension_N") if k in val}
        val_load = _load_plan(load_part, len(val_poses), lab, source, "validation.")
    else:
        val_poses, val_load = np.zeros((0, robot.dof)), LoadPlan((), (), ())
    name = data["name"]
    if not isinstance(name, str) or not name:
        raise _err(source, "name", "must be a non-empty string")
    return Scenario(
        name=name,
        description=str(data.get("description", "")),
        robot_name=robot.name,
        seed=seed,
        poses=poses,
        load=load,
        scanner=scanner,
        force_sensor=force,
        method=method,
        validation_poses=val_poses,
        validation_load=val_load,
        source=Path(source) if source else None,
        raw=data,
    )


def _check_noise_params(params: dict, source) -> None:
    from .world.scanner import ScanNoise

    valid = tuple(ScanNoise.__dataclass_fields__)
    _check_keys(params, valid, source, "scanner.noise_params.")
    for key, value in params.items():
        _number(value, source, f"scanner.noise_params.{key}", 0.0, 90.0)
    try:
        ScanNoise(**params)
    except OutOfRangeError as exc:
        raise _err(source, "scanner.noise_params", str(exc)) from None


def read_toml(path: str | Path, what: str = "scenario") -> dict:
    """The mapping in a TOML file, or a :class:`ScenarioError` saying what is wrong with it."""
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{what} file {path} does not exist")
    try:
        return tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario TOML file."""
    return parse_scenario(read_toml(path), Path(path))


def scenario_summary(s: Scenario) -> dict:
    return {
        "name": s.name,
        "robot": s.robot_name,
        "seed": s.seed,
        "n_tests": s.n_tests,
        "method": s.method,
        "scanner": asdict(s.scanner),
        "force_sensor": asdict(s.force_sensor),
        "fingerprint": s.fingerprint,
    }
