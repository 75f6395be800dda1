"""Signed MAVLink between the simulator (per-vehicle keys from ``bearingflock keys init``), the
daemon's pymavlink link and the ground station, over real UDP sockets (issue 24): with the key
everything works; unsigned or wrongly signed commands and forged telemetry change nothing and
are counted; a link without the right key says why it cannot connect."""

from __future__ import annotations

import json
import socket
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common
from typer.testing import CliRunner

from groundstation.gcs_cli import gcs_app
from messages import mavlink as mv
from messages.fleetkeys import init_fleet, load_signing_key
from messages.mavsign import sign_outgoing
from onboard.autopilot.base import LinkConfig, LinkError
from onboard.autopilot.mavsdk_link import MavsdkLink
from onboard.autopilot.pymavlink_link import PymavlinkLink
from sim.server import SimConfig, SimServer, free_port_base
from sim.world import grid_layout

pytestmark = [pytest.mark.e2e, pytest.mark.timeout(120)]
N = 2


def _sim(keys: Path, gcs: bool = False) -> tuple[SimServer, int]:
    base = free_port_base(N, span=60)
    p, yaw = grid_layout(N)
    cfg = SimConfig(
        p, yaw, flavour="px4", client_base=base, gcs_port=base + 50 if gcs else None,
        speedup=2.0, signing_keys=[load_signing_key(keys, i) for i in range(N)],
    )  # fmt: skip
    return SimServer(cfg).start(), base


def _wait(pred, timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while not pred():
        assert time.monotonic() < deadline, "condition not reached"
        time.sleep(0.02)


def test_daemon_link_signs_and_rejects_forged_telemetry(tmp_path):
    keys = tmp_path / "keys"
    init_fleet(keys, "alpha", N)
    init_fleet(tmp_path / "other", "alpha", N)
    srv, base = _sim(keys)
    link = PymavlinkLink(LinkConfig(system_id=1, signing_key=load_signing_key(keys, 0)))
    try:
        # vehicle 1's key on vehicle 0's port: no heartbeat verifies, and the error says so
        wrong = PymavlinkLink(
            LinkConfig(system_id=1, signing_key=load_signing_key(tmp_path / "other", 0))
        )
        with pytest.raises(
            LinkError, match=r"no correctly signed autopilot heartbeat.*bad_signature"
        ):
            wrong.connect(f"udpin:127.0.0.1:{base}", timeout_s=2.0)
        link.connect(f"udpin:127.0.0.1:{base}", timeout_s=5.0)
        assert link.wait_ready(10.0).ok
        assert link.arm().ok and srv.autopilots[0].armed  # our commands are signed
        before = link.telemetry()
        assert before.mode == "AUTO.LOITER" and before.armed
        assert before.counters.signed_ok > 0 and before.counters.bad_signature == 0
        # forged vehicle heartbeats (disarmed, another mode) to the link's port
        main, sub = 6, 0  # OFFBOARD
        forged_hb = common.MAVLink_heartbeat_message(2, 12, 0, mv.px4_custom_mode(main, sub), 0, 3)
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            for key in (load_signing_key(tmp_path / "other", 0), None):
                mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
                if key is not None:
                    sign_outgoing(mav, key, 0)
                for _ in range(20):
                    s.sendto(bytes(forged_hb.pack(mav)), ("127.0.0.1", base))
                    mav.seq = (mav.seq + 1) % 256
        _wait(lambda: link.telemetry().counters.unsigned_rejected >= 20)
        after = link.telemetry()
        print(f"\nlink counters: {after.counters}")
        assert after.counters.bad_signature == 20 and after.counters.unsigned_rejected == 20
        assert after.mode == "AUTO.LOITER" and after.armed  # the forgeries changed nothing
    finally:
        link.close()
        srv.stop()


def test_mavsdk_link_refuses_to_start_with_signing_required():
    with pytest.raises(LinkError, match="cannot sign"):
        MavsdkLink(LinkConfig(signing_key=bytes(32)))


def _gcs(*args: str):
    return CliRunner().invoke(gcs_app, [*args], catch_exceptions=False)


def test_gcs_commands_and_monitor_with_and_without_the_keys(tmp_path):
    keys = tmp_path / "keys"
    init_fleet(keys, "alpha", N)
    init_fleet(tmp_path / "other", "alpha", N)
    srv, base = _sim(keys, gcs=True)
    gcs = ["--mavlink", f"udp:127.0.0.1:{base + 50}", "--zenoh", "none"]
    try:
        # without keys: the vehicles are heard, the unsigned ARMs are rejected and counted
        r = _gcs("arm", "--all", "--yes", "--json", "--discover", "1.5", "--timeout", "1", *gcs)
        assert r.exit_code == 1, r.output
        assert all(not res["ok"] for res in json.loads(r.output)["results"])
        assert not any(ap.armed for ap in srv.autopilots)
        rejected = [ap.counters.unsigned_rejected for ap in srv.autopilots]
        assert all(n >= 1 for n in rejected), rejected
        # another fleet's keys: nothing the vehicles send verifies, so nobody is heard
        r = _gcs("arm", "--all", "--yes", "--discover", "1.5", "--keys", str(tmp_path / "other"),
                 *gcs)  # fmt: skip
        assert r.exit_code == 1 and "no vehicles heard" in r.output, r.output
        assert not any(ap.armed for ap in srv.autopilots)
        bad = [ap.counters.bad_signature for ap in srv.autopilots]
        # with the fleet's keys: armed, each vehicle with its own key
        r = _gcs("arm", "--all", "--yes", "--json", "--discover", "1.5", "--keys", str(keys), *gcs)
        assert r.exit_code == 0, r.output
        assert all(ap.armed for ap in srv.autopilots)
        assert [ap.counters.bad_signature for ap in srv.autopilots] == bad
        r = _gcs("monitor", "--once", "--json", "--wait", "1.5", "--keys", str(keys), *gcs)
        assert r.exit_code == 0, r.output
        counters = json.loads(r.output)["mavlink"]["counters"]
        print(f"\nunsigned ARMs rejected per vehicle {rejected}; monitor counters {counters}")
        assert counters.get("sig_good", 0) > 10 and "sig_bad_signature" not in counters
    finally:
        srv.stop()
