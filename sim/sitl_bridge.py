"""The bridge between ArduCopter SITL instances and the project's simulated sensors.

The built-in simulator knows its world and publishes, from it, each vehicle's virtual-camera
bearings, its ground truth and the simulation clock (:mod:`sim.camera`, :mod:`sim.clock`).
With real SITL the world is inside the SITL processes, so the bridge rebuilds it:

* it connects to every instance's SERIAL1 (a link the daemons do not use) at the same moment,
  which starts their clocks together (:mod:`sim.sitl`), and asks on that link, with
  SET_MESSAGE_INTERVAL, for SIM_STATE (the simulated vehicle's true attitude, position and
  velocity) and SYSTEM_TIME (its ``time_boot_ms``) at :data:`TRUTH_RATE_HZ`; ArduPilot keeps
  message rates per port, so the daemons' own links are untouched;
* each SIM_STATE is stamped with the instance's simulation time (the SYSTEM_TIME sent with it,
  or the instance's clock, ``speedup * wall`` plus the offset of its least-delayed recent
  SYSTEM_TIME) and converted to the common NED frame of the layout
  (:func:`truth_from_sim_state`);
* every loop it carries every vehicle's truth to the same physical instant (now) and hands it
  to :class:`SitlPublisher`, which publishes, as ``bearingflock sim`` does, each vehicle's
  virtual-camera bearings (:func:`sim.camera.visible_bearings`, the same camera model), its
  truth and the fleet's :class:`~messages.sim.SimClock`.

Clocks. Each SITL instance counts its own simulation time, and the daemons stamp their own
odometry with their autopilot's ``time_boot_ms``. Released together, the instances' clocks
still differ by the few to tens of milliseconds their boots take after the release (measured
on this 2-core machine: median 19 ms between the first and the last of three, loaded), and by
whatever an instance loses when it is starved of CPU for more than 0.2 s (SITL then gives up
catching up). So by default (``stamps = "own"``) a vehicle's camera frames and truth are
stamped on its own instance's clock, as a real camera synchronized to its autopilot would be,
and the published SimClock is the earliest clock: a daemon follows its own autopilot's clock
when that is ahead (``onboard.daemon.clock.SimClockFollower.observe``), so every daemon runs on
its own instance's time, in which its odometry and its bearings agree. ``stamps = "common"``
stamps everything with the fleet's clock instead (for comparison). The status line shows the
spread between the instances' clocks.

Truth never goes to an estimator: the daemons get bearings (what a camera would see) and their
own autopilot's telemetry; truth is published for the evaluation only, as in the simulator.
"""

from __future__ import annotations

import math
import selectors
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as dialect

from messages import mavlink as mv
from messages.codec import encode
from messages.sim import CameraBearings, SimClock, Truth, camera_key, clock_key, truth_key
from onboard.geometry import FloatArray
from sim.autopilot.state import EARTH_RADIUS_M, Home
from sim.camera import CameraConfig, perturb_bearings, visible_bearings

TRUTH_RATE_HZ = 50.0
"""SIM_STATE and SYSTEM_TIME per second (of simulation time) on the bridge's link."""
CLOCK_WINDOW = 100
"""SYSTEM_TIMEs (2 s at 50 Hz) over which an instance's clock offset is estimated."""
MAX_EXTRAPOLATION_S = 0.2
"""Simulation seconds a vehicle's truth is carried forward along its velocity at most."""
BRIDGE_SYSID = 244
CONNECT_TIMEOUT_S = 10.0

TickHook = Callable[["SitlFrame"], None]


def truth_from_sim_state(msg: Any, origin: Home) -> tuple[FloatArray, FloatArray, float, float]:
    """``(p_ned (3,), v_ned (3,), yaw_rad, yaw_rate_rad_s)`` of one SIM_STATE in the NED frame of
    ``origin`` (flat earth, the inverse of :meth:`Home.to_global`). Position from the
    integer fields ``lat_int``/``lon_int`` (1e-7 degree, about 1 cm; the float ``lat``/``lon``
    carry the same in float32, 0.4 m steps). The yaw rate is the Euler rate
    ``(q sin(roll) + r cos(roll)) / cos(pitch)`` of the body rates."""
    lat = msg.lat_int * 1e-7
    lon = msg.lon_int * 1e-7
    north = math.radians(lat - origin.lat_deg) * EARTH_RADIUS_M
    east = (
        math.radians(lon - origin.lon_deg) * EARTH_RADIUS_M * math.cos(math.radians(origin.lat_deg))
    )
    down = origin.alt_amsl_m - float(msg.alt)
    roll, pitch = float(msg.roll), float(msg.pitch)
    yaw_rate = (float(msg.ygyro) * math.sin(roll) + float(msg.zgyro) * math.cos(roll)) / max(
        1e-6, math.cos(pitch)
    )
    return (
        np.array([north, east, down]),
        np.array([float(msg.vn), float(msg.ve), float(msg.vd)]),
        float(msg.yaw),
        yaw_rate,
    )


@dataclass
class VehicleTruth:
    """The newest truth of one instance and when (its simulation time) it held."""

    t_s: float | None = None
    p_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    v_ned: FloatArray = field(default_factory=lambda: np.zeros(3))
    yaw_rad: float = 0.0
    yaw_rate_rad_s: float = 0.0
    boot_s: float | None = None
    """``time_boot_ms`` of the newest SYSTEM_TIME ..."""
    boot_wall_s: float = 0.0
    """... and the wall time it arrived."""
    offsets_s: deque[float] = field(default_factory=lambda: deque(maxlen=CLOCK_WINDOW))
    """``time_boot - speedup * wall`` of the recent SYSTEM_TIMEs: their largest is the one
    that arrived with the least delay (messages arrive up to tens of ms late)."""
    samples: int = 0
    armed: bool = False
    mode: int = -1

    def system_time(self, boot_s: float, wall_s: float, speedup: float) -> None:
        self.boot_s, self.boot_wall_s = boot_s, wall_s
        self.offsets_s.append(boot_s - speedup * wall_s)

    def sim_now(self, wall_s: float, speedup: float) -> float | None:
        """This instance's simulation time at wall time ``wall_s``: ``speedup * wall`` plus the
        least-delay offset of its recent SYSTEM_TIMEs (``None`` before the first)."""
        if not self.offsets_s:
            return None
        return speedup * wall_s + max(self.offsets_s)


@dataclass
class SitlFrame:
    """Every vehicle's truth at one physical instant, for the tick hooks. ``stamps_s`` is that
    instant on each instance's own clock, ``t_s`` the earliest of them (the fleet's clock)."""

    t_s: float
    stamps_s: FloatArray
    p_ned: FloatArray
    yaw_rad: FloatArray
    v_ned: FloatArray
    yaw_rate_rad_s: FloatArray

    @property
    def n(self) -> int:
        return int(self.p_ned.shape[0])


class SitlBridge:
    """Connects to the instances' bridge ports and runs the tick hooks (module docstring)."""

    def __init__(
        self,
        ports: Sequence[int],
        origin: Home,
        speedup: float = 1.0,
        rate_hz: float = TRUTH_RATE_HZ,
        host: str = "127.0.0.1",
    ) -> None:
        self.ports = list(ports)
        self.origin = origin
        self.speedup = speedup
        self.rate_hz = rate_hz
        self.host = host
        self.hooks: list[TickHook] = []
        self.truth = [VehicleTruth() for _ in self.ports]
        self.counters: dict[str, int] = {"sim_state": 0, "bad_data": 0, "lost": 0}
        self.spread_s: list[float] = []
        """Per tick: max - min of the instances' clocks (they should agree)."""
        self.t_s = 0.0
        self._socks: list[socket.socket] = []
        self._parsers: list[Any] = []
        self._tx = dialect.MAVLink(None, srcSystem=BRIDGE_SYSID, srcComponent=191)
        self._selector = selectors.DefaultSelector()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.error: str | None = None

    # --- connection -----------------------------------------------------------------------------
    def connect(self, timeout_s: float = CONNECT_TIMEOUT_S) -> None:
        """Connect to every bridge port back to back (this starts the instances' clocks
        together) and ask for the truth streams."""
        deadline = time.monotonic() + timeout_s
        for port in self.ports:
            while True:
                try:
                    s = socket.create_connection((self.host, port), timeout=1.0)
                    break
                except OSError:
                    if time.monotonic() > deadline:
                        self.close()
                        raise ConnectionError(f"no SITL on TCP {self.host}:{port}") from None
                    time.sleep(0.02)
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            s.setblocking(False)
            self._socks.append(s)
            p = dialect.MAVLink(None)
            p.robust_parsing = True
            self._parsers.append(p)
        for k, s in enumerate(self._socks):
            self._selector.register(s, selectors.EVENT_READ, k)

    def _ask(self, k: int) -> None:
        """SET_MESSAGE_INTERVAL for SIM_STATE and SYSTEM_TIME to instance ``k`` (the same
        interval: ArduPilot sends messages due together in one go)."""
        interval_us = 1e6 / self.rate_hz
        for msg_id in (dialect.MAVLINK_MSG_ID_SIM_STATE, dialect.MAVLINK_MSG_ID_SYSTEM_TIME):
            msg = dialect.MAVLink_command_long_message(
                k + 1, 1, mv.CMD_SET_MESSAGE_INTERVAL, 0, msg_id, interval_us, 0, 0, 0, 0, 0
            )
            self._send(k, msg)

    def _send(self, k: int, msg: Any) -> None:
        try:
            self._socks[k].sendall(msg.pack(self._tx))
        except OSError:
            self.counters["lost"] += 1

    # --- loop -----------------------------------------------------------------------------------
    def start(self) -> SitlBridge:
        self._thread = threading.Thread(target=self.run, name="sitl-bridge", daemon=True)
        self._thread.start()
        return self

    def run(self) -> None:
        asked_at = [-math.inf] * len(self._socks)
        while not self._stop.is_set():
            now = time.monotonic()
            for k, vt in enumerate(self.truth):
                # ask until the truth streams (SITL takes its first requests only once booted)
                if (vt.samples == 0 or now - vt.boot_wall_s > 2.0) and now - asked_at[k] > 1.0:
                    asked_at[k] = now
                    self._ask(k)
            for key, _mask in self._selector.select(0.005):
                self._read(key.data)
            self.tick(time.monotonic())

    def _read(self, k: int) -> None:
        try:
            data = self._socks[k].recv(65536)
        except (BlockingIOError, InterruptedError):
            return
        except OSError:
            data = b""
        if not data:
            self.error = f"SITL vehicle {k} closed its bridge link"
            self._selector.unregister(self._socks[k])
            return
        wall = time.monotonic()
        for msg in self._parsers[k].parse_buffer(data) or []:
            self.feed(k, msg, wall)

    def feed(self, k: int, msg: Any, wall_s: float) -> None:
        """Fold one message of instance ``k`` received at ``wall_s`` (public for tests)."""
        kind = msg.get_type()
        vt = self.truth[k]
        if kind == "BAD_DATA":
            self.counters["bad_data"] += 1
        elif kind == "SYSTEM_TIME":
            vt.system_time(msg.time_boot_ms / 1000.0, wall_s, self.speedup)
        elif kind == "SIM_STATE":
            # sent together with a SYSTEM_TIME (same interval): its time if it came in the same
            # read, else the instance's clock at the arrival
            same_read = vt.boot_s is not None and vt.boot_wall_s == wall_s
            t = vt.boot_s if same_read else vt.sim_now(wall_s, self.speedup)
            if t is None:
                return
            try:
                p, v, yaw, rate = truth_from_sim_state(msg, self.origin)
            except (AttributeError, ValueError):
                self.counters["bad_data"] += 1
                return
            if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v)) and math.isfinite(rate)):
                self.counters["bad_data"] += 1
                return
            vt.t_s, vt.p_ned, vt.v_ned, vt.yaw_rad, vt.yaw_rate_rad_s = t, p, v, yaw, rate
            vt.samples += 1
            self.counters["sim_state"] += 1
        elif kind == "HEARTBEAT" and msg.autopilot == mv.MAV_AUTOPILOT_ARDUPILOTMEGA:
            vt.armed = bool(msg.base_mode & mv.BASE_MODE_ARMED)
            vt.mode = int(msg.custom_mode)

    def clocks(self, wall_s: float) -> FloatArray | None:
        """Every instance's simulation time at wall time ``wall_s`` (``None`` until each has
        sent its time)."""
        clocks = [vt.sim_now(wall_s, self.speedup) for vt in self.truth]
        if any(c is None for c in clocks):
            return None
        out = np.array(clocks, dtype=float)
        self.spread_s.append(float(out.max() - out.min()))
        del self.spread_s[:-1000]
        return out

    def frame_at(self, wall_s: float) -> SitlFrame | None:
        """Every vehicle's truth carried to the physical instant ``wall_s`` along its velocity
        and yaw rate (each from its own last sample, at most :data:`MAX_EXTRAPOLATION_S`)."""
        clocks = self.clocks(wall_s)
        if clocks is None or any(vt.t_s is None for vt in self.truth):
            return None
        p, v, yaw, rate = [], [], [], []
        for vt, t_k in zip(self.truth, clocks, strict=True):
            assert vt.t_s is not None
            dt = min(MAX_EXTRAPOLATION_S, max(-MAX_EXTRAPOLATION_S, float(t_k) - vt.t_s))
            p.append(vt.p_ned + vt.v_ned * dt)
            v.append(vt.v_ned)
            yaw.append(math.remainder(vt.yaw_rad + vt.yaw_rate_rad_s * dt, math.tau))
            rate.append(vt.yaw_rate_rad_s)
        return SitlFrame(
            float(clocks.min()), clocks, np.array(p), np.array(yaw), np.array(v), np.array(rate)
        )

    def tick(self, wall_s: float) -> None:
        """Run the hooks on the frame of ``wall_s`` (the fleet's clock never runs backwards)."""
        frame = self.frame_at(wall_s)
        if frame is None or frame.t_s <= self.t_s:
            return
        self.t_s = frame.t_s
        for hook in self.hooks:
            hook(frame)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=2.0)
        self.close()

    def close(self) -> None:
        for s in self._socks:
            try:
                self._selector.unregister(s)
            except (KeyError, ValueError):
                pass
            s.close()
        self._socks = []
        self._selector.close()

    def status(self) -> str:
        """One line: time, armed count, modes, truth samples, clock spread."""
        armed = sum(vt.armed for vt in self.truth)
        modes = ",".join(str(vt.mode) for vt in self.truth)
        spread = max(self.spread_s[-100:], default=0.0) * 1000.0
        return (
            f"t={self.t_s:8.2f}s  armed {armed}/{len(self.truth)}  modes {modes}  "
            f"truth {self.counters['sim_state']}  clock spread {spread:.1f} ms"
        )


class SitlPublisher:
    """Tick hook of the bridge: camera bearings (at the camera's rate of simulation time),
    truth with them, and the SimClock (10 Hz), through ``put(key, bytes)`` (Zenoh)."""

    def __init__(
        self,
        camera: CameraConfig,
        fleet: str,
        put: Callable[[str, bytes], None],
        speedup: float,
        ids: Sequence[int] | None = None,
        stamps: str = "own",
        clock_rate_hz: float = 10.0,
    ) -> None:
        if stamps not in ("own", "common"):
            raise ValueError(f"stamps must be own or common, got {stamps!r}")
        self.camera = camera
        self.fleet = fleet
        self.put = put
        self.speedup = speedup
        self.ids = list(ids) if ids is not None else None
        self.stamps = stamps
        self.rng = np.random.default_rng(camera.seed)
        self.clock_period_s = 1.0 / clock_rate_hz
        self.next_frame_s = -math.inf
        self.next_clock_s = -math.inf
        self.seq = 0
        self.clock_seq = 0
        self.published = 0

    def __call__(self, frame: SitlFrame) -> None:
        t = frame.t_s
        if t + 1e-9 >= self.next_frame_s:
            self.next_frame_s = max(self.next_frame_s + 1.0 / self.camera.rate_hz, t)
            for key, payload in self.camera_frame(frame):
                self.put(key, encode(payload))
                self.published += 1
            self.seq += 1
        if t + 1e-9 >= self.next_clock_s:
            self.next_clock_s = max(self.next_clock_s + self.clock_period_s, t)
            msg = SimClock(
                sender=0, seq=self.clock_seq, stamp_s=t, t_s=t, step=self.clock_seq,
                speedup=float(self.speedup), lockstep=False,
            )  # fmt: skip
            self.clock_seq += 1
            self.put(clock_key(self.fleet), encode(msg))

    def camera_frame(self, frame: SitlFrame) -> list[tuple[str, CameraBearings | Truth]]:
        """Bearings and truth of every vehicle for one frame (key, payload)."""
        cfg = self.camera
        ids = self.ids if self.ids is not None else list(range(frame.n))
        edges, beta, _ = visible_bearings(frame.p_ned, frame.yaw_rad, cfg.fov_deg, cfg.range_m)
        keep, beta = perturb_bearings(beta, cfg.noise_std_rad, cfg.dropout, self.rng)
        edges, beta = edges[keep], beta[keep]
        out: list[tuple[str, CameraBearings | Truth]] = []
        for i in range(frame.n):
            stamp = float(frame.stamps_s[i]) if self.stamps == "own" else frame.t_s
            rows = edges[:, 0] == i
            out.append((
                camera_key(self.fleet, ids[i]),
                CameraBearings(
                    sender=ids[i], seq=self.seq, stamp_s=stamp,
                    targets=[ids[j] for j in edges[rows, 1]],
                    beta_body=[tuple(b) for b in beta[rows].tolist()],
                ),
            ))  # fmt: skip
            out.append((
                truth_key(self.fleet, ids[i]),
                Truth(
                    sender=ids[i], seq=self.seq, stamp_s=stamp,
                    p_ned=tuple(frame.p_ned[i].tolist()), v_ned=tuple(frame.v_ned[i].tolist()),
                    yaw_rad=float(frame.yaw_rad[i]),
                    yaw_rate_rad_s=float(frame.yaw_rate_rad_s[i]),
                ),
            ))  # fmt: skip
        return out
