"""``bearingflock scenario NAME``: run one of paper 000's cases headless and report.

The lead registers :func:`scenario` on the main typer app (``app.command()(scenario)``).
"""

from __future__ import annotations

import json as json_lib
from pathlib import Path
from typing import Annotated

import typer

from sim.distributed_scenarios import DISTRIBUTED_SCENARIOS
from sim.rigidity_scenarios import RIGIDITY_SCENARIOS
from sim.scenarios import SCENARIOS
from sim.se3_runner import SE3_SCENARIOS

ALL_SCENARIOS = [*SCENARIOS, *RIGIDITY_SCENARIOS, *SE3_SCENARIOS, *DISTRIBUTED_SCENARIOS]


def scenario(
    name: Annotated[str, typer.Argument(help=f"One of: {', '.join(ALL_SCENARIOS)}")],
    seed: Annotated[int, typer.Option(min=0, help="Seed of every random choice")] = 0,
    duration: Annotated[
        float | None, typer.Option(help="Simulated seconds (default: 20, rigidity-*: 60)")
    ] = None,
    plot: Annotated[Path | None, typer.Option(help="Directory for PNG figures")] = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object")] = False,
    bearing_noise_deg: Annotated[float, typer.Option(help="Bearing noise (deg, 1 sigma)")] = 0.0,
    loss: Annotated[float, typer.Option(help="Message loss probability")] = 0.0,
    latency: Annotated[float, typer.Option(help="Extra message latency (s)")] = 0.0,
    engine: Annotated[
        str,
        typer.Option(
            help="'cores' steps one agent core per vehicle (the reference), "
            "'compiled' the same team compiled with numba (scale-*: ~250x real time; "
            "rigidity-*: ~25x; the first run compiles it, 1-3 min)"
        ),
    ] = "cores",
) -> None:
    """Reproduce a scale-from-motion case of paper 000 (N = 6, 2 ms clock, 50 Hz bearings), a
    rigidity-maintenance simulation of paper 003 (rigidity-*), paper 001's centralized SE(3)
    EKF (ekf-se3: 60 s by default, bearing noise 1 deg unless given) or paper 002's distributed
    framework (formation-*, localization-*)."""
    import math

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from sim.runner import summarize
    from sim.scenarios import run_scenario

    if name not in ALL_SCENARIOS:
        raise typer.BadParameter(
            f"unknown scenario {name!r}; choose from {', '.join(ALL_SCENARIOS)}"
        )
    if name in DISTRIBUTED_SCENARIOS:  # paper 002 (sim/distributed_cli.py)
        from sim.distributed_cli import run_distributed

        result = run_distributed(name, seed, duration, plot, bearing_noise_deg, loss, latency)
        return _print(result, json, Console(stderr=True))
    if duration is None:
        duration = 60.0 if name in RIGIDITY_SCENARIOS or name in SE3_SCENARIOS else 20.0
    if not (math.isfinite(duration) and duration > 0):
        raise typer.BadParameter("duration must be a positive number of seconds")
    if not (math.isfinite(bearing_noise_deg) and bearing_noise_deg >= 0):
        raise typer.BadParameter("bearing noise must be >= 0 degrees")
    if not (math.isfinite(latency) and latency >= 0):
        raise typer.BadParameter("latency must be >= 0 seconds")
    if not 0.0 <= loss < 1.0:
        raise typer.BadParameter("loss must be in [0, 1)")
    if engine not in ("cores", "compiled"):
        raise typer.BadParameter(f"unknown engine {engine!r}; choose 'cores' or 'compiled'")
    console = Console(stderr=True)
    if name in SE3_SCENARIOS:
        _run_se3(name, seed, duration, bearing_noise_deg, loss, latency, plot, json, console)
        return
    with Progress(
        TextColumn(f"[bold]{name}[/] seed {seed}"),
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        console=console,
        transient=json,
    ) as progress:
        note = "(compiled engine: the first run compiles it, about 30 s)"
        task = progress.add_task(note if engine == "compiled" else "", total=1.0)
        if name in RIGIDITY_SCENARIOS:
            from sim.rigidity_scenarios import run_rigidity_scenario

            rr = run_rigidity_scenario(
                name,
                seed,
                duration,
                progress=lambda f: progress.update(task, completed=f),
                bearing_noise_rad=math.radians(bearing_noise_deg),
                loss=loss,
                latency_s=latency,
                engine=engine,
            )
        else:
            rec = run_scenario(
                name,
                seed=seed,
                duration_s=duration,
                progress=lambda f: progress.update(task, completed=f),
                bearing_noise_rad=math.radians(bearing_noise_deg),
                loss=loss,
                latency_s=latency,
                engine=engine,
            )
    if name in RIGIDITY_SCENARIOS:
        result: dict[str, object] = {"duration_s": duration, **rr.summary()}
        if plot is not None:
            from sim.rigidity_plots import plot_rigidity

            result["plots"] = [str(p) for p in plot_rigidity(rr, plot)]
    else:
        result = {
            "scenario": name,
            "seed": seed,
            "duration_s": duration,
            "engine": engine,
            **summarize(rec),
        }
        if plot is not None:
            from sim.plots import plot_recording

            result["plots"] = [str(p) for p in plot_recording(rec, plot, name)]
    _print(result, json, console)


def _run_se3(name, seed, duration, noise_deg, loss, latency, plot, json, console) -> None:
    """``ekf-se3``: :func:`sim.se3_runner.run_se3` (no message loss or latency: centralized)."""
    import math

    from sim.se3_runner import Se3RunConfig, run_se3

    if loss or latency:
        raise typer.BadParameter("ekf-se3 is centralized: --loss and --latency do not apply")
    noise_rad = math.radians(noise_deg) if noise_deg > 0 else Se3RunConfig.bearing_noise_rad
    rec = run_se3(Se3RunConfig(duration_s=duration, seed=seed, bearing_noise_rad=noise_rad))
    result: dict[str, object] = {"scenario": name, "seed": seed, "duration_s": duration}
    result.update(rec.summary())
    if plot is not None:
        from sim.se3_plots import plot_se3

        result["plots"] = [str(p) for p in plot_se3(rec, plot, name)]
    _print(result, json, console)


def _print(result: dict, json: bool, console) -> None:
    if json:
        typer.echo(json_lib.dumps(result))
    else:
        for k, v in result.items():
            console.print(f"{k:>40}: {v}")
