"""A corrupted autopilot on a flying team (issue 23, defect 8): finite but impossible telemetry
(altitude 1e6 m, velocity 1e4 m/s) once passed ``TelemetryState.apply``; the daemon's
estimates then stayed 100-150% off and it kept commanding the speed limit for 60 s with no
alarm. The simulator and three daemons as processes, real UDP MAVLink and Zenoh on loopback:
for 2 s vehicle 1's daemon also receives forged LOCAL_POSITION_NED and ATTITUDE messages in its
autopilot's name (system id 2, an unsigned fleet). It must drop them as implausible, hold with
``telemetry_implausible`` while they come, keep publishing its status (defect 9), and fly on
once they stop; the rest of the team keeps flying."""

from __future__ import annotations

import socket
import time

import pytest
from pymavlink.dialects.v20 import common

pytestmark = pytest.mark.e2e
VICTIM = 1
FORGE_S = 2.0
FORGE_HZ = 20.0


def _forged_frames(boot_ms: int) -> list[bytes]:
    mav = common.MAVLink(None, srcSystem=VICTIM + 1, srcComponent=1)
    return [
        common.MAVLink_local_position_ned_message(boot_ms, 0.0, 0.0, -1e6, 1e4, 0.0, 0.0).pack(mav),
        common.MAVLink_attitude_message(boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 100.0).pack(mav),
    ]


def test_impossible_telemetry_holds_with_an_alarm_and_the_vehicle_flies_on(fleet, wait_for):
    ev, procs, ports, _agent_args, _name = fleet

    def status(j: int):
        return ev.snapshot().get(j)

    def flying(j: int) -> bool:
        st = status(j)
        return st is not None and st.phase == "flying" and not st.alarms

    wait_for(lambda: all(flying(j) for j in range(3)), 40.0, "the team flying, no alarms", ev)
    before = status(VICTIM)
    seen_alarm = False
    statuses = set()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < FORGE_S:
            for frame in _forged_frames(boot_ms=10_000_000 + 50 * k):
                sock.sendto(frame, ("127.0.0.1", ports.mavlink + VICTIM))
            k += 1
            st = status(VICTIM)
            if st is not None:
                statuses.add(st.seq)
                seen_alarm |= "telemetry_implausible" in st.alarms
            time.sleep(1.0 / FORGE_HZ)
    st = status(VICTIM)
    print(f"during the forgery: {len(statuses)} statuses, alarm seen {seen_alarm}; "
          f"after: phase {st.phase}, alarms {st.alarms}, dropped {st.dropped}")  # fmt: skip
    assert seen_alarm, st.alarms
    assert len(statuses) >= 2, "the status kept coming while the telemetry was rejected"
    assert st.dropped.get("mavlink_implausible", 0) > 0, st.dropped
    assert abs(st.altitude_m) < 50.0 and st.speed_m_s < 5.0, (st.altitude_m, st.speed_m_s)
    took = wait_for(lambda: flying(VICTIM), 10.0, "vehicle 1 flying again without alarms", ev)
    print(f"vehicle {VICTIM} flying again {took:.1f} s after the forgery stopped")
    others = [j for j in range(3) if j != VICTIM]
    assert all(status(j).phase == "flying" for j in others), {j: status(j) for j in others}
    assert before.seq < status(VICTIM).seq
    assert all(p.poll() is None for _, p in procs.procs), "every process lives on"
