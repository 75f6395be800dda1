"""What securing the fleet costs (issue 24): plain and ``--secure`` side by side in one run.

1. The whole demo (simulator + N daemons, real time), plain and secure (signed MAVLink, Zenoh
   over mutual TLS with the fleet's access control), in interleaved rounds (the VM is shared):
   CPU per daemon process (fraction of one core), bearing -> wire latency (camera frame over
   Zenoh, core, setpoint out: p50/p99), final scale error.
2. Zenoh message latency on loopback between two sessions, TCP vs TLS + ACL: put -> callback,
   p50/p99 over many small messages.
3. MAVLink per message: pymavlink parsing alone (the baseline) vs parsing + our signature
   check (HMAC-SHA256, constant-time compare, stream timestamp).

Usage: ``python benchmarks/bench_security.py [--vehicles 3] [--duration 30] [--rounds 2]``
(``--quick``: 1 round of 20 s).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
from bench_daemon import _agent_metrics
from pymavlink.dialects.v20 import common

from groundstation.demo import run_demo
from messages.fleetkeys import GCS_NAME, identity_files, init_fleet, vehicle_name
from messages.mavsign import SignatureVerifier, sign_outgoing
from messages.transport import ZenohSettings, open_session, with_mutual_tls
from messages.zenoh_acl import fleet_access_control
from sim.server import free_port_base


def demo_rows(vehicles: int, duration: float, rounds: int) -> None:
    rows: dict[str, list[dict]] = {"plain": [], "secure": []}
    for _ in range(rounds):
        for name in ("plain", "secure"):
            with tempfile.TemporaryDirectory(prefix=f"bench-security-{name}-") as tmp:
                summary = run_demo(
                    vehicles, "px4", duration, Path(tmp), seed=0, secure=name == "secure"
                )
                metrics = _agent_metrics(Path(tmp), vehicles)
            rows[name].append({"summary": summary, "metrics": metrics})
    print(f"{'demo':>7} {'cpu/agent':>9} {'b->wire p50':>11} {'p99 ms':>7} {'scale err':>9}")
    base_cpu = None
    for name, runs in rows.items():
        ms = [m for r in runs for m in r["metrics"]]
        if len(ms) < vehicles * len(runs):
            print(f"{name:>7} only {len(ms)} agent metrics")
            continue
        cpu = float(np.mean([m["cpu_fraction"] for m in ms]))
        p50 = float(np.median([m["bearing_to_wire"].get("p50_ms", np.nan) for m in ms]))
        p99 = float(np.max([m["bearing_to_wire"].get("p99_ms", np.nan) for m in ms]))
        errs = [r["summary"].get("final_scale_error") for r in runs]
        err = max(e for e in errs if e is not None) if any(e is not None for e in errs) else None
        base_cpu = cpu if base_cpu is None else base_cpu
        print(
            f"{name:>7} {100 * cpu:>8.1f}% {p50:>11.1f} {p99:>7.1f} "
            f"{'-' if err is None else f'{100 * err:.2f}%':>9}   cpu x{cpu / base_cpu:.2f}"
        )


def zenoh_latency(n: int, keys: Path | None) -> tuple[float, float]:
    port = free_port_base(2, span=10)
    a_set = ZenohSettings(listen=[f"tcp/127.0.0.1:{port}"])
    b_set = ZenohSettings(listen=[f"tcp/127.0.0.1:{port + 1}"], connect=[f"tcp/127.0.0.1:{port}"])
    if keys is not None:
        acl = fleet_access_control("bench", 2)
        a_set = with_mutual_tls(a_set, *identity_files(keys, GCS_NAME), acl)
        b_set = with_mutual_tls(b_set, *identity_files(keys, vehicle_name(0)), acl)
    a, b = open_session(a_set), open_session(b_set)
    lat: list[float] = []
    done = threading.Event()

    def on_sample(sample) -> None:
        lat.append(time.perf_counter() - float(sample.payload.to_bytes().decode()))
        if len(lat) >= n:
            done.set()

    sub = a.declare_subscriber("bf/bench/0/peer/x", on_sample)
    pub = b.declare_publisher("bf/bench/0/peer/x")
    time.sleep(1.5)
    for _ in range(n):
        pub.put(f"{time.perf_counter():.9f}".encode())
        time.sleep(0.002)
    done.wait(5.0)
    sub.undeclare()
    a.close()
    b.close()
    ms = np.array(lat) * 1e3
    return float(np.percentile(ms, 50)), float(np.percentile(ms, 99))


def mavlink_cost(n: int) -> tuple[float, float]:
    key = bytes(range(32))
    tx = common.MAVLink(None, srcSystem=245, srcComponent=191)
    sign_outgoing(tx, key, 1)
    sp = common.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, 8, 1479, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0, 0.3
    )
    frames = []
    for _ in range(n):
        frames.append(bytes(sp.pack(tx)))
        tx.seq = (tx.seq + 1) % 256
    data = b"".join(frames)
    t0 = time.perf_counter()
    msgs = common.MAVLink(None).parse_buffer(data)
    t_parse = time.perf_counter() - t0
    v = SignatureVerifier(key)
    t0 = time.perf_counter()
    msgs = common.MAVLink(None).parse_buffer(data)
    ok = sum(v.check_message(m).accepted for m in msgs)
    t_both = time.perf_counter() - t0
    assert ok == n
    return t_parse / n * 1e6, t_both / n * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, default=3)
    parser.add_argument("--duration", type=float, default=30.0)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--quick", action="store_true", help="1 round of 20 s")
    args = parser.parse_args()
    duration, rounds = (20.0, 1) if args.quick else (args.duration, args.rounds)
    print(f"load average before: {os.getloadavg()[0]:.2f} (2-core machine: treat > 0.5 as noise)")
    parse_us, both_us = mavlink_cost(20_000)
    print(
        f"mavlink per message: parse {parse_us:.1f} us, parse + signature check {both_us:.1f} us "
        f"(x{both_us / parse_us:.2f})"
    )
    with tempfile.TemporaryDirectory(prefix="bench-security-keys-") as tmp:
        init_fleet(Path(tmp), "bench", 1)
        tcp = zenoh_latency(500, None)
        tls = zenoh_latency(500, Path(tmp))
    print(
        f"zenoh put -> callback: tcp p50 {tcp[0]:.3f} ms p99 {tcp[1]:.3f} ms; "
        f"tls + acl p50 {tls[0]:.3f} ms p99 {tls[1]:.3f} ms (p50 x{tls[0] / tcp[0]:.2f})"
    )
    demo_rows(args.vehicles, duration, rounds)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
