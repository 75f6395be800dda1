"""The simulator as a target (issue 23, defect 7): its memory under spoofed source addresses and
its CPU under spoofed heartbeats, each against a baseline measured in the same run.

A real simulator process (PX4 flavour, UDP, 2 vehicles, real time, its own ports kernel-chosen)
is attacked over loopback:

* codec memory: the same heartbeat from ``--sources`` addresses straight into one vehicle's
  parser table (no socket, so every one arrives): the memory it holds afterwards (tracemalloc).
* memory: ``--sources`` datagrams (default 60,000), each a valid HEARTBEAT from a different
  source address (127.0.0.0/8 addresses x ports), sent to vehicle 0. Reported: the process's
  resident memory (VmRSS) before and after, and the growth.
* CPU: ``--spoofers`` sockets (default 1,000), each sending one valid HEARTBEAT a second to
  vehicle 0, as a flock of fake ground stations. Reported: the simulator's CPU (fraction of one
  core, from /proc utime+stime) and the heartbeat rate a real ground station on the GCS port
  sees, for ``--seconds`` without the attack (the baseline) and then with it; the ratio
  attacked / baseline.

Run against a tree (its ``sim`` package) with ``PYTHONPATH=TREE python
benchmarks/bench_sim_target.py [--sources 60000] [--spoofers 1000] [--seconds 5]``.
"""

from __future__ import annotations

import argparse
import os
import resource
import socket
import subprocess
import sys
import time

from pymavlink.dialects.v20 import common

READY = "Ctrl-C to stop"
TICK_S = os.sysconf("SC_CLK_TCK")


def heartbeat() -> bytes:
    mav = common.MAVLink(None, srcSystem=250, srcComponent=190)
    return common.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(mav)


def start_sim(gcs_port: int) -> tuple[subprocess.Popen[str], list[int]]:
    """A 2-vehicle simulator; returns it and its vehicles' own UDP ports."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "sim.cli", "--quiet", "--vehicles", "2", "--bind-base", "0",
         "--port-base", "9", "--gcs-port", str(gcs_port)],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    assert proc.stdout is not None
    ports = []
    for line in proc.stdout:
        if line.startswith("vehicle ") and "udp 127.0.0.1:" in line:
            ports.append(int(line.split("udp 127.0.0.1:")[1].split()[0]))
        if READY in line:
            return proc, ports
    raise RuntimeError("simulator did not start")


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS")


def cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK_S


def spoof_sources(port: int, n: int) -> None:
    """``n`` valid heartbeats to ``port``, each from another source address."""
    frame = heartbeat()
    for k in range(n):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((f"127.0.{1 + k // 250 % 250}.{1 + k % 250}", 0))
        s.sendto(frame, ("127.0.0.1", port))
        s.close()
        if k % 500 == 499:
            time.sleep(0.01)  # let the simulator read its socket buffer


def drain(sock: socket.socket) -> None:
    """Throw away what waits in ``sock`` (messages of an earlier phase)."""
    sock.setblocking(False)
    try:
        while sock.recv(65535):
            pass
    except OSError:
        pass
    sock.settimeout(0.05)


def gcs_heartbeats(gcs: socket.socket, seconds: float, tick: object = None) -> float:
    """HEARTBEATs per second that reach the ground-station socket over ``seconds``."""
    mav = common.MAVLink(None)
    mav.robust_parsing = True
    n = 0
    end = time.monotonic() + seconds
    next_tick = time.monotonic()
    while time.monotonic() < end:
        if tick is not None and time.monotonic() >= next_tick:
            tick()  # type: ignore[operator]
            next_tick += 1.0
        try:
            data = gcs.recv(65535)
        except (BlockingIOError, TimeoutError):
            continue
        n += sum(m.get_type() == "HEARTBEAT" for m in mav.parse_buffer(data) or [])
    return n / seconds


def codec_memory_mb(n: int) -> tuple[float, int]:
    """Memory (tracemalloc, MB) one vehicle's :class:`Codec` holds after a valid HEARTBEAT from
    each of ``n`` source addresses, and its parser count (all ``n`` reach it: no socket)."""
    import gc
    import tracemalloc

    from sim.autopilot.link import Codec

    frame = heartbeat()
    gc.collect()
    tracemalloc.start()
    codec = Codec(common, 1)
    base = tracemalloc.get_traced_memory()[0]
    for k in range(n):
        codec.parse((f"127.0.{k // 250 % 250}.{k % 250}", 1024 + k), frame, datagram=True)
    gc.collect()
    held = tracemalloc.get_traced_memory()[0] - base
    tracemalloc.stop()
    return held / 2**20, len(codec._parsers)


def memory_attack(pid: int, port: int, sources: int) -> dict[str, float]:
    """``sources`` spoofed source addresses, one valid HEARTBEAT each, to ``port`` of the
    simulator ``pid``: its VmRSS before and 1 s after (MB), and how long sending took."""
    before = rss_mb(pid)
    t0 = time.monotonic()
    spoof_sources(port, sources)
    sent_s = time.monotonic() - t0
    time.sleep(1.0)
    after = rss_mb(pid)
    return {"sources": sources, "rss_before_mb": before, "rss_after_mb": after, "send_s": sent_s}


def cpu_attack(pid: int, port: int, gcs: socket.socket, spoofers: int, seconds: float) -> dict:
    """The simulator ``pid``'s CPU (fraction of one core) and the HEARTBEAT rate ``gcs`` (the
    ground-station socket it streams to) receives, ``seconds`` without an attack (the baseline)
    and then with ``spoofers`` fake ground stations each sending one HEARTBEAT a second to
    ``port``. The caller's file limit must allow ``spoofers`` more sockets."""
    drain(gcs)
    c0 = cpu_s(pid)
    base_hb = gcs_heartbeats(gcs, seconds)
    base_cpu = (cpu_s(pid) - c0) / seconds
    frame = heartbeat()
    flock = []
    for k in range(spoofers):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind((f"127.1.{1 + k // 250}.{1 + k % 250}", 0))
        s.setblocking(False)
        flock.append(s)

    def beat() -> None:
        for s in flock:
            try:
                s.sendto(frame, ("127.0.0.1", port))
            except OSError:
                pass
            try:
                while s.recv(65535):
                    pass
            except OSError:
                pass

    try:
        beat()
        time.sleep(1.0)
        drain(gcs)  # what arrived during that second would count as 1 s more of heartbeats
        c0 = cpu_s(pid)
        att_hb = gcs_heartbeats(gcs, seconds, tick=beat)
        att_cpu = (cpu_s(pid) - c0) / seconds
    finally:
        for s in flock:
            s.close()
    return {"spoofers": spoofers, "seconds": seconds, "base_cpu": base_cpu,
            "base_heartbeats_s": base_hb, "attacked_cpu": att_cpu, "attacked_heartbeats_s": att_hb}  # fmt: skip


def raise_file_limit(sockets: int) -> None:
    """Room for ``sockets`` more open files (the spoofers' sockets)."""
    _soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (min(hard, sockets + 256), hard))


def stop_sim(proc: subprocess.Popen[str]) -> str:
    """SIGINT the simulator; its last output line (its counters)."""
    proc.send_signal(2)
    out, _ = proc.communicate(timeout=20)
    lines = out.strip().splitlines()
    return lines[-1] if lines else ""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sources", type=int, default=60000)
    parser.add_argument("--spoofers", type=int, default=1000)
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    raise_file_limit(args.spoofers)

    held, parsers = codec_memory_mb(args.sources)
    print(f"codec: {args.sources} source addresses -> {parsers} parsers, {held:.1f} MB held")
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.05)
    proc, ports = start_sim(gcs.getsockname()[1])
    try:
        time.sleep(1.0)
        m = memory_attack(proc.pid, ports[0], args.sources)
        print(f"memory: {args.sources} spoofed sources (datagrams sent) in {m['send_s']:.1f} s: "
              f"RSS {m['rss_before_mb']:.1f} -> {m['rss_after_mb']:.1f} MB "
              f"(+{m['rss_after_mb'] - m['rss_before_mb']:.1f} MB)")  # fmt: skip
        time.sleep(32.0 if args.sources else 0.0)  # earlier peers expire (30 s)
        c = cpu_attack(proc.pid, ports[0], gcs, args.spoofers, args.seconds)
        print(f"cpu: baseline {100 * c['base_cpu']:.1f}% of a core, GCS heartbeats "
              f"{c['base_heartbeats_s']:.2f}/s; {args.spoofers} spoofed heartbeats/s: "
              f"{100 * c['attacked_cpu']:.1f}% (x{c['attacked_cpu'] / max(c['base_cpu'], 1e-9):.1f}), "
              f"GCS heartbeats {c['attacked_heartbeats_s']:.2f}/s")  # fmt: skip
    finally:
        last = stop_sim(proc)
        gcs.close()
    print("simulator:", last)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
