"""Run a scenario: the world writes a dataset, the researcher's code identifies from it.

``simulate`` drives the truth world (:mod:`vtestbed.rig`, the scanner, the F/T sensor) and
writes a lab-compatible dataset plus a separate ``truth.json``. ``run`` then identifies from the
dataset alone (:mod:`vtestbed.analysis`) and only afterwards compares with the truth.

Reproducibility: test ``i`` of group ``g`` draws from ``SeedSequence(seed, spawn_key=(g, i))``,
so a test's numbers do not depend on which other tests ran before it, and a resumed run gives
the same dataset as an uninterrupted one.
"""

from __future__ import annotations

import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .dataset import CLOUD_DIR, TRUTH_FILE, DatasetSetup, TestRecord, TestWriter, write_setup
from .errors import DatasetError
from .lab import LabSetup
from .researcher import cloud
from .researcher.measure import displacement_in_block_frame
from .scenario import Scenario
from .world.rig import Rig, RigState
from .world.scanner import ScanGeometry, Scanner, ScanNoise
from .world.sensors import ForceTorqueSensor

GROUP_KEYS = {"identification": 0, "validation": 1}


@dataclass
class Timings:
    """Wall time per phase [s], for the benchmark and the run summary."""

    physics: float = 0.0
    scan: float = 0.0
    write: float = 0.0
    process: float = 0.0
    identify: float = 0.0
    report: float = 0.0

    def as_dict(self) -> dict:
        return {k: round(v, 4) for k, v in self.__dict__.items()}


def test_rng(seed: int, group: str, index: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(GROUP_KEYS[group], index)))


def dataset_setup(scenario: Scenario, lab: LabSetup) -> DatasetSetup:
    return DatasetSetup(
        robot=scenario.robot_name,
        angle_convention="dh",
        block_in_flange=lab.block_in_flange,
        sensor_in_flange=lab.sensor_in_flange,
        block_edge=lab.block.edge,
        sensor_name=lab.sensor.name,
        sensor_range=lab.sensor.wrench_range,
        notes=f"simulated by vtestbed from scenario {scenario.name!r}",
    )


def scanner_placement(scenario: Scenario) -> dict:
    """Keyword arguments of :meth:`Scanner.place` that the scenario sets."""
    return {} if scenario.scanner.spacing is None else {"point_spacing_m": scenario.scanner.spacing}


@dataclass(frozen=True)
class TestPhysics:
    """One test in the truth world, before any noise: both equilibria and both ray casts."""

    unloaded: RigState
    loaded: RigState
    scanner: Scanner
    hits_unloaded: ScanGeometry
    hits_loaded: ScanGeometry

    @property
    def displacement_true(self) -> np.ndarray:
        """(6,) true block displacement in the unloaded block frame [m, rad]."""
        return displacement_in_block_frame(self.unloaded.block_pose, self.loaded.block_pose)


def run_test_physics(
    rig: Rig, q, hook: str, anchor: str, tension: float, distance: float, placement: dict, timings=None
) -> TestPhysics:
    """Command, hook, solve, place the scanner and cast; tighten and cast again (deterministic).

    Raises the world's VtestbedError when the test cannot be run (scanner view, sensor range).
    """
    t0 = time.perf_counter()
    rig.command(q)
    rig.hook(hook, anchor)
    s0 = rig.solve()
    t1 = time.perf_counter()
    scanner = Scanner.place(rig.lab, s0.block_pose, distance_m=distance, **placement)
    hits0 = scanner.cast(rig.model, rig.data)
    t2 = time.perf_counter()
    s1 = rig.tighten(tension)
    t3 = time.perf_counter()
    hits1 = scanner.cast(rig.model, rig.data)
    if timings is not None:
        timings.physics += (t1 - t0) + (t3 - t2)
        timings.scan += (t2 - t1) + (time.perf_counter() - t3)
    return TestPhysics(s0, s1, scanner, hits0, hits1)


def draw_readings(hits_unloaded, hits_loaded, wrench_unloaded, wrench_loaded, noise, sensor, rng):
    """One test's noisy measurements, drawn in a fixed order: scan, F/T, scan, F/T.

    ``noise=None`` is a perfect scanner (it draws nothing). Returns (cloud0, w0, cloud1, w1).
    """
    cloud0 = noise.apply(hits_unloaded, rng) if noise is not None else hits_unloaded.points_m.copy()
    w0 = sensor.read(wrench_unloaded, rng)
    cloud1 = noise.apply(hits_loaded, rng) if noise is not None else hits_loaded.points_m.copy()
    w1 = sensor.read(wrench_loaded, rng)
    return cloud0, w0, cloud1, w1


def _write_json_atomic(path: Path, data: dict) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def _remove_dataset(out: Path) -> None:
    """Delete the files a simulation writes in ``out`` (and nothing else)."""
    import shutil

    for name in (TRUTH_FILE, "tests.csv", "setup.json"):
        (out / name).unlink(missing_ok=True)
    shutil.rmtree(out / CLOUD_DIR, ignore_errors=True)


def _start_truth(out: Path, scenario: Scenario, rig: Rig, replace_stale: bool = False) -> dict:
    truth_path = out / TRUTH_FILE
    if truth_path.exists():
        truth = json.loads(truth_path.read_text())
        if truth.get("scenario_fingerprint") != scenario.fingerprint and replace_stale:
            _remove_dataset(out)
            return _start_truth(out, scenario, rig)
        if truth.get("scenario_fingerprint") != scenario.fingerprint:
            raise DatasetError(
                f"{out} holds a dataset of another scenario (fingerprint {truth.get('scenario_fingerprint')} "
                f"!= {scenario.fingerprint}); choose a new output folder"
            )
        return truth
    return {
        "scenario": scenario.name,
        "scenario_fingerprint": scenario.fingerprint,
        "seed": scenario.seed,
        "robot": scenario.robot_name,
        "joint_names": list(rig.robot.joint_names),
        "stiffness_true_Nm_per_rad": rig.robot.stiffness_true.tolist(),
        "effects": [],
        "tests": {},
    }


def simulate(
    scenario: Scenario,
    out: str | Path,
    progress: bool = False,
    timings: Timings | None = None,
    replace_stale: bool = False,
) -> Path:
    """Run every test of ``scenario`` in the truth world and write the dataset to ``out``.

    Finished tests are kept: rerunning into the same folder does only what is missing. A folder
    holding another scenario's dataset is refused, or replaced with ``replace_stale``.
    """
    out = Path(out)
    timings = timings or Timings()
    lab = LabSetup()
    rig = Rig(scenario.robot(), lab)
    out.mkdir(parents=True, exist_ok=True)
    truth = _start_truth(out, scenario, rig, replace_stale)
    write_setup(out, dataset_setup(scenario, lab))
    noise = ScanNoise(**scenario.scanner.noise_params) if scenario.scanner.noise else None
    sensor = ForceTorqueSensor(lab.sensor, scenario.force_sensor.noise_std, scenario.force_sensor.bias)
    placement = scanner_placement(scenario)
    jobs = [("identification", i, q, scenario.load) for i, q in enumerate(scenario.poses)]
    jobs += [("validation", i, q, scenario.validation_load) for i, q in enumerate(scenario.validation_poses)]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(jobs), desc="simulate", unit="test")
    with TestWriter(out) as writer:
        for group, i, q, load in jobs:
            test_id = f"{'T' if group == 'identification' else 'V'}{i + 1:03d}"
            if test_id not in writer.done:
                rng = test_rng(scenario.seed, group, i)
                phys = run_test_physics(
                    rig, q, load.hooks[i], load.anchors[i], load.tensions[i], scenario.scanner.distance,
                    placement, timings,
                )  # fmt: skip
                s0, s1, scanner = phys.unloaded, phys.loaded, phys.scanner
                t3 = time.perf_counter()
                cloud0, w0, cloud1, w1 = draw_readings(
                    phys.hits_unloaded,
                    phys.hits_loaded,
                    s0.sensor_wrench,
                    s1.sensor_wrench,
                    noise,
                    sensor,
                    rng,
                )
                t4 = time.perf_counter()
                timings.scan += t4 - t3
                paths = (
                    out / CLOUD_DIR / f"{test_id}_unloaded.ply",
                    out / CLOUD_DIR / f"{test_id}_loaded.ply",
                )
                cloud.write_ply(paths[0], cloud0)
                cloud.write_ply(paths[1], cloud1)
                truth["tests"][test_id] = {
                    "group": group,
                    "hook": load.hooks[i],
                    "anchor": load.anchors[i],
                    "tension_N": s1.wire_tension,
                    "q_cmd_rad": s0.q_cmd.tolist(),
                    "q_unloaded_rad": s0.q.tolist(),
                    "q_loaded_rad": s1.q.tolist(),
                    "block_pose_unloaded": s0.block_pose.tolist(),
                    "block_pose_loaded": s1.block_pose.tolist(),
                    "displacement_true_block_frame": phys.displacement_true.tolist(),
                    "sensor_wrench_true_unloaded": s0.sensor_wrench.tolist(),
                    "sensor_wrench_true_loaded": s1.sensor_wrench.tolist(),
                    "scanner_pose_world": scanner.pose_world.tolist(),
                    "points": [len(cloud0), len(cloud1)],
                }
                _write_json_atomic(out / TRUTH_FILE, truth)
                # the row is written last: it marks the test as finished
                writer.append(TestRecord(test_id, group, np.degrees(q), w0, w1, scanner.pose_world, *paths))
                t5 = time.perf_counter()
                timings.write += t5 - t4
            if bar:
                bar.update()
    if bar:
        bar.close()
    return out


def identify_dataset(
    root: str | Path, method: str = "fgls", progress: bool = False, timings: Timings | None = None
):
    """The researcher's job on any dataset: returns (setup, measurements, IdentificationResult)."""
    from .researcher.measure import identify_measurements, load_measurements
    from .robots import load_robot

    timings = timings or Timings()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc="process clouds", unit="test")

    def tick(done, total):
        if bar is not None:
            bar.total = total
            bar.update(done - bar.n)

    t0 = time.perf_counter()
    setup, measurements = load_measurements(root, progress=tick)
    if bar:
        bar.close()
    t1 = time.perf_counter()
    result = identify_measurements(
        measurements, method=method, joint_names=load_robot(setup.robot).joint_names
    )
    timings.process += t1 - t0
    timings.identify += time.perf_counter() - t1
    return setup, measurements, result


def run(
    scenario: Scenario,
    out: str | Path,
    progress: bool = False,
    figures: bool = True,
    replace_stale: bool = False,
) -> dict:
    """simulate + identify + compare; writes ``out/result.json`` and figures; returns the result."""
    from .dataset import read_truth
    from .researcher import report

    out = Path(out)
    timings = Timings()
    simulate(scenario, out / "dataset", progress=progress, timings=timings, replace_stale=replace_stale)
    setup, measurements, result = identify_dataset(out / "dataset", scenario.method, progress, timings)
    t0 = time.perf_counter()
    truth = read_truth(out / "dataset")
    joints = report.compare(result, truth)
    k_true = np.array([j["k_true"] for j in joints])
    conv = report.convergence(measurements, scenario.method, result.joint_names)
    ranges = report.error_ranges(conv, k_true)
    val = report.validation(measurements, result.stiffness)
    files = {}
    if figures:
        files["convergence"] = str(
            report.plot_convergence(conv, k_true, result.joint_names, out / "convergence.png")
        )
        if val:
            files["validation"] = str(report.plot_validation(val, out / "validation.png"))
    timings.report += time.perf_counter() - t0
    summary = {
        "scenario": scenario.name,
        "seed": scenario.seed,
        "n_tests": result.n_tests,
        "method": result.method,
        "joints": joints,
        "table5": {"first_n": report.PAPER_FIRST_N, **ranges},
        "identification": result.as_dict(),
        "convergence": conv,
        "validation": val,
        "figures": files,
        "timings_s": timings.as_dict(),
    }
    (out / "result.json").write_text(json.dumps(summary, indent=1))
    summary["table"] = report.table5(joints, ranges, n_tests=result.n_tests)
    return summary
