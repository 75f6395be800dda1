"""``bearingflock demo``: the README's main command (see :mod:`groundstation.demo`).

``--bearings camera`` flies it on bearings from pixels: :func:`write_camera_rig` writes a ring of
cameras and one coloured ball per vehicle, the simulator renders them and the agents run the
camera pipeline (docs/vision.md, "Flying on camera bearings").
"""

from __future__ import annotations

import json as jsonlib
import math
import os
import sys
import time
from enum import StrEnum
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.live import Live
from rich.markup import escape
from rich.table import Table


class DemoPhase(StrEnum):
    """The demo's own phases for the person watching (run_demo's ``on_tick`` says ``mission``
    or ``landing``; :class:`Progress` splits take-off off the mission)."""

    TAKEOFF = "take-off"
    MISSION = "mission"
    LANDING = "landing"


LANDING_ESTIMATE_S = 10.0
"""Simulation seconds a landing from the demo's 5-6.5 m takes (for the ETA)."""


class Progress:
    """Where the run is, for a person: the phase (take-off until every vehicle flies, mission,
    landing), wall-clock time since the start and an ETA from the simulation speed measured so
    far (simulation seconds per wall second)."""

    def __init__(self, duration_s: float, clock=time.monotonic) -> None:
        self.duration_s = duration_s
        self.clock = clock
        self.t0_wall = clock()
        self._first: tuple[float, float] | None = None  # (wall, sim elapsed) of the first tick
        self.rate: float | None = None
        self._landing_from: float | None = None

    def update(self, ev, elapsed_s: float, phase: str) -> tuple[str, float, float | None]:
        """``(phase label, wall seconds so far, ETA in wall seconds or None)``."""
        now = self.clock()
        if phase == DemoPhase.MISSION and not any(ev.series.flying):
            phase = DemoPhase.TAKEOFF.value
        if phase != DemoPhase.LANDING and elapsed_s > 0.0:
            if self._first is None:
                self._first = (now, elapsed_s)
            elif now - self._first[0] > 1.0:
                self.rate = (elapsed_s - self._first[1]) / (now - self._first[0])
        eta = None
        if self.rate is not None and self.rate > 0.0:
            if phase == DemoPhase.LANDING:
                if self._landing_from is None:
                    self._landing_from = now
                left = max(0.0, LANDING_ESTIMATE_S - (now - self._landing_from) * self.rate)
            else:
                left = max(0.0, self.duration_s - elapsed_s) + LANDING_ESTIMATE_S
            eta = left / self.rate
        return phase, now - self.t0_wall, eta


def progress_line(ev, elapsed_s: float, phase: str, duration_s: float, wall_s: float,
                  eta_s: float | None) -> str:  # fmt: skip
    """One line: phase, simulation time, wall time, ETA (and, landing, how many are down)."""
    from groundstation.demo import LANDED_HEIGHT_M

    eta = "ETA --" if eta_s is None else f"ETA {_clock(eta_s)}"
    if phase == DemoPhase.LANDING:
        down = sum(1 for tr in list(ev.truth.values()) if tr.p_ned[2] > -LANDED_HEIGHT_M)
        where = f"{down}/{ev.plan.n} on the ground"
    else:
        where = f"sim {elapsed_s:5.1f} / {duration_s:.0f} s"
    return f"bearingflock demo: {phase}, {where}, wall {_clock(wall_s)}, {eta}"


def _clock(s: float) -> str:
    m, sec = divmod(round(s), 60)
    return f"{m}:{sec:02d}"


def _table(ev, elapsed_s: float, phase: str, duration_s: float, title: str = "") -> Table:
    table = Table(
        title=title or f"bearingflock demo: {phase}, {elapsed_s:5.1f} / {duration_s:.0f} s"
    )
    for col in (
        "id",
        "phase",
        "autopilot",
        "alt m",
        "speed m/s",
        "d_hat m",
        "scale err %",
        "E",
        "lambda",
        "nbrs",
        "alarms",
    ):
        table.add_column(col, justify="right")
    status = ev.snapshot()
    errors = ev.series.scale_error[-1] if ev.series.scale_error else []
    err_by_agent: dict[int, float] = {}  # both ends of a pair, the worst of its pairs
    for (i, j), e in zip(ev.pairs, errors, strict=False):
        for k in (int(i), int(j)):
            if e == e:
                err_by_agent[k] = max(e, err_by_agent.get(k, 0.0))
    for agent_id in range(ev.plan.n):
        st = status.get(agent_id)
        if st is None:
            table.add_row(str(agent_id), "[dim]starting[/dim]", *[""] * 9)
            continue
        chis = st.agent.chi_hat_inv_m
        d_hat = ", ".join(f"{j}:{1 / c:.2f}" for j, c in sorted(chis.items()) if c > 0)
        err = err_by_agent.get(agent_id)
        err_txt = "" if err is None or err != err else f"{100 * err:.1f}"
        style = "red" if st.alarms else ""
        table.add_row(
            str(agent_id),
            st.phase,
            f"{st.autopilot_mode}{' armed' if st.armed else ''}",
            f"{st.altitude_m:.1f}",
            f"{st.speed_m_s:.2f}",
            d_hat,
            err_txt,
            f"{st.agent.e_index:.1e}",
            "" if (lam := st.agent.rigidity_eigenvalue) is None else f"{lam:.2f}",
            str(len(st.agent.neighbours)),
            ", ".join(st.alarms),
            style=style,
        )
    return table


BALL_COLOURS_HSV = ((0, "red"), (30, "yellow"), (60, "green"), (90, "cyan"), (120, "blue"),
                    (150, "magenta"))  # fmt: skip
"""Hues (OpenCV H 0-179) of the balls the vehicles carry: one identity per colour."""
HUE_HALF_WIDTH = 10
CAMERA_SPEEDUP = 0.5
"""Default simulation speed with camera bearings: rendering three vehicles at 10 frames per
simulation second (22 ms a 320x240 frame) needs about a third of one core at this speed."""
CAMERA_RENDER_RATE_HZ = 10.0
"""Frames per simulation second. 10 rather than 5 since rendering got 3x cheaper: 1% of the
frames skipped, and the scale error's wobble while the formation moves halves (docs/vision.md)."""
MIN_SPEEDUP = 0.2
"""Slowest simulation the demo accepts. The daemons scale their heartbeat timeout with the speed
(the simulator's heartbeats come once per *simulated* second); below 0.2 the other wall-clock
timers of the flight stack (command retries, the evaluator's guards) have not been tried."""
CPU_PER_AGENT = 0.2
CPU_SIMULATOR = 0.25
"""Cores one daemon, and the simulator with the demo's recorder and evaluator, use in real time.
A daemon with rigidity maintenance in the six-vehicle demo at 1x: 0.19 CPU s per simulated s
(``benchmarks/bench_footprint.py``, issue 27); the whole 1x demo took 1.5 cores of this 2-core
machine on average (74 s wall, 111 CPU s). It was 0.45 per daemon before the footprint work."""
CPU_BUDGET = 0.75
"""Fraction of the machine's idle cores the default speed plans to use. The six-vehicle demo at
1x on an idle 2-core machine (73% of it) passed with 0.12% scale error and no late ticks; 0.6
was set when daemons took 0.45 core and late core ticks made the constrained active case
drift. A machine that turns out slower than measured is named in the verdict (DEGRADED)."""


IDLE_SAMPLE_S = 0.5
"""Wall seconds over which the demo measures how much of the machine is idle."""


def _cpu_times() -> tuple[int, int] | None:
    """``(idle, total)`` jiffies of all CPUs (Linux ``/proc/stat``; ``None`` elsewhere)."""
    try:
        with open("/proc/stat") as f:
            fields = [int(x) for x in f.readline().split()[1:]]
    except (OSError, ValueError):
        return None
    if len(fields) < 4:
        return None
    return fields[3] + (fields[4] if len(fields) > 4 else 0), sum(fields[:8])


def idle_cores(cores: int, sample_s: float = IDLE_SAMPLE_S) -> float | None:
    """How many of ``cores`` were idle over the next ``sample_s`` (the machine's idle share of
    ``/proc/stat``); ``None`` where it cannot be measured."""
    first = _cpu_times()
    if first is None:
        return None
    time.sleep(sample_s)
    second = _cpu_times()
    if second is None or second[1] <= first[1]:
        return None
    return cores * max(0.0, min(1.0, (second[0] - first[0]) / (second[1] - first[1])))


def default_speedup(vehicles: int, cores: float) -> float:
    """The simulation speed at which ``vehicles`` daemons and the simulator fit ``CPU_BUDGET`` of
    ``cores`` (at most real time), rounded down to 0.05."""
    need = CPU_PER_AGENT * vehicles + CPU_SIMULATOR
    speed = min(1.0, CPU_BUDGET * cores / need)
    return max(MIN_SPEEDUP, math.floor(speed * 20.0 + 1e-9) / 20.0)


def write_camera_rig(
    out: Path,
    vehicles: int,
    cameras: int = 4,
    width: int = 320,
    height: int = 240,
    hfov_deg: float = 100.0,
    ball_m: float = 0.6,
) -> tuple[list[Path], Path]:
    """Camera files of a ring of ``cameras`` pinhole cameras (camera ``k`` looks ``360 k /
    cameras`` degrees right of the nose; ``hfov_deg`` a little over ``360 / cameras`` makes
    neighbours overlap, so a ball cut by one frame is whole in the next) and a markers file with
    one coloured ball per vehicle id ``0..vehicles-1``. Returns ``(camera files, markers file)``."""
    if not 1 <= vehicles <= len(BALL_COLOURS_HSV):
        raise ValueError(
            f"camera bearings: at most {len(BALL_COLOURS_HSV)} vehicles (ball colours)"
        )
    if cameras < 1 or not 0.0 < hfov_deg < 170.0:
        raise ValueError("a rig needs >= 1 camera and a field of view in (0, 170) degrees")
    out.mkdir(parents=True, exist_ok=True)
    f = 0.5 * width / math.tan(math.radians(hfov_deg) / 2.0)
    files = []
    for k in range(cameras):
        path = out / f"camera{k}.toml"
        path.write_text(
            f"# ring camera {k} of {cameras}: {hfov_deg:g} deg horizontal field of view\n"
            f"width = {width}\nheight = {height}\nfx = {f:.4f}\nfy = {f:.4f}\n"
            f"cx = {0.5 * width}\ncy = {0.5 * height}\ndist = [0.0, 0.0, 0.0, 0.0, 0.0]\n"
            f"mount_rpy_deg = [0.0, 0.0, {360.0 * k / cameras:g}]\n"
        )
        files.append(path)
    lines = ["# one coloured ball per vehicle, centred on its body origin (docs/vision.md)", ""]
    for vid in range(vehicles):
        hue, name = BALL_COLOURS_HSV[vid]
        lo, hi = (hue - HUE_HALF_WIDTH) % 180, (hue + HUE_HALF_WIDTH) % 180
        lines += [
            "[[marker]]",
            f"id = {vid}",
            f'kind = "disc"  # a {name} ball',
            f"size_m = {ball_m}",
            f"color_hsv_min = [{lo}, 120, 60]",
            f"color_hsv_max = [{hi}, 255, 255]",
            "",
        ]
    markers = out / "markers.toml"
    markers.write_text("\n".join(lines))
    return files, markers


def demo(
    vehicles: Annotated[int, typer.Option(help="Number of vehicles.")] = 6,
    flavour: Annotated[str, typer.Option(help="px4 or ardupilot.")] = "px4",
    duration: Annotated[
        float, typer.Option(help="Mission time before landing (simulation s).")
    ] = 60.0,
    out: Annotated[
        Path | None,
        typer.Option(
            help="Directory for logs, data, plots and the recording "
            "(default: ./bearingflock-demo-<time>; --headless: only summary.json, and only "
            "with --out)."
        ),
    ] = None,
    seed: Annotated[int, typer.Option(min=0, help="Seed of the formation and of all noise.")] = 0,
    mode: Annotated[str, typer.Option(help="Agent core mode.")] = "formation-active",
    json: Annotated[
        bool, typer.Option("--json", help="Print the summary as one JSON object.")
    ] = False,
    bearings: Annotated[
        str, typer.Option(help="sim (virtual camera) or camera (rendered images + pipeline).")
    ] = "sim",
    dynamics: Annotated[
        str,
        typer.Option(
            help="Built-in simulator: ideal (kinematic, exact telemetry) or realistic "
            "(multicopter dynamics and EKF-like telemetry fitted to ArduCopter SITL)."
        ),
    ] = "ideal",
    speedup: Annotated[
        float | None,
        typer.Option(
            help="Simulation speed (sim s per wall s); default: what this machine's cores run "
            "comfortably, at most 1 (0.5 with camera)."
        ),
    ] = None,
    cameras: Annotated[
        int, typer.Option(help="Camera bearings: 1 (forward) or a ring of 3 or more.")
    ] = 1,
    camera_fov: Annotated[
        float | None,
        typer.Option(
            help="Camera bearings: horizontal fov (deg; default: 110 forward, 360/N + 10 ring)."
        ),
    ] = None,
    camera_size: Annotated[
        str, typer.Option(help="Camera bearings: image size WIDTHxHEIGHT.")
    ] = "320x240",
    render_rate: Annotated[
        float, typer.Option(help="Camera bearings: frames per simulation second.")
    ] = CAMERA_RENDER_RATE_HZ,
    loss: Annotated[
        float,
        typer.Option(help="Fault injection: fraction of peer messages every daemon drops."),
    ] = 0.0,
    rigidity: Annotated[
        bool,
        typer.Option(
            help="Rigidity maintenance (paper 003): keep the sensing graph's weighted angle "
            "rigidity eigenvalue above its safe level, and avoid collisions (sim bearings only)."
        ),
    ] = True,
    autopilot: Annotated[
        str,
        typer.Option(
            help="builtin (the simulator's autopilots) or ardupilot-sitl (real ArduCopter SITL, "
            "one process per vehicle; binary from --sitl or $BEARINGFLOCK_SITL)."
        ),
    ] = "builtin",
    sitl: Annotated[
        Path | None, typer.Option(help="ardupilot-sitl: the arducopter SITL binary.")
    ] = None,
    sitl_sensors: Annotated[
        str, typer.Option(help="ardupilot-sitl: flow (optical flow, no GPS) or gps.")
    ] = "flow",
    sitl_param: Annotated[
        list[str] | None,
        typer.Option(help="ardupilot-sitl: NAME=VALUE parameter for every vehicle, repeatable."),
    ] = None,
    secure: Annotated[
        bool,
        typer.Option(
            "--secure",
            help="Signed MAVLink everywhere: fresh fleet keys in OUT/keys, the fleet file's "
            "security.dir, a simulator that rejects unsigned messages.",
        ),
    ] = False,
    localization: Annotated[
        str,
        typer.Option(
            help="The fleet file's core.localization: paper000 (paper 000's filter) or "
            "paper002 (paper 002's distributed gradient localization, docs/distributed.md).",
        ),
    ] = "paper000",
    headless: Annotated[
        bool,
        typer.Option(
            "--headless",
            help="Fly the same agent configurations in the headless runner instead "
            "(no processes, no sockets; 30 ms network latency): the reference for the real run.",
        ),
    ] = False,
) -> None:
    """Fly a whole simulated mission: simulator + one daemon per vehicle, live table, summary."""
    from groundstation.demo import run_demo
    from groundstation.demo_plots import plot_demo

    if vehicles < 3:
        typer.echo("error: --vehicles must be at least 3", err=True)
        raise typer.Exit(2)
    if not 0.0 <= loss < 1.0:
        typer.echo("error: --loss must be in [0, 1)", err=True)
        raise typer.Exit(2)
    if not (math.isfinite(duration) and duration > 0.0):
        typer.echo("error: --duration must be a positive number of seconds", err=True)
        raise typer.Exit(2)
    if flavour not in ("px4", "ardupilot"):
        typer.echo("error: --flavour must be px4 or ardupilot", err=True)
        raise typer.Exit(2)
    if autopilot not in ("builtin", "ardupilot-sitl"):
        typer.echo("error: --autopilot must be builtin or ardupilot-sitl", err=True)
        raise typer.Exit(2)
    if dynamics not in ("ideal", "realistic"):
        typer.echo("error: --dynamics must be ideal or realistic", err=True)
        raise typer.Exit(2)
    if autopilot == "ardupilot-sitl":
        from sim.sitl import SENSOR_DEFAULTS, SitlError, find_sitl

        if headless or bearings != "sim" or sitl_sensors not in SENSOR_DEFAULTS:
            typer.echo(
                "error: --autopilot ardupilot-sitl flies processes with the virtual camera "
                f"(not --headless, --bearings sim) and --sitl-sensors {'|'.join(SENSOR_DEFAULTS)}",
                err=True,
            )
            raise typer.Exit(2)
        try:
            find_sitl(sitl)
        except SitlError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
        flavour = "ardupilot"
    if bearings not in ("sim", "camera"):
        typer.echo("error: --bearings must be sim or camera", err=True)
        raise typer.Exit(2)
    if secure and (headless or autopilot != "builtin"):
        typer.echo(
            "error: --secure flies the simulated autopilots (not --headless or SITL)", err=True
        )
        raise typer.Exit(2)
    from messages.optional import require
    from messages.vocabulary import LOCALIZATIONS, MODES

    if localization not in LOCALIZATIONS:
        typer.echo(f"error: --localization must be one of {', '.join(LOCALIZATIONS)}", err=True)
        raise typer.Exit(2)

    # the plots, the recording and the camera pipeline: a missing extra says so before the run
    for module in ("matplotlib", "mcap", *(("cv2",) if bearings == "camera" else ())):
        require(module)

    if mode not in MODES:
        typer.echo(f"error: --mode must be one of {', '.join(MODES)}", err=True)
        raise typer.Exit(2)
    if headless:  # writes summary.json into --out when given (it used to write nothing)
        out_dir = _writable_out(out) if out is not None else None
        _headless(vehicles, seed, duration, mode, loss, json, rigidity, out_dir, localization)
        return
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    cores = cores or 1
    idle = idle_cores(cores) if speedup is None else None  # a short measurement of the machine
    auto = default_speedup(vehicles, cores if idle is None else max(idle, 0.5))
    if bearings == "camera":
        auto = min(auto, CAMERA_SPEEDUP)
    speed = speedup if speedup is not None else auto
    if not speed >= MIN_SPEEDUP:
        typer.echo(f"error: --speedup must be >= {MIN_SPEEDUP:g}", err=True)
        raise typer.Exit(2)
    if speedup is None and not json:
        idle_txt = "" if idle is None else f", {idle:.1f} of them idle just now"
        Console(stderr=True).print(
            f"[dim]simulation at {speed:g}x real time: {vehicles} daemons and the simulator need "
            f"about {CPU_PER_AGENT * vehicles + CPU_SIMULATOR:.1f} cores at 1x, this machine has "
            f"{cores}{idle_txt} (--speedup to choose; the verdict says DEGRADED if ticks ran "
            "late)[/dim]"
        )
    if not render_rate > 0.0:
        typer.echo("error: --render-rate must be > 0", err=True)
        raise typer.Exit(2)
    out_dir = _writable_out(out or default_out_dir())
    camera_files: list[Path] = []
    markers_file = None
    if bearings == "camera":
        try:
            width, height = (int(x) for x in camera_size.lower().split("x"))
            if cameras == 2:
                raise ValueError("--cameras: 1 (forward) or a ring of 3 or more")
            hfov = camera_fov or (110.0 if cameras == 1 else 360.0 / cameras + 10.0)
            camera_files, markers_file = write_camera_rig(
                out_dir / "rig", vehicles, cameras, width, height, hfov_deg=hfov
            )
        except ValueError as exc:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(2) from None
    console = Console(stderr=json)
    live_view = console.is_terminal and not json
    last_print = [-10.0]
    progress = Progress(duration)

    def on_tick(ev, elapsed_s: float, phase: str) -> None:
        label, wall_s, eta_s = progress.update(ev, elapsed_s, phase)
        line = progress_line(ev, elapsed_s, label, duration, wall_s, eta_s)
        if live_view:
            live.update(_table(ev, elapsed_s, label, duration, title=line))
        elif wall_s - last_print[0] >= 5.0:  # no terminal: one line every 5 s, not a table
            last_print[0] = wall_s
            console.print(line, soft_wrap=True)

    try:
        with (
            Live(console=console, refresh_per_second=4, transient=False)
            if live_view
            else _Null() as live
        ):
            summary = run_demo(
                vehicles, flavour, duration, out_dir, seed, mode, on_tick, bearings=bearings,
                camera_files=camera_files, markers_file=markers_file, speedup=speed,
                render_rate_hz=render_rate, loss=loss, rigidity=rigidity, autopilot=autopilot,
                sitl=sitl, sitl_sensors=sitl_sensors, sitl_params=tuple(sitl_param or ()),
                dynamics=dynamics,
                secure=secure, localization=localization,
            )  # fmt: skip
    except KeyboardInterrupt:
        console.print("[yellow]interrupted: every process was stopped[/yellow]")
        raise typer.Exit(130) from None
    except RuntimeError as exc:
        console.print(f"[red]error:[/red] {escape(str(exc))}")
        raise typer.Exit(1) from None
    summary["bearings"] = bearings
    summary["autopilot"] = autopilot
    summary["speedup"] = speed
    summary["out"] = str(out_dir)
    summary["plots"] = [str(p) for p in plot_demo(out_dir)]
    _finish(summary, json, console, out_dir)


def _writable_out(out_dir: Path) -> Path:
    """``out_dir``, created; exit 2 with one line if it cannot be written."""
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / ".write-test").touch()
        (out_dir / ".write-test").unlink()
    except OSError as exc:
        typer.echo(f"error: --out {out_dir}: cannot write there ({exc.strerror})", err=True)
        raise typer.Exit(2) from None
    return out_dir


def default_out_dir(now: float | None = None) -> Path:
    """``./bearingflock-demo-<local time>``: where a demo without ``--out`` writes its files."""
    return Path(f"bearingflock-demo-{time.strftime('%Y%m%d-%H%M%S', time.localtime(now))}")


def _finish(summary: dict, json: bool, console: Console, out_dir: Path | None) -> None:
    """Add the verdict, write ``summary.json`` (with an output directory), print the summary
    (``--json``: one JSON object on stdout) and end with the verdict line; exit 1 on FAIL."""
    from groundstation.demo_verdict import demo_verdict

    verdict = demo_verdict(summary, str(out_dir) if out_dir is not None else None)
    summary["verdict"] = verdict.as_json()
    if out_dir is not None:
        (out_dir / "summary.json").write_text(jsonlib.dumps(summary, indent=1) + "\n")
    if json:
        sys.stdout.write(jsonlib.dumps(summary) + "\n")
    else:
        for name in ("plots", "recording"):
            value = summary.get(name)
            if value:
                shown = ", ".join(value) if isinstance(value, list) else value
                console.print(f"{name}: {escape(shown)}")
        if out_dir is not None:
            console.print(f"summary: {escape(str(out_dir / 'summary.json'))}")
        colour = "green" if verdict.passed else "red"
        console.print(f"[bold {colour}]{escape(verdict.line)}[/bold {colour}]", soft_wrap=True)
    if not verdict.passed:
        raise typer.Exit(1)


def _headless(
    vehicles: int,
    seed: int,
    duration: float,
    mode: str,
    loss: float,
    json: bool,
    rigidity: bool,
    out_dir: Path | None = None,
    localization: str = "paper000",
):
    from rich.progress import Progress

    from groundstation.demo_headless import headless_demo

    console = Console(stderr=True)
    with Progress(console=console, transient=True) as bar:
        task = bar.add_task(f"headless mission, {vehicles} vehicles, {duration:.0f} s", total=1.0)
        summary, _ = headless_demo(
            vehicles, seed, duration, mode=mode, loss=loss, rigidity=rigidity,
            progress=lambda f: bar.update(task, completed=f), localization=localization,
        )  # fmt: skip
    summary["headless"] = True
    if out_dir is not None:
        summary["out"] = str(out_dir)
    _finish(summary, json, Console(), out_dir)


class _Null:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *exc: object) -> None:
        return None
