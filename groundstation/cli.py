"""The ``bearingflock`` command line: one entry point, one subcommand per job.

Each subcommand lives next to the code it drives (``groundstation/check_cli.py``,
``sim/cli.py``, ...); this module only assembles them. Subcommand modules import their heavy
dependencies (Zenoh, OpenCV, casadi, matplotlib) inside the command function so that
``bearingflock --help`` stays instant. ``bearingflock agent`` runs numpy's BLAS on one thread
and loads one MAVLink dialect unless the user set the variables (``onboard/daemon/daemon_env.py``):
set before the subcommand modules import numpy or pymavlink.
"""

# the daemon's BLAS and MAVLink variables must be set before any import below loads numpy

from __future__ import annotations

import os
import sys

from onboard.daemon.daemon_env import daemon_env_defaults

os.environ.update(daemon_env_defaults(sys.argv[1:], os.environ))  # agent: one BLAS thread, ...

import typer

from groundstation.agent_cli import agent_command
from groundstation.check_cli import check
from groundstation.demo_cli import demo
from groundstation.gcs_cli import gcs_app
from groundstation.keys_cli import keys_app
from groundstation.plan_cli import plan
from groundstation.vision_cli import vision_app
from sim.cli import sim
from sim.scenario_cli import scenario
from sim.sweep.cli import sweep

app = typer.Typer(
    name="bearingflock",
    help="Bearing-only localization and formation control for multicopter teams.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.command("agent")(agent_command)
app.command("check")(check)
app.command("demo")(demo)
app.command("plan")(plan)
app.command("scenario")(scenario)
app.command("sim")(sim)
app.command("sweep")(sweep)
app.add_typer(gcs_app, name="gcs")
app.add_typer(keys_app, name="keys")
app.add_typer(vision_app, name="vision")


@app.callback()
def _root() -> None:
    """Bearing-only localization and formation control for multicopter teams."""


def main() -> None:
    """Console-script entry point. A command that needs an optional dependency the install
    lacks ends on one line naming the extra that brings it (``messages.optional``), exit 2."""
    from messages.optional import missing_extra_message

    try:
        app()
    except ModuleNotFoundError as exc:
        message = missing_extra_message(exc.name or "")
        if message is None:
            raise
        typer.echo(f"error: {message}", err=True)
        raise SystemExit(2) from None


if __name__ == "__main__":
    main()
