"""Monte Carlo on fixed physics: solve and ray-cast each test once, redraw the noise per trial.

The equilibrium and the ray-cast geometry of a test depend on the pose and the load only, not
on the noise, so :func:`prepare` computes them once; :func:`trial` then draws the scanner and
force-sensor noise for one seed and runs the researcher's own code
(:func:`vtestbed.researcher.measure.measure_arrays`, :func:`vtestbed.researcher.identify.identify`)
on the result. The researcher's kinematic model is built once per prepared scenario, never per
trial.

A trial with seed ``s`` consumes the random numbers in the same order as
:func:`vtestbed.experiment.simulate` with ``seed = s``, so it reproduces that dataset exactly.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from ..dataset import DatasetSetup, TestRecord, scanner_pose_as_recorded
from ..experiment import dataset_setup, test_id
from ..researcher.identify import IdentificationResult
from ..researcher.kinematics import ArmKinematics
from ..researcher.measure import TestMeasurement, identify_measurements, measure_arrays
from ..scenario import Scenario
from ..world.physics import draw_readings, run_test_physics, test_rng
from ..world.rig import Rig
from ..world.scan_noise import ScanGeometry, ScanNoise
from ..world.sensors import ForceTorqueSensor
from ..world.truth import load_truth


@dataclass(frozen=True)
class PreparedTest:
    """The noise-free part of one test: equilibrium wrenches and ray-cast geometry."""

    test_id: str
    group: str
    index: int
    q: np.ndarray  # (n,) commanded DH [rad]
    scanner_pose: np.ndarray  # (4, 4)
    hits_unloaded: ScanGeometry
    hits_loaded: ScanGeometry
    wrench_unloaded: np.ndarray  # (6,) true sensor wrench
    wrench_loaded: np.ndarray  # (6,)
    displacement_true: np.ndarray  # (6,) block frame [m, rad]


@dataclass(frozen=True)
class PreparedScenario:
    """A scenario's tests with their physics done; trials only add noise and run the researcher."""

    scenario: Scenario
    setup: DatasetSetup
    tests: tuple[PreparedTest, ...]
    stiffness_true: np.ndarray  # (n,) N*m/rad: for the reports of a campaign, never for a trial

    def identification_tests(self) -> list[PreparedTest]:
        return [t for t in self.tests if t.group == "identification"]

    @cached_property
    def kinematics(self) -> ArmKinematics:
        """The researcher's Pinocchio model of the block, built on first use and then reused."""
        return ArmKinematics(self.scenario.robot, self.setup.block_in_flange)

    @cached_property
    def sensor(self) -> ForceTorqueSensor:
        """The scenario's force sensor (its noise and bias)."""
        fs = self.scenario.force_sensor
        return ForceTorqueSensor(self.scenario.lab.sensor, fs.noise_std, fs.bias)


def prepare(scenario: Scenario, include_validation: bool = False) -> PreparedScenario:
    """Solve every test's equilibrium and ray-cast both scans once (deterministic)."""
    lab = scenario.lab
    rig = Rig(scenario.robot, lab, truth=load_truth(scenario.robot_name), effects=scenario.effects)
    placement = scenario.scanner.placement
    jobs = [("identification", i, q, scenario.load) for i, q in enumerate(scenario.poses)]
    if include_validation:
        jobs += [
            ("validation", i, q, scenario.validation_load) for i, q in enumerate(scenario.validation_poses)
        ]
    tests = []
    for group, i, q, load in jobs:
        phys = run_test_physics(
            rig, q, load.hooks[i], load.anchors[i], load.tensions[i], scenario.scanner.distance, placement
        )
        tests.append(
            PreparedTest(
                test_id=test_id(group, i),
                group=group,
                index=i,
                q=np.asarray(q),
                scanner_pose=scanner_pose_as_recorded(phys.scanner.pose_world),
                hits_unloaded=phys.hits_unloaded,
                hits_loaded=phys.hits_loaded,
                wrench_unloaded=phys.unloaded.sensor_wrench,
                wrench_loaded=phys.loaded.sensor_wrench,
                displacement_true=phys.displacement_true,
            )
        )
    return PreparedScenario(scenario, dataset_setup(scenario, lab), tuple(tests), rig.truth.stiffness_true)


def measure_trial(
    prepared: PreparedScenario,
    seed: int,
    tests: list[PreparedTest] | None = None,
    noise: ScanNoise | None | str = "scenario",
    sensor: ForceTorqueSensor | None = None,
) -> list[TestMeasurement]:
    """Draw one trial's noise (seed ``seed``) and reduce each test as the researcher would.

    ``noise="scenario"`` uses the scenario's scanner noise; ``None`` is a perfect scanner.
    """
    if isinstance(noise, str):
        noise = prepared.scenario.scanner.noise_model
    sensor = sensor or prepared.sensor
    kin = prepared.kinematics
    out = []
    for t in tests if tests is not None else prepared.identification_tests():
        rng = test_rng(seed, t.group, t.index)
        cloud0, w0, cloud1, w1 = draw_readings(
            t.hits_unloaded,
            t.hits_loaded,
            t.wrench_unloaded,
            t.wrench_loaded,
            noise,
            sensor,
            rng,
            prepared.scenario.effects,
        )
        record = TestRecord(t.test_id, t.group, np.degrees(t.q), w0, w1, t.scanner_pose, Path(), Path())
        out.append(measure_arrays(record, cloud0, cloud1, prepared.setup, kin))
    return out


def trial(
    prepared: PreparedScenario,
    seed: int,
    n_tests: int | None = None,
    method: str | None = None,
    noise: ScanNoise | None | str = "scenario",
    sensor: ForceTorqueSensor | None = None,
) -> IdentificationResult:
    """One virtual experiment with the first ``n_tests`` identification tests."""
    tests = prepared.identification_tests()[:n_tests]
    measurements = measure_trial(prepared, seed, tests, noise, sensor)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify_measurements(
            measurements, method or prepared.scenario.method, prepared.scenario.robot.joint_names
        )
