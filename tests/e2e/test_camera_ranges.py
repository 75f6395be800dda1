"""Ranges from pixels, end to end (issue 25, "Bearing + distance"): the simulator renders each
vehicle's camera over real Zenoh; three real daemons fly paper 002's localization
(``[core] localization = "paper002"``, ``bearings = "camera"``), and their camera pipeline's disc
ranges reach its eq. 22 range terms (``AgentStatus.range_terms``). The scales ``lambda_ij`` the
agents share (``GradientLocalizationShare``, in their peer envelopes) match the simulator's true distances."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np
import pytest

from groundstation.demo import DemoPorts, Evaluator, Processes, plan_formation, write_demo_files
from groundstation.demo_cli import write_camera_rig
from messages.codec import MessageError, decode
from messages.envelope import sample_payloads
from messages.peer import GradientLocalizationShare
from messages.sim import Truth
from messages.transport import ZenohSettings, loopback_endpoint
from sim.server import free_port_base

pytestmark = pytest.mark.e2e
N = 3
SPEEDUP = 0.5


class Recorder:
    """Every agent's gradient-localization shares and the simulator's truth (evaluation only)."""

    def __init__(self, ev: Evaluator, fleet: str) -> None:
        self.lock = threading.Lock()
        self.shares: list[GradientLocalizationShare] = []
        self.truth: dict[int, list[Truth]] = {k: [] for k in range(N)}
        s = ev.session
        self.subs = [
            s.declare_subscriber(f"bf/{fleet}/*/peer", self._on_share),
            s.declare_subscriber(f"bf/{fleet}/*/truth", self._on_truth),
        ]

    def _on_share(self, sample) -> None:
        try:  # the agent's peer envelope: keep its GradientLocalizationShare
            got = sample_payloads(
                str(sample.key_expr), sample.payload.to_bytes(), kinds={"gradloc"}
            )
        except MessageError:
            return
        with self.lock:
            self.shares.extend(got.payloads)

    def _on_truth(self, sample) -> None:
        msg = decode(sample.payload.to_bytes(), Truth)
        with self.lock:
            self.truth[msg.sender].append(msg)

    def true_p(self, k: int, t_s: float) -> np.ndarray | None:
        with self.lock:
            rows = sorted(self.truth[k], key=lambda m: m.stamp_s)
        t = np.array([m.stamp_s for m in rows])
        if len(t) < 2 or not t[0] <= t_s <= t[-1]:
            return None
        return np.array([np.interp(t_s, t, [m.p_ned[a] for m in rows]) for a in range(3)])


def test_camera_ranges_reach_paper002_localization(tmp_path: Path, wait_for) -> None:
    base = free_port_base(N + 2, span=60)
    ports = DemoPorts(zenoh=base, mavlink=base + 10 + N, gcs=base + 9)
    plan = plan_formation(N, seed=1)
    name = f"r{base}"
    fleet_path = write_demo_files(tmp_path, plan, ports, name, "formation-active",
                                  rigidity=False, localization="paper002")  # fmt: skip
    cams, markers = write_camera_rig(tmp_path / "rig", N, cameras=1, hfov_deg=110.0)
    procs = Processes(tmp_path)
    procs.start(
        "sim",
        [
            "-m", "sim.cli", "--vehicles", str(N), "--layout", str(tmp_path / "start.toml"),
            "--zenoh", loopback_endpoint(ports.zenoh), "--fleet", name,
            "--port-base", str(ports.mavlink), "--gcs-port", str(ports.gcs),
            "--bind-base", "0", "--speedup", str(SPEEDUP), "--quiet",
            "--render-camera", str(cams[0]), "--markers", str(markers), "--render-rate", "5",
        ],
    )  # fmt: skip
    for i in range(N):
        procs.start(
            f"agent{i}",
            ["-m", "groundstation.cli", "agent", "--id", str(i), "--config", str(fleet_path),
             "--bearings", "camera", "--camera", str(cams[0]), "--markers", str(markers)],
        )  # fmt: skip
    ev = Evaluator(
        name,
        plan,
        ZenohSettings(connect=[loopback_endpoint(ports.zenoh + k) for k in range(N + 1)]),
    )
    rec = Recorder(ev, name)
    try:

        def all_flying() -> bool:
            st = ev.snapshot()
            return len(st) == N and all(s.phase == "flying" and s.in_air for s in st.values())

        wait_for(all_flying, 40.0, "every daemon flying on camera bearings", ev)

        def ranges_used() -> bool:
            st = ev.snapshot()
            return len(st) == N and all(s.agent.range_terms > 0 for s in st.values())

        wait_for(ranges_used, 20.0, "every paper 002 layer to use camera ranges", ev)
        first = {k: s.agent.range_terms for k, s in ev.snapshot().items()}
        t_used = max(s.stamp_s for s in ev.snapshot().values())
        time.sleep(6.0)  # 3 s of simulation time
        assert not procs.dead()
        status = ev.snapshot()
        for k, s in status.items():
            assert s.agent.range_terms > first[k], (k, s.agent.range_terms, first[k])
            bad = {c: v for c, v in s.dropped.items() if c.startswith("camera_")}
            assert set(bad) <= {"camera_no_attitude"}, bad
            assert "core_bad_range" not in s.dropped, s.dropped

        # the shared scales are metric: lambda_ij = |lambda_ij u_ij| against the true distance
        with rec.lock:
            shares = [m for m in rec.shares if m.stamp_s > t_used + 1.0]
        rel = []
        for m in shares:
            p_i = rec.true_p(m.sender, m.stamp_s)
            for e in m.edges:
                p_j = rec.true_p(e.target, m.stamp_s)
                if p_i is None or p_j is None:
                    continue
                d = float(np.linalg.norm(p_j - p_i))
                rel.append(abs(float(np.linalg.norm(e.w_ned)) - d) / d)
        assert len(rel) >= 10
        print(f"range_terms {[s.agent.range_terms for s in status.values()]}, lambda vs true "
              f"distance: median {np.median(rel):.4f}, max {max(rel):.4f} (relative)")  # fmt: skip
        assert np.median(rel) < 0.05 and max(rel) < 0.2, (np.median(rel), max(rel))
    finally:
        ev.close()
        procs.stop()
