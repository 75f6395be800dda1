"""The vocabulary: one word per alarm, phase, drop reason and mode, the same at both ends."""

from __future__ import annotations

import ast
from pathlib import Path

import msgspec
import pytest

from messages.agent import VehicleStatus
from messages.codec import MessageError, decode, encode
from messages.vocabulary import (
    FLEET_MODES,
    MODES,
    PER_PEER,
    Alarm,
    AlarmWord,
    DropReason,
    DropScope,
    Phase,
    alarm_kind,
    alarm_text,
    drop_key,
    parse_alarm,
)
from onboard.core.modes import MODE_LAYERS
from tests.groundstation.standin import StandinConfig, scripted_status

ROOT = Path(__file__).resolve().parents[2]


def test_every_kind_reads_back_from_its_wire_form() -> None:
    for kind in Alarm:
        peer = 3 if kind in PER_PEER else None
        text = alarm_text(kind, peer)
        assert alarm_kind(text) is kind
        assert parse_alarm(text) == AlarmWord(kind, peer)
    assert alarm_text(Alarm.PEER_LOST, 3) == "peer_lost:3"
    assert alarm_text(Alarm.RIGIDITY_LOST) == "rigidity_lost"


def test_a_per_peer_kind_needs_its_peer_and_the_others_take_none() -> None:
    with pytest.raises(ValueError, match="needs peer id"):
        alarm_text(Alarm.PEER_CLOCK)
    with pytest.raises(ValueError, match="takes no peer id"):
        alarm_text(Alarm.FENCE, 2)


def test_an_unknown_word_is_no_kind() -> None:
    assert alarm_kind("rigidity_low") is None
    assert alarm_kind("") is None


def test_a_malformed_peer_id_is_no_alarm() -> None:
    for text in (
        "peer_lost",
        "peer_lost:",
        "peer_lost:x",
        "peer_lost:-1",
        "peer_clock:٣",
        "fence:2",
    ):
        assert parse_alarm(text) is None, text


def _status(phase: Phase, alarms: list[str], dropped: dict[str, int]) -> VehicleStatus:
    st = scripted_status(StandinConfig(fleet="alpha", ids=(0, 1)), 0, 1.0, 1, phase)
    return msgspec.structs.replace(st, alarms=alarms, dropped=dropped)


def test_every_word_round_trips_through_the_codec() -> None:
    alarms = [alarm_text(k, 1 if k in PER_PEER else None) for k in Alarm]
    dropped = {drop_key(r): 1 for r in DropReason} | {
        drop_key(r, s): 2 for r in DropReason for s in DropScope
    }
    for phase in Phase:
        back = decode(encode(_status(phase, alarms, dropped)), VehicleStatus)
        assert back.phase is phase
        assert [parse_alarm(a) for a in back.alarms] == [
            AlarmWord(k, 1 if k in PER_PEER else None) for k in Alarm
        ]
        assert back.dropped == dropped


def test_the_wire_words_did_not_change() -> None:
    """The schema version stayed: the phases and keys are the strings they were before."""
    assert [p.value for p in Phase] == [
        "connecting", "waiting", "ready", "flying", "holding", "pilot", "failsafe", "landing",
        "stopped",
    ]  # fmt: skip
    assert drop_key(DropReason.NOT_UNIT, DropScope.CAMERA) == "camera_not_unit"
    assert drop_key(DropReason.IMPLAUSIBLE, DropScope.MAVLINK) == "mavlink_implausible"
    assert drop_key(DropReason.MALFORMED, DropScope.OWN_STATUS) == "own_status_malformed"
    assert drop_key(DropReason.SEQ_REPLAY) == "seq_replay"


def test_an_unknown_phase_is_a_malformed_status() -> None:
    raw = msgspec.msgpack.decode(encode(_status(Phase.READY, [], {})))
    raw["phase"] = "dancing"
    with pytest.raises(MessageError) as info:
        decode(msgspec.msgpack.encode(raw), VehicleStatus)
    assert info.value.reason is DropReason.MALFORMED


def test_the_fleet_modes_are_core_modes_with_layers() -> None:
    assert set(FLEET_MODES) < set(MODES)
    assert set(MODE_LAYERS) == set(MODES)


PHASE_WORDS = frozenset(Phase)
DROP_WORDS = frozenset(DropReason) | {drop_key(r, s) for r in DropReason for s in DropScope}
COUNTING_CALLS = frozenset(
    {"drop", "_drop", "_reject", "_step_failed", "MessageError", "FrameError"}
)


def _literals(node: ast.expr) -> list[str]:
    if isinstance(node, ast.Constant) and isinstance(node.value, str):
        return [node.value]
    if isinstance(node, ast.Tuple | ast.List | ast.Set):
        return [s for e in node.elts for s in _literals(e)]
    return []


def spelled_out_words(source: str) -> list[str]:
    """Phase and drop-reason words ``source`` spells as string literals where it compares a
    phase or a reason, or counts a drop, instead of naming the enum member."""
    found: list[str] = []
    if (
        "drop" not in source
        and "Error(" not in source
        and not any(f'"{w}"' in source for w in PHASE_WORDS | DROP_WORDS)
    ):
        return found  # nothing to look for (most files: keeps the scan fast)
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Compare):
            sides = [node.left, *node.comparators]
            words = {w for s in sides for w in _literals(s)} & (PHASE_WORDS | DROP_WORDS)
            if not words:
                continue
            text = " ".join(ast.unparse(s) for s in sides if not _literals(s))
            if "phase" in text or "state.get()" in text:
                found += sorted(words & PHASE_WORDS)
            if "reason" in text or "drop" in text:
                found += sorted(words & DROP_WORDS)
        elif isinstance(node, ast.Call) and node.args:
            f = node.func
            name = f.attr if isinstance(f, ast.Attribute) else getattr(f, "id", "")
            if name in COUNTING_CALLS or (name == "count" and "drop" in ast.unparse(f)):
                first = node.args[0]
                if isinstance(first, ast.JoinedStr):
                    found.append(ast.unparse(first))
                found += [w for w in _literals(first) if w in DROP_WORDS]
    return found


def test_the_check_sees_spelled_out_words() -> None:
    source = (
        'if st.phase == "flying": pass\n'
        'ok = self.state.get() in ("holding", "pilot")\n'
        'if reason == "seq_resync": pass\n'
        'self.drops.drop("camera_not_unit", "x")\n'
        'self.drops.count("future_stamp")\n'
        'raise MessageError("malformed", "x")\n'
        'self.drops.drop(f"own_{exc.reason}", "x")\n'
        'if mode == "flying" or action == "land": pass\n'
        'self.state.count("malformed")\n'
    )
    assert spelled_out_words(source) == [
        "flying", "holding", "pilot", "seq_resync", "camera_not_unit", "future_stamp",
        "malformed", "f'own_{exc.reason}'",
    ]  # fmt: skip


def test_phases_and_drop_reasons_are_named_not_spelled() -> None:
    vocabulary = ROOT / "messages" / "vocabulary.py"
    found = {
        str(path.relative_to(ROOT)): hits
        for folder in ("messages", "onboard", "sim", "groundstation")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path != vocabulary and (hits := spelled_out_words(path.read_text()))
    }
    assert found == {}
