"""The demo's live line for a person (issue 29): take-off until every vehicle flies, then
mission, then landing; wall-clock time and an ETA from the simulation speed measured so far."""

from __future__ import annotations

from types import SimpleNamespace

from groundstation.demo_cli import LANDING_ESTIMATE_S, Progress, progress_line


class Clock:
    t = 100.0

    def __call__(self) -> float:
        return self.t


def test_phases_wall_time_and_eta_at_the_measured_speed():
    clock = Clock()
    ev = SimpleNamespace(series=SimpleNamespace(flying=[]), truth={}, plan=SimpleNamespace(n=3))
    prog = Progress(60.0, clock=clock)
    assert prog.update(ev, 0.0, "mission") == ("take-off", 0.0, None)  # nothing measured yet
    clock.t += 1.0
    prog.update(ev, 0.5, "mission")
    clock.t += 10.0  # 4 simulation seconds in 10 wall seconds: 0.4x
    phase, wall, eta = prog.update(ev, 4.5, "mission")
    assert phase == "take-off" and wall == 11.0
    assert abs(eta - (60.0 - 4.5 + LANDING_ESTIMATE_S) / 0.4) < 1e-9
    ev.series.flying = [False, True]
    assert prog.update(ev, 4.5, "mission")[0] == "mission"
    line = progress_line(ev, 4.5, "mission", 60.0, wall, eta)
    assert line == "bearingflock demo: mission, sim   4.5 / 60 s, wall 0:11, ETA 2:44"
    phase, _, eta = prog.update(ev, 60.0, "landing")
    assert phase == "landing" and abs(eta - LANDING_ESTIMATE_S / 0.4) < 1e-9
    clock.t += 30.0  # longer than the estimate: ETA 0, not negative
    assert prog.update(ev, 60.0, "landing")[2] == 0.0
    ev.truth = {0: SimpleNamespace(p_ned=(0, 0, -0.05)), 1: SimpleNamespace(p_ned=(0, 0, -3.0))}
    assert "1/3 on the ground" in progress_line(ev, 60.0, "landing", 60.0, 41.0, 0.0)


def test_the_speed_comes_from_the_idle_share_measured_on_this_machine(monkeypatch):
    import groundstation.demo_cli as cli

    readings = iter([(1000, 4000), (1150, 4200)])  # 150 of 200 jiffies idle: 75%
    monkeypatch.setattr(cli, "_cpu_times", lambda: next(readings))
    assert cli.idle_cores(2, sample_s=0.0) == 1.5
    assert cli.default_speedup(6, 1.5) < cli.default_speedup(6, 2)  # a busy machine: slower
    monkeypatch.setattr(cli, "_cpu_times", lambda: None)
    assert cli.idle_cores(2, sample_s=0.0) is None  # not Linux: the cores alone decide
    monkeypatch.undo()
    idle = cli.idle_cores(2, sample_s=0.05)
    assert idle is None or 0.0 <= idle <= 2.0
