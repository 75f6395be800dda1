"""The README's main job end to end: ``bearingflock demo``'s mission with 6 vehicles, as real
processes (simulator, six daemons, real UDP MAVLink, real Zenoh on loopback), scored against
the simulator's truth and against the headless runner flying the same configurations.

It flies with security on (``--secure``: fresh fleet keys, ``[security] dir``, a simulator that
accepts only correctly signed MAVLink, Zenoh over mutual TLS with per-vehicle access control),
so the one long mission checks both; the plain links fly the same demo in
``test_demo_realistic.py`` and every other end-to-end test (issue 24)."""

from __future__ import annotations

import pytest
from pymavlink import mavutil

from groundstation.demo import run_demo
from groundstation.demo_headless import headless_demo

pytestmark = pytest.mark.e2e

VEHICLES = 6
SPEEDUP = 0.6
"""Simulation seconds per wall second, fixed rather than the demo's default (real time on an idle
2-core machine): a correctness test must not depend on the machine's margin, and CI's cores are
shared (real-time capacity is measured by benchmarks/bench_daemon.py and bench_footprint.py).
Six daemons at 0.19 core each at 1x (issue 27) use about 0.7 core at 0.6, less than they used
at 0.4 when each took 0.45 core (then a CI run at 0.6, 85% of two cores, ended 2.5% off in
scale). At 0.6 this test took 121 s instead of 150 s at 0.4, passing with a helper's load on
the machine."""
MISSION_S = 34.0
"""Simulation seconds of mission before the demo lands everyone: take-off (about 8 s), the active
motion until every SfM edge is excited (10-20 s), then the formation settles (quiet machine, 10%
loss: scale within 2% 2.0 s after the start, formation 0.9 deg at the end)."""
LOSS = 0.1
"""Every daemon drops 10% of the peer messages it receives (``zenoh.inject_loss``). Runs of this
test's mission: quiet machine 0.08% scale / 0.9 deg; one core taken by a busy loop 0.23% /
0.8 deg (docs/demo.md, "How robust it is")."""
SCALE_TOLERANCE = 0.02
BEARING_TOLERANCE_DEG = 3.0
EIGEN_TOLERANCE = 0.1
"""Rigidity maintenance is on: every daemon's distributed estimate of the weighted angle
rigidity eigenvalue must end within 10% of the truth (headless at 30 ms and 10% loss:
0.6-2.4%; this test's mission: 4.5%. Without the shares of the agents outside the formation
graph it converged to the eigenvalue of a smaller graph, 21% low)."""


def test_demo_finds_metric_scale_and_holds_the_formation(tmp_path, recording_schemas):
    summary = run_demo(
        VEHICLES, "px4", MISSION_S, tmp_path, seed=0, speedup=SPEEDUP, loss=LOSS, secure=True
    )
    # security on: keys made 0600, the fleet file points at them, nothing unsigned or rejected
    assert (tmp_path / "keys" / "mavlink-vehicle-5.key").stat().st_mode & 0o777 == 0o600
    assert 'dir = "keys"' in (tmp_path / "fleet.toml").read_text()
    dropped = summary["dropped_by_reason"]
    assert not [k for k in dropped if k.startswith("mavlink_")], dropped  # no rejection
    # nothing replays in a clean flight (the rigidity layer's re-sent shares were ~1,000 per run)
    assert dropped.get("seq_replay", 0) == 0, dropped
    log = (tmp_path / "sim.log").read_text().splitlines()[-1]
    assert "signed_ok=" in log and "unsigned_rejected" not in log, log
    # the run's recording opens in Foxglove: every channel schema'd, the team in a 3D scene
    names, problems = recording_schemas(tmp_path / "recording.mcap")
    assert summary["recording"] == str(tmp_path / "recording.mcap")
    assert problems == [] and names["scene/team"] == "foxglove.SceneUpdate", problems[:5]
    assert {f"{k}/status" for k in range(VEHICLES)} <= {t.split("/", 2)[2] for t in names
                                                            if t.startswith("bf/")}  # fmt: skip
    tlog = mavutil.mavlink_connection(str(tmp_path / "recording.tlog"))
    sysids = set()
    while (msg := tlog.recv_match(type="HEARTBEAT")) is not None:
        sysids.add(msg.get_srcSystem())
    assert sysids == {k + 1 for k in range(VEHICLES)}
    report = {
        k: summary[k] for k in ("time_to_scale_s", "final_scale_error", "final_bearing_error_deg")
    }
    assert summary["final_scale_error"] is not None, report
    assert summary["final_scale_error"] < SCALE_TOLERANCE, report
    assert summary["final_bearing_error_deg"] < BEARING_TOLERANCE_DEG, report
    assert summary["time_to_scale_s"] is not None, report
    assert summary["landed"], "every vehicle lands at the end"
    assert summary["dropped_by_reason"].get("injected_loss", 0) > 0, "the loss was injected"
    assert not any("malformed" in r for r in summary["dropped_by_reason"]), summary
    # six daemons on one simulated clock, a loaded machine, 10% loss: no false clock alarm
    assert not [a for a in summary["alarms_seen"] if a.startswith("peer_clock")], summary
    lam_error = summary["final_angle_eigenvalue_error"]
    assert lam_error is not None and lam_error < EIGEN_TOLERANCE, summary
    # within noise of the headless runner flying the same configurations from the same start
    reference, _ = headless_demo(VEHICLES, seed=0, duration_s=25.0, loss=LOSS)
    assert reference["final_scale_error"] < SCALE_TOLERANCE
    assert reference["final_bearing_error_deg"] < BEARING_TOLERANCE_DEG
    assert abs(summary["final_scale_error"] - reference["final_scale_error"]) < SCALE_TOLERANCE
    assert (
        abs(summary["final_bearing_error_deg"] - reference["final_bearing_error_deg"])
        < BEARING_TOLERANCE_DEG
    )
