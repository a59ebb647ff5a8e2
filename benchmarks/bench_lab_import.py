"""`vtestbed dataset import`: time and peak memory of importing a lab's files.

Simulates the paper's experiment (scenarios/kr60_paper.toml: 20 identification and 5 validation
tests) with ``--repeats`` repeat scans of the unloaded and of the loaded block per test, writes
it out as a lab would hand it over (every cloud a PLY in metres, every F/T reading a 2 s stream
at 500 Hz with the sensor's noise, a manifest listing them), then imports it with
:func:`vtestbed.lab_import.import_dataset` under ``tracemalloc``. Printed: the clouds' total size
as float64 arrays (what an import holding every cloud until the end needs at least), the largest
cloud, the import's peak of Python-allocated memory (numpy's arrays included) and its wall time.

    .venv/bin/python benchmarks/bench_lab_import.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import tempfile
import time
import tracemalloc
from pathlib import Path

import numpy as np

from vtestbed.dataset import read_tests
from vtestbed.dataset_repeats import read_repeats
from vtestbed.experiment import simulate
from vtestbed.lab_import import import_dataset
from vtestbed.ply import read_ply
from vtestbed.scenario import load_scenario
from vtestbed.transforms import rotation_vector
from vtestbed.world.sensors import DEFAULT_NOISE_STD

ROOT = Path(__file__).resolve().parents[1]
FS_HZ, DURATION_S, WINDOW_S = 500.0, 2.0, (0.5, 1.5)


def write_lab(sim: Path, lab: Path, rng: np.random.Generator) -> Path:
    """The simulated dataset as a lab's files (PLY clouds in m, CSV streams in N and N*m)."""
    (lab / "ft").mkdir(parents=True)
    (lab / "scans").mkdir()
    shutil.copy(sim / "setup.json", lab / "setup.json")
    t = np.arange(int(DURATION_S * FS_HZ) + 1) / FS_HZ
    header = "time_s,Fx_N,Fy_N,Fz_N,Tx_Nm,Ty_Nm,Tz_Nm"
    repeats = {s: read_repeats(sim, state=s) for s in ("unloaded", "loaded")}
    entries = []
    for r in read_tests(sim):
        lines = [f'[[tests]]\nid = "{r.test_id}"\ngroup = "{r.group}"\nq_deg = {json.dumps(r.q_deg.tolist())}',
                 f"scanner_position_m = {json.dumps(r.scanner_pose[:3, 3].tolist())}",
                 f"scanner_rotvec_rad = {json.dumps(rotation_vector(r.scanner_pose[:3, :3]).tolist())}"]  # fmt: skip
        for state, reading, cloud in (
            ("unloaded", r.wrench_unloaded, r.cloud_unloaded),
            ("loaded", r.wrench_loaded, r.cloud_loaded),
        ):
            wrench = reading + rng.normal(0.0, 1.0, (t.size, 6)) * np.asarray(DEFAULT_NOISE_STD)
            np.savetxt(lab / "ft" / f"{r.test_id}_{state}.csv", np.column_stack([t, wrench]), fmt="%.17g",
                       delimiter=",", header=header, comments="")  # fmt: skip
            shutil.copy(cloud, lab / "scans" / Path(cloud).name)
            lines += [
                f'ft_{state} = "ft/{r.test_id}_{state}.csv"',
                f'cloud_{state} = "scans/{Path(cloud).name}"',
            ]
            names = []
            for rep in (x for x in repeats[state] if x.test_id == r.test_id):
                names.append(f"scans/{Path(rep.cloud).name}")
                shutil.copy(rep.cloud, lab / names[-1])
            if names:
                lines.append(f"{'' if state == 'unloaded' else 'loaded_'}repeat_clouds = {json.dumps(names)}")
        entries.append("\n".join(lines))
    manifest = lab / "manifest.toml"
    head = f'setup = "setup.json"\n\n[units]\ncloud = "m"\n\n[ft]\nwindow_s = {list(WINDOW_S)}\n\n'
    manifest.write_text(head + "\n\n".join(entries) + "\n")
    return manifest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="repeat scans of each block per test")
    args = parser.parse_args()
    scenario = load_scenario(ROOT / "scenarios" / "kr60_paper.toml")
    scanner = dataclasses.replace(scenario.scanner, repeats=args.repeats, loaded_repeats=args.repeats)
    with tempfile.TemporaryDirectory() as tmp:
        sim = simulate(dataclasses.replace(scenario, scanner=scanner), Path(tmp) / "sim")
        manifest = write_lab(sim, Path(tmp) / "lab", np.random.default_rng(1))
        sizes = [read_ply(p).nbytes for p in sorted((Path(tmp) / "lab" / "scans").iterdir())]
        tracemalloc.start()
        t0 = time.perf_counter()
        result = import_dataset(manifest, Path(tmp) / "imported")
        wall = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    mb = 1 / 2**20
    print(f"# bench_lab_import: kr60_paper.toml, {len(result.records)} tests, {args.repeats} repeat scans of "
          f"each block per test: {len(sizes)} clouds")  # fmt: skip
    print(f"clouds as float64 arrays: {sum(sizes) * mb:.1f} MB in all, the largest {max(sizes) * mb:.2f} MB")
    print(f"import: peak {peak * mb:.1f} MB allocated (tracemalloc), {wall:.1f} s wall")


if __name__ == "__main__":
    main()
