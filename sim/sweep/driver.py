"""Run a sweep on an executor: batches out, rows in, written as each batch finishes.

The client (this process) owns all bookkeeping: which runs remain (``--resume``), the results
directory, the progress bar. Workers only execute :func:`sim.sweep.runs.run_batch` on plain
data, so the rows do not depend on the executor, the number of workers or the order in which
batches finish (the tests compare them embedded and on a Dask cluster).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait
from dataclasses import dataclass

from sim.sweep.results import ResultsDir, git_commit, make_row, package_version
from sim.sweep.runs import RunStatus, RunTask, run_batch
from sim.sweep.spec import SweepSpec, run_seed

MAX_AUTO_BATCH = 16
TASKS_PER_SLOT = 4
"""The automatic batch size aims at this many tasks per worker slot (load balance) and at most
:data:`MAX_AUTO_BATCH` runs per task (a finished task is the unit the results keep)."""


def tasks_of(spec: SweepSpec) -> list[RunTask]:
    """Every run of the sweep, grid point by grid point, seeds in order."""
    return [
        RunTask(
            i,
            gp.key,
            gp.scenario,
            gp.params,
            gp.duration_s,
            spec.engine,
            seed,
            run_seed(seed, spec.seed_root),
            spec.timeout_s,
        )
        for i, gp in enumerate(spec.points())
        for seed in spec.seeds
    ]


def auto_batch(n_tasks: int, slots: int) -> int:
    return max(1, min(MAX_AUTO_BATCH, math.ceil(n_tasks / (TASKS_PER_SLOT * max(slots, 1)))))


def batches(tasks: list[RunTask], size: int) -> list[list[RunTask]]:
    return [tasks[i : i + size] for i in range(0, len(tasks), size)]


@dataclass
class Progress:
    """What the progress callback gets after every finished batch."""

    done: int
    total: int
    failed: int
    skipped: int


@dataclass
class Outcome:
    done: int
    failed: int
    skipped: int
    interrupted: bool
    wall_s: float


def _stop_now(executor: Executor) -> None:
    """Cancel what has not started; for a local process pool, stop the running workers too
    (their batches are lost, the finished ones are on disk)."""
    try:
        executor.shutdown(wait=False, cancel_futures=True)
    except TypeError:  # distributed's ClientExecutor: wait=False cancels what is pending
        executor.shutdown(wait=False)
    procs = getattr(executor, "_processes", None) or {}
    for p in list(procs.values()):
        p.terminate()


def run_sweep(
    spec: SweepSpec,
    results: ResultsDir,
    executor: Executor,
    slots: int,
    resume: bool = False,
    batch_size: int | None = None,
    on_progress: Callable[[Progress], None] | None = None,
) -> Outcome:
    """Run every run of ``spec`` not yet in ``results`` (with ``resume``) on ``executor``."""
    t0 = time.perf_counter()
    results.start(spec.to_json() | {"seeds": list(spec.seeds)}, resume)
    done_keys = results.done() if resume else set()
    todo = [t for t in tasks_of(spec) if (t.point_key, t.seed) not in done_keys]
    skipped = len(done_keys)
    labels = {i: gp.label for i, gp in enumerate(spec.points())}
    version, commit = package_version(), git_commit()
    size = batch_size or auto_batch(len(todo), slots)
    pending: set[Future] = {executor.submit(run_batch, b) for b in batches(todo, size)}
    state = Progress(0, len(todo), 0, skipped)
    if on_progress:
        on_progress(state)
    try:
        while pending:
            finished, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in finished:
                pairs = fut.result()
                rows = [make_row(t, r, labels[t.point], version, commit) for t, r in pairs]
                results.append(rows)
                state.done += len(rows)
                state.failed += sum(r["status"] != RunStatus.OK.value for r in rows)
            if on_progress:
                on_progress(state)
    except KeyboardInterrupt:
        _stop_now(executor)
        return Outcome(state.done, state.failed, skipped, True, time.perf_counter() - t0)
    return Outcome(state.done, state.failed, skipped, False, time.perf_counter() - t0)
