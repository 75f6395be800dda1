"""One sweep run and a batch of them: what a worker executes.

A run is ``bearingflock scenario NAME --seed S --json`` without the printing: the same scenario
runners (:func:`sim.scenarios.run_scenario` + :func:`sim.runner.summarize`,
:func:`sim.rigidity_scenarios.run_rigidity_scenario` + its ``summary()``) and the same metrics.
:func:`run_batch` is a plain top-level function of plain data, so any
:class:`concurrent.futures.Executor` (a process pool, a Dask cluster) can ship it.
"""

from __future__ import annotations

import os
import socket
import time
from dataclasses import dataclass
from enum import Enum

from sim.sweep.params import ParamValue, split

RIGIDITY_DEFAULT_DURATION_S = 60.0
SCALE_DEFAULT_DURATION_S = 20.0
ID_FIELDS = ("scenario", "seed", "duration_s", "engine")
"""Keys of the scenario's ``--json`` that a row holds as its own columns, not as metrics."""


class RunStatus(str, Enum):
    """How a run ended (a row's ``status``)."""

    OK = "ok"
    FAILED = "failed"
    TIMEOUT = "timeout"


class RunTimeout(Exception):
    """The run used more than its wall-clock budget."""


@dataclass(frozen=True)
class RunTask:
    """Everything a worker needs for one run (picklable, no references to the client)."""

    point: int
    point_key: str
    scenario: str
    params: tuple[tuple[str, ParamValue], ...]
    duration_s: float
    engine: str
    seed: int
    run_seed: int
    timeout_s: float | None = None


def _scenario_sets() -> tuple[set[str], set[str]]:
    from sim.rigidity_scenarios import RIGIDITY_SCENARIOS
    from sim.scenarios import SCENARIOS

    return set(SCENARIOS), set(RIGIDITY_SCENARIOS)


def default_duration(scenario: str) -> float:
    """``bearingflock scenario``'s default: 20 s, rigidity-*: 60 s."""
    _, rigidity = _scenario_sets()
    return RIGIDITY_DEFAULT_DURATION_S if scenario in rigidity else SCALE_DEFAULT_DURATION_S


def check_scenario(scenario: str, engine: str) -> None:
    """:class:`ValueError` for an unknown scenario or one the engine cannot run."""
    scale, rigidity = _scenario_sets()
    if scenario not in scale | rigidity:
        raise ValueError(
            f"unknown scenario {scenario!r}; choose from {', '.join([*scale, *rigidity])}"
        )


def scenario_metrics(task: RunTask, progress=None) -> dict[str, object]:
    """The scenario's ``--json`` metrics for one run (identity fields left out)."""
    runner, agent = split(dict(task.params))
    _, rigidity = _scenario_sets()
    if task.scenario in rigidity:
        from sim.rigidity_scenarios import run_rigidity_scenario

        summary = run_rigidity_scenario(
            task.scenario,
            task.run_seed,
            task.duration_s,
            progress,
            agent,
            engine=task.engine,
            **runner,
        ).summary()
    else:
        from sim.runner import summarize
        from sim.scenarios import run_scenario

        rec = run_scenario(
            task.scenario,
            seed=task.run_seed,
            duration_s=task.duration_s,
            progress=progress,
            engine=task.engine,
            config_overrides=agent,
            **runner,
        )
        summary = summarize(rec)
    return {k: v for k, v in summary.items() if k not in ID_FIELDS}


def run_one(task: RunTask) -> dict[str, object]:
    """Run ``task``; never raises for a failed run: the row says ``status`` and ``error``."""
    t0 = time.perf_counter()
    c0 = time.thread_time()

    def progress(_fraction: float) -> None:
        # cooperative timeout: the runners report progress every few hundred steps (the
        # compiled engine only at its end, so its overrun is detected, not interrupted)
        if task.timeout_s is not None and time.perf_counter() - t0 > task.timeout_s:
            raise RunTimeout(f"run exceeded its timeout of {task.timeout_s} s")

    row: dict[str, object] = {"status": RunStatus.OK.value, "error": ""}
    try:
        row.update(scenario_metrics(task, progress))
    except RunTimeout as e:
        row.update(status=RunStatus.TIMEOUT.value, error=str(e))
    except Exception as e:
        row.update(status=RunStatus.FAILED.value, error=f"{type(e).__name__}: {e}")
    row.update(
        wall_s=time.perf_counter() - t0,
        cpu_s=time.thread_time() - c0,
        worker=f"{socket.gethostname()}:{os.getpid()}",
    )
    return row


def run_batch(tasks: list[RunTask]) -> list[tuple[RunTask, dict[str, object]]]:
    """Run several tasks in a row (one executor task: keeps scheduler overhead small)."""
    return [(t, run_one(t)) for t in tasks]
