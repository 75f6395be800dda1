"""Onboard footprint of the daemon (issue 27): resident memory and CPU per simulated second.

It flies the demo (simulator + N agent daemons as processes on loopback, simulator bearings,
rigidity maintenance on for N >= 4, ``groundstation.demo.run_demo``) and samples every daemon
process with psutil: resident set size (RSS) and process CPU time (user + system). CPU is
reported as **CPU seconds per simulated second** over the mission after a warm-up, which is
far less sensitive to other load on the machine than a wall-clock share: a daemon ticks in
simulation time, so its work per simulated second does not depend on how fast the simulator
is allowed to run (``--speedup``).

The bearing -> setpoint latency (p50 over the daemons / worst p99, wall ms) is what every
daemon logs on exit, in two windows (onboard/autopilot/base.py): ``b->wire``, the age of the
newest frame at every setpoint sent (staleness: it includes up to a camera period of waiting
for the next frame), and ``frame->wire``, each frame's capture to the first setpoint based on
it (the loop's latency). Both are comparable only at ``--speedup 1`` (slower, the core ticks
are stretched in wall time).

``--decode`` times instead ``messages.codec.decode`` of every peer payload kind (a sample
built from each kind's field types: six neighbours, six-entry arrays), microseconds per
message: the validation path every one of a daemon's ~1,150 peer callbacks a second took
before the peer envelope (issue 27), and ``messages.envelope.unpack`` of one envelope holding
one of each (a checkout that has it).

``--before PATH`` measures another checkout (e.g. ``git worktree add --detach /tmp/fp-before
main``) in the same invocation, first, with the same script (this file run with that
checkout first on ``PYTHONPATH``), and prints both rows side by side.

Usage: ``python benchmarks/bench_footprint.py [--vehicles 6] [--duration 30] [--speedup 0.5]
[--before PATH] [--profile]``. ``--profile`` has each daemon split its CPU
(``bearingflock agent --profile``, onboard/daemon/profile.py: core, rigidity, codec, zenoh,
mavlink, loop, other); the split is of the whole run, scaled to the CPU per simulated second.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

HERE = Path(__file__).resolve()
WARMUP_S = 5.0
"""Simulated seconds of the mission left out of the CPU figure (take-off, first solves)."""


def _daemons() -> list[psutil.Process]:
    """This process's daemon children: ``... -m onboard.daemon --id I ...`` (the demo's lean
    entry point) or ``... groundstation.cli agent --id I ...`` (a checkout from before it)."""
    found = []
    for p in psutil.Process().children(recursive=True):
        try:
            cmd = p.cmdline()
            if "--id" in cmd and ("agent" in cmd or "onboard.daemon" in cmd):
                found.append(p)
        except psutil.Error:
            continue
    return found


def _cpu_s(p: psutil.Process) -> float:
    t = p.cpu_times()
    return t.user + t.system


def measure(vehicles: int, duration_s: float, speedup: float, seed: int) -> dict[str, Any]:
    """One demo run of this checkout; per-daemon RSS (max over samples, MB) and CPU s/sim-s."""
    from groundstation.demo import run_demo

    marks: dict[str, Any] = {"start": None, "end": None, "rss": {}}

    def on_tick(ev: Any, elapsed: float, phase: str) -> None:
        if phase != "mission":
            return
        stamps = [tr.stamp_s for tr in list(ev.truth.values())]
        if not stamps:
            return
        now = max(stamps)
        procs = _daemons()
        cpu = {}
        for p in procs:
            try:
                cpu[p.pid] = _cpu_s(p)
                rss = p.memory_info().rss / 2**20
                marks["rss"][p.pid] = max(marks["rss"].get(p.pid, 0.0), rss)
            except psutil.Error:
                continue
        if marks["start"] is None and elapsed >= WARMUP_S and len(cpu) == vehicles:
            marks["start"] = (now, cpu)
        if marks["start"] is not None:
            marks["end"] = (now, cpu)

    with tempfile.TemporaryDirectory(prefix="bench-footprint-") as tmp:
        summary = run_demo(
            vehicles, "px4", duration_s, Path(tmp), seed=seed, speedup=speedup, on_tick=on_tick,
            record=False,
        )  # fmt: skip
        logged = _agent_metrics(Path(tmp), vehicles)
        splits = _agent_lines(Path(tmp), vehicles, "cpu_split ")
    if marks["start"] is None or marks["end"] is None:
        raise RuntimeError("no daemon samples: the mission did not run past the warm-up")
    (t0, c0), (t1, c1) = marks["start"], marks["end"]
    per = [(c1[pid] - c0[pid]) / (t1 - t0) for pid in c0 if pid in c1]
    rss = list(marks["rss"].values())
    return {
        "cpu_s_per_sim_s": float(np.mean(per)),
        "cpu_max": float(np.max(per)),
        "rss_mb": float(np.mean(rss)),
        "rss_max_mb": float(np.max(rss)),
        "sim_s": t1 - t0,
        # bearing -> setpoint on the wire (wall ms, as the daemons log it, onboard/daemon/metrics)
        "latency_p50_ms": _pooled(logged, "p50_ms", np.median),
        "latency_p99_ms": _pooled(logged, "p99_ms", np.max),
        # capture -> first setpoint on the wire based on that frame (the loop's latency)
        "frame_p50_ms": _pooled(logged, "p50_ms", np.median, "frame_to_wire"),
        "frame_p99_ms": _pooled(logged, "p99_ms", np.max, "frame_to_wire"),
        # where a daemon's CPU goes (onboard/daemon/profile.py; --profile), mean fractions
        "split": _mean_split(splits),
        "late_p99_ms": _late_p99(logged),
        "scale_error": summary.get("final_scale_error"),
        "landed": summary.get("landed"),
    }


def _agent_metrics(out: Path, n: int) -> list[dict[str, Any]]:
    """The ``metrics {...}`` line each daemon logs on exit (as benchmarks/bench_daemon.py)."""
    return _agent_lines(out, n, "metrics ")


def _agent_lines(out: Path, n: int, prefix: str) -> list[dict[str, Any]]:
    """The last JSON line ``PREFIX{...}`` of each daemon's log."""
    found = []
    for i in range(n):
        text = (out / f"agent{i}.log").read_text().splitlines()
        lines = [x for x in text if prefix + "{" in x]
        if lines:
            found.append(json.loads(lines[-1].split(prefix, 1)[1]))
    return found


def _mean_split(splits: list[dict[str, Any]]) -> dict[str, float] | None:
    """Mean over the daemons of each category's fraction of the process CPU."""
    if not splits:
        return None
    return {k: float(np.mean([s["fraction"][k] for s in splits])) for k in splits[0]["fraction"]}


def _late_p99(metrics: list[dict[str, Any]]) -> float | None:
    """Worst daemon's p99 of how late its core ticks started (wall ms)."""
    values = [m["tick_late"].get("p99_ms") for m in metrics]
    values = [v for v in values if v is not None]
    return float(np.max(values)) if values else None


def _pooled(
    metrics: list[dict[str, Any]], key: str, pool: Any, window: str = "bearing_to_wire"
) -> float | None:
    values = [m.get(window, {}).get(key) for m in metrics]
    values = [v for v in values if v is not None]
    return float(pool(values)) if values else None


def _sample(t: Any) -> Any:
    """A valid plain value (MessagePack-able) of a ``msgspec.inspect`` type: mid-range floats,
    six entries per list, six-entry float64 arrays."""
    import msgspec.inspect as mi

    if isinstance(t, mi.FloatType):
        return 0.5
    if isinstance(t, mi.IntType):
        return 1
    if isinstance(t, mi.BoolType):
        return True
    if isinstance(t, mi.StrType):
        return "x"
    if isinstance(t, (mi.ListType, mi.VarTupleType)):
        return [_sample(t.item_type) for _ in range(6)]
    if isinstance(t, mi.TupleType):
        return [_sample(x) for x in t.item_types]
    if isinstance(t, mi.UnionType):
        return _sample(next(x for x in t.types if not isinstance(x, mi.NoneType)))
    if isinstance(t, mi.CustomType):
        return np.full(6, 0.5).tobytes()
    if isinstance(t, mi.LiteralType):
        return t.values[0]
    if isinstance(t, mi.StructType):  # a list entry (schema 4): a short array, or a map
        if t.array_like:
            return [_sample(f.type) for f in t.fields]
        return {f.encode_name: _sample(f.type) for f in t.fields}
    raise TypeError(f"no sample for {t!r}")


def measure_decode(repeat: int = 20_000) -> dict[str, Any]:
    """Microseconds per ``decode(data, PeerPayload)`` of each peer kind, best of 5."""
    from typing import get_args

    import msgspec
    import msgspec.inspect as mi

    from messages.codec import decode
    from messages.peer import PeerPayload

    def best_us(fn: Any, data: bytes) -> float:
        fn(data)  # valid, and the decoder cached
        best = float("inf")
        for _ in range(5):
            t0 = time.perf_counter()
            for _ in range(repeat):
                fn(data)
            best = min(best, (time.perf_counter() - t0) / repeat)
        return 1e6 * best

    per_kind = {}
    raws = []
    for kind in get_args(PeerPayload):
        info = mi.type_info(kind)
        raw = {f.encode_name: _sample(f.type) for f in info.fields if f.name != "version"}
        raw[info.tag_field] = info.tag
        raws.append(raw)
        per_kind[kind.__name__] = best_us(
            lambda d: decode(d, PeerPayload), msgspec.msgpack.encode(raw)
        )
    try:  # one envelope of every kind (issue 27); a checkout from before has none
        from messages.envelope import unpack
    except ImportError:
        return {"decode_us": per_kind}
    per_kind["sum of the kinds"] = sum(per_kind.values())
    env = {"type": "peer.envelope", "sender": raws[0]["sender"], "payloads": raws}
    data = msgspec.msgpack.encode(env)
    assert len(unpack(data).payloads) == len(raws)
    per_kind["PeerEnvelope (all)"] = best_us(unpack, data)
    return {"decode_us": per_kind}


def _measure_checkout(path: Path, args: argparse.Namespace) -> dict[str, Any]:
    """Run this script's ``--json`` measurement with ``path`` first on the import path."""
    env = dict(os.environ, PYTHONPATH=str(path))
    if args.profile:
        env["BEARINGFLOCK_AGENT_PROFILE"] = "1"  # onboard/daemon/profile.py
    cmd = [sys.executable, str(HERE), "--json", *(["--decode"] if args.decode else []),
           "--vehicles", str(args.vehicles),
           "--duration", str(args.duration), "--speedup", str(args.speedup),
           "--seed", str(args.seed)]  # fmt: skip
    out = subprocess.run(cmd, env=env, cwd=path, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _row(name: str, m: dict[str, Any]) -> str:
    err = m["scale_error"]
    lat = [m.get(k) for k in ("latency_p50_ms", "latency_p99_ms")]
    lat_txt = "-" if None in lat else f"{lat[0]:.0f} / {lat[1]:.0f}"
    frm = [m.get(k) for k in ("frame_p50_ms", "frame_p99_ms")]
    frm_txt = "-" if None in frm else f"{frm[0]:.0f} / {frm[1]:.0f}"
    return (
        f"{name:<10} {m['cpu_s_per_sim_s']:>9.3f} {m['cpu_max']:>7.3f} {m['rss_mb']:>8.1f} "
        f"{m['rss_max_mb']:>7.1f} {m['sim_s']:>6.1f} {lat_txt:>13} {frm_txt:>13} "
        f"{'-' if err is None else f'{100 * err:.2f}%':>9} {m['landed']!s:>6}"
    )


def _decode_table(args: argparse.Namespace) -> None:
    rows = [("this", _measure_checkout(HERE.parent.parent, args)["decode_us"])]
    if args.before is not None:
        rows.insert(0, ("before", _measure_checkout(args.before.resolve(), args)["decode_us"]))
    kinds = list(rows[-1][1])
    print(f"{'decode us/message':<22}" + "".join(f"{name:>9}" for name, _ in rows)
          + ("    ratio" if len(rows) == 2 else ""))  # fmt: skip
    for k in kinds:
        vals = [r.get(k, float("nan")) for _, r in rows]
        ratio = f"{vals[1] / vals[0]:>9.2f}" if len(vals) == 2 else ""
        print(f"{k:<22}" + "".join(f"{v:>9.2f}" for v in vals) + ratio)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, default=6)
    parser.add_argument("--duration", type=float, default=30.0, help="mission, simulated s")
    parser.add_argument("--speedup", type=float, default=0.5, help="simulator speed (x real)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--before", type=Path, help="another checkout to measure first")
    parser.add_argument("--decode", action="store_true", help="time the peer decode instead")
    parser.add_argument(
        "--profile",
        action="store_true",
        help="daemons split their CPU (core, rigidity, codec, zenoh, ...)",
    )
    parser.add_argument("--json", action="store_true", help="one JSON line (used by --before)")
    args = parser.parse_args()
    if args.json:
        if args.decode:
            print(json.dumps(measure_decode()))
        else:
            print(json.dumps(measure(args.vehicles, args.duration, args.speedup, args.seed)))
        return
    if args.decode:
        _decode_table(args)
        return
    print(f"load average before: {os.getloadavg()[0]:.2f}; {args.vehicles} daemons, "
          f"{args.duration:g} sim s at {args.speedup:g}x, CPU after {WARMUP_S:g} s warm-up")  # fmt: skip
    rows = []
    t = time.monotonic()
    if args.before is not None:
        rows.append(("before", _measure_checkout(args.before.resolve(), args)))
    rows.append(("this", _measure_checkout(HERE.parent.parent, args)))
    print(f"{'checkout':<10} {'cpu s/s':>9} {'max':>7} {'RSS MB':>8} {'max':>7} {'sim s':>6} "
          f"{'b->wire ms':>13} {'frame->wire':>13} {'scale err':>9} {'landed':>6} {'late p99':>8}")  # fmt: skip
    for name, m in rows:
        late = m.get("late_p99_ms")
        print(_row(name, m) + f" {'-' if late is None else f'{late:.1f}':>8}")
    for name, m in rows:
        if m.get("split"):
            cpu = m["cpu_s_per_sim_s"]
            print(f"{name}: CPU split (core per sim s): "
                  + ", ".join(f"{k} {cpu * v:.3f}" for k, v in m["split"].items()))  # fmt: skip
    if len(rows) == 2:
        b, a = rows[0][1], rows[1][1]
        print(f"ratio this/before: CPU {a['cpu_s_per_sim_s'] / b['cpu_s_per_sim_s']:.2f}, "
              f"RSS {a['rss_mb'] / b['rss_mb']:.2f}")  # fmt: skip
    print(f"load average after: {os.getloadavg()[0]:.2f} ({time.monotonic() - t:.0f} s wall)")


if __name__ == "__main__":
    main()
