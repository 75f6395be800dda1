"""``bearingflock demo --secure``: the whole mission with signed MAVLink everywhere (fresh fleet
keys, ``[security] dir``, a simulator that accepts only correctly signed messages) reaches
metric scale like the plain demo (issue 24)."""

from __future__ import annotations

import pytest

from groundstation.demo import run_demo
from groundstation.demo_cli import default_speedup

pytestmark = pytest.mark.e2e

VEHICLES = 6
SPEEDUP = default_speedup(VEHICLES, cores=2)
MISSION_S = 34.0
LOSS = 0.1
SCALE_TOLERANCE = 0.02
BEARING_TOLERANCE_DEG = 3.0
"""The plain demo's mission and bounds (tests/e2e/test_demo.py). With 4 vehicles the 34 s
mission is too short: one secure run ended 2.02% off in scale, 4.1 degrees in formation,
the scale found only 26 s in."""


def test_secure_demo_finds_metric_scale(tmp_path):
    summary = run_demo(
        VEHICLES, "px4", MISSION_S, tmp_path, seed=0, speedup=SPEEDUP, loss=LOSS, secure=True
    )
    dropped = summary["dropped_by_reason"]
    report = {
        k: summary[k] for k in ("time_to_scale_s", "final_scale_error", "final_bearing_error_deg")
    }
    print(f"\nsecure demo: {report}; signing counters "
          f"{ {k: v for k, v in dropped.items() if k.startswith('mavlink_')} }")  # fmt: skip
    assert (tmp_path / "keys" / "mavlink-vehicle-5.key").stat().st_mode & 0o777 == 0o600
    assert 'dir = "keys"' in (tmp_path / "fleet.toml").read_text()
    assert summary["final_scale_error"] is not None, report
    assert summary["final_scale_error"] < SCALE_TOLERANCE, report
    assert summary["final_bearing_error_deg"] < BEARING_TOLERANCE_DEG, report
    assert summary["landed"], "every vehicle lands at the end"
    assert not [k for k in dropped if k.startswith("mavlink_")], dropped  # no rejection
    log = (tmp_path / "sim.log").read_text().splitlines()[-1]
    assert "signed_ok=" in log and "unsigned_rejected" not in log, log
