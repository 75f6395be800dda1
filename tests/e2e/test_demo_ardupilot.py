"""``bearingflock demo --flavour ardupilot``: the same mission with ArduPilot-flavour simulated
autopilots (GUIDED mode, ArduPilot's command set), as real processes over real UDP MAVLink.

The ArduPilot flavour listens on TCP like SITL unless told otherwise; the demo once left that
default in place while its daemons dialled UDP, so no vehicle ever connected and the demo
still exited 0. This test flies three vehicles to metric scale and back to the ground."""

from __future__ import annotations

import pytest

from groundstation.demo import run_demo
from groundstation.demo_cli import default_speedup

pytestmark = pytest.mark.e2e

VEHICLES = 3
MISSION_S = 16.0
"""Take-off takes about 7 s of simulation; scale within 2% about 2 s after the mission starts
(manual run, 25 s at 0.5x: 1.9 s, final scale error 0.04%)."""


def test_ardupilot_demo_reaches_metric_scale(tmp_path):
    summary = run_demo(
        VEHICLES,
        "ardupilot",
        MISSION_S,
        tmp_path,
        seed=0,
        speedup=default_speedup(VEHICLES, cores=2),
        rigidity=False,
    )
    report = {k: summary[k] for k in ("mission_start_s", "time_to_scale_s", "final_scale_error")}
    assert summary["mission_start_s"] is not None, report
    assert summary["time_to_scale_s"] is not None, report
    assert summary["final_scale_error"] < 0.02, report
    assert summary["landed"], "every vehicle lands at the end"
    assert summary["dropped_messages"] == 0, summary["dropped_by_reason"]
