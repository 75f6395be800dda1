"""The alarm vocabulary: one word per kind, the same at both ends."""

import pytest

from messages.vocabulary import PER_PEER, Alarm, alarm_kind, alarm_text


def test_every_kind_reads_back_from_its_wire_form() -> None:
    for kind in Alarm:
        text = alarm_text(kind, 3 if kind in PER_PEER else None)
        assert alarm_kind(text) is kind
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
