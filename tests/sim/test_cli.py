"""``bearingflock sim`` command-line errors (running it is covered by the e2e tests)."""

from __future__ import annotations

import typer
from typer.testing import CliRunner

from sim.cli import sim

app = typer.Typer()
app.command()(sim)
runner = CliRunner()


def test_bad_formation_file_is_a_clear_error(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[[agent]]\nid = 1\n")
    r = runner.invoke(app, ["--layout", str(bad)])
    assert r.exit_code == 2
    assert "error" in r.output and "bad.toml" in r.output


def test_bad_options():
    assert runner.invoke(app, ["--flavour", "betaflight"]).exit_code == 2
    r = runner.invoke(app, ["--lockstep"])
    assert r.exit_code == 2 and "zenoh" in r.output
    r = runner.invoke(app, ["--speedup", "0", "--port-base", "31000"])
    assert r.exit_code == 2 and "speedup" in r.output
    r = runner.invoke(app, ["--signing-key", "/nonexistent/key"])
    assert r.exit_code == 2 and "signing key" in r.output
