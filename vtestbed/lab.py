"""The lab around the robot: force sensor, target block, table with rings, wire and scanner.

Values are frozen dataclasses in SI units whose defaults follow the paper's setup (ATI
SI-330-30 sensor, a steel wire to a ring on a table, a VTOP 200B scanner). The block frame ``B``
is the frame the scanner pipeline measures: its origin is the block corner where the three
scanned faces meet and its axes are the outward normals of those faces (parallel to the flange
axes).

Both sides read this module: the world builds its scene from a :class:`LabSetup`, the
researcher knows the same layout as nominal data. It is also the one home of the lab's defaults
and rules: the wire tension a test may use (:meth:`LabSetup.check_tension`), the measuring range
of the force sensor (:meth:`ForceSensorSpec.check`) and the scanner's stand-off
(:data:`DEFAULT_SCANNER_DISTANCE_M`, :attr:`ScannerSpec.working_distance_m`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

from .errors import OutOfRangeError, SensorOverloadError, UnknownNameError
from .transforms import homogeneous

WRENCH_AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
WRENCH_UNITS = ("N", "N", "N", "N*m", "N*m", "N*m")
DEFAULT_TENSION_N = 200.0  # the paper's wire load
MIN_TENSION_N = 1.0  # below this a steel wire is not reliably taut
DEFAULT_SCANNER_DISTANCE_M = 0.6  # scanner optical centre to block centre


@dataclass(frozen=True)
class ForceSensorSpec:
    """A 6-axis force/torque sensor between the flange and the block (ATI SI-330-30)."""

    name: str = "ATI Delta SI-330-30"
    # Measuring range |Fx|, |Fy|, |Fz| [N], |Tx|, |Ty|, |Tz| [N*m] (paper Table 4).
    wrench_range: tuple[float, ...] = (330.0, 330.0, 990.0, 30.0, 30.0, 30.0)
    diameter: float = 0.0945  # m
    height: float = 0.0333  # m
    adapter_thickness: float = 0.010  # m, flange-to-sensor mounting plate
    mass_mount_side: float = 0.45  # kg, belongs to the flange side
    mass_tool_side: float = 0.46  # kg, hangs below the measurement

    @property
    def origin_in_flange(self) -> np.ndarray:
        """Measurement origin: centre of the tool-side face, on the flange z axis [m]."""
        return np.array([0.0, 0.0, self.adapter_thickness + self.height])

    @property
    def max_force(self) -> float:
        """Largest force [N] the sensor measures on any axis."""
        return max(self.wrench_range[:3])

    def check(self, wrench, field_name: str = "wrench") -> np.ndarray:
        """Return ``wrench`` (6,) [N, N*m] or raise :class:`SensorOverloadError` naming the axis."""
        wrench = np.asarray(wrench, dtype=float)
        if wrench.shape != (6,) or not np.all(np.isfinite(wrench)):
            raise SensorOverloadError(f"{field_name} must be 6 finite numbers (Fx..Tz), got {wrench!r}")
        for axis, unit, value, limit in zip(WRENCH_AXES, WRENCH_UNITS, wrench, self.wrench_range):
            if not abs(value) <= limit:  # a NaN limit refuses, never silently accepts
                raise SensorOverloadError(
                    f"{field_name}: {axis} = {value:.2f} {unit} is outside the measuring range "
                    f"[-{limit:g}, {limit:g}] {unit} of the {self.name}"
                )
        return wrench


@dataclass(frozen=True)
class BlockSpec:
    """The aluminium target block and its wire hooks."""

    edge: float = 0.08  # m, a cube
    density: float = 2700.0  # kg/m^3
    standoff: float = 0.02  # m, stem between the sensor's tool face and the block
    stem_mass: float = 0.15  # kg

    @property
    def hooks(self) -> dict[str, tuple[float, float, float]]:
        """Hook points in the block frame B [m]. B's origin is the scanned corner and the block
        occupies [-edge, 0]^3; the hooks sit on the hidden faces, off the sensor axis."""
        e, h = -self.edge, -self.edge / 2
        return {
            "hook_x": (e, h, h),  # centre of the -x face
            "hook_y": (h, e, h),  # centre of the -y face
            "hook_edge": (e, e, h),  # middle of the -x/-y edge
        }

    @property
    def mass(self) -> float:
        return self.density * self.edge**3

    def hook(self, name: str) -> np.ndarray:
        if name not in self.hooks:
            raise UnknownNameError("hook", name, self.hooks)
        return np.array(self.hooks[name], dtype=float)


@dataclass(frozen=True)
class TableSpec:
    """A table in front of the robot with rings (wire anchors) screwed to its top."""

    center: tuple[float, float] = (1.6, 0.0)  # m, in the robot base frame
    size: tuple[float, float] = (1.4, 1.8)  # m
    height: float = 0.5  # m, top surface
    ring_x: tuple[float, ...] = (1.1, 1.6, 2.1)
    ring_y: tuple[float, ...] = (-0.7, 0.0, 0.7)

    @property
    def anchors(self) -> dict[str, np.ndarray]:
        """Ring anchor points ``ring_1``..``ring_9`` (row-major in x, then y) [m]."""
        names = {}
        for i, x in enumerate(self.ring_x):
            for j, y in enumerate(self.ring_y):
                names[f"ring_{i * len(self.ring_y) + j + 1}"] = np.array([x, y, self.height])
        return names

    def anchor(self, name: str) -> np.ndarray:
        anchors = self.anchors
        if name not in anchors:
            raise UnknownNameError("anchor", name, anchors)
        return anchors[name]


@dataclass(frozen=True)
class WireSpec:
    """A steel wire: it pulls with EA/L0 per metre of stretch and never pushes."""

    axial_rigidity: float = 6.28e5  # N, E*A of a 2 mm steel wire (200 GPa)
    diameter: float = 0.002  # m, for the scanner's view only
    damping: float = 200.0  # N*s/m, only for dynamic settling


@dataclass(frozen=True)
class ScannerSpec:
    """Datasheet of the scanner (paper Table 3, TECHLEGO VTOP 200B), SI units."""

    name: str = "TECHLEGO VTOP 200B"
    working_distance_m: tuple[float, float] = (0.100, 1.250)
    area_min_m: tuple[float, float] = (0.050, 0.038)  # smallest measuring area (width, height)
    area_max_m: tuple[float, float] = (0.450, 0.342)  # largest measuring area
    point_spacing_m: tuple[float, float] = (0.02e-3, 0.5e-3)
    resolution_px: tuple[int, int] = (2592, 1944)  # "5 million pixels, monochrome"
    accuracy_m: tuple[float, float] = (0.010e-3, 0.015e-3)  # the default noise model's source


@dataclass(frozen=True)
class LabSetup:
    """Everything bolted around the robot."""

    sensor: ForceSensorSpec = field(default_factory=ForceSensorSpec)
    block: BlockSpec = field(default_factory=BlockSpec)
    table: TableSpec = field(default_factory=TableSpec)
    wire: WireSpec = field(default_factory=WireSpec)
    scanner: ScannerSpec = field(default_factory=ScannerSpec)

    @property
    def tension_range_N(self) -> tuple[float, float]:
        """Wire tensions [N] a test may use: taut, and measurable by the force sensor."""
        return MIN_TENSION_N, self.sensor.max_force

    def check_tension(self, tension, field_name: str = "tension_N") -> float:
        """Return ``tension`` [N] or raise :class:`OutOfRangeError` naming the field and range."""
        low, high = self.tension_range_N
        if isinstance(tension, bool) or not isinstance(tension, int | float | np.floating | np.integer):
            raise OutOfRangeError(f"{field_name} must be a number in [{low:g}, {high:g}] N, got {tension!r}")
        if not low <= tension <= high:  # also refuses NaN
            raise OutOfRangeError(
                f"{field_name} = {tension:g} N is outside the valid range [{low:g}, {high:g}] N (taut, and "
                f"at most the {self.sensor.name}'s {high:g} N on any axis)"
            )
        return float(tension)

    @property
    def block_in_flange(self) -> np.ndarray:
        """(4, 4) pose of the block frame B in the flange frame (nominal geometry)."""
        e = self.block.edge
        top = self.sensor.origin_in_flange[2] + self.block.standoff + e
        return homogeneous(np.eye(3), [e / 2, e / 2, top])

    @property
    def sensor_in_flange(self) -> np.ndarray:
        """(4, 4) pose of the force sensor's measurement frame in the flange frame."""
        return homogeneous(np.eye(3), self.sensor.origin_in_flange)


PAPER_LAB = LabSetup()  # the paper's lab: the one default when no scenario gives a lab


# What a scenario's [lab] table may override: table -> key -> (dataclass field, length or None, low, high).
# Lengths: None for a number, an int for a fixed-length list, 0 for a list of any length >= 1.
LAB_FIELDS = {
    "table": {
        "center_m": ("center", 2, -10.0, 10.0),
        "size_m": ("size", 2, 0.1, 10.0),
        "height_m": ("height", None, 0.0, 3.0),
        "ring_x_m": ("ring_x", 0, -10.0, 10.0),
        "ring_y_m": ("ring_y", 0, -10.0, 10.0),
    },
    "block": {
        "edge_m": ("edge", None, 0.02, 0.3),
        "density_kg_m3": ("density", None, 100.0, 25000.0),
        "standoff_m": ("standoff", None, 0.0, 0.5),
    },
    "force_sensor": {"range_N_Nm": ("wrench_range", 6, 1e-3, 1e6)},
    "wire": {"axial_rigidity_N": ("axial_rigidity", None, 1e3, 1e9)},
}
_LAB_PARTS = {"table": "table", "block": "block", "force_sensor": "sensor", "wire": "wire"}


def parse_lab(table, fields) -> LabSetup:
    """The lab of a scenario: the paper's :class:`LabSetup` with the ``[lab]`` table's overrides.

    ``fields`` is a :class:`vtestbed.schema.Fields` bound to the scenario file; every key and
    range is in :data:`LAB_FIELDS`, and errors name the field (``lab.table.height_m``).
    """

    fields.table(table, "lab", tuple(LAB_FIELDS))
    lab = PAPER_LAB
    for part, keys in LAB_FIELDS.items():
        given = fields.table(table.get(part, {}), f"lab.{part}", tuple(keys))
        changes = {}
        for key, value in given.items():
            name, length, low, high = keys[key]
            where = f"lab.{part}.{key}"
            if length is None:
                changes[name] = fields.number(value, where, low, high)
            elif length == 0:
                if not isinstance(value, list) or not value:
                    raise fields.error(where, f"must be a non-empty list of numbers in [{low:g}, {high:g}]")
                changes[name] = fields.vector(value, where, len(value), low, high)
            else:
                changes[name] = fields.vector(value, where, length, low, high)
        if changes:
            attr = _LAB_PARTS[part]
            lab = dataclasses.replace(lab, **{attr: dataclasses.replace(getattr(lab, attr), **changes)})
    return lab
