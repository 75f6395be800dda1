"""Paper 001's experiment in the headless SE(3) runner (``bearingflock scenario ekf-se3``)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from sim.se3_runner import (
    ARENA_HALF_XY_M,
    ARENA_HEIGHT_M,
    Se3RunConfig,
    run_se3,
    true_angular_velocity,
    true_positions,
)


@pytest.fixture(scope="module")
def short_run():
    return run_se3(Se3RunConfig(duration_s=12.0, singular_values_every=25))


def test_trajectories_stay_inside_the_arena_and_turn_about_every_axis():
    for t in np.linspace(0.0, 120.0, 1201):
        p, _ = true_positions(t)
        assert np.all(np.abs(p[:, :2]) <= ARENA_HALF_XY_M)
        assert np.all((p[:, 2] <= 0.0) & (p[:, 2] >= -ARENA_HEIGHT_M))
        assert np.linalg.norm(p[1] - p[2]) > 0.5 and np.min(np.linalg.norm(p[1:], axis=1)) > 1.0
    w = np.array([true_angular_velocity(t) for t in np.linspace(0.0, 60.0, 601)])
    assert np.all(w[:, 0] == 0.0)  # the reference is static
    assert np.all(np.abs(w[:, 1:]).max(axis=0) > 0.1)  # roll, pitch and yaw rates


def test_velocity_matches_the_derivative_of_the_position():
    h = 1e-6
    for t in (0.3, 7.1, 33.0):
        num = (true_positions(t + h)[0] - true_positions(t - h)[0]) / (2 * h)
        np.testing.assert_allclose(true_positions(t)[1], num, atol=1e-6)


def test_far_start_converges_in_scale_and_orientation(short_run):
    s = short_run.summary()
    assert s["initial_rotation_error"] == pytest.approx(1.0 - math.cos(math.radians(60.0)))
    assert s["initial_scale_error"] > 0.1
    assert s["final_scale_error"] < 0.02
    assert s["final_rotation_error"] < 1e-3
    assert s["time_to_scale_s"] is not None and s["time_to_scale_s"] < 10.0
    assert s["final_position_error_m"] < 0.1


def test_fig1_ranks_rigidity_11_and_both_dboms_12(short_run):
    """Normalized singular values: R_A has 7 zeros (rank 6N - 7), the DBOMs 6 (6N - 6)."""
    for sv, zeros in (
        (short_run.sv_rigidity, 7),
        (short_run.sv_dbom, 6),
        (short_run.sv_fields, 6),
    ):
        assert np.all(sv[:, -zeros:] < 1e-10)
        assert np.all(sv[:, -zeros - 1] > 1e-3)


def test_time_to_scale_is_the_first_time_the_error_stays_below_2_percent(short_run):
    s = short_run.summary()
    err = short_run.scale_error
    k = int(np.searchsorted(short_run.t_s, s["time_to_scale_s"]))
    assert np.all(err[k:] < 0.02) and err[k - 1] >= 0.02


def test_cli_json_and_plots(tmp_path):
    from sim.scenario_cli import scenario

    app = typer.Typer()
    app.command()(scenario)
    res = CliRunner().invoke(
        app, ["ekf-se3", "--duration", "0.5", "--json", "--seed", "3", "--plot", str(tmp_path)]
    )
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["scenario"] == "ekf-se3" and out["seed"] == 3
    assert {"final_scale_error", "final_rotation_error", "time_to_scale_s"} <= out.keys()
    assert out["bearing_noise_deg"] == pytest.approx(1.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "ekf-se3_fig1.png",
        "ekf-se3_fig2.png",
        "ekf-se3_fig3.png",
    ]
    bad = CliRunner().invoke(app, ["ekf-se3", "--duration", "1", "--loss", "0.1"])
    assert bad.exit_code != 0
