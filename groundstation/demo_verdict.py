"""The demo's one-line verdict: PASS or FAIL against the criteria the demo states
(docs/demo.md, "The verdict"), with the numbers behind it and where the run's files are."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

SCALE_CRITERION = 0.02
"""Metric scale: every reciprocal pair's SfM distance within 2% of the truth (paper 000's
results count an edge converged at 1%; the demo's summary has always used 2%)."""
BEARING_CRITERION_DEG = 3.0
"""The formation: mean angle between flown and planned body-frame bearings at the end."""


@dataclass(frozen=True)
class Verdict:
    passed: bool
    line: str
    failed: list[str] = field(default_factory=list)
    """The criteria that were not met, in words."""
    degraded: bool = False
    """A daemon's core ticks ran late (summary ``degraded``): the numbers are this machine's
    at this speed, not the method's."""

    def as_json(self) -> dict[str, Any]:
        return {
            "pass": self.passed,
            "line": self.line,
            "failed": list(self.failed),
            "degraded": self.degraded,
        }


def _pct(x: float) -> str:
    return f"{100 * x:.2f}%"


def _limit(ok: bool, limit: str) -> str:
    return f"(< {limit})" if ok else f"(>= {limit})"


SCALE_LIMIT = f"{100 * SCALE_CRITERION:g}%"
BEARING_LIMIT = f"{BEARING_CRITERION_DEG:g} deg"


def demo_verdict(summary: dict[str, Any], out: str | None = None) -> Verdict:
    """PASS when the scale became metric (every pair within 2% and staying so), ended within 2%,
    the formation ended within 3 degrees, and (when the summary says) every vehicle landed;
    DEGRADED added when a daemon's ticks ran late (the verdict still judges the numbers)."""
    failed: list[str] = []
    parts: list[str] = []
    tts = summary.get("time_to_scale_s")
    if tts is None:
        failed.append(f"scale never within {SCALE_LIMIT} for good")
        parts.append("metric scale: never")
    else:
        parts.append(f"metric scale {tts:.1f} s after mission start")
    scale = summary.get("final_scale_error")
    if scale is None:
        failed.append("no final scale estimate")
        parts.append("final scale error: none")
    else:
        ok = scale < SCALE_CRITERION
        if not ok:
            failed.append(f"final scale error {_pct(scale)}")
        parts.append(f"final scale error {_pct(scale)} {_limit(ok, SCALE_LIMIT)}")
    bearing = summary.get("final_bearing_error_deg")
    if bearing is None:
        failed.append("no final formation error")
    else:
        ok = bearing < BEARING_CRITERION_DEG
        if not ok:
            failed.append(f"formation error {bearing:.2f} deg")
        parts.append(f"formation error {bearing:.2f} deg {_limit(ok, BEARING_LIMIT)}")
    if "landed" in summary:
        if summary["landed"]:
            parts.append(f"all {summary.get('vehicles', '')} landed".replace("  ", " "))
        else:
            failed.append("not every vehicle landed")
            parts.append("NOT all landed")
    passed = not failed
    head = "PASS" if passed else "FAIL (" + "; ".join(failed) + ")"
    degraded = bool(summary.get("degraded"))
    if degraded:
        late = ", ".join(str(i) for i in summary.get("late_tick_vehicles", []))
        speed = summary.get("speedup")
        at = f" at {speed:g}x" if isinstance(speed, (int, float)) else ""
        head += (
            f" DEGRADED (core ticks ran late on vehicle(s) {late}{at}: this machine was too "
            "slow for the speed, try a lower --speedup)"
        )
    tail = f"; plots and recording in {out}" if out else ""
    return Verdict(passed, f"{head}: " + ", ".join(parts) + tail, failed, degraded)
