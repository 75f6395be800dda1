"""``bearingflock agent``: the daemon's typer command, built from its plain option table.

The options live in :data:`onboard.daemon.options.AGENT_OPTIONS` so the vehicle's lean entry
point (``python -m onboard.daemon``, ``onboard/daemon/entry.py``) reads them with
:mod:`argparse` and never imports typer (issue 27, onboard footprint). Here the same table
becomes the typer signature of :func:`agent_command`: each option an
``Annotated[type, typer.Option(...)]`` parameter, so ``bearingflock agent --help`` and its
parsing are typer's as before (``tests/onboard/test_daemon_entry.py`` compares both parsers).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Annotated, Any

import typer

from onboard.daemon.options import AGENT_HELP, AGENT_OPTIONS, AgentOption


def _annotation(opt: AgentOption) -> Any:
    """The typer annotation of ``opt``: ``T``, ``T | None`` or ``list[T] | None``."""
    info = typer.Option(*opt.decls, help=opt.help, min=opt.low, max=opt.high)
    kind: Any = opt.kind
    if opt.repeatable:
        kind = list[kind] | None  # type: ignore[valid-type]
    elif opt.default is None:
        kind = kind | None
    return Annotated[kind, info]


def _command() -> Callable[..., None]:
    """A function with the typer signature of :data:`AGENT_OPTIONS` that runs the daemon."""

    def agent(**options: Any) -> None:
        from onboard.daemon.cli import agent as run

        run(**options)

    params = [
        inspect.Parameter(
            opt.name,
            inspect.Parameter.POSITIONAL_OR_KEYWORD,
            default=inspect.Parameter.empty if opt.required else opt.default,
            annotation=_annotation(opt),
        )
        for opt in AGENT_OPTIONS
    ]
    agent.__signature__ = inspect.Signature(params, return_annotation=None)  # type: ignore[attr-defined]
    agent.__annotations__ = {p.name: p.annotation for p in params} | {"return": None}
    agent.__doc__ = AGENT_HELP
    return agent


agent_command = _command()
"""``bearingflock agent``'s command function (``app.command("agent")(agent_command)``)."""
