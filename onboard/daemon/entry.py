"""The daemon's lean command line: ``python -m onboard.daemon --id I --config FLEET.toml``.

``bearingflock agent`` (``groundstation/cli.py``) assembles every subcommand of the toolkit
before it parses a word: the simulator's and the ground station's command modules, and typer
0.29, which coerces every option through a pydantic ``TypeAdapter`` (``typer/_coercion.py``),
loads pydantic and pydantic-core. A vehicle needs none of it: measured in a fresh interpreter,
the daemon's modules take 51 MB resident from this entry point against 65 MB from
``groundstation.cli`` (issue 27, onboard footprint; ``tests/onboard/test_daemon_imports.py``).

The options are not written twice: :func:`agent_parser` builds an :mod:`argparse` parser from
the plain option table :data:`onboard.daemon.options.AGENT_OPTIONS` (names, types, defaults,
help, ranges), from which ``bearingflock agent`` builds its typer command
(``groundstation/agent_cli.py``), so ``python -m onboard.daemon`` and ``bearingflock agent``
take the same command line and call the same function without the daemon importing typer
(``tests/onboard/test_daemon_entry.py`` compares the two parsers). A usage error exits 2 (as
typer does); the daemon's own exit codes pass through.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from onboard.daemon.options import AGENT_HELP, AGENT_OPTIONS

PROG = "python -m onboard.daemon"


def _ranged(kind: type, low: float | None, high: float | None, name: str) -> Any:
    """An argparse type converter for ``kind`` that rejects values outside ``[low, high]``,
    as typer's ``min``/``max`` do."""

    def convert(text: str) -> Any:
        value = kind(text)
        if (low is not None and value < low) or (high is not None and value > high):
            raise argparse.ArgumentTypeError(
                f"{name}: {value} is not in the range {low}<=x<={high}"
            )
        return value

    convert.__name__ = kind.__name__
    return convert


class _Parser(argparse.ArgumentParser):
    """An argument parser that knows its repeatable options: given none, they are ``()``, as
    typer passes them (argparse would pass ``None``)."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.repeatable: list[str] = []

    def options(self, argv: Sequence[str] | None = None) -> dict[str, Any]:
        """The keyword arguments of :func:`onboard.daemon.cli.agent` for ``argv``."""
        options = vars(self.parse_args(argv))
        for name in self.repeatable:
            options[name] = options[name] or ()
        return options


def agent_parser() -> _Parser:
    """The ``agent`` command's options as an :class:`argparse.ArgumentParser`; each option's
    destination is the parameter name of :func:`onboard.daemon.cli.agent`."""
    parser = _Parser(prog=PROG, description=AGENT_HELP)
    for opt in AGENT_OPTIONS:
        if opt.kind is bool:
            parser.add_argument(*opt.flags, dest=opt.name, action="store_true", help=opt.help)
            continue
        convert: Any = opt.kind if opt.kind in (int, float, str, Path) else str
        if opt.low is not None or opt.high is not None:
            convert = _ranged(opt.kind, opt.low, opt.high, opt.flags[0])
        parser.add_argument(
            *opt.flags,
            dest=opt.name,
            type=convert,
            action="append" if opt.repeatable else "store",
            required=opt.required,
            default=None if opt.required or opt.repeatable else opt.default,
            help=opt.help,
        )
        if opt.repeatable:
            parser.repeatable.append(opt.name)
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    """Parse ``argv`` (default ``sys.argv[1:]``) and run the daemon; its :class:`SystemExit`
    (2: a bad fleet file, ...) passes through."""
    from onboard.daemon.cli import agent

    agent(**agent_parser().options(argv))
