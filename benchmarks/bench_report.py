"""Size and load time of the demo's report in headless Chromium, against the targets.

Targets: the page at most 10 MB; loaded (readable, every static figure shown) in under 2 s. The
3-D view is drawn when it scrolls into view (it needs a WebGL context and plotly.js, slow without
a GPU): its time is printed too, from scrolling to it until it is drawn.

Run: .venv/bin/python benchmarks/bench_report.py [--dir runs/demo] [--repeats 3]
(without --dir, or if the folder has no result.json, the demo is run into a temporary folder).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SIZE_TARGET_MB = 10.0
LOAD_TARGET_S = 2.0


def measure(folder: Path, repeats: int) -> None:
    from vtestbed.reports import write_report
    from vtestbed.reports.browser import block_network, chromium, draw_3d, open_report

    t0 = time.perf_counter()
    page_path = write_report(folder)
    write_s = time.perf_counter() - t0
    size_mb = page_path.stat().st_size / 1e6
    loads, draws = [], []
    with chromium() as context:
        block_network(context)  # offline, as a reader of the file would open it
        for _ in range(repeats + 1):  # the first load warms Chromium's caches up; not counted
            page, errors, load_s = open_report(context, page_path)
            draw_s = draw_3d(page)
            if errors:
                raise SystemExit(f"console errors: {errors}")
            loads.append(load_s)
            draws.append(draw_s)
            page.close()
    load, draw = float(np.median(loads[1:])), float(np.median(draws[1:]))
    print(f"report of {folder}: written in {write_s:.1f} s")
    print(f"size        {size_mb:6.2f} MB   (target <= {SIZE_TARGET_MB:g} MB)  {'ok' if size_mb <= SIZE_TARGET_MB else 'OVER'}")  # fmt: skip
    print(f"load time   {load:6.2f} s    (target < {LOAD_TARGET_S:g} s)   {'ok' if load < LOAD_TARGET_S else 'OVER'}"
          f"   median of {repeats}, file:// to the page's ready mark")  # fmt: skip
    print(f"3-D drawn   {draw:6.2f} s    after scrolling to it (plotly.js evaluated, WebGL without GPU)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--dir", type=Path, help="a run folder (default: run the demo into a temporary folder)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="loads measured (median shown; default 3)")
    args = parser.parse_args()
    if args.dir is not None and (args.dir / "result.json").is_file():
        measure(args.dir, args.repeats)
        return
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "vtestbed", "demo", "--out", tmp, "--quiet"]
        subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
        measure(Path(tmp), args.repeats)


if __name__ == "__main__":
    main()
