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
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from ..dataset import DatasetSetup, TestRecord, scanner_pose_as_recorded
from ..errors import ScanError, SensorOverloadError
from ..experiment import dataset_setup, test_error, test_id
from ..researcher.identify import IdentificationResult
from ..researcher.kinematics import ArmKinematics
from ..researcher.measure import TestMeasurement, identify_measurements, measure_arrays
from ..researcher.noise_floor import noise_floor_from_frames
from ..scenario import Scenario, pose_field
from ..world.physics import draw_readings, run_test_physics, test_rng
from ..world.rig import Rig
from ..world.scan_noise import ScanGeometry, ScanNoise
from ..world.sensors import ForceTorqueSensor
from ..world.truth import load_truth
from .compact_scan import CompactScan, GridBox, ray_grid, shared_rays


@dataclass(frozen=True)
class PreparedTest:
    """The noise-free part of one test: equilibrium wrenches and ray-cast geometry."""

    test_id: str
    group: str
    index: int
    q: np.ndarray  # (n,) commanded DH [rad]
    scanner_pose: np.ndarray  # (4, 4)
    rays: np.ndarray  # (M, 3) ray table the scans index (shared by the tests of a list)
    scan_unloaded: CompactScan
    scan_loaded: CompactScan
    wrench_unloaded: np.ndarray  # (6,) true sensor wrench
    wrench_loaded: np.ndarray  # (6,)
    displacement_true: np.ndarray  # (6,) block frame [m, rad]
    block_loaded_in_scanner: np.ndarray | None = None  # (4, 4) true loaded block pose, scanner frame

    @property
    def hits_unloaded(self) -> ScanGeometry:
        """The unloaded scan's hits (points and directions as cast; no normals or geoms)."""
        return self.scan_unloaded.hits(self.rays)

    @property
    def hits_loaded(self) -> ScanGeometry:
        return self.scan_loaded.hits(self.rays)

    def record(self, wrench_unloaded=None, wrench_loaded=None) -> TestRecord:
        """This test as a dataset row (no cloud files): the F/T readings given [N, N*m], by default
        the true wrenches; what the researcher's reduction (``measure_arrays``) reads."""
        return TestRecord(
            self.test_id, self.group, np.degrees(self.q),
            self.wrench_unloaded if wrench_unloaded is None else wrench_unloaded,
            self.wrench_loaded if wrench_loaded is None else wrench_loaded,
            self.scanner_pose, Path(), Path(),
        )  # fmt: skip

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays held (the scans dominate; the ray table is shared with other tests)."""
        return self.rays.nbytes + self.scan_unloaded.nbytes + self.scan_loaded.nbytes


@dataclass(frozen=True)
class PreparedScenario:
    """A scenario's tests with their physics done; trials only add noise and run the researcher."""

    scenario: Scenario
    setup: DatasetSetup
    tests: tuple[PreparedTest, ...]
    stiffness_true: np.ndarray  # (n,) N*m/rad: for the reports of a campaign, never for a trial

    def identification_tests(self) -> list[PreparedTest]:
        return [t for t in self.tests if t.group == "identification"]

    @property
    def nbytes(self) -> int:
        """Bytes of the prepared hits held, each shared ray table counted once."""
        tables = {id(t.rays): t.rays.nbytes for t in self.tests}
        return sum(tables.values()) + sum(t.scan_unloaded.nbytes + t.scan_loaded.nbytes for t in self.tests)

    @cached_property
    def kinematics(self) -> ArmKinematics:
        """The researcher's Pinocchio model of the block, built on first use and then reused."""
        return ArmKinematics.for_setup(self.setup, self.scenario.robot)

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
    rows = []
    for group, i, q, load in jobs:
        try:
            phys = run_test_physics(
                rig, q, load.hooks[i], load.anchors[i], load.tensions[i], scenario.scanner.distance, placement,
                label=pose_field(group, i),
            )  # fmt: skip
        except (ScanError, SensorOverloadError) as exc:  # in the scenario's terms, as `simulate` says it
            raise test_error(scenario, group, i, exc) from None
        rays = phys.scanner.ray_directions
        box = GridBox.of(phys.scanner)
        if not np.array_equal(ray_grid(box.step, box.ku, box.kv), rays):
            box = rays  # cannot be regenerated: keep this test's own rays
        fields = dict(
            test_id=test_id(group, i),
            group=group,
            index=i,
            q=np.asarray(q),
            scanner_pose=scanner_pose_as_recorded(phys.scanner.pose_world),
            wrench_unloaded=phys.unloaded.sensor_wrench,
            wrench_loaded=phys.loaded.sensor_wrench,
            displacement_true=phys.displacement_true,
            block_loaded_in_scanner=phys.loaded_block_in_scanner,
        )
        scans = (CompactScan.of(phys.hits_unloaded, rays), CompactScan.of(phys.hits_loaded, rays))
        rows.append((fields, box, scans))
        del phys, rays  # only the compact scans outlive the test
    tests = [
        PreparedTest(rays=rays, scan_unloaded=s0, scan_loaded=s1, **fields)
        for fields, rays, (s0, s1) in shared_rays(rows)
    ]
    return PreparedScenario(scenario, dataset_setup(scenario, lab), tuple(tests), rig.truth.stiffness_true)


def measure_trial(
    prepared: PreparedScenario,
    seed: int,
    tests: list[PreparedTest] | None = None,
    noise: ScanNoise | None | str = "scenario",
    sensor: ForceTorqueSensor | None = None,
    edges: bool = False,
) -> list[TestMeasurement]:
    """Draw one trial's noise (seed ``seed``) and reduce each test as the researcher would.

    ``noise="scenario"`` uses the scenario's scanner noise; ``None`` is a perfect scanner.
    ``edges``: with the block's apparent edges (``measure_arrays``; the scale check's).
    """
    noise = _scan_noise(prepared, noise)
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
        out.append(measure_arrays(t.record(w0, w1), cloud0, cloud1, prepared.setup, kin, edges))
    return out


def _scan_noise(prepared: PreparedScenario, noise: ScanNoise | None | str) -> ScanNoise | None:
    """``noise="scenario"``: the scenario's scanner noise model; otherwise ``noise`` itself."""
    return prepared.scenario.scanner.noise_model if isinstance(noise, str) else noise


def trial(
    prepared: PreparedScenario,
    seed: int,
    n_tests: int | None = None,
    method: str | None = None,
    noise: ScanNoise | None | str = "scenario",
    sensor: ForceTorqueSensor | None = None,
    reference: str | None = None,
) -> IdentificationResult:
    """One virtual experiment with the first ``n_tests`` identification tests.

    ``method="gls_floor"`` also draws the scenario's repeat scans of those tests (as ``simulate``
    writes them: :func:`~vtestbed.world.repeats.repeat_rng`) for the noise floor it weights with.
    ``reference="mean"`` measures each displacement against the mean of the test's unloaded scan
    and its repeats (:func:`~vtestbed.researcher.scan_mean.against_reference`), as
    ``vtestbed identify --reference mean`` does on the dataset; None: the scenario's
    ``identification.reference``.
    """
    from ..researcher.scan_mean import against_reference

    tests = prepared.identification_tests()[:n_tests]
    measurements = measure_trial(prepared, seed, tests, noise, sensor)
    method = method or prepared.scenario.method
    reference = reference or prepared.scenario.reference
    floor = None
    if method == "gls_floor" or reference != "scan":
        frames = _trial_frames(prepared, seed, tests, measurements, noise)
        floor = None if frames is None else noise_floor_from_frames(frames)
        loaded = (
            None
            if reference == "scan"
            else _trial_frames(prepared, seed, tests, measurements, noise, "loaded")
        )
        where = f"scenario {prepared.scenario.name!r}"
        setup = prepared.setup  # its F/T noise is what the dataset's setup.json would state
        if sensor is not None:
            setup = replace(setup, sensor_noise_std=tuple(sensor.noise_std))
        measurements, floor = against_reference(
            reference, measurements, frames, floor, where, loaded, setup=setup
        )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return identify_measurements(
            measurements, method, prepared.scenario.robot.joint_names, noise_floor=floor
        )


def _trial_frames(prepared: PreparedScenario, seed: int, tests, measurements, noise, state="unloaded"):
    """:func:`repeat_frames` of one trial's tests (``scanner.repeats`` repeats each; ``state=
    "loaded"``: ``scanner.loaded_repeats``), or None without them or without scanner noise (the
    researcher's code then says what is missing)."""
    sc = prepared.scenario
    noise = _scan_noise(prepared, noise)
    repeats = sc.scanner.loaded_repeats if state == "loaded" else sc.scanner.repeats
    if noise is None or repeats < 1:
        return None
    return repeat_frames(prepared, seed, tests, measurements, noise, repeats, state)


def repeat_frames(
    prepared: PreparedScenario,
    seed: int,
    tests,
    measurements,
    noise: ScanNoise,
    repeats: int,
    state: str = "unloaded",
) -> dict[str, list[np.ndarray]]:
    """Per test, the fitted frames (4, 4) of its unloaded scan and ``repeats`` repeat scans
    (``state="loaded"``: of its loaded scan and ``repeats`` loaded repeats).

    The repeats are drawn as ``simulate`` writes them (:func:`~vtestbed.world.repeats.repeat_rng`
    or ``loaded_repeat_rng`` of trial ``seed``) with the world's effects, and fitted by the
    researcher's pipeline (:func:`~vtestbed.researcher.repeat_scans.scan_frames`, loaded repeats
    :func:`~vtestbed.researcher.scan_mean.loaded_repeat_frames`, as for a dataset);
    ``measurements`` are the trial's reduced tests (their frames are reused).
    """
    from ..researcher.repeat_scans import scan_frames
    from ..researcher.scan_mean import loaded_repeat_frames
    from ..world.repeats import draw_repeat_scans, loaded_repeat_geometries, loaded_repeat_rng, repeat_rng

    effects, setup = prepared.scenario.effects, prepared.setup
    frames = {}
    for t, m in zip(tests, measurements):
        if state == "loaded":
            rng = loaded_repeat_rng(seed, t.group, t.index)
            hits = t.hits_loaded  # as simulate draws them: a creeping block moves on between scans
            moved = loaded_repeat_geometries(
                hits, t.block_loaded_in_scanner, t.displacement_true, effects, repeats
            )
            clouds = draw_repeat_scans(hits, noise, rng, repeats, effects, moved)
            labels = [f"test {t.test_id}, loaded repeat {k} cloud" for k in range(1, repeats + 1)]
            frames[t.test_id] = loaded_repeat_frames(m.frame_loaded, clouds, setup, labels)
            continue
        rng = repeat_rng(seed, t.group, t.index)
        clouds = draw_repeat_scans(t.hits_unloaded, noise, rng, repeats, effects)
        frames[t.test_id] = scan_frames(
            t.record(), None, clouds, setup, prepared.kinematics, m.frame_unloaded
        )
    return frames
