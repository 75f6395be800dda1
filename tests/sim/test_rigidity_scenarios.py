"""Paper 003 scenarios in the headless runner: setup, the runner's virtual field of view,
short runs of the warm-up (estimators converge, nobody moves) and the CLI's JSON."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from messages.agent import OwnMeasurements
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.geometry import camera_axis_ned
from onboard.graph import complete_graph, sensing_graph
from onboard.rigidity.angle import is_infinitesimally_angle_rigid
from sim.rigidity_scenarios import (
    FOV_DEG,
    RANGE_M,
    RIGIDITY_SCENARIOS,
    agent_configs,
    initial_configuration,
    rigid_alignment_error,
    run_rigidity_scenario,
    target_path,
)
from sim.runner import RunnerConfig, run


@pytest.mark.parametrize("seed", range(5))
def test_start_is_iar_with_cameras_toward_the_barycenter(seed: int) -> None:
    p, yaw = initial_configuration(5, seed)
    c = p.mean(axis=0)
    to_c = (c - p)[:, :2] / np.linalg.norm((c - p)[:, :2], axis=1, keepdims=True)
    np.testing.assert_allclose(camera_axis_ned(yaw)[:, :2], to_c, atol=1e-12)
    assert np.all(np.abs(p[:, :2]) <= 2.0) and np.all(np.abs(p[:, 2] + 6.0) <= 2.0)
    assert is_infinitesimally_angle_rigid(p, sensing_graph(p, yaw, FOV_DEG, RANGE_M))


def test_setup_is_deterministic_per_seed() -> None:
    a, pa, _ = agent_configs("rigidity-tracking", 3)
    b, pb, _ = agent_configs("rigidity-tracking", 3)
    c, pc, _ = agent_configs("rigidity-tracking", 4)
    assert a == b and np.array_equal(pa, pb)
    assert a[0].graph.p_hat0_ned != c[0].graph.p_hat0_ned and not np.array_equal(pa, pc)
    assert [x.rigidity.track_target for x in a] == [0, 1, 2, -1, -1]
    assert all(x.rigidity.rigidity_maintenance for x in a)
    off, _, _ = agent_configs("rigidity-tracking-off", 3)
    assert not any(x.rigidity.rigidity_maintenance for x in off)
    path = target_path("rigidity-tracking", 3, pa.mean(axis=0))
    np.testing.assert_array_equal(path(0.0), path(2.0))  # targets wait for the warm-up
    assert not np.allclose(path(10.0), path(0.0))
    sphere = target_path("rigidity-sphere", 3, pa.mean(axis=0))
    assert np.linalg.norm(sphere(20.0)[0] - pa.mean(axis=0)) == pytest.approx(9.0)


def test_runner_field_of_view_limits_bearings() -> None:
    p, yaw = initial_configuration(5, 1)
    yaw = yaw.copy()
    yaw[0] += np.pi  # agent 0 looks away from everyone
    edges = tuple((int(i), int(j)) for i, j in complete_graph(5))
    seen: list[set[int]] = [set() for _ in range(5)]

    class Spy(AgentCore):
        def step(self, t_s: float, own: OwnMeasurements, inbox=()):
            seen[self.id] |= {b.target for b in own.bearings}
            return super().step(t_s, own, inbox)

    import sim.runner as runner_mod

    base = runner_mod.AgentCore
    runner_mod.AgentCore = Spy
    try:
        prior = tuple(tuple(float(x) for x in row) for row in p)
        configs = [
            build_config(agent_id=i, n_agents=5, edges=edges, mode="hold", p_hat0_ned=prior)
            for i in range(5)
        ]
        rc = RunnerConfig(duration_s=0.05, dt_s=0.01, fov_deg=FOV_DEG, sensing_range_m=RANGE_M)
        run(configs, p, yaw, rc)
    finally:
        runner_mod.AgentCore = base
    truth = sensing_graph(p, yaw, FOV_DEG, RANGE_M)
    for i in range(5):
        assert seen[i] == set(truth[truth[:, 0] == i, 1].tolist())
    assert seen[0] == set()


def test_rigid_alignment_error_ignores_rotation_and_translation() -> None:
    p, _ = initial_configuration(6, 2)
    r = np.array([[0.0, -1.0, 0.0], [0.6, 0.0, 0.8], [-0.8, 0.0, 0.6]])
    assert rigid_alignment_error(p @ r.T + 3.0, p) < 1e-12
    assert rigid_alignment_error(1.1 * p, p) > 0.01


@pytest.fixture(scope="module")
def warmup_run():
    # a 100 Hz loop keeps the test fast (the eigen-estimator's gains are per message round)
    return run_rigidity_scenario(
        "rigidity-tracking", seed=1, duration_s=3.0, dt_s=0.01, record_every=10
    )


def test_warmup_converges_estimators_without_moving(warmup_run) -> None:
    rr = warmup_run
    assert rr.rec.dropped == {}
    np.testing.assert_array_equal(rr.rec.p_ned[-1], rr.rec.p_ned[0])  # hovering
    err = rr.localization_error
    assert err[0] > 0.2 and err[-1] < 0.2 * err[0]
    central = rr.lambda_central_est[-1]
    assert central > 0.0
    np.testing.assert_allclose(rr.lambda_hat[-1], central, rtol=0.05)
    assert abs(rr.lambda_true[-1] - central) < 0.15 * rr.lambda_true[-1]


def test_summary_has_the_acceptance_fields(warmup_run) -> None:
    s = warmup_run.summary()
    for key in (
        "scenario",
        "seed",
        "min_rigidity_eigenvalue",
        "fraction_time_rigid",
        "targets_tracked",
        "final_localization_error",
        "distributed_eigen_error_max",
    ):
        assert key in s
    # nobody moves during the warm-up: the IAR start stays rigid, above the barrier level
    assert s["fraction_time_rigid"] == 1.0
    assert s["min_rigidity_eigenvalue"] == pytest.approx(float(warmup_run.lambda_true[0]))
    assert s["stayed_above_lambda_min"] and not s["rigidity_lost"]
    assert s["distributed_eigen_error_max"] < 0.05


def test_cli_json_for_a_rigidity_scenario() -> None:
    import typer

    from sim.scenario_cli import scenario

    app = typer.Typer()
    app.command()(scenario)
    res = CliRunner().invoke(app, ["rigidity-sphere", "--duration", "0.1", "--json", "--seed", "2"])
    assert res.exit_code == 0, res.output
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["scenario"] == "rigidity-sphere" and out["seed"] == 2
    assert out["n_targets"] == 1
    assert set(RIGIDITY_SCENARIOS) == {
        "rigidity-tracking",
        "rigidity-tracking-off",
        "rigidity-sphere",
    }
