"""The demo's one-line verdict against its stated criteria (issue 29)."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from groundstation.cli import app
from groundstation.demo_cli import default_out_dir
from groundstation.demo_verdict import demo_verdict

GOOD = {
    "vehicles": 6,
    "time_to_scale_s": 1.8,
    "final_scale_error": 0.0014,
    "final_bearing_error_deg": 0.9,
    "landed": True,
}


def test_a_good_run_passes_in_one_line_that_says_where_its_files_are():
    v = demo_verdict(GOOD, "bearingflock-demo-20261202-010000")
    assert v.passed and v.failed == []
    assert v.line == (
        "PASS: metric scale 1.8 s after mission start, final scale error 0.14% (< 2%), "
        "formation error 0.90 deg (< 3 deg), all 6 landed; plots and recording in "
        "bearingflock-demo-20261202-010000"
    )
    assert "\n" not in v.line


def test_late_ticks_mark_the_run_degraded_whatever_its_numbers():
    late = {**GOOD, "degraded": True, "late_tick_vehicles": [0, 4], "speedup": 1.0}
    v = demo_verdict(late)
    assert v.passed and v.degraded and v.as_json()["degraded"] is True
    assert v.line.startswith(
        "PASS DEGRADED (core ticks ran late on vehicle(s) 0, 4 at 1x: this machine was too "
        "slow for the speed, try a lower --speedup): metric scale 1.8 s"
    )
    assert not demo_verdict({**GOOD, "degraded": False}).degraded


def test_each_criterion_fails_the_run_and_is_named():
    cases = {
        "time_to_scale_s": (None, "scale never within 2% for good"),
        "final_scale_error": (0.03, "final scale error 3.00%"),
        "final_bearing_error_deg": (3.5, "formation error 3.50 deg"),
        "landed": (False, "not every vehicle landed"),
    }
    for key, (value, reason) in cases.items():
        v = demo_verdict({**GOOD, key: value})
        assert not v.passed and v.failed == [reason], key
        assert v.line.startswith(f"FAIL ({reason}): ")
        assert "(>= " in v.line or value in (None, False)
    assert demo_verdict({**GOOD, "final_scale_error": None}).failed == ["no final scale estimate"]


def test_without_a_landing_phase_landing_is_no_criterion():
    v = demo_verdict({k: v for k, v in GOOD.items() if k != "landed"})
    assert v.passed and "landed" not in v.line


def test_the_default_output_directory_is_named_after_the_time():
    assert str(default_out_dir(0.0)).startswith("bearingflock-demo-19")
    assert default_out_dir(0.0).parent == Path(".")


def test_an_unwritable_out_is_a_one_line_error(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    res = CliRunner().invoke(app, ["demo", "--out", str(blocker / "sub")])
    assert res.exit_code == 2 and "cannot write there" in res.output, res.output


def test_the_headless_demo_ends_with_its_verdict_and_exits_by_it():
    res = CliRunner().invoke(app, ["demo", "--headless", "--vehicles", "3", "--duration", "4"])
    last = res.stdout.strip().splitlines()[-1]
    assert last.startswith(("PASS: ", "FAIL ("))
    assert res.exit_code == (0 if last.startswith("PASS") else 1)
    res = CliRunner().invoke(
        app, ["demo", "--headless", "--vehicles", "3", "--duration", "4", "--json"]
    )
    verdict = json.loads(res.stdout.strip().splitlines()[-1])["verdict"]
    assert verdict["line"] == last and res.exit_code == (0 if verdict["pass"] else 1)
