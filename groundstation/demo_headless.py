"""The demo's mission in the headless runner: the reference the real processes are compared with.

``bearingflock demo`` flies N daemons against the MAVLink simulator in real time; this module
flies the *same* agent configurations (built from the same fleet file by
:func:`onboard.daemon.loop.agent_config`), from the same start layout, in
:func:`sim.runner.run`: no processes, no sockets, no autopilot. What stands in for the network
is the runner's latency and loss; the default latency (30 ms) is the daemons' own: peer
messages go out at 50 Hz (10 ms late on average), the core ticks at 100 Hz, and loopback Zenoh
adds a few milliseconds. The vehicles respond to setpoints like the simulator's multicopters
(first-order lags, ``tau_v_s = 0.3``, ``tau_yaw_s = 0.2``).

The summary has the keys of :func:`groundstation.demo.summarize` that do not depend on
processes (time to metric scale, final scale and bearing errors, minimum rigidity eigenvalue),
computed the same way from the recorded truth.
"""

from __future__ import annotations

import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from groundstation.demo import SCALE_TOLERANCE, DemoPorts, plan_formation, write_demo_files
from onboard.core.config import replace_fields
from onboard.daemon.config import load_fleet
from onboard.daemon.loop import agent_config
from onboard.geometry import bearings_body
from onboard.rigidity.bearing import ibr_r3s1
from sim.runner import Recording, RunnerConfig, converged_time, run

DEFAULT_LATENCY_S = 0.03
FINAL_WINDOW_S = 2.0
"""The final errors are averaged over this last stretch of the run (as in the demo)."""


def headless_demo(
    vehicles: int = 6,
    seed: int = 0,
    duration_s: float = 40.0,
    mode: str = "formation-active",
    latency_s: float = DEFAULT_LATENCY_S,
    loss: float = 0.0,
    dt_s: float = 0.005,
    tau_v_s: float = 0.3,
    tau_yaw_s: float = 0.2,
    camera_latency_s: float = 0.0,
    rigidity: bool = True,
    progress: Callable[[float], None] | None = None,
    localization: str = "paper000",
    core_fields: dict[str, Any] | None = None,
    bearing_noise_rad: float = 0.0,
) -> tuple[dict[str, Any], Recording]:
    """Fly the demo's mission headless; returns ``(summary, recording)``. ``localization``
    is the fleet file's ``[core] localization``; ``core_fields`` replaces flat agent-config
    fields (:func:`onboard.core.config.replace_fields`) in every vehicle's configuration, e.g.
    ``{"gradloc_yaw_from_bearings": True}``; ``bearing_noise_rad`` is the runner's bearing noise
    (per tangent axis, :class:`sim.runner.RunnerConfig`; the demo's is 0)."""
    plan = plan_formation(vehicles, seed)
    with tempfile.TemporaryDirectory() as tmp:
        ports = DemoPorts(zenoh=7447, mavlink=14540, gcs=14550)  # written, never opened
        fleet = load_fleet(
            write_demo_files(
                Path(tmp),
                plan,
                ports,
                "headless",
                mode,
                rigidity=rigidity,
                localization=localization,
            )
        )
        configs = [agent_config(fleet, i) for i in range(vehicles)]
    if core_fields:
        configs = [replace_fields(c, **core_fields) for c in configs]
    runner = RunnerConfig(
        duration_s=duration_s,
        dt_s=dt_s,
        latency_s=latency_s,
        loss=loss,
        seed=seed,
        record_every=max(1, round(0.05 / dt_s)),
        tau_v_s=tau_v_s,
        tau_yaw_s=tau_yaw_s,
        camera_latency_s=camera_latency_s,
        bearing_noise_rad=bearing_noise_rad,
    )
    rec = run(configs, plan.p_start_ned, plan.yaw_start_rad, runner, progress)
    return summarize_recording(rec, plan.p_ned, plan.yaw_rad, vehicles), rec


def summarize_recording(
    rec: Recording, p_desired_ned: np.ndarray, yaw_desired_rad: np.ndarray, vehicles: int
) -> dict[str, Any]:
    """Time to metric scale (every reciprocal pair within 2% and staying), final errors, and the
    smallest bearing-rigidity eigenvalue of the true formation."""
    t = rec.t_s
    a, b = rec.pairs[:, 0], rec.pairs[:, 1]
    d_true = np.linalg.norm(rec.p_ned[:, b] - rec.p_ned[:, a], axis=2)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(1.0 / rec.chi_hat - d_true) / d_true
    desired, _ = bearings_body(p_desired_ned, yaw_desired_rad, rec.edges)
    bearing_error = np.array(
        [
            np.degrees(
                np.arccos(np.clip((bearings_body(p, y, rec.edges)[0] * desired).sum(1), -1, 1))
            ).mean()
            for p, y in zip(rec.p_ned, rec.yaw_rad, strict=True)
        ]
    )
    tail = t >= t[-1] - FINAL_WINDOW_S
    every = max(1, len(t) // 200)
    eig = [
        ibr_r3s1(p, y, rec.edges).eigenvalue
        for p, y in zip(rec.p_ned[::every], rec.yaw_rad[::every], strict=True)
    ]
    return {
        "vehicles": vehicles,
        "time_to_scale_s": converged_time(t, err, SCALE_TOLERANCE),
        "final_scale_error": float(np.nanmax(np.nanmean(err[tail], axis=0))),
        "final_bearing_error_deg": float(bearing_error[tail].mean()),
        "min_rigidity_eigenvalue": float(min(eig)),
        "dropped_messages": int(sum(rec.dropped.values())),
        "reciprocal_pairs": rec.pairs.tolist(),
    }
