"""``bearingflock sim --autopilot ardupilot-sitl``: N real ArduCopter SITL processes, the bridge
that rebuilds their world, and the simulator's camera, truth and clock on Zenoh.

Prints one line per vehicle (its SITL instance and where its daemon connects), then the
simulator's ready line (:data:`sim.launch.READY_LINE`) and a live status; SIGINT or SIGTERM
stops the bridge and every SITL process. A SITL process that dies ends the run with exit
status 1 and the last lines of its output.
"""

from __future__ import annotations

import signal
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from sim.camera import CameraConfig
from sim.sitl import (
    SITL_HOME,
    SitlError,
    SitlFleet,
    default_param_files,
    find_sitl,
    free_instances,
    parse_params,
)
from sim.sitl_bridge import SitlBridge, SitlPublisher


@dataclass(frozen=True)
class SitlOptions:
    """What ``bearingflock sim`` passes on (the ``--sitl*`` options)."""

    binary: Path | None = None
    sensors: str = "flow"
    defaults: str | None = None
    """Comma-separated parameter files (``None``: the sensors' files next to the binary)."""
    instance: int | None = None
    workdir: Path | None = None
    speedup: float = 1.0
    gcs_port: int | None = 14550
    stamps: str = "own"
    """Camera frames and truth on each instance's own clock, or ``"common"`` (sim.sitl_bridge)."""
    params: tuple[str, ...] = ()
    """``NAME=VALUE`` parameters set on top of the files."""


def make_fleet(p_ned: np.ndarray, yaw_rad: np.ndarray, options: SitlOptions) -> SitlFleet:
    """The (not yet started) processes; :class:`SitlError` for a missing binary or file."""
    binary = find_sitl(options.binary)
    if options.defaults:
        files = tuple(Path(f) for f in options.defaults.split(",") if f)
        missing = [str(f) for f in files if not f.is_file()]
        if missing:
            raise SitlError(f"--sitl-defaults: no such file: {', '.join(missing)}")
    else:
        files = default_param_files(binary, options.sensors)
    if not options.speedup > 0.0:
        raise SitlError(f"--speedup must be > 0, got {options.speedup}")
    params = parse_params(options.params)
    first = options.instance if options.instance is not None else free_instances(len(p_ned))
    return SitlFleet(
        binary, files, np.asarray(p_ned, dtype=float), np.asarray(yaw_rad, dtype=float),
        first, options.speedup, options.gcs_port, SITL_HOME, options.workdir, params,
    )  # fmt: skip


def run_sitl(
    p_ned: np.ndarray,
    yaw_rad: np.ndarray,
    ids: list[int] | None,
    options: SitlOptions,
    camera: CameraConfig,
    zenoh_listen: str | None,
    zenoh_connect: list[str],
    fleet_name: str,
    quiet: bool,
) -> int:
    """Run until SIGINT/SIGTERM (exit status 0) or a SITL process dies (1); 2 if SITL cannot
    start. Messages are one line each."""
    from messages.transport import TransportError, ZenohSettings, open_session, publisher_put
    from sim.launch import READY_LINE

    try:
        fleet = make_fleet(p_ned, yaw_rad, options)
    except SitlError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    stop = threading.Event()
    previous = {
        sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)
    }
    session: Any = None
    bridge: SitlBridge | None = None
    code = 0
    try:
        if zenoh_listen is not None or zenoh_connect:  # first: a port in use starts no SITL
            session = open_session(
                ZenohSettings(listen=[zenoh_listen] if zenoh_listen else [], connect=zenoh_connect)
            )
        fleet.start()
        bridge = SitlBridge([fleet.ports(i).serial1 for i in range(fleet.n)], SITL_HOME,
                            options.speedup)  # fmt: skip
        bridge.connect()  # starts the instances' clocks together
        if session is not None:
            put = publisher_put(session)
            bridge.hooks.append(
                SitlPublisher(camera, fleet_name, put, options.speedup, ids, options.stamps)
            )
        bridge.start()
        for i in range(fleet.n):
            ports = fleet.ports(i)
            gcs = f", SERIAL2 -> udp 127.0.0.1:{options.gcs_port}" if options.gcs_port else ""
            print(
                f"vehicle {i} sysid {i + 1}: ArduCopter SITL instance {ports.instance}, "
                f"tcp 127.0.0.1:{ports.serial0} (SERIAL0, the daemon's){gcs}"
            )
        if session is not None:
            print(f"zenoh: fleet {fleet_name!r}, listening on {zenoh_listen}, connecting to "
                  f"{zenoh_connect}")  # fmt: skip
        print(
            f"{fleet.n} ArduCopter SITL vehicles ({fleet.binary.name}, {options.sensors}), "
            f"speedup {options.speedup:g}; {READY_LINE}"
        )
        sys.stdout.flush()
        while not stop.wait(0.5):
            if dead := fleet.dead():
                print(f"\nerror: SITL vehicle {dead[0]} died: {fleet.log_tail(dead[0])}",
                      file=sys.stderr)  # fmt: skip
                code = 1
                break
            if bridge.error is not None:
                print(f"\nerror: {bridge.error}", file=sys.stderr)
                code = 1
                break
            if not quiet:
                end = "\r" if sys.stdout.isatty() else "\n"
                sys.stdout.write(bridge.status() + end)
                sys.stdout.flush()
    except (SitlError, ConnectionError, OSError, TransportError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        code = 2
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        if bridge is not None:
            bridge.stop()
        if session is not None:
            session.close()
        fleet.close()
    if bridge is not None:
        spread = max(bridge.spread_s, default=0.0) * 1000.0
        print(f"\nstopped at t={bridge.t_s:.2f}s; truth samples {bridge.counters['sim_state']}, "
              f"largest clock spread {spread:.1f} ms")  # fmt: skip
    return code
