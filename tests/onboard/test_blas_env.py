"""One BLAS thread for the daemon unless the user says otherwise (issue 27)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from onboard.daemon.blas_env import BLAS_THREAD_VARIABLES, daemon_blas_defaults

ROOT = Path(__file__).resolve().parents[2]


def test_agent_gets_one_thread_for_each_unset_variable() -> None:
    assert daemon_blas_defaults(["agent", "--id", "0"], {}) == dict.fromkeys(
        BLAS_THREAD_VARIABLES, "1"
    )


def test_user_setting_wins() -> None:
    out = daemon_blas_defaults(["agent"], {"OPENBLAS_NUM_THREADS": "4"})
    assert "OPENBLAS_NUM_THREADS" not in out
    assert out == {"OMP_NUM_THREADS": "1"}


def test_other_subcommands_keep_every_core() -> None:
    assert daemon_blas_defaults(["sim"], {}) == {}
    assert daemon_blas_defaults([], {}) == {}
    assert daemon_blas_defaults(["demo", "agent"], {}) == {}


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
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    out = subprocess.run(
        [sys.executable, "-c", code],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_agent_entry_point_runs_blas_on_one_thread() -> None:
    report = _entry_point_report(["agent"], {})
    assert report == {"var": "1", "threads": 1}


def test_agent_entry_point_keeps_the_users_setting() -> None:
    assert _entry_point_report(["agent"], {"OPENBLAS_NUM_THREADS": "2"})["var"] == "2"
