"""Timing of one daemon: how fresh its setpoints are and whether it keeps up with real time.

Three samples, kept in bounded windows and summarized as percentiles on exit (one structured
log line, ``metrics {...}``, that ``benchmarks/bench_daemon.py`` reads):

* ``bearing_to_wire_s``: for every setpoint put on the wire, the time since the camera captured
  the newest bearing frame it is based on: capture -> Zenoh -> core tick -> setpoint stream
  (paper 000's loop closed through the autopilot). Capture stamps are simulation time; they are
  converted to the link's clock with the simulation's speed-up.
* ``tick_late_s``: how late each core tick started against its schedule (a machine that cannot
  run the fleet in real time shows it here first).
* ``core_step_s``: wall time of one core tick (all its sub-steps).
* ``telemetry_age_s``: at each core tick, the daemon clock minus the autopilot's stamp
  (``time_boot_ms``) of the newest attitude/velocity it holds; in simulation both are
  simulation time, so this is the telemetry's latency plus the follower clock's error.
* ``frame_age_s``: for every camera frame, the daemon clock at its arrival minus its capture
  stamp.

CPU time of the process (``time.process_time``) and wall time since start are reported too.
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

WINDOW = 20_000


def percentiles_ms(samples: deque[float] | list[float]) -> dict[str, float | int]:
    """``{"n", "min_ms", "p50_ms", "p99_ms", "max_ms"}`` of samples in seconds (NaN-free; empty -> n = 0)."""
    if not samples:
        return {"n": 0}
    a = 1e3 * np.asarray(samples, dtype=float)
    p50, p99 = np.percentile(a, [50, 99])
    return {
        "n": len(a),
        "min_ms": float(a.min()),
        "p50_ms": float(p50),
        "p99_ms": float(p99),
        "max_ms": float(a.max()),
    }


@dataclass
class DaemonMetrics:
    bearing_to_wire_s: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))
    tick_late_s: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))
    core_step_s: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))
    telemetry_age_s: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))
    frame_age_s: deque[float] = field(default_factory=lambda: deque(maxlen=WINDOW))
    t_start_wall: float = field(default_factory=time.monotonic)
    cpu_start_s: float = field(default_factory=time.process_time)

    def summary(self) -> dict[str, object]:
        wall = time.monotonic() - self.t_start_wall
        cpu = time.process_time() - self.cpu_start_s
        return {
            "bearing_to_wire": percentiles_ms(list(self.bearing_to_wire_s)),
            "tick_late": percentiles_ms(list(self.tick_late_s)),
            "core_step": percentiles_ms(list(self.core_step_s)),
            "telemetry_age": percentiles_ms(list(self.telemetry_age_s)),
            "frame_age": percentiles_ms(list(self.frame_age_s)),
            "cpu_s": cpu,
            "wall_s": wall,
            "cpu_fraction": cpu / wall if wall > 0 else 0.0,
        }
