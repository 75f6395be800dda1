"""How many vehicles one simulator process runs in real time, and the MAVLink rate it sustains.

For each fleet size the simulator runs in real time (speedup 1, default stream rates, PX4
flavour, every vehicle sending to its offboard port and to a ground-station port) for a few
seconds of wall time. Reported per size: the simulated/wall time ratio (1.00 = keeps up), the
CPU it used (fraction of one core), MAVLink messages sent per second, and the loop's overruns.
The baseline, measured in the same run, is the raw cost of packing and sending one message
with pymavlink, so the ratio "CPU per message / raw" shows the simulator's own overhead.

Run: ``python benchmarks/bench_sim.py [--sizes 1 25 50 100] [--seconds 4]``
"""

from __future__ import annotations

import argparse
import socket
import statistics
import time

from pymavlink.dialects.v20 import common

from sim.server import SimConfig, SimServer, free_port_base
from sim.world import grid_layout


def raw_message_cost_s(n: int = 20000) -> float:
    """Median seconds to pack one ATTITUDE and send it to two UDP ports (the baseline)."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    mav = common.MAVLink(None, srcSystem=1, srcComponent=1)
    dests = [("127.0.0.1", 9), ("127.0.0.1", 10)]
    samples = []
    for _ in range(5):
        t0 = time.perf_counter()
        for k in range(n // 5):
            buf = common.MAVLink_attitude_message(k, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0).pack(mav)
            for d in dests:
                sock.sendto(buf, d)
        samples.append((time.perf_counter() - t0) / (n // 5))
    sock.close()
    return statistics.median(samples)


def run_fleet(n: int, seconds: float) -> dict[str, float]:
    p, yaw = grid_layout(n, 5.0)
    base = free_port_base(n, span=n + 60)
    server = SimServer(
        SimConfig(p, yaw, client_base=base, gcs_port=base + n + 10, bind_base=base + n + 20)
    )
    server.start()
    time.sleep(0.5)  # warm up
    tx0, t_sim0, cpu0, wall0 = (
        server.counters()["tx_packets"],
        server.world.t_s,
        time.process_time(),
        time.monotonic(),
    )
    time.sleep(seconds)
    wall = time.monotonic() - wall0
    cpu = time.process_time() - cpu0
    c = server.counters()
    tx = c["tx_packets"] - tx0
    t_sim = server.world.t_s - t_sim0
    server.stop()
    return {
        "n": n,
        "realtime": t_sim / wall,
        "cpu": cpu / wall,
        "msgs_per_s": tx / wall,
        "cpu_per_msg_s": cpu / max(tx, 1),
        "overruns": c["overruns"],
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[1, 25, 50, 100])
    ap.add_argument("--seconds", type=float, default=4.0)
    args = ap.parse_args()
    raw = raw_message_cost_s()
    print(f"baseline: pymavlink pack + 2 sendto = {raw * 1e6:.1f} us/message (median of 5)")
    print(
        f"{'vehicles':>8} {'sim/wall':>9} {'cpu(core)':>10} {'msgs/s':>9} {'us/msg':>8} {'x raw':>6} {'overruns':>9}"
    )
    best = 0
    for n in args.sizes:
        r = run_fleet(n, args.seconds)
        ok = r["realtime"] >= 0.99 and r["overruns"] == 0 and r["cpu"] < 1.0
        best = n if ok else best
        print(
            f"{n:>8} {r['realtime']:>9.3f} {r['cpu']:>10.2f} {r['msgs_per_s']:>9.0f} "
            f"{r['cpu_per_msg_s'] * 1e6:>8.1f} {r['cpu_per_msg_s'] / raw:>6.2f} {r['overruns']:>9.0f}"
        )
    print(f"largest fleet in real time under one core: {best} vehicles")


if __name__ == "__main__":
    main()
