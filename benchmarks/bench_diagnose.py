"""`vtestbed diagnose` speed on the worked example (target: at most 10 s on one core, cloud fits included).

Simulates scenarios/kr60_hidden_link.toml once (20 tests + 5 validation tests, 3 repeat scans each)
into a temporary folder, then times the whole diagnosis: reading and fitting the 150 clouds, the
noise floor, every candidate's fits over the forward rounds, the report and its figures. Prints
wall and CPU time (the process runs on one core: BLAS and open3d are single-threaded here).
``--loaded-repeats R`` scans the loaded block R more times per test too (25 R more clouds).

    .venv/bin/python benchmarks/bench_diagnose.py [--loaded-repeats 3]
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from vtestbed.experiment import simulate  # noqa: E402
from vtestbed.researcher.discrepancy import diagnose  # noqa: E402
from vtestbed.scenario import load_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--loaded-repeats", type=int, default=0, help="repeat scans of the loaded block per test"
    )
    args = parser.parse_args()
    scenario = load_scenario(ROOT / "scenarios" / "kr60_hidden_link.toml")
    scanner = dataclasses.replace(scenario.scanner, loaded_repeats=args.loaded_repeats)
    scenario = dataclasses.replace(scenario, scanner=scanner)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "dataset"
        simulate(scenario, data)
        clouds = sum(1 for _ in (data / "clouds").iterdir())
        print(f"{clouds} clouds ({args.loaded_repeats} loaded repeats per test)")
        for statics in ("exact", "paper"):
            w0, c0 = time.perf_counter(), time.process_time()
            report = diagnose(data, out=Path(tmp) / f"diag_{statics}", statics=statics)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            print(
                f"diagnose ({statics} statics): {wall:.2f} s wall, {cpu:.2f} s CPU; named {report['named']}"
            )


if __name__ == "__main__":
    main()
