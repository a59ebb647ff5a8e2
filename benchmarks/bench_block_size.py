"""The block's size as a scale reference: the scale check on simulated datasets, per world.

Run: .venv/bin/python benchmarks/bench_block_size.py [--seeds 50] [--workers 1] [--worlds W,W,...]
     [--scenario FILE] [--out /tmp/bench_block_size]

The defaults are the table of docs/discrepancy.md ("The scanner's scale, measured on the block"):
50 seeds of the worlds clean, scale:100, scale:1000, scale:1500, scale:6080, scale:9610 and
block_offset:1, about 13 min on one core.

Each seed simulates ``scenarios/kr60_confusable.toml``'s 25 tests (the paper's 20 and the 5
validation tests; no repeat scans, which the check does not read; ``--scenario`` another file's,
e.g. ``scenarios/kr60_paper_a6a1.toml``, whose poses differ) in a world with one hidden
effect, reduces every scan with the researcher's code (``load_measurements(..., edges=True)``) and
runs :func:`vtestbed.researcher.block_size.scale_check` at alpha 0.01 with the default tolerance.
A world is ``clean``, ``scale:PPM`` (``scanner_scale`` at that scale) or ``NAME:F`` (effect NAME at
F times its realistic size). Per world it prints the measured scale's mean and spread over the
seeds, the mean standard error the check reports, the z-score spread of the measured scale against
the truth less the mean bias of the clean world (1 when the reported error is honest), and how
often the check finds the scale beyond the tolerance. Datasets go to ``--out/<world>-s<seed>`` and
are deleted after use.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import shutil
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from bench_discriminate import scenario_for as discriminate_scenario  # benchmarks/ is on sys.path

from vtestbed.experiment import simulate
from vtestbed.researcher.block_size import SCALE_TOLERANCE_PPM, scale_check
from vtestbed.researcher.measure import load_measurements

ROOT = Path(__file__).resolve().parents[1]
SCENARIO = ROOT / "scenarios" / "kr60_confusable.toml"
ALPHA = 0.01


def scenario_for(world: str, seed: int, path: Path = SCENARIO):
    """The scenario with ``world`` hidden (see the module docstring) and ``seed``; no repeat scans.
    ``scale:PPM`` is ``scanner_scale`` at PPM / 100 times its realistic 100 ppm."""
    name, _, size = world.partition(":")
    if world == "clean":
        sc = discriminate_scenario(str(path), seed, 0)
    else:
        effect, factor = ("scanner_scale", float(size) / 100.0) if name == "scale" else (name, float(size))
        sc = discriminate_scenario(str(path), seed, factor, (effect,))
    return dataclasses.replace(sc, scanner=dataclasses.replace(sc.scanner, repeats=0))


def true_scale_ppm(world: str) -> float:
    return float(world.split(":")[1]) if world.startswith("scale:") else 0.0


def run_seed(world: str, seed: int, out: str, path: Path = SCENARIO) -> dict:
    folder = Path(out) / f"{world.replace(':', '_')}-s{seed}"
    t0 = time.perf_counter()
    try:
        simulate(scenario_for(world, seed, path), folder)
        setup, tests = load_measurements(folder, edges=True)
        check = scale_check([t.edge_lengths for t in tests], setup.block_edge, ALPHA)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return {"world": world, "seed": seed, **check.to_dict(), "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument(
        "--worlds", default="clean,scale:100,scale:1000,scale:1500,scale:6080,scale:9610,block_offset:1"
    )
    ap.add_argument("--scenario", type=Path, default=SCENARIO)
    ap.add_argument("--out", default="/tmp/bench_block_size")
    args = ap.parse_args()
    worlds = [w.strip() for w in args.worlds.split(",") if w.strip()]
    with ProcessPoolExecutor(args.workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [
            (w, pool.submit(run_seed, w, s, args.out, args.scenario))
            for w in worlds
            for s in range(1, args.seeds + 1)
        ]
        rows = []
        for _, future in futures:
            rows.append(future.result())
            print(json.dumps(rows[-1], default=float), flush=True)
    clean = [r["scale_ppm"] for r in rows if r["world"] == "clean"]
    bias = float(np.mean(clean)) if clean else 0.0
    print(f"\n{args.scenario.name}, {args.seeds} seeds per world, alpha {ALPHA}, tolerance {SCALE_TOLERANCE_PPM:g} ppm; "
          f"bias = the clean world's mean, {bias:+.1f} ppm")  # fmt: skip
    print("| world | true scale [ppm] | measured: mean | spread (std over seeds) | reported std (mean) "
          "| z-score std (truth + bias) | beyond the tolerance |")  # fmt: skip
    print("| --- | ---: | ---: | ---: | ---: | ---: | ---: |")
    for world in worlds:
        mine = [r for r in rows if r["world"] == world]
        s = np.array([r["scale_ppm"] for r in mine])
        se = np.array([r["std_ppm"] for r in mine])
        z = (s - true_scale_ppm(world) - bias) / se
        beyond = sum(r["beyond"] for r in mine)
        print(f"| {world} | {true_scale_ppm(world):g} | {s.mean():+.1f} | {s.std(ddof=1):.1f} | {se.mean():.1f} "
              f"| {z.std(ddof=1):.2f} | {beyond} of {len(mine)} |")  # fmt: skip
    print(f"wall per seed: {np.mean([r['wall_s'] for r in rows]):.1f} s")


if __name__ == "__main__":
    main()
