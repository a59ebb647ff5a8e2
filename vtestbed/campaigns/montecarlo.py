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
from ..world.scanner import Scanner
from ..world.sensors import ForceTorqueSensor
from ..world.truth import load_truth


@dataclass(frozen=True, eq=False)
class _Hits(ScanGeometry):
    """A prepared scan's hits as the noise model needs them: the incidence cosines are stored
    (computed once, as :class:`ScanGeometry` computes them), the normals and geoms are not."""

    cos: np.ndarray | None = None

    @property
    def cos_incidence(self) -> np.ndarray:
        return self.cos


@dataclass(frozen=True, eq=False)
class CompactScan:
    """One scan's noise-free hits in 20 bytes a point instead of 88.

    A worker keeps the hits of every test of a test list for all its trials, so their size is
    the worker's memory. The cast computes a hit as ``dist * rays[index]``: storing ``dist``,
    ``index`` and the incidence cosine (and a ray table shared by the tests, :func:`_shared_rays`)
    rebuilds the same doubles bit for bit. A scan whose distances cannot be recovered exactly
    from its points keeps the points themselves (``points``).
    """

    dist: np.ndarray | None  # (N,) distance along the ray [m], or None: ``points`` holds them
    index: np.ndarray  # (N,) int32 row of the test's ray grid
    cos: np.ndarray  # (N,) cosine of the incidence angle
    points: np.ndarray | None = None  # (N, 3), only when ``dist`` is None

    @classmethod
    def of(cls, hits: ScanGeometry, rays: np.ndarray) -> CompactScan:
        index = hits.ray_index.astype(np.int32)
        dirs, pts = rays[index], hits.points_m
        if not np.array_equal(dirs, hits.directions):
            raise ValueError("the hits do not come from this ray grid")
        quotient = pts[:, 2] / dirs[:, 2]
        dist = quotient.copy()
        bad = ~np.all(dist[:, None] * dirs == pts, axis=1)
        for step in (np.inf, -np.inf):  # a quotient can be one ulp off the cast's distance
            candidate = np.where(bad, np.nextafter(quotient, step), dist)
            fixed = bad & np.all(candidate[:, None] * dirs == pts, axis=1)
            dist[fixed] = candidate[fixed]
            bad &= ~fixed
        exact = not bad.any()
        return cls(dist if exact else None, index, hits.cos_incidence, None if exact else pts.copy())

    def hits(self, rays: np.ndarray) -> ScanGeometry:
        dirs = rays[self.index]
        points = self.dist[:, None] * dirs if self.dist is not None else self.points
        return _Hits(points, dirs, None, None, self.index, self.cos)

    def reindexed(self, index: np.ndarray) -> CompactScan:
        """The same scan with its rays numbered as rows of another table."""
        return CompactScan(self.dist, index, self.cos, self.points)

    @property
    def nbytes(self) -> int:
        return sum(a.nbytes for a in (self.dist, self.index, self.cos, self.points) if a is not None)


def _ray_grid(step: float, ku: tuple[float, float], kv: tuple[float, float]) -> np.ndarray:
    """(M, 3) unit rays through the lattice points ``(ku, kv) * step`` of the normalised image
    plane, ``ku[0] <= ku <= ku[1]`` (row-major in v, u): :attr:`Scanner.ray_directions`'
    own arithmetic, so a window's rays are the same doubles in any grid that covers it."""
    us = np.arange(ku[0], ku[1] + 1) * step
    vs = np.arange(kv[0], kv[1] + 1) * step
    uu, vv = np.meshgrid(us, vs)
    dirs = np.stack([uu.ravel(), vv.ravel(), np.ones(uu.size)], axis=1)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs.flags.writeable = False
    return dirs


@dataclass(frozen=True)
class _GridBox:
    """Where a scanner's ray grid lies on the lattice of its pitch: lattice columns ``ku`` and
    rows ``kv`` (inclusive, integral floats as :attr:`Scanner.ray_directions` computes them)."""

    step: float
    ku: tuple[float, float]
    kv: tuple[float, float]

    @classmethod
    def of(cls, scanner: Scanner) -> _GridBox:
        step = scanner.point_spacing_m / scanner.standoff_m
        hu, hv = scanner.half_field
        u0, u1, v0, v1 = scanner.window if scanner.window is not None else (-hu, hu, -hv, hv)
        ku = (float(np.ceil(u0 / step)), float(np.floor(u1 / step)))
        kv = (float(np.ceil(v0 / step)), float(np.floor(v1 / step)))
        return cls(step, ku, kv)

    def rows_in(self, outer: _GridBox, index: np.ndarray) -> np.ndarray:
        """Rows of ``outer``'s grid of the rays numbered ``index`` in this grid."""
        nu, outer_nu = int(self.ku[1] - self.ku[0]) + 1, int(outer.ku[1] - outer.ku[0]) + 1
        iv, iu = np.divmod(index.astype(np.int64), nu)
        rows = (iv + int(self.kv[0] - outer.kv[0])) * outer_nu + (iu + int(self.ku[0] - outer.ku[0]))
        return rows.astype(np.int32)


def _shared_rays(tests: list[tuple]) -> list[tuple]:
    """Re-point every test's scans at one ray table per lattice pitch (the union of the windows).

    A scanner's rays depend only on its pitch and window, and the windows of a test list overlap
    nearly wholly: one table of about 2.6 MB replaces 2.3 MB per test. ``tests`` rows are
    ``(fields, box, scans)``; a test whose rays do not regenerate bit for bit (``box`` is its
    own ray array) keeps its own table. Returns ``(fields, rays, scans)`` rows.
    """
    tables = {}
    for step in {box.step for _, box, _ in tests if isinstance(box, _GridBox)}:
        boxes = [box for _, box, _ in tests if isinstance(box, _GridBox) and box.step == step]
        ku = (min(b.ku[0] for b in boxes), max(b.ku[1] for b in boxes))
        kv = (min(b.kv[0] for b in boxes), max(b.kv[1] for b in boxes))
        outer = _GridBox(step, ku, kv)
        tables[step] = (outer, _ray_grid(step, ku, kv))
    out = []
    for fields, box, scans in tests:
        if isinstance(box, _GridBox):
            outer, table = tables[box.step]
            own = _ray_grid(box.step, box.ku, box.kv)
            all_rows = box.rows_in(outer, np.arange(len(own)))
            if np.array_equal(table[all_rows], own):
                scans = tuple(scan.reindexed(all_rows[scan.index]) for scan in scans)
                out.append((fields, table, scans))
                continue
            box = own  # the shared table differs: keep the test's own rays
        out.append((fields, box, scans))
    return out


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
        box = _GridBox.of(phys.scanner)
        if not np.array_equal(_ray_grid(box.step, box.ku, box.kv), rays):
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
        )
        scans = (CompactScan.of(phys.hits_unloaded, rays), CompactScan.of(phys.hits_loaded, rays))
        rows.append((fields, box, scans))
        del phys, rays  # only the compact scans outlive the test
    tests = [
        PreparedTest(rays=rays, scan_unloaded=s0, scan_loaded=s1, **fields)
        for fields, rays, (s0, s1) in _shared_rays(rows)
    ]
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
        out.append(measure_arrays(t.record(w0, w1), cloud0, cloud1, prepared.setup, kin))
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
        measurements, floor = against_reference(reference, measurements, frames, floor, where, loaded)
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
    researcher's pipeline (:func:`~vtestbed.researcher.noise_floor.scan_frames`, loaded repeats
    :func:`~vtestbed.researcher.scan_mean.loaded_repeat_frames`, as for a dataset);
    ``measurements`` are the trial's reduced tests (their frames are reused).
    """
    from ..researcher.noise_floor import scan_frames
    from ..researcher.scan_mean import loaded_repeat_frames
    from ..world.repeats import draw_repeat_scans, loaded_repeat_rng, repeat_rng

    effects, setup = prepared.scenario.effects, prepared.setup
    frames = {}
    for t, m in zip(tests, measurements):
        if state == "loaded":
            rng = loaded_repeat_rng(seed, t.group, t.index)
            clouds = draw_repeat_scans(t.hits_loaded, noise, rng, repeats, effects)
            labels = [f"test {t.test_id}, loaded repeat {k} cloud" for k in range(1, repeats + 1)]
            frames[t.test_id] = loaded_repeat_frames(m.frame_loaded, clouds, setup, labels)
            continue
        rng = repeat_rng(seed, t.group, t.index)
        clouds = draw_repeat_scans(t.hits_unloaded, noise, rng, repeats, effects)
        frames[t.test_id] = scan_frames(
            t.record(), None, clouds, setup, prepared.kinematics, m.frame_unloaded
        )
    return frames
