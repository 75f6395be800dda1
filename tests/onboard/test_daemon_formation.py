"""The daemon's side of a formation change (onboard/daemon/loop.py): a valid change is adopted
once and shown in the status fields; one with vehicle ids that are not the fleet's is counted and
dropped, and the formation flown stays. Stand-ins for the links; no loop thread."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from groundstation.demo import DemoPorts, plan_formation, write_demo_files
from messages.command import FormationChange, FormationSlot
from onboard.daemon.clock import WallClock
from onboard.daemon.config import load_fleet
from onboard.daemon.loop import AgentDaemon
from onboard.daemon.peers import DropCounter
from onboard.geometry import bearings_body


class _Peers:
    def __init__(self) -> None:
        self.queued: FormationChange | None = None

    def commands(self) -> list:
        return []

    def formation(self) -> FormationChange | None:
        out, self.queued = self.queued, None
        return out


def _change(formation_id: int, ids: list[int], p: np.ndarray, leader: int | None = None):
    slots = [FormationSlot(id=i, position_ned=tuple(float(x) for x in p[k])) for k, i in
             enumerate(ids)]  # fmt: skip
    return FormationChange(sender=0, target=1, formation_id=formation_id, agents=slots,
                           leader=leader)  # fmt: skip


def test_the_daemon_adopts_a_valid_change_and_counts_a_foreign_one(tmp_path):
    plan = plan_formation(3, seed=1)
    path = write_demo_files(tmp_path, plan, DemoPorts(zenoh=1, mavlink=2, gcs=3), "t",
                            "formation-active")  # fmt: skip
    peers, drops = _Peers(), DropCounter()
    daemon = AgentDaemon(load_fleet(path), 1, SimpleNamespace(), peers, None, WallClock(),
                         drops, "x")  # fmt: skip
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
