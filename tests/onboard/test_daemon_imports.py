"""The daemon's import path stays lean (issue 27, resident memory <= 70 MB per daemon).

A daemon is ``python -m groundstation.cli agent`` (``bearingflock agent``) or, as the demo
starts it, ``python -m onboard.daemon`` (``onboard/daemon/entry.py``): the command line module,
then the modules ``onboard.daemon.cli._run_agent`` imports unconditionally (read from its
source, so the test follows the code) and the pymavlink link it opens with simulator bearings.
None of that may pull in SciPy (about 27 MB resident), OpenCV (only with a camera), numba or
matplotlib. The lean entry point, run for real up to the fleet file, must in addition leave out
the rest of the toolkit's command line (``groundstation``, ``sim``), pydantic (typer's option
coercion), rich (typer's help and errors) and typer itself (about 3 MB with click; the
options are a plain table, ``onboard/daemon/options.py``): 51 against 65 MB of imports. A
core as the demo configures it (active, rigidity maintenance on) starts without
``numpy.random`` (6.8 MB; its seeded draws are ``onboard/seeded.py``). Checked in a fresh
interpreter: ``sys.modules`` of the test process says nothing about a daemon's.
"""

from __future__ import annotations

import ast
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("scipy", "cv2", "numba", "matplotlib")
NOT_ON_A_VEHICLE = ("groundstation", "sim", "pydantic", "pydantic_core", "rich", "typer", "click")
"""Packages the lean entry point leaves out: the ground station's and simulator's commands,
typer and click (its options are a plain table, ``onboard/daemon/options.py``)."""


def run_agent_imports() -> list[str]:
    """Modules the body of ``_run_agent`` imports on every start (not inside a branch)."""
    tree = ast.parse((ROOT / "onboard" / "daemon" / "cli.py").read_text())
    body = next(
        node.body
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef) and node.name == "_run_agent"
    )
    names = []
    for stmt in body:
        if isinstance(stmt, ast.Import):
            names += [alias.name for alias in stmt.names]
        elif isinstance(stmt, ast.ImportFrom) and stmt.module and stmt.level == 0:
            names.append(stmt.module)
    return names


def test_run_agent_imports_are_found() -> None:
    modules = run_agent_imports()
    assert "onboard.daemon.loop" in modules
    assert "onboard.autopilot" in modules


def test_daemon_import_path_has_no_heavy_modules() -> None:
    modules = ["groundstation.cli", *run_agent_imports(), "onboard.autopilot.pymavlink_link"]
    code = (
        "import importlib, json, sys\n"
        f"for m in {modules!r}:\n"
        "    importlib.import_module(m)\n"
        f"print(json.dumps([h for h in {HEAVY!r} if h in sys.modules]))\n"
    )
    assert _fresh_interpreter_json(code) == []


def _fresh_interpreter_json(code: str) -> object:
    """Run ``code`` in a fresh interpreter on this tree; the JSON of its last line."""
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]),
    }
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


def _started_daemon_packages(entry: list[str], missing: Path) -> list[str]:
    """In a fresh interpreter: run the entry point ``entry`` (``python -m ENTRY``) as a daemon
    of a fleet file that does not exist, which gets through parsing and the daemon's imports
    and exits 2 at the fleet file; then the pymavlink link and Zenoh, which it opens next.
    The top-level packages of :data:`HEAVY` and :data:`NOT_ON_A_VEHICLE` then loaded."""
    code = (
        "import json, runpy, sys\n"
        f"sys.argv = ['x', *{entry[1:]!r}, '--id', '0', '--config', {str(missing)!r}]\n"
        "try:\n"
        f"    runpy.run_module({entry[0]!r}, run_name='__main__', alter_sys=True)\n"
        "except SystemExit as exc:\n"
        "    assert exc.code == 2, exc.code\n"
        "import onboard.autopilot.pymavlink_link, zenoh\n"
        "top = {m.split('.')[0] for m, v in sys.modules.items() if v is not None}\n"
        f"print(json.dumps(sorted(top & set({(*HEAVY, *NOT_ON_A_VEHICLE)!r}))))\n"
    )
    return _fresh_interpreter_json(code)  # type: ignore[return-value]


def test_lean_entry_point_leaves_out_the_ground_station_sim_pydantic_and_rich(
    tmp_path: Path,
) -> None:
    lean = _started_daemon_packages(["onboard.daemon"], tmp_path / "missing.toml")
    assert lean == []
    # the same check sees them through bearingflock's full command line
    full = _started_daemon_packages(["groundstation.cli", "agent"], tmp_path / "missing.toml")
    assert {"groundstation", "sim"} <= set(full)


def test_a_core_in_the_demos_mode_starts_without_numpy_random() -> None:
    """The lean entry point's modules and an agent core in the demo's mode (active, rigidity
    maintenance on, so the distributed eigen estimator starts too) load neither
    ``numpy.random`` (its seeded draws loaded it: 6.8 MB) nor typer."""
    code = (
        "import json, sys\n"
        "import onboard.daemon.entry\n"
        "from onboard.core.agent import AgentCore\n"
        "from onboard.core.config import build_config\n"
        "edges = ((0, 1), (1, 0), (1, 2), (2, 1), (0, 2), (2, 0), (0, 3), (3, 0), (1, 3), (3, 1))\n"
        "desired = tuple((i, j, (1.0, 0.0, 0.0)) for i, j in edges)\n"
        "core = AgentCore(build_config(agent_id=0, n_agents=4, edges=edges,\n"
        "    mode='formation-active', desired_beta_body=desired, rigidity_maintenance=True))\n"
        "assert core.rigidity is not None and core.rigidity.eigen.v.shape == (3, 3)\n"
        "print(json.dumps([m for m in ('numpy.random', 'typer', 'click') if m in sys.modules]))\n"
    )
    assert _fresh_interpreter_json(code) == []
