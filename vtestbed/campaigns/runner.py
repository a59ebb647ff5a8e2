"""Run a Monte Carlo campaign: local processes or a Dask cluster, Parquet results, resumable.

:func:`sweep` validates the campaign, draws the pose sets once (recorded in
``DIR/campaign.json``), splits the missing trials into batches of one cell and runs them:
in this process (``workers=1``), on ``workers`` local processes (``spawn`` context), or on a
Dask cluster (``scheduler`` = address or :class:`distributed.Client`). Every finished batch is
written at once as ``DIR/trials/part-*.parquet`` (:mod:`vtestbed.campaigns.store`), one row per
trial with its parameters, seed, estimates, predicted std and errors. An interrupted campaign
(Ctrl-C, a killed process) keeps every finished batch; a rerun with the same campaign skips the
trials already on disk (rows are keyed by ``trial_key`` and deduplicated on reading).

Speed: a worker prepares the physics of a test list once (equilibria and ray casts,
:func:`vtestbed.campaigns.montecarlo.prepare`) and keeps it in a small cache keyed by the test list, so
every cell on that list (any noise level, test count or estimator) reuses it; each trial draws
its own noise and runs the full researcher pipeline (cloud fits, identification). The worker's
side is :mod:`vtestbed.campaigns.worker`, which imports none of this module's bookkeeping
(pandas, pyarrow, the pose-set design code); local workers die with this process.
"""

from __future__ import annotations

import math
import multiprocessing
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from ..files import folder_lock
from ..output_folders import SWEEP, require_own_kind
from .spec import Campaign, load_campaign
from .store import (
    TRIALS_DIR,
    SweepError,
    open_manifest,
    plans_on_disk,
    read_results,
    remove_stale_parts,
    results,
    write_part,
)
from .worker import Batch, BatchResult, init_local_worker, run_batch

if TYPE_CHECKING:
    import pandas as pd

__all__ = ["Batch", "BatchResult", "SweepStats", "run_batch", "sweep"]

SECONDS_PER_TEST = 0.065  # one test of one trial (two noisy clouds, two fits), for batch sizing
TARGET_BATCH_S = 2.0


@dataclass
class SweepStats:
    """Where the time went (for benchmarks): seconds and counts."""

    wall_s: float = 0.0
    generate_s: float = 0.0
    prepare_s: float = 0.0
    compute_s: float = 0.0
    trials_run: int = 0
    tests_run: int = 0
    batches: int = 0
    pids: set = field(default_factory=set)
    worker_peak_rss_mib: float = 0.0  # the largest peak resident memory a worker reported


SINGLE_THREAD_ENV = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@contextmanager
def _single_threaded_children():
    """Spawned workers start with one BLAS/OpenMP thread each (unless the user set a number).

    The cloud fits multiply (3, N) arrays: a second BLAS thread per process gains nothing and two
    workers x two threads on two cores lose a third of the throughput to oversubscription.
    """
    saved = {k: os.environ.get(k) for k in SINGLE_THREAD_ENV}
    for k in SINGLE_THREAD_ENV:
        os.environ.setdefault(k, "1")
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _batches(campaign: Campaign, plans, done: set, workers: int, batch_trials: int | None) -> list[Batch]:
    todo = []
    for cell in campaign.cells():
        missing = [t for t in range(campaign.trials) if f"{cell.key};trial={t}" not in done]
        if missing:
            todo.append((cell, missing))
    total = sum(len(m) for _, m in todo)
    out, lists = [], {}
    for cell, missing in todo:
        size = batch_trials or max(1, round(TARGET_BATCH_S / (SECONDS_PER_TEST * cell.n_tests)))
        if batch_trials is None:  # enough batches to keep every worker busy to the end
            size = max(1, min(size, math.ceil(total / (4 * workers))))
        key = campaign.plan_key(cell)
        if key not in lists:  # the test list's scenario, built once and shared by its batches
            lists[key] = (
                plans[key].scenario(campaign.scenario),
                campaign.scenario.fingerprint + plans[key].digest,
            )
        tests, list_key = lists[key]
        noise, ft = campaign.scan_noise(cell), campaign.ft_noise_std(cell)
        for i in range(0, len(missing), size):
            trials = tuple(missing[i : i + size])
            seeds = tuple(campaign.trial_seed(cell, t) for t in trials)
            out.append(Batch(tests, list_key, cell, noise, ft, trials, seeds))
    out.sort(key=lambda b: (campaign.plan_key(b.cell), b.cell.key, b.trials[0]))
    return out


# ---------------------------------------------------------------------- executors
def _run_inline(batches):
    for b in batches:
        yield b, run_batch(b)


def _run_processes(batches, workers: int):
    ctx = multiprocessing.get_context("spawn")
    pool = ProcessPoolExecutor(
        max_workers=workers, mp_context=ctx, initializer=init_local_worker, initargs=(os.getpid(),)
    )
    try:
        with _single_threaded_children():  # workers are spawned during the submits
            futures = {pool.submit(run_batch, b): b for b in batches}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()
    except BaseException:  # Ctrl-C, GeneratorExit, a failed batch: stop now
        procs = list((getattr(pool, "_processes", None) or {}).values())
        pool.shutdown(wait=False, cancel_futures=True)
        for proc in procs:
            proc.terminate()  # a batch in flight is lost; finished ones are on disk
        raise
    pool.shutdown(wait=True)


def _dask_client(scheduler):
    from distributed import Client

    if isinstance(scheduler, Client):
        return scheduler
    try:
        return Client(scheduler, timeout=30)
    except (OSError, ValueError, TypeError) as exc:  # unreachable, or not an address at all
        raise SweepError(
            f"--scheduler {scheduler!r}: cannot reach the Dask scheduler ({exc}); "
            "give an address such as tcp://127.0.0.1:8786"
        ) from None


def _run_dask(batches, client, owned: bool):
    from distributed import as_completed as dask_completed

    futures = {}
    try:
        for b in batches:
            futures[client.submit(run_batch, b, pure=False)] = b
        for fut, result in dask_completed(list(futures), with_results=True):
            yield futures[fut], result
    finally:
        client.cancel(list(futures))
        if owned:
            client.close()


# ---------------------------------------------------------------------- the call
def sweep(
    campaign: Campaign | str | Path,
    out: str | Path,
    workers: int = 1,
    scheduler=None,
    progress: bool = True,
    batch_trials: int | None = None,
    stats: SweepStats | None = None,
    allow_code_change: bool = False,
) -> pd.DataFrame:
    """Run (or complete) a campaign into ``out``; returns its trials as a DataFrame.

    Parameters
    ----------
    campaign : Campaign or path of a scenario TOML file with a ``[campaign]`` table
    out : results folder (``campaign.json``, ``trials/part-*.parquet``)
    workers : local processes (1: in this process); ignored with ``scheduler``
    scheduler : Dask scheduler address (``"tcp://host:8786"``) or a ``distributed.Client``
    progress : show a progress bar (stderr)
    batch_trials : trials per task (default: about 2 s of work, at least 4 tasks per worker)
    stats : filled with timings (:class:`SweepStats`)
    allow_code_change : complete a folder started by other vtestbed source code (mixes results)

    Returns
    -------
    pandas.DataFrame, one row per trial of this campaign, sorted by the axes and the trial.
    Columns: ``trial_key``, ``cell_key``, the axes, ``trial``, ``seed``, ``status``, ``error``,
    per joint ``k_<j>``, ``k_std_<j>``, ``k_true_<j>`` [N*m/rad] and ``err_<j>`` (k/k_true - 1),
    ``res_std_<x..rz>`` [m | rad], ``condition_number``, ``chi2_reduced``, ``n_warnings``.
    """
    t_start = time.perf_counter()
    stats = stats if stats is not None else SweepStats()
    campaign = campaign if isinstance(campaign, Campaign) else load_campaign(campaign)
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise SweepError(f"workers = {workers!r} must be an integer >= 1")
    if batch_trials is not None and (
        isinstance(batch_trials, bool) or not isinstance(batch_trials, int) or batch_trials < 1
    ):
        raise SweepError(
            f"batch_trials = {batch_trials!r} must be an integer >= 1 (or None: about 2 s of work)"
        )
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    with folder_lock(out, "results folder", SweepError):  # one writer at a time
        return _sweep_into(
            out, campaign, workers, scheduler, progress, batch_trials, stats, allow_code_change, t_start
        )


def _sweep_into(out, campaign, workers, scheduler, progress, batch_trials, stats, allow_code_change, t_start):
    require_own_kind(out, (SWEEP,), "vtestbed sweep", SweepError)  # a run's or a dataset's folder
    manifest = open_manifest(out, campaign, allow_code_change)
    log = _logger(progress)
    t0 = time.perf_counter()
    plans = plans_on_disk(out, campaign, manifest, log)
    stats.generate_s += time.perf_counter() - t0
    (out / TRIALS_DIR).mkdir(parents=True, exist_ok=True)
    remove_stale_parts(out)
    done = set(read_results(out)["trial_key"])
    client = None if scheduler is None else _dask_client(scheduler)
    n_workers = workers if client is None else max(1, sum(client.nthreads().values()))
    batches = _batches(campaign, plans, done, n_workers, batch_trials)
    if client is not None:
        runner = _run_dask(batches, client, owned=client is not scheduler)
    elif workers == 1:
        runner = _run_inline(batches)
    else:
        runner = _run_processes(batches, workers)
    import pandas as pd  # the parent's bookkeeping only: workers never import it
    from tqdm import tqdm

    todo = sum(len(b.trials) for b in batches)
    bar = tqdm(total=campaign.n_trials, initial=campaign.n_trials - todo, desc=campaign.scenario.name,
               unit="trial", disable=not progress, dynamic_ncols=True)  # fmt: skip
    try:
        for batch, result in runner:
            write_part(out, batch.name, pd.DataFrame(result.rows))
            stats.worker_peak_rss_mib = max(stats.worker_peak_rss_mib, result.peak_rss_mib)
            stats.prepare_s += result.prepare_s
            stats.compute_s += result.compute_s
            stats.trials_run += len(batch.trials)
            stats.tests_run += len(batch.trials) * batch.cell.n_tests
            stats.batches += 1
            stats.pids.add(result.pid)
            bar.update(len(batch.trials))
    finally:
        runner.close()
        bar.close()
    stats.wall_s += time.perf_counter() - t_start
    return results(out, campaign)


def _logger(progress: bool):
    if not progress:
        return None

    def log(message: str) -> None:
        print(f"vtestbed sweep: {message}", file=sys.stderr, flush=True)

    return log
