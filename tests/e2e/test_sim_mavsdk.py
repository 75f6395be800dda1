"""MAVSDK (``mavsdk`` 4.x, the native binding) flies three simulated PX4 vehicles at once.

The simulator runs as a separate process (``python -m sim.cli``) on free ports at twice real
time; one MAVSDK instance per vehicle listens on that vehicle's offboard port, as with PX4 SITL.
"""

from __future__ import annotations

import asyncio
import math
import time

import pytest

from sim.launch import start_sim, stop_sim
from sim.server import free_port_base

pytestmark = pytest.mark.e2e

SPEEDUP = 3.0
N = 3
U_FWD_MPS = 1.0
YAWSPEED_DEG_S = 15.0
OFFBOARD_WALL_S = 3.0


@pytest.fixture
def px4_sim():
    base = free_port_base(N)
    proc = start_sim(
        "--vehicles", str(N), "--flavour", "px4", "--port-base", str(base),
        "--gcs-port", str(base + 10), "--speedup", str(SPEEDUP),
    )  # fmt: skip
    yield base
    out = stop_sim(proc)
    assert "stopped" in out


async def _first(gen, pred=lambda _x: True, timeout=15.0):
    async def take():
        async for x in gen:
            if pred(x):
                return x
        raise AssertionError("stream ended")

    return await asyncio.wait_for(take(), timeout)


async def fly_one(port: int, sys_id: int) -> dict[str, float]:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, VelocityBodyYawspeed
    from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

    cfg = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(cfg) as mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await mavsdk.first_autopilot(timeout_s=10.0)
        assert system is not None
        assert await system.get_system_id() == sys_id
        tel, act, off = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)

        # telemetry
        assert await _first(tel.subscribe_health_all_ok(), lambda ok: ok)
        assert await _first(tel.subscribe_armed()) is False
        assert await _first(tel.subscribe_flight_mode()) == FlightMode.HOLD
        assert await _first(tel.subscribe_landed_state()) == LandedState.ON_GROUND
        home = await _first(tel.subscribe_home())
        assert home.latitude_deg == pytest.approx(47.397742, abs=1e-3)
        battery = await _first(tel.subscribe_battery())
        assert 0.0 < battery.remaining_percent <= 100.0

        # arm and take off to MIS_TAKEOFF_ALT, then HOLD
        await act.arm()
        await _first(tel.subscribe_armed(), lambda a: a)
        await act.takeoff()
        await _first(tel.subscribe_in_air(), lambda a: a)
        await _first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD)
        pos = await _first(tel.subscribe_position())
        assert pos.relative_altitude_m == pytest.approx(2.5, abs=0.3)
        await asyncio.sleep(1.0)

        # offboard: body-frame velocity + yaw rate
        start = await _first(tel.subscribe_position_velocity_ned())
        heading0 = (await _first(tel.subscribe_heading())).heading_deg
        sp = VelocityBodyYawspeed(U_FWD_MPS, 0.0, 0.0, YAWSPEED_DEG_S)
        await off.set_velocity_body(sp)
        await off.start()
        t0 = time.monotonic()
        assert await _first(tel.subscribe_flight_mode()) == FlightMode.OFFBOARD
        await asyncio.sleep(OFFBOARD_WALL_S)
        end = await _first(tel.subscribe_position_velocity_ned())
        heading1 = (await _first(tel.subscribe_heading())).heading_deg
        wall = time.monotonic() - t0
        await off.set_velocity_body(VelocityBodyYawspeed(0.0, 0.0, 0.0, 0.0))
        await off.stop()
        await _first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD)

        # land; the vehicle disarms itself
        await act.land()
        await _first(tel.subscribe_flight_mode(), lambda m: m == FlightMode.LAND)
        await _first(tel.subscribe_armed(), lambda a: not a, timeout=20.0)
        assert await _first(tel.subscribe_landed_state()) == LandedState.ON_GROUND

    dn = end.position.north_m - start.position.north_m
    de = end.position.east_m - start.position.east_m
    return {
        "dist": math.hypot(dn, de),
        "bearing_deg": math.degrees(math.atan2(de, dn)),
        "dpsi_deg": (heading1 - heading0 + 180.0) % 360.0 - 180.0,
        "heading0_deg": heading0,
        "wall_s": wall,
    }


def test_mavsdk_flies_three_px4_vehicles(px4_sim):
    async def all_three():
        return await asyncio.gather(*(fly_one(px4_sim + i, i + 1) for i in range(N)))

    results = asyncio.run(asyncio.wait_for(all_three(), 90.0))
    r_rad = math.radians(YAWSPEED_DEG_S)
    for res in results:
        # heading: the commanded yaw rate over the simulated offboard time
        expected_dpsi = YAWSPEED_DEG_S * SPEEDUP * res["wall_s"]
        assert res["dpsi_deg"] == pytest.approx(expected_dpsi, rel=0.10)
        # distance: the chord of a circular arc of radius u / r flown for the same time
        t_sim = math.radians(res["dpsi_deg"]) / r_rad
        chord = 2.0 * (U_FWD_MPS / r_rad) * math.sin(r_rad * t_sim / 2.0)
        assert res["dist"] == pytest.approx(chord, rel=0.10)
        # direction: the chord points half way through the turn (the velocity lag of
        # r * tau_v ~ 4.5 deg is within 10% of the turn)
        mid = res["heading0_deg"] + res["dpsi_deg"] / 2.0
        off = (res["bearing_deg"] - mid + 180.0) % 360.0 - 180.0
        assert abs(off) < 0.10 * abs(res["dpsi_deg"])
