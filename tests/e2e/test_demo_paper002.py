"""The demo's mission flown on paper 002's distributed gradient localization (``[core]
localization = "paper002"``, issue 25 "In flight"): simulator and six daemons as real processes
(real UDP MAVLink, real Zenoh on loopback, 10% injected loss), the same mission, speed and
bounds as ``test_demo.py`` (plain links: the secured ones are that test's subject).

Besides the demo's verdict (SfM scale within 2%, formation within 3 degrees, everyone lands)
it scores what the layer itself estimates: every daemon's status carries its ``T_i``, which
must match the true formation after the best rigid alignment, metric scale included."""

from __future__ import annotations

import numpy as np
import pytest

from groundstation.demo import run_demo
from tests.e2e.test_demo import BEARING_TOLERANCE_DEG, LOSS, MISSION_S, SCALE_TOLERANCE, SPEEDUP

pytestmark = pytest.mark.e2e

VEHICLES = 6
LOC_SCALE_TOLERANCE = 0.05
"""``|size of the estimated formation / true size - 1|`` over the last 2 s (RMS distance to the
centroid). Headless, 40 s without loss: 0.1% (paper 000's filter 0.24%)."""
LOC_POSITION_TOLERANCE_M = 0.5
"""RMS position error after the best rigid alignment (no scale) over the last 2 s."""


def rigid_error_m(est: np.ndarray, true: np.ndarray) -> float:
    """RMS error after the best proper rigid alignment (Kabsch; a scale error shows in it)."""
    a, b = est - est.mean(axis=0), true - true.mean(axis=0)
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    return float(np.sqrt(np.mean(np.sum((a @ (u @ d @ vt) - b) ** 2, axis=1))))


def size_error(est: np.ndarray, true: np.ndarray) -> float:
    """RMS distance to the centroid, estimate over truth, minus 1."""
    a, b = est - est.mean(axis=0), true - true.mean(axis=0)
    return float(np.sqrt(np.sum(a * a) / np.sum(b * b)) - 1.0)


def test_demo_flies_on_paper002_localization(tmp_path):
    summary = run_demo(
        VEHICLES, "px4", MISSION_S, tmp_path, seed=0, speedup=SPEEDUP, loss=LOSS,
        localization="paper002", record=False,
    )  # fmt: skip
    assert 'localization = "paper002"' in (tmp_path / "fleet.toml").read_text()
    report = {
        k: summary[k] for k in ("time_to_scale_s", "final_scale_error", "final_bearing_error_deg")
    }
    assert summary["final_scale_error"] is not None, report
    assert summary["final_scale_error"] < SCALE_TOLERANCE, report
    assert summary["final_bearing_error_deg"] < BEARING_TOLERANCE_DEG, report
    assert summary["time_to_scale_s"] is not None, report
    assert summary["landed"], "every vehicle lands at the end"
    dropped = summary["dropped_by_reason"]
    assert dropped.get("injected_loss", 0) > 0, "the loss was injected"
    assert not any("malformed" in r or "nonfinite" in r for r in dropped), dropped
    # the layer's own estimate, from every daemon's status, against the simulator's truth
    s = np.load(tmp_path / "demo_series.npz")
    t, p, p_hat, flying = s["t_s"], s["p_ned"], s["p_hat_ned"], s["flying"]
    tail = flying & (t >= t[flying][-1] - 2.0)
    assert tail.sum() >= 5, "too few samples at the end of the mission"
    rows = [k for k in np.flatnonzero(tail) if np.isfinite(p_hat[k]).all()]
    assert len(rows) >= 5, "the daemons' statuses carried no estimate"
    size = float(np.mean([abs(size_error(p_hat[k], p[k])) for k in rows]))
    pos = float(np.mean([rigid_error_m(p_hat[k], p[k]) for k in rows]))
    print(f"paper002 in flight: {report}, localization size error {size:.4f}, rigid {pos:.3f} m")
    assert size < LOC_SCALE_TOLERANCE, (size, pos, report)
    assert pos < LOC_POSITION_TOLERANCE_M, (size, pos, report)
