"""``bearingflock sim`` and ``bearingflock scenario`` command-line errors (running it is covered by the e2e tests)."""

from __future__ import annotations

import json

import pytest
import typer
from typer.testing import CliRunner

from sim.cli import sim
from sim.scenario_cli import scenario

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
    r = runner.invoke(app, ["--dynamics", "wobbly"])
    assert r.exit_code == 2 and "dynamics" in r.output


def test_negative_seed_is_a_usage_error():
    r = runner.invoke(app, ["--seed", "-1"])
    assert r.exit_code == 2 and "--seed" in r.output


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["scale-active", "--seed", "-1"], "--seed"),
        (["scale-active", "--duration", "nan"], "duration"),
        (["scale-active", "--duration", "0"], "duration"),
        (["scale-active", "--latency", "-0.1"], "latency"),
        (["scale-active", "--bearing-noise-deg", "nan"], "bearing noise"),
        (["scale-active", "--loss", "1"], "loss"),
        (["no-such-scenario"], "unknown scenario"),
        (["scale-active", "--engine", "gpu"], "unknown engine"),
    ],
)
def test_scenario_bad_options_exit_2(args: list[str], message: str) -> None:
    scenario_app = typer.Typer()
    scenario_app.command()(scenario)
    r = runner.invoke(scenario_app, args)
    assert r.exit_code == 2 and message in r.output, r.output


def test_scenario_with_the_compiled_engine_prints_its_result() -> None:
    scenario_app = typer.Typer()
    scenario_app.command()(scenario)
    args = ["scale-active", "--engine", "compiled", "--duration", "0.5", "--json"]
    r = runner.invoke(scenario_app, args)
    assert r.exit_code == 0, r.output
    result = json.loads(r.output.strip().splitlines()[-1])
    assert result["engine"] == "compiled" and result["duration_s"] == 0.5
    assert result["final_scale_ratio"] > 0.0
