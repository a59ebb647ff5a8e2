"""The lab around the robot: force sensor, target block, table with rings, wire and scanner.

Values are frozen dataclasses in SI units whose defaults follow the paper's setup (ATI
SI-330-30 sensor, a steel wire to a ring on a table, a VTOP 200B scanner). The block frame ``B``
is the frame the scanner pipeline measures: its origin is the block corner where the three
scanned faces meet and its axes are the outward normals of those faces (parallel to the flange
axes).

Both sides read this module: the world builds its scene from a :class:`LabSetup`, the
researcher knows the same layout as nominal data. It is also the one home of the lab's defaults
and rules: the wire tension a test may use (:meth:`LabSetup.check_tension`, capped by the
robot's rated payload, the wire's safe working load and the sensor), the measuring range of the
force sensor (:meth:`ForceSensorSpec.check`), the scanner's stand-off
(:attr:`LabSetup.scanner_distance`, :attr:`ScannerSpec.working_distance_m`) and a lab that fits
the robot (:func:`vtestbed.robot_lab.lab_for_robot`, checked by
:func:`vtestbed.robot_lab.check_lab`; docs/lab.md); the stand-offs at which the whole block lies in
the scanner's measuring depth (:meth:`LabSetup.scanner_distance_range_m`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from .errors import OutOfRangeError, SensorOverloadError, UnknownNameError, check_range
from .transforms import homogeneous

WRENCH_AXES = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
WRENCH_UNITS = ("N", "N", "N", "N*m", "N*m", "N*m")
DEFAULT_TENSION_N = 200.0  # the paper's wire load
MIN_TENSION_N = 1.0  # below this a steel wire is not reliably taut
DEFAULT_SCANNER_DISTANCE_M = 0.6  # scanner optical centre to block centre, the paper's robot
DEFAULT_VIEW_DIRECTION = (1.0, 1.0, 1.0)  # block centre to scanner, block frame B: three faces alike
DEFAULT_SCAN_DEPTH_M = 0.3  # depth of the measuring volume about the stand-off (the datasheet gives none)
STANDOFF_STEP_M = 1e-3  # a stand-off range is stated in whole millimetres, rounded inward
G_N_PER_KG = 9.81  # a rated payload [kg] as the force [N] it may put on the flange
PAPER_RATED_PAYLOAD_KG = 60.0  # the KR60-3's (models/kuka_kr60_3/robot.toml; a test keeps them equal)
FLOOR_HEIGHT_M = 0.0  # the floor plane of the scene; nothing of the lab goes below it
# The KR60's joint 2 axis point at q = 0 (DH frame 2's origin) and reach (the largest flange distance
# from that axis, stretched: a2 + |(a3, d4)| + d6): every other robot's lab is scaled from them.
PAPER_SHOULDER_M = (0.35, 0.0, 0.815)
PAPER_REACH_M = 0.85 + math.hypot(0.145, 0.82) + 0.17


def _number_in_range(value, field_name: str, low: float, high: float, unit: str, why: str) -> float:
    """``value`` as a float, or :class:`OutOfRangeError` naming the field, the range and ``why``
    (:func:`~vtestbed.errors.check_range`, after refusing what is not a number)."""
    if isinstance(value, bool) or not isinstance(value, int | float | np.floating | np.integer):
        raise OutOfRangeError(f"{field_name} must be a number in [{low:g}, {high:g}] {unit}, got {value!r}")
    return check_range(field_name, value, low, high, unit, why)


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
    def mount_side_com_in_flange(self) -> np.ndarray:
        """Centre of mass [m] of the mount side (plate and upper half), on the flange z axis: the
        weight the flange carries but the sensor does not read."""
        return np.array([0.0, 0.0, (self.adapter_thickness + self.height / 2) / 2])

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

    def largest_load_scale(self, base, per_unit) -> float:
        """The largest ``t >= 0`` for which ``base + t * per_unit`` (6,) [N, N*m] is in the
        measuring range on every axis: the largest wire tension [N] the sensor can measure, given
        the wrench ``base`` without the wire and ``per_unit`` per newton of tension (the wrench is
        linear in the tension but for the arm's small deflection). 0 when ``base`` is out of range
        itself, inf when the wire does not load the sensor."""
        base, per_unit = np.asarray(base, dtype=float), np.asarray(per_unit, dtype=float)
        limits = np.asarray(self.wrench_range, dtype=float)
        if not np.all(np.abs(base) <= limits):
            return 0.0
        largest = math.inf
        for b, u, limit in zip(base, per_unit, limits):
            if u != 0.0:  # the axis reaches +limit or -limit, whichever it heads for
                largest = min(largest, ((limit if u > 0 else -limit) - b) / u)
        return float(largest)


@dataclass(frozen=True)
class BlockSpec:
    """The aluminium target block and its wire hooks."""

    edge: float = 0.08  # m, a cube
    density: float = 2700.0  # kg/m^3
    standoff: float = 0.02  # m, stem between the sensor's tool face and the block
    stem_mass: float = 0.15  # kg
    mesh: object = None  # a vtestbed.target_mesh.MeshTarget (edge: its largest extent), None: the box

    @property
    def hooks(self) -> dict[str, tuple[float, float, float]]:
        """Hook points in the block frame B [m]. B's origin is the scanned corner and the block
        occupies [-edge, 0]^3; the hooks sit on the hidden faces, off the sensor axis (a mesh
        target's: moved to the nearest point of its surface, docs/targets.md)."""
        if self.mesh is not None:
            return self.mesh.hooks
        e, h = -self.edge, -self.edge / 2
        return {
            "hook_x": (e, h, h),  # centre of the -x face
            "hook_y": (h, e, h),  # centre of the -y face
            "hook_edge": (e, e, h),  # middle of the -x/-y edge
        }

    @property
    def mass(self) -> float:
        return self.density * self.edge**3 if self.mesh is None else self.mesh.mass

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
    # A solid 2 mm wire of rope-wire grade 1770 N/mm^2 breaks at 1770 MPa * pi (1 mm)^2 = 5561 N;
    # a lifting safety factor of 5 leaves a safe working load of 1112 N.
    breaking_load_N: float = 1.77e9 * math.pi * 0.001**2
    safety_factor: float = 5.0

    @property
    def safe_working_load_N(self) -> float:
        """Largest tension [N] the wire may carry: breaking load over the safety factor."""
        return self.breaking_load_N / self.safety_factor


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
class BlockZone:
    """Where generated tests may put the block: above ``min_height`` [m] and inside ``box``
    ``(x_min, y_min, z_min, x_max, y_max, z_max)`` [m], robot base frame (the campaigns' pose sets)."""

    min_height: float = 0.8
    box: tuple[float, ...] = (0.3, -1.0, 0.0, 2.3, 1.0, 2.2)


@dataclass(frozen=True)
class LabSetup:
    """Everything bolted around the robot.

    ``rated_payload_kg``: the robot's (None: not known); ``tension_cap_N``: a stricter tension limit
    the lab sets itself (None: none); ``scanner_distance`` [m]: the scanner's default stand-off.
    """

    sensor: ForceSensorSpec = field(default_factory=ForceSensorSpec)
    block: BlockSpec = field(default_factory=BlockSpec)
    table: TableSpec = field(default_factory=TableSpec)
    wire: WireSpec = field(default_factory=WireSpec)
    scanner: ScannerSpec = field(default_factory=ScannerSpec)
    zone: BlockZone = field(default_factory=BlockZone)
    scanner_distance: float = DEFAULT_SCANNER_DISTANCE_M
    rated_payload_kg: float | None = PAPER_RATED_PAYLOAD_KG
    tension_cap_N: float | None = None

    @property
    def tension_limits_N(self) -> dict[str, float]:
        """What caps the wire tension [N], keyed by what sets it (the robot only when known)."""
        kg, g = self.rated_payload_kg, G_N_PER_KG
        robot = {} if kg is None else {f"the robot's rated payload ({kg:g} kg * {g:g} m/s^2)": kg * g}
        return {**robot, "the wire's safe working load": self.wire.safe_working_load_N,
                f"the {self.sensor.name}'s force range": self.sensor.max_force}  # fmt: skip

    @cached_property  # checked on every tighten; the setup is frozen
    def max_tension(self) -> tuple[float, str]:
        """The lab's largest wire tension [N] and what sets it: the lowest of
        :attr:`tension_limits_N`, or the lab's own ``tension_cap_N`` when given."""
        if self.tension_cap_N is not None:
            return self.tension_cap_N, "the lab's max_tension_N"
        source = min(self.tension_limits_N, key=self.tension_limits_N.get)
        return self.tension_limits_N[source], source

    @property
    def tension_range_N(self) -> tuple[float, float]:
        """Wire tensions [N] a test may use: taut, and at most :attr:`max_tension`."""
        return MIN_TENSION_N, self.max_tension[0]

    @property
    def default_tension_N(self) -> float:
        """The paper's 200 N, or half the lab's limit when lower (a design's doubled load fits)."""
        return min(DEFAULT_TENSION_N, self.max_tension[0] / 2)

    def check_tension(self, tension, field_name: str = "tension_N") -> float:
        """Return ``tension`` [N] or raise :class:`OutOfRangeError` naming the field, the range
        and which limit sets its top."""
        low, (high, source) = MIN_TENSION_N, self.max_tension
        why = f" (taut, and at most {high:g} N, set by {source})"
        return _number_in_range(tension, field_name, low, high, "N", why)

    def block_half_depth_m(self, view_direction=DEFAULT_VIEW_DIRECTION) -> float:
        """How far [m] the block's corners reach in front of and behind its centre along the
        scanner's optical axis, the scanner looking at the block centre from ``view_direction``
        (block frame B): ``edge / 2 * (|vx| + |vy| + |vz|)`` for the unit view; 0.0693 m for the
        paper's 80 mm block seen along (1, 1, 1). A mesh target counts as its bounding cube, as
        the scanner's placement does."""
        v = np.abs(np.asarray(view_direction, dtype=float))
        return self.block.edge / 2 * float(v.sum() / np.linalg.norm(v))

    def scanner_distance_range_m(
        self, view_direction=DEFAULT_VIEW_DIRECTION, depth_m: float = DEFAULT_SCAN_DEPTH_M
    ) -> tuple[float, float] | None:
        """The stand-offs [m] (optical centre to block centre) at which every corner of the block
        lies within the scanner's measuring depth, for any pose: the working distance less
        :meth:`block_half_depth_m` at each end, rounded inward to whole millimetres (0.17-1.18 m
        for the paper's block); None when the block is deeper than the measuring volume
        (``depth_m``, centred on the stand-off), so that no stand-off works. The field of view
        and the scanner's place above the floor depend on the pose and are checked when the
        scanner is placed (:meth:`vtestbed.world.scanner.Scanner.place`)."""
        (low, high), half = self.scanner.working_distance_m, self.block_half_depth_m(view_direction)
        if half > depth_m / 2:
            return None
        step = STANDOFF_STEP_M
        inward = math.ceil((low + half) / step - 1e-9), math.floor((high - half) / step + 1e-9)
        return round(inward[0] * step, 9), round(inward[1] * step, 9)

    def check_scanner_distance(
        self,
        distance,
        field_name: str = "distance_m",
        view_direction=DEFAULT_VIEW_DIRECTION,
        depth_m: float = DEFAULT_SCAN_DEPTH_M,
    ) -> float:
        """Return ``distance`` [m] or raise :class:`OutOfRangeError` naming the field, the range
        in which every corner of the block lies in the scanner's measuring depth
        (:meth:`scanner_distance_range_m`) and why; when no stand-off works, the largest block."""
        scanner, half = self.scanner, self.block_half_depth_m(view_direction)
        valid = self.scanner_distance_range_m(view_direction, depth_m)
        if valid is None:
            most = math.floor(self.block.edge * depth_m / 2 / half * 1e3) / 1e3
            raise OutOfRangeError(
                f"no {field_name} can scan a block of edge {self.block.edge:g} m: its corners lie {half:.4f} m "
                f"in front of and behind its centre as the scanner sees it, more than the {scanner.name}'s "
                f"measuring depth ({depth_m:g} m about the stand-off) holds; valid: a block edge of at most "
                f"{most:g} m"
            )
        (low, high), (wd_low, wd_high) = valid, scanner.working_distance_m
        why = (f": the block's corners must all lie within the {scanner.name}'s working distance "
               f"[{wd_low:g}, {wd_high:g}] m, and they lie up to {half:.4f} m in front of and behind the block "
               "centre, to which the stand-off is measured")  # fmt: skip
        return _number_in_range(distance, field_name, low, high, "m", why)

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


PAPER_LAB = LabSetup()  # the paper's lab, the KR60-3's (lab_for_robot gives it for the KR60)

# What a scenario's [lab] table may override: table -> key -> (dataclass field, length or None, low, high).
# Lengths: None for a number, an int for a fixed-length list, 0 for a list of any length >= 1.
LAB_FIELDS = {
    "table": {
        "center_m": ("center", 2, -10.0, 10.0),
        "size_m": ("size", 2, 0.1, 10.0),
        "height_m": ("height", None, FLOOR_HEIGHT_M, 3.0),
        "ring_x_m": ("ring_x", 0, -10.0, 10.0),
        "ring_y_m": ("ring_y", 0, -10.0, 10.0),
    },
    "block": {
        "edge_m": ("edge", None, 0.02, 0.3),
        "density_kg_m3": ("density", None, 100.0, 25000.0),
        "standoff_m": ("standoff", None, 0.0, 0.5),
    },
    "force_sensor": {"range_N_Nm": ("wrench_range", 6, 1e-3, 1e6)},
    "wire": {"axial_rigidity_N": ("axial_rigidity", None, 1e3, 1e9), "breaking_load_N": ("breaking_load_N", None, 10.0, 1e6)},
    "zone": {"min_height_m": ("min_height", None, FLOOR_HEIGHT_M, 3.0), "box_m": ("box", 6, -10.0, 10.0)},
}  # fmt: skip
_LAB_PARTS = {"table": "table", "block": "block", "force_sensor": "sensor", "wire": "wire", "zone": "zone"}


def parse_lab(table, fields, robot=None) -> LabSetup:
    """The lab of a scenario: the robot's lab (:func:`lab_for_robot`; the paper's without a
    robot) with the ``[lab]`` table's overrides, checked against the robot (:func:`check_lab`).

    ``fields`` is a :class:`vtestbed.schema.Fields` bound to the scenario file; every key and
    range is in :data:`LAB_FIELDS` (and ``max_tension_N``, at most the lowest of the robot's,
    the wire's and the sensor's limits); errors name the field (``lab.table.height_m``).
    """
    fields.table(table, "lab", (*LAB_FIELDS, "max_tension_N"))
    from .robot_lab import check_lab, lab_for_robot  # here: robot_lab builds on this module

    lab = PAPER_LAB if robot is None else lab_for_robot(robot)
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
    top, source = lab.max_tension
    if top < MIN_TENSION_N:  # every tension would be refused, and the refusal would name the test
        part = ("force_sensor.range_N_Nm" if source.endswith("force range")
                else "max_tension_N" if "max_tension_N" in source else "wire")  # fmt: skip
        raise fields.error(
            f"lab.{part}",
            f"leaves no wire tension to test with: {source} caps it at {top:g} N, below the "
            f"{MIN_TENSION_N:g} N a taut wire needs",
        )
    if "max_tension_N" in table:  # only stricter: the robot, wire and sensor limits still hold
        cap = fields.number(table["max_tension_N"], "lab.max_tension_N", MIN_TENSION_N, lab.max_tension[0])
        lab = dataclasses.replace(lab, tension_cap_N=cap)
    return lab if robot is None else check_lab(lab, robot, fields)
