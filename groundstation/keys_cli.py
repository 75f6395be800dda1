"""``bearingflock keys init | show | issue``: the fleet's certificates and MAVLink signing keys
(:mod:`messages.fleetkeys`, docs/flying.md).

Exit status: 0 success, 2 a refused or failed operation (existing files without ``--force``,
a missing CA key, a bad directory); the message is one line on stderr.
"""

from __future__ import annotations

import json as jsonlib
from dataclasses import asdict
from pathlib import Path
from typing import Annotated

import typer

EXIT_OK, EXIT_INVALID = 0, 2

keys_app = typer.Typer(
    name="keys",
    help="Fleet identity: certificate authority, vehicle and ground station certificates, "
    "MAVLink signing keys.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)

DirArg = Annotated[Path, typer.Argument(help="Key directory (the fleet file's security.dir).")]
ForceOpt = Annotated[
    bool, typer.Option("--force", help="Replace existing files (old keys stop working).")
]
DaysOpt = Annotated[int, typer.Option("--days", help="Validity of the issued certificates.")]


def _fail(msg: str) -> None:
    typer.echo(f"error: {msg}", err=True)
    raise typer.Exit(EXIT_INVALID)


@keys_app.callback()
def _keys() -> None:
    """Fleet identity: certificate authority, certificates, MAVLink signing keys."""


@keys_app.command("init")
def init(
    directory: DirArg,
    fleet: Annotated[str, typer.Option("--fleet", help="Fleet name (the certificates' O=).")],
    vehicles: Annotated[int, typer.Option("--vehicles", help="Number of vehicles, ids 0..N-1.")],
    force: ForceOpt = False,
    days: DaysOpt = 365,
) -> None:
    """Create the fleet CA, a certificate and key for each vehicle and the ground station, and
    one MAVLink signing key per vehicle link. Files are mode 0600."""
    from messages.fleetkeys import KeyStoreError, init_fleet

    try:
        written = init_fleet(directory, fleet, vehicles, force=force, days=days)
    except KeyStoreError as exc:
        _fail(str(exc))
        return
    typer.echo(f"wrote {len(written)} files to {directory}; keep ca.key offline once issued")


@keys_app.command("issue")
def issue(
    directory: DirArg,
    vehicle: Annotated[int, typer.Option("--vehicle", help="Vehicle id to add or re-issue.")],
    force: ForceOpt = False,
    days: DaysOpt = 365,
) -> None:
    """Add a vehicle (certificate, key, signing key) with the CA key in DIR."""
    from messages.fleetkeys import KeyStoreError, issue_vehicle

    try:
        written = issue_vehicle(directory, vehicle, force=force, days=days)
    except KeyStoreError as exc:
        _fail(str(exc))
        return
    typer.echo(f"wrote {', '.join(p.name for p in written)}")


@keys_app.command("show")
def show(
    directory: DirArg,
    json: Annotated[bool, typer.Option("--json", help="One JSON object per line.")] = False,
) -> None:
    """Certificates (subject, fingerprint, expiry, vehicle) and signing keys (fingerprint
    only); never a secret. Problems (expired, wrong CA, mode not 0600) are flagged."""
    from messages.fleetkeys import KeyStoreError, describe

    try:
        entries = describe(directory)
    except KeyStoreError as exc:
        _fail(str(exc))
        return
    if json:
        for e in entries:
            typer.echo(jsonlib.dumps(asdict(e)))
        return
    from rich.console import Console
    from rich.table import Table

    table = Table("file", "kind", "subject", "vehicle", "sha256 (first 16 bytes)", "expires",
                  "problem")  # fmt: skip
    for e in entries:
        v = "" if e.vehicle is None else str(e.vehicle)
        table.add_row(e.file, e.kind, e.subject, v, e.fingerprint, e.expires[:19], e.problem)
    Console(width=160).print(table)
