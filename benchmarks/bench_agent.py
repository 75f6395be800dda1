"""Timing of the agent core and the headless runner (issue 3 targets).

* one ``AgentCore.step`` of an agent with 5 neighbours (complete graph of 6, every edge
  reciprocal, so agent 0 runs 5 SfM observers: the worst case), target median < 0.2 ms;
* baseline in the same run: a step of an agent without neighbours (the fixed overhead);
  both timed by replaying agent 0's recorded inputs, in turn (``core_replay.py``);
* a 20 s run of the N = 6 paper scenarios and a run of N = 30 (ring + chords, 2 reciprocal and
  2 one-way bearings each), reported as multiples of real time (target N = 6: >= 20x), with
  the agent cores (one Python ``AgentCore`` per vehicle, the baseline) and the compiled engine
  (``sim.compiled_runner``), measured in the same run; the compiled runs exclude compilation.

Usage: ``python benchmarks/bench_agent.py [--duration 20] [--duration30 4] [--repeats 7]
[--runs 5]``.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from core_replay import describe, record, time_cases

from onboard.core.config import build_config
from sim.compiled_runner import run_compiled
from sim.runner import RunnerConfig, run
from sim.scenarios import PAPER_SFM, run_scenario


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
        build_config(
            agent_id=i,
            n_agents=n,
            edges=edges,
            mode="active",
            p_hat0_ned=p_hat0,
            yaw_hat0_rad=tuple(float(y) for y in yaw0),
            seed=seed,
            **PAPER_SFM,  # the observer both engines run (the compiled one has no safeguards)
        )
        for i in range(n)
    ]
    return cfgs, p0, yaw0


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--duration", type=float, default=20.0)
    ap.add_argument("--duration30", type=float, default=4.0)
    ap.add_argument("--repeats", type=int, default=7, help="replays of each recorded run")
    ap.add_argument("--runs", type=int, default=5, help="timed runs of the compiled engine")
    args = ap.parse_args()

    # one step, 5 neighbours
    n = 6
    edges = tuple((i, j) for i in range(n) for j in range(n) if i != j)
    rng = np.random.default_rng(1)
    p0 = rng.normal(size=(n, 3)) * 2.0 + np.array([0, 0, -3.0])
    yaw0 = rng.uniform(-np.pi, np.pi, n)
    p_hat0 = tuple(tuple(float(x) for x in 0.7 * row) for row in p0)
    cfgs = [
        build_config(
            agent_id=i,
            n_agents=n,
            edges=edges,
            mode="active",
            p_hat0_ned=p_hat0,
            yaw_hat0_rad=tuple(float(y) for y in yaw0),
        )
        for i in range(n)
    ]
    alone_cfg = build_config(agent_id=0, n_agents=1, edges=(), mode="active")
    cases = {
        "busy": (cfgs[0], record(cfgs, p0, yaw0, RunnerConfig(duration_s=2.0, seed=0))),
        "alone": (
            alone_cfg,
            record([alone_cfg], p0[:1], yaw0[:1], RunnerConfig(duration_s=2.0, seed=0)),
        ),
    }
    t = time_cases(cases, args.repeats, skip=50)
    ratio = np.median(np.median(t["busy"], axis=1) / np.median(t["alone"], axis=1))
    print(f"core step (agent 0, {args.repeats} replays each, benchmarks/core_replay.py)")
    print(f"  5 neighbours (5 observers): {describe(t['busy'])}  target < 0.2 ms")
    print(f"  baseline, no neighbours:    {describe(t['alone'])}; ratio {ratio:.1f}x")

    # whole runs: the agent cores (the reference) and the compiled engine, in the same run
    run_scenario("scale-active", duration_s=0.1, engine="compiled")  # compile or load it
    print(f"whole runs, wall seconds (median of {args.runs}) and multiples of real time")
    for name in ("scale-formation-active", "scale-active"):
        row = {}
        for engine in ("cores", "compiled"):
            walls = []
            for _ in range(args.runs if engine == "compiled" else 1):
                t0 = time.perf_counter()
                run_scenario(name, seed=0, duration_s=args.duration, engine=engine)
                walls.append(time.perf_counter() - t0)
            row[engine] = float(np.median(walls))
        print(
            f"  N = 6 {name}, {args.duration:.0f} s: cores {row['cores']:.2f} s "
            f"({args.duration / row['cores']:.1f}x), compiled {row['compiled']:.3f} s "
            f"({args.duration / row['compiled']:.0f}x; target >= 20x), "
            f"ratio {row['cores'] / row['compiled']:.0f}"
        )
    cfgs30, p30, y30 = _ring_team(30)
    t0 = time.perf_counter()
    run(cfgs30, p30, y30, RunnerConfig(duration_s=args.duration30, seed=0))
    wall_cores = time.perf_counter() - t0
    t0 = time.perf_counter()
    run_compiled(cfgs30, p30, y30, RunnerConfig(duration_s=args.duration, seed=0))
    wall = time.perf_counter() - t0
    print(
        f"  N = 30 active: cores {args.duration30:.0f} s in {wall_cores:.2f} s "
        f"({args.duration30 / wall_cores:.2f}x), compiled {args.duration:.0f} s in {wall:.2f} s "
        f"({args.duration / wall:.1f}x)"
    )


if __name__ == "__main__":
    main()
