"""``bearingflock scenario <paper-002 scenario>``: the runner behind the scenario CLI for the
scenarios of :mod:`sim.distributed_scenarios` (registered in :mod:`sim.scenario_cli`)."""

from __future__ import annotations

import math
from pathlib import Path

import typer


def run_distributed(
    name: str,
    seed: int,
    duration: float | None,
    plot: Path | None,
    bearing_noise_deg: float,
    loss: float,
    latency: float,
) -> dict[str, object]:
    """Run one scenario and return its JSON summary (plus ``plots`` when ``plot`` is given)."""
    from sim.distributed_plots import plot_formation, plot_localization
    from sim.distributed_scenarios import FormationResult, run_distributed_scenario

    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise typer.BadParameter("duration must be a positive number of seconds")
    if not (math.isfinite(bearing_noise_deg) and bearing_noise_deg >= 0):
        raise typer.BadParameter("bearing noise must be >= 0 degrees")
    if loss != 0.0 or latency != 0.0:
        raise typer.BadParameter("the paper-002 scenarios run synchronous rounds: no loss/latency")
    res = run_distributed_scenario(name, seed, duration, math.radians(bearing_noise_deg))
    out: dict[str, object] = {**res.summary(), "bearing_noise_deg": bearing_noise_deg}
    if plot is not None:
        if isinstance(res, FormationResult):
            out["plots"] = [str(p) for p in plot_formation(res, plot)]
        else:
            out["plots"] = [str(p) for p in plot_localization(res, plot)]
    return out
