"""Campaign workers: a real worker process imports only what a trial needs and computes the same
row as the in-process Monte Carlo trial; a ``kill -9`` of ``vtestbed sweep`` leaves no worker or
resource tracker behind."""

from __future__ import annotations

import dataclasses
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from quick_campaign import BASE_TEXT, tiny

from vtestbed.campaigns import montecarlo
from vtestbed.campaigns.store import TRIALS_DIR
from vtestbed.campaigns.worker import Batch
from vtestbed.scenario import LoadPlan
from vtestbed.world.sensors import ForceTorqueSensor

# What a worker must not load: the parent's bookkeeping and reports, open3d's plotting
HEAVY = ("pandas", "pyarrow", "matplotlib", "dash", "plotly", "dask", "distributed", "tqdm")

WORKER_SCRIPT = """
import json, pickle, sys
with open(sys.argv[1], "rb") as fh:
    batch = pickle.load(fh)  # imports what unpickling a task imports, as a pool worker does
from vtestbed.campaigns.worker import run_batch
result = run_batch(batch)
print(json.dumps({"modules": sorted(sys.modules), "row": result.rows[0], "peak": result.peak_rss_mib}))
"""


def test_a_worker_process_loads_no_reporting_libraries_and_computes_the_trial(tmp_path):
    c = tiny(axes={"n_tests": [3]})
    cell = next(iter(c.cells()))
    load = c.scenario.load
    three = dataclasses.replace(  # the first three tests: the worker prepares them itself
        c.scenario,
        poses=c.scenario.poses[:3],
        load=LoadPlan(load.hooks[:3], load.anchors[:3], load.tensions[:3]),
    )
    seed = c.trial_seed(cell, 2)
    batch = Batch(three, "k", cell, c.scan_noise(cell), c.ft_noise_std(cell), (2,), (seed,))
    (tmp_path / "batch.pkl").write_bytes(pickle.dumps(batch))
    out = subprocess.run(
        [sys.executable, "-c", WORKER_SCRIPT, str(tmp_path / "batch.pkl")],
        capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    report = json.loads(out.stdout.splitlines()[-1])
    loaded = {m.split(".")[0] for m in report["modules"]}
    assert not loaded & set(HEAVY), sorted(loaded & set(HEAVY))
    sensor = ForceTorqueSensor(c.scenario.lab.sensor, c.ft_noise_std(cell), c.scenario.force_sensor.bias)
    ref = montecarlo.trial(montecarlo.prepare(three), seed, 3, cell.method, c.scan_noise(cell), sensor)
    row = report["row"]
    assert row["status"] == "ok" and row["seed"] == seed
    for j, name in enumerate(ref.joint_names):  # bit for bit: the same code on the same seed
        assert row[f"k_{name}"] == ref.stiffness[j]
        assert row[f"k_std_{name}"] == ref.stiffness_std[j]
    assert 50.0 < report["peak"] < 2000.0  # MiB: the figure is reported (the target is a benchmark's)


PEAK_SCRIPT = """
import sys
import numpy as np
from vtestbed.campaigns.worker import peak_rss_mib
before = peak_rss_mib()
block = np.ones(int(sys.argv[1]) * 2**20 // 8)  # touched: resident
print(before, peak_rss_mib())
"""


@pytest.mark.skipif(not Path("/proc/self/status").exists(), reason="VmHWM is Linux's")
def test_a_workers_peak_memory_is_its_own_not_its_parents():
    """A spawned worker is forked from its parent, then exec'd; its peak must not include the
    parent's resident memory (``ru_maxrss`` does on Linux). Reference: the size it allocates."""
    parent_block = np.ones(400 * 2**20 // 8)  # this process: 400 MiB more resident
    out = subprocess.run([sys.executable, "-c", PEAK_SCRIPT, "120"], capture_output=True, text=True,
                         timeout=120, check=True)  # fmt: skip
    before, after = map(float, out.stdout.split())
    assert before < 250.0  # its imports only: not the 400 MiB parent
    assert 115.0 < after - before < 135.0  # the 120 MiB it touched
    del parent_block


def test_prepared_tests_share_one_ray_table_and_rebuild_the_cast_hits_bit_for_bit():
    from vtestbed.world.physics import run_test_physics
    from vtestbed.world.rig import Rig
    from vtestbed.world.truth import load_truth

    sc = tiny().scenario
    load = sc.load
    four = dataclasses.replace(
        sc, poses=sc.poses[:4], load=LoadPlan(load.hooks[:4], load.anchors[:4], load.tensions[:4])
    )
    prepared = montecarlo.prepare(four)
    assert len({id(t.rays) for t in prepared.tests}) == 1  # one table for the list, not one per test
    rig = Rig(four.robot, four.lab, truth=load_truth(four.robot_name), effects=four.effects)
    for i, t in enumerate(prepared.tests):
        phys = run_test_physics(rig, four.poses[i], load.hooks[i], load.anchors[i], load.tensions[i],
                                four.scanner.distance, four.scanner.placement)  # fmt: skip
        for cast, kept in ((phys.hits_unloaded, t.hits_unloaded), (phys.hits_loaded, t.hits_loaded)):
            assert np.array_equal(kept.points_m, cast.points_m)
            assert np.array_equal(kept.directions, cast.directions)
            assert np.array_equal(kept.cos_incidence, cast.cos_incidence)


def _children(pid: int) -> dict[int, str]:
    """Direct children of ``pid`` and their command lines (Linux /proc)."""
    found = {}
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
            cmd = (entry / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
        except OSError:  # the process ended meanwhile
            continue
        if int(stat.rsplit(")", 1)[1].split()[1]) == pid:
            found[int(entry.name)] = cmd
    return found


def _alive(pid: int) -> bool:
    """Running (a zombie left for a busy init to reap counts as gone)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_killing_the_sweep_kills_its_workers_and_resource_tracker(tmp_path):
    path = tmp_path / "tiny.toml"
    path.write_text(BASE_TEXT + "\n[campaign]\ntrials = 40\nseed = 9\n[campaign.axes]\nn_tests = [3]\n")
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "vtestbed", "sweep", str(path), "--out", str(out), "--workers", "2",
           "--batch-trials", "1", "--no-report", "--quiet"]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    pids: list[int] = []
    try:
        deadline = time.monotonic() + 120
        workers: dict[int, str] = {}
        while time.monotonic() < deadline and proc.poll() is None:
            children = _children(proc.pid)
            workers = {p: c for p, c in children.items() if "spawn_main" in c}
            if len(workers) == 2 and list((out / TRIALS_DIR).glob("part-*.parquet")):
                break  # both workers started and trials are being computed
            time.sleep(0.05)
        assert proc.poll() is None, proc.stderr.read().decode()[-2000:]
        assert len(workers) == 2, children
        tracker = [p for p, c in children.items() if "resource_tracker" in c]
        os.kill(proc.pid, signal.SIGKILL)
        assert proc.wait(timeout=10) == -signal.SIGKILL
        pids = [*workers, *tracker]
        # 5 s: the kernel's parent-death signal acts at once; the watcher thread polls every 0.5 s
        gone_by = time.monotonic() + 5.0
        while time.monotonic() < gone_by and any(_alive(p) for p in pids):
            time.sleep(0.05)
        left = {p: (workers | dict.fromkeys(tracker, "resource tracker"))[p] for p in pids if _alive(p)}
        assert not left, f"still running 5 s after the parent was killed: {left}"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid in pids:  # a regression must not leave its orphans running on the CI machine
            if _alive(pid):
                os.kill(pid, signal.SIGKILL)
    rows = len(list((out / TRIALS_DIR).glob("part-*.parquet")))
    assert 1 <= rows < 40  # the sweep was really cut short mid-campaign
