"""``bearingflock agent --id I --config FLEET.toml``: run one vehicle's onboard daemon."""

from __future__ import annotations

import logging
import signal
import sys
from pathlib import Path
from typing import Annotated

import typer


def agent(
    agent_id: Annotated[int, typer.Option("--id", help="This vehicle's agent id (0-based index).")],
    config: Annotated[Path, typer.Option("--config", help="Fleet file (TOML), see docs/agent.md.")],
    mavlink: Annotated[
        str | None,
        typer.Option(help="Autopilot URL (pymavlink style); default from the fleet file."),
    ] = None,
    backend: Annotated[str | None, typer.Option(help="pymavlink or mavsdk.")] = None,
    json_status: Annotated[
        bool, typer.Option("--json-status", help="Print every status as a JSON line on stdout.")
    ] = False,
    log_level: Annotated[str, typer.Option(help="debug, info, warning.")] = "info",
) -> None:
    """Run one vehicle's onboard daemon: autopilot link, bearings, Zenoh peers, agent core."""
    import msgspec

    from messages.sim import SimClock, clock_key
    from messages.transport import ZenohSettings, loopback_endpoint
    from onboard.autopilot import open_link
    from onboard.autopilot.base import LinkConfig
    from onboard.daemon.bearings import SimCameraSource
    from onboard.daemon.clock import SimClockFollower, WallClock
    from onboard.daemon.config import ConfigError, load_fleet
    from onboard.daemon.loop import AgentDaemon, agent_config
    from onboard.daemon.peers import DropCounter, PeerLink

    logging.basicConfig(
        level=getattr(logging, log_level.upper(), logging.INFO),
        format=f"%(asctime)s %(levelname)s agent={agent_id} %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        fleet = load_fleet(config)
    except ConfigError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    if not 0 <= agent_id < fleet.n:
        typer.echo(f"error: --id {agent_id}: the fleet has agents 0..{fleet.n - 1}", err=True)
        raise typer.Exit(2)
    c = fleet.config
    others = [fleet.zenoh_port(j) for j in range(fleet.n) if j != agent_id]
    settings = ZenohSettings(
        mode=c.zenoh.mode,
        listen=[loopback_endpoint(fleet.zenoh_port(agent_id))] if c.zenoh.mode == "peer" else [],
        connect=[loopback_endpoint(p) for p in [fleet.sim_zenoh_port(), *others]] + c.zenoh.connect,
        config_file=c.zenoh.config_file or None,
    )
    drops = DropCounter()
    core_config = agent_config(fleet, agent_id)
    neighbours = {j for e in core_config.edges for j in e if agent_id in e} - {agent_id}
    peers = PeerLink(c.fleet, agent_id, range(fleet.n), settings, drops, neighbours)
    if c.clock == "sim":
        follower = SimClockFollower()

        def on_clock(sample: object) -> None:
            try:
                msg = msgspec.msgpack.decode(sample.payload.to_bytes(), type=SimClock)  # type: ignore[attr-defined]
            except (msgspec.DecodeError, msgspec.ValidationError) as exc:
                drops.drop("clock_malformed", str(exc))
                return
            follower.update(msg.t_s, msg.speedup, msg.lockstep)

        peers.subscribe(clock_key(c.fleet), on_clock)
        clock = follower
    else:
        clock = WallClock()
    link = open_link(
        backend or c.mavlink.backend,
        LinkConfig(
            rate_hz=c.rates.setpoint,
            max_speed_xy_mps=c.limits.max_speed_m_s,
            max_speed_z_mps=c.limits.max_speed_m_s,
            max_yaw_rate_radps=c.limits.max_yaw_rate_rad_s,
        ),
    )
    on_status = None
    if json_status:

        def on_status(status: object) -> None:
            sys.stdout.write(msgspec.json.encode(status).decode() + "\n")
            sys.stdout.flush()

    url = mavlink or fleet.mavlink_url(agent_id)
    daemon = AgentDaemon(
        fleet, agent_id, link, peers, SimCameraSource(peers, drops), clock, drops, url, on_status
    )
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: daemon.stop_event.set())
    try:
        daemon.run()
    finally:
        link.close()
        peers.close()
