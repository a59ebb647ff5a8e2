"""The lab around the robot: force sensor, target block, table with rings, and the wire.

Values are frozen dataclasses in SI units whose defaults follow the paper's setup (ATI
SI-330-30 sensor, a steel wire to a ring on a table). The block frame ``B`` is the frame the
scanner pipeline measures: its origin is the block corner where the three scanned faces meet
and its axes are the outward normals of those faces (parallel to the flange axes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import UnknownNameError
from .transforms import homogeneous


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


@dataclass(frozen=True)
class BlockSpec:
    """The aluminium target block and its wire hooks."""

    edge: float = 0.08  # m, a cube
    density: float = 2700.0  # kg/m^3
    standoff: float = 0.02  # m, stem between the sensor's tool face and the block
    stem_mass: float = 0.15  # kg
    # Hook points in the block frame B [m]; B's origin is the scanned corner, the block
    # occupies [-edge, 0]^3. Hooks sit on the hidden faces, off the sensor axis.
    hooks: dict[str, tuple[float, float, float]] = field(
        default_factory=lambda: {
            "hook_x": (-0.08, -0.04, -0.04),  # centre of the -x face
            "hook_y": (-0.04, -0.08, -0.04),  # centre of the -y face
            "hook_edge": (-0.08, -0.08, -0.04),  # middle of the -x/-y edge
        }
    )

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
class LabSetup:
    """Everything bolted around the robot."""

    sensor: ForceSensorSpec = field(default_factory=ForceSensorSpec)
    block: BlockSpec = field(default_factory=BlockSpec)
    table: TableSpec = field(default_factory=TableSpec)
    wire: WireSpec = field(default_factory=WireSpec)

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
