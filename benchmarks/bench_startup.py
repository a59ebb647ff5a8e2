"""Start-up: import time and resident memory of the main modules, and of a campaign worker doing
a trial, next to the targets.

Run: .venv/bin/python benchmarks/bench_startup.py [--repeats 5] [--demo]

Every figure is measured in a fresh interpreter (``sys.executable``), the median of
``--repeats`` runs; the machine's load average is printed beside them because other users only
ever slow a start-up down. Memory is resident memory after the import (/proc/self/statm) and
the process's own peak (VmHWM, :func:`vtestbed.campaigns.worker.peak_rss_mib`; ``getrusage``'s
``ru_maxrss`` would include the parent's resident size, which Linux carries over fork and exec).

The worker figure is a real worker's life: unpickle a task of the quick campaign's base scenario
(20 tests, as the paper campaign's largest test lists), import what that needs, prepare the
physics of the 20 tests (equilibria, ray casts), run two trials of 20 tests. Targets: worker
peak at most 250 MiB; ``vtestbed demo`` at most 4 s wall on a quiet machine (``--demo`` times it
too, from scratch each time: it writes runs/bench_demo_<k>).
"""

from __future__ import annotations

import argparse
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_WORKER_PEAK_MIB = 250.0
TARGET_DEMO_S = 4.0
MODULES = [
    "vtestbed",
    "vtestbed.cli.main",
    "vtestbed.ply",
    "vtestbed._open3d",
    "vtestbed.researcher",
    "vtestbed.campaigns.worker",
    "vtestbed.campaigns.runner",
    "vtestbed.experiment",
]
IMPORT_PROBE = """
import sys, time
t0 = time.perf_counter()
import {module}
wall = time.perf_counter() - t0
rss = int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
peak = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM:")) / 1024  # own peak
print(wall, rss, peak, len(sys.modules))
"""
WORKER_PROBE = """
import json, pickle, resource, sys, time
t0 = time.perf_counter()
with open(sys.argv[1], "rb") as fh:
    batch = pickle.load(fh)
from vtestbed.campaigns.worker import run_batch
t_import = time.perf_counter() - t0
rss_import = int(open("/proc/self/statm").read().split()[1]) * 4096 / 2**20
result = run_batch(batch)
from vtestbed.campaigns import worker
held = sum(p.nbytes for p in worker._CACHE.values()) / 2**20
heavy = [m for m in ("pandas", "pyarrow", "matplotlib", "dash", "plotly", "open3d", "scipy.stats") if m in sys.modules]
print(json.dumps({"import_s": t_import, "rss_import": rss_import, "prepare_s": result.prepare_s,
                  "trial_s": result.compute_s / len(batch.trials), "peak": result.peak_rss_mib, "held": held, "heavy": heavy}))
"""


def _env() -> dict:
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, "1")  # as the sweep's workers run
    return env


def import_figures(module: str, repeats: int) -> tuple[float, float, float, int]:
    """Median import wall [s], resident [MiB], peak [MiB] and module count of a fresh interpreter."""
    rows = []
    for _ in range(repeats):
        out = subprocess.run([sys.executable, "-c", IMPORT_PROBE.format(module=module)], capture_output=True,
                             text=True, check=True, env=_env())  # fmt: skip
        rows.append([float(v) for v in out.stdout.split()])
    wall, rss, peak, count = np.median(np.array(rows), axis=0)
    return float(wall), float(rss), float(peak), int(count)


def worker_batch(path: Path, trials: int = 2):
    """A task of the quick campaign's base scenario: 20 tests, ``trials`` trials of 20 tests."""
    from vtestbed.campaigns.spec import parse_campaign
    from vtestbed.campaigns.worker import Batch

    data = tomllib.loads((ROOT / "scenarios" / "kr60_sweep_quick.toml").read_text())
    data["campaign"] = {"trials": trials, "seed": 1, "axes": {"n_tests": [20]}}
    c = parse_campaign(data, "bench")
    cell = next(iter(c.cells()))
    seeds = tuple(c.trial_seed(cell, t) for t in range(trials))
    batch = Batch(
        c.scenario, "bench", cell, c.scan_noise(cell), c.ft_noise_std(cell), tuple(range(trials)), seeds
    )
    path.write_bytes(pickle.dumps(batch))


def worker_figures(repeats: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        task = Path(tmp) / "batch.pkl"
        worker_batch(task)
        runs = []
        for _ in range(repeats):
            out = subprocess.run([sys.executable, "-c", WORKER_PROBE, str(task)], capture_output=True, text=True,
                                 check=True, env=_env())  # fmt: skip
            runs.append(json.loads(out.stdout.splitlines()[-1]))
    keys = ("import_s", "rss_import", "prepare_s", "trial_s", "peak", "held")
    return {k: float(np.median([r[k] for r in runs])) for k in keys} | {"heavy": runs[-1]["heavy"]}


def demo_wall(repeats: int) -> float:
    exe = Path(sys.executable).with_name("vtestbed")
    walls = []
    for k in range(repeats):
        out = ROOT / "runs" / f"bench_demo_{k}"
        shutil.rmtree(out, ignore_errors=True)  # a finished dataset would be resumed, not simulated
        t0 = time.perf_counter()
        subprocess.run([str(exe), "demo", "--out", str(out), "--quiet"], check=True,
                       capture_output=True, env=_env())  # fmt: skip
        walls.append(time.perf_counter() - t0)
    return float(np.median(walls))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--demo", action="store_true", help="also time `vtestbed demo` (median of 3)")
    args = ap.parse_args()
    print(
        f"load average before: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs; medians of {args.repeats}"
    )
    print(f"{'import':28s} {'wall [s]':>9s} {'RSS [MiB]':>10s} {'peak [MiB]':>11s} {'modules':>8s}")
    for module in MODULES:
        wall, rss, peak, count = import_figures(module, args.repeats)
        print(f"{module:28s} {wall:9.2f} {rss:10.0f} {peak:11.0f} {count:8d}")
    w = worker_figures(max(1, args.repeats // 2))
    print("\ncampaign worker (unpickle a task, import, prepare 20 tests, 2 trials of 20 tests):")
    print(f"  import {w['import_s']:.2f} s, {w['rss_import']:.0f} MiB; prepare {w['prepare_s']:.2f} s; "
          f"trial {w['trial_s']:.2f} s; prepared physics held {w['held']:.0f} MiB")  # fmt: skip
    verdict = "meets" if w["peak"] <= TARGET_WORKER_PEAK_MIB else "misses"
    print(f"  peak resident {w['peak']:.0f} MiB   target <= {TARGET_WORKER_PEAK_MIB:.0f} MiB: {verdict}")
    print(f"  heavy modules loaded: {', '.join(w['heavy']) or 'none'}")
    if args.demo:
        wall = demo_wall(3)
        verdict = "meets" if wall <= TARGET_DEMO_S else "misses"
        print(
            f"\nvtestbed demo: {wall:.2f} s wall (median of 3)   target <= {TARGET_DEMO_S:.0f} s: {verdict}"
        )
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
