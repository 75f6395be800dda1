"""Small pieces: MAVLink vocabulary, parameter encodings, signing keys, clocks."""

from __future__ import annotations

import hashlib
import math
import struct

import numpy as np
import pytest

from messages import mavlink as mv
from sim.autopilot.params import ardupilot_params, px4_params
from sim.autopilot.signing import key_from_bytes, load_key
from sim.clock import LockstepClock, RealTimeClock
from sim.server import SimConfig, SimServer, free_port_base
from sim.world import grid_layout


def test_px4_mode_encoding():
    assert mv.px4_custom_mode(6) == 6 << 16
    assert mv.px4_custom_mode(4, 3) == (4 << 16) | (3 << 24) == 50593792
    for name, (main, sub) in mv.PX4_MODES.items():
        assert mv.px4_mode_name(*mv.px4_decode_custom_mode(mv.px4_custom_mode(main, sub))) == name
    assert mv.px4_mode_name(42) is None
    assert mv.COPTER_MODES["GUIDED"] == 4 and mv.COPTER_MODE_NAMES[9] == "LAND"


def test_type_masks_and_setpoint_interpretation():
    assert mv.MASK_VELOCITY_YAW_RATE == 1 + 2 + 4 + 64 + 128 + 256 + 1024 == 1479
    assert mv.MASK_VELOCITY_YAW == 1 + 2 + 4 + 64 + 128 + 256 + 2048 == 2503
    sp = mv.velocity_setpoint(8, 1479, (1.0, 2.0, 3.0), math.nan, 0.5)
    assert sp is not None and sp.body and not sp.stop
    assert sp.yaw_rad is None and sp.yaw_rate_rad_s == 0.5
    sp = mv.velocity_setpoint(1, 2503, (1.0, 0.0, 0.0), 1.0, math.nan)
    assert sp is not None and sp.yaw_rad == 1.0 and sp.yaw_rate_rad_s is None and not sp.stop
    assert mv.velocity_setpoint(1, 1479, (math.nan, 0.0, 0.0), 0.0, 0.0).stop
    assert mv.velocity_setpoint(1, 0b110111111000, (0.0, 0.0, 0.0), 0.0, 0.0) is None  # position


def test_param_encodings():
    px4 = px4_params(7)
    _, p = px4.by_name("MAV_SYS_ID")
    wire = px4.wire_value(p)
    assert struct.unpack("<i", struct.pack("<f", wire))[0] == 7  # bytewise
    assert (
        px4.set_from_wire("MAV_SYS_ID", struct.unpack("<f", struct.pack("<i", 9))[0], 6).value == 9
    )
    assert px4.set_from_wire("MIS_TAKEOFF_ALT", math.nan, 9) is None
    assert px4.set_from_wire("MIS_TAKEOFF_ALT", 3.0, 6) is None  # wrong type
    assert px4.set_from_wire("NOPE", 1.0, 9) is None
    ap = ardupilot_params(3)
    _, p = ap.by_name("SYSID_THISMAV")
    assert ap.wire_value(p) == 3.0  # cast
    assert ap.set_from_wire("SYSID_THISMAV", 200.0, 6).value == 200
    assert ap.set_from_wire("SYSID_THISMAV", 300.0, 6) is None  # outside 1..255 (issue 23)
    assert ap.by_index(len(ap)) is None and ap.by_index(-1) is None


def test_signing_key_files(tmp_path):
    key = bytes(range(32))
    (tmp_path / "hex").write_text(key.hex() + "\n")
    (tmp_path / "raw").write_bytes(key)
    (tmp_path / "pass").write_text("correct horse battery staple\n")
    assert load_key(tmp_path / "hex") == key
    assert load_key(tmp_path / "raw") == key
    assert load_key(tmp_path / "pass") == hashlib.sha256(b"correct horse battery staple").digest()
    with pytest.raises(ValueError):
        key_from_bytes(b"   \n")
    with pytest.raises(ValueError):
        load_key(tmp_path / "missing")


def test_realtime_clock_speedup():
    now = [100.0]
    c = RealTimeClock(speedup=4.0, wall=lambda: now[0])
    now[0] += 0.5
    assert c.target_s() == pytest.approx(2.0)
    assert c.wall_wait_s(3.0) == pytest.approx(0.25)
    c.resync(1.0)
    assert c.target_s() == pytest.approx(1.0)
    with pytest.raises(ValueError):
        RealTimeClock(speedup=0.0)


def test_lockstep_clock():
    woken = []
    c = LockstepClock(on_advance=lambda: woken.append(1))
    assert c.target_s() == 0.0 and c.wall_wait_s(0.01) is None
    c.advance(0.5)
    c.advance_to(0.2)  # never backwards
    c.advance_to(math.nan)
    assert c.target_s() == 0.5 and len(woken) == 2
    assert c.wall_wait_s(0.4) == 0.0


def _lockstep_run(seed_cmds: int) -> np.ndarray:
    p, yaw = grid_layout(3)
    base = free_port_base(3)
    srv = SimServer(SimConfig(p, yaw, client_base=base, gcs_port=None, lockstep=True)).start()
    try:
        rng = np.random.default_rng(seed_cmds)
        for k in range(5):
            for i in range(3):
                srv.world.command_velocity(i, tuple(rng.normal(size=3)), body=bool(k % 2))
                srv.world.command_yaw_rate(i, float(rng.normal()))
            srv.advance_to(0.5 * (k + 1))
            assert srv.world.t_s == pytest.approx(0.5 * (k + 1))
        return srv.world.p_ned.copy()
    finally:
        srv.stop()


def test_lockstep_is_deterministic():
    a = _lockstep_run(1)
    b = _lockstep_run(1)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, _lockstep_run(2))
