"""Wall time of `vtestbed run scenarios/kr60_paper.toml` and where it goes.

Run: .venv/bin/python benchmarks/bench_run.py
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run(
            [
                sys.executable,
                "-m",
                "vtestbed",
                "run",
                str(ROOT / "scenarios" / "kr60_paper.toml"),
                "--out",
                tmp,
                "--quiet",
            ],
            check=True,
            stdout=subprocess.DEVNULL,
        )
        wall = time.perf_counter() - t0
        result = json.loads((Path(tmp) / "result.json").read_text())
    t = result["timings_s"]
    n = result["n_tests"] + len(result["validation"])
    print(f"vtestbed run scenarios/kr60_paper.toml: {wall:.2f} s wall ({n} tests, 2 scans each)")
    labels = {
        "physics": "static equilibria + tightening (MuJoCo)",
        "scan": "scanner placement, ray casting (mj_multiRay) and noise",
        "write": "PLY files and dataset rows",
        "process": "reading PLYs and fitting block frames (nominal segmentation + SVD; open3d RANSAC as fallback)",
        "identify": "stacked least squares",
        "report": "convergence study (n = 1..N), validation, figures",
    }
    for key, label in labels.items():
        print(f"  {key:9s}{t[key]:7.2f} s  {label}")
    rest = wall - sum(t[k] for k in labels)
    print(
        f"  {'other':9s}{rest:7.2f} s  interpreter start, imports (open3d, mujoco, pinocchio), model compile"
    )


if __name__ == "__main__":
    main()
