"""``bearingflock gcs ...``: the operator's commands (``docs/gcs.md``).

* ``monitor`` — live full-screen table of every vehicle (``--once --json``: one snapshot);
* ``arm | takeoff | land`` (autopilots, MAVLink), ``start | hold`` (agents, Zenoh), ``stop``
  (both: the emergency action) — to ``--ids 1,3`` or ``--all``, confirmed unless ``--yes``;
* ``view`` — the team's 3D scene live to Foxglove over its WebSocket protocol;


* ``formation FILE.toml [--leader ID] [--distances] [--ramp S]`` — a new desired formation to the
  flying agents (``--distances``: its size too, a scale change);
* ``leader ID --velocity VX,VY,VZ [--duration S] | --waypoints FILE`` — drive the formation's
  leader (the others follow its bearings);
* ``record OUT.mcap``, ``replay IN.mcap [--speed K]``, ``plot IN.mcap --out DIR``;
* ``estimate [--duration S] [--json]`` — paper 001's centralized EKF live over Zenoh beside the
  daemons' estimates (``--replay IN.mcap``: on a recording).

Exit status: 0 success, 1 a command failed for some vehicle (or was not confirmed), 2 bad
usage or a link that cannot be opened. Zenoh, pymavlink, mcap and matplotlib are imported
inside the commands so that ``bearingflock --help`` stays instant.
"""

from __future__ import annotations

import json as jsonlib
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer

EXIT_OK, EXIT_FAILED, EXIT_INVALID = 0, 1, 2
DEFAULT_MAVLINK = "udp:0.0.0.0:14550"
DEFAULT_ZENOH = "tcp/127.0.0.1:7447"

gcs_app = typer.Typer(
    name="gcs",
    help="Ground station: monitor, fleet commands, view, record, replay, plot.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)


@gcs_app.callback()
def _gcs() -> None:
    """Ground station: monitor, fleet commands, view, record, replay, plot."""


# --- shared options ---------------------------------------------------------------------------------
FleetOpt = Annotated[str, typer.Option("--fleet", help="Fleet name (Zenoh keys bf/NAME/...).")]
MavlinkOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--mavlink",
        help=f"MAVLink endpoint, repeatable: udp:HOST:PORT listens, udpout:HOST:PORT sends to a "
        f"vehicle; 'none' turns MAVLink off (default {DEFAULT_MAVLINK}).",
    ),
]
ZenohOpt = Annotated[
    list[str] | None,
    typer.Option(
        "--zenoh",
        help=f"Zenoh endpoint to connect to, repeatable; 'none' turns Zenoh off "
        f"(default {DEFAULT_ZENOH}).",
    ),
]
ZenohListenOpt = Annotated[
    list[str] | None, typer.Option("--zenoh-listen", help="Zenoh endpoint to listen on.")
]
KeysOpt = Annotated[
    Path | None,
    typer.Option(
        "--keys",
        help="Fleet key directory (security.dir): sign MAVLink to vehicle i with "
        "mavlink-vehicle-<i>.key and accept only correctly signed messages; Zenoh over mutual "
        "TLS as the ground station (gcs.crt; tcp/ endpoints become tls/).",
    ),
]
SysidOpt = Annotated[
    int, typer.Option("--sysid-offset", help="MAVLink system id = agent id + this.")
]


def _fail(message: str, code: int = EXIT_INVALID) -> typer.Exit:
    sys.stderr.write(f"error: {message}\n")
    return typer.Exit(code)


def _check_recording(src: Path) -> None:
    """Exit 2 unless ``src`` is an MCAP file (``gcs replay`` and ``gcs plot``)."""
    from groundstation.gcs.record import NotMcapError, check_mcap

    if not src.is_file():
        raise _fail(f"{src}: no such file")
    try:
        check_mcap(src)
    except NotMcapError as exc:
        raise _fail(str(exc)) from None


def _read_recording(src: Path) -> Any:
    """Read a recording (also one a killed recorder left: say so, and how much was recovered);
    exit 2 if it is not one, 1 if nothing could be recovered."""
    from groundstation.gcs.record import read_recording

    _check_recording(src)
    recording = read_recording(src)
    if recording.unreadable:
        typer.echo(
            f"{src}: skipped {recording.unreadable} messages of payload types this version "
            "does not know (a newer bearingflock's recording?)",
            err=True,
        )
    if not recording.complete:
        typer.echo(recording.describe(src), err=True)
        if not recording.records:
            raise _fail(f"{src}: nothing to read before its truncated end", EXIT_FAILED)
    return recording


def _off(values: list[str]) -> bool:
    return any(v.strip().lower() in ("none", "off", "") for v in values)


def _signing_keys(keys: Path | None, sysid_offset: int) -> dict[int, bytes] | None:
    """System id -> signing key of every vehicle in ``keys`` (``None`` without ``--keys``)."""
    if keys is None:
        return None
    from messages.fleetkeys import KeyStoreError, load_signing_keys

    try:
        return {i + sysid_offset: k for i, k in load_signing_keys(keys).items()}
    except KeyStoreError as exc:
        raise _fail(f"--keys: {exc}") from None


def _open_mavlink(
    stack: ExitStack,
    endpoints: list[str] | None,
    keys: Path | None = None,
    sysid_offset: int = 1,
) -> Any:
    from groundstation.gcs.mavlink_listener import MavlinkListener, parse_endpoint

    values = endpoints or [DEFAULT_MAVLINK]
    if _off(values):
        return None
    signing = _signing_keys(keys, sysid_offset)
    try:
        listener = MavlinkListener([parse_endpoint(e) for e in values], signing_keys=signing)
    except (ValueError, OSError) as exc:
        raise _fail(str(exc)) from None
    stack.callback(listener.close)
    return listener.start()


def _open_zenoh(
    stack: ExitStack,
    connect: list[str] | None,
    listen: list[str] | None,
    keys: Path | None = None,
    fleet: str = "alpha",
) -> Any:
    from messages.transport import ZenohSettings, open_session, with_mutual_tls

    values = connect if connect is not None else [DEFAULT_ZENOH]
    if _off(values):
        if listen:  # never drop an endpoint silently (issue 23)
            raise _fail(f"--zenoh-listen {' '.join(listen)}: Zenoh is off (--zenoh none)")
        return None
    settings = ZenohSettings(connect=values, listen=listen or [])
    if keys is not None:  # mutual TLS with the fleet CA, as the ground station
        from messages.fleetkeys import (
            GCS_NAME,
            KeyStoreError,
            identity_files,
            identity_fleet,
            vehicle_count,
        )
        from messages.zenoh_acl import fleet_access_control

        try:
            acl = fleet_access_control(fleet, vehicle_count(keys), identity_fleet(keys))
            settings = with_mutual_tls(settings, *identity_files(keys, GCS_NAME), acl)
        except (ValueError, KeyStoreError) as exc:
            raise _fail(f"--keys: {exc}") from None
    try:
        session = open_session(settings)
    except Exception as exc:  # zenoh raises its own error type for a bad endpoint
        raise _fail(f"cannot open a Zenoh session: {exc}") from None
    stack.callback(session.close)
    return session


def _zenoh_listener(stack: ExitStack, session: Any, fleet: str) -> Any:
    from groundstation.gcs.zenoh_listener import ZenohListener

    if session is None:
        return None
    listener = ZenohListener(session, fleet).start()
    stack.callback(listener.close)
    return listener


def _wait(stop: Any, duration: float | None) -> None:
    """Until ``stop`` (a ``threading.Event``) is set, ``duration`` seconds pass, or Ctrl-C."""
    t_end = None if duration is None else time.monotonic() + duration
    try:
        while not stop.wait(0.2):
            if t_end is not None and time.monotonic() >= t_end:
                return
    except KeyboardInterrupt:
        pass


def _check_fleet(fleet: str) -> None:
    from messages.keys import fleet_keys

    try:
        fleet_keys(fleet)
    except ValueError as exc:
        raise _fail(str(exc)) from None


@contextmanager
def _sigterm_event() -> Iterator[threading.Event]:
    """An event set on SIGTERM (Ctrl-C raises KeyboardInterrupt as usual); the previous
    handler comes back on exit. Outside the main thread there is no handler to install."""
    stop = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield stop
        return
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        yield stop
    finally:
        signal.signal(signal.SIGTERM, previous)


# --- monitor ----------------------------------------------------------------------------------------
@gcs_app.command("monitor")
def monitor(
    fleet: FleetOpt = "alpha",
    mavlink: MavlinkOpt = None,
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    once: Annotated[bool, typer.Option("--once", help="Print one snapshot and exit.")] = False,
    json: Annotated[bool, typer.Option("--json", help="With --once: print JSON.")] = False,
    wait: Annotated[
        float, typer.Option("--wait", help="With --once: listen this long first (s).")
    ] = 2.5,
    sysid_offset: SysidOpt = 1,
    keys: KeysOpt = None,
    ekf: Annotated[
        bool,
        typer.Option(
            "--ekf", help="Also run paper 001's EKF (as gcs estimate) and show its columns."
        ),
    ] = False,
) -> None:
    """Live table of every vehicle: link health, autopilot, estimator, alarms."""
    from groundstation.gcs.monitor import Monitor, MonitorConfig, render

    _check_fleet(fleet)
    if json and not once:
        raise _fail("--json needs --once")
    with ExitStack() as stack:
        session = _open_zenoh(
            stack, zenoh, zenoh_listen, keys, fleet
        )  # first: opening takes a while
        zen = _zenoh_listener(stack, session, fleet)
        mav = _open_mavlink(stack, mavlink, keys, sysid_offset)
        summary = None
        if ekf:
            if session is None:
                raise _fail("--ekf listens on Zenoh: --zenoh none is not possible")
            from groundstation.gcs.ekf_live import BackgroundEstimator
            from groundstation.gcs.ekf_loop import EkfLoop

            bg = BackgroundEstimator(session, fleet, EkfLoop()).start()
            stack.callback(bg.close)
            summary = bg.summary
        mon = Monitor(MonitorConfig(fleet=fleet, sysid_offset=sysid_offset), mav, zen, ekf=summary)
        if once:
            time.sleep(max(0.0, wait))
            snap = mon.snapshot()
            if json:
                typer.echo(jsonlib.dumps(snap, indent=1))
            else:
                from rich.console import Console

                Console(width=None if sys.stdout.isatty() else 160).print(render(snap))
            return
        with _sigterm_event() as stop:
            mon.live(stop=stop)


# --- fleet commands -----------------------------------------------------------------------------------
def _fleet_command(
    action: str,
    ids: str | None,
    all_: bool,
    yes: bool,
    fleet: str,
    mavlink: list[str] | None,
    zenoh: list[str] | None,
    zenoh_listen: list[str] | None,
    timeout: float,
    discover_s: float,
    sysid_offset: int,
    alt: float,
    json: bool,
    keys: Path | None = None,
) -> None:
    from groundstation.gcs import commands as cmds

    _check_fleet(fleet)
    if ids is not None and all_:
        raise _fail("give either --ids or --all, not both")
    if ids is None and not all_ and action != "stop":
        raise _fail(f"{action}: select vehicles with --ids 1,3 or --all")
    try:
        wanted = cmds.parse_ids(ids) if ids is not None else None
    except ValueError as exc:
        raise _fail(str(exc)) from None
    needs_mav = action in ("arm", "takeoff", "land", "stop")
    needs_zen = action in ("start", "hold", "stop")
    with ExitStack() as stack:
        session = _open_zenoh(stack, zenoh, zenoh_listen, keys, fleet) if needs_zen else None
        zen = _zenoh_listener(stack, session, fleet)
        mav = _open_mavlink(stack, mavlink, keys, sysid_offset) if needs_mav else None
        if needs_mav and mav is None and action != "stop":
            raise _fail(f"{action} goes over MAVLink: --mavlink none is not possible")
        if needs_zen and zen is None and action != "stop":
            raise _fail(f"{action} goes over Zenoh: --zenoh none is not possible")
        autopilots, agents = cmds.discover(mav, zen, wanted, discover_s, sysid_offset)
        if wanted is not None:
            targets = list(wanted)
        elif action == "stop":
            targets = sorted(autopilots | agents)
        else:
            targets = sorted(autopilots if needs_mav else agents)
        if not targets:
            heard_on = []
            if needs_zen:
                heard_on.append(f"agents of fleet {fleet!r} on Zenoh (--fleet, --zenoh)")
            if needs_mav:
                heard_on.append("autopilots on MAVLink (--mavlink)")
            raise _fail(
                f"{action}: no vehicles heard within {discover_s:g} s; listened for "
                + " and ".join(heard_on),
                EXIT_FAILED,
            )
        listing = ", ".join(str(i) for i in targets)
        if not yes and not typer.confirm(f"{action} vehicles {listing} of fleet {fleet!r}?"):
            typer.echo("not confirmed: nothing sent")
            raise typer.Exit(EXIT_FAILED)
        if action == "stop":
            results = _stop(cmds, mav, session, zen, fleet, targets, agents, timeout, sysid_offset)
        elif needs_mav:
            results = cmds.run_mavlink(mav, action, targets, sysid_offset, timeout, alt)
        else:
            results = cmds.run_zenoh(session, zen, fleet, action, targets, timeout)
    failed = [i for i, o in results.items() if not o.ok]
    if json:
        payload = [{"id": i, "ok": o.ok, "details": o.details} for i, o in sorted(results.items())]
        typer.echo(jsonlib.dumps({"action": action, "results": payload}))
    else:
        for i, o in sorted(results.items()):
            typer.echo(f"vehicle {i}: {'OK  ' if o.ok else 'FAIL'}  " + "; ".join(o.details))
        typer.echo(f"{action}: {len(results) - len(failed)}/{len(results)} vehicles OK")
    if failed:
        raise typer.Exit(EXIT_FAILED)


def _stop(
    cmds: Any,
    mav: Any,
    session: Any,
    zen: Any,
    fleet: str,
    targets: list[int],
    agents: set[int],
    timeout: float,
    sysid_offset: int,
) -> dict[int, Any]:
    """LAND over MAVLink and ``stop`` over Zenoh, both at once (two threads)."""
    mav_out: dict[int, Any] = {}
    zen_out: dict[int, Any] = {}

    def over_zenoh() -> None:
        zen_out.update(
            cmds.run_zenoh(session, zen, fleet, "stop", targets, timeout, expect=sorted(agents))
        )

    thread = None
    if session is not None:
        thread = threading.Thread(target=over_zenoh, daemon=True)
        thread.start()
    if mav is not None:
        mav_out = cmds.run_mavlink(mav, "stop", targets, sysid_offset, timeout)
    if thread is not None:
        thread.join(timeout + 1.0)
    return cmds.merge_stop(mav_out, zen_out)


def _make_command(action: str, doc: str) -> None:
    def command(
        ids: Annotated[
            str | None, typer.Option("--ids", help="Vehicle (agent) ids, e.g. 1,3 or 0-3.")
        ] = None,
        all_: Annotated[bool, typer.Option("--all", help="Every vehicle heard.")] = False,
        yes: Annotated[
            bool, typer.Option("--yes", "-y", help="Do not ask for confirmation.")
        ] = False,
        fleet: FleetOpt = "alpha",
        mavlink: MavlinkOpt = None,
        zenoh: ZenohOpt = None,
        zenoh_listen: ZenohListenOpt = None,
        timeout: Annotated[
            float, typer.Option("--timeout", help="Seconds to wait for each acknowledgement.")
        ] = 3.0,
        discover: Annotated[
            float, typer.Option("--discover", help="Seconds to listen for vehicles first.")
        ] = 2.0,
        sysid_offset: SysidOpt = 1,
        alt: Annotated[
            float,
            typer.Option(
                "--alt", help="takeoff: altitude (m, ArduPilot; PX4 uses MIS_TAKEOFF_ALT)."
            ),
        ] = 2.5,
        json: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")] = False,
        keys: KeysOpt = None,
    ) -> None:
        _fleet_command(
            action, ids, all_, yes, fleet, mavlink, zenoh, zenoh_listen, timeout, discover,
            sysid_offset, alt, json, keys,
        )  # fmt: skip

    command.__doc__ = doc
    gcs_app.command(action)(command)


_make_command("arm", "Arm the selected autopilots (MAVLink).")
_make_command("takeoff", "Take off with the selected autopilots (MAVLink).")
_make_command("start", "Start the mission on the selected agents (Zenoh).")
_make_command("hold", "Hold position: the selected agents stop moving (Zenoh).")
_make_command("land", "Land the selected autopilots (MAVLink).")
_make_command(
    "stop",
    "EMERGENCY: LAND to every selected autopilot and stop to every agent (default: all).",
)


# --- view ------------------------------------------------------------------------------------------
@gcs_app.command("view")
def view(
    fleet: FleetOpt = "alpha",
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    host: Annotated[
        str, typer.Option("--host", help="Address the Foxglove WebSocket server binds to.")
    ] = "127.0.0.1",
    port: Annotated[
        int, typer.Option("--port", min=0, max=65535, help="Its port (0: a free one).")
    ] = 8765,
    fov_deg: Annotated[
        float, typer.Option("--fov-deg", help="The vehicles' camera field of view (deg).")
    ] = 120.0,
    range_m: Annotated[
        float, typer.Option("--range-m", help="The vehicles' sensing range (m).")
    ] = 15.0,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds.")
    ] = None,
    keys: KeysOpt = None,
) -> None:
    """Serve the team live to Foxglove (WebSocket): poses, estimates, edges, frusta, alarms."""
    from messages.optional import require

    require("foxglove")
    from groundstation.gcs.foxglove_scene import SceneBuilder
    from groundstation.gcs.view import LiveView
    from onboard.rigidity.weights import SensingModel

    _check_fleet(fleet)
    if duration is not None and not (math.isfinite(duration) and duration > 0.0):
        raise _fail(f"--duration must be a finite number of seconds > 0, got {duration}")
    try:
        camera = SensingModel(fov_deg, range_m)
    except ValueError as exc:
        raise _fail(f"--fov-deg/--range-m: {exc}") from None
    with ExitStack() as stack:
        stop = stack.enter_context(_sigterm_event())
        session = _open_zenoh(stack, zenoh, zenoh_listen, keys, fleet)
        if session is None:
            raise _fail("gcs view draws what it hears on Zenoh: --zenoh none leaves nothing")
        try:
            live = LiveView(fleet, SceneBuilder(camera=camera), host, port).start()
        except Exception as exc:  # the SDK raises its own error type for a taken port
            raise _fail(f"cannot serve on {host}:{port}: {exc}") from None
        stack.callback(live.close)
        zen = _zenoh_listener(stack, session, fleet)
        zen.sample_hooks.append(live.zenoh_sample)
        typer.echo(
            f"serving fleet {fleet!r} to Foxglove on ws://{host}:{live.port} "
            "(Foxglove: Open connection, Foxglove WebSocket); Ctrl-C to stop",
            err=True,
        )
        _wait(stop, duration)
        zen.close()  # the hooks stop before the server does


@gcs_app.command("formation")
def formation(
    file: Annotated[Path, typer.Argument(help="Formation file (README, 'Formation files').")],
    leader: Annotated[
        int | None,
        typer.Option("--leader", help="Vehicle that holds its position (or flies `gcs leader`)."),
    ] = None,
    distances: Annotated[
        bool,
        typer.Option(
            "--distances",
            help="Hold the file's distances too (paper 002 eq. 23): a scale change. Default: "
            "bearings only, the team keeps its size.",
        ),
    ] = False,
    ramp: Annotated[
        float | None,
        typer.Option("--ramp", help="Seconds over which the agents switch (default: theirs, 3)."),
    ] = None,
    formation_id: Annotated[
        int | None, typer.Option("--id", help="Formation id (default: from the clock).")
    ] = None,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask for confirmation.")] = False,
    fleet: FleetOpt = "alpha",
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    timeout: Annotated[
        float, typer.Option("--timeout", help="Seconds to wait for every status to show it.")
    ] = 5.0,
    json: Annotated[bool, typer.Option("--json", help="Print the results as JSON.")] = False,
    keys: KeysOpt = None,
) -> None:
    """Send a new desired formation to the flying agents (Zenoh); each status acknowledges it."""
    from groundstation.gcs import commands as cmds
    from messages.command import RAMP_MAX_S
    from messages.formation import FormationError, load_formation

    _check_fleet(fleet)
    if ramp is not None and not (math.isfinite(ramp) and 0.0 <= ramp <= RAMP_MAX_S):
        raise _fail(f"--ramp must be a number of seconds in [0, {RAMP_MAX_S:g}], got {ramp}")
    try:
        f = load_formation(file)
    except FormationError as exc:
        raise _fail(str(exc)) from None
    ids = [int(i) for i in f.ids]
    if leader is not None and leader not in ids:
        raise _fail(f"--leader {leader} is not a vehicle of {file} (ids {ids})")
    fid = formation_id if formation_id is not None else time.time_ns() // 1_000_000 % (1 << 40)
    if fid < 1:
        raise _fail(f"--id must be >= 1 (0 is the fleet file's formation), got {fid}")
    if not yes and not typer.confirm(f"formation {f.name!r} (id {fid}) to vehicles {ids}?"):
        typer.echo("not confirmed: nothing sent")
        raise typer.Exit(EXIT_FAILED)
    with ExitStack() as stack:
        session = _open_zenoh(stack, zenoh, zenoh_listen, keys, fleet)
        zen = _zenoh_listener(stack, session, fleet)
        if zen is None:
            raise _fail("formation goes over Zenoh: --zenoh none is not possible")
        results = cmds.run_formation(
            session, zen, fleet, f, ids, timeout, fid, leader, distances, ramp
        )
    failed = [i for i, o in results.items() if not o.ok]
    sent = {"formation": f.name, "id": fid, "leader": leader, "vehicles": ids,
            "distances": distances, "ramp_s": ramp}  # fmt: skip
    if json:
        rows = [{"id": i, "ok": o.ok, "details": o.details} for i, o in sorted(results.items())]
        typer.echo(jsonlib.dumps({**sent, "results": rows}))
    else:
        lead = f", leader {leader}" if leader is not None else ""
        lead += ", with its distances" if distances else ""
        typer.echo(f"sent formation {f.name!r} id {fid}{lead} to vehicles {ids}")
        for i, o in sorted(results.items()):
            typer.echo(f"vehicle {i}: {'OK  ' if o.ok else 'FAIL'}  " + "; ".join(o.details))
        typer.echo(f"formation: {len(results) - len(failed)}/{len(results)} vehicles OK")
    if failed:
        raise typer.Exit(EXIT_FAILED)


def _vector3(text: str, what: str) -> tuple[float, float, float]:
    try:
        v = tuple(float(x) for x in text.split(","))
    except ValueError:
        v = ()
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        raise _fail(f"{what} must be three finite numbers VX,VY,VZ, got {text!r}")
    return v  # type: ignore[return-value]


@gcs_app.command("leader")
def leader(
    vehicle: Annotated[
        int, typer.Argument(help="The formation's leader (gcs formation --leader).")
    ],
    velocity: Annotated[
        str | None,
        typer.Option("--velocity", help="VX,VY,VZ m/s, NED in the leader's odometry frame."),
    ] = None,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Seconds of --velocity, then it holds.")
    ] = None,
    waypoints: Annotated[
        Path | None,
        typer.Option("--waypoints", help="Waypoint file (docs/gcs.md): NED in its odometry frame."),
    ] = None,
    speed: Annotated[
        float | None, typer.Option("--speed", help="Waypoint speed bound, m/s (default 0.5).")
    ] = None,
    drive_id: Annotated[
        int | None, typer.Option("--id", help="Drive id (default: from the clock).")
    ] = None,
    yes: Annotated[bool, typer.Option("--yes", "-y", help="Do not ask for confirmation.")] = False,
    fleet: FleetOpt = "alpha",
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    timeout: Annotated[
        float, typer.Option("--timeout", help="Seconds to wait for its status to show it.")
    ] = 5.0,
    json: Annotated[bool, typer.Option("--json", help="Print the result as JSON.")] = False,
    keys: KeysOpt = None,
) -> None:
    """Drive the formation's leader with a velocity or waypoints (Zenoh); the others follow."""
    import msgspec

    from groundstation.gcs import commands as cmds
    from messages.command import LeaderDrive

    _check_fleet(fleet)
    if (velocity is None) == (waypoints is None):
        raise _fail("give exactly one of --velocity VX,VY,VZ and --waypoints FILE")
    if duration is not None and velocity is None:
        raise _fail("--duration goes with --velocity")
    if speed is not None and waypoints is None:
        raise _fail("--speed goes with --waypoints")
    fields: dict[str, Any] = {"sender": cmds.GCS_SENDER_ID, "target": vehicle}
    if velocity is not None:
        fields["velocity_ned"] = _vector3(velocity, "--velocity")
        if duration is not None:
            fields["duration_s"] = duration
    else:
        assert waypoints is not None
        try:
            points, file_speed = cmds.load_waypoints(waypoints)
        except cmds.WaypointError as exc:
            raise _fail(str(exc)) from None
        fields["waypoints_ned"] = points
        if speed is not None or file_speed is not None:
            fields["speed_m_s"] = speed if speed is not None else file_speed
    did = drive_id if drive_id is not None else time.time_ns() // 1_000_000 % (1 << 40)
    fields["drive_id"] = did
    try:  # the payload's own bounds (messages/command.py), as the agent will check them
        drive = msgspec.convert(fields, LeaderDrive)
    except msgspec.ValidationError as exc:
        raise _fail(f"not a leader drive: {exc}") from None
    what = (
        f"velocity {drive.velocity_ned} m/s"
        + (f" for {drive.duration_s:g} s" if drive.duration_s is not None else "")
        if drive.velocity_ned is not None
        else f"{len(drive.waypoints_ned)} waypoints at {drive.speed_m_s:g} m/s"
    )
    if not yes and not typer.confirm(f"leader {vehicle}: {what} (drive {did})?"):
        typer.echo("not confirmed: nothing sent")
        raise typer.Exit(EXIT_FAILED)
    with ExitStack() as stack:
        session = _open_zenoh(stack, zenoh, zenoh_listen, keys, fleet)
        zen = _zenoh_listener(stack, session, fleet)
        if zen is None:
            raise _fail("leader goes over Zenoh: --zenoh none is not possible")
        result = cmds.run_leader(session, zen, fleet, drive, timeout)
    if json:
        typer.echo(jsonlib.dumps({"vehicle": vehicle, "id": did, "drive": what, "ok": result.ok,
                                  "details": result.details}))  # fmt: skip
    else:
        typer.echo(f"sent leader drive {did} to vehicle {vehicle}: {what}")
        typer.echo(f"vehicle {vehicle}: {'OK  ' if result.ok else 'FAIL'}  "
                   + "; ".join(result.details))  # fmt: skip
    if not result.ok:
        raise typer.Exit(EXIT_FAILED)


# --- record / replay / plot ----------------------------------------------------------------------------
@gcs_app.command("record")
def record(
    out: Annotated[Path, typer.Argument(help="Output MCAP file.")],
    fleet: FleetOpt = "alpha",
    mavlink: MavlinkOpt = None,
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Stop after this many seconds.")
    ] = None,
    keys: KeysOpt = None,
    sysid_offset: SysidOpt = 1,
) -> None:
    """Record every Zenoh sample of the fleet and every MAVLink message heard (MCAP)."""
    from groundstation.gcs.record import Recorder

    _check_fleet(fleet)
    if duration is not None and not (math.isfinite(duration) and duration > 0.0):
        raise _fail(f"--duration must be a finite number of seconds > 0, got {duration}")
    with ExitStack() as stack:
        stop = stack.enter_context(_sigterm_event())
        try:
            rec = Recorder(out, fleet)
        except OSError as exc:
            raise _fail(f"cannot write {out}: {exc.strerror}") from None
        stack.callback(rec.close)
        session = _open_zenoh(stack, zenoh, zenoh_listen, keys, fleet)
        zen = _zenoh_listener(stack, session, fleet)
        mav = _open_mavlink(stack, mavlink, keys, sysid_offset)
        if mav is not None:
            mav.hooks.append(rec.mavlink)
        if zen is not None:
            zen.sample_hooks.append(rec.zenoh_sample)
            zen.alive_hooks.append(rec.alive)
        typer.echo(f"recording fleet {fleet!r} to {out}; Ctrl-C to stop", err=True)
        _wait(stop, duration)
        if zen is not None:  # stop the hooks before the file is closed
            zen.close()
    counts = " ".join(f"{k}={v}" for k, v in sorted(rec.counts.items())) or "nothing"
    typer.echo(f"recorded {counts} to {out}", err=True)


@gcs_app.command("replay")
def replay(
    src: Annotated[Path, typer.Argument(help="MCAP file written by gcs record.")],
    speed: Annotated[
        float, typer.Option("--speed", help="Time scale (2: twice as fast; 0: no pacing).")
    ] = 1.0,
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    as_fleet: Annotated[
        str | None, typer.Option("--as-fleet", help="Republish under this fleet name.")
    ] = None,
    include_commands: Annotated[
        bool, typer.Option(help="Also republish fleet commands and lockstep steps (unsafe).")
    ] = False,
    wait_subscribers: Annotated[
        float, typer.Option("--wait-subscribers", help="Wait up to this long for a subscriber (s).")
    ] = 2.0,
) -> None:
    """Republish a recording's Zenoh samples and liveliness tokens, paced by its timestamps."""
    from groundstation.gcs.replay import replay as run_replay

    recording = _read_recording(src)
    if as_fleet is not None:
        _check_fleet(as_fleet)
    with ExitStack() as stack:
        stop = stack.enter_context(_sigterm_event())
        session = _open_zenoh(stack, zenoh, zenoh_listen)
        if session is None:
            raise _fail("replay publishes on Zenoh: --zenoh none is not possible")
        try:
            stats = run_replay(
                recording.records, session, speed, as_fleet, include_commands,
                wait_subscribers, stop,
            )  # fmt: skip
        except KeyboardInterrupt:
            return
    skipped = " ".join(f"{k}={v}" for k, v in sorted(stats.skipped.items())) or "nothing"
    typer.echo(f"replayed {stats.published} samples, {stats.tokens} tokens; skipped {skipped}")


@gcs_app.command("plot")
def plot(
    src: Annotated[Path, typer.Argument(help="MCAP file written by gcs record.")],
    out: Annotated[Path, typer.Option("--out", help="Directory for the PNG files.")],
    fleet: Annotated[
        str | None, typer.Option("--fleet", help="Fleet to plot (default: the recording's).")
    ] = None,
) -> None:
    """PNGs of scale error, SfM convergence, rigidity, bearing errors and trajectories."""
    from groundstation.gcs.analysis import load_series
    from groundstation.gcs.plot import plot_all

    recording = _read_recording(src)
    series = load_series(src, fleet, recording.records)
    if not series.vehicles:
        raise _fail(f"{src}: no vehicle data for fleet {series.fleet!r}", EXIT_FAILED)
    try:
        out.mkdir(parents=True, exist_ok=True)
        paths = plot_all(series, out)
    except OSError as exc:
        raise _fail(f"cannot write the plots to {out}: {exc.strerror or exc}") from None
    for path in paths:
        typer.echo(str(path))


@gcs_app.command("estimate")
def estimate(
    replay: Annotated[
        Path | None, typer.Option("--replay", help="Run on a gcs record MCAP file.")
    ] = None,
    json: Annotated[bool, typer.Option("--json", help="Print one JSON object.")] = False,
    bearing_noise_deg: Annotated[
        float, typer.Option(help="Bearing noise the filter assumes (deg, 1 sigma).")
    ] = 1.0,
    fleet: FleetOpt = "alpha",
    zenoh: ZenohOpt = None,
    zenoh_listen: ZenohListenOpt = None,
    keys: KeysOpt = None,
    duration: Annotated[
        float | None, typer.Option("--duration", help="Live: stop after this long (s).")
    ] = None,
    max_disagreement_m: Annotated[
        float,
        typer.Option(help="Live: alarm when the EKF and the daemons disagree by more (m)."),
    ] = 1.5,
    silent_s: Annotated[
        float, typer.Option(help="Live: drop a vehicle silent for this long (s).")
    ] = 3.0,
    plot: Annotated[
        Path | None,
        typer.Option("--plot", help="Replay: write the EKF's figures (PNG) into this directory."),
    ] = None,
) -> None:
    """Paper 001's centralized EKF on the team's bearings and odometry (issue 26). Live (over
    Zenoh): a table of its scale and each vehicle's pose beside the daemons' own estimates, an
    alarm when they disagree; --json prints the summary at the end. --replay FILE.mcap: final
    scale and, with truth in the recording, each vehicle's pose error (--plot DIR: distances,
    scale error and uncertainty over time)."""
    import math

    if not (math.isfinite(bearing_noise_deg) and bearing_noise_deg > 0):
        raise _fail("--bearing-noise-deg must be a positive number")
    if plot is not None and replay is None:
        raise _fail("--plot needs --replay FILE.mcap")
    if replay is None:
        _estimate_live(
            fleet, zenoh, zenoh_listen, keys, duration, json, bearing_noise_deg,
            max_disagreement_m, silent_s,
        )  # fmt: skip
        return
    from groundstation.gcs.ekf_replay import ReplayConfig, replay_estimate

    _check_recording(replay)
    result = replay_estimate(
        replay, ReplayConfig(bearing_sigma_rad=math.radians(bearing_noise_deg))
    )
    summary = result.summary()
    if plot is not None and result.state is not None:
        from groundstation.gcs.plot import plot_ekf_replay

        try:
            plot.mkdir(parents=True, exist_ok=True)
            summary["plots"] = [str(p) for p in plot_ekf_replay(result, plot)]
        except OSError as exc:
            raise _fail(f"cannot write the plots to {plot}: {exc.strerror or exc}") from None
    if json:
        typer.echo(jsonlib.dumps(summary))
    else:
        for k, v in summary.items():
            typer.echo(f"{k:>20}: {v}")
    if result.state is None:
        raise typer.Exit(EXIT_FAILED)


def _estimate_live(
    fleet: str,
    zenoh: list[str] | None,
    zenoh_listen: list[str] | None,
    keys: Path | None,
    duration: float | None,
    json: bool,
    bearing_noise_deg: float,
    max_disagreement_m: float,
    silent_s: float,
) -> None:
    """``gcs estimate`` without ``--replay`` (:mod:`groundstation.gcs.ekf_live`): until
    ``--duration``, Ctrl-C or SIGTERM; exit 1 if the filter never updated."""
    import math

    from groundstation.gcs.ekf_live import LiveEstimator, render
    from groundstation.gcs.ekf_loop import EkfLoop, EkfLoopConfig

    _check_fleet(fleet)
    for name, x in (("--max-disagreement-m", max_disagreement_m), ("--silent-s", silent_s)):
        if not (math.isfinite(x) and x > 0):
            raise _fail(f"{name} must be a positive number")
    if duration is not None and not (math.isfinite(duration) and duration > 0):
        raise _fail("--duration must be a positive number of seconds")
    if zenoh is not None and _off(zenoh):
        raise _fail("live estimation listens on Zenoh: --zenoh none is not possible")
    cfg = EkfLoopConfig(
        bearing_sigma_rad=math.radians(bearing_noise_deg),
        max_disagreement_m=max_disagreement_m,
        silent_s=silent_s,
    )
    loop = EkfLoop(cfg)
    live_view = sys.stdout.isatty() and not json
    from rich.console import Console

    console = Console(width=None if sys.stdout.isatty() else 160)
    err = Console(stderr=True, width=160)
    est: LiveEstimator | None = None
    with _sigterm_event() as stop, ExitStack() as stack:
        try:  # Ctrl-C (or SIGTERM) at any point ends the run with its summary
            session = _open_zenoh(stack, zenoh, zenoh_listen, keys, fleet)
            est = LiveEstimator(session, fleet, loop, on_event=lambda m: err.print(m, markup=False))
            est.start()
            stack.callback(est.close)
            err.print(f"estimating fleet {fleet!r}: listening on Zenoh", markup=False)
            t_end = None if duration is None else time.monotonic() + duration
            live = None
            if live_view:
                from rich.live import Live

                live = stack.enter_context(
                    Live(render(loop.summary(), fleet), console=console, auto_refresh=False)
                )
            next_draw = 0.0
            while not stop.is_set() and (t_end is None or time.monotonic() < t_end):
                est.pump(0.05)
                if live is not None and time.monotonic() >= next_draw:
                    live.update(render(loop.summary(), fleet), refresh=True)
                    next_draw = time.monotonic() + 0.25
        except KeyboardInterrupt:
            pass
    summary = loop.summary()
    summary["samples"] = est.received if est is not None else 0
    if json:
        typer.echo(jsonlib.dumps(summary))
    elif not live_view:
        console.print(render(summary, fleet))
    if loop.updates == 0:
        err.print("the filter never updated: no odometry and bearings from 2 vehicles heard")
        raise typer.Exit(EXIT_FAILED)
