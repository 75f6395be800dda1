"""Fleet configuration: one TOML file every agent daemon of a fleet reads.

::

    fleet = "alpha"                   # Zenoh key prefix bf/alpha/...
    formation = "formation.toml"      # the `check` format, relative to this file: agent ids
                                      # 0..N-1, the planned (desired) formation, sensing edges
    mode = "formation-active"         # agent core mode: active, random, formation,
                                      # formation-active, hold
    clock = "wall"                    # "wall" (real flights) or "sim" (follow the simulator)
    auto_start = false                # arm, take off and start without the ground station
    takeoff_alt_m = 5.0
    prior_scale = 0.6                 # initial localization guess = planned positions x this
    on_exit = "hold"                  # on SIGINT/SIGTERM: "hold" or "land"
    bearings = "sim"                  # "sim": the simulator's virtual camera; "camera": images
                                      # through the camera pipeline (the [camera] section)

    [rates]                           # Hz
    core = 100.0                      # agent core ticks (integrated in sub-steps of <= 5 ms)
    publish = 50.0                    # peer messages (latest of each kind)
    status = 5.0                      # VehicleStatus for the ground station
    setpoint = 50.0                   # MAVLink setpoint stream (a setpoint waits <= 20 ms)

    [limits]
    max_speed_m_s = 2.0
    max_yaw_rate_rad_s = 0.8
    stale_s = 0.5                     # inputs older than this -> hold
    min_alt_m = 2.0                   # altitude envelope while flying the mission (m above the
    max_alt_m = 50.0                  # autopilot's local origin; onboard/control/envelope.py)
    max_radius_m = 100.0              # horizontal fence: a circle about the local origin (the
                                      # take-off spot); a few metres in an indoor net

    [mavlink]
    backend = "pymavlink"             # or "mavsdk"
    url = "udpin:127.0.0.1:{port}"    # {port} = port_base + port_stride * id, {id} = agent id;
                                      # on a companion computer's UART:
                                      # "serial:/dev/ttyAMA0:921600"
    port_base = 14540
    port_stride = 1                   # ArduPilot SITL: url = "tcp:127.0.0.1:{port}",
                                      # port_base = 5760, port_stride = 10 (instance i's SERIAL0)
    system_id_base = 1                # agent i talks only to autopilot system id base + i
                                      # (PX4 MAV_SYS_ID; ArduPilot MAV_SYSID, SYSID_THISMAV
                                      # before 4.7); others on the link are ignored

    [zenoh]
    mode = "peer"                     # or "client" with a router in connect
    port_base = 7447                  # agent i listens on port_base + 1 + i; the simulator on port_base
    listen = []                       # endpoints besides loopback, "{port}" = this agent's
                                      # port: ["tcp/0.0.0.0:{port}"] on a team's network
    connect = []                      # extra endpoints (a router, the other vehicles)
    multicast_scouting = false        # find peers on the local network by UDP multicast
    inject_loss = 0.0                 # fault injection (tests, demos): drop this fraction of
                                      # the peer messages received, at random
    config_file = ""                  # a full Zenoh JSON5 config (TLS...): replaces the above

    [rigidity]                        # paper 003's layer on top of the mode (docs/demo.md)
    maintenance = false               # rigidity maintenance + collision avoidance (eq. 19-31)
    graph = "all"                     # whom a camera may see: "all" (the weights drop who is
                                      # out of view or range) or "formation" (its edges only)
    rate_hz = 20.0                    # the layer's steps (a slow outer loop), <= rates.core

    [core]                            # the agent core's estimators
    localization = "paper000"         # the position estimate it flies on: paper 000's filter
                                      # (eq. 6) or "paper002", paper 002's distributed gradient
                                      # localization (eq. 16-17, 22; docs/distributed.md)
    yaw_from_bearings = false         # "paper002" only: its rotations from paper 002's yaw-only
                                      # estimate (eq. 13-15 on SO(2)) over the relative yaws of
                                      # reciprocal bearings, not paper 000's filter yaw

    [sfm]                             # the SfM observers against a biased odometry (0: off,
                                      # paper 000's observer; onboard/core/config.py AgentConfig)
    bias_speed_m_s = 0.1              # no scale correction below this speed across a bearing
    wander_window_s = 2.0             # an estimate corrected by more than wander_max within
    wander_max = 0.02                 # wander_window_s is not converged (active motion on)
    folds_forget_s = 0.0              # forget past excitation over this time (0: never)
    bias_gain = 0.0                   # estimate and subtract each edge's relative velocity
                                      # bias with this gain, 1/s^2 (0: off; an experiment,
                                      # docs/equations.md)
    bias_max_m_s = 0.1                # ... at most this large
    team_scale = false                # every pair's distance on one team scale: the SfM
                                      # distances fused through the bearings' shape (an
                                      # experiment, docs/equations.md "Fused team scale")
    warmup_s = 5.0                    # no rigidity action for this long after the core starts,
                                      # while angle localization and the eigen-estimate converge
    eigen = "distributed"             # lambda from the distributed subspace iteration, or
                                      # "centralized" (every agent's estimate, all-to-all)
    fov_deg = 120.0                   # camera field of view and range of the sensing weights
    range_m = 15.0
    lambda_safe = 0.2                 # the maintenance action starts below this eigenvalue
    lambda_min = 0.02                 # ... and grows without bound towards this one
    r_safe_m = 1.5                    # collision avoidance starts inside this distance

    [security]                        # docs/flying.md "Securing the links"
    dir = ""                          # key directory of `bearingflock keys init` (relative to
                                      # this file): MAVLink 2 signing with mavlink-vehicle-<id>.key
                                      # on every autopilot link, and Zenoh over mutual TLS with
                                      # the fleet CA (vehicle-<id>.crt/.key, every tcp/ endpoint
                                      # becomes tls/); "" = neither

    [camera]                          # bearings = "camera" (docs/vision.md)
    files = ["camera.toml"]           # camera rig: one camera file per camera_id, relative to
                                      # this file
    markers = "markers.toml"          # the fleet's markers (one per vehicle id)
    device = ""                       # "": images over Zenoh (bf/<fleet>/<id>/camera/image);
                                      # else a local OpenCV capture (index, file or URL) as camera 0
    attitude_rate_hz = 100.0          # ATTITUDE stream asked of the autopilot (pymavlink link):
                                      # levelling needs roll and pitch at each frame's exposure
    ranges = true                     # pass the markers' ranges (discs: apparent size; tags:
                                      # pose) to the core with the bearings. Unset: on with
                                      # [core] localization = "paper002" (its eq. 22 range
                                      # terms) unless rigidity.maintenance is on, else off:
                                      # paper 003's angle localization takes any range in
                                      # place of its SfM distances

Agent ids are the vehicle indices ``0..N-1`` (MAVLink system id = id + 1, PX4 SITL port
14540 + id).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Literal

import msgspec

from messages.formation import Formation, FormationError, load_formation
from messages.keys import key
from messages.transport import ZenohSettings, check_endpoint, loopback_endpoint, with_mutual_tls
from messages.vocabulary import FleetMode, Localization
from onboard.core.config import yaw_components_message
from onboard.graph import complete_graph, formation_edges, reciprocal_components
from onboard.rigidity.angle import weighted_angle_rigidity_eigenvalue
from onboard.rigidity.weights import SensingModel

MIN_MAINTENANCE_AGENTS = 4
"""Rigidity maintenance needs this many agents (:func:`load_fleet`)."""


class ConfigError(ValueError):
    """An invalid fleet configuration; the message names the problem and its place."""


class Rates(msgspec.Struct, forbid_unknown_fields=True):
    core: float = 100.0
    publish: float = 50.0
    status: float = 5.0
    setpoint: float = 50.0
    """MAVLink setpoint stream, Hz: a new setpoint waits up to a period for it (issue 27:
    50 Hz keeps bearing -> setpoint on the wire within 25 ms; 20 Hz gave p99 51-57 ms)."""


class Limits(msgspec.Struct, forbid_unknown_fields=True):
    max_speed_m_s: float = 2.0
    max_yaw_rate_rad_s: float = 0.8
    stale_s: float = 0.5
    min_alt_m: float = 2.0
    max_alt_m: float = 50.0
    max_radius_m: float = 100.0


class MavlinkSettings(msgspec.Struct, forbid_unknown_fields=True):
    backend: Literal["pymavlink", "mavsdk"] = "pymavlink"
    url: str = "udpin:127.0.0.1:{port}"
    port_base: int = 14540
    port_stride: int = 1
    system_id_base: int = 1


class ZenohSection(msgspec.Struct, forbid_unknown_fields=True):
    mode: Literal["peer", "client"] = "peer"
    port_base: int = 7447
    listen: list[str] = msgspec.field(default_factory=list)
    connect: list[str] = msgspec.field(default_factory=list)
    multicast_scouting: bool = False
    config_file: str = ""
    inject_loss: float = 0.0


class RigiditySection(msgspec.Struct, forbid_unknown_fields=True):
    maintenance: bool = False
    graph: Literal["all", "formation"] = "all"
    rate_hz: float = 20.0
    warmup_s: float = 5.0
    eigen: Literal["distributed", "centralized"] = "distributed"
    fov_deg: float = 120.0
    range_m: float = 15.0
    lambda_safe: float = 0.2
    lambda_min: float = 0.02
    r_safe_m: float = 1.5


class SfmSection(msgspec.Struct, forbid_unknown_fields=True):
    """The SfM observers' safeguards against a biased odometry (onboard/core/config.py AgentConfig;
    0 turns each off: paper 000's observer)."""

    bias_speed_m_s: float = 0.1
    wander_window_s: float = 2.0
    wander_max: float = 0.02
    folds_forget_s: float = 0.0
    bias_gain: float = 0.0
    bias_max_m_s: float = 0.1
    team_scale: bool = False


class CoreSection(msgspec.Struct, forbid_unknown_fields=True):
    """The agent core's choice of estimators (onboard/core/config.py GradientLocalizationGains)."""

    localization: Localization = "paper000"
    yaw_from_bearings: bool = False
    """``gradloc_yaw_from_bearings``: paper 002's localization flies on its own yaw-only rotation
    estimate from reciprocal bearings instead of paper 000's filter yaw (needs "paper002")."""

    def __post_init__(self) -> None:
        if self.yaw_from_bearings and self.localization != "paper002":
            raise ValueError("core.yaw_from_bearings needs localization = 'paper002'")


class CameraSection(msgspec.Struct, forbid_unknown_fields=True):
    files: list[str] = msgspec.field(default_factory=list)
    markers: str = ""
    device: str = ""
    attitude_rate_hz: float = 100.0
    ranges: bool | None = None
    """Feed the markers' ranges to the core (:attr:`Fleet.camera_ranges`; ``None``: unset)."""


class SecuritySection(msgspec.Struct, forbid_unknown_fields=True):
    dir: str = ""


class FleetConfig(msgspec.Struct, forbid_unknown_fields=True):
    formation: str
    fleet: str = "alpha"
    mode: FleetMode = "formation-active"
    clock: Literal["wall", "sim"] = "wall"
    auto_start: bool = False
    takeoff_alt_m: float = 5.0
    prior_scale: float = 0.6
    on_exit: Literal["hold", "land"] = "hold"
    bearings: Literal["sim", "camera"] = "sim"
    rates: Rates = msgspec.field(default_factory=Rates)
    limits: Limits = msgspec.field(default_factory=Limits)
    mavlink: MavlinkSettings = msgspec.field(default_factory=MavlinkSettings)
    zenoh: ZenohSection = msgspec.field(default_factory=ZenohSection)
    rigidity: RigiditySection = msgspec.field(default_factory=RigiditySection)
    camera: CameraSection = msgspec.field(default_factory=CameraSection)
    sfm: SfmSection = msgspec.field(default_factory=SfmSection)
    core: CoreSection = msgspec.field(default_factory=CoreSection)
    security: SecuritySection = msgspec.field(default_factory=SecuritySection)


class Fleet(msgspec.Struct, frozen=True):
    """A validated fleet: the parsed file and its formation."""

    config: FleetConfig
    formation: Formation
    path: str

    @property
    def n(self) -> int:
        return self.formation.n

    @property
    def camera_ranges(self) -> bool:
        """Whether the camera source passes its ranges to the core (``[camera] ranges``).

        Unset, only where a layer was built for them and nothing changes otherwise: paper 002's
        localization (eq. 22) without the rigidity layer. Paper 003's angle localization
        (:mod:`onboard.core.rigidity`) reads every range in ``own.ranges``, in place of the SfM
        distances it flies on today, so it gets camera ranges only when the file asks."""
        c = self.config
        if c.camera.ranges is not None:
            return c.camera.ranges
        return c.core.localization == "paper002" and not c.rigidity.maintenance

    def mavlink_url(self, agent_id: int) -> str:
        """``[mavlink] url`` with ``{port}`` = ``port_base + port_stride * id`` and ``{id}``."""
        return mavlink_url(self.config.mavlink, agent_id)

    def system_id(self, agent_id: int) -> int:
        """The MAVLink system id of agent ``agent_id``'s autopilot."""
        return self.config.mavlink.system_id_base + agent_id

    def zenoh_port(self, agent_id: int) -> int:
        return self.config.zenoh.port_base + 1 + agent_id

    def sim_zenoh_port(self) -> int:
        return self.config.zenoh.port_base

    def zenoh_settings(self, agent_id: int) -> ZenohSettings:
        """How agent ``agent_id`` joins the fleet's Zenoh network: it listens on its loopback
        port (and on ``[zenoh] listen``, ``{port}`` filled in) and connects to the simulator's
        and every other agent's loopback ports and to ``[zenoh] connect``."""
        z = self.config.zenoh
        port = self.zenoh_port(agent_id)
        others = [self.zenoh_port(j) for j in range(self.n) if j != agent_id]
        extra_listen = [e.replace("{port}", str(port)) for e in z.listen]
        own = loopback_endpoint(port)
        # a wildcard on the same port covers loopback, and both cannot bind it
        covered = any(
            e.split("/", 1)[-1] in (f"0.0.0.0:{port}", f"[::]:{port}") for e in extra_listen
        )
        loopback = [] if covered or z.mode != "peer" else [own]
        settings = ZenohSettings(
            mode=z.mode,
            listen=[*loopback, *extra_listen],
            connect=[loopback_endpoint(p) for p in [self.sim_zenoh_port(), *others]] + z.connect,
            multicast_scouting=z.multicast_scouting,
            config_file=str(self.resolve(z.config_file)) if z.config_file else None,
        )
        keys = self.security_dir()
        if keys is None:
            return settings
        from messages.fleetkeys import KeyStoreError, identity_files, identity_fleet, vehicle_name
        from messages.zenoh_acl import fleet_access_control

        try:  # mutual TLS with the fleet CA, as vehicle agent_id
            acl = fleet_access_control(self.config.fleet, self.n, identity_fleet(keys))
            return with_mutual_tls(
                settings, *identity_files(keys, vehicle_name(agent_id)), access_control=acl
            )
        except (ValueError, KeyStoreError) as exc:
            raise ConfigError(f"{self.path}: security.dir: {exc}") from None

    def security_dir(self) -> Path | None:
        """The key directory (``[security] dir``), or ``None`` when the links are not secured."""
        d = self.config.security.dir
        return self.resolve(d) if d else None

    def signing_key(self, agent_id: int) -> bytes | None:
        """Agent ``agent_id``'s MAVLink signing key, ``None`` without ``[security]``;
        :class:`ConfigError` (one line) if the key file is missing or malformed."""
        d = self.security_dir()
        if d is None:
            return None
        from messages.fleetkeys import KeyStoreError, load_signing_key

        try:
            return load_signing_key(d, agent_id)
        except KeyStoreError as exc:
            raise ConfigError(f"{self.path}: security.dir: {exc}") from None

    def resolve(self, name: str) -> Path:
        """A file named in the fleet file, relative to the fleet file's directory."""
        return Path(self.path).parent / name


def mavlink_url(m: MavlinkSettings, agent_id: int) -> str:
    """The autopilot URL of agent ``agent_id`` (:meth:`Fleet.mavlink_url`); raises
    ``ValueError`` for a placeholder other than ``{port}`` and ``{id}``."""
    try:
        return m.url.format(port=m.port_base + m.port_stride * agent_id, id=agent_id)
    except (KeyError, IndexError, ValueError) as exc:
        raise ValueError(
            f"mavlink.url {m.url!r}: only {{port}} and {{id}} may be filled in ({exc!r})"
        ) from None


MAVLINK_SCHEMES = frozenset({"udpin", "udpout", "udp", "udpbcast", "tcp", "tcpin", "tcpout"})
"""Network schemes of ``[mavlink] url`` (pymavlink's; MAVSDK's ``scheme://`` forms too)."""


def check_mavlink_url(url: str) -> str:
    """``url`` if it is a serial device (:func:`onboard.autopilot.base.serial_device`) or
    ``SCHEME:HOST:PORT`` / ``SCHEME://HOST:PORT`` with a scheme of :data:`MAVLINK_SCHEMES` and
    a port in 1..65535; else ``ValueError`` (a URL such as ``bogus:::`` made a daemon retry
    forever, a port of 70000 ended its link thread)."""
    from onboard.autopilot.base import serial_device

    if serial_device(url) is not None:
        return url
    scheme, sep, rest = url.partition(":")
    rest = rest[2:] if rest.startswith("//") else rest
    host, colon, port = rest.rpartition(":")
    if not sep or scheme not in MAVLINK_SCHEMES or not colon or not port.isdigit():
        raise ValueError(
            f"mavlink.url {url!r}: expected udpin:HOST:PORT, udpout:, tcp:HOST:PORT (or "
            "scheme://HOST:PORT) or a serial device such as serial:/dev/ttyACM0:921600"
        )
    if not 1 <= int(port) <= 65535:
        raise ValueError(f"mavlink.url {url!r}: port {port} outside 1..65535 (mavlink.port_base?)")
    if not host and scheme not in ("udpin", "tcpin", "udp"):
        raise ValueError(f"mavlink.url {url!r}: no host")
    return url


def _check_zenoh(path: Path, z: ZenohSection, n: int) -> None:
    """``[zenoh]``: the fleet's ports (``port_base .. port_base + n``) in 1..65535, every
    ``listen``/``connect`` endpoint well formed (``{port}`` filled in), ``config_file`` present."""
    if not (1 <= z.port_base and z.port_base + n <= 65535):
        raise ConfigError(
            f"{path}: zenoh.port_base: ports {z.port_base}..{z.port_base + n} (the simulator and "
            f"{n} agents) must lie in 1..65535"
        )
    try:
        for e in [*z.listen, *z.connect]:
            check_endpoint(e.replace("{port}", str(z.port_base + 1)))
    except ValueError as exc:
        raise ConfigError(f"{path}: zenoh: {exc}") from None
    if z.config_file and not (path.parent / z.config_file).is_file():
        raise ConfigError(f"{path}: zenoh.config_file: {path.parent / z.config_file} is not a file")


def load_fleet(path: str | Path) -> Fleet:
    """Read and validate a fleet file and the formation it names."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read file ({exc.strerror})") from None
    try:
        config = msgspec.toml.decode(raw, type=FleetConfig)
    except msgspec.ValidationError as exc:
        msg = str(exc)
        if " - at `$." in msg:
            what, where = msg.rsplit(" - at `$.", 1)
            msg = f"{where.rstrip('`')}: {what}"
        raise ConfigError(f"{path}: {msg}") from None
    except msgspec.DecodeError as exc:
        raise ConfigError(f"{path}: invalid TOML ({exc})") from None
    try:
        key(config.fleet, 0, "status")  # the fleet name is part of every Zenoh key
    except ValueError as exc:
        raise ConfigError(f"{path}: fleet: {exc}") from None
    for name, value in msgspec.structs.asdict(config.rates).items():
        if not (value > 0.0 and math.isfinite(value)):
            raise ConfigError(f"{path}: rates.{name}: must be > 0 and finite, got {value}")
    if not config.limits.min_alt_m < config.limits.max_alt_m:
        raise ConfigError(f"{path}: limits.min_alt_m must be < limits.max_alt_m")
    if config.rates.core < config.rates.publish:
        raise ConfigError(f"{path}: rates.core must be >= rates.publish")
    for name, value in msgspec.structs.asdict(config.limits).items():
        if not (value > 0.0 and math.isfinite(value)):
            raise ConfigError(f"{path}: limits.{name}: must be > 0 and finite, got {value}")
    if not 0.0 <= config.zenoh.inject_loss < 1.0:
        raise ConfigError(
            f"{path}: zenoh.inject_loss: must be in [0, 1), got {config.zenoh.inject_loss}"
        )
    if not 0.0 < config.prior_scale <= 10.0:
        raise ConfigError(f"{path}: prior_scale: must be in (0, 10], got {config.prior_scale}")
    if not 0.5 <= config.takeoff_alt_m <= 100.0:
        raise ConfigError(
            f"{path}: takeoff_alt_m: must be in [0.5, 100], got {config.takeoff_alt_m}"
        )
    rig = config.rigidity
    if not 0.0 < rig.fov_deg <= 360.0:
        raise ConfigError(f"{path}: rigidity.fov_deg: must be in (0, 360], got {rig.fov_deg}")
    if not 0.0 < rig.rate_hz <= config.rates.core:
        raise ConfigError(
            f"{path}: rigidity.rate_hz: must be in (0, rates.core], got {rig.rate_hz}"
        )
    if not rig.warmup_s >= 0.0:
        raise ConfigError(f"{path}: rigidity.warmup_s: must be >= 0, got {rig.warmup_s}")
    if not rig.range_m > 0.0 or not rig.r_safe_m > 0.0:
        raise ConfigError(f"{path}: rigidity.range_m and rigidity.r_safe_m must be > 0")
    if not 0.0 < rig.lambda_min < rig.lambda_safe:
        raise ConfigError(
            f"{path}: rigidity: need 0 < lambda_min < lambda_safe, got "
            f"{rig.lambda_min} and {rig.lambda_safe}"
        )
    for name, value in msgspec.structs.asdict(config.sfm).items():
        if not (value >= 0.0 and math.isfinite(value)) or (
            name == "wander_window_s" and value == 0
        ):
            raise ConfigError(
                f"{path}: sfm.{name}: must be finite and >= 0 (window > 0), got {value}"
            )
    cam = config.camera
    if config.bearings == "camera" and not (cam.files and cam.markers):
        raise ConfigError(f"{path}: bearings = 'camera' needs camera.files and camera.markers")
    if cam.device and len(cam.files) != 1:
        raise ConfigError(f"{path}: camera.device feeds one camera: give exactly one camera file")
    if not 0.0 < cam.attitude_rate_hz <= 1000.0:
        raise ConfigError(
            f"{path}: camera.attitude_rate_hz: must be in (0, 1000], got {cam.attitude_rate_hz}"
        )
    if config.security.dir and not (path.parent / config.security.dir).is_dir():
        raise ConfigError(
            f"{path}: security.dir: {path.parent / config.security.dir} is not a directory "
            "(bearingflock keys init DIR --fleet NAME --vehicles N)"
        )
    try:
        formation = load_formation(path.parent / config.formation)
    except FormationError as exc:
        raise ConfigError(f"{path}: formation: {exc}") from None
    if config.core.yaw_from_bearings:
        comps = reciprocal_components(formation_edges(formation), formation.n)
        if len(comps) > 1:
            raise ConfigError(f"{path}: core.yaw_from_bearings: {yaw_components_message(comps)}")
    if config.mavlink.port_stride < 1:
        raise ConfigError(
            f"{path}: mavlink.port_stride: must be >= 1, got {config.mavlink.port_stride}"
        )
    try:
        for agent_id in range(formation.n):
            check_mavlink_url(mavlink_url(config.mavlink, agent_id))
    except ValueError as exc:
        raise ConfigError(f"{path}: {exc}") from None
    _check_zenoh(path, config.zenoh, formation.n)
    base = config.mavlink.system_id_base
    if not (1 <= base and base + formation.n - 1 <= 255):
        raise ConfigError(
            f"{path}: mavlink.system_id_base: system ids {base}..{base + formation.n - 1} must "
            "be in 1..255"
        )
    if sorted(formation.ids.tolist()) != list(range(formation.n)):
        raise ConfigError(
            f"{path}: formation: agent ids must be 0..{formation.n - 1} (vehicle indices), "
            f"got {formation.ids.tolist()}"
        )
    if rig.maintenance and formation.n < MIN_MAINTENANCE_AGENTS:
        raise ConfigError(
            f"{path}: rigidity.maintenance needs at least {MIN_MAINTENANCE_AGENTS} agents, the "
            f"formation has {formation.n}: with 3 the weighted angle rigidity matrix has only 2 "
            "non-trivial modes, next to its largest eigenvalue, and the distributed estimate "
            "cannot tell them from the trivial motions (it reads 0)"
        )
    if rig.maintenance:
        lam = planned_rigidity_eigenvalue(formation, rig)
        if not lam > rig.lambda_safe:
            raise ConfigError(
                f"{path}: rigidity: the planned formation's weighted angle rigidity eigenvalue is "
                f"{lam:.3g}, not above rigidity.lambda_safe = {rig.lambda_safe:g}: the maintenance "
                "would push the team away from the formation it is told to hold. Lower "
                "lambda_safe (and lambda_min) below it, or plan a more rigid formation."
            )
    return Fleet(config=config, formation=formation, path=str(path))


def planned_rigidity_eigenvalue(formation: Formation, rigidity: RigiditySection) -> float:
    """The weighted angle rigidity eigenvalue (paper 003 eq. 16-18) of the planned formation,
    over the graph and camera the rigidity layer will use: the level its maintenance sees when
    the team holds the formation."""
    edges = complete_graph(formation.n) if rigidity.graph == "all" else formation_edges(formation)
    model = SensingModel(rigidity.fov_deg, rigidity.range_m)
    try:
        lam, _ = weighted_angle_rigidity_eigenvalue(
            formation.p_ned, formation.yaw_rad, edges, model
        )
    except ValueError:  # coincident agents
        return 0.0
    return float(lam)
