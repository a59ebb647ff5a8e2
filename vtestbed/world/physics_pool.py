"""Several tests' physics on a few threads, handed back in test order.

Most of a test's physics is its two ray casts (``mujoco.mj_multiRay``), which run in C without
Python's global interpreter lock, so threads overlap the casts of different tests (``simulate`` of
the paper scenario: 1.5-1.8 s on two threads against 1.9-2.1 s on one, 2 cores).

Each thread owns a :class:`~vtestbed.world.rig.Rig` from ``make_rig``: a scan reads the MuJoCo
model the rig edits (the wire's hook and anchor sites, its rest length and its stand-in capsule),
so rigs are never shared. A test's physics depends on the test alone (each starts from its
commanded pose with the wire slack and a fresh tangent), so the results are bit-identical to one
rig running the tests in turn (``tests/test_physics_pool.py``). Clearance findings travel back in
:attr:`~vtestbed.world.physics.TestPhysics.clearance`; the caller enforces them in test order, so
warnings come out in that order too.
"""

from __future__ import annotations

import os
import threading
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

from .rig import Rig

Job = TypeVar("Job")
Result = TypeVar("Result")
MAX_THREADS = 4  # ray casts of one scan take ~20 ms; beyond a few threads the Python parts serialise


def default_threads() -> int:
    """Threads for a scenario's physics: the cores this process may use, at most MAX_THREADS."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1
    return max(1, min(MAX_THREADS, cores))


def physics_in_order(
    make_rig: Callable[[], Rig],
    run: Callable[[Rig, Job], Result],
    jobs: Iterable[Job],
    threads: int | None = None,
) -> Iterator[Result]:
    """Yield ``run(rig, job)`` for each job, in the jobs' order, computed on ``threads`` threads.

    Parameters
    ----------
    make_rig : callable
        Builds one rig per thread (called at most ``threads`` times).
    run : callable (Rig, job) -> result
        One test's physics; an exception it raises comes out of this iterator at that job,
        after every earlier job's result.
    jobs : iterable
        The tests, in the order the results are wanted.
    threads : int, optional
        Default :func:`default_threads`; 1 runs everything on the calling thread.

    Notes
    -----
    At most ``2 * threads`` jobs run ahead of the consumer. Closing the iterator (an error or an
    interrupt in the consumer) cancels the jobs not started and waits for the few running ones.
    """
    threads = default_threads() if threads is None else threads
    if threads <= 1:
        rig = make_rig()
        for job in jobs:
            yield run(rig, job)
        return
    local = threading.local()

    def task(job):
        if not hasattr(local, "rig"):
            local.rig = make_rig()
        return run(local.rig, job)

    pending: deque = deque()
    pool = ThreadPoolExecutor(threads, thread_name_prefix="vtestbed-physics")
    try:
        for job in jobs:
            pending.append(pool.submit(task, job))
            if len(pending) >= 2 * threads:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()
    finally:
        for future in pending:
            future.cancel()
        pool.shutdown(wait=True)
