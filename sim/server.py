"""The simulator process: N autopilot endpoints, the world, the clock and the camera.

One thread runs everything with a ``selectors`` loop (no thread per vehicle): it advances the
world in fixed steps of ``dt_s`` simulation seconds as far as the clock allows, updates each
autopilot's flight logic, sends the telemetry that is due, runs the tick hooks (virtual camera,
clock publisher), and between steps reads whatever the clients sent.

Ports (docs/sim.md): in UDP mode (PX4 SITL style) vehicle ``i`` owns one socket
bound to ``bind_base + i`` and sends to ``client_base + i`` (the offboard/API port) and to
``gcs_port`` (ground stations), and to every address a valid packet came from. In TCP mode
(ArduPilot SITL style) vehicle ``i`` is a TCP server on ``tcp_base + 10 i``.

The ArduPilot flavour behaves like ArduCopter 4.7 SITL (:mod:`sim.autopilot.ardupilot`): it
streams only what is requested (``boot_streams`` streams from boot), has a position only
``ekf_warmup_s`` after boot, spools up before a take-off climbs, and refuses NaN parameters
the real one crashes on. ``strict`` makes every vehicle behave like an autopilot fresh from
boot: arming (and PX4's OFFBOARD) is refused with STATUSTEXT reasons until a simulated
warm-up of ``warmup_s`` ends, a mode set during boot is reverted when it ends, and a PX4 armed
but not flown for about 10 s disarms itself (an ArduPilot always does, after DISARM_DELAY).
"""

from __future__ import annotations

import selectors
import socket
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from sim.autopilot import (
    Autopilot,
    AutopilotOptions,
    Codec,
    LinkCounters,
    TcpLink,
    UdpLink,
    make_autopilot,
)
from sim.clock import LockstepClock, RealTimeClock
from sim.dynamics import RealisticConfig
from sim.world import DynamicsConfig, SensorNoise, World, observe

MAX_TICKS_PER_POLL = 10
"""World steps run back to back before the loop reads sockets again."""
MAX_LAG_S = 1.0
"""Real-time mode: a loop that falls further behind than this (simulation s) skips ahead."""


@dataclass
class SimConfig:
    """Everything needed to start a simulator (the CLI fills it from its options)."""

    p_ned: np.ndarray
    yaw_rad: np.ndarray
    flavour: str = "px4"
    transport: str | None = None
    """``"udp"`` or ``"tcp"``; default: udp for px4, tcp for ardupilot."""
    host: str = "127.0.0.1"
    client_base: int = 14540
    gcs_port: int | None = 14550
    bind_base: int | None = None
    """UDP port of vehicle 0's own socket (``client_base + 40`` if None, like PX4's 14580)."""
    tcp_base: int = 5760
    dt_s: float = 0.01
    speedup: float = 1.0
    lockstep: bool = False
    strict: bool = False
    warmup_s: float = 5.0
    ekf_warmup_s: float = 4.0
    """ArduPilot flavour: EKF warm-up (:class:`sim.autopilot.state.AutopilotOptions`)."""
    boot_streams: bool = False
    """ArduPilot flavour: stream from boot instead of only on request."""
    signing_key: bytes | None = None
    """One MAVLink signing key for every vehicle (``--signing-key``)."""
    signing_keys: list[bytes] | None = None
    """One key per vehicle, ``signing_keys[i]`` for vehicle ``i`` (``--keys DIR``, the fleet's
    ``mavlink-vehicle-<i>.key``); takes precedence over ``signing_key``."""
    dynamics: DynamicsConfig = field(default_factory=DynamicsConfig)
    noise: SensorNoise = field(default_factory=SensorNoise)
    realistic: RealisticConfig | None = None
    """Realistic multicopter dynamics and EKF-like telemetry (:mod:`sim.dynamics`, ``--dynamics
    realistic``); ``None`` is the ideal kinematic model."""

    def __post_init__(self) -> None:
        if self.transport is None:
            self.transport = "udp" if self.flavour == "px4" else "tcp"
        if self.transport not in ("udp", "tcp"):
            raise ValueError(f"transport must be udp or tcp, got {self.transport!r}")
        if not self.dt_s > 0.0:
            raise ValueError(f"dt_s must be > 0, got {self.dt_s}")
        if self.bind_base is None:
            self.bind_base = self.client_base + 40
        self._check_ports()
        if self.signing_keys is not None and len(self.signing_keys) != self.n:
            raise ValueError(f"signing_keys: {len(self.signing_keys)} keys for {self.n} vehicles")

    @property
    def n(self) -> int:
        return int(np.asarray(self.p_ned).reshape(-1, 3).shape[0])

    def _check_ports(self) -> None:
        """Every port the vehicles bind or send to must be a port (1..65535); ``bind_base = 0``
        (``tcp_base = 0``) lets the kernel choose each vehicle's own UDP port (TCP server port),
        printed by :meth:`SimServer.endpoints`.
        A port of 70000 used to end the loop thread with an OverflowError at its first send."""
        last = self.n - 1
        ranges: list[tuple[str, int, int]] = []
        if self.transport == "udp":
            ranges.append(("port base (client ports)", self.client_base, self.client_base + last))
            if self.bind_base != 0:
                assert self.bind_base is not None
                ranges.append(("bind base", self.bind_base, self.bind_base + last))
            if self.gcs_port is not None:
                ranges.append(("gcs port", self.gcs_port, self.gcs_port))
        elif self.tcp_base != 0:
            ranges.append(("tcp base", self.tcp_base, self.tcp_base + 10 * last))
        for name, lo, hi in ranges:
            if not (1 <= lo and hi <= 65535):
                raise ValueError(
                    f"{name}: ports {lo}..{hi} for {self.n} vehicle(s) must lie in 1..65535"
                )


TickHook = Callable[[float, World], None]


class SimServer:
    """Runs the simulation loop; :meth:`run` blocks, :meth:`start` runs it in a thread."""

    def __init__(self, config: SimConfig) -> None:
        self.config = config
        self.world = World(
            config.p_ned, config.yaw_rad, config.dynamics, realistic=config.realistic,
            dt_s=config.dt_s,
        )  # fmt: skip
        self.rng = np.random.default_rng(config.noise.seed)
        self.clock: RealTimeClock | LockstepClock
        if config.lockstep:
            self.clock = LockstepClock(on_advance=self._wake)
        else:
            self.clock = RealTimeClock(speedup=config.speedup)
        self.selector = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self.selector.register(self._wake_r, selectors.EVENT_READ, self._drain_wake)
        options = AutopilotOptions(
            strict=config.strict,
            warmup_s=config.warmup_s,
            ekf_warmup_s=config.ekf_warmup_s,
            boot_streams=config.boot_streams,
        )
        self.autopilots: list[Autopilot] = []
        self.links: list[UdpLink | TcpLink] = []
        self.hooks: list[TickHook] = []
        self.steps = 0
        self.overruns = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.failure: BaseException | None = None
        """The exception that ended the loop (:meth:`start`'s thread), ``None`` while it runs
        or after a clean :meth:`stop`: a loop that died must never look alive."""
        self._step_cond = threading.Condition()
        try:
            for i in range(self.world.n):
                self._add_vehicle(i, options)
        except Exception:  # a port in use, a bad flavour: release what was opened
            self.close()
            raise
        obs = observe(self.world, config.noise, self.rng)
        for ap in self.autopilots:
            ap.obs = obs

    def _add_vehicle(self, i: int, options: AutopilotOptions) -> None:
        cfg = self.config
        counters = LinkCounters()
        ap = make_autopilot(cfg.flavour, i, self.world, options, counters)
        key = cfg.signing_keys[i] if cfg.signing_keys is not None else cfg.signing_key
        codec = Codec(ap.dialect, ap.sys_id, signing_key=key, counters=counters)
        link: UdpLink | TcpLink
        if cfg.transport == "udp":
            assert cfg.bind_base is not None
            dests = [(cfg.host, cfg.client_base + i)]
            if cfg.gcs_port is not None:
                dests.append((cfg.host, cfg.gcs_port))
            port = 0 if cfg.bind_base == 0 else cfg.bind_base + i
            link = UdpLink(codec, (cfg.host, port), dests, ap.handle)
        else:
            port = 0 if cfg.tcp_base == 0 else cfg.tcp_base + 10 * i
            link = TcpLink(codec, (cfg.host, port), ap.handle)
        ap.send = link.send
        link.register(self.selector)
        self.autopilots.append(ap)
        self.links.append(link)

    # --- loop --------------------------------------------------------------------------------------
    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except (BlockingIOError, OSError):
            pass

    def _drain_wake(self, _mask: int) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except (BlockingIOError, OSError):
            pass

    def tick(self) -> None:
        """One world step of ``dt_s`` simulation seconds, then logic, streams and hooks."""
        w = self.world
        w.step(self.config.dt_s)
        self.steps += 1
        t = w.t_s
        for ap in self.autopilots:
            ap.update(t)
        if any(ap.due(t) for ap in self.autopilots):
            obs = observe(w, self.config.noise, self.rng)
            for ap in self.autopilots:
                ap.send_streams(t, obs)
        for hook in self.hooks:
            hook(t, w)

    def poll(self, timeout_s: float | None) -> None:
        """Handle socket events (waiting at most ``timeout_s``; ``None`` waits for one)."""
        for key, mask in self.selector.select(timeout_s):
            key.data(mask)

    def run_once(self) -> None:
        """Run the world steps the clock allows now, then wait for the next step or input."""
        dt = self.config.dt_s
        target = self.clock.target_s()
        lag = target - self.world.t_s
        if not self.clock.lockstep and lag > MAX_LAG_S:
            self.overruns += 1
            self.clock.resync(self.world.t_s)
            target = self.world.t_s + dt
        ticks = 0
        while self.world.t_s + dt <= target + 1e-9 and ticks < MAX_TICKS_PER_POLL:
            self.tick()
            ticks += 1
        if ticks:
            with self._step_cond:
                self._step_cond.notify_all()
        if self.world.t_s + dt <= self.clock.target_s() + 1e-9:
            self.poll(0.0)  # more steps are due: only read what is already there
        else:
            self.poll(self.clock.wall_wait_s(self.world.t_s + dt))

    def run(self) -> None:
        """Run until :meth:`stop` (or Ctrl-C in the caller); an exception that escapes a step
        is kept in :attr:`failure`, stops the loop and is raised again."""
        try:
            while not self._stop.is_set():
                self.run_once()
        except BaseException as exc:
            self.failure = exc
            self._stop.set()
            with self._step_cond:
                self._step_cond.notify_all()
            raise

    def _run_thread(self) -> None:
        try:
            self.run()
        except BaseException:  # kept in self.failure; the owner decides (the CLI exits 1)
            import traceback

            traceback.print_exc(file=sys.stderr)

    def start(self) -> SimServer:
        """Run the loop in a background thread (tests, embedding); watch :attr:`failure` or
        :meth:`alive`: a loop that dies sets it and stops."""
        self._thread = threading.Thread(
            target=self._run_thread, name="bearingflock-sim", daemon=True
        )
        self._thread.start()
        return self

    def alive(self) -> bool:
        """Whether the loop runs: started, not stopped, not failed."""
        return self._thread is not None and self._thread.is_alive() and not self._stop.is_set()

    def failure_text(self) -> str:
        """One line naming what ended the loop (``""`` if nothing did)."""
        exc = self.failure
        if exc is None:
            return ""
        return f"simulator loop died at t={self.world.t_s:.2f}s: {type(exc).__name__}: {exc}"

    def stop(self) -> None:
        self._stop.set()
        self._wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)
        self.close()

    def close(self) -> None:
        for link in self.links:
            link.close()
        self.links = []
        for s in (self._wake_r, self._wake_w):
            try:
                self.selector.unregister(s)
            except (KeyError, ValueError):
                pass
            s.close()
        self.selector.close()

    # --- lockstep ------------------------------------------------------------------------------------
    def advance_to(self, t_s: float, wait: bool = True, timeout_s: float = 30.0) -> None:
        """Lockstep: allow simulation time up to ``t_s``; with ``wait``, return once reached."""
        if not isinstance(self.clock, LockstepClock):
            raise RuntimeError("advance_to needs a lockstep simulator")
        self.clock.advance_to(t_s)
        if wait:
            deadline = time.monotonic() + timeout_s
            with self._step_cond:
                while self.world.t_s + self.config.dt_s <= t_s + 1e-9:
                    if self.failure is not None:
                        raise RuntimeError(self.failure_text()) from self.failure
                    left = deadline - time.monotonic()
                    if left <= 0:
                        raise TimeoutError(f"simulation did not reach t={t_s}")
                    self._step_cond.wait(min(left, 0.1))

    # --- reporting -----------------------------------------------------------------------------------
    def endpoints(self) -> list[str]:
        """Where each vehicle listens, one line per vehicle."""
        out = []
        for ap, link in zip(self.autopilots, self.links, strict=True):
            out.append(f"vehicle {ap.index} sysid {ap.sys_id}: {link.describe()}")
        return out

    def counters(self) -> dict[str, int]:
        """Counters summed over vehicles, plus loop health."""
        total: dict[str, int] = {}
        for ap in self.autopilots:
            for k, v in ap.counters.as_dict().items():
                total[k] = total.get(k, 0) + v
        total["steps"] = self.steps
        total["overruns"] = self.overruns
        return total

    def status(self) -> str:
        """A one-line live status."""
        armed = sum(ap.armed for ap in self.autopilots)
        flying = sum(ap.airborne for ap in self.autopilots)
        c = self.counters()
        bad = c["garbage_bytes"] + c["bad_crc"] + c["malformed"] + c["unknown_ids"]
        modes: dict[str, int] = {}
        for ap in self.autopilots:
            modes[ap.mode] = modes.get(ap.mode, 0) + 1
        mode_s = " ".join(f"{m}:{k}" for m, k in sorted(modes.items()))
        return (
            f"t={self.world.t_s:8.2f}s  armed {armed}/{len(self.autopilots)}  flying {flying}  "
            f"{mode_s}  rx {c['rx_packets']} tx {c['tx_packets']}  bad {bad}  "
            f"rejected {c['unsigned_rejected'] + c['bad_signature'] + c['replayed']}  overruns {c['overruns']}"
        )


def ports_needed(config: SimConfig) -> list[tuple[int, int]]:
    """(socket type, port) pairs a simulator with ``config`` binds or sends to."""
    n = config.n
    if config.transport == "tcp":
        if config.tcp_base == 0:
            return []
        return [(socket.SOCK_STREAM, config.tcp_base + 10 * i) for i in range(n)]
    assert config.bind_base is not None
    out = (
        []
        if config.bind_base == 0
        else [(socket.SOCK_DGRAM, config.bind_base + i) for i in range(n)]
    )
    out += [(socket.SOCK_DGRAM, config.client_base + i) for i in range(n)]
    if config.gcs_port is not None:
        out.append((socket.SOCK_DGRAM, config.gcs_port))
    return out


def ports_free(ports: list[tuple[int, int]], host: str = "127.0.0.1") -> bool:
    """True if every (type, port) can be bound on ``host`` right now."""
    for kind, port in ports:
        s = socket.socket(socket.AF_INET, kind)
        try:
            s.bind((host, port))
        except OSError:
            return False
        finally:
            s.close()
    return True


def ephemeral_port_start(path: str = "/proc/sys/net/ipv4/ip_local_port_range") -> int:
    """First port the kernel hands out to outgoing connections (Linux; 32768 elsewhere)."""
    try:
        with open(path) as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768


def free_port_base(n: int, span: int = 50, seed: int | None = None, tries: int = 200) -> int:
    """A port base ``b`` such that ``b .. b + span + n`` are free for UDP and TCP (tests use it
    so parallel simulators do not collide). Raises ``RuntimeError`` if none is found.

    The range lies below the kernel's ephemeral ports: there, any outgoing connection (the
    daemons' Zenoh sessions open dozens) may take a port between this check and the bind, and
    a demo daemon died of exactly that ("Address already in use")."""
    rng = np.random.default_rng(seed)
    top = min(60000, ephemeral_port_start()) - span - n
    if top <= 20000:
        top = 60000 - span - n  # no room below the ephemeral range: take the old range
    for _ in range(tries):
        base = int(rng.integers(20000, top))
        ports = [
            (k, base + d) for d in range(span + n) for k in (socket.SOCK_DGRAM, socket.SOCK_STREAM)
        ]
        if ports_free(ports):
            return base
    raise RuntimeError("no free port range found")
