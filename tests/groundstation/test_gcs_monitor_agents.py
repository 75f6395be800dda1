"""A monitor started after the agents died (issue 22, bug 6): their vehicles, heard only on
MAVLink, were shown with no phase and not red. Once the monitor has listened on Zenoh for
``agent_lost_s``, a running agent would have been heard: those vehicles are ``agent_lost``."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as dialect
from rich.console import Console

from groundstation.gcs.mavlink_state import MavlinkState
from groundstation.gcs.monitor import AGENT_LOST_S, MonitorConfig, render, snapshot
from groundstation.gcs.zenoh_listener import ZenohState


def _autopilots(now: float) -> MavlinkState:
    state = MavlinkState()
    parser = dialect.MAVLink(None)
    for sysid in (1, 2):
        enc = dialect.MAVLink(None, srcSystem=sysid, srcComponent=1)
        hb = dialect.MAVLink_heartbeat_message(2, 3, 81 | 128, 4, 4, 3)  # armed, GUIDED
        (msg,) = parser.parse_buffer(hb.pack(enc))
        state.fold(msg, now - 0.5)
    return state


def test_vehicles_without_an_agent_turn_red_once_the_monitor_has_listened_long_enough():
    now, config = 50.0, MonitorConfig(fleet="alpha")
    mav, zen = _autopilots(now), ZenohState("alpha")
    early = snapshot(mav, zen, now, config, zenoh_listening_s=AGENT_LOST_S / 2)
    assert [r["alarms"] for r in early["vehicles"]] == [[], []]  # tokens may still be coming
    snap = snapshot(mav, zen, now, config, zenoh_listening_s=AGENT_LOST_S + 0.1)
    for row in snap["vehicles"]:
        assert row["phase"] is None and row["alarms"] == ["agent_lost"] and row["red"]
    assert snap["fleet_status"]["red"] == 2
    console = Console(record=True, width=160)
    console.print(render(snap))
    rows = [ln for ln in console.export_text().splitlines() if "GUIDED" in ln]
    assert len(rows) == 2 and all("no agent" in ln and "agent_lost" in ln for ln in rows)
    # without Zenoh (``--zenoh none``) nobody expects an agent
    assert not any(r["red"] for r in snapshot(mav, None, now, config, 60.0)["vehicles"])


def test_late_ticks_are_named_under_the_table():
    """A daemon whose ticks run late (issue 29) is red and the monitor says what it means."""
    import msgspec

    from messages.codec import encode
    from tests.groundstation.standin import StandinConfig, scripted_status

    now, config = 50.0, MonitorConfig(fleet="alpha")
    zen = ZenohState("alpha")
    cfg = StandinConfig("alpha", [0, 1])
    for i in (0, 1):
        status = scripted_status(cfg, i, 1.0, 1, "flying")
        if i == 1:
            status = msgspec.structs.replace(status, alarms=["ticks_late"])
        zen.fold_sample(f"bf/alpha/{i}/status", encode(status), now - 0.2)
    snap = snapshot(_autopilots(now), zen, now, config, zenoh_listening_s=10.0)
    assert [r["red"] for r in snap["vehicles"]] == [False, True]
    console = Console(record=True, width=200)
    console.print(render(snap))
    assert "ticks late on vehicle(s) 1: this machine is too slow" in console.export_text()
