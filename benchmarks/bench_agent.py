"""Timing of the agent core and the headless runner (issue 3 targets).

* one ``AgentCore.step`` of an agent with 5 neighbours (complete graph of 6, every edge
  reciprocal, so agent 0 runs 5 SfM observers: the worst case), target median < 0.2 ms;
* baseline in the same run: a step of an agent without neighbours (the fixed overhead);
* a 20 s run of the N = 6 paper scenario and a run of N = 30 (ring + chords, 2 reciprocal and
  2 one-way bearings each), reported as multiples of real time (target N = 6: >= 20x).

Usage: ``python benchmarks/bench_agent.py [--duration 20] [--duration30 4]``.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from onboard.agent import AgentConfig
from sim.runner import RunnerConfig, run
from sim.scenarios import run_scenario


def _time_steps(configs, p0, yaw0, agent: int, duration: float) -> list[float]:
    """Run the team with the runner and time agent ``agent``'s steps."""
    import sim.runner as runner_mod

    times: list[float] = []
    base = runner_mod.AgentCore

    class Timed(base):  # type: ignore[misc, valid-type]
        def step(self, t_s, own, inbox=()):
            if self.id != agent:
                return super().step(t_s, own, inbox)
            t0 = time.perf_counter()
            out = super().step(t_s, own, inbox)
            times.append(time.perf_counter() - t0)
            return out

    runner_mod.AgentCore = Timed
    try:
        run(configs, p0, yaw0, RunnerConfig(duration_s=duration, seed=0))
    finally:
        runner_mod.AgentCore = base
    return times[50:]


def _ring_team(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    ang = np.arange(n) * 2 * np.pi / n
    r = n * 0.5
    p0 = np.stack([r * np.cos(ang), r * np.sin(ang), -2.0 - rng.uniform(0, 1, n)], axis=1)
    yaw0 = rng.uniform(-np.pi, np.pi, n)
    edges = set()
    for i in range(n):
        j = (i + 1) % n
        edges |= {(i, j), (j, i), (i, (i + 3) % n), (i, (i + 7) % n)}
    edges = tuple(sorted(e for e in edges if e[0] != e[1]))
    p_hat0 = tuple(tuple(float(x) for x in 0.7 * row) for row in p0)
    cfgs = [
        AgentConfig(
            agent_id=i,
            n_agents=n,
            edges=edges,
            mode="active",
            p_hat0_ned=p_hat0,
            yaw_hat0_rad=tuple(float(y) for y in yaw0),
            seed=seed,
        )
        for i in range(n)
    ]
    return cfgs, p0, yaw0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--duration30", type=float, default=4.0)
    args = ap.parse_args()

    # one step, 5 neighbours
    n = 6
    edges = tuple((i, j) for i in range(n) for j in range(n) if i != j)
    rng = np.random.default_rng(1)
    p0 = rng.normal(size=(n, 3)) * 2.0 + np.array([0, 0, -3.0])
    yaw0 = rng.uniform(-np.pi, np.pi, n)
    p_hat0 = tuple(tuple(float(x) for x in 0.7 * row) for row in p0)
    cfgs = [
        AgentConfig(
            agent_id=i,
            n_agents=n,
            edges=edges,
            mode="active",
            p_hat0_ned=p_hat0,
            yaw_hat0_rad=tuple(float(y) for y in yaw0),
        )
        for i in range(n)
    ]
    busy = _time_steps(cfgs, p0, yaw0, agent=0, duration=2.0)
    alone_cfg = [AgentConfig(agent_id=0, n_agents=1, edges=(), mode="active")]
    alone = _time_steps(alone_cfg, p0[:1], yaw0[:1], agent=0, duration=2.0)
    m_busy, m_alone = statistics.median(busy), statistics.median(alone)
    print(
        f"core step, 5 neighbours (5 observers): median {m_busy * 1e3:.3f} ms "
        f"(p90 {np.percentile(busy, 90) * 1e3:.3f} ms)  target < 0.2 ms"
    )
    print(
        f"baseline core step, no neighbours:     median {m_alone * 1e3:.3f} ms  "
        f"ratio {m_busy / m_alone:.1f}x"
    )

    t0 = time.perf_counter()
    run_scenario("scale-formation-active", seed=0, duration_s=args.duration)
    wall = time.perf_counter() - t0
    print(
        f"N = 6 scale-formation-active, {args.duration:.0f} s: {wall:.2f} s wall, "
        f"{args.duration / wall:.1f}x real time (target >= 20x)"
    )
    t0 = time.perf_counter()
    run_scenario("scale-active", seed=0, duration_s=args.duration)
    wall = time.perf_counter() - t0
    print(
        f"N = 6 scale-active, {args.duration:.0f} s: {wall:.2f} s wall, "
        f"{args.duration / wall:.1f}x real time"
    )
    cfgs30, p30, y30 = _ring_team(30)
    t0 = time.perf_counter()
    run(cfgs30, p30, y30, RunnerConfig(duration_s=args.duration30, seed=0))
    wall = time.perf_counter() - t0
    print(
        f"N = 30 active, {args.duration30:.0f} s: {wall:.2f} s wall, "
        f"{args.duration30 / wall:.2f}x real time"
    )


if __name__ == "__main__":
    main()
