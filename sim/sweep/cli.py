"""``bearingflock sweep``: Monte Carlo sweeps over seeds x a parameter grid (docs/sweep.md).

``bearingflock sweep SCENARIO[,SCENARIO...] --seeds 0:99 --set loss=0,0.1`` or
``bearingflock sweep sweeps/paper-000.toml`` runs a sweep; ``bearingflock sweep plot DIR``
draws one. The lead registers :func:`sweep` on the main typer app.
"""

from __future__ import annotations

import json as json_lib
import sys
from pathlib import Path
from typing import Annotated

import typer

DEFAULT_OUT = Path("sweep-results")


def sweep(
    target: Annotated[
        str,
        typer.Argument(
            help="A scenario (as `bearingflock scenario` knows it; several with commas), a "
            "sweep file (*.toml, see sweeps/), or `plot` to draw the sweep in DIR"
        ),
    ],
    directory: Annotated[
        Path | None, typer.Argument(help="With `plot`: the results directory")
    ] = None,
    seeds: Annotated[
        str | None,
        typer.Option(help="A:B (inclusive: 0:999 is 1000 seeds) or a list 3,7,11 (default 0:9)"),
    ] = None,
    set_: Annotated[
        list[str] | None,
        typer.Option(
            "--set",
            help="NAME=V1,V2,... a grid axis (repeat for a product): bearing_noise_deg, loss, "
            "latency, a RunnerConfig or AgentConfig field",
        ),
    ] = None,
    duration: Annotated[
        float | None, typer.Option(help="Simulated seconds per run (default: 20, rigidity-*: 60)")
    ] = None,
    engine: Annotated[
        str | None,
        typer.Option(help="cores (reference) or compiled (scale-* only; first run compiles ~30 s)"),
    ] = None,
    executor: Annotated[
        str | None,
        typer.Option(
            help="local | processes\\[:N] (default) | dask\\[:N] | dask://HOST:PORT "
            "(default dask when DASK_SCHEDULER_ADDRESS is set)"
        ),
    ] = None,
    out: Annotated[Path, typer.Option(help="Results directory (Parquet rows)")] = DEFAULT_OUT,
    resume: Annotated[
        bool, typer.Option("--resume", help="Continue the sweep in --out, skip finished runs")
    ] = False,
    timeout: Annotated[
        float | None, typer.Option(help="Wall seconds per run; an overrun is recorded as timeout")
    ] = None,
    batch: Annotated[
        int | None, typer.Option(min=1, help="Runs per executor task (default: automatic)")
    ] = None,
    seed_root: Annotated[
        int | None,
        typer.Option(help="Derive run seeds from SeedSequence(seed_root, spawn_key=(seed,))"),
    ] = None,
    json: Annotated[
        bool, typer.Option("--json", help="Print one JSON object: rows and summary")
    ] = False,
) -> None:
    """Run a scenario over seeds x a parameter grid on a process pool or a Dask cluster; one
    Parquet row per run, a summary per grid point (median, IQR, bootstrap CI)."""
    import signal

    from rich.console import Console

    # Ctrl-C / kill -INT stop the sweep even when a shell started it in the background with
    # SIGINT ignored: the finished rows are on disk, --resume continues
    signal.signal(signal.SIGINT, signal.default_int_handler)
    console = Console(stderr=True)
    if target == "plot":
        if directory is None:
            raise typer.BadParameter("bearingflock sweep plot DIR: give the results directory")
        _plot(directory, console)
        return
    if directory is not None:
        raise typer.BadParameter(f"unexpected argument {directory} (only `plot` takes DIR)")
    from sim.sweep import spec as spec_mod
    from sim.sweep.executors import ExecutorError, open_executor, parse_executor

    try:
        if target.endswith(".toml") or Path(target).is_file():
            if set_:
                raise spec_mod.SpecError("--set does not combine with a sweep file: edit it")
            spec = spec_mod.from_toml(Path(target), seeds, engine)
            if duration is not None or timeout is not None or seed_root is not None:
                from dataclasses import replace

                spec = replace(
                    spec,
                    # --duration wins over the file's, cases' included
                    cases=spec.cases
                    if duration is None
                    else tuple(replace(c, duration_s=None) for c in spec.cases),
                    duration_s=duration or spec.duration_s,
                    timeout_s=timeout or spec.timeout_s,
                    seed_root=spec.seed_root if seed_root is None else seed_root,
                )
        else:
            spec = spec_mod.from_cli(
                target, seeds or "0:9", set_ or [], engine or "cores", duration, seed_root, timeout
            )
        choice = parse_executor(executor)
    except (ValueError, ExecutorError) as e:
        raise typer.BadParameter(str(e)) from None
    from sim.sweep.results import ResultsDir

    results = ResultsDir(out)
    n_runs = len(spec.points()) * len(spec.seeds)
    console.print(
        f"[bold]sweep[/] {len(spec.points())} grid points x {len(spec.seeds)} seeds = {n_runs} "
        f"runs, engine {spec.engine}, on {choice.describe()} -> {out}"
    )
    try:
        with open_executor(choice) as (ex, slots):
            outcome = _run_with_progress(spec, results, ex, slots, resume, batch, console, json)
    except (ValueError, ExecutorError, FileExistsError) as e:
        raise typer.BadParameter(str(e)) from None
    _report(results, outcome, console, json)
    if outcome.interrupted:
        raise typer.Exit(130)


def _run_with_progress(spec, results, ex, slots, resume, batch, console, transient):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    from sim.sweep.driver import run_sweep

    with Progress(
        TextColumn("[bold]runs[/]"),
        BarColumn(),
        MofNCompleteColumn(),
        TextColumn("{task.fields[failed]} failed"),
        TextColumn("{task.fields[skipped]} resumed"),
        TimeElapsedColumn(),
        TextColumn("ETA"),
        TimeRemainingColumn(),
        console=console,
        transient=transient,
    ) as bar:
        task = bar.add_task("sweep", total=None, failed=0, skipped=0)

        def update(p) -> None:
            bar.update(task, total=p.total, completed=p.done, failed=p.failed, skipped=p.skipped)

        return run_sweep(spec, results, ex, slots, resume, batch, update)


def _report(results, outcome, console, json: bool) -> None:
    from sim.sweep.results import json_row
    from sim.sweep.summary import json_safe, summarize_points, table

    rows = results.read()
    summaries = summarize_points(rows)
    if outcome.interrupted:
        console.print(
            f"[yellow]interrupted[/]: {outcome.done} runs of this session kept in "
            f"{results.path}; --resume continues"
        )
    console.print(
        f"{outcome.done} runs in {outcome.wall_s:.1f} s ({outcome.failed} failed, "
        f"{outcome.skipped} from earlier sessions); rows in {results.rows_dir}"
    )
    for r in rows:
        if r["status"] != "ok":
            console.print(
                f"[red]{r['status']}[/] point {r['point']} seed {r['seed']}: {r['error']}"
            )
    if json:
        doc = {"rows": [json_row(r) for r in rows], "summary": summaries}
        typer.echo(json_lib.dumps(json_safe(doc)))
    else:
        out = type(console)(file=sys.stdout, width=None if sys.stdout.isatty() else 220)
        out.print(table(summaries))


def _plot(directory: Path, console) -> None:
    from sim.sweep.plots import plot_sweep
    from sim.sweep.results import ResultsDir

    results = ResultsDir(directory)
    rows = results.read()
    if not rows:
        raise typer.BadParameter(f"{directory} holds no sweep rows")
    for p in plot_sweep(rows, directory / "plots"):
        console.print(str(p))
