"""``bearingflock scenario NAME``: run one of paper 000's cases headless and report.

The lead registers :func:`scenario` on the main typer app (``app.command()(scenario)``).
"""

from __future__ import annotations

import json as json_lib
from pathlib import Path
from typing import Annotated

import typer

from sim.scenarios import SCENARIOS


def scenario(
    name: Annotated[str, typer.Argument(help=f"One of: {', '.join(SCENARIOS)}")],
    seed: Annotated[int, typer.Option(help="Seed of every random choice")] = 0,
    duration: Annotated[float, typer.Option(help="Simulated seconds")] = 20.0,
    plot: Annotated[Path | None, typer.Option(help="Directory for PNG figures")] = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object")] = False,
    bearing_noise_deg: Annotated[float, typer.Option(help="Bearing noise (deg, 1 sigma)")] = 0.0,
    loss: Annotated[float, typer.Option(help="Message loss probability")] = 0.0,
    latency: Annotated[float, typer.Option(help="Extra message latency (s)")] = 0.0,
) -> None:
    """Reproduce a scale-from-motion case of paper 000 (N = 6, 2 ms clock, 50 Hz bearings)."""
    import math

    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from sim.runner import summarize
    from sim.scenarios import run_scenario

    if name not in SCENARIOS:
        raise typer.BadParameter(f"unknown scenario {name!r}; choose from {', '.join(SCENARIOS)}")
    if duration <= 0:
        raise typer.BadParameter("duration must be positive")
    if not 0.0 <= loss < 1.0:
        raise typer.BadParameter("loss must be in [0, 1)")
    console = Console(stderr=True)
    with Progress(
        TextColumn(f"[bold]{name}[/] seed {seed}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TimeElapsedColumn(),
        console=console,
        transient=json,
    ) as progress:
        task = progress.add_task("run", total=1.0)
        rec = run_scenario(
            name,
            seed=seed,
            duration_s=duration,
            progress=lambda f: progress.update(task, completed=f),
            bearing_noise_rad=math.radians(bearing_noise_deg),
            loss=loss,
            latency_s=latency,
        )
    result = {"scenario": name, "seed": seed, "duration_s": duration, **summarize(rec)}
    if plot is not None:
        from sim.plots import plot_recording

        result["plots"] = [str(p) for p in plot_recording(rec, plot, name)]
    if json:
        typer.echo(json_lib.dumps(result))
    else:
        for k, v in result.items():
            console.print(f"{k:>40}: {v}")
