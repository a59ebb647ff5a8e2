"""The researcher's side: from a measurement dataset to joint stiffness.

Everything here reads only the dataset (setup.json, tests.csv, the PLY clouds) and the robot's
nominal kinematics, never the truth, so it runs unchanged on a dataset recorded in a real lab.

Frames: the identification works in the block frame B at the commanded pose. The displacement
of B's origin is ``[R0^T (o1 - o0); rotvec(R0^T R1)]`` from the two fitted frames (so no
scanner-to-robot calibration is needed), the wrench change (loaded minus unloaded, which
cancels the block's weight and the sensor bias) is moved from the sensor origin to B's origin
and into B's axes, and the Jacobian is the geometric Jacobian of B in B's axes at the
commanded pose.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..dataset import DatasetSetup, TestRecord, read_setup, read_tests
from ..errors import DatasetError, ImplausibleDataError, ScanError, VtestbedError
from ..ply import MAX_CLOUD_COORDINATE_M, read_ply
from ..robots import load_robot
from ..transforms import displacement_in_block_frame, invert
from . import block_size, cloud
from .identify import IdentificationResult, identify
from .kinematics import ArmKinematics
from .plausibility import plausibility_notes


@dataclass(frozen=True)
class TestMeasurement:
    """One test reduced to what the identification needs (block frame, SI)."""

    __test__ = False  # a data class, not a pytest test class

    test_id: str
    group: str
    q: np.ndarray  # (n,) commanded DH angles [rad]
    wrench: np.ndarray  # (6,) external wrench change at B's origin, B axes [N, N*m]
    displacement: np.ndarray  # (6,) B's displacement in B axes [m, rad]
    jacobian: np.ndarray  # (6, n) at B, B axes, commanded pose
    frame_unloaded: np.ndarray  # (4, 4) fitted block frame in the scanner frame
    frame_loaded: np.ndarray  # (4, 4)
    readings: tuple | None = None  # (unloaded, loaded) F/T readings (6,) [N, N*m], sensor frame
    # (unloaded, loaded) path of each cloud fit, cloud.BlockFrame.method: "fast", or "ransac" when
    # a check of the fast path failed (the nominal pose far off, clutter, a face cut off)
    fit_methods: tuple[str, str] = ("fast", "fast")
    # (unloaded, loaded) apparent edge lengths (2, 6) [m] of the plain block's scans (a length
    # standard for the scanner's scale: block_size.apparent_edges); None for a mesh target, or
    # when not asked for (measure_arrays(..., edges=True); diagnose asks)
    edge_lengths: np.ndarray | None = None


def wrench_at_block(wrench_sensor: np.ndarray, setup: DatasetSetup) -> np.ndarray:
    """Move a wrench (6,) from the sensor origin/axes to the block origin/axes."""
    sensor_in_block = invert(setup.block_in_flange) @ setup.sensor_in_flange
    rot, origin = sensor_in_block[:3, :3], sensor_in_block[:3, 3]
    force = rot @ wrench_sensor[:3]
    torque = rot @ wrench_sensor[3:] + np.cross(origin, force)
    return np.concatenate([force, torque])


def commanded_pose(record: TestRecord, setup: DatasetSetup, robot) -> np.ndarray:
    q = np.radians(record.q_deg)
    return robot.controller_to_dh(q) if setup.angle_convention == "controller" else q


def nominal_block_frame(record: TestRecord, setup: DatasetSetup, kin: ArmKinematics):
    """The commanded pose and where the block should be in the scanner frame.

    Returns ``(q, nominal)``: the commanded DH angles (n,) [rad] (checked against the joint
    limits) and the block frame's predicted pose (4, 4) in the scanner frame, from the rough
    scanner pose and the nominal kinematics: enough to crop the clutter around the block.
    """
    q = commanded_pose(record, setup, kin.robot)
    where = f"test {record.test_id} pose (tests.csv q1_deg.., {setup.angle_convention} angles)"
    kin.robot.check_pose(q, field=where)
    return q, invert(record.scanner_pose) @ kin.tool_pose(q, setup.block_in_flange)


def fit_scan_frame(points: np.ndarray, nominal, setup: DatasetSetup, label: str) -> cloud.BlockFrame:
    """The fitted block frame of one cloud (N, 3) [m, scanner frame] near ``nominal`` (4, 4).

    The fast path when the nominal pose is good to 3 deg and 8 mm (the commanded pose through the
    nominal kinematics and the recorded scanner pose are; the unloaded fit for the loaded scan is),
    open3d RANSAC otherwise (``BlockFrame.method``). Raises a ScanError that starts with ``label``
    (e.g. ``test T001, unloaded cloud``).
    """
    try:
        band = cloud.CHAMFER_EDGE_BAND_M if setup.block_face_margin > 0 else 0.0  # a chamfered target
        return cloud.fit_block_frame(
            points, nominal, cloud.FitParams(edge_m=setup.block_edge, edge_band_m=band)
        )
    except VtestbedError as exc:
        raise ScanError(f"{label}: {exc}") from None


def fit_scan(points: np.ndarray, nominal, setup: DatasetSetup, label: str) -> np.ndarray:
    """The pose (4, 4) of :func:`fit_scan_frame`."""
    return fit_scan_frame(points, nominal, setup, label).pose


def read_scan(path: Path, label: str) -> np.ndarray:
    """The points (N, 3) [m, scanner frame] of one scan file, or a ScanError that starts with
    ``label`` and the file (an unreadable file, or points with a NaN or infinite coordinate, which
    the fit would refuse without saying which file held them)."""
    try:
        points = read_ply(path)
    except VtestbedError as exc:
        raise ScanError(f"{label} {path}: {exc}") from None
    bad = ~np.all(np.isfinite(points), axis=1)
    if bad.any():
        raise ScanError(
            f"{label} {path}: {int(bad.sum())} of its {len(points)} points have a NaN or infinite "
            "coordinate; valid: finite coordinates in m (remove those points, or rescan)"
        )
    reach = float(np.abs(points).max())
    if reach > MAX_CLOUD_COORDINATE_M:  # mm read as m: the fit would only say "block not found"
        raise ScanError(
            f"{label} {path}: coordinates reach {reach:.4g} m, beyond {MAX_CLOUD_COORDINATE_M:g} m: is the "
            "file in mm? A dataset's clouds are in m (vtestbed dataset import --cloud-units mm converts them)"
        )
    return points


def measure_test(
    record: TestRecord, setup: DatasetSetup, kin: ArmKinematics, edges: bool = False
) -> TestMeasurement:
    """Fit both clouds of one recorded test and build its wrench, displacement and Jacobian (and,
    with ``edges``, the block's apparent edge lengths: :attr:`TestMeasurement.edge_lengths`)."""
    clouds = [
        read_scan(path, f"test {record.test_id}, {label} cloud")
        for label, path in (("unloaded", record.cloud_unloaded), ("loaded", record.cloud_loaded))
    ]
    return measure_arrays(record, clouds[0], clouds[1], setup, kin, edges)


def measure_arrays(
    record: TestRecord,
    cloud_unloaded: np.ndarray,
    cloud_loaded: np.ndarray,
    setup: DatasetSetup,
    kin: ArmKinematics,
    edges: bool = False,
) -> TestMeasurement:
    """As :func:`measure_test`, with the clouds (N, 3) [m, scanner frame] already in memory."""
    q, nominal = nominal_block_frame(record, setup, kin)
    # The loaded scan starts from the unloaded fit (the block moves by less than a millimetre).
    fits = []
    for label, points in (("unloaded", cloud_unloaded), ("loaded", cloud_loaded)):
        path = Path(getattr(record, f"cloud_{label}"))  # Path() for a record without files (a sweep's)
        where = f"test {record.test_id}, {label} cloud" + (f" {path}" if path.name else "")
        fits.append(fit_scan_frame(points, nominal, setup, where))
        nominal = fits[-1].pose
    frames = [f.pose for f in fits]
    lengths = None
    if edges and setup.target is None:  # the plain block: its declared edge is a length standard
        lengths = np.array([block_size.apparent_edges(points, fit.pose, setup.block_edge, fit.rms_residual_m)
                          for points, fit in zip((cloud_unloaded, cloud_loaded), fits, strict=True)])  # fmt: skip
    return TestMeasurement(
        test_id=record.test_id,
        group=record.group,
        q=q,
        wrench=wrench_at_block(record.wrench_loaded - record.wrench_unloaded, setup),
        displacement=displacement_in_block_frame(*frames),
        jacobian=kin.jacobian(q, setup.block_in_flange, frame="tool"),
        frame_unloaded=frames[0],
        frame_loaded=frames[1],
        readings=(np.array(record.wrench_unloaded, dtype=float), np.array(record.wrench_loaded, dtype=float)),
        fit_methods=(fits[0].method, fits[1].method),
        edge_lengths=lengths,
    )


def load_measurements(
    root: str | Path, progress: Callable[[int, int], None] | None = None, edges: bool = False
):
    """Read and reduce a dataset: returns (setup, list of TestMeasurement); ``edges``: with each
    test's apparent block edges (:mod:`.block_size`, about 3 ms a scan)."""
    root = Path(root)
    setup = read_setup(root)
    records = read_tests(
        root, check_files=True, sensor_range=setup.sensor_range, sensor_name=setup.sensor_name
    )
    if not records:
        raise DatasetError(f"{root / 'tests.csv'} holds no tests")
    robot = load_robot(setup.robot)
    kin = ArmKinematics.for_setup(setup, robot)
    out = []
    for i, record in enumerate(records):
        out.append(measure_test(record, setup, kin, edges))
        if progress:
            progress(i + 1, len(records))
    return setup, out


def stacked(tests: list[TestMeasurement]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tests' Jacobians (T, 6, n), wrenches (T, 6) and displacements (T, 6), as
    :func:`~vtestbed.researcher.identify.identify` takes them."""
    return (np.array([m.jacobian for m in tests]), np.array([m.wrench for m in tests]),
            np.array([m.displacement for m in tests]))  # fmt: skip


NO_FLOOR = (
    "identification method 'gls_floor' weights the tests with the repeat-scan noise floor, and there "
    "are no repeat scans: record 2 or more scans of the unloaded block per test (repeats.csv; "
    "[scanner] repeats = 3 in a scenario), or use method 'fgls', which needs none"
)


# gls_floor whitens with the floor's 6 x 6 covariance: estimated from fewer than 6 independent
# displacement samples it has rank < 6 (singular), and its weights would be meaningless; its
# sampling inflation nu / (nu - 7) needs nu > 7, as the model fit against the floor does.
MIN_FLOOR_SAMPLES = 8


def gls_floor_covariance(noise_floor, source: str | None = None) -> np.ndarray:
    """The covariance ``gls_floor`` weights with and reports under, or a DatasetError naming
    ``source`` (the dataset folder, if any), the samples it has and the samples it needs (no floor,
    or one from too few repeat scans).

    It is the floor's displacement covariance (the scans' plus, where setup.json states the F/T
    sensor's noise, the readings': ``NoiseFloor.displacement_covariance``) times ``nu / (nu - 7)``,
    the mean inflation of the inverse of a 6 x 6 covariance estimated from ``nu`` repeat samples
    (:func:`.floor_calibration.inflation`, the same as the model fit's :class:`.model_fit.Whitener`):
    the inflation leaves the weights, so the estimate, as they are; the reported std grows by its
    square root (1.11 at 12 tests with 3 repeats, 1.06 at 20), which brings the z-score std into
    [0.8, 1.25] on every design of docs/uncertainty.md."""
    from .floor_calibration import inflation

    where = f"{source}: " if source else ""
    if noise_floor is None:
        raise DatasetError(f"{where}{NO_FLOOR}")
    if noise_floor.n_samples < MIN_FLOOR_SAMPLES:
        raise DatasetError(
            f"{where}identification method 'gls_floor' weights with the repeat-scan noise floor's "
            f"6 x 6 covariance, which needs at least {MIN_FLOOR_SAMPLES} repeat-scan samples (one per "
            f"repeat of a test); repeats.csv gives {noise_floor.n_samples} (from {noise_floor.n_tests} "
            f"test{'s' * (noise_floor.n_tests != 1)}): record {MIN_FLOOR_SAMPLES - noise_floor.n_samples} "
            "more repeat scans, or use method 'fgls'"
        )
    return noise_floor.displacement_covariance * inflation(noise_floor.n_samples)


def identify_measurements(
    measurements: list[TestMeasurement],
    method: str = "fgls",
    joint_names=None,
    strict: bool = False,
    noise_floor=None,
    source: str | None = None,
) -> IdentificationResult:
    """Identify from the ``identification`` group of reduced tests.

    ``noise_floor`` (a :class:`~vtestbed.researcher.noise_floor.NoiseFloor`) is required by
    ``method="gls_floor"``, which weights with its covariance, and ignored by the others;
    ``source`` (the dataset folder) names where a missing or too small floor comes from.

    Tests that no wire load could produce (:func:`motionless_tests` and the checks of
    :mod:`.plausibility`) are named in the result's warnings, or, with ``strict``, raise an
    :class:`~vtestbed.errors.ImplausibleDataError` listing them all.
    """
    tests = [m for m in measurements if m.group == "identification"]
    if not tests:
        where = f"{Path(source) / 'tests.csv'}: " if source else ""
        raise DatasetError(
            f"{where}the dataset has no test in group 'identification' (column group: identification or "
            f"validation; its {len(measurements)} tests are all validation): at least one identification "
            "test is needed"
        )
    ids = tuple(m.test_id for m in tests)
    cov = None
    if method == "gls_floor":
        cov = gls_floor_covariance(noise_floor, source)
    result = identify(
        *stacked(tests), method=method, displacement_cov=cov, joint_names=joint_names, test_ids=ids
    )
    notes = []
    still = motionless_tests(tests, result.compliance)
    if still:
        notes.append(
            f"tests {', '.join(still)}: the block barely moved under the load (measured displacement below "
            f"{MOTIONLESS_FRACTION:.0%} of the fitted model's, translation and rotation): the same scan given "
            "twice, or the load never reached the block? Check their clouds and readings"
        )
    if np.all(result.compliance < 0):  # the per-test checks need a positive fit to predict from
        notes.append(
            f"every joint's fitted compliance is negative: in all {len(tests)} tests the block moved against "
            "the load, which no spring does. Loaded and unloaded scans swapped, or the wrench's sign "
            "flipped, throughout? Check the columns cloud_unloaded, cloud_loaded and the F/T readings"
        )
    notes += plausibility_notes(tests)
    if not notes:
        return result
    if strict:
        raise ImplausibleDataError("implausible measurements (--strict): " + "; ".join(notes))
    for note in notes:
        warnings.warn(note, stacklevel=2)
    return replace(result, warnings=(*result.warnings, *notes))


# A loaded block moves: a test whose measured displacement is below this fraction of the fitted
# model's prediction, in translation and in rotation, cannot be a real loaded scan.
MOTIONLESS_FRACTION = 0.05


def motionless_tests(tests: list[TestMeasurement], compliance: np.ndarray) -> list[str]:
    """Ids of the tests whose block did not move (physically impossible under their load): a
    measured displacement exactly zero, or below :data:`MOTIONLESS_FRACTION` of the prediction
    ``J C J^T F`` of the fitted compliance ``C``, both in translation and in rotation."""
    out = []
    compliance = np.asarray(compliance, dtype=float)
    for m in tests:
        measured = np.asarray(m.displacement)
        if not np.any(measured):
            out.append(m.test_id)
            continue
        if not np.all(np.isfinite(compliance)) or np.any(compliance <= 0):
            continue  # no trustworthy prediction to compare with
        predicted = predict_displacement(m, 1.0 / compliance)
        ratios = [
            np.linalg.norm(measured[s]) / np.linalg.norm(predicted[s])
            for s in (slice(0, 3), slice(3, 6))
            if np.linalg.norm(predicted[s]) > 0
        ]
        if ratios and max(ratios) < MOTIONLESS_FRACTION:
            out.append(m.test_id)
    return out


def predict_displacement(measurement: TestMeasurement, stiffness: np.ndarray) -> np.ndarray:
    """The model's displacement J K^-1 J^T F (6,) for one test, given stiffness [N*m/rad]."""
    jac = measurement.jacobian
    return jac @ ((jac.T @ measurement.wrench) / np.asarray(stiffness))
