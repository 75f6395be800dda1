"""The core's flight recorder (onboard/daemon/tape.py): a tape replays to the same outputs."""

from __future__ import annotations

import pytest

from benchmarks.core_replay import record
from messages.agent import OwnMeasurements
from messages.codec import Payload, encode
from onboard.core.agent import AgentCore
from onboard.core.config import AgentConfig
from onboard.daemon.tape import TapeError, TapeWriter, open_tape, read_tape, replay, tape_path
from sim.runner import RunnerConfig
from sim.scenarios import P0_NED, YAW0_RAD, agent_configs


def _flown_inputs() -> tuple[AgentConfig, list[tuple[float, OwnMeasurements, list[Payload]]]]:
    """Agent 0's core inputs in 1.5 s of paper 000's active scale estimation (headless)."""
    cfgs = agent_configs("scale-active")
    return cfgs[0], record(cfgs, P0_NED, YAW0_RAD, RunnerConfig(duration_s=1.5, seed=0))


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


def test_a_failing_tape_stops_recording_never_the_daemon(tmp_path, caplog):
    config, inputs = _flown_inputs()
    tape = TapeWriter(tmp_path / "agent0.tape", config)
    tape.step(*inputs[0])
    tape._file.close()  # as a full disk would: every write fails from here
    tape.step(*inputs[1])
    tape.step(*inputs[2])
    assert tape.failed
    assert sum("recording stopped" in r.message for r in caplog.records) == 1
    _, steps = read_tape(tmp_path / "agent0.tape")
    assert sum(1 for _ in steps) == 1  # what was written before the failure reads back


def test_a_tape_that_cannot_be_opened_is_logged_and_skipped(tmp_path, caplog):
    config, _ = _flown_inputs()
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    assert open_tape(blocker / "agent0.tape", config) is None
    assert "flying without it" in caplog.text
    assert open_tape(None, config) is None
