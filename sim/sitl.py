"""Real ArduCopter SITL processes in place of the built-in autopilots.

ArduPilot's software-in-the-loop build (``./waf configure --board sitl && ./waf copter``) runs
the real flight code against its own multicopter physics. :class:`SitlFleet` starts one
``arducopter`` process per vehicle:

* the binary comes from ``--sitl PATH``, else ``$BEARINGFLOCK_SITL``, else ``arducopter`` on
  ``PATH`` (:func:`find_sitl`); its parameter defaults from ``--sitl-defaults``, else the files
  ArduPilot's ``Tools/autotest/default_params`` ships, looked up next to the binary;
* vehicle ``i`` is SITL instance ``I0 + i`` (``-I``; :func:`free_instances` picks ``I0`` so that
  every port is free) with MAVLink system id ``i + 1`` (``--sysid``), its home at its start
  position (one common origin, flat earth as the built-in simulator) and heading;
* SERIAL0 (TCP ``5760 + 10 I``) is the daemon's link, SERIAL1 (TCP ``5762 + 10 I``) the
  bridge's (:mod:`sim.sitl_bridge`), SERIAL2 sends to the ground-station UDP port;
* SERIAL1 is opened with ``wait``: an instance does not start its clock until the bridge
  connects, and the bridge connects to all of them at once, so their ``time_boot_ms`` differ
  only by what the rest of their boots takes (a few to 30 ms on a loaded 2-core machine;
  started one after the other they would differ by whole start-up times);
* working directories (``eeprom.bin``, logs, the process output) live in a temporary directory
  removed on :meth:`SitlFleet.close` (or in ``workdir``, kept), and every process is stopped
  (SIGTERM, then SIGKILL) when the fleet closes.

Sensors: ``"flow"`` (default: optical flow and a rangefinder, no GPS; the EKF has a position
about 4.5 s after boot) or ``"gps"`` (about 40 s). Either way ArduCopter refuses to arm for
about 24 s ("Arm: Accels inconsistent", then "Gyros inconsistent": its two simulated IMUs must
agree for 10 s each); ``params={"ARMING_CHECK": 786374}`` (the optical-flow file's checks
without INS, 16) arms as soon as the EKF is ready.

"""

from __future__ import annotations

import math
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sim.autopilot.state import Home

ENV_VAR = "BEARINGFLOCK_SITL"
"""Environment variable with the path of the ``arducopter`` SITL binary."""
BINARY_NAME = "arducopter"
SENSOR_DEFAULTS: dict[str, tuple[str, ...]] = {
    "flow": ("copter.parm", "copter-optflow.parm", "copter-nogps.parm"),
    "gps": ("copter.parm",),
}
"""Parameter files (ArduPilot's ``Tools/autotest/default_params``) of each sensor set."""
SITL_HOME = Home(lat_deg=-35.36, lon_deg=149.16, alt_amsl_m=584.0)
"""Common origin of the SITL vehicles' homes (ArduPilot's usual test site)."""
MAX_INSTANCE = 255
"""SITL keeps its instance ``-I`` in 8 bits: 256 is instance 0 again."""
STOP_TIMEOUT_S = 3.0


class SitlError(RuntimeError):
    """SITL cannot be started (no binary, no parameter files, a process died); one line."""


def find_sitl(explicit: str | os.PathLike[str] | None = None) -> Path:
    """The SITL binary: ``explicit``, else ``$BEARINGFLOCK_SITL``, else ``arducopter`` on PATH.
    Raises :class:`SitlError` with a one-line message when none is found or it is not an
    executable file."""
    where = "given"
    path: str | None = str(explicit) if explicit else None
    if path is None and os.environ.get(ENV_VAR):
        path, where = os.environ[ENV_VAR], f"in ${ENV_VAR}"
    if path is None:
        path, where = shutil.which(BINARY_NAME), "on PATH"
        if path is None:
            raise SitlError(
                f"no ArduCopter SITL binary: pass --sitl PATH, set ${ENV_VAR}, or put "
                f"{BINARY_NAME} on PATH (build it: ./waf configure --board sitl && ./waf copter)"
            )
    p = Path(path)
    if not (p.is_file() and os.access(p, os.X_OK)):
        raise SitlError(f"the ArduCopter SITL binary {where} is not an executable file: {p}")
    return p


def parse_params(items: Sequence[str]) -> dict[str, float]:
    """``["NAME=VALUE", ...]`` -> ``{NAME: VALUE}``; :class:`SitlError` for anything else."""
    out: dict[str, float] = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            number = float(value)
        except ValueError:
            number = math.nan
        if not sep or not name.strip() or not math.isfinite(number):
            raise SitlError(f"--sitl-param {item!r}: expected NAME=VALUE with a finite number")
        out[name.strip().upper()] = number
    return out


def default_param_files(binary: Path, sensors: str) -> tuple[Path, ...]:
    """The parameter files of ``sensors`` next to ``binary``; :class:`SitlError` if missing."""
    if sensors not in SENSOR_DEFAULTS:
        raise SitlError(f"unknown SITL sensors {sensors!r}: use one of {sorted(SENSOR_DEFAULTS)}")
    files = tuple(binary.parent / name for name in SENSOR_DEFAULTS[sensors])
    missing = [f.name for f in files if not f.is_file()]
    if missing:
        raise SitlError(
            f"no {', '.join(missing)} next to {binary}: pass --sitl-defaults FILE,... (ArduPilot's "
            "Tools/autotest/default_params)"
        )
    return files


@dataclass(frozen=True)
class SitlPorts:
    """The ports of SITL instance ``instance``."""

    instance: int

    @property
    def serial0(self) -> int:
        """TCP: the daemon's MAVLink link."""
        return 5760 + 10 * self.instance

    @property
    def serial1(self) -> int:
        """TCP: the bridge's MAVLink link (the clock starts when it connects)."""
        return 5762 + 10 * self.instance

    def bound(self) -> list[tuple[int, int]]:
        """(socket type, port) the instance binds: SERIAL0-2, RC input, IRLock."""
        i = 10 * self.instance
        tcp = [(socket.SOCK_STREAM, 5760 + i + k) for k in range(4)]
        return [*tcp, (socket.SOCK_DGRAM, 5501 + i), (socket.SOCK_DGRAM, 9005 + i)]


def _free(kind: int, port: int) -> bool:
    s = socket.socket(socket.AF_INET, kind)
    try:
        s.bind(("0.0.0.0", port))
        return True
    except OSError:
        return False
    finally:
        s.close()


def free_instances(n: int, seed: int | None = None, tries: int = 200) -> int:
    """The first of ``n`` consecutive SITL instance numbers whose ports are all free (random
    start, so parallel runs do not collide); :class:`SitlError` if none is found."""
    rng = np.random.default_rng(seed)
    for _ in range(tries):
        first = int(rng.integers(1, MAX_INSTANCE - n + 1))
        ports = [p for k in range(n) for p in SitlPorts(first + k).bound()]
        if all(_free(kind, port) for kind, port in ports):
            return first
    raise SitlError(f"no {n} consecutive free SITL instances below {MAX_INSTANCE}")


def home_of(origin: Home, p_ned: Sequence[float], yaw_rad: float) -> str:
    """SITL's ``--home LAT,LON,ALT,HEADING`` of a vehicle starting at ``p_ned`` (m from the
    origin, on the ground) facing ``yaw_rad``."""
    lat, lon, _ = origin.to_global(np.array([p_ned[0], p_ned[1], 0.0]))
    heading = math.degrees(yaw_rad) % 360.0
    return f"{lat:.9f},{lon:.9f},{origin.alt_amsl_m:.3f},{heading:.3f}"


@dataclass
class SitlFleet:
    """N ArduCopter SITL processes (module docstring). :meth:`start`, then :meth:`close`."""

    binary: Path
    param_files: tuple[Path, ...]
    p_start_ned: np.ndarray
    yaw_start_rad: np.ndarray
    first_instance: int
    speedup: float = 1.0
    gcs_port: int | None = None
    """SERIAL2 sends MAVLink to this UDP port on loopback (``None``: SERIAL2 stays TCP)."""
    origin: Home = SITL_HOME
    workdir: Path | None = None
    """Where the instances' working directories go (kept); ``None``: a temporary directory."""
    params: dict[str, float] = field(default_factory=dict)
    """Parameters set on top of ``param_files`` (written to a file loaded last)."""
    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)
    _tmp: Path | None = None
    _extra: Path | None = None

    @property
    def n(self) -> int:
        return len(self.p_start_ned)

    def ports(self, i: int) -> SitlPorts:
        return SitlPorts(self.first_instance + i)

    def daemon_url(self, i: int) -> str:
        """The pymavlink URL of vehicle ``i``'s SERIAL0."""
        return f"tcp:127.0.0.1:{self.ports(i).serial0}"

    def defaults(self) -> list[Path]:
        """The parameter files every instance loads, in order."""
        return [*self.param_files, *([self._extra] if self._extra is not None else [])]

    def command(self, i: int) -> list[str]:
        """The command line of vehicle ``i``'s process."""
        ports = self.ports(i)
        serial2 = f"udpclient:127.0.0.1:{self.gcs_port}" if self.gcs_port else "tcp:3"
        return [
            str(self.binary), "--model", "+", "--speedup", f"{self.speedup:g}",
            "--defaults", ",".join(str(f) for f in self.defaults()),
            "-I", str(ports.instance), "--sysid", str(i + 1),
            "--home", home_of(self.origin, self.p_start_ned[i], float(self.yaw_start_rad[i])),
            "-w", "--serial0", "tcp:0", "--serial1", "tcp:2:wait", "--serial2", serial2,
        ]  # fmt: skip

    def start(self, timeout_s: float = 20.0) -> None:
        """Start every process and wait until each listens on SERIAL1 (booting stops there
        until the bridge connects). Raises :class:`SitlError` with the log of one that died."""
        if self.workdir is None:
            self._tmp = Path(tempfile.mkdtemp(prefix="bearingflock-sitl-"))
            root = self._tmp
        else:
            root = self.workdir
            root.mkdir(parents=True, exist_ok=True)
        if self.params:
            self._extra = root / "extra.parm"
            self._extra.write_text("".join(f"{k} {v:g}\n" for k, v in self.params.items()))
        try:
            for i in range(self.n):
                cwd = root / f"vehicle{i}"
                cwd.mkdir(exist_ok=True)
                with open(cwd / "sitl.log", "wb") as log:
                    self.procs.append(
                        subprocess.Popen(
                            self.command(i),
                            cwd=cwd,
                            stdout=log,
                            stderr=subprocess.STDOUT,
                            stdin=subprocess.DEVNULL,
                            start_new_session=True,
                        )
                    )
            deadline = time.monotonic() + timeout_s
            for i in range(self.n):
                self._wait_listening(i, deadline, root)
        except BaseException:
            self.close()
            raise

    def _wait_listening(self, i: int, deadline: float, root: Path) -> None:
        port = self.ports(i).serial1
        while True:
            if self.procs[i].poll() is not None:
                raise SitlError(f"SITL vehicle {i} exited: {self.log_tail(i, root)}")
            if not _free(socket.SOCK_STREAM, port):  # bound: it listens
                return
            if time.monotonic() > deadline:
                raise SitlError(f"SITL vehicle {i} never listened on TCP {port}")
            time.sleep(0.02)

    def log_tail(self, i: int, root: Path | None = None, lines: int = 3) -> str:
        """The last lines of vehicle ``i``'s process output, on one line."""
        root = root or self.workdir or self._tmp
        try:
            text = (Path(root or ".") / f"vehicle{i}" / "sitl.log").read_text(errors="replace")
        except OSError:
            return "(no log)"
        return " | ".join(text.strip().splitlines()[-lines:])

    def dead(self) -> list[int]:
        """Vehicles whose process has exited."""
        return [i for i, p in enumerate(self.procs) if p.poll() is not None]

    def close(self) -> None:
        """Stop every process (SIGTERM, then SIGKILL after a few seconds) and remove the
        temporary directory. Idempotent."""
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for p in self.procs:
            try:
                p.wait(max(0.05, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
        self.procs = []
        if self._tmp is not None:
            shutil.rmtree(self._tmp, ignore_errors=True)
            self._tmp = None
