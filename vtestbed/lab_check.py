"""The nominal lab's answer to "can this proposed test be run?", for ``discover``'s rounds.

A researcher proposing extra tests (:mod:`vtestbed.discovery`) can only ask a simulator of their
own *nominal* lab: the robot's description, the lab's layout, the scanner's stand-off and the
F/T sensor's range, without the scenario's hidden effects. A test passes when MuJoCo runs it
with every clearance kept, the true F/T load stays within :data:`SENSOR_MARGIN` of the range,
and the researcher's cloud fit accepts both noise-free scans with the faces spanning
:data:`SCAN_MARGIN` of the edge. Units: SI; the sensor's range in N and N*m.
"""

from __future__ import annotations

import numpy as np

from .errors import OutOfRangeError, VtestbedError
from .researcher import cloud
from .researcher.kinematics import ArmKinematics
from .scenario import Scenario
from .transforms import invert

__all__ = ["SCAN_MARGIN", "SENSOR_MARGIN", "LabCheck"]

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
