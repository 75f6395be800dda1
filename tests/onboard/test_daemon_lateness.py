"""The late-tick alarm (onboard/daemon/lateness.py): raised when ticks lose over a quarter of
the last 2 s of wall time, cleared below an eighth, not raised by one short stall."""

from __future__ import annotations

from onboard.daemon.lateness import TickLateness


def _run(track: TickLateness, t0_s: float, seconds: float, period_s: float, late_s: float):
    t = t0_s
    while t < t0_s + seconds:
        t += period_s + late_s
        track.add(t, late_s)
    return t


def test_on_schedule_no_alarm():
    track = TickLateness()
    _run(track, 0.0, 5.0, 0.01, 0.0005)  # 5% late: a busy but keeping-up machine
    assert not track.late and abs(track.fraction - 0.05 / 1.05) < 0.01


def test_starved_raises_then_clears():
    track = TickLateness()
    t = _run(track, 0.0, 3.0, 0.01, 0.01)  # every tick a period late: half the time lost
    assert track.late and track.fraction > 0.4
    t = _run(track, t, 0.5, 0.01, 0.0)  # the lost share falls, still above the clear level
    assert track.late
    _run(track, t, 2.5, 0.01, 0.0)
    assert not track.late and track.fraction == 0.0


def test_one_short_stall_is_not_late():
    track = TickLateness()
    t = _run(track, 0.0, 3.0, 0.01, 0.0)
    track.add(t + 0.3, 0.3)  # descheduled 0.3 s once: 15% of the window
    assert not track.late
    track.add(t + 0.65, 0.3)  # twice within 2 s: 30%
    assert track.late


def test_stopped_half_the_time_is_late():
    """What a SIGSTOP/SIGCONT duty cycle does to the loop (the e2e starvation test)."""
    track = TickLateness()
    t = 0.0
    for _ in range(8):
        t = _run(track, t, 0.2, 0.01, 0.0)
        t += 0.2
        track.add(t, 0.2)
    assert track.late
