"""The fleet line's "rigid" column keys on the agents' own ``rigidity_lost`` (one enum,
:mod:`messages.vocabulary`), also for modes that estimate no rigidity eigenvalue (paper 000's
formation modes: the daemon's rigidity guard raises it from the planned framework)."""

from __future__ import annotations

from groundstation.gcs.monitor import fleet_line
from messages.vocabulary import Alarm, alarm_text


def _row(agent_id: int, alarms: list[str], eigenvalue: float | None) -> dict:
    return {
        "id": agent_id,
        "heartbeat_age_s": 0.1,
        "alarms": sorted(alarms),
        "red": bool(alarms),
        "agent_mode": "formation-active",
        "rigidity_eigenvalue": eigenvalue,
        "scale_converged": False,
    }


def test_rigidity_lost_without_an_eigenvalue_is_not_rigid():
    ok = [_row(0, [], None), _row(1, [], None)]
    assert fleet_line(ok, None)["rigid"] is None  # nothing known either way
    lost = [_row(0, [alarm_text(Alarm.PEER_LOST, 1), Alarm.RIGIDITY_LOST.value], None), ok[1]]
    assert fleet_line(lost, None)["rigid"] is False


def test_eigenvalues_decide_when_nobody_lost_rigidity():
    assert fleet_line([_row(0, [], 0.3), _row(1, [], 0.2)], None)["rigid"] is True
    assert fleet_line([_row(0, [], 0.3), _row(1, [], 0.0)], None)["rigid"] is False
    assert fleet_line([_row(0, [Alarm.RIGIDITY_LOST.value], 0.3)], None)["rigid"] is False
