"""Run a scenario: the world writes a dataset, the researcher's code identifies from it.

The orchestrator of one scenario, and one of the few modules that may touch both sides:
``simulate`` drives the truth world (:mod:`vtestbed.world`: rig, scanner, F/T sensor, one test's
physics in :mod:`vtestbed.world.physics`) and writes a lab-compatible dataset plus a separate
``truth.json``. ``identify_dataset`` (:mod:`vtestbed.dataset_identification`, imported here for
``run`` and its callers) is the researcher's job on any dataset, and ``run`` does both, then
compares with the truth (:mod:`vtestbed.comparison`) only after identification.

Reproducibility: test ``i`` of group ``g`` draws from ``SeedSequence(seed, spawn_key=(g, i))``,
so a test's numbers do not depend on which other tests ran before it, and a resumed run gives
the same dataset as an uninterrupted one. Repeat scans (``[scanner] repeats``) draw from a
separate stream (:func:`vtestbed.world.repeats.repeat_rng`), so they change no other number.
"""

from __future__ import annotations

import math
import time
from contextlib import ExitStack, closing
from pathlib import Path

import numpy as np

from . import comparison, ply
from .dataset import CLOUD_DIR, TRUTH_FILE, DatasetSetup, TestRecord, TestWriter, write_setup
from .dataset_identification import identify_dataset
from .dataset_repeats import LoadedRepeatWriter, RepeatRecord, RepeatWriter, repeat_cloud_path
from .errors import (
    DatasetError,
    OutOfRangeError,
    ScanError,
    ScenarioError,
    SensorOverloadError,
    VtestbedError,
)
from .experiment_resume import check_finished, lost_clouds, start_truth
from .files import folder_lock, write_json_atomic
from .lab import MIN_TENSION_N, LabSetup
from .output_folders import RUN, require_own_kind
from .researcher import report
from .run_record import Timings, versions
from .scenario import Scenario, load_field, pose_field
from .truth_file import TruthFile
from .world.effects import check_effects
from .world.physics import draw_readings, run_test_physics, test_rng
from .world.physics_pool import physics_in_order
from .world.repeats import draw_repeat_scans, loaded_repeat_geometries, loaded_repeat_rng, repeat_rng
from .world.rig import Rig
from .world.sensors import ForceTorqueSensor
from .world.truth import load_truth

__all__ = ["Timings", "dataset_setup", "identify_dataset", "run", "simulate", "test_id"]


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
        sensor_mount_mass=lab.sensor.mass_mount_side,
        sensor_mount_com=tuple(float(v) for v in lab.sensor.mount_side_com_in_flange),
        sensor_noise_std=tuple(float(v) for v in scenario.force_sensor.noise_std),
        target=None if lab.block.mesh is None else lab.block.mesh.setup_json(),
    )


def test_id(group: str, index: int) -> str:
    """``T001``, ``T002``, ... for identification tests, ``V001``, ... for validation tests."""
    return f"{'T' if group == 'identification' else 'V'}{index + 1:03d}"


test_id.__test__ = False  # a naming helper, not a pytest test


def check_world_effects(scenario: Scenario) -> None:
    """Each hidden effect against the robot and its true stiffness (a coupling that would make the
    stiffness matrix indefinite, a joint the robot lacks), as the rig checks them, with the
    scenario file's name (the scenario reader does not read the truth)."""
    if all(e.is_null for e in scenario.effects):
        return
    try:
        check_effects(scenario.effects, scenario.robot, load_truth(scenario.robot_name))
    except VtestbedError as exc:
        where = f"{scenario.source}: " if scenario.source else ""
        raise ScenarioError(f"{where}{exc}") from None


def _scenario_physics(scenario: Scenario, rig: Rig, jobs: list):
    """The truth-world physics of ``jobs`` (group, index, pose, load), in order, on a few threads
    (:mod:`vtestbed.world.physics_pool`); yields (TestPhysics, Timings of that test)."""
    spare_rigs = [rig]  # the first thread takes this one (list.pop is atomic), the others build theirs

    def make_rig() -> Rig:
        if spare_rigs:
            return spare_rigs.pop()
        return Rig(scenario.robot, scenario.lab, truth=rig.truth, effects=scenario.effects)

    def run(thread_rig: Rig, job):
        group, i, q, load = job
        test_timings = Timings()
        try:
            phys = run_test_physics(
                thread_rig, q, load.hooks[i], load.anchors[i], load.tensions[i], scenario.scanner.distance,
                scenario.scanner.placement, test_timings, clearance="report",
            )  # fmt: skip
        except (ScanError, SensorOverloadError) as exc:
            raise test_error(scenario, group, i, exc) from None
        except OutOfRangeError as exc:  # the world's springs at this test's pose and load (rig._equilibrium)
            where = f"{scenario.source}: " if scenario.source else ""
            raise OutOfRangeError(
                f"{where}{pose_field(group, i)} (test {test_id(group, i)}): {exc}"
            ) from None
        return phys, test_timings

    return physics_in_order(make_rig, run, jobs)


def test_error(scenario: Scenario, group: str, index: int, exc: ScanError | SensorOverloadError):
    """The world's refusal of one test, said in the scenario file's terms: the file, the field to
    change, the test's id and (an overloaded sensor) the valid tension range for that test.

    A scan that fails names the test's pose and ``scanner.distance_m`` (the stand-off is checked
    for every pose when the scenario is read, :meth:`LabSetup.check_scanner_distance`; what is left
    depends on the pose: the field of view, the scanner above the floor, the faces in sight).
    """
    where = f"{scenario.source}: " if scenario.source else ""
    tid = test_id(group, index)
    if isinstance(exc, ScanError):
        distance = f"scanner.distance_m = {scenario.scanner.distance:g} m"
        return ScanError(f"{where}{pose_field(group, index)} (test {tid}, {distance}): {exc}")
    field_name = load_field(group, index, "tension_N", scenario.raw)
    low, (high, _) = MIN_TENSION_N, scenario.lab.max_tension
    if exc.max_tension is None:
        valid = f"the {scenario.lab.sensor.name}'s range is exceeded"
    elif min(exc.max_tension, high) >= low:
        top = math.floor(min(exc.max_tension, high) * 10) / 10
        valid = (f"valid for this test: [{low:g}, {top:g}] N (the largest tension whose wrench the sensor "
                 "measures at this pose, hook and anchor)")  # fmt: skip
    else:
        valid = ("no tension is valid for this test: the sensor's range is exceeded without the wire "
                 "(choose another pose, or a sensor of a wider lab.force_sensor.range_N_Nm)")  # fmt: skip
    return SensorOverloadError(f"{where}{field_name} (test {tid}): {exc}; {valid}")


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

    With ``scenario.scanner.repeats = r > 0``, every test (identification and validation) also
    gets ``r`` repeat scans of its unloaded block (``clouds/<id>_repeatK.ply`` and rows of
    ``repeats.csv``), written before the test's tests.csv row, which marks the test finished;
    ``truth.json`` records ``"repeats": r``. setup.json and tests.csv do not depend on ``r``.
    ``scenario.scanner.loaded_repeats = r' > 0`` adds ``r'`` scans of the loaded block
    (``clouds/<id>_loaded_repeatK.ply``, ``loaded_repeats.csv``), written the same way.
    """
    out = Path(out)
    timings = timings or Timings()
    lab = scenario.lab
    check_world_effects(scenario)  # before the folder is made: a refused world writes nothing
    out.mkdir(parents=True, exist_ok=True)
    with folder_lock(out, "dataset folder", DatasetError):  # one writer at a time
        rig = Rig(scenario.robot, lab, truth=load_truth(scenario.robot_name), effects=scenario.effects)
        truth = start_truth(out, scenario, rig, replace_stale)  # refuses another command's folder
        repeats, loaded_repeats = scenario.scanner.repeats, scenario.scanner.loaded_repeats
        truth["repeats"] = repeats
        if loaded_repeats:  # absent otherwise: the truth of every other dataset stays as it was
            truth["loaded_repeats"] = loaded_repeats
        jobs = [("identification", i, q, scenario.load) for i, q in enumerate(scenario.poses)]
        jobs += [
            ("validation", i, q, scenario.validation_load) for i, q in enumerate(scenario.validation_poses)
        ]
        check_finished(out, truth, [test_id(g, i) for g, i, _, _ in jobs])  # before writing anything
        truth_file = TruthFile(out / TRUTH_FILE, truth)
        truth_file.write()  # first: it marks the folder as a simulation's (experiment_resume)
        write_setup(out, dataset_setup(scenario, lab))
        noise = scenario.scanner.noise_model
        sensor = ForceTorqueSensor(lab.sensor, scenario.force_sensor.noise_std, scenario.force_sensor.bias)
        bar = None
        if progress:
            from tqdm import tqdm

            bar = tqdm(total=len(jobs), desc="simulate", unit="test")
        with ExitStack() as stack:
            writer = stack.enter_context(TestWriter(out))
            repeat_writer = stack.enter_context(RepeatWriter(out)) if repeats else None
            loaded_writer = stack.enter_context(LoadedRepeatWriter(out)) if loaded_repeats else None
            todos = {
                test_id(g, i): _repeats_to_do(repeat_writer, test_id(g, i), repeats) for g, i, _, _ in jobs
            }
            loaded_todos = {
                test_id(g, i): _repeats_to_do(loaded_writer, test_id(g, i), loaded_repeats)
                for g, i, _, _ in jobs
            }
            lost = lost_clouds(out, writer.done)  # redone from the test's own stream, byte for byte
            needed = [job for job in jobs if test_id(*job[:2]) not in writer.done or todos[test_id(*job[:2])]
                      or loaded_todos[test_id(*job[:2])] or test_id(*job[:2]) in lost]  # fmt: skip

            computed = stack.enter_context(closing(_scenario_physics(scenario, rig, needed)))
            for group, i, q, load in jobs:
                tid = test_id(group, i)
                todo = todos[tid]
                if tid not in writer.done or todo or loaded_todos[tid] or tid in lost:
                    phys, test_timings = next(computed)
                    timings.physics += test_timings.physics  # summed over threads that overlap
                    timings.scan += test_timings.scan
                    if phys.clearance is not None:
                        phys.clearance.enforce(pose_field(group, i), "warn")
                # before the test's row: a resumed run finds the test finished only with them
                if todo:
                    rng = repeat_rng(scenario.seed, group, i)
                    _write_repeats(
                        out, repeat_writer, tid, todo, phys.hits_unloaded, rng, repeats, scenario, timings
                    )
                if loaded_todos[tid]:  # the loaded block scanned again, from its own stream
                    rng = loaded_repeat_rng(scenario.seed, group, i)
                    moved = loaded_repeat_geometries(  # a creeping block moves on between its scans
                        phys.hits_loaded, phys.loaded_block_in_scanner,
                        phys.displacement_true, scenario.effects, loaded_repeats,
                    )  # fmt: skip
                    _write_repeats(out, loaded_writer, tid, loaded_todos[tid], phys.hits_loaded, rng,
                                   loaded_repeats, scenario, timings, "loaded", moved)  # fmt: skip
                if tid not in writer.done or tid in lost:
                    rng = test_rng(scenario.seed, group, i)
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
                        scenario.effects,
                    )
                    t4 = time.perf_counter()
                    timings.scan += t4 - t3
                    paths = (
                        out / CLOUD_DIR / f"{tid}_unloaded.ply",
                        out / CLOUD_DIR / f"{tid}_loaded.ply",
                    )
                    if tid in lost:  # a finished test: only its lost clouds are written again
                        for path, cloud in zip(paths, (cloud0, cloud1)):
                            if path in lost[tid]:
                                ply.write_ply(path, cloud)
                        timings.write += time.perf_counter() - t4
                        if bar:
                            bar.update()
                        continue
                    ply.write_ply(paths[0], cloud0)
                    ply.write_ply(paths[1], cloud1)
                    truth_file.add(tid, {
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
                    })  # fmt: skip
                    # the row is written last: it marks the test as finished
                    writer.append(TestRecord(tid, group, np.degrees(q), w0, w1, scanner.pose_world, *paths))
                    t5 = time.perf_counter()
                    timings.write += t5 - t4
                if bar:
                    bar.update()
        if bar:
            bar.close()
    return out


def _write_repeats(
    out: Path,
    writer,
    tid: str,
    todo: list[int],
    hits,
    rng,
    repeats: int,
    scenario: Scenario,
    timings: Timings,
    state: str = "unloaded",
    geometries=None,
) -> None:
    """Draw all ``repeats`` repeat scans of test ``tid``'s ``state`` block from its ``hits`` (per
    repeat from ``geometries`` when the block moves between scans) with ``rng`` (consumed in order,
    so repeat k is the same on a resume) and write those numbered in ``todo`` (1, 2, ...), each
    recorded in ``writer``'s file."""
    t0 = time.perf_counter()
    clouds = draw_repeat_scans(hits, scenario.scanner.noise_model, rng, repeats, scenario.effects, geometries)
    t1 = time.perf_counter()
    timings.scan += t1 - t0
    for k in todo:
        path = ply.write_ply(repeat_cloud_path(out, tid, k, state), clouds[k - 1])
        writer.append(RepeatRecord(tid, k, path))
    timings.write += time.perf_counter() - t1


def _repeats_to_do(writer, tid: str, repeats: int) -> list[int]:
    """The repeat numbers 1..``repeats`` of test ``tid`` that ``writer``'s file does not hold yet."""
    return [k for k in range(1, repeats + 1) if (tid, k) not in writer.done] if repeats else []


def run(
    scenario: Scenario,
    out: str | Path,
    progress: bool = False,
    figures: bool = True,
    replace_stale: bool = False,
    strict: bool = False,
) -> dict:
    """simulate + identify + compare; writes ``out/result.json`` and figures; returns the result."""
    out = Path(out)
    timings = Timings()
    require_own_kind(out, (RUN,), "vtestbed run", DatasetError)  # its report.html is not a sweep's
    simulate(scenario, out / "dataset", progress=progress, timings=timings, replace_stale=replace_stale)
    setup, measurements, result = identify_dataset(
        out / "dataset", scenario.method, progress, timings, strict=strict, reference=scenario.reference
    )
    t0 = time.perf_counter()
    truth = comparison.read_truth(out / "dataset", dof=len(result.joint_names))
    joints = comparison.compare(result, truth)
    k_true = np.array([j["k_true"] for j in joints])
    conv = report.convergence(measurements, scenario.method, result.joint_names, result.displacement_cov)
    ranges = comparison.error_ranges(conv, k_true)
    val = report.validation(measurements, result.stiffness)
    files = {}
    if figures:
        files["convergence"] = str(
            report.plot_convergence(conv, result.joint_names, out / "convergence.png", reference=k_true)
        )
        if val:
            files["validation"] = str(report.plot_validation(val, out / "validation.png"))
    timings.report += time.perf_counter() - t0
    summary = {
        "scenario": scenario.name,
        "seed": scenario.seed,
        "n_tests": result.n_tests,
        "method": result.method,
        "reference": scenario.reference,
        "joints": joints,
        "table5": {"first_n": comparison.PAPER_FIRST_N, **ranges},
        "identification": result.as_dict(),
        "convergence": conv,
        "validation": val,
        "figures": files,
        "timings_s": timings.as_dict(),
        "versions": versions(),
    }
    write_json_atomic(out / "result.json", summary)
    summary["table"] = comparison.table5(joints, ranges, n_tests=result.n_tests)
    return summary
