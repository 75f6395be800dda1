"""The daemon's lean command line: ``python -m onboard.daemon --id I --config FLEET.toml``.

``bearingflock agent`` (``groundstation/cli.py``) assembles every subcommand of the toolkit
before it parses a word: the simulator's and the ground station's command modules, and typer
0.29, which coerces every option through a pydantic ``TypeAdapter`` (``typer/_coercion.py``),
loads pydantic and pydantic-core. A vehicle needs none of it: measured in a fresh interpreter,
the daemon's modules take 51 MB resident from this entry point against 65 MB from
``groundstation.cli`` (issue 27, onboard footprint; ``tests/onboard/test_daemon_imports.py``).

The options are not written twice: :func:`agent_parser` builds an :mod:`argparse` parser from
the typer options of :func:`onboard.daemon.cli.agent` itself (names, types, defaults, help,
``min``/``max``), so ``python -m onboard.daemon`` and ``bearingflock agent`` take the same
command line and call the same function (``tests/onboard/test_daemon_entry.py`` compares the
two parsers). A usage error exits 2 (as typer does); the daemon's own exit codes pass through.
"""

from __future__ import annotations

import argparse
import sys
import types
import typing
from collections.abc import Sequence
from pathlib import Path
from typing import Any

PROG = "python -m onboard.daemon"


def _base_type(annotation: Any) -> tuple[Any, bool]:
    """``(scalar type, repeatable)`` of an option's annotation: ``X``, ``X | None``,
    ``list[X] | None``."""
    args = [a for a in typing.get_args(annotation) if a is not type(None)]
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        annotation = args[0]
    if typing.get_origin(annotation) is list:
        return typing.get_args(annotation)[0], True
    return annotation, False


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
    from typer.utils import get_params_from_function

    from onboard.daemon.cli import agent

    parser = _Parser(prog=PROG, description=(agent.__doc__ or "").strip())
    for name, meta in get_params_from_function(agent).items():
        info = meta.default
        decls = list(info.param_decls or ()) or ["--" + name.replace("_", "-")]
        kind, repeatable = _base_type(meta.annotation)
        required = info.default is ...
        if kind is bool:
            parser.add_argument(*decls, dest=name, action="store_true", help=info.help)
            continue
        convert: Any = kind if kind in (int, float, str, Path) else str
        if info.min is not None or info.max is not None:
            convert = _ranged(kind, info.min, info.max, decls[0])
        parser.add_argument(
            *decls,
            dest=name,
            type=convert,
            action="append" if repeatable else "store",
            required=required,
            default=None if required or repeatable else info.default,
            help=info.help,
        )
        if repeatable:
            parser.repeatable.append(name)
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    """Parse ``argv`` (default ``sys.argv[1:]``) and run the daemon; exits with its code."""
    import typer

    from onboard.daemon.cli import agent

    options = agent_parser().options(argv)
    try:
        agent(**options)
    except typer.Exit as exc:  # the daemon's own exit codes (2: a bad fleet file, ...)
        sys.exit(exc.exit_code)
