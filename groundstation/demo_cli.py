"""``bearingflock demo``: the README's main command (see :mod:`groundstation.demo`)."""

from __future__ import annotations

import json as jsonlib
import sys
import tempfile
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.live import Live
from rich.table import Table


def _table(ev, elapsed_s: float, phase: str, duration_s: float) -> Table:
    table = Table(title=f"bearingflock demo: {phase}, {elapsed_s:5.1f} / {duration_s:.0f} s")
    for col in (
        "id",
        "phase",
        "autopilot",
        "alt m",
        "speed m/s",
        "d_hat m",
        "scale err %",
        "E",
        "nbrs",
        "alarms",
    ):
        table.add_column(col, justify="right")
    status = ev.snapshot()
    errors = ev.series.scale_error[-1] if ev.series.scale_error else []
    err_by_agent = {int(i): e for (i, _), e in zip(ev.pairs, errors, strict=False)}
    for agent_id in range(ev.plan.n):
        st = status.get(agent_id)
        if st is None:
            table.add_row(str(agent_id), "[dim]starting[/dim]", *[""] * 8)
            continue
        chis = st.agent.chi_hat_inv_m
        d_hat = ", ".join(f"{j}:{1 / c:.2f}" for j, c in sorted(chis.items()) if c > 0)
        err = err_by_agent.get(agent_id)
        err_txt = "" if err is None or err != err else f"{100 * err:.1f}"
        style = "red" if st.alarms else ""
        table.add_row(
            str(agent_id),
            st.phase,
            f"{st.autopilot_mode}{' armed' if st.armed else ''}",
            f"{st.altitude_m:.1f}",
            f"{st.speed_m_s:.2f}",
            d_hat,
            err_txt,
            f"{st.agent.e_index:.1e}",
            str(len(st.agent.neighbours)),
            ", ".join(st.alarms),
            style=style,
        )
    return table


def demo(
    vehicles: Annotated[int, typer.Option(help="Number of vehicles.")] = 6,
    flavour: Annotated[str, typer.Option(help="px4 or ardupilot.")] = "px4",
    duration: Annotated[float, typer.Option(help="Mission time before landing (s).")] = 60.0,
    out: Annotated[Path | None, typer.Option(help="Directory for logs, data and plots.")] = None,
    seed: Annotated[int, typer.Option(help="Seed of the formation and of all noise.")] = 0,
    mode: Annotated[str, typer.Option(help="Agent core mode.")] = "formation-active",
    json: Annotated[
        bool, typer.Option("--json", help="Print the summary as one JSON object.")
    ] = False,
) -> None:
    """Fly a whole simulated mission: simulator + one daemon per vehicle, live table, summary."""
    from groundstation.demo import run_demo
    from groundstation.demo_plots import plot_demo

    if vehicles < 3:
        typer.echo("error: --vehicles must be at least 3", err=True)
        raise typer.Exit(2)
    if flavour not in ("px4", "ardupilot"):
        typer.echo("error: --flavour must be px4 or ardupilot", err=True)
        raise typer.Exit(2)
    out_dir = out or Path(tempfile.mkdtemp(prefix="bearingflock-demo-"))
    console = Console(stderr=json)
    live_view = console.is_terminal and not json
    last_print = [-10.0]

    def on_tick(ev, elapsed_s: float, phase: str) -> None:
        if live_view:
            live.update(_table(ev, elapsed_s, phase, duration))
        elif elapsed_s - last_print[0] >= 5.0:
            last_print[0] = elapsed_s
            console.print(_table(ev, elapsed_s, phase, duration))

    try:
        with (
            Live(console=console, refresh_per_second=4, transient=False)
            if live_view
            else _Null() as live
        ):
            summary = run_demo(vehicles, flavour, duration, out_dir, seed, mode, on_tick)
    except KeyboardInterrupt:
        console.print("[yellow]interrupted: every process was stopped[/yellow]")
        raise typer.Exit(130) from None
    except RuntimeError as exc:
        console.print(f"[red]error:[/red] {exc}")
        raise typer.Exit(1) from None
    summary["out"] = str(out_dir)
    summary["plots"] = [str(p) for p in plot_demo(out_dir)]
    if json:
        sys.stdout.write(jsonlib.dumps(summary) + "\n")
    else:
        console.print_json(jsonlib.dumps(summary))


class _Null:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None
