"""Scheduler overhead and throughput of ``bearingflock sweep``: embedded vs 2 local Dask workers.

The work is paper 000's ``scale-active`` case on the compiled engine (20 s runs, the
README's study), one run per seed. For each executor, measured in one process:

* start-up: open the executor and get one trivial task back from every slot;
* after a warm-up (every worker loads the compiled kernel once), a timed sweep of ``--runs``
  runs; throughput = runs per minute of wall time;
* overhead per run = (wall x slots - sum of the runs' own wall seconds) / runs: the time a slot
  spent on anything but running scenarios (pickling, scheduling, the result rows, writing
  Parquet, idle slots at the end), and its share of the slots' time.

The baseline is ``local`` (every run in this process, no scheduler: its "overhead" is the
client's own bookkeeping). Automatic batching and one run per task (``--batch 1``) are both
measured, which shows what batching buys.

Run: ``python benchmarks/bench_sweep.py [--runs 80] [--quick]`` (needs dask[distributed]).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from sim.sweep.driver import auto_batch, run_sweep
from sim.sweep.executors import open_executor, parse_executor
from sim.sweep.results import ResultsDir
from sim.sweep.spec import from_cli

DURATION_S = 20.0


def _startup_s(name: str) -> tuple[float, object]:
    t0 = time.perf_counter()
    cm = open_executor(parse_executor(name, env={}))
    ex, slots = cm.__enter__()
    futs = [ex.submit(os.getpid) for _ in range(2 * slots)]
    for f in futs:
        f.result()
    return time.perf_counter() - t0, (cm, ex, slots)


def measure(name: str, runs: int, batch: int | None, tmp: Path) -> dict[str, float | str]:
    start_s, (cm, ex, slots) = _startup_s(name)
    try:
        warm = from_cli("scale-active", f"0:{2 * slots - 1}", [], "compiled", DURATION_S)
        run_sweep(warm, ResultsDir(tmp / f"warm-{name}-{batch}"), ex, slots, batch_size=1)
        spec = from_cli("scale-active", f"1000:{1000 + runs - 1}", [], "compiled", DURATION_S)
        out = ResultsDir(tmp / f"{name}-{batch}")
        t0 = time.perf_counter()
        outcome = run_sweep(spec, out, ex, slots, batch_size=batch)
        wall = time.perf_counter() - t0
    finally:
        cm.__exit__(None, None, None)
    rows = out.read()
    assert outcome.failed == 0 and len(rows) == runs
    work = sum(float(r["wall_s"]) for r in rows)
    over = max(wall * slots - work, 0.0)
    return {
        "executor": name,
        "batch": str(batch or auto_batch(runs, slots)),
        "slots": slots,
        "startup_s": start_s,
        "wall_s": wall,
        "run_s": work / runs,
        "runs_per_min": 60.0 * runs / wall,
        "overhead_ms_per_run": 1000.0 * over / runs,
        "overhead_share": over / (wall * slots),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=80)
    ap.add_argument("--quick", action="store_true", help="20 runs")
    args = ap.parse_args()
    runs = 20 if args.quick else args.runs
    configs = [
        ("local", None),
        ("processes:2", None),
        ("processes:2", 1),
        ("dask:2", None),
        ("dask:2", 1),
    ]
    results = []
    with tempfile.TemporaryDirectory() as d:
        for name, batch in configs:
            results.append(measure(name, runs, batch, Path(d)))
            r = results[-1]
            print(f"  {name} batch {r['batch']}: {r['runs_per_min']:.0f} runs/min", flush=True)
    base = results[0]["runs_per_min"]
    print(
        f"\n{runs} runs of scale-active, compiled engine, {DURATION_S:.0f} s simulated each\n"
        f"{'executor':<13}{'batch':>6}{'start s':>9}{'run s':>8}{'runs/min':>10}"
        f"{'x local':>9}{'overhead ms/run':>17}{'overhead %':>12}"
    )
    for r in results:
        print(
            f"{r['executor']:<13}{r['batch']:>6}{r['startup_s']:>9.2f}{r['run_s']:>8.3f}"
            f"{r['runs_per_min']:>10.0f}{r['runs_per_min'] / base:>9.2f}"  # type: ignore[operator]
            f"{r['overhead_ms_per_run']:>17.1f}{100 * r['overhead_share']:>11.1f}%"  # type: ignore[operator]
        )


if __name__ == "__main__":
    main()
