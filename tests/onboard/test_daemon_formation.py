"""The daemon's side of a formation change (onboard/daemon/loop.py): a valid change is adopted
once and shown in the status fields; one with vehicle ids that are not the fleet's is counted and
dropped, and the formation flown stays. A leader drive is taken only by the formation's leader
(others count it ``command_foreign``), one that is not one drive is ``command_malformed``.
Stand-ins for the links; no loop thread."""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as dialect

from groundstation.demo import DemoPorts, plan_formation, write_demo_files
from messages import mavlink as mv
from messages.command import FormationChange, FormationSlot, LeaderDrive
from onboard.autopilot.base import Flavour, LinkConfig, LinkCounters, StreamState
from onboard.autopilot.states import Saturated, TelemetryState, snapshot
from onboard.daemon.clock import WallClock
from onboard.daemon.config import load_fleet
from onboard.daemon.loop import AgentDaemon
from onboard.daemon.peers import DropCounter
from onboard.geometry import bearings_body


def _telemetry():
    st = TelemetryState(flavour=Flavour.PX4)
    t = time.monotonic()
    st.apply(dialect.MAVLink_heartbeat_message(2, 12, mv.BASE_MODE_CUSTOM, 0, 3, 3), t)
    st.apply(dialect.MAVLink_local_position_ned_message(1000, 0, 0, -5.0, 0, 0, 0), t)
    return snapshot(st, t, LinkConfig(), 1, StreamState.IDLE,
                    Saturated((0.0, 0.0, 0.0), 0.0, False, False), LinkCounters())  # fmt: skip


class _Peers:
    def __init__(self) -> None:
        self.queued: FormationChange | None = None
        self.drive: LeaderDrive | None = None

    def commands(self) -> list:
        return []

    def formation(self) -> FormationChange | None:
        out, self.queued = self.queued, None
        return out

    def leader_drive(self) -> LeaderDrive | None:
        out, self.drive = self.drive, None
        return out


def _change(formation_id: int, ids: list[int], p: np.ndarray, leader: int | None = None):
    slots = [FormationSlot(id=i, position_ned=tuple(float(x) for x in p[k])) for k, i in
             enumerate(ids)]  # fmt: skip
    return FormationChange(sender=0, target=1, formation_id=formation_id, agents=slots,
                           leader=leader)  # fmt: skip


def _daemon(tmp_path, agent_id=1):
    plan = plan_formation(3, seed=1)
    path = write_demo_files(tmp_path, plan, DemoPorts(zenoh=1, mavlink=2, gcs=3), "t",
                            "formation-active")  # fmt: skip
    peers, drops = _Peers(), DropCounter()
    daemon = AgentDaemon(load_fleet(path), agent_id, SimpleNamespace(), peers, None, WallClock(),
                         drops, "x")  # fmt: skip
    return plan, peers, drops, daemon


def test_the_daemon_adopts_a_valid_change_and_counts_a_foreign_one(tmp_path):
    plan, peers, drops, daemon = _daemon(tmp_path)
    p_new = plan.p_ned * 1.5
    peers.queued = _change(9, [0, 1, 2], p_new, leader=2)
    daemon._handle_commands()
    assert daemon._formation == (9, 2)
    want, _ = bearings_body(p_new, np.zeros(3), plan.edges)
    desired = daemon.core.controller.desired
    for (i, j), b in zip(plan.edges, want, strict=True):
        assert np.allclose(desired[(int(i), int(j))], b)

    peers.queued = _change(10, [0, 1, 7], plan.p_ned)  # vehicle 7 is not in the fleet
    daemon._handle_commands()
    assert daemon._formation == (9, 2)
    assert drops.snapshot() == {"command_malformed": 1}


def test_only_the_leader_takes_a_drive_and_a_bad_one_is_counted(tmp_path):
    plan, peers, drops, daemon = _daemon(tmp_path, agent_id=2)
    drive = LeaderDrive(sender=0, target=2, drive_id=5, velocity_ned=(0.2, 0.0, 0.0),
                        duration_s=4.0)  # fmt: skip
    peers.drive = drive  # the fleet file's formation has no leader
    daemon._handle_commands()
    assert daemon.core.controller.drive is None and daemon._drive_id == 0
    assert drops.snapshot() == {"command_foreign": 1}

    peers.queued = _change(9, [0, 1, 2], plan.p_ned * 2.0, leader=2)
    daemon._handle_commands()
    peers.drive = drive
    daemon._handle_commands()
    assert daemon._drive_id == 5
    assert daemon.core.controller.drive.velocity_ned == (0.2, 0.0, 0.0)
    assert daemon._status(0.0, _telemetry()).leader_drive_id == 5

    both = LeaderDrive(sender=0, target=2, drive_id=6, velocity_ned=(0.2, 0.0, 0.0),
                       waypoints_ned=[(1.0, 0.0, -5.0)])  # fmt: skip
    peers.drive = both
    daemon._handle_commands()
    assert daemon._drive_id == 5
    assert drops.snapshot() == {"command_foreign": 1, "command_malformed": 1}

    peers.queued = _change(10, [0, 1, 2], plan.p_ned, leader=0)  # 2 leads no more: drive gone
    daemon._handle_commands()
    assert daemon.core.controller.drive is None and daemon._drive_id == 0


def test_a_change_with_distances_is_reported_in_the_status(tmp_path):
    plan, peers, _drops, daemon = _daemon(tmp_path)
    peers.queued = FormationChange(
        sender=0, target=1, formation_id=3, name="double", distances=True, ramp_s=2.0,
        agents=[FormationSlot(id=i, position_ned=tuple(float(x) for x in 2.0 * plan.p_ned[i]))
                for i in range(3)],
    )  # fmt: skip
    daemon._handle_commands()
    status = daemon._status(0.0, _telemetry())
    assert (status.formation_id, status.formation_name, status.formation_distances) == (
        3, "double", True,
    )  # fmt: skip
    d = daemon.core.controller.desired_distance
    assert sorted(d) == sorted(e for e in map(tuple, plan.edges.tolist()) if 1 in e)
    for (i, j), dd in d.items():
        assert dd == pytest.approx(2.0 * np.linalg.norm(plan.p_ned[j] - plan.p_ned[i]))
