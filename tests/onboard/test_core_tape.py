"""The core's flight recorder (onboard/daemon/tape.py): a tape replays to the same outputs."""

from __future__ import annotations

import numpy as np
import pytest

import sim.runner as runner_mod
from messages.agent import OwnMeasurements
from messages.codec import Payload, encode
from onboard.core.agent import AgentCore
from onboard.core.config import build_config
from onboard.daemon.tape import TapeError, TapeWriter, read_tape, replay, tape_path
from sim.runner import RunnerConfig, run


def _flown_inputs() -> tuple[object, list[tuple[float, OwnMeasurements, list[Payload]]]]:
    n = 3
    edges = tuple((i, j) for i in range(n) for j in range(n) if i != j)
    rng = np.random.default_rng(4)
    p0 = rng.normal(size=(n, 3)) * 2.0 + np.array([0.0, 0.0, -3.0])
    yaw0 = rng.uniform(-np.pi, np.pi, n)
    p_hat0 = tuple(tuple(float(x) for x in 0.7 * row) for row in p0)
    cfgs = [
        build_config(
            agent_id=i,
            n_agents=n,
            edges=edges,
            mode="active",
            p_hat0_ned=p_hat0,
            yaw_hat0_rad=tuple(float(y) for y in yaw0),
        )
        for i in range(n)
    ]
    inputs: list[tuple[float, OwnMeasurements, list[Payload]]] = []
    base = runner_mod.AgentCore

    class Recorded(base):  # type: ignore[misc, valid-type]
        def step(self, t_s, own, inbox=()):  # type: ignore[no-untyped-def]
            if self.id == 0:
                inputs.append((t_s, own, list(inbox)))
            return super().step(t_s, own, inbox)

    runner_mod.AgentCore = Recorded
    try:
        run(cfgs, p0, yaw0, RunnerConfig(duration_s=1.5, seed=0))
    finally:
        runner_mod.AgentCore = base
    return cfgs[0], inputs


def test_a_tape_replays_to_the_flights_outputs(tmp_path):
    config, inputs = _flown_inputs()
    assert any(inbox for _, _, inbox in inputs), "the agent heard its peers"
    path = tmp_path / "agent0.tape"
    tape = TapeWriter(path, config)
    core = AgentCore(config)
    flown = []
    for t_s, own, inbox in inputs:
        tape.step(t_s, own, inbox)
        flown.append(core.step(t_s, own, inbox))
    tape.close()

    header, steps = read_tape(path)
    assert header.agent_id == 0 and header.config == config
    assert sum(1 for _ in steps) == len(inputs)
    replayed = list(replay(path))
    assert len(replayed) == len(flown)
    for (_t_s, setpoint, out), (sp_flown, out_flown) in zip(replayed, flown, strict=True):
        assert setpoint == sp_flown
        assert [encode(p) for p in out] == [encode(p) for p in out_flown]


def test_a_changed_configuration_changes_the_replay(tmp_path):
    import msgspec

    config, inputs = _flown_inputs()
    path = tmp_path / "agent0.tape"
    tape = TapeWriter(path, config)
    for step in inputs:
        tape.step(*step)
    tape.close()
    slower = lambda c: msgspec.structs.replace(  # noqa: E731
        c, scale=msgspec.structs.replace(c.scale, alpha=0.5 * c.scale.alpha)
    )
    same = [sp for _, sp, _ in replay(path)]
    other = [sp for _, sp, _ in replay(path, slower)]
    assert len(same) == len(other) and same != other


def test_a_tape_cut_short_reads_to_its_last_whole_step(tmp_path):
    config, inputs = _flown_inputs()
    path = tmp_path / "agent0.tape"
    tape = TapeWriter(path, config)
    for step in inputs[:20]:
        tape.step(*step)
    tape.close()
    data = path.read_bytes()
    path.write_bytes(data[:-3])  # a crash in the middle of the last frame
    _, steps = read_tape(path)
    assert sum(1 for _ in steps) == 19


def test_not_a_tape_is_a_clear_error(tmp_path):
    path = tmp_path / "x.tape"
    path.write_bytes(b"\x00\x00\x00\x03abc")
    with pytest.raises(TapeError, match="not a core tape"):
        read_tape(path)
    path.write_bytes(b"")
    with pytest.raises(TapeError, match="not a core tape"):
        read_tape(path)


def test_tapes_are_off_unless_asked(monkeypatch, tmp_path):
    monkeypatch.delenv("BEARINGFLOCK_CORE_TAPE", raising=False)
    assert tape_path(2) is None
    monkeypatch.setenv("BEARINGFLOCK_CORE_TAPE", str(tmp_path))
    assert tape_path(2) == tmp_path / "agent2.tape"
