"""The leader-drive payload and the formation change's new fields (messages/command.py): bounded
by msgspec ``Meta`` like every payload (a bad one is refused by the codec with its reason, and
the daemon counts it), one drive at a time (:func:`drive_problem`), classified by the ground
station's listener on its target's key only; waypoint files load or fail in one line."""

import msgspec
import pytest

from groundstation.gcs.commands import WaypointError, load_waypoints
from groundstation.gcs.zenoh_listener import classify
from messages.codec import MessageError, decode, encode
from messages.command import FormationChange, FormationSlot, LeaderDrive, drive_problem
from messages.limits import LIST_MAX
from messages.vocabulary import DropReason


def _drive(**kw):
    fields = {"sender": 0, "target": 2, "drive_id": 7, "velocity_ned": (0.2, 0.0, -0.1),
              "duration_s": 5.0} | kw  # fmt: skip
    return LeaderDrive(**fields)


def _raw(payload, **override):
    return msgspec.msgpack.encode(msgspec.to_builtins(payload) | override)


def test_a_drive_travels_whole():
    for drive in (_drive(), _drive(velocity_ned=None, duration_s=None,
                                   waypoints_ned=[(1.0, 2.0, -5.0), (0.0, 0.0, -6.0)])):  # fmt: skip
        assert decode(encode(drive), LeaderDrive) == drive
        assert drive_problem(drive) == ""


@pytest.mark.parametrize(
    ("override", "reason"),
    [
        ({"version": 3}, DropReason.VERSION),
        ({"drive_id": 0}, DropReason.OUT_OF_RANGE),
        ({"target": -1}, DropReason.OUT_OF_RANGE),
        ({"velocity_ned": [1e3, 0.0, 0.0]}, DropReason.OUT_OF_RANGE),  # > 100 m/s
        ({"duration_s": 0.0}, DropReason.OUT_OF_RANGE),
        ({"duration_s": 1e5}, DropReason.OUT_OF_RANGE),
        ({"speed_m_s": 0.0}, DropReason.OUT_OF_RANGE),
        ({"speed_m_s": 1e3}, DropReason.OUT_OF_RANGE),
        ({"tolerance_m": -1.0}, DropReason.OUT_OF_RANGE),
        ({"waypoints_ned": [[0.0, 0.0, 1e6]]}, DropReason.OUT_OF_RANGE),
        ({"waypoints_ned": [[0.0, 0.0, 0.0]] * (LIST_MAX + 1)}, DropReason.OUT_OF_RANGE),
        ({"waypoints_ned": [[0.0, 0.0]]}, DropReason.MALFORMED),
        ({"velocity_ned": [0.1, 0.0]}, DropReason.MALFORMED),
        ({"extra": 1}, DropReason.MALFORMED),
    ],
)
def test_bad_drives_are_refused_by_the_codec_with_a_reason(override, reason):
    with pytest.raises(MessageError) as exc:
        decode(_raw(_drive(), **override), LeaderDrive)
    assert exc.value.reason == reason


def test_a_non_finite_velocity_is_refused():
    with pytest.raises(MessageError) as exc:
        decode(_raw(_drive(), velocity_ned=[float("nan"), 0.0, 0.0]), LeaderDrive)
    assert exc.value.reason == DropReason.NONFINITE


def test_one_drive_at_a_time():
    assert "both" in drive_problem(_drive(waypoints_ned=[(1.0, 0.0, 0.0)]))
    assert "duration without a velocity" in drive_problem(_drive(velocity_ned=None))
    assert drive_problem(_drive(velocity_ned=None, duration_s=None)) == ""  # a stop: hold


@pytest.mark.parametrize(
    ("override", "reason"),
    [
        ({"ramp_s": -1.0}, DropReason.OUT_OF_RANGE),
        ({"ramp_s": 1e4}, DropReason.OUT_OF_RANGE),
        ({"distances": "yes"}, DropReason.MALFORMED),
    ],
)
def test_the_formation_changes_new_fields_are_bounded(override, reason):
    slots = [FormationSlot(id=i, position_ned=(float(i), 0.0, -5.0)) for i in range(3)]
    change = FormationChange(sender=0, target=1, formation_id=3, agents=slots, distances=True,
                             ramp_s=2.0)  # fmt: skip
    assert decode(encode(change), FormationChange) == change
    with pytest.raises(MessageError) as exc:
        decode(_raw(change, **override), FormationChange)
    assert exc.value.reason == reason


def test_the_listener_takes_a_drive_only_on_its_targets_key():
    data = encode(_drive(target=2))
    d = classify("alpha", "bf/alpha/2/command/leader", data)
    assert isinstance(d.payload, LeaderDrive) and d.agent_id == 2
    with pytest.raises(MessageError) as exc:
        classify("alpha", "bf/alpha/1/command/leader", data)
    assert exc.value.reason == DropReason.SENDER_MISMATCH


def test_waypoint_files(tmp_path):
    good = tmp_path / "wp.toml"
    good.write_text(
        "speed_m_s = 0.3\n[[waypoint]]\nned = [1, 2, -5]\n[[waypoint]]\nned = [0, 0, -5]\n"
    )
    assert load_waypoints(good) == ([(1.0, 2.0, -5.0), (0.0, 0.0, -5.0)], 0.3)
    cases = {
        "none.toml": "speed_m_s = 0.3\n",
        "far.toml": "[[waypoint]]\nned = [0, 0, 1e6]\n",
        "short.toml": "[[waypoint]]\nned = [0, 0]\n",
        "fast.toml": "speed_m_s = 1e3\n[[waypoint]]\nned = [0, 0, -5]\n",
        "nan.toml": "[[waypoint]]\nned = [nan, 0, -5]\n",
        "typo.toml": "[[waypoint]]\nned = [0, 0, -5]\nspeed = 1\n",
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        with pytest.raises(WaypointError) as exc:
            load_waypoints(tmp_path / name)
        assert str(exc.value).startswith(str(tmp_path / name)) and "\n" not in str(exc.value)
    with pytest.raises(WaypointError):
        load_waypoints(tmp_path / "missing.toml")
