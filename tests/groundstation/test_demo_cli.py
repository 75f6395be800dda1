"""``bearingflock demo``: argument errors exit 2 with a message; ``--headless`` flies the demo's
configurations in the headless runner and reports the same summary keys as the real demo."""

import json

import pytest
from typer.testing import CliRunner

from groundstation.cli import app

runner = CliRunner()


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--vehicles", "2"], "--vehicles"),
        (["--loss", "1.0"], "--loss"),
        (["--flavour", "inav"], "--flavour"),
        (["--bearings", "lidar"], "--bearings"),
        (["--mode", "foo"], "--mode"),
        (["--mode", "foo", "--headless"], "--mode"),
        (["--duration", "nan", "--headless"], "--duration"),
        (["--duration", "-1"], "--duration"),
        (["--seed", "-1", "--headless"], "--seed"),
        (["--speedup", "0.1"], "--speedup"),
        (["--speedup", "0"], "--speedup"),
        (["--bearings", "camera", "--render-rate", "0"], "--render-rate"),
    ],
)
def test_bad_arguments_exit_2_with_a_message(args, message):
    result = runner.invoke(app, ["demo", *args])
    assert result.exit_code == 2
    assert message in result.output


def test_headless_demo_reports_the_summary_keys():
    result = runner.invoke(
        app, ["demo", "--headless", "--vehicles", "3", "--duration", "4", "--json"]
    )
    summary = json.loads(result.stdout.strip().splitlines()[-1])
    assert result.exit_code == (0 if summary["verdict"]["pass"] else 1), result.output
    for k in ("vehicles", "time_to_scale_s", "final_scale_error", "final_bearing_error_deg",
              "min_rigidity_eigenvalue", "dropped_messages"):  # fmt: skip
        assert k in summary
    assert summary["vehicles"] == 3 and summary["headless"] is True
    assert 0.0 <= summary["final_scale_error"] < 1.0


def test_default_speed_fits_the_fleet_in_the_machine():
    from groundstation.demo_cli import CPU_BUDGET, CPU_PER_AGENT, CPU_SIMULATOR, default_speedup

    assert default_speedup(6, 16) == 1.0  # a workstation: real time
    assert default_speedup(6, 2) == 1.0  # an idle 2-core machine: real time (issue 29)
    one_core = default_speedup(6, 1)  # the other one busy
    assert 0.2 <= one_core < 1.0
    assert (CPU_PER_AGENT * 6 + CPU_SIMULATOR) * one_core <= CPU_BUDGET * 1 + 1e-9
    assert default_speedup(30, 2) == 0.2  # never slower than the tried floor
    assert default_speedup(12, 4) <= default_speedup(6, 4)
