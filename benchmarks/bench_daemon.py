"""End-to-end timing of the flight stack (issue 6): the real demo processes, measured from inside.

For each fleet size N it runs ``bearingflock demo`` (simulator + N agent daemons on loopback,
real MAVLink and Zenoh, real time) and reads what every daemon logs on exit
(``onboard/daemon/metrics.py``):

* bearing -> wire latency: for every velocity setpoint sent to the autopilot, the age of the
  newest camera frame it is based on (capture, Zenoh, core tick, the ``[rates] setpoint``
  stream, 50 Hz); the baseline in the same run is the setpoint stream period alone (20 ms: a
  setpoint waits 0-20 ms for the stream however fast the rest is, so p50 >= 10 ms);
* CPU per agent process (fraction of one core) and the core tick's own wall time;
* whether the machine keeps up: p99 of how late the 100 Hz core ticks start, and the
  simulator's overrun count (steps that started late).

N "runs in real time" when the p99 tick lateness stays under one core period (10 ms) for
every agent and the simulator overran fewer than 1% of its steps (when it reports overruns).

Usage: ``python benchmarks/bench_daemon.py [--sizes 3 6 9] [--duration 40]``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import tempfile
from pathlib import Path

import numpy as np

from groundstation.demo import run_demo
from onboard.daemon.config import Rates

STREAM_PERIOD_MS = 1000.0 / Rates().setpoint  # the fleet file's default stream
CORE_PERIOD_MS = 10.0


def _agent_metrics(out: Path, n: int) -> list[dict]:
    found = []
    for i in range(n):
        text = (out / f"agent{i}.log").read_text()
        m = re.findall(r"metrics (\{.*\})", text)
        if m:
            found.append(json.loads(m[-1]))
    return found


def _sim_overruns(out: Path) -> float | None:
    """Fraction of simulator steps that started late (None when the simulator did not say)."""
    m = re.search(r"steps=(\d+) overruns=(\d+)", (out / "sim.log").read_text())
    return int(m.group(2)) / max(1, int(m.group(1))) if m else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[3, 6, 9])
    parser.add_argument(
        "--duration", type=float, default=40.0, help="simulation seconds per run (real time)"
    )
    parser.add_argument("--quick", action="store_true", help="N = 3 and 6, 25 s each")
    args = parser.parse_args()
    sizes, duration = ([3, 6], 25.0) if args.quick else (args.sizes, args.duration)
    print(f"load average before: {os.getloadavg()[0]:.2f} (2-core machine: treat > 0.5 as noise)")
    head = (
        f"{'N':>3} {'b->wire p50':>11} {'p99 ms':>7} {'stream':>7} {'cpu/agent':>9} "
        f"{'core ms':>7} {'late p99':>8} {'sim overrun':>11} {'real time':>9} {'scale err':>9}"
    )
    print(head)
    for n in sizes:
        with tempfile.TemporaryDirectory(prefix="bench-daemon-") as tmp:
            out = Path(tmp)
            summary = run_demo(n, "px4", duration, out, seed=0)
            metrics = _agent_metrics(out, n)
            over = _sim_overruns(out)
        if len(metrics) < n:
            print(f"{n:>3} only {len(metrics)} of {n} agents reported metrics")
            continue
        p50 = np.median([m["bearing_to_wire"].get("p50_ms", np.nan) for m in metrics])
        p99 = np.max([m["bearing_to_wire"].get("p99_ms", np.nan) for m in metrics])
        cpu = np.mean([m["cpu_fraction"] for m in metrics])
        core = np.median([m["core_step"].get("p50_ms", np.nan) for m in metrics])
        late = np.max([m["tick_late"].get("p99_ms", np.nan) for m in metrics])
        realtime = late < CORE_PERIOD_MS and (over is None or over < 0.01)
        over_txt = "-" if over is None else f"{100 * over:.1f}%"
        err = summary.get("final_scale_error")
        print(
            f"{n:>3} {p50:>11.1f} {p99:>7.1f} {STREAM_PERIOD_MS:>7.0f} {100 * cpu:>8.0f}% "
            f"{core:>7.2f} {late:>8.1f} {over_txt:>11} {'yes' if realtime else 'no':>9} "
            f"{'-' if err is None else f'{100 * err:.2f}%':>9}",
            flush=True,
        )
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
