"""The formation-change payload (messages/command.py): validated by the codec like every payload
(version, finiteness, bounds, sizes), its vehicle ids checked against the fleet, and classified by
the ground station's listener on its own key only."""

import msgspec
import pytest

from groundstation.gcs.commands import formation_slots
from groundstation.gcs.zenoh_listener import classify
from messages.codec import MessageError, decode, encode
from messages.command import FormationChange, FormationSlot, formation_problem
from messages.formation import parse_formation
from messages.limits import LIST_MAX
from messages.vocabulary import DropReason

TRIANGLE_TOML = """
name = "tri"
[[agent]]
id = 0
position_ned = [0.0, 0.0, -5.0]
[[agent]]
id = 1
position_ned = [4.0, 0.0, -5.0]
yaw_deg = 90.0
[[agent]]
id = 2
position_ned = [0.0, 3.0, -5.0]
"""


def _change(**kw):
    slots = formation_slots(parse_formation(TRIANGLE_TOML))
    fields = {"sender": 0, "target": 1, "formation_id": 7, "agents": slots, "leader": 2} | kw
    return FormationChange(**fields)


def _raw(change, **override):
    d = msgspec.to_builtins(change) | override
    return msgspec.msgpack.encode(d)


def test_a_formation_file_travels_whole():
    change = _change()
    back = decode(encode(change), FormationChange)
    assert back == change
    assert [a.id for a in back.agents] == [0, 1, 2]
    assert back.agents[1].yaw_rad == pytest.approx(1.5707963, abs=1e-6)
    assert formation_problem(back, {0, 1, 2}) == ""


@pytest.mark.parametrize(
    ("override", "reason"),
    [
        ({"version": 3}, DropReason.VERSION),
        ({"formation_id": 0}, DropReason.OUT_OF_RANGE),  # 0 is the fleet file's formation
        ({"leader": -1}, DropReason.OUT_OF_RANGE),
        ({"name": "x" * 65}, DropReason.OUT_OF_RANGE),
        ({"agents": [{"id": 0, "position_ned": [0.0, 0.0, 0.0]}]}, DropReason.OUT_OF_RANGE),
        ({"agents": [{"id": 0, "position_ned": [0.0, 0.0, 1e6]}] * 2}, DropReason.OUT_OF_RANGE),
        (
            {"agents": [{"id": i, "position_ned": [i, 0.0, 0.0]} for i in range(LIST_MAX + 1)]},
            DropReason.OUT_OF_RANGE,
        ),
        ({"agents": [{"id": 0, "position_ned": [0.0, 0.0]}] * 2}, DropReason.MALFORMED),
        ({"extra": 1}, DropReason.MALFORMED),
    ],
)
def test_bad_changes_are_refused_by_the_codec_with_a_reason(override, reason):
    with pytest.raises(MessageError) as exc:
        decode(_raw(_change(), **override), FormationChange)
    assert exc.value.reason == reason


def test_a_non_finite_position_is_refused():
    data = _raw(_change(), agents=[{"id": 0, "position_ned": [float("nan"), 0.0, 0.0]}] * 2)
    with pytest.raises(MessageError) as exc:
        decode(data, FormationChange)
    assert exc.value.reason == DropReason.NONFINITE
    with pytest.raises(MessageError):
        encode(_change(agents=[FormationSlot(id=0, position_ned=(float("inf"), 0.0, 0.0))] * 2))


def test_vehicle_ids_must_be_the_fleets_exactly():
    slot = _change().agents
    assert "unknown vehicle ids [5]" in formation_problem(
        _change(agents=[*slot, FormationSlot(id=5, position_ned=(9.0, 9.0, 9.0))]), {0, 1, 2}
    )
    assert "leaves out vehicles [3]" in formation_problem(_change(), {0, 1, 2, 3})
    assert "duplicate" in formation_problem(_change(agents=[*slot, slot[0]]), {0, 1, 2})
    assert "unknown leader 4" in formation_problem(_change(leader=4), {0, 1, 2})
    same = [slot[0], FormationSlot(id=1, position_ned=slot[0].position_ned), slot[2]]
    assert "coincident" in formation_problem(_change(agents=same), {0, 1, 2})


@pytest.mark.parametrize("apart_m", [1e-200, 1e-160, 1e-9, 5e-7])
def test_vehicles_closer_than_the_formation_files_tolerance_are_coincident(apart_m):
    """Found by the command fuzzing (tests/onboard/test_fuzz_receivers.py): two slots near the
    origin 1e-200 m apart passed the equality test, and the agents' desired bearing between
    them, (p_j - p_i) / |p_j - p_i| with |.| underflowing to 0, was NaN: a NaN setpoint."""
    slot = _change().agents
    near = [FormationSlot(id=0, position_ned=(0.0, 0.0, 0.0)),
            FormationSlot(id=1, position_ned=(apart_m, 0.0, 0.0)), slot[2]]  # fmt: skip
    problem = formation_problem(_change(agents=near), {0, 1, 2})
    assert "coincident vehicles 0 and 1" in problem
    far = [near[0], FormationSlot(id=1, position_ned=(2e-6, 0.0, 0.0)), slot[2]]
    assert formation_problem(_change(agents=far), {0, 1, 2}) == ""


def test_the_listener_takes_it_only_on_its_targets_key():
    data = encode(_change(target=1))
    d = classify("alpha", "bf/alpha/1/command/formation", data)
    assert isinstance(d.payload, FormationChange) and d.agent_id == 1
    with pytest.raises(MessageError) as exc:
        classify("alpha", "bf/alpha/2/command/formation", data)
    assert exc.value.reason == DropReason.SENDER_MISMATCH
