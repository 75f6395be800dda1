"""The onboard daemon end to end: the simulator and three daemons as processes, real UDP
MAVLink, real Zenoh on loopback. The fleet file puts the altitude floor (``[limits]
min_alt_m``) above the take-off height: once flying the mission, every vehicle climbs above it
and reports ``altitude_floor`` meanwhile; and a horizontal fence (``max_radius_m``) that the
growing formation meets: no vehicle gets out of it. Faults: malformed peer payloads and MAVLink garbage
are counted and dropped; a killed agent is noticed by its peers and its autopilot fails safe;
restarted with its clock 1.5 s off, its peers name it (``peer_clock``) and it names them;
restarted again with a good clock, it rejoins; a land command brings everyone down."""

from __future__ import annotations

import math
import socket
import threading
import time

import msgspec
import pytest
from pymavlink import mavutil

pytestmark = pytest.mark.e2e
N = 3  # vehicles in the fleet (conftest.py)
FLOOR_M = 9.0
"""Altitude floor of the fleet file; the daemons take off to 5 m."""
FENCE_M = 1.5
"""Horizontal fence of the fleet file, about each autopilot's local origin (its start)."""


def test_daemons_fly_survive_bad_input_and_faults(tmp_path, fleet_with, wait_for):
    limits = f"[limits]\nmin_alt_m = {FLOOR_M}\nmax_radius_m = {FENCE_M}\n"
    with fleet_with(tmp_path, limits) as fleet:
        fly_survive_bad_input_and_faults(fleet, wait_for)


def fly_survive_bad_input_and_faults(fleet, wait_for) -> None:
    ev, procs, ports, agent_args, name = fleet
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{ports.gcs}", source_system=250)

    def all_flying() -> bool:
        st = ev.snapshot()
        return len(st) == N and all(
            s.phase == "flying" and s.autopilot_mode == "OFFBOARD" and s.in_air for s in st.values()
        )

    wait_for(all_flying, 60.0, "every daemon flying in OFFBOARD", ev)
    fence = FenceWatch(ev)

    # the altitude envelope lifts everyone from the 5 m take-off above the floor (the daemons
    # start flying one after the other: the last one has only just begun to climb)
    heights = [-float(tr.p_ned[2]) for tr in ev.truth.values()]
    assert min(heights) < FLOOR_M - 2.0, heights
    floor_alarm_seen: set[int] = set()
    clock_alarms: list[str] = []  # synchronized clocks (one simulator): must stay empty

    def above_floor() -> bool:
        floor_alarm_seen.update(k for k, s in ev.snapshot().items() if "altitude_floor" in s.alarms)
        clock_alarms.extend(a for s in ev.snapshot().values() for a in s.alarms if "clock" in a)
        return len(ev.truth) == N and all(
            -float(tr.p_ned[2]) > FLOOR_M - 0.3 for tr in ev.truth.values()
        )

    wait_for(above_floor, 30.0, f"every vehicle above the {FLOOR_M} m floor", ev)
    assert floor_alarm_seen == set(range(N))
    assert clock_alarms == []

    # bad input on the peer keys and on an agent's MAVLink port: a broken envelope, and in
    # envelopes of vehicle 1 a NaN, a vehicle not in the fleet and vehicle 2 (forged)
    def envelope(payload: dict) -> bytes:
        return msgspec.msgpack.encode({"type": "peer.envelope", "sender": 1, "payloads": [payload]})

    bad = [
        (f"bf/{name}/1/peer", b"\xc1 not msgpack"),
        (f"bf/{name}/1/peer", envelope(
            {"type": "peer.motion", "sender": 1, "v_body": [float("nan"), 0.0, 0.0],
             "yaw_rate_rad_s": 0.0, "yaw_rad": 0.0})),
        (f"bf/{name}/1/peer", envelope(
            {"type": "peer.motion", "sender": 9, "v_body": [0.0, 0.0, 0.0],
             "yaw_rate_rad_s": 0.0, "yaw_rad": 0.0})),
        (f"bf/{name}/1/peer", envelope(
            {"type": "peer.motion", "sender": 2, "v_body": [0.0, 0.0, 0.0],
             "yaw_rate_rad_s": 0.0, "yaw_rad": 0.0})),
    ]  # fmt: skip
    for k, data in bad:
        ev.session.put(k, data)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.sendto(b"\xfd\x09garbage-bytes", ("127.0.0.1", ports.mavlink + 0))

    def counted() -> bool:
        d = ev.snapshot()[0].dropped
        return (
            d.get("malformed", 0) >= 1
            and d.get("nonfinite", 0) >= 1
            and d.get("unknown_sender", 0) >= 1
            and d.get("sender_mismatch", 0) >= 1
        )

    wait_for(counted, 5.0, "agent 0 to count the four bad payloads", ev)
    assert not procs.dead()

    # kill agent 2: its peers notice within 2 s (+ status period), its autopilot fails safe
    victim = dict(procs.procs)["agent2"]
    victim.kill()
    t_kill = time.monotonic()
    noticed = wait_for(
        lambda: all("peer_lost:2" in ev.snapshot()[k].alarms for k in (0, 1)), 5.0,
        "agents 0 and 1 to report peer 2 lost", ev,
    )  # fmt: skip
    assert noticed <= 3.0

    def vehicle3_left_offboard() -> bool:
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
        return msg is not None and msg.get_srcSystem() == 3 and msg.custom_mode != (6 << 16)

    wait_for(vehicle3_left_offboard, 5.0, "vehicle 3's PX4 offboard-loss failsafe")
    assert time.monotonic() - t_kill < 5.0

    # restart it with its clock 1.5 s ahead of the team's: everyone names the disagreement
    procs.start("agent2-skewed", [*agent_args[2], "--clock-offset", "1.5"])

    def clocks_flagged() -> bool:
        st = ev.snapshot()
        return all("peer_clock:2" in st[k].alarms for k in (0, 1)) and {
            "peer_clock:0",
            "peer_clock:1",
        } <= set(st[2].alarms)

    wait_for(clocks_flagged, 15.0, "agents 0 and 1 to flag 2's clock, and 2 to flag theirs", ev)
    st = ev.snapshot()
    assert "peer_clock:1" not in st[0].alarms and "peer_clock:0" not in st[1].alarms
    dict(procs.procs)["agent2-skewed"].kill()

    # restart it with the team's clock: it rejoins (its peers clear the alarms, it publishes)
    procs.start("agent2-restart", agent_args[2])
    wait_for(
        lambda: all(
            "peer_lost:2" not in ev.snapshot()[k].alarms
            and "peer_clock:2" not in ev.snapshot()[k].alarms for k in (0, 1)
        )
        and ev.snapshot()[2].stamp_s > 0 and ev.snapshot()[2].phase in ("ready", "flying"),
        30.0, "agent 2 to rejoin", ev,
    )  # fmt: skip

    fence.stop()
    print(f"fence: largest distance from the start {fence.largest_m:.2f} m, "
          f"alarms from {sorted(fence.alarmed)}")  # fmt: skip
    assert fence.largest_m < FENCE_M + 0.3
    assert fence.alarmed  # the formation met the fence: the bound acted
    ev.command_all("land")
    wait_for(lambda: all(not s.in_air for s in ev.snapshot().values()), 40.0, "everyone landed", ev)
    assert sorted(procs.dead()) == ["agent2", "agent2-skewed"]  # only the ones we killed


class FenceWatch:
    """Samples, while the test runs, how far each vehicle is from its start (its autopilot's
    local origin, the simulator's truth) and who reports the ``fence`` alarm."""

    def __init__(self, ev) -> None:
        from groundstation.demo import plan_formation

        self.start = plan_formation(N, seed=1).p_start_ned  # the layout of conftest.py
        self.ev = ev
        self.largest_m = 0.0
        self.alarmed: set[int] = set()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(0.05):
            for k, tr in list(self.ev.truth.items()):
                d = tr.p_ned[:2] - self.start[k][:2]
                self.largest_m = max(self.largest_m, math.hypot(float(d[0]), float(d[1])))
            self.alarmed |= {k for k, st in self.ev.snapshot().items() if "fence" in st.alarms}

    def stop(self) -> None:
        self._stop.set()
        self._thread.join()
