"""What a campaign worker process runs: one batch of trials of one cell, on cached physics.

This module is all a worker imports (through unpickling a :class:`Batch` and :func:`run_batch`):
the Monte Carlo trial, the world's noise models and the researcher's pipeline, and nothing of
the parent's bookkeeping (no pandas, pyarrow, matplotlib, the pose-set design code or Dask), so a
worker starts in about half the time and memory of the full package
(``tests/test_workers.py`` checks ``sys.modules``; ``benchmarks/bench_startup.py`` measures it).

A worker prepares the physics of a test list once (:func:`vtestbed.campaigns.montecarlo.prepare`)
and keeps it in a small cache keyed by the list, so every cell on that list (any noise level,
test count or estimator) reuses it.

Local worker processes die with their parent (:func:`init_local_worker`): a ``kill -9`` of
``vtestbed sweep`` leaves no worker computing for nobody.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import signal
import sys
import threading
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..errors import VtestbedError
from ..scenario import Scenario
from ..transforms import DISPLACEMENT_COMPONENTS as COMPONENTS
from ..world.scan_noise import ScanNoise
from ..world.sensors import ForceTorqueSensor
from . import montecarlo
from .spec import Cell

# Prepared test lists kept per worker process (about 47 MiB per 20 tests). One: the runner sends
# the batches sorted by test list (``runner``), so a list, once left, is not asked again, and a
# second one kept only raised the worker's peak (293 MiB against 226 on the paper campaign).
CACHE_SIZE = 1
PARENT_POLL_S = 0.5  # how often the fallback watcher looks for the parent
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3  # glibc mallopt parameters
PR_SET_PDEATHSIG = 1  # linux/prctl.h


@dataclass(frozen=True)
class Batch:
    """Trials of one cell: everything a worker needs (a few kB; the physics is prepared there)."""

    tests: Scenario  # the base scenario with the cell's test list (no validation tests)
    list_key: str  # identifies the test list: base scenario fingerprint + plan digest
    cell: Cell
    noise: ScanNoise | None
    ft_noise_std: tuple[float, ...]
    trials: tuple[int, ...]
    seeds: tuple[int, ...]

    @property
    def name(self) -> str:
        cell = hashlib.sha256(self.cell.key.encode()).hexdigest()[:12]
        return f"part-{cell}-{self.trials[0]:06d}-{self.trials[-1]:06d}-{len(self.trials)}"


@dataclass(frozen=True)
class BatchResult:
    rows: list
    prepare_s: float  # s spent preparing physics for this batch (0 when cached)
    compute_s: float  # s spent on the trials
    pid: int
    peak_rss_mib: float = 0.0  # the worker's peak resident memory so far


_CACHE: OrderedDict = OrderedDict()
_LOCK = threading.Lock()
_TUNED: list = []


def _tune_worker() -> None:
    """Once per process: undo Dask's ``MALLOC_TRIM_THRESHOLD_`` for our large temporary arrays.

    Dask's nanny starts workers with ``MALLOC_TRIM_THRESHOLD_=65536``, which also switches off
    glibc's dynamic mmap threshold: every cloud-sized array (about 1 MB) is then a fresh mmap,
    zeroed and page-faulted, and a trial takes twice as long (measured: 0.87 s instead of 0.47 s).
    Raising the two thresholds (32 MiB, 256 MiB) restores the normal speed; results are unchanged.
    """
    if _TUNED:
        return
    _TUNED.append(True)
    if "MALLOC_TRIM_THRESHOLD_" in os.environ:
        try:
            libc = ctypes.CDLL("libc.so.6")
            libc.mallopt(M_MMAP_THRESHOLD, 32 * 2**20)
            libc.mallopt(M_TRIM_THRESHOLD, 256 * 2**20)
        except (OSError, AttributeError):  # not glibc: leave it
            pass


def _prepared(batch: Batch) -> tuple[montecarlo.PreparedScenario, float]:
    with _LOCK:
        _tune_worker()
        if batch.list_key in _CACHE:
            _CACHE.move_to_end(batch.list_key)
            return _CACHE[batch.list_key], 0.0
        while len(_CACHE) >= CACHE_SIZE:  # free the oldest list before preparing the next one
            _CACHE.popitem(last=False)
        t0 = time.perf_counter()
        prepared = montecarlo.prepare(batch.tests)
        _CACHE[batch.list_key] = prepared
        _release_free_memory()
        return prepared, time.perf_counter() - t0


def _release_free_memory() -> None:
    """Give the heap that preparing freed back to the system (glibc keeps it otherwise).

    Preparing casts 10 MB of full-detail hits per test and keeps a 2.2 MB compact copy; glibc
    keeps the freed rest in its heap, which showed as 40-60 MiB more resident memory per worker
    for the whole campaign. ``malloc_trim`` returns it (a few ms, once per test list).
    """
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass


def _row(
    batch: Batch, trial: int, seed: int, k_true: np.ndarray, names, result=None, error: str = ""
) -> dict:
    cell = batch.cell
    row = {"trial_key": f"{cell.key};trial={trial}", "cell_key": cell.key, **cell.params(), "trial": trial,
           "seed": seed, "status": "ok" if result is not None else "failed", "error": error}  # fmt: skip
    nan = np.full(len(names), np.nan)
    k = result.stiffness if result is not None else nan
    k_std = result.stiffness_std if result is not None else nan
    for j, name in enumerate(names):
        row[f"k_{name}"] = float(k[j])
        row[f"k_std_{name}"] = float(k_std[j])
        row[f"k_true_{name}"] = float(k_true[j])
        row[f"err_{name}"] = float(k[j] / k_true[j] - 1.0)
    res_std = result.component_std if result is not None else np.full(6, np.nan)
    row.update({f"res_std_{c}": float(v) for c, v in zip(COMPONENTS, res_std)})
    row["condition_number"] = float(result.condition_number) if result is not None else np.nan
    row["chi2_reduced"] = float(result.chi2_reduced) if result is not None else np.nan
    row["n_warnings"] = len(result.warnings) if result is not None else 0
    return row


def peak_rss_mib() -> float:
    """This process's peak resident memory [MiB] (0 where the platform does not report it).

    Linux: ``VmHWM`` of /proc/self/status, the high-water mark of this process's own memory.
    Not ``getrusage``'s ``ru_maxrss``: a spawned worker is forked from its parent and then
    exec'd, and Linux carries the forked copy's resident size (the parent's, with pandas and the
    pose-set design code) over the exec into ``ru_maxrss`` (measured: a bare child of a 300 MiB
    parent reports 326 MiB there, 11 MiB in VmHWM).
    """
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 2**10  # kB
    except OSError:  # not Linux
        pass
    try:
        import resource
    except ImportError:  # not POSIX
        return 0.0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 2**10  # bytes on macOS, KiB on Linux


def run_batch(batch: Batch) -> BatchResult:
    """Run the trials of one batch (in a worker): prepared physics from the cache, noise per trial."""
    prepared, prep_s = _prepared(batch)
    names = batch.tests.robot.joint_names
    sensor = ForceTorqueSensor(batch.tests.lab.sensor, batch.ft_noise_std, batch.tests.force_sensor.bias)
    t0 = time.perf_counter()
    rows = []
    for trial, seed in zip(batch.trials, batch.seeds):
        try:
            result = montecarlo.trial(
                prepared, seed, batch.cell.n_tests, batch.cell.method, batch.noise, sensor
            )
            rows.append(_row(batch, trial, seed, prepared.stiffness_true, names, result))
        except VtestbedError as exc:
            error = f"{type(exc).__name__}: {exc}"
            rows.append(_row(batch, trial, seed, prepared.stiffness_true, names, error=error))
    return BatchResult(rows, prep_s, time.perf_counter() - t0, os.getpid(), peak_rss_mib())


# ---------------------------------------------------------------------- dying with the parent
def init_local_worker(parent_pid: int) -> None:
    """Initializer of a local worker process: Ctrl-C is the parent's; die when the parent dies.

    The parent handles Ctrl-C and stops the pool, so the worker ignores SIGINT. A worker blocked
    on the task queue never notices a parent killed with SIGKILL (its siblings keep the queue's
    pipe open), so: on Linux the kernel sends SIGKILL when the parent dies (``prctl
    PR_SET_PDEATHSIG``, set from the parent's main thread's child, checked against a parent that
    died before it was set), and everywhere a daemon thread polls the parent's pid as a fallback.
    The multiprocessing resource tracker exits by itself once the last worker holding its pipe
    is gone.
    """
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # warnings (an unclear scenario test) as the command line shows them: one line, in words, once
    from ..cli.args import show_warning

    warnings.showwarning = show_warning
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):  # no prctl: the watcher below still works
            pass
    if os.getppid() != parent_pid:  # the parent died before the death signal was armed
        os._exit(1)
    threading.Thread(
        target=_watch_parent, args=(parent_pid,), name="vtestbed-parent-watch", daemon=True
    ).start()


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(PARENT_POLL_S)
        if os.getppid() != parent_pid:  # re-parented: the sweep is gone, so are its results
            os._exit(1)
