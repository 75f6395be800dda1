"""One BLAS thread and one MAVLink dialect for the daemon unless the user says otherwise (issue 27)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from onboard.daemon.daemon_env import (
    BLAS_THREAD_VARIABLES,
    CURSES,
    MAVLINK_VARIABLES,
    PYINSTALLER_DIALECT,
    blocked_imports,
    daemon_env_defaults,
)

ROOT = Path(__file__).resolve().parents[2]


def test_agent_gets_one_thread_and_one_dialect_for_each_unset_variable() -> None:
    assert daemon_env_defaults(["agent", "--id", "0"], {}) == {
        **dict.fromkeys(BLAS_THREAD_VARIABLES, "1"),
        "MAVLINK20": "1",
        "MAVLINK_DIALECT": "ardupilotmega",
    }


def test_user_setting_wins() -> None:
    out = daemon_env_defaults(["agent"], {"OPENBLAS_NUM_THREADS": "4", "MAVLINK_DIALECT": "all"})
    assert "OPENBLAS_NUM_THREADS" not in out and "MAVLINK_DIALECT" not in out
    assert out == {"OMP_NUM_THREADS": "1", "MAVLINK20": "1"}


def test_other_subcommands_keep_every_core_and_dialect() -> None:
    assert daemon_env_defaults(["sim"], {}) == {}
    assert daemon_env_defaults([], {}) == {}
    assert daemon_env_defaults(["demo", "agent"], {}) == {}


def test_the_pyinstaller_dialect_is_blocked_unless_it_is_the_dialect() -> None:
    assert blocked_imports(MAVLINK_VARIABLES) == (PYINSTALLER_DIALECT, CURSES)
    assert blocked_imports({"MAVLINK20": "1"}) == (PYINSTALLER_DIALECT, CURSES)  # v2 "all"
    assert blocked_imports({}) == (CURSES,)  # mavutil's default: MAVLink 1 "all", that module
    assert blocked_imports({"MAVLINK_DIALECT": "all"}) == (CURSES,)


def test_pymavlink_without_curses_finds_the_same_printable_characters() -> None:
    """mavutil's ``is_printable`` falls back to ASCII 32-126 without curses (blocked)."""
    code = (
        "import json, sys\n"
        "sys.modules['curses'] = None\n"
        "from pymavlink import mavutil\n"
        "print(json.dumps([mavutil.have_ascii, [c for c in range(256) if mavutil.is_printable(c)]]))\n"
    )
    have_ascii, printable = _fresh_interpreter_json(code, dict(os.environ))
    from curses import ascii

    assert have_ascii is False
    assert printable == [c for c in range(256) if ascii.isprint(c)]


def _entry_point_report(argv: list[str], extra_env: dict[str, str]) -> dict:
    """In a fresh interpreter: import the command line as ``bearingflock ARGV`` would, then run
    a product large enough for OpenBLAS to use its pool, and report the variable and the
    process's thread count."""
    code = (
        "import json, os, sys\n"
        f"sys.argv = ['bearingflock', *{argv!r}]\n"
        "import groundstation.cli\n"
        "import numpy as np, psutil\n"
        "a = np.ones((400, 400)); a @ a\n"
        "print(json.dumps({'var': os.environ.get('OPENBLAS_NUM_THREADS'),"
        " 'threads': psutil.Process().num_threads()}))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in BLAS_THREAD_VARIABLES}
    env.update(extra_env)
    return _fresh_interpreter_json(code, env)


def _fresh_interpreter_json(code: str, env: dict[str, str]) -> dict:
    """Run ``code`` in a fresh interpreter on this tree; the JSON of its last line."""
    env = {**env, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, env=env, capture_output=True, text=True,
        timeout=60, check=True,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_agent_entry_point_runs_blas_on_one_thread() -> None:
    report = _entry_point_report(["agent"], {})
    assert report == {"var": "1", "threads": 1}


def test_agent_entry_point_keeps_the_users_setting() -> None:
    assert _entry_point_report(["agent"], {"OPENBLAS_NUM_THREADS": "2"})["var"] == "2"


def _dialect_report(argv: list[str]) -> dict:
    """In a fresh interpreter: the command line as ``bearingflock ARGV``, the ``agent``
    command's first step, then pymavlink as the link imports it; which dialect modules and
    how many MB it loaded."""
    code = (
        "import json, os, sys, psutil\n"
        f"sys.argv = ['bearingflock', *{argv!r}]\n"
        "import groundstation.cli\n"
        "from onboard.daemon.daemon_env import block_unused_imports\n"
        "if sys.argv[1] == 'agent': block_unused_imports(os.environ, sys.modules)\n"
        "import numpy\n"
        "rss0 = psutil.Process().memory_info().rss\n"
        "import onboard.autopilot.pymavlink_link\n"
        "from pymavlink import mavutil\n"
        "os.environ['MAVLINK20'] = '1'; mavutil.set_dialect(mavutil.current_dialect)\n"
        "mb = (psutil.Process().memory_info().rss - rss0) / 2**20\n"
        "loaded = sorted(m for m in sys.modules if m.startswith('pymavlink.dialects.v') and m.count('.') == 3\n"
        "                and sys.modules[m] is not None)\n"
        "print(json.dumps({'dialect': mavutil.mavlink.__name__, 'loaded': loaded, 'mb': mb}))\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in MAVLINK_VARIABLES}
    return _fresh_interpreter_json(code, env)


def test_the_agent_loads_one_mavlink_dialect_and_others_keep_pymavlinks_default() -> None:
    agent, sim = _dialect_report(["agent"]), _dialect_report(["sim"])
    assert agent["dialect"] == "pymavlink.dialects.v20.ardupilotmega"
    assert agent["loaded"] == ["pymavlink.dialects.v20.ardupilotmega"]
    assert sim["dialect"] == "pymavlink.dialects.v20.all"  # after the MAVLink 2 upgrade
    assert "pymavlink.dialects.v10.all" in sim["loaded"]
    assert agent["mb"] < sim["mb"] - 3  # measured 13.9 against 18.5 MB
