"""A ``gcs record`` killed without warning (SIGKILL) keeps what it wrote up to its last chunk,
and every reader recovers it and says so (issue 23, defect 10)."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest
from typer.testing import CliRunner

from groundstation.gcs.record import FLUSH_PERIOD_S, Source, read_recording
from groundstation.gcs_cli import gcs_app
from messages.agent import VehicleStatus
from messages.codec import decode, encode
from messages.transport import ZenohSettings, loopback_endpoint, open_session
from sim.server import free_port_base
from tests.groundstation.standin import StandinConfig, scripted_status

pytestmark = pytest.mark.e2e
RATE_HZ = 20.0
SECONDS = 4.5
WARMUP_S = 0.5


def test_a_sigkilled_recorder_keeps_what_it_flushed(tmp_path):
    endpoint = loopback_endpoint(free_port_base(1))
    session = open_session(ZenohSettings(listen=[endpoint]))
    out = tmp_path / "killed.mcap"
    code = "from groundstation.cli import main; main()"
    proc = subprocess.Popen(
        [sys.executable, "-c", code, "gcs", "record", str(out), "--fleet", "crash",
         "--zenoh", endpoint, "--mavlink", "none"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    cfg = StandinConfig("crash", [0, 1])
    sent: list[tuple[float, int]] = []  # (monotonic send time, seq)
    t0 = 0.0
    try:
        pubs = [session.declare_publisher(f"bf/crash/{i}/status") for i in (0, 1)]
        deadline = time.monotonic() + 20.0
        while not all(p.matching_status.matching for p in pubs):
            assert time.monotonic() < deadline and proc.poll() is None, "recorder never joined"
            time.sleep(0.05)
        t0 = time.monotonic()
        k = 0
        while (now := time.monotonic()) - t0 < SECONDS:
            for i, pub in enumerate(pubs):
                pub.put(encode(scripted_status(cfg, i, now - t0, k, "flying")))
            sent.append((now, k))
            k += 1
            time.sleep(1.0 / RATE_HZ)
        t_kill = time.monotonic()
        proc.send_signal(signal.SIGKILL)
        assert proc.wait(10.0) == -signal.SIGKILL
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        proc.stderr.close()
        session.close()

    recording = read_recording(out)
    assert not recording.complete and "was not closed" in recording.describe(out)
    seqs = {
        decode(r.data, VehicleStatus).seq
        for r in recording.records
        if r.source == Source.ZENOH and r.topic == "bf/crash/0/status"
    }
    # everything sent well before the kill is on disk: the recorder flushes every
    # FLUSH_PERIOD_S, checked twice per period, plus delivery (0.5 s margin)
    # (the first WARMUP_S: a fresh Zenoh route may drop a sample or two, not the recorder's doing)
    older = {seq for t, seq in sent if t0 + WARMUP_S < t < t_kill - 1.5 * FLUSH_PERIOD_S - 0.5}
    assert len(older) > 15 and older <= seqs, sorted(older - seqs)[:10]

    res = CliRunner().invoke(gcs_app, ["plot", str(out), "--out", str(tmp_path / "plots")])
    assert res.exit_code == 0, res.output
    assert f"recovered {len(recording.records)} messages" in res.output


def test_a_file_cut_before_its_first_chunk_is_a_clear_failure(tmp_path):
    out = tmp_path / "empty.mcap"
    out.write_bytes(b"\x89MCAP0\r\n\x01\x05")  # the magic and half a header: nothing else
    res = CliRunner().invoke(gcs_app, ["replay", str(out), "--zenoh", "tcp/127.0.0.1:1"])
    assert res.exit_code == 1, res.output
    assert "recovered 0 messages" in res.output and "nothing to read" in res.output
