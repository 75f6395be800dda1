"""Fleet files and the daemon's clock: validation messages and clock semantics."""

import time
from pathlib import Path

import pytest

from onboard.daemon.clock import SimClockFollower
from onboard.daemon.config import ConfigError, load_fleet
from onboard.daemon.loop import agent_config

FORMATION = """
[[agent]]
id = 0
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 1
position_ned = [4.0, 0.0, -5.0]
yaw_deg = 180.0
[[agent]]
id = 2
position_ned = [2.0, 3.0, -6.0]
yaw_deg = -90.0
"""


def write(tmp_path: Path, fleet: str, formation: str = FORMATION) -> Path:
    (tmp_path / "formation.toml").write_text(formation)
    path = tmp_path / "fleet.toml"
    path.write_text(fleet)
    return path


def test_defaults_and_urls(tmp_path):
    fleet = load_fleet(write(tmp_path, 'formation = "formation.toml"\n'))
    assert fleet.n == 3
    assert fleet.mavlink_url(2) == "udpin:127.0.0.1:14542"
    assert fleet.system_id(2) == 3  # MAVLink system id = agent id + 1
    assert fleet.zenoh_port(0) == 7448 and fleet.sim_zenoh_port() == 7447
    cfg = agent_config(fleet, 1)
    assert cfg.graph.agent_id == 1 and cfg.graph.n_agents == 3
    assert len(cfg.graph.edges) == 6  # no [[edge]], no [camera]: everyone sees everyone
    # the prior is the plan scaled by prior_scale (0.6) about its centroid, not any truth
    centroid = (2.0, 1.0, -16.0 / 3.0)
    plan0 = (0.0, 0.0, -5.0)
    expected = tuple(c + 0.6 * (p - c) for p, c in zip(plan0, centroid, strict=True))
    assert cfg.graph.p_hat0_ned[0] == pytest.approx(expected, abs=1e-12)


@pytest.mark.parametrize(
    ("fleet", "needle"),
    [
        ('formation = "formation.toml"\n[rates]\ncore = 0.0\n', "rates.core: must be > 0"),
        ('formation = "formation.toml"\nmode = "dance"\n', "mode"),
        ('formation = "missing.toml"\n', "formation:"),
        ('formation = "formation.toml"\nspeed = 3\n', "unknown field"),
        (
            'formation = "formation.toml"\n[rates]\ncore = 10.0\npublish = 50.0\n',
            "rates.core must be >=",
        ),
        ('formation = "formation.toml"\nprior_scale = -1.0\n', "prior_scale"),
        (
            'formation = "formation.toml"\n[rigidity]\nlambda_min = 0.3\nlambda_safe = 0.2\n',
            "lambda_min < lambda_safe",
        ),
        ('formation = "formation.toml"\n[rigidity]\nwarmup_s = -1.0\n', "rigidity.warmup_s"),
        ('formation = "formation.toml"\n[rigidity]\ngraph = "some"\n', "rigidity.graph"),
        (
            'formation = "formation.toml"\n[limits]\nmin_alt_m = 30.0\nmax_alt_m = 20.0\n',
            "limits.min_alt_m must be < limits.max_alt_m",
        ),
        ('formation = "formation.toml"\n[limits]\nmin_alt_m = nan\n', "limits.min_alt_m"),
        ('formation = "formation.toml"\n[mavlink]\nsystem_id_base = 0\n', "system_id_base"),
        ('formation = "formation.toml"\n[sfm]\nbias_speed_m_s = -0.1\n', "sfm.bias_speed_m_s"),
        ('formation = "formation.toml"\n[sfm]\nwander_window_s = 0.0\n', "sfm.wander_window_s"),
        ('formation = "formation.toml"\n[sfm]\nwander_max = nan\n', "sfm.wander_max"),
        ('formation = "formation.toml"\n[mavlink]\nsystem_id_base = 254\n', "254..256"),
    ],
)
def test_bad_fleet_files(tmp_path, fleet, needle):
    with pytest.raises(ConfigError, match=r"fleet\.toml") as info:
        load_fleet(write(tmp_path, fleet))
    assert needle in str(info.value)


def test_ids_must_be_vehicle_indices(tmp_path):
    with pytest.raises(ConfigError, match=r"agent ids must be 0\.\.2"):
        load_fleet(
            write(tmp_path, 'formation = "formation.toml"\n', FORMATION.replace("id = 0", "id = 7"))
        )


def test_sim_clock_follower():
    clock = SimClockFollower()
    assert clock.now() is None
    clock.update(10.0, speedup=2.0, lockstep=False)
    time.sleep(0.05)
    t1 = clock.now()
    assert 10.08 <= t1 <= 10.5  # extrapolated at twice the wall rate
    clock.update(10.01, speedup=2.0, lockstep=False)  # a sample behind the extrapolation
    assert clock.now() >= t1  # never runs backwards
    clock.update(11.0, speedup=1.0, lockstep=True)  # (a jump beyond 2 s would be rejected)
    time.sleep(0.02)
    assert clock.now() == 11.0  # lockstep: holds until the next step


FORMATION4 = (
    FORMATION
    + """
[[agent]]
id = 3
position_ned = [2.0, -3.0, -7.5]
yaw_deg = 90.0
"""
)


def test_rigidity_section_reaches_the_core_and_refuses_a_safe_level_above_the_plan(tmp_path):
    from onboard.daemon.config import planned_rigidity_eigenvalue

    rig = "[rigidity]\nmaintenance = true\nfov_deg = 360.0\n"
    fleet = load_fleet(
        write(tmp_path, f'formation = "formation.toml"\n{rig}lambda_safe = 0.05\n'
              'lambda_min = 0.005\n', FORMATION4)
    )  # fmt: skip
    cfg = agent_config(fleet, 0)
    assert cfg.rigidity.rigidity_maintenance and cfg.rigidity.rigidity_scale_from_sfm
    assert (
        len(cfg.rigidity.rigidity_edges) == 12
        and cfg.rigidity.lambda_safe == 0.05
        and cfg.rigidity.fov_deg == 360.0
    )
    assert cfg.rigidity.rigidity_period_s == 1.0 / 20.0
    lam = planned_rigidity_eigenvalue(fleet.formation, fleet.config.rigidity)
    assert 0.05 < lam < 100.0
    # a safe level above the planned formation's eigenvalue would fight the formation
    with pytest.raises(ConfigError, match="lambda_safe") as info:
        load_fleet(
            write(tmp_path, f'formation = "formation.toml"\n{rig}lambda_safe = {2 * lam}\n'
                  'lambda_min = 0.01\n', FORMATION4)
        )  # fmt: skip
    assert f"{lam:.3g}" in str(info.value)
    # three agents: the distributed estimate cannot work (docs/demo.md)
    with pytest.raises(ConfigError, match="at least 4 agents"):
        load_fleet(write(tmp_path, f'formation = "formation.toml"\n{rig}'))
    # off by default: the core has no rigidity layer
    plain = agent_config(load_fleet(write(tmp_path, 'formation = "formation.toml"\n')), 0)
    assert not plain.rigidity.rigidity_maintenance and plain.rigidity.rigidity_edges == ()


def test_zenoh_settings_on_loopback_by_default(tmp_path):
    fleet = load_fleet(write(tmp_path, 'formation = "formation.toml"\n'))
    s = fleet.zenoh_settings(1)
    assert list(s.listen) == ["tcp/127.0.0.1:7449"]
    assert list(s.connect) == ["tcp/127.0.0.1:7447", "tcp/127.0.0.1:7448", "tcp/127.0.0.1:7450"]
    assert not s.multicast_scouting and s.config_file is None


def test_zenoh_settings_for_a_team_network(tmp_path):
    text = (
        'formation = "formation.toml"\n[zenoh]\nlisten = ["tcp/0.0.0.0:{port}"]\n'
        'connect = ["tcp/192.168.1.20:7448"]\nmulticast_scouting = true\n'
        'config_file = "zenoh.json5"\n'
    )
    (tmp_path / "zenoh.json5").write_text("{}\n")  # a missing file is a ConfigError (issue 23)
    fleet = load_fleet(write(tmp_path, text))
    s = fleet.zenoh_settings(2)
    assert list(s.listen) == ["tcp/0.0.0.0:7450"]  # the wildcard covers loopback
    assert list(s.connect)[-1] == "tcp/192.168.1.20:7448"
    assert s.multicast_scouting
    assert s.config_file == str(tmp_path / "zenoh.json5")
    text = 'formation = "formation.toml"\n[zenoh]\nlisten = ["tcp/10.0.0.3:{port}"]\n'
    s = load_fleet(write(tmp_path, text)).zenoh_settings(0)
    assert list(s.listen) == ["tcp/127.0.0.1:7448", "tcp/10.0.0.3:7448"]


def test_an_agent_listening_on_every_interface_is_reachable_off_loopback(tmp_path):
    """A real session from the settings: a peer reaches it at 127.0.0.2, which only the
    wildcard listener accepts (the loopback one is bound to 127.0.0.1)."""
    from messages.transport import ZenohSettings, open_session
    from sim.server import free_port_base

    base = free_port_base(4, span=10)
    text = f'formation = "formation.toml"\n[zenoh]\nport_base = {base}\nlisten = ["tcp/0.0.0.0:{{port}}"]\n'
    settings = load_fleet(write(tmp_path, text)).zenoh_settings(0)
    agent = open_session(settings)
    peer = open_session(ZenohSettings(connect=[f"tcp/127.0.0.2:{base + 1}"]))
    got: list[bytes] = []
    try:
        agent.declare_subscriber("bf/t/probe", lambda s: got.append(s.payload.to_bytes()))
        deadline = time.monotonic() + 5.0
        while not got and time.monotonic() < deadline:
            peer.put("bf/t/probe", b"hello")
            time.sleep(0.1)
    finally:
        peer.close()
        agent.close()
    assert got and bytes(got[0]) == b"hello"


def test_sfm_section_reaches_the_core(tmp_path):
    default = agent_config(load_fleet(write(tmp_path, 'formation = "formation.toml"\n')), 0)
    assert default.scale.sfm_bias_speed_m_s == 0.1 and default.scale.sfm_wander_max == 0.02
    off = 'formation = "formation.toml"\n[sfm]\nbias_speed_m_s = 0.0\nwander_max = 0.0\n'
    cfg = agent_config(load_fleet(write(tmp_path, off)), 1)
    assert cfg.scale.sfm_bias_speed_m_s == 0.0 and cfg.scale.sfm_wander_max == 0.0
