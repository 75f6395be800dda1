"""A machine too slow for the speed says so (issue 29): the simulator and three real daemons,
the daemons starved of CPU on purpose (SIGSTOP/SIGCONT, stopped 60% of every 0.5 s), raise
``ticks_late``; the demo's summary marks the run degraded and its verdict line says so. Before
the starving, on the same machine, no daemon reports it (the control)."""

from __future__ import annotations

import os
import signal
import time

import pytest

from groundstation.demo import summarize
from groundstation.demo_verdict import demo_verdict
from messages.vocabulary import Alarm, Phase

pytestmark = pytest.mark.e2e
N = 3  # vehicles in the `fleet` fixture (conftest.py)
STOPPED_S, RUNNING_S = 0.3, 0.2


def test_starved_daemons_make_the_summary_say_degraded(fleet, wait_for):
    ev, procs, _ports, _, _name = fleet
    wait_for(
        lambda: len(s := ev.snapshot()) == N
        and all(st.phase != Phase.CONNECTING for st in s.values()),
        30.0, "every daemon connected", ev,
    )  # fmt: skip
    time.sleep(1.0)  # a few statuses on schedule
    assert ev.late_ticks == set(), ev.alarms_seen  # the control: not late when not starved
    agents = [p for name, p in procs.procs if name.startswith("agent")]
    deadline = time.monotonic() + 8.0
    try:
        while ev.late_ticks != set(range(N)) and time.monotonic() < deadline:
            for p in agents:
                os.killpg(p.pid, signal.SIGSTOP)
            time.sleep(STOPPED_S)
            for p in agents:
                os.killpg(p.pid, signal.SIGCONT)
            time.sleep(RUNNING_S)
    finally:
        for p in agents:
            os.killpg(p.pid, signal.SIGCONT)
    assert ev.late_ticks == set(range(N)), ev.alarms_seen
    assert set(ev.alarms_seen[Alarm.TICKS_LATE]) == set(range(N))
    summary = summarize(ev, N)
    assert summary["degraded"] is True and summary["late_tick_vehicles"] == list(range(N))
    verdict = demo_verdict({**summary, "speedup": 1.0})
    assert verdict.degraded and " DEGRADED (core ticks ran late on vehicle(s) 0, 1, 2 at 1x" in (
        verdict.line
    ), verdict.line
