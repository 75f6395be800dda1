"""`bearingflock gcs formation` against the simulator and three real daemons: a new desired
formation (a shape change, with a leader) sent in flight is acknowledged in every status and the
true bearings move towards it while the leader holds; a bad formation file is a one-line error."""

from __future__ import annotations

import json
import subprocess
import sys
import time

import numpy as np
import pytest

from onboard.geometry import bearings_body

pytestmark = pytest.mark.e2e
N = 3  # vehicles in the `fleet` fixture (conftest.py)


def gcs(*args: str, timeout_s: float = 30.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "groundstation.cli", "gcs", *args],
        capture_output=True, text=True, timeout=timeout_s,
    )  # fmt: skip


def _truth(ev) -> tuple[np.ndarray, np.ndarray]:
    with ev._lock:
        tr = [ev.truth[k] for k in range(N)]
    return np.array([t.p_ned for t in tr]), np.array([t.yaw_rad for t in tr])


def _bearing_error_deg(ev, desired: np.ndarray) -> float:
    """Largest angle between a true bearing of the sensing graph and its new desired one."""
    p, yaw = _truth(ev)
    beta, _ = bearings_body(p, yaw, ev.plan.edges)
    cos = np.clip(np.sum(beta * desired, axis=1), -1.0, 1.0)
    return float(np.degrees(np.arccos(cos)).max())


def test_formation_change_in_flight(fleet, wait_for, tmp_path):
    ev, _, ports, _, name = fleet
    bad = tmp_path / "bad.toml"
    bad.write_text("[[agent]]\nid = 0\nposition_ned = [0.0, 0.0]\n")
    out = gcs("formation", str(bad), "--yes", "--fleet", name, "--zenoh", "none")
    assert out.returncode == 2 and out.stdout == "", out
    assert out.stderr.count("\n") == 1 and out.stderr.startswith("error: "), out.stderr

    # the planned ring, one vehicle pulled out 3 m: equilateral -> isosceles (paper 002 Sect. 6)
    plan = ev.plan
    p_new = plan.p_ned.copy()
    p_new[2] += (
        3.0
        * (p_new[2] - p_new[:2].mean(axis=0))
        / np.linalg.norm(p_new[2] - p_new[:2].mean(axis=0))
    )
    lines = ['name = "isosceles"']
    for k in range(N):
        pos = ", ".join(f"{x:.6f}" for x in p_new[k])
        lines += ["[[agent]]", f"id = {k}", f"position_ned = [{pos}]",
                  f"yaw_deg = {np.degrees(plan.yaw_rad[k]):.6f}"]  # fmt: skip
    new = tmp_path / "isosceles.toml"
    new.write_text("\n".join(lines) + "\n")
    desired, _ = bearings_body(p_new, plan.yaw_rad, plan.edges)

    wait_for(
        lambda: len(ev.snapshot()) == N and len(ev.truth) == N
        and all(s.phase == "flying" for s in ev.snapshot().values()),
        30.0, "every daemon flying", ev,
    )  # fmt: skip
    assert all(s.formation_id == 0 for s in ev.snapshot().values())
    links = ["--fleet", name]
    for k in range(N + 1):
        links += ["--zenoh", f"tcp/127.0.0.1:{ports.zenoh + k}"]
    before = _bearing_error_deg(ev, desired)
    out = gcs("formation", str(new), "--leader", "0", "--id", "42", "--yes", "--json", *links)
    assert out.returncode == 0, out.stdout + out.stderr
    sent = json.loads(out.stdout)
    assert sent["id"] == 42 and sent["leader"] == 0 and sent["vehicles"] == [0, 1, 2]
    assert all(r["ok"] for r in sent["results"]), sent
    statuses = ev.snapshot()
    assert all(s.formation_id == 42 and s.formation_leader == 0 for s in statuses.values())

    p_leader0 = _truth(ev)[0][0]  # from the acknowledgement on, the leader holds
    t0 = time.monotonic()
    wait_for(lambda: _bearing_error_deg(ev, desired) < 0.25 * before, 12.0,
             f"bearings within a quarter of the {before:.1f} deg at the change", ev)  # fmt: skip
    moved_leader_m = float(np.linalg.norm(_truth(ev)[0][0] - p_leader0))
    print(f"bearing error {before:.1f} deg -> {_bearing_error_deg(ev, desired):.2f} deg "
          f"in {time.monotonic() - t0:.1f} s; leader moved {moved_leader_m:.2f} m")  # fmt: skip
    old, _ = bearings_body(plan.p_ned, plan.yaw_rad, plan.edges)
    assert before > 5.0
    assert _bearing_error_deg(ev, desired) < _bearing_error_deg(ev, old)  # towards the new one
    assert moved_leader_m < 0.5
