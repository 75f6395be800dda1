"""``bearingflock sim``: run N simulated autopilots that real MAVLink clients can fly.

Prints where each vehicle listens, then a live one-line status; Ctrl-C (or SIGTERM) stops it
cleanly. Zenoh is imported only when ``--zenoh`` is given. Also runnable as
``python -m sim.cli``.
"""

from __future__ import annotations

import signal
import sys
import threading
from pathlib import Path
from typing import Annotated, Any

import typer


def sim(
    vehicles: Annotated[int, typer.Option("--vehicles", "-n", help="Number of vehicles.")] = 3,
    flavour: Annotated[str, typer.Option(help="Autopilot flavour: px4 or ardupilot.")] = "px4",
    layout: Annotated[
        str, typer.Option(help="grid, random, or a formation file (vehicles start on the ground).")
    ] = "grid",
    spacing: Annotated[float, typer.Option(help="Grid spacing (m).")] = 5.0,
    seed: Annotated[
        int, typer.Option(min=0, help="Seed of the random layout and of all noise.")
    ] = 0,
    speedup: Annotated[float, typer.Option(help="Simulation time per wall second.")] = 1.0,
    dynamics: Annotated[
        str,
        typer.Option(
            help="ideal: the kinematic first-order lag, exact telemetry (paper reproductions); "
            "realistic: tilt-to-accelerate, delay, overshoot, hover wander, EKF-like velocity "
            "noise and bias, unsynchronized cameras, fitted to ArduCopter SITL (docs/sim.md)."
        ),
    ] = "ideal",
    lockstep: Annotated[
        bool, typer.Option(help="Advance only on SimStep messages (needs --zenoh).")
    ] = False,
    strict: Annotated[bool, typer.Option(help="Behave like an autopilot fresh from boot.")] = False,
    warmup: Annotated[float, typer.Option(help="Strict mode: estimator warm-up (s).")] = 5.0,
    ekf_warmup: Annotated[
        float,
        typer.Option(
            help="ArduPilot: seconds after boot until the EKF has a position (LOCAL_POSITION_NED "
            "streams, arming is allowed). ArduCopter SITL: about 40 with GPS, 4.5 with optical "
            "flow."
        ),
    ] = 4.0,
    boot_streams: Annotated[
        bool,
        typer.Option(
            help="ArduPilot: stream telemetry from boot, for clients that never ask (a real "
            "ArduCopter streams nothing until asked)."
        ),
    ] = False,
    signing_key: Annotated[
        Path | None, typer.Option(help="MAVLink 2 signing key file (hex, raw or passphrase).")
    ] = None,
    keys: Annotated[
        Path | None,
        typer.Option(
            "--keys",
            help="Fleet key directory (bearingflock keys init): vehicle i signs and checks with "
            "mavlink-vehicle-<i>.key, as its autopilot would, and Zenoh runs over mutual TLS "
            "(sim.crt, tcp/ endpoints become tls/).",
        ),
    ] = None,
    zenoh: Annotated[
        str | None,
        typer.Option(
            help="Zenoh endpoint to listen on (e.g. tcp/127.0.0.1:7447): camera, truth, clock."
        ),
    ] = None,
    zenoh_connect: Annotated[
        list[str] | None, typer.Option(help="Zenoh endpoints to connect to (repeatable).")
    ] = None,
    fleet: Annotated[str, typer.Option(help="Fleet name in Zenoh keys.")] = "alpha",
    port_base: Annotated[
        int, typer.Option(help="UDP: vehicle i sends to port-base + i (PX4: 14540).")
    ] = 14540,
    gcs_port: Annotated[
        int, typer.Option(help="UDP: every vehicle also sends here (0: off).")
    ] = 14550,
    bind_base: Annotated[
        int | None,
        typer.Option(
            help="UDP: vehicle i binds port bind-base + i (default: port-base + 40; 0: the "
            "kernel picks free ports, printed at start)."
        ),
    ] = None,
    tcp_base: Annotated[
        int, typer.Option(help="TCP: vehicle i listens on tcp-base + 10 i.")
    ] = 5760,
    transport: Annotated[
        str | None, typer.Option(help="udp or tcp (default: udp for px4, tcp for ardupilot).")
    ] = None,
    camera_fov: Annotated[float, typer.Option(help="Camera field of view (deg, cone).")] = 90.0,
    camera_range: Annotated[float, typer.Option(help="Camera range (m).")] = 25.0,
    camera_rate: Annotated[float, typer.Option(help="Camera rate (Hz).")] = 30.0,
    camera_noise: Annotated[float, typer.Option(help="Bearing noise std (rad).")] = 0.0,
    camera_dropout: Annotated[float, typer.Option(help="Probability of a missed detection.")] = 0.0,
    render_camera: Annotated[
        list[Path] | None,
        typer.Option(
            help="Render images with this camera file (repeatable: a rig, camera_id = order); "
            "needs --markers and --zenoh."
        ),
    ] = None,
    markers: Annotated[
        Path | None, typer.Option(help="Markers file: what each vehicle carries (rendering).")
    ] = None,
    render_rate: Annotated[float, typer.Option(help="Rendered frames per sim second.")] = 10.0,
    render_blur: Annotated[float, typer.Option(help="Gaussian blur sigma (px).")] = 0.5,
    render_noise: Annotated[float, typer.Option(help="Pixel noise std (grey levels).")] = 1.0,
    render_encoding: Annotated[str, typer.Option(help="jpeg or png.")] = "jpeg",
    render_quality: Annotated[int, typer.Option(help="JPEG quality (1-100).")] = 90,
    quiet: Annotated[bool, typer.Option(help="No live status line.")] = False,
    autopilot: Annotated[
        str,
        typer.Option(
            help="builtin (the simulated autopilots) or ardupilot-sitl (one real ArduCopter "
            "SITL process per vehicle; docs/sim.md)."
        ),
    ] = "builtin",
    sitl: Annotated[
        Path | None,
        typer.Option(help="ardupilot-sitl: the arducopter binary (default $BEARINGFLOCK_SITL)."),
    ] = None,
    sitl_sensors: Annotated[
        str, typer.Option(help="ardupilot-sitl: flow (optical flow, no GPS) or gps.")
    ] = "flow",
    sitl_defaults: Annotated[
        str | None,
        typer.Option(
            help="ardupilot-sitl: parameter files, comma-separated (default: the sensors' files "
            "next to the binary)."
        ),
    ] = None,
    sitl_instance: Annotated[
        int | None,
        typer.Option(
            min=0, help="ardupilot-sitl: instance of vehicle 0 (-I; default: the first free)."
        ),
    ] = None,
    sitl_dir: Annotated[
        Path | None,
        typer.Option(help="ardupilot-sitl: keep the instances' working directories here."),
    ] = None,
    sitl_stamps: Annotated[
        str,
        typer.Option(
            help="ardupilot-sitl: stamp camera frames and truth on each instance's own clock "
            "(own) or on the fleet's (common)."
        ),
    ] = "own",
    sitl_param: Annotated[
        list[str] | None,
        typer.Option(
            help="ardupilot-sitl: NAME=VALUE set on every instance, repeatable (e.g. "
            "ARMING_CHECK=786374 arms without waiting for SITL's IMUs to agree, ~20 s)."
        ),
    ] = None,
) -> None:
    """Run a multi-vehicle kinematic MAVLink simulator (PX4 or ArduPilot flavour), or real
    ArduCopter SITL with the same camera, truth and clock (``--autopilot ardupilot-sitl``)."""
    # heavy imports here, so that ``bearingflock --help`` stays instant
    from messages.fatal import FatalThreads
    from sim.autopilot.signing import load_key
    from sim.camera import CameraConfig, CameraPublisher
    from sim.clock import ClockPublisher
    from sim.dynamics import RealisticConfig
    from sim.server import SimConfig, SimServer
    from sim.world import SensorNoise, formation_layout, grid_layout, random_layout

    if lockstep and zenoh is None and not zenoh_connect:
        raise typer.BadParameter("--lockstep needs --zenoh (steps arrive as SimStep messages)")
    if render_camera and (markers is None or (zenoh is None and not zenoh_connect)):
        raise typer.BadParameter("--render-camera needs --markers and --zenoh (images go to Zenoh)")
    if render_encoding not in ("jpeg", "png"):
        raise typer.BadParameter("--render-encoding must be jpeg or png")
    if dynamics not in ("ideal", "realistic"):
        raise typer.BadParameter("--dynamics must be ideal or realistic")
    if autopilot not in ("builtin", "ardupilot-sitl"):
        raise typer.BadParameter("--autopilot must be builtin or ardupilot-sitl")
    if sitl_stamps not in ("own", "common"):
        raise typer.BadParameter("--sitl-stamps must be own or common")
    try:
        ids: list[int] | None = None
        if layout == "grid":
            p, yaw = grid_layout(vehicles, spacing)
        elif layout == "random":
            p, yaw = random_layout(vehicles, (spacing * vehicles, spacing * vehicles), seed=seed)
        else:
            p, yaw, ids = formation_layout(layout)
            p[:, 2] = 0.0
    except (ValueError, OSError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None
    if autopilot == "ardupilot-sitl":
        unsupported = [
            name
            for name, given in (
                ("--lockstep", lockstep), ("--strict", strict), ("--signing-key", signing_key),
                ("--keys", keys), ("--render-camera", render_camera),
            )
            if given
        ]  # fmt: skip
        if unsupported:
            raise typer.BadParameter(
                f"{', '.join(unsupported)}: not available with --autopilot ardupilot-sitl"
            )
        from sim.camera import CameraConfig
        from sim.sitl_run import SitlOptions, run_sitl

        try:
            camera_cfg = CameraConfig(
                camera_fov, camera_range, camera_noise, camera_dropout, camera_rate, seed
            )
        except ValueError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        options = SitlOptions(
            binary=sitl, sensors=sitl_sensors, defaults=sitl_defaults, instance=sitl_instance,
            workdir=sitl_dir, speedup=speedup, gcs_port=gcs_port or None, stamps=sitl_stamps,
            params=tuple(sitl_param or ()),
        )  # fmt: skip
        code = run_sitl(p, yaw, ids, options, camera_cfg, zenoh, zenoh_connect or [], fleet, quiet)
        raise typer.Exit(code)
    if keys is not None and signing_key is not None:
        raise typer.BadParameter("--keys and --signing-key: give one")
    try:
        key = load_key(signing_key) if signing_key is not None else None
        per_vehicle = None
        if keys is not None:
            from messages.fleetkeys import KeyStoreError, load_signing_key

            try:
                agent_ids = ids if ids is not None else list(range(len(p)))
                per_vehicle = [load_signing_key(keys, int(a)) for a in agent_ids]
            except KeyStoreError as exc:
                raise ValueError(str(exc)) from None
        config = SimConfig(
            p,
            yaw,
            flavour=flavour,
            transport=transport,
            client_base=port_base,
            gcs_port=gcs_port or None,
            bind_base=bind_base,
            tcp_base=tcp_base,
            speedup=speedup,
            lockstep=lockstep,
            strict=strict,
            warmup_s=warmup,
            ekf_warmup_s=ekf_warmup,
            boot_streams=boot_streams,
            signing_key=key,
            signing_keys=per_vehicle,
            noise=SensorNoise(seed=seed),
            realistic=RealisticConfig(seed=seed) if dynamics == "realistic" else None,
        )
        camera = CameraConfig(
            camera_fov, camera_range, camera_noise, camera_dropout, camera_rate, seed,
            unsynchronized=dynamics == "realistic",
        )  # fmt: skip
        rig = _render_rig(render_camera, markers, render_rate, render_blur, render_noise,
                          render_encoding, render_quality, seed)  # fmt: skip
        server = SimServer(config)
    except (ValueError, OSError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(2) from None

    session = None
    images: Any = None
    subscribers: list[Any] = []  # keep Zenoh subscribers alive
    if zenoh is not None or zenoh_connect:
        from messages.transport import (
            ZenohSettings,
            open_session,
            publisher_put,
            with_mutual_tls,
        )

        zsettings = ZenohSettings(listen=[zenoh] if zenoh else [], connect=zenoh_connect or [])
        if keys is not None:  # the fleet's identity: Zenoh over mutual TLS as <fleet>-sim
            from messages.fleetkeys import SIM_NAME, KeyStoreError, identity_files, identity_fleet
            from messages.zenoh_acl import fleet_access_control

            try:
                zsettings = with_mutual_tls(
                    zsettings,
                    *identity_files(keys, SIM_NAME),
                    access_control=fleet_access_control(
                        fleet,
                        len(p) if ids is None else max(int(a) for a in ids) + 1,
                        identity_fleet(keys),
                    ),
                )
            except (ValueError, KeyStoreError) as exc:
                typer.echo(f"error: {exc}", err=True)
                raise typer.Exit(2) from None
        try:
            session = open_session(zsettings)
        except ValueError as exc:  # TransportError: a port in use, a bad endpoint
            server.close()
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        put = publisher_put(session)
        server.hooks.append(CameraPublisher(camera, fleet, put, ids=ids))
        server.hooks.append(ClockPublisher(fleet, put, server.clock, config.dt_s))
        if rig is not None:
            from sim.image_publisher import ImagePublisher

            cameras, specs, render = rig
            images = ImagePublisher(
                cameras, specs, render, fleet, publisher_put(session), ids=ids,
                wind_ned=config.noise.wind_ned_m_s,
            )  # fmt: skip
            server.hooks.append(images)
        if lockstep:
            subscribers.append(_subscribe_steps(session, fleet, server))

    # SIGINT and SIGTERM both stop the simulator, through handlers of our own: a process
    # started in the background by a non-interactive shell inherits SIGINT *ignored*, and
    # Python then never raises KeyboardInterrupt, so Ctrl-C or `kill -INT` did nothing.
    # Installed before the ready line: a signal sent as soon as it appears must stop us cleanly.
    stop = threading.Event()
    # any other thread that dies (a renderer) stops the simulator too (messages/fatal.py)
    fatal = FatalThreads(on_fatal=lambda _text: stop.set()).install()
    stop_signals = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in stop_signals}
    for line in server.endpoints():
        typer.echo(line)
    if session is not None:
        typer.echo(f"zenoh: fleet {fleet!r}, listening on {zenoh}, connecting to {zenoh_connect}")
    if images is not None:
        typer.echo(
            f"rendering {len(images.renderers)} camera(s) per vehicle at {render_rate} Hz "
            f"(sim time) on {fleet!r}/<id>/camera/image"
        )
    typer.echo(
        f"{server.world.n} {flavour} vehicles, speedup {speedup}, "
        f"{'lockstep' if lockstep else 'real time'}{', strict' if strict else ''}"
        f"{', signed' if key or per_vehicle else ''}; Ctrl-C to stop"
    )
    sys.stdout.flush()

    server.start()
    try:
        while not stop.wait(0.5) and server.failure is None:
            if not quiet:
                end = "\r" if sys.stdout.isatty() else "\n"
                extra = f"  {images.status()}" if images is not None else ""
                sys.stdout.write(server.status() + extra + end)
                sys.stdout.flush()
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        server.stop()
        if images is not None:
            images.close()
            typer.echo(f"\n{images.status()}")
        if session is not None:
            session.close()
        counters = " ".join(f"{k}={v}" for k, v in server.counters().items() if v)
        typer.echo(f"\nstopped at t={server.world.t_s:.2f}s; {counters}")
        fatal.uninstall()
    if server.failure is not None:  # never a live-looking process with a dead loop (issue 23)
        typer.echo(f"error: {server.failure_text()}", err=True)
        raise typer.Exit(1)
    if fatal.message:
        typer.echo(f"error: {fatal.message}", err=True)
        raise typer.Exit(1)


def _render_rig(
    files: list[Path] | None,
    markers: Path | None,
    rate_hz: float,
    blur_px: float,
    noise: float,
    encoding: str,
    quality: int,
    seed: int,
) -> tuple[list[Any], list[Any], Any] | None:
    """``(cameras, marker specs, RenderConfig)`` of ``--render-camera``, or ``None``; raises
    ``ValueError`` (a :class:`VisionConfigError`) for a bad file or option."""
    if not files:
        return None
    from onboard.vision.config import load_camera, load_markers
    from sim.image_publisher import RenderConfig

    assert markers is not None
    render = RenderConfig(rate_hz, blur_px, noise, encoding, quality, seed)  # type: ignore[arg-type]
    return [load_camera(f) for f in files], load_markers(markers), render


def _subscribe_steps(session: Any, fleet: str, server: Any) -> Any:
    """Advance a lockstep server on every valid SimStep; malformed ones are counted."""
    from messages.codec import MessageError, decode
    from messages.sim import SimStep, step_key

    def on_sample(sample: Any) -> None:
        try:
            msg = decode(sample.payload.to_bytes(), SimStep)
        except MessageError:
            server.autopilots[0].counters.malformed += 1
            return
        server.advance_to(msg.until_s, wait=False)

    return session.declare_subscriber(step_key(fleet), on_sample)


def main() -> None:
    typer.run(sim)


if __name__ == "__main__":
    main()
