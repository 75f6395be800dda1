"""``python -m onboard.daemon`` takes the command line of ``bearingflock agent`` (issue 27).

The lean entry point's argparse parser (``onboard/daemon/entry.py``) and the typer command of
``bearingflock agent`` (``groundstation/agent_cli.py``) are both built from the plain option
table ``onboard.daemon.options.AGENT_OPTIONS``; this compares the argparse parser with the
click command typer builds: option names, which are required and repeatable,
defaults, the values a full command line parses to, and the ``--system-id`` range.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import typer
import typer.main

from groundstation.agent_cli import agent_command
from onboard.daemon.entry import agent_parser

ROOT = Path(__file__).resolve().parents[2]
TYPER_ONLY = {"install_completion", "show_completion"}  # typer's own, of a one-command app


def _typer_command() -> Any:
    app = typer.Typer()
    app.command()(agent_command)
    return typer.main.get_command(app)


def _typer_params() -> dict[str, Any]:
    return {p.name: p for p in _typer_command().params if p.name not in TYPER_ONLY}


def _argparse_actions() -> dict[str, argparse.Action]:
    return {a.dest: a for a in agent_parser()._actions if a.dest != "help"}


def test_same_options_required_repeatable_and_defaults() -> None:
    click_params, actions = _typer_params(), _argparse_actions()
    assert list(actions) == list(click_params)
    for name, p in click_params.items():
        a = actions[name]
        assert a.option_strings == p.opts + p.secondary_opts, name
        assert a.required == p.required, name
        assert isinstance(a, argparse._AppendAction) == p.multiple, name
        assert (a.nargs == 0) == bool(p.is_flag), name
        if not p.multiple and not p.required:
            assert a.default == p.default, name


@pytest.mark.parametrize(
    "argv",
    [
        ["--id", "1", "--config", "fleet.toml"],
        ["--id", "3", "--config", "f.toml", "--mavlink", "udpin:0.0.0.0:14550",
         "--backend", "pymavlink", "--json-status", "--log-level", "debug", "--bearings",
         "camera", "--camera", "a.toml", "--camera", "b.toml", "--markers", "m.toml",
         "--camera-device", "0", "--system-id", "7", "--clock-offset", "-0.25", "--profile"],
    ],
)  # fmt: skip
def test_a_command_line_parses_to_the_same_arguments(argv: list[str]) -> None:
    typer_values = _typer_command().make_context("agent", list(argv)).params
    assert agent_parser().options(argv) == typer_values


@pytest.mark.parametrize("value", ["0", "256"])
def test_system_id_out_of_range_is_a_usage_error_in_both(value: str) -> None:
    argv = ["--id", "0", "--config", "f.toml", "--system-id", value]
    with pytest.raises(typer.BadParameter):
        _typer_command().make_context("agent", list(argv))
    with pytest.raises(SystemExit) as exc:
        agent_parser().options(argv)
    assert exc.value.code == 2


def test_lean_entry_point_exits_like_the_agent_command(tmp_path: Path) -> None:
    """A fleet file that cannot be read: both print the daemon's error and exit 2."""
    missing = str(tmp_path / "missing.toml")
    runs = [
        subprocess.run(
            [sys.executable, "-m", *entry, "--id", "0", "--config", missing],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=60,
        )
        for entry in (["onboard.daemon"], ["groundstation.cli", "agent"])
    ]
    assert [r.returncode for r in runs] == [2, 2]
    assert runs[0].stderr.strip() == runs[1].stderr.strip()
    assert "missing.toml" in runs[0].stderr
