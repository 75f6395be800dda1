"""``bearingflock plan``: place bearing landmarks for a set of setpoints (paper 004).

The command function :func:`plan` is registered on the main typer app by
``groundstation/cli.py``. Heavy imports (casadi, nlopt, matplotlib) happen inside it, so
``bearingflock --help`` stays fast.
"""

from __future__ import annotations

import enum
import json
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

if TYPE_CHECKING:
    from groundstation.planner.problem import PlacementProblem, PlacementResult


class Method(str, enum.Enum):
    ipopt = "ipopt"
    greedy = "greedy"
    isres = "isres"


def _fail(message: str, code: int) -> typer.Exit:
    """Print ``message`` as one line on stderr and return the exit to raise."""
    from rich.console import Console
    from rich.markup import escape

    Console(stderr=True, highlight=False, soft_wrap=True).print(
        f"[bold red]error:[/] {escape(message)}", markup=True
    )
    return typer.Exit(code)


def plan(
    setpoints: Annotated[
        Path, typer.Argument(help="Setpoints TOML file (see docs/planner.md).", show_default=False)
    ],
    landmarks: Annotated[int, typer.Option("--landmarks", "-m", help="Number of landmarks M.")],
    method: Annotated[Method, typer.Option(help="Solver.")] = Method.ipopt,
    fov: Annotated[
        float | None,
        typer.Option(help="Camera field of view (deg): landmarks on the ground, in view."),
    ] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the random starts (ipopt, isres).")] = 0,
    starts: Annotated[int, typer.Option(help="IPOPT multi-start count.")] = 5,
    compile_c: Annotated[
        bool,
        typer.Option(
            "--compile",
            help="ipopt: compile the derivatives to C (needs a C compiler; 20-40 s once per "
            "problem shape, cached under ~/.cache/bearingflock), then each solve is ~1.8x faster.",
        ),
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    plot: Annotated[Path | None, typer.Option(help="Write a figure (png, pdf, svg).")] = None,
) -> None:
    """Place M landmarks minimizing the worst setpoint's position uncertainty (paper 004)."""
    from groundstation.planner.problem import PlannerError, ProblemError
    from groundstation.planner.setpoints import (
        SetpointsError,
        load_setpoints,
        problem_from_spec,
    )

    if landmarks < 1:
        raise _fail(f"--landmarks must be at least 1, got {landmarks}", 2)
    if starts < 1:
        raise _fail(f"--starts must be at least 1, got {starts}", 2)
    try:
        spec = load_setpoints(setpoints)
        problem = problem_from_spec(spec, landmarks, fov, source=str(setpoints))
    except SetpointsError as exc:
        raise _fail(str(exc), 2) from None
    try:
        result = _solve(problem, method, seed, starts, compile_c)
    except ProblemError as exc:
        raise _fail(f"{setpoints}: {exc}", 2) from None
    except PlannerError as exc:
        raise _fail(str(exc), 1) from None
    if plot is not None:
        from groundstation.planner.plot import plot_placement

        try:
            plot_placement(problem, result, plot)
        except (OSError, ValueError) as exc:
            raise _fail(f"cannot write plot {plot}: {exc}", 1) from None
    if as_json:
        typer.echo(json.dumps(result_to_json(result)))
    else:
        _print_result(result, plot)


def _solve(
    problem: PlacementProblem, method: Method, seed: int, starts: int, compile_c: bool
) -> PlacementResult:
    if compile_c and method is not Method.ipopt:
        raise _fail("--compile applies to --method ipopt only", 2)
    if compile_c:  # the first solve of a shape compiles: say so, and time the solve alone
        import time

        from rich.console import Console

        from groundstation.planner.ipopt import IpoptPlacer

        placer = IpoptPlacer(compiled=True)
        t0 = time.perf_counter()
        with Console(stderr=True).status(
            "building the solver (compiling its derivatives to C "
            "the first time this problem shape is seen)"
        ):
            placer.prepare(problem)
        result = placer.solve(problem, seed=seed, starts=starts)
        result.details["build_seconds"] = time.perf_counter() - t0 - result.seconds
        return result
    if method is Method.ipopt:
        from groundstation.planner.ipopt import solve_ipopt

        return solve_ipopt(problem, seed=seed, starts=starts)
    if method is Method.greedy:
        from groundstation.planner.greedy import solve_greedy

        return solve_greedy(problem)
    from groundstation.planner.isres import solve_isres

    return solve_isres(problem, seed=seed)


def result_to_json(result: PlacementResult) -> dict[str, object]:
    """The ``--json`` object: method, objective, landmarks, traces, radii, headings, seconds."""
    import numpy as np

    return {
        "method": result.method,
        "objective": result.objective,
        "landmarks": result.landmarks_ned.tolist(),
        "setpoint_traces": result.setpoint_traces.tolist(),
        "setpoint_radii": np.sqrt(result.setpoint_traces).tolist(),
        "headings_deg": None
        if result.headings_rad is None
        else np.degrees(result.headings_rad).tolist(),
        "seconds": result.seconds,
        "details": {
            k: v for k, v in result.details.items() if isinstance(v, int | float | str | list)
        },
    }


def _print_result(result: PlacementResult, plot: Path | None) -> None:
    import numpy as np
    from rich.console import Console
    from rich.markup import escape
    from rich.table import Table

    console = Console()
    lm = Table(title=f"landmarks ({result.method})")
    for col in ("#", "north (m)", "east (m)", "down (m)"):
        lm.add_column(col, justify="right")
    for j, z in enumerate(result.landmarks_ned):
        lm.add_row(str(j), *(f"{c:.2f}" for c in z))
    console.print(lm)
    sp = Table(title="setpoint uncertainty")
    for col in ("#", "trace (m^2)", "1-sigma radius (m)"):
        sp.add_column(col, justify="right")
    if result.headings_rad is not None:
        sp.add_column("heading (deg)", justify="right")
    for i, tr in enumerate(result.setpoint_traces):
        row = [str(i), f"{tr:.4g}", f"{np.sqrt(tr):.3g}"]
        if result.headings_rad is not None:
            row.append(f"{np.degrees(result.headings_rad[i]):.1f}")
        sp.add_row(*row)
    console.print(sp)
    build = result.details.get("build_seconds")
    built = "" if build is None else f" (+ {build:.1f} s to build the compiled solver)"
    console.print(
        f"objective (worst trace): [bold]{result.objective:.4g}[/] m^2, "
        f"1-sigma radius {np.sqrt(result.objective):.3g} m, {result.seconds:.2f} s{built}"
    )
    if plot is not None:
        console.print(f"figure written to {escape(str(plot))}")
