"""Scheduler overhead and throughput of ``bearingflock sweep``: embedded vs 2 local Dask workers.

The work is paper 000's ``scale-active`` case on the compiled engine (20 s runs, the
README's study), one run per seed. For each executor, measured in one process:

* start-up: open the executor and get one trivial task back from every slot;
* after a warm-up (every worker loads the compiled kernel once), a timed sweep of ``--runs``
  runs; throughput = runs per minute of wall time;
* overhead per run = (wall x slots - sum of the runs' own wall seconds) / runs: the time a slot
  spent on anything but running scenarios (pickling, scheduling, the result rows, writing
  Parquet, idle slots at the end), and its share of the slots' time.

* scheduler cost per task, measured alone: ``--empty`` tasks that run an empty batch, all
  submitted at once; cost = wall x slots / tasks. With the median run time this gives the
  overhead share at a batch size, ``cost / (batch x run s)``, free of the machine's noise.

The baseline is ``local`` (every run in this process, no scheduler: its "overhead" is the
client's own bookkeeping). Automatic batching and one run per task (``--batch 1``) are both
measured, which shows what batching buys. This VM shares its 2 cores and slows down for tens of
seconds at a time, so the configurations are measured in interleaved rounds (``--rounds``) and
the table shows each one's median over rounds.

Run: ``python benchmarks/bench_sweep.py [--runs 80] [--rounds 3] [--quick]`` (needs
dask[distributed]).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

from sim.sweep.driver import auto_batch, run_sweep
from sim.sweep.executors import open_executor, parse_executor
from sim.sweep.results import ResultsDir
from sim.sweep.runs import run_batch
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


def _task_cost_s(ex, slots: int, tasks: int) -> float:
    """Seconds of slot time per task for tasks that do nothing (an empty batch)."""
    t0 = time.perf_counter()
    futs = [ex.submit(run_batch, []) for _ in range(tasks)]
    for f in futs:
        f.result()
    return (time.perf_counter() - t0) * slots / tasks


def measure(
    name: str, runs: int, batch: int | None, tmp: Path, tag: str, empty: int = 200
) -> dict[str, float | str]:
    start_s, (cm, ex, slots) = _startup_s(name)
    try:
        task_s = _task_cost_s(ex, slots, empty)
        warm = from_cli("scale-active", f"0:{2 * slots - 1}", [], "compiled", DURATION_S)
        run_sweep(warm, ResultsDir(tmp / f"warm-{name}-{batch}-{tag}"), ex, slots, batch_size=1)
        spec = from_cli("scale-active", f"1000:{1000 + runs - 1}", [], "compiled", DURATION_S)
        out = ResultsDir(tmp / f"{name}-{batch}-{tag}")
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
        "task_ms": 1000.0 * task_s,
        "wall_s": wall,
        "run_s": work / runs,
        "runs_per_min": 60.0 * runs / wall,
        "overhead_ms_per_run": 1000.0 * over / runs,
        "overhead_share": over / (wall * slots),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=80)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="20 runs, 1 round")
    args = ap.parse_args()
    runs, rounds = (20, 1) if args.quick else (args.runs, args.rounds)
    configs = [
        ("local", None),
        ("processes:2", None),
        ("processes:2", 1),
        ("dask:2", None),
        ("dask:2", 1),
    ]
    samples: dict[tuple[str, int | None], list[dict]] = {c: [] for c in configs}
    with tempfile.TemporaryDirectory() as d:
        for k in range(rounds):
            for name, batch in configs:
                r = measure(name, runs, batch, Path(d), str(k))
                samples[(name, batch)].append(r)
                print(
                    f"  round {k + 1}: {name} batch {r['batch']}: {r['runs_per_min']:.0f} "
                    f"runs/min, run {r['run_s']:.3f} s",
                    flush=True,
                )

    def med(c: tuple[str, int | None], key: str) -> float:
        return statistics.median(float(r[key]) for r in samples[c])

    base = med(configs[0], "runs_per_min")
    run_s = statistics.median(float(r["run_s"]) for rs in samples.values() for r in rs)
    print(
        f"\n{runs} runs of scale-active, compiled engine, {DURATION_S:.0f} s simulated each; "
        f"median of {rounds} interleaved rounds; median run {run_s:.3f} s; task/batch: the "
        f"scheduler cost per task over the batch's work\n"
        f"{'executor':<13}{'batch':>6}{'start s':>9}{'run s':>8}{'runs/min':>10}"
        f"{'x local':>9}{'overhead ms/run':>17}{'overhead %':>12}{'task ms':>9}"
        f"{'task/batch %':>14}"
    )
    for c in configs:
        name = c[0]
        print(
            f"{name:<13}{samples[c][0]['batch']:>6}{med(c, 'startup_s'):>9.2f}"
            f"{med(c, 'run_s'):>8.3f}{med(c, 'runs_per_min'):>10.0f}"
            f"{med(c, 'runs_per_min') / base:>9.2f}{med(c, 'overhead_ms_per_run'):>17.1f}"
            f"{100 * med(c, 'overhead_share'):>11.1f}%{med(c, 'task_ms'):>9.2f}"
            f"{100 * med(c, 'task_ms') / 1000 / (int(samples[c][0]['batch']) * run_s):>13.2f}%"
        )


if __name__ == "__main__":
    main()
