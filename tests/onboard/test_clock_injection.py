"""Clock injection (issue 23, defect 3): the simulation clock is decoded through the checked
codec, implausible jumps are rejected and alarmed, and a restarted simulator is followed."""

from __future__ import annotations

import msgspec
import pytest

from messages.codec import SCHEMA_VERSION, encode
from messages.sim import SimClock
from onboard.daemon.clock import SimClockFollower
from onboard.daemon.peers import DropCounter


class _Sample:
    """A Zenoh sample as the handler reads it (``sample.payload.to_bytes()``)."""

    def __init__(self, data: bytes) -> None:
        self.payload, self.data = self, data

    def to_bytes(self) -> bytes:
        return self.data


def clock_msg(t_s: float, sender: int = 0, seq: int = 0) -> bytes:
    return encode(SimClock(sender=sender, seq=seq, stamp_s=t_s, t_s=t_s, step=seq, speedup=1.0,
                           lockstep=True))  # fmt: skip


def test_one_forged_sim_clock_far_ahead_does_not_move_the_clock():
    clock = SimClockFollower()
    clock.update(100.0, speedup=1.0, lockstep=True)
    clock.update(1100.0, speedup=1.0, lockstep=True)  # ONE sample at t + 1000 s
    assert clock.now() == 100.0
    clock.update(100.1, speedup=1.0, lockstep=True)  # the real simulator carries on
    assert clock.now() == pytest.approx(100.1)


def test_a_forged_autopilot_time_does_not_jump_the_clock():
    clock = SimClockFollower()
    clock.update(100.0, speedup=1.0, lockstep=True)
    clock.observe(4e6)  # ATTITUDE with time_boot_ms = 4e9: 46 days
    assert clock.now() == 100.0
    clock.observe(100.05)  # a plausible autopilot stamp still moves it
    assert clock.now() == pytest.approx(100.05)


def test_a_restarted_simulator_is_followed_after_a_few_consistent_samples():
    drops = DropCounter()
    clock = SimClockFollower(drop=drops.drop)
    clock.update(500.0, speedup=1.0, lockstep=True)
    for k in range(5):  # the simulator restarted: its time starts again at 0
        clock.update(0.1 * k, speedup=1.0, lockstep=True)
    assert clock.now() == pytest.approx(0.4)
    assert drops.snapshot() == {"clock_jump": 4, "clock_resync": 1}
    assert clock.fault() == "clock_resync"


def test_jumps_are_counted_and_alarmed():
    drops = DropCounter()
    clock = SimClockFollower(drop=drops.drop)
    assert clock.fault() is None
    clock.update(10.0, speedup=1.0, lockstep=True)
    clock.update(1010.0, speedup=1.0, lockstep=True)
    clock.observe(4e6)
    assert drops.snapshot() == {"clock_jump": 2} and clock.fault() == "clock_jump"


def test_the_clock_key_goes_through_the_checked_codec():
    from onboard.daemon.clock import sim_clock_handler

    drops = DropCounter()
    clock = SimClockFollower(drop=drops.drop)
    handler = sim_clock_handler(clock, drops.drop)
    raw = {"type": "sim_clock", "sender": 0, "seq": 1, "stamp_s": 5.0, "t_s": 5.0, "step": 1,
           "speedup": 1.0, "lockstep": True}  # fmt: skip
    bad = [
        clock_msg(5.0, sender=3),  # not the simulator
        msgspec.msgpack.encode({**raw, "version": SCHEMA_VERSION + 1}),
        msgspec.msgpack.encode({**raw, "version": SCHEMA_VERSION, "t_s": float("nan")}),
        msgspec.msgpack.encode({**raw, "version": SCHEMA_VERSION, "t_s": 1e300}),
        msgspec.msgpack.encode({**raw, "version": SCHEMA_VERSION, "speedup": 1e9}),
        b"\xc1",
    ]
    for data in bad:
        handler(_Sample(data))
    assert clock.now() is None
    assert drops.snapshot() == {
        "clock_unknown_sender": 1, "clock_version": 1, "clock_nonfinite": 1,
        "clock_out_of_range": 2, "clock_malformed": 1,
    }  # fmt: skip
    handler(_Sample(clock_msg(5.0)))
    assert clock.now() == 5.0
