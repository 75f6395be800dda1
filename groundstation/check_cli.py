"""``bearingflock check FORMATION``: print the rigidity report of a formation file."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import msgspec
import typer
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from messages.formation import FormationError, load_formation

if TYPE_CHECKING:
    from groundstation.check import CheckReport

EXIT_RIGID, EXIT_NOT_RIGID, EXIT_INVALID = 0, 1, 2


def check(
    formation: Annotated[Path, typer.Argument(help="Formation file (TOML), see the README.")],
    json: Annotated[
        bool, typer.Option("--json", help="Print the report as one JSON object.")
    ] = False,
) -> None:
    """Rigidity report of a formation: IBR in R^3 x S^1 and SE(3), angle rigidity, eigenvalues,
    scale observability under motion, degenerate agents and critical edges.

    Exit status 0 when the formation is infinitesimally bearing rigid in R^3 x S^1, 1 when it is
    not, 2 when the file is invalid.
    """
    from groundstation.check import analyze  # scipy: imported only when the command runs

    try:
        report = analyze(load_formation(formation))
    except FormationError as exc:
        Console(stderr=True).print(
            f"[red]error:[/red] {escape(str(exc))}", highlight=False, soft_wrap=True
        )
        raise typer.Exit(EXIT_INVALID) from None
    if json:
        sys.stdout.write(msgspec.json.encode(report).decode() + "\n")
    else:
        render(report, Console())
    raise typer.Exit(EXIT_RIGID if report.ibr_r3s1 else EXIT_NOT_RIGID)


def _verdict(ok: bool) -> str:
    return "[green]yes[/green]" if ok else "[red]no[/red]"


def render(report: CheckReport, console: Console) -> None:
    """Human-readable report: agents, graph, rigidity tests, observability, weak points."""
    console.rule(f"[bold]{report.name}[/bold]: {report.n_agents} agents, {report.n_edges} edges")
    agents = Table(title="Agents", title_justify="left")
    for col in ("id", "position NED (m)", "yaw (deg)", "fov (deg)", "range (m)", "sees", "seen by"):
        agents.add_column(col, justify="right")
    for a in report.agents:
        agents.add_row(
            str(a.id),
            ", ".join(f"{x:.1f}" for x in a.position_ned),
            f"{a.yaw_deg:.1f}",
            f"{a.fov_deg:.0f}",
            f"{a.range_m:.1f}",
            str(a.out_degree),
            str(a.in_degree),
        )
    console.print(agents)
    source = {
        "file": "the file's [[edge]] list",
        "camera": "camera field of view and range",
        "complete": "everyone sees everyone (no [camera], no [[edge]])",
    }[report.edge_source]
    console.print(f"Edges ({escape(source)}): " + ", ".join(f"{i}->{j}" for i, j in report.edges))
    console.print(
        "Reciprocal pairs: "
        + (", ".join(f"{i}<->{j}" for i, j in report.reciprocal_pairs) or "[red]none[/red]")
    )
    tests = Table(title="Rigidity", title_justify="left")
    for col in ("test", "rank", "expected", "rigid", "rigidity eigenvalue"):
        tests.add_column(col, justify="right" if col != "test" else "left")
    tests.add_row(
        "bearing, R^3 x S^1 (paper 000)",
        str(report.rank_r3s1),
        str(report.expected_rank_r3s1),
        _verdict(report.ibr_r3s1),
        f"{report.rigidity_eigenvalue_bearing:.4g}",
    )
    tests.add_row(
        "bearing, SE(3) (paper 001)",
        str(report.rank_se3),
        str(report.expected_rank_se3),
        _verdict(report.ibr_se3),
        f"{report.rigidity_eigenvalue_se3:.4g}",
    )
    tests.add_row(
        "angle (paper 003)",
        str(report.rank_angle),
        str(report.expected_rank_angle),
        _verdict(report.iar),
        f"{report.rigidity_eigenvalue_angle:.4g}",
    )
    if report.rigidity_eigenvalue_angle_weighted is not None:
        tests.add_row(
            "angle, fov + range weighted",
            "",
            "",
            "",
            f"{report.rigidity_eigenvalue_angle_weighted:.4g}",
        )
    tests.add_row(
        "observability, moving (paper 001)",
        f"{report.rank_observability_static} -> {report.rank_observability_moving}",
        str(report.expected_rank_observability_moving),
        _verdict(report.scale_observable_moving),
        "",
    )
    console.print(tests)
    console.print(
        f"Scale observable when moving ({report.velocities} velocities): "
        f"{_verdict(report.scale_observable_moving)}"
    )
    theorem = "holds" if report.paper003_theorem_holds else "[red]does not hold (degenerate?)[/red]"
    console.print(f"Paper 003 theorem (IBR <=> IAR and >= 2 bearings each): {theorem}")
    if report.degenerate_vertices:
        console.print("[yellow]Degenerate agents:[/yellow]")
        for d in report.degenerate_vertices:
            console.print(f"  agent {d.id}: {d.reason}")
    if report.ibr_r3s1:
        crit = ", ".join(f"{i}->{j}" for i, j in report.critical_edges)
        console.print(f"Edges whose loss alone breaks rigidity: {crit or 'none'}")
    for note in report.notes:
        console.print(f"[yellow]note:[/yellow] {note}")
    verdict = (
        "[bold green]RIGID[/bold green]" if report.ibr_r3s1 else "[bold red]NOT RIGID[/bold red]"
    )
    console.print(f"Verdict: {verdict} (infinitesimal bearing rigidity in R^3 x S^1)")
