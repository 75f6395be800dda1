"""Timing one agent core on recorded inputs (shared by ``bench_agent.py`` and
``bench_rigidity_control.py``).

The machine these benchmarks were written on (2 shared cores) runs everything 1.6-1.8x slower
for tens of seconds at a time: one run's median step read 1.6 or 2.9 ms for the same code.
So a team first flies once in the headless runner while one agent's inputs (time, own
measurements, inbox) are recorded; then a fresh core of that agent is fed the same inputs
several times, the cases of a benchmark in turn. The core is deterministic, so each replay
repeats the run's computation exactly: a step's fastest time over the replays is its cost
without interference, and the reported figure is the median of those over the steps. Each
replay's own median is returned too, so the spread stays visible.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from messages.agent import OwnMeasurements
from messages.codec import Payload
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig
from onboard.geometry import FloatArray
from sim.runner import RunnerConfig, run

Inputs = list[tuple[float, OwnMeasurements, list[Payload]]]


def record(
    configs: Sequence[AgentConfig],
    p0_ned: FloatArray,
    yaw0_rad: FloatArray,
    runner: RunnerConfig,
    agent: int = 0,
) -> Inputs:
    """Fly the team in the headless runner and record ``agent``'s inputs, step by step."""
    import sim.runner as runner_mod

    inputs: Inputs = []
    base = runner_mod.AgentCore

    class Recorded(base):  # type: ignore[misc, valid-type]
        def step(self, t_s, own, inbox=()):
            if self.id == agent:
                inputs.append((t_s, own, list(inbox)))
            return super().step(t_s, own, inbox)

    runner_mod.AgentCore = Recorded
    try:
        run(list(configs), p0_ned, yaw0_rad, runner)
    finally:
        runner_mod.AgentCore = base
    return inputs


def replay(config: AgentConfig, inputs: Inputs) -> FloatArray:
    """Wall-clock seconds of each step of a fresh core fed the recorded inputs."""
    core = AgentCore(config)
    out = np.zeros(len(inputs))
    for k, (t_s, own, inbox) in enumerate(inputs):
        t0 = time.perf_counter()
        core.step(t_s, own, inbox)
        out[k] = time.perf_counter() - t0
    return out


def time_cases(
    cases: dict[str, tuple[AgentConfig, Inputs]], repeats: int, skip: int
) -> dict[str, FloatArray]:
    """Per-step seconds ``(repeats, steps - skip)`` of every case, the cases replayed in turn
    (so that a slow phase of the machine hits them alike)."""
    times: dict[str, list[FloatArray]] = {name: [] for name in cases}
    for _ in range(repeats):
        for name, (config, inputs) in cases.items():
            times[name].append(replay(config, inputs)[skip:])
    return {name: np.array(t) for name, t in times.items()}


def fastest_median_ms(t: FloatArray) -> float:
    """Median over the steps of each step's fastest replay, in ms."""
    return float(np.median(t.min(axis=0))) * 1e3


def describe(t: FloatArray) -> str:
    """``"1.234 ms [each replay's median: 1.5, 1.4-1.9]"``."""
    each = np.median(t, axis=1) * 1e3
    return (
        f"{fastest_median_ms(t):.3f} ms [replay medians {np.median(each):.3f}, "
        f"{each.min():.3f}-{each.max():.3f}]"
    )
