"""The options of the daemon's command line, as plain data (issue 27, onboard footprint).

One table, two command lines: ``bearingflock agent`` builds its typer command from it
(``groundstation/agent_cli.py``) and ``python -m onboard.daemon`` its :mod:`argparse` parser
(``onboard/daemon/entry.py``), so a vehicle's daemon does not import typer (about 3 MB
resident with click) to read its own options. ``tests/onboard/test_daemon_entry.py`` compares
the two parsers: names, required, repeatable, defaults, parsed values, ranges.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

REQUIRED: Any = ...
"""The default of an option that must be given (typer's and click's spelling: ``...``)."""


@dataclass(frozen=True)
class AgentOption:
    """One option of the ``agent`` command: the keyword ``name`` of
    :func:`onboard.daemon.cli.agent`, its flags, value type and default."""

    name: str
    kind: type
    """``int``, ``float``, ``str``, ``Path`` or ``bool`` (a flag: present or not)."""
    help: str
    default: Any = None
    """:data:`REQUIRED`, or the value when the option is not given."""
    decls: tuple[str, ...] = ()
    """The option's flags; ``--name-with-dashes`` when empty."""
    repeatable: bool = False
    """Given any number of times; the function receives the list (``()`` when none)."""
    low: float | None = None
    high: float | None = None
    """Inclusive range of the value (typer's ``min``/``max``)."""

    @property
    def flags(self) -> tuple[str, ...]:
        return self.decls or ("--" + self.name.replace("_", "-"),)

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def __post_init__(self) -> None:
        if self.kind is bool and (not self.decls or self.default is not False):
            raise ValueError(f"{self.name}: a flag needs its decls and the default False")


AGENT_HELP = "Run one vehicle's onboard daemon: autopilot link, bearings, Zenoh peers, agent core."

AGENT_OPTIONS: tuple[AgentOption, ...] = (
    AgentOption("agent_id", int, "This vehicle's agent id (0-based index).", REQUIRED, ("--id",)),
    AgentOption("config", Path, "Fleet file (TOML): docs/flying.md.", REQUIRED, ("--config",)),
    AgentOption("mavlink", str, "Autopilot URL (pymavlink style); default from the fleet file."),
    AgentOption("backend", str, "pymavlink or mavsdk."),
    AgentOption(
        "json_status",
        bool,
        "Print every status as a JSON line on stdout.",
        False,
        ("--json-status",),
    ),
    AgentOption("log_level", str, "debug, info, warning.", "info"),
    AgentOption(
        "bearings",
        str,
        "sim (the simulator's virtual camera) or camera (images through the camera "
        "pipeline); default from the fleet file.",
    ),
    AgentOption(
        "camera",
        Path,
        "Camera file, repeatable: camera_id = order (overrides camera.files).",
        repeatable=True,
    ),
    AgentOption("markers", Path, "Markers file (overrides camera.markers)."),
    AgentOption(
        "camera_device", str, "Local OpenCV capture (index, file or URL) instead of Zenoh images."
    ),
    AgentOption(
        "system_id",
        int,
        "MAVLink system id of this vehicle's autopilot; default: the fleet's "
        "mavlink.system_id_base + id. Heartbeats of other systems are ignored.",
        low=1,
        high=255,
    ),
    AgentOption(
        "clock_offset",
        float,
        "Fault injection: shift this daemon's clock by this many seconds, to rehearse "
        "a vehicle whose clock disagrees with the team's (its peers hold; never in flight).",
        0.0,
    ),
    AgentOption(
        "profile",
        bool,
        "Log on exit where the daemon's CPU went: core, rigidity, codec, Zenoh, "
        "MAVLink, loop (onboard/daemon/profile.py; also BEARINGFLOCK_AGENT_PROFILE=1).",
        False,
        ("--profile",),
    ),
)
"""The ``agent`` command's options, in the order of :func:`onboard.daemon.cli.agent`'s
parameters."""
