"""Size and write speed of a recording: the JSON + JSON Schema channels ``gcs record`` writes
(issue 29, Foxglove shows them) against the schema-less ``msgpack`` channels of before.

The same Zenoh samples (the wire bytes, in the same order and at the same times) are written
twice in one run: as before (one channel per key, the raw bytes, no schema) and with today's
:class:`~groundstation.gcs.record.Recorder` (decode, JSON, schema'd channels, Foxglove scene;
no ``.tlog``: no MAVLink here). Both use the same MCAP chunk size and zstd compression.
Samples: ``--from FILE`` takes the Zenoh samples of a recording; by default a synthetic team of
``--agents`` agents for ``--seconds`` s at the daemons' rates (status 10 Hz, truth 50 Hz,
camera bearings 30 Hz, peer envelopes 50 Hz: motion in each, SfM estimates and consensus in
every fifth).

Usage: ``python benchmarks/bench_record.py [--agents 6] [--seconds 20] [--from FILE]``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

from mcap.writer import Writer

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the scripted statuses: tests/


from groundstation.gcs.record import CHUNK_BYTES, Recorder, Source, iter_records
from messages.codec import encode
from messages.envelope import pack
from messages.peer import (
    ConsensusEntry,
    ConsensusState,
    MotionShare,
    SfmEdgeEstimate,
    SfmEstimate,
)
from messages.sim import CameraBearings, Truth
from tests.groundstation.standin import StandinConfig, scripted_status

T0 = 1_700_000_000.0


def synthetic(n: int, seconds: float) -> list[tuple[str, bytes, float]]:
    cfg = StandinConfig("alpha", list(range(n)))
    out = []
    for k in range(int(seconds * 50)):
        t = 0.02 * k
        for i in range(n):
            nb = [j for j in range(n) if j != i]
            pre = f"bf/alpha/{i}"
            out.append((f"{pre}/truth", encode(Truth(sender=i, seq=k, stamp_s=t,
                        p_ned=(1.0 * i, t, -5.0), v_ned=(0.0, 1.0, 0.1), yaw_rad=0.1 * i,
                        yaw_rate_rad_s=0.01)), t))  # fmt: skip
            tick: list = [MotionShare(sender=i, seq=k, stamp_s=t, v_body=(1.0, 0.2, 0.0),
                                      yaw_rate_rad_s=0.01, yaw_rad=t)]  # fmt: skip
            if k % 5 == 0:
                out.append((f"{pre}/status", encode(scripted_status(cfg, i, t, k, "flying")), t))
                tick.append(SfmEstimate(sender=i, seq=k, stamp_s=t,
                            edges=[SfmEdgeEstimate(j, 0.1, 0.5, 0.01, 3.0) for j in nb]))  # fmt: skip
                tick.append(ConsensusState(sender=i, seq=k, stamp_s=t,
                            states=[ConsensusEntry(name, [0.1] * n, [0.2] * n)
                                    for name in ("e", "lambda", "w")]))  # fmt: skip
            # a tick's peer payloads in one envelope, as the daemons send them (issue 27)
            out.append((f"{pre}/peer", pack(i, k, tick).data, t))
            if k % 5 in (0, 2, 3):  # 30 Hz
                cam = CameraBearings(sender=i, seq=k, stamp_s=t, targets=nb[:3],
                                     beta_body=[(0.6, 0.8, 0.0)] * len(nb[:3]))  # fmt: skip
                out.append((f"{pre}/camera/bearings", encode(cam), t))
    return out


def from_recording(path: Path) -> list[tuple[str, bytes, float]]:
    return [
        (r.topic, r.data, r.log_time_ns / 1e9)
        for r in iter_records(path)
        if r.source == Source.ZENOH
    ]


def write_msgpack(path: Path, samples: list[tuple[str, bytes, float]]) -> None:
    """The recorder of before: raw sample bytes, one schema-less channel per key."""
    with path.open("wb") as f:
        w = Writer(f, chunk_size=CHUNK_BYTES)
        w.start()
        channels: dict[str, int] = {}
        for key, data, t in samples:
            ch = channels.get(key)
            if ch is None:
                ch = channels[key] = w.register_channel(key, "msgpack", 0, {"source": "zenoh"})
            t_ns = int((T0 + t) * 1e9)
            w.add_message(ch, t_ns, data, t_ns, 0)
        w.finish()


def write_json(path: Path, samples: list[tuple[str, bytes, float]]) -> None:
    rec = Recorder(path, "alpha", tlog=False)
    for key, data, t in samples:
        rec.zenoh_sample(key, data, T0 + t)
    rec.close()


def best_of(fn, path: Path, samples, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(path, samples)
        times.append(time.perf_counter() - t0)
    return min(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--agents", type=int, default=6)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--from", dest="src", type=Path, default=None)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    samples = from_recording(args.src) if args.src else synthetic(args.agents, args.seconds)
    raw_bytes = sum(len(d) for _, d, _ in samples)
    print(f"{len(samples)} samples, {raw_bytes / 1e6:.2f} MB of wire bytes")
    with tempfile.TemporaryDirectory() as tmp:
        rows = []
        for name, fn in (("msgpack, no schema (before)", write_msgpack),
                         ("json + jsonschema + scene (now)", write_json)):  # fmt: skip
            path = Path(tmp) / f"{fn.__name__}.mcap"
            dt = best_of(fn, path, samples, args.repeats)
            rows.append((name, path.stat().st_size, dt))
        base_size, base_dt = rows[0][1], rows[0][2]
        span_s = max(t for _, _, t in samples) - min(t for _, _, t in samples)
        for name, size, dt in rows:
            print(
                f"{name:34s} {size / 1e6:7.2f} MB ({size / base_size:4.2f}x)  "
                f"{len(samples) / dt / 1e3:7.1f} k samples/s ({dt / base_dt:4.2f}x the time), "
                f"{100 * dt / span_s:5.1f}% of a core at the recorded rate"
            )


if __name__ == "__main__":
    main()
