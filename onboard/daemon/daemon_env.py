"""The daemon's process environment, set before its imports (issue 27: onboard footprint).

Two things are decided by environment variables that libraries read once, when they are
first imported, so the daemon's entry point (``groundstation/cli.py``) sets them before
anything imports numpy or pymavlink. Only the ``agent`` subcommand is affected; the
simulator, planner, studies and ground-station tools keep the libraries' defaults. A variable
the user set always wins.

* **One BLAS thread.** numpy's OpenBLAS starts a pool of one thread per core when it is
  loaded and may hand a product to it; a daemon's matrices are 3x3 to 30x30, where the pool
  only adds threads, their buffers and wake-ups (:data:`BLAS_THREAD_VARIABLES`).
* **One MAVLink dialect.** ``pymavlink.mavutil`` loads the MAVLink 1 ``all`` dialect at import
  (for PyInstaller, whether used or not) and its default dialect is ``all``, so a daemon held
  the MAVLink 1 and (after the upgrade on the first MAVLink 2 packet) MAVLink 2 ``all``
  modules: 18.5 MB of pymavlink and the link module, against 13.9 MB with MAVLink 2
  ``ardupilotmega`` alone (which includes ``common``: every message PX4, ArduPilot and the
  simulator send a daemon; ``tests/onboard/test_daemon_env.py`` measures both). The daemon
  asks for :data:`MAVLINK_VARIABLES` and, unless the user chose MAVLink 1 ``all``, blocks
  the one unused import (:func:`block_unused_imports`; ``mavutil`` imports it inside ``try``),
  and ``curses``, which ``mavutil`` also tries (:data:`CURSES`).

No numpy or pymavlink here: this module must be importable before either is.
"""

from __future__ import annotations

from collections.abc import Mapping, MutableMapping, Sequence
from typing import Any

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS")
"""Read when OpenBLAS (numpy's BLAS) and an OpenMP runtime are loaded, never afterwards."""

MAVLINK_VARIABLES = {"MAVLINK20": "1", "MAVLINK_DIALECT": "ardupilotmega"}
"""Read by ``pymavlink.mavutil`` at import: MAVLink 2 from the first packet (signing needs
it; every supported autopilot speaks it), and the dialect the daemon parses with."""

PYINSTALLER_DIALECT = "pymavlink.dialects.v10.all"
"""The module ``mavutil`` imports for PyInstaller's sake and the daemon never uses."""

CURSES = "curses"
"""Imported by ``pymavlink.mavutil`` inside ``try`` for ``is_printable``, whose fallback without
it is the same test (ASCII 32-126); 0.55 MB resident with ``_curses`` and libtinfo. Nothing
else a daemon runs uses a terminal library."""

DAEMON_SUBCOMMAND = "agent"


def daemon_env_defaults(args: Sequence[str], environ: Mapping[str, str]) -> dict[str, str]:
    """The variables to add to ``environ`` for a command line ``args`` (``sys.argv[1:]``):
    for the ``agent`` subcommand, one thread for each of :data:`BLAS_THREAD_VARIABLES` and
    :data:`MAVLINK_VARIABLES`, each only if the user left it unset; nothing otherwise."""
    if not args or args[0] != DAEMON_SUBCOMMAND:
        return {}
    wanted = {**dict.fromkeys(BLAS_THREAD_VARIABLES, "1"), **MAVLINK_VARIABLES}
    return {name: value for name, value in wanted.items() if name not in environ}


def blocked_imports(environ: Mapping[str, str]) -> tuple[str, ...]:
    """Modules the daemon need not load: :data:`CURSES`, and :data:`PYINSTALLER_DIALECT` unless
    ``environ`` (the daemon's, with :func:`daemon_env_defaults` applied) makes that very module
    the dialect: MAVLink 1 (no ``MAVLINK20``) and ``MAVLINK_DIALECT`` unset or ``all``."""
    if environ.get("MAVLINK_DIALECT", "all") == "all" and "MAVLINK20" not in environ:
        return (CURSES,)
    return (PYINSTALLER_DIALECT, CURSES)


def block_unused_imports(environ: Mapping[str, str], modules: MutableMapping[str, Any]) -> None:
    """Set each of :func:`blocked_imports` to ``None`` in ``modules`` (``sys.modules``), which
    makes importing it raise ``ImportError``; the ``agent`` command calls it first thing."""
    for name in blocked_imports(environ):
        modules.setdefault(name, None)
