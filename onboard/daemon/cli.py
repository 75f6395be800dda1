"""``bearingflock agent --id I --config FLEET.toml``: run one vehicle's onboard daemon."""

from __future__ import annotations

import json
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the camera pipeline imports OpenCV: only with camera bearings
    from onboard.daemon.bearings import SimCameraSource
    from onboard.daemon.camera_source import CameraImageSource, DeviceCapture


def _error(message: str) -> None:
    """Print ``message`` on stderr (the daemon's errors; no typer on a vehicle, issue 27)."""
    print(message, file=sys.stderr, flush=True)


SIM_CLOCK_WAIT_S = 10.0
"""How long a daemon with ``clock = "sim"`` waits for the simulator's clock before its link."""


def agent(
    agent_id: int,
    config: Path,
    mavlink: str | None = None,
    backend: str | None = None,
    json_status: bool = False,
    log_level: str = "info",
    bearings: str | None = None,
    camera: Sequence[Path] | None = None,
    markers: Path | None = None,
    camera_device: str | None = None,
    system_id: int | None = None,
    clock_offset: float = 0.0,
    profile: bool = False,
) -> None:
    """Run one vehicle's onboard daemon: autopilot link, bearings, Zenoh peers, agent core.

    The options are :data:`onboard.daemon.options.AGENT_OPTIONS` (help, flags, ranges). Ends
    with :class:`SystemExit` (2: a bad fleet file or option, 1: a worker thread died): the
    code of ``bearingflock agent`` and ``python -m onboard.daemon``."""
    import os

    from messages.fatal import FatalThreads
    from onboard.daemon.daemon_env import block_unused_imports

    block_unused_imports(os.environ, sys.modules)  # before pymavlink: one dialect (issue 27)

    # first thing: a worker thread that dies at any time (a camera capture at startup, the
    # flight sequence, the link's loops) stops the daemon, which holds and exits 1 saying why,
    # instead of running on half alive (messages/fatal.py, issue 23)
    stop = threading.Event()
    fatal = FatalThreads(on_fatal=lambda _text: stop.set()).install()
    try:
        _run_agent(
            stop, agent_id, config, mavlink, backend, json_status, log_level, bearings, camera,
            markers, camera_device, system_id, clock_offset, profile,
        )  # fmt: skip
    finally:
        fatal.uninstall()
    if fatal.message:  # a worker died: the daemon held and stopped, and says why
        _error(f"error: {fatal.message}")
        raise SystemExit(1)


def _run_agent(
    stop: threading.Event,
    agent_id: int,
    config: Path,
    mavlink: str | None,
    backend: str | None,
    json_status: bool,
    log_level: str,
    bearings: str | None,
    camera: Sequence[Path] | None,
    markers: Path | None,
    camera_device: str | None,
    system_id: int | None,
    clock_offset: float,
    profile: bool = False,
) -> None:
    """The body of :func:`agent`; ``stop`` is set by the fatal-thread hook (and the signals)."""
    import msgspec

    from messages.rigidity import RIGIDITY_KINDS
    from messages.sim import clock_key
    from messages.transport import TransportError
    from onboard.autopilot import open_link
    from onboard.autopilot.base import LinkConfig
    from onboard.daemon import profile as cpu_profile
    from onboard.daemon.bearings import SimCameraSource
    from onboard.daemon.clock import OffsetClock, SimClockFollower, WallClock, sim_clock_handler
    from onboard.daemon.config import ConfigError, load_fleet
    from onboard.daemon.loop import AgentDaemon, agent_config
    from onboard.daemon.peers import DropCounter, PeerLink

    logging.basicConfig(
        level=getattr(logging, log_level.upper(), logging.INFO),
        format=f"%(asctime)s %(levelname)s agent={agent_id} %(name)s: %(message)s",
        stream=sys.stderr,
    )
    try:
        fleet = load_fleet(config)
    except ConfigError as exc:
        _error(f"error: {exc}")
        raise SystemExit(2) from None
    if not math.isfinite(clock_offset):
        _error(f"error: --clock-offset must be finite, got {clock_offset}")
        raise SystemExit(2)
    if not 0 <= agent_id < fleet.n:
        _error(f"error: --id {agent_id}: the fleet has agents 0..{fleet.n - 1}")
        raise SystemExit(2)
    c = fleet.config
    try:
        signing_key = fleet.signing_key(agent_id)
    except ConfigError as exc:
        _error(f"error: {exc}")
        raise SystemExit(2) from None
    if signing_key is not None and (backend or c.mavlink.backend) == "mavsdk":
        from onboard.autopilot.mavsdk_link import MAVSDK_CANNOT_SIGN

        _error(f"error: {MAVSDK_CANNOT_SIGN}")
        raise SystemExit(2)
    bearings = bearings or c.bearings
    if bearings not in ("sim", "camera"):
        _error(f"error: --bearings must be sim or camera, got {bearings!r}")
        raise SystemExit(2)
    pipelines = _camera_pipelines(fleet, camera, markers) if bearings == "camera" else []
    try:
        settings = fleet.zenoh_settings(agent_id)
    except ConfigError as exc:
        _error(f"error: {exc}")
        raise SystemExit(2) from None
    drops = DropCounter()
    core_config = agent_config(fleet, agent_id)
    neighbours = {j for e in core_config.graph.edges for j in e if agent_id in e} - {agent_id}
    rigidity_only = (
        {j for e in core_config.rigidity.rigidity_edges for j in e if agent_id in e}
        - neighbours
        - {agent_id}
    )
    try:
        peers = PeerLink(
            c.fleet, agent_id, range(fleet.n), settings, drops, neighbours, c.zenoh.inject_loss,
            listen_kinds=[(j, k) for j in rigidity_only for k in RIGIDITY_KINDS],
        )  # fmt: skip
    except TransportError as exc:  # a Zenoh port in use, a bad endpoint or config file
        _error(f"error: {exc}")
        raise SystemExit(2) from None
    if signing_key is not None:  # [security]: Zenoh over mutual TLS
        _warn_without_peers(peers.session, TLS_PEER_WAIT_S)
    if c.clock == "sim":
        follower = SimClockFollower(drop=drops.drop)
        peers.subscribe(clock_key(c.fleet), sim_clock_handler(follower, drops.drop))
        clock = follower
        # The simulator's autopilots send a heartbeat per *simulated* second: slower than real
        # time they arrive 1/speedup wall seconds apart, and a wall-clock heartbeat timeout would
        # declare the link lost between two of them. Learn the speed before opening the link.
        t0 = time.monotonic()
        while (
            follower.now() is None
            and time.monotonic() - t0 < SIM_CLOCK_WAIT_S
            and not stop.is_set()
        ):
            time.sleep(0.05)
        slowdown = 1.0 / min(1.0, max(follower.speedup, 1e-3))
    else:
        clock = WallClock()
        slowdown = 1.0
    if clock_offset:
        logging.getLogger(__name__).warning(
            "fault injection: clock shifted by %+.3f s", clock_offset
        )
        clock = OffsetClock(clock, clock_offset)
    link = open_link(
        backend or c.mavlink.backend,
        LinkConfig(
            rate_hz=c.rates.setpoint,
            max_speed_xy_m_s=c.limits.max_speed_m_s,
            max_speed_z_m_s=c.limits.max_speed_m_s,
            max_yaw_rate_rad_s=c.limits.max_yaw_rate_rad_s,
            heartbeat_timeout_s=LinkConfig.heartbeat_timeout_s * slowdown,
            stream_rates_hz=_stream_rates(bearings, c.camera.attitude_rate_hz),
            system_id=system_id or fleet.system_id(agent_id),
            signing_key=signing_key,
        ),
    )
    on_status = None
    if json_status:

        def on_status(status: object) -> None:
            sys.stdout.write(msgspec.json.encode(status).decode() + "\n")
            sys.stdout.flush()

    url = mavlink or fleet.mavlink_url(agent_id)
    source: SimCameraSource | CameraImageSource
    capture: DeviceCapture | None = None
    camera_source: CameraImageSource | None = None
    if bearings == "camera":
        # the camera pipeline (OpenCV, 26 MB resident) only when the bearings come from images
        from onboard.daemon.camera_source import CameraImageSource, DeviceCapture

        source = camera_source = CameraImageSource(
            agent_id,
            pipelines,
            range(fleet.n),
            drops,
            _attitude(link, clock, c.clock),
            clock=clock.now,
            ranges=fleet.camera_ranges,
        )
        device = camera_device if camera_device is not None else c.camera.device
        if device:
            try:
                capture = DeviceCapture(device, source, clock.now)
            except OSError as exc:
                _error(f"error: {exc}")
                raise SystemExit(2) from None
        else:
            source.subscribe(peers)
    else:
        source = SimCameraSource(peers, drops, clock.now)
    daemon = AgentDaemon(fleet, agent_id, link, peers, source, clock, drops, url, on_status)
    daemon.stop_event = stop  # set already if a thread died while the daemon was being built
    split = None
    if cpu_profile.enabled(profile):
        split = cpu_profile.CpuSplit()
        cpu_profile.instrument(split, daemon.core, peers)
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: daemon.stop_event.set())
    try:
        if not stop.is_set():  # a thread died during startup: nothing to fly, clean up
            daemon.run()
    finally:
        if split is not None:
            logging.getLogger(__name__).info("cpu_split %s", json.dumps(split.split()))
        if capture is not None:
            capture.close()
        if camera_source is not None:
            camera_source.close()
            st = camera_source.stats
            logging.getLogger(__name__).info(
                "camera: %d frames processed, %d skipped, %d late, %d incomplete sets, "
                "%d cut at the border, %d bearings",
                st.frames, st.skipped, st.late, st.incomplete, st.cut, st.detections,
            )  # fmt: skip
        if signing_key is not None:
            lc = link.telemetry().counters
            logging.getLogger(__name__).info(
                "mavlink signing: %d signed_ok, %d bad_signature, %d unsigned_rejected, "
                "%d replayed, %d signing_unavailable",
                lc.signed_ok, lc.bad_signature, lc.unsigned_rejected, lc.replayed,
                lc.signing_unavailable,
            )  # fmt: skip
        _close_all(link.close, peers.close)


TLS_PEER_WAIT_S = 10.0
"""With Zenoh TLS: no peer after this long is reported (a failed handshake does not fail
``zenoh.open``, the session just stays alone)."""


def _warn_without_peers(session: Any, wait_s: float) -> None:
    """Log an error once if ``session`` has no Zenoh peer ``wait_s`` after it opened."""
    from messages.transport import peer_count

    def check() -> None:
        if peer_count(session) == 0:
            logging.getLogger(__name__).error(
                "zenoh: no peer over TLS after %.0f s: the other processes' certificates are "
                "not from this fleet's CA, or they are not up (bearingflock keys show DIR)",
                wait_s,
            )

    timer = threading.Timer(wait_s, check)
    timer.daemon = True
    timer.start()


def _close_all(*closers: Any) -> None:
    """Call every closer, in order, whatever the earlier ones raise (logged). A link that
    raised on close (its TCP autopilot gone) once skipped the peers' close: Zenoh's port stayed
    held and the daemon hung on SIGTERM."""
    for close in closers:
        try:
            close()
        except Exception:
            logging.getLogger(__name__).exception("while closing %s", close)


def _camera_pipelines(fleet: Any, camera: Sequence[Path] | None, markers: Path | None) -> list[Any]:
    """One vision pipeline per camera of the rig, from the options or the fleet file."""
    from onboard.vision.config import VisionConfigError, load_camera, load_markers
    from onboard.vision.pipeline import VisionPipeline

    c = fleet.config.camera
    files = list(camera) if camera else [fleet.resolve(f) for f in c.files]
    markers_file = markers or (fleet.resolve(c.markers) if c.markers else None)
    if not files or markers_file is None:
        _error(
            "error: camera bearings need camera files and a markers file "
            "(--camera/--markers or [camera] files/markers in the fleet file)"
        )
        raise SystemExit(2)
    try:
        specs = load_markers(markers_file)
        return [VisionPipeline(load_camera(f), specs) for f in files]
    except VisionConfigError as exc:
        _error(f"error: {exc}")
        raise SystemExit(2) from None


def _stream_rates(bearings: str, attitude_rate_hz: float) -> dict[str, float]:
    """Telemetry rates to ask for: the link's defaults, and with camera bearings ATTITUDE at
    ``attitude_rate_hz``. A multicopter's tilt follows its acceleration, which changes with
    every setpoint: interpolated from a 20 Hz stream, roll and pitch at a frame's exposure were
    off by 0.2 degree (median) while flying, four times the pipeline's own bearing error; from
    100 Hz they are exact in the simulator (docs/vision.md). PX4 streams ATTITUDE at 100 Hz
    on an onboard link anyway."""
    from onboard.autopilot.base import DEFAULT_STREAM_RATES_HZ

    rates = dict(DEFAULT_STREAM_RATES_HZ)
    if bearings == "camera":
        rates["ATTITUDE"] = attitude_rate_hz
    return rates


def _attitude(link: Any, clock: Any, clock_kind: str) -> Any:
    """The autopilot's roll and pitch stamped in the frames' clock: the ATTITUDE message's own
    autopilot time (``time_boot_ms``, which is simulation time) with the simulator's clock;
    otherwise the daemon's clock minus the attitude's age. Not the newest autopilot time of any
    message: a LOCAL_POSITION_NED after the ATTITUDE re-stamped the old roll and pitch up to a
    stream period late, and levelling paired them with the wrong frames."""
    from messages.limits import stamp_ahead
    from onboard.daemon.camera_source import AttitudeSample
    from onboard.daemon.clock import autopilot_stamp

    def sample() -> AttitudeSample | None:
        tel, now = link.telemetry(), clock.now()
        if not tel.connected or now is None:
            return None
        t = autopilot_stamp(tel.t_boot_attitude_s, tel.attitude_age_s, now, clock_kind == "sim")
        if t is None or stamp_ahead(t, now):  # a forged time_boot_ms would end the history
            return None
        return AttitudeSample(t, tel.roll_rad, tel.pitch_rad)

    return sample
