"""What held in issue 23's campaign, measured again after the hardening (the issue's first line).

The issue opens with what did NOT break: "all 194,846 deliveries of 100,000 malformed Zenoh
samples were rejected and counted; 110,000 fuzzed MAVLink frames never crashed the simulator's
parser; [...] 30% packet loss for 60 s did not stop the flight; a gracefully stopped recorder
lost 0 of 9,864 samples". The fixes since must not have broken any of it. Parts (``--only``):

* ``malformed``: a flying team (``tests/e2e/conftest.py::running_fleet``: ``bearingflock sim``
  and three daemons as processes, real Zenoh and MAVLink; bench_poison's attacker view) gets
  100,000 malformed samples on its peer keys, at ``--rate`` per second: random bytes, cut
  payloads, msgpack that is not a payload, another schema version, a NaN or an infinity, a
  field of the wrong type, a missing field, an unknown payload type, an unknown sender, a
  payload on another sender's key, a key the fleet does not use (each a real captured payload
  of the team changed in one way; fresh sequence numbers and stamps, so the change is the only
  reason to drop it; each goes in a peer envelope of the key's vehicle, as the daemons send
  payloads since issue 27, so a malformation that breaks MessagePack breaks the envelope).
  Measured: what the receivers counted and dropped, by reason, against the
  deliveries there can be (each sample reaches the two other daemons), and whether the team kept
  flying (daemons alive, status gaps, formation size, distance error, fast flight).
* ``mavlink-fuzz``: a 2-vehicle simulator (``bench_sim_target.start_sim``) gets 110,000 fuzzed
  MAVLink 2 frames on vehicle 0's UDP port: frames of the messages a ground station sends
  (HEARTBEAT, COMMAND_LONG / COMMAND_INT with random commands and parameters, SET_MODE,
  SET_POSITION_TARGET_LOCAL_NED, PARAM_SET, PARAM_REQUEST_READ, REQUEST_DATA_STREAM,
  MANUAL_CONTROL, MISSION_COUNT, TIMESYNC) with random field values and a valid checksum, the
  same with 1-3 flipped bits, cut frames, random bytes, several frames in one datagram.
  Measured: the simulator alive, its heartbeats at the ground-station port before / during /
  after, its resident memory, its counters line.
* ``loss``: a flying team whose daemons drop 30% of the peer messages they receive
  (``[zenoh] inject_loss = 0.3``) for 60 s, while ``bearingflock gcs record`` records the fleet;
  the recorder is stopped with SIGTERM (a graceful stop, as Ctrl-C). Measured: the team's
  flight (as above) and the recorder's own counts against what its file reads back (``groundstation.gcs.record``).

Usage: ``python benchmarks/bench_held.py [--only malformed mavlink-fuzz loss] [--seed 0]
[--json FILE]``. The tree measured is the one this file is in (as bench_poison).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import random
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import msgspec

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
for _p in (str(HERE), str(ROOT)):
    if _p in sys.path:
        sys.path.remove(_p)
    sys.path.insert(0, _p)

import bench_poison as bp  # noqa: E402
import bench_sim_target as st  # noqa: E402

from messages.codec import SCHEMA_VERSION  # noqa: E402

ISSUE_MALFORMED = 100_000
ISSUE_FRAMES = 110_000
ISSUE_LOSS = 0.3
ISSUE_LOSS_S = 60.0
CODEC_REASONS = (
    "malformed", "version", "nonfinite", "unknown_sender", "sender_mismatch", "bad_key",
    "out_of_range", "oversize", "foreign",
)  # fmt: skip
"""Drop reasons a malformed sample can get (``messages.vocabulary.DropReason``); a clean
flight counts none of them."""


# ------------------------------------------------------------------------ malformed samples
def _floats(raw: Any, path: tuple = ()) -> list[tuple]:
    """Paths to every float in a decoded payload."""
    if isinstance(raw, float):
        return [path]
    if isinstance(raw, dict):
        return [p for k, v in raw.items() if k not in ("stamp_s",) for p in _floats(v, (*path, k))]
    if isinstance(raw, list):
        return [p for i, v in enumerate(raw) for p in _floats(v, (*path, i))]
    return []


def _set(raw: Any, path: tuple, value: Any) -> None:
    for k in path[:-1]:
        raw = raw[k]
    raw[path[-1]] = value


MalformFn = Callable[[random.Random, str, dict, bytes], tuple[str, bytes]]


def _retag(key: str, sender: int) -> str:
    parts = key.split("/")
    parts[2] = str(sender)
    return "/".join(parts)


def _key_sender(key: str) -> int:
    return int(key.split("/")[2])


def _enc(raw: dict) -> bytes:
    return msgspec.msgpack.encode(raw)


def m_random_bytes(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    return key, rng.randbytes(rng.randint(1, 256))


def m_cut(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    return key, data[: rng.randrange(1, len(data))]


def m_not_a_payload(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    return key, _enc(rng.choice([[1, 2, 3], "peer.motion", 42, None, {"type": 7}, list(raw)]))


def m_version(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    raw["version"] = rng.choice([SCHEMA_VERSION + 1, SCHEMA_VERSION - 1, 0, 999])
    return key, _enc(raw)


def m_nonfinite(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    paths = _floats(raw)
    if not paths:
        raw["stamp_s"] = math.nan
    else:
        _set(raw, rng.choice(paths), rng.choice([math.nan, math.inf, -math.inf]))
    return key, _enc(raw)


def m_wrong_type(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    field = rng.choice([k for k in raw if k not in ("type",)])
    raw[field] = rng.choice(["x", [], {"a": 1}, b"\x00"])
    return key, _enc(raw)


def m_missing(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    del raw[rng.choice([k for k in raw if k != "type"])]
    return key, _enc(raw)


def m_unknown_type(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    raw["type"] = rng.choice(["peer.bogus", "command.fly", "", "x" * 40])
    return key, _enc(raw)


def m_unknown_sender(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    s = rng.choice([bp.N + 1, 77, 65_535])
    raw["sender"] = s
    return _retag(key, s), _enc(raw)


def m_sender_mismatch(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    other = rng.choice([k for k in range(bp.N) if k != raw["sender"]])
    return _retag(key, other), _enc(raw)


def m_bad_key(rng: random.Random, key: str, raw: dict, data: bytes) -> tuple[str, bytes]:
    return key.rsplit("/", 1)[0] + "/" + rng.choice(["bogus", "motion2", "x"]), _enc(raw)


MALFORMATIONS: dict[str, MalformFn] = {
    f.__name__.removeprefix("m_"): f
    for f in (m_random_bytes, m_cut, m_not_a_payload, m_version, m_nonfinite, m_wrong_type,
              m_missing, m_unknown_type, m_unknown_sender, m_sender_mismatch, m_bad_key)
}  # fmt: skip


def _decodes(data: bytes) -> bool:
    """Whether the codec takes ``data`` as a peer payload."""
    from messages.codec import MessageError, decode
    from messages.peer import PeerPayload

    try:
        decode(data, PeerPayload)
    except MessageError:
        return False
    return True


KEY_LEVEL = frozenset({"sender_mismatch", "bad_key", "unknown_sender"})
"""Malformations of the key (a well-formed payload where it does not belong)."""


def _codec_drops(status: dict[int, Any]) -> dict[str, int]:
    tot = dict.fromkeys(CODEC_REASONS, 0)
    for s in status.values():
        for reason in CODEC_REASONS:
            tot[reason] += int(s.dropped.get(reason, 0))
    return tot


def _diff(after: dict[str, int], before: dict[str, int]) -> dict[str, int]:
    return {k: after[k] - before.get(k, 0) for k in after if after[k] - before.get(k, 0)}


@contextlib.contextmanager
def team_with(tag: str, loss: float = 0.0) -> Iterator[bp.Team]:
    """bench_poison's flying team, its daemons dropping ``loss`` of the peer messages."""
    from tests.e2e.conftest import running_fleet

    with tempfile.TemporaryDirectory(prefix=f"bench-held-{tag}-") as tmp:
        with running_fleet(Path(tmp), loss=loss) as (ev, procs, ports, _args, name):
            team = bp.Team(ev, procs, ports, name, Path(tmp))
            team.start()
            team.endpoints = {  # type: ignore[attr-defined]
                "zenoh": [f"tcp/127.0.0.1:{ports.zenoh + k}" for k in range(bp.N + 1)],
                "mavlink": [f"udp:127.0.0.1:{ports.gcs}"],  # where the simulator streams
            }
            try:
                t = team.wait_flying(120.0)
                print(f"  [{tag}] team flying after {t:.0f} s", flush=True)
                yield team
            finally:
                team.close()


def part_malformed(seed: int, count: int, rate: float, watch_s: float) -> dict[str, Any]:
    rng = random.Random(seed)
    with team_with("malformed") as team:
        base = bp.settle(team, quick=False)
        team.capture = True
        time.sleep(2.0)
        team.capture = False
        corpus = list(team.captured)  # (envelope key, one payload of it as a map)
        before = _codec_drops(team.ev.snapshot())
        kinds = dict.fromkeys(MALFORMATIONS, 0)
        names = list(MALFORMATIONS)
        valid = 0
        a = time.monotonic()
        n = 0
        while n < count:
            key, raw = rng.choice(corpus)
            raw = json.loads(json.dumps(raw))  # a deep copy of plain data
            raw["seq"] = int(raw["seq"]) + 10**9  # fresh, but never ahead of a real one's window
            raw["stamp_s"] = team.now_s()
            kind = names[n % len(names)]
            k, data = MALFORMATIONS[kind](rng, key, raw, _enc(raw))
            if kind not in KEY_LEVEL and _decodes(data):  # e.g. a missing field with a default
                valid += 1
                continue
            # in an envelope of the key's vehicle, as the daemons send them (messages.envelope)
            team.put(k, bp.envelope(_key_sender(k), [msgspec.Raw(data)]))
            kinds[kind] += 1
            n += 1
            delay = a + (n + 1) / rate - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        sent_s = time.monotonic() - a
        print(f"  [malformed] {count} samples sent in {sent_s:.1f} s", flush=True)
        time.sleep(watch_s)
        after = team.window(a, time.monotonic())
        counted = _diff(_codec_drops(team.ev.snapshot()), before)
        return {"baseline": base, "after": after, "samples": count, "sent_in_s": sent_s,
                "by_malformation": kinds, "skipped_valid": valid, "deliveries_possible": count * (bp.N - 1),
                "counted": counted, "counted_total": sum(counted.values()),
                "baseline_codec_drops": before, **team.state()}  # fmt: skip


# ------------------------------------------------------------------------ fuzzed MAVLink
def _frames(rng: random.Random) -> Callable[[], bytes]:
    """A maker of one fuzzed MAVLink 2 frame (module docstring)."""
    from pymavlink.dialects.v20 import common as mav2

    mav = mav2.MAVLink(None, srcSystem=255, srcComponent=190)

    def f() -> float:
        return rng.choice([0.0, 1.0, -1.0, rng.uniform(-1e4, 1e4), 1e38, -1e38, math.nan,
                           math.inf, rng.uniform(-10, 10)])  # fmt: skip

    def u(bits: int) -> int:
        return rng.randrange(1 << bits)

    def i(bits: int) -> int:
        return rng.randrange(-(1 << (bits - 1)), 1 << (bits - 1))

    cmds = [400, 22, 21, 176, 511, 512, 20, 16, 84, 178, 183, 241, 246, 300, 520, u(16)]
    makers = [
        lambda: mav2.MAVLink_heartbeat_message(u(8), u(8), u(8), u(32), u(8), u(8)),
        lambda: mav2.MAVLink_command_long_message(
            rng.choice([1, 0, u(8)]), u(8), rng.choice(cmds), u(8), *(f() for _ in range(7))),
        lambda: mav2.MAVLink_command_int_message(
            rng.choice([1, 0, u(8)]), u(8), u(8), rng.choice(cmds), u(8), u(8), f(), f(), f(),
            f(), i(32), i(32), f()),
        lambda: mav2.MAVLink_set_mode_message(rng.choice([1, u(8)]), u(8), u(32)),
        lambda: mav2.MAVLink_set_position_target_local_ned_message(
            u(32), rng.choice([1, u(8)]), u(8), u(8), u(16), *(f() for _ in range(11))),
        lambda: mav2.MAVLink_param_set_message(
            rng.choice([1, u(8)]), u(8),
            rng.choice([b"COM_OF_LOSS_T", b"MIS_TAKEOFF_ALT", b"GUID_TIMEOUT", rng.randbytes(16)]),
            f(), u(8)),
        lambda: mav2.MAVLink_param_request_read_message(
            rng.choice([1, u(8)]), u(8), rng.randbytes(16), i(16)),
        lambda: mav2.MAVLink_request_data_stream_message(
            rng.choice([1, u(8)]), u(8), u(8), u(16), u(8)),
        lambda: mav2.MAVLink_manual_control_message(
            rng.choice([1, u(8)]), i(16), i(16), i(16), i(16), u(16)),
        lambda: mav2.MAVLink_mission_count_message(rng.choice([1, u(8)]), u(8), u(16)),
        lambda: mav2.MAVLink_timesync_message(i(64), i(64)),
    ]  # fmt: skip

    def frame() -> bytes:
        data = rng.choice(makers)().pack(mav, force_mavlink1=False)
        r = rng.random()
        if r < 0.45:
            return data
        if r < 0.75:
            return bp._bitflip(rng, data, rng.randint(1, 3))
        if r < 0.9:
            return data[: rng.randrange(1, len(data))]
        return rng.randbytes(rng.randint(1, 280))

    return frame


def part_mavlink_fuzz(seed: int, count: int, rate: float, seconds: float) -> dict[str, Any]:
    rng = random.Random(seed)
    frame = _frames(rng)
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.05)
    proc, ports = st.start_sim(gcs.getsockname()[1])
    out: dict[str, Any] = {"frames": count}
    fuzzer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        time.sleep(1.0)
        out["rss_before_mb"] = st.rss_mb(proc.pid)
        st.drain(gcs)
        out["heartbeats_before_s"] = st.gcs_heartbeats(gcs, seconds)
        sent = datagrams = 0
        a = time.monotonic()
        while sent < count:
            k = 1 if rng.random() < 0.8 else rng.randint(2, 5)  # several frames in one datagram
            k = min(k, count - sent)
            with contextlib.suppress(OSError):  # a full socket buffer drops, as a network would
                fuzzer.sendto(b"".join(frame() for _ in range(k)), ("127.0.0.1", ports[0]))
            sent += k
            datagrams += 1
            if sent % 200 < k:
                delay = a + sent / rate - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                # the ground station's view while it goes on
                with contextlib.suppress(BlockingIOError, TimeoutError):
                    gcs.recv(65535)
        out["sent_in_s"] = time.monotonic() - a
        out["datagrams"] = datagrams
        out["alive_after_attack"] = proc.poll() is None
        st.drain(gcs)
        out["heartbeats_after_s"] = st.gcs_heartbeats(gcs, seconds)
        out["rss_after_mb"] = st.rss_mb(proc.pid) if proc.poll() is None else math.nan
        out["alive_at_end"] = proc.poll() is None
        print(f"  [mavlink-fuzz] {count} frames in {datagrams} datagrams, "
              f"{out['sent_in_s']:.1f} s", flush=True)  # fmt: skip
    finally:
        fuzzer.close()
        out["exit"] = proc.poll()
        out["last_line"] = st.stop_sim(proc) if proc.poll() is None else "(dead)"
        gcs.close()
    return out


# ------------------------------------------------------------------------- loss + recorder
def part_loss(loss: float, seconds: float) -> dict[str, Any]:
    from groundstation.gcs.record import read_recording

    with team_with("loss", loss=loss) as team, tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "loss.mcap"
        rec = subprocess.Popen(
            [sys.executable, "-m", "groundstation.cli", "gcs", "record", str(out), "--fleet",
             team.name, *(x for kind, eps in team.endpoints.items()  # type: ignore[attr-defined]
                          for e in eps for x in (f"--{kind}", e))],
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        assert rec.stdout is not None
        started = rec.stdout.readline()  # "recording fleet ...": its signal handler is set
        base = bp.settle(team, quick=False)
        a = time.monotonic()
        time.sleep(seconds)
        after = team.window(a, time.monotonic())
        rec.send_signal(signal.SIGTERM)
        text, _ = rec.communicate(timeout=30)
        text = started + text
        m = re.search(r"recorded (.*) to ", text)
        counts = dict(kv.split("=") for kv in m.group(1).split()) if m else {}
        recording = read_recording(out)
        return {"loss": loss, "baseline": base, "after": after, **team.state(),
                "recorder_exit": rec.returncode, "recorder_said": text.strip().splitlines()[-1:],
                "recorded": {k: int(v) for k, v in counts.items()},
                "read_back": len(recording.records), "complete": recording.complete,
                "unreadable": recording.unreadable}  # fmt: skip


# -------------------------------------------------------------------------------- report
def rows(r: dict[str, dict]) -> list[tuple[str, str, str]]:
    out = []
    if m := r.get("malformed"):
        w = m["after"]
        top = ", ".join(f"{v} `{k}`" for k, v in sorted(m["counted"].items(), key=lambda x: -x[1]))
        out.append((
            f"{m['samples']:,} malformed Zenoh samples ({len(m['by_malformation'])} kinds, "
            f"{m['samples'] / m['sent_in_s']:,.0f}/s)",
            "all 194,846 deliveries rejected and counted",
            f"{m['counted_total']:,} counted of at most {m['deliveries_possible']:,} deliveries "
            f"({top}); {bp._alive(m)}; {bp._gap(w)}; {bp._size(m)}; {bp._scale(w)}; "
            f"{bp._fast(w)}",
        ))  # fmt: skip
    if f := r.get("mavlink-fuzz"):
        out.append((
            f"{f['frames']:,} fuzzed MAVLink frames at a simulator vehicle "
            f"({f['datagrams']:,} datagrams, {f['sent_in_s']:.0f} s)",
            "never crashed the simulator's parser",
            f"simulator {'alive' if f['alive_at_end'] else 'DEAD'}; GCS heartbeats "
            f"{f['heartbeats_before_s']:.1f} -> {f['heartbeats_after_s']:.1f}/s; RSS "
            f"{f['rss_before_mb']:.0f} -> {f['rss_after_mb']:.0f} MB; its counters: "
            f"{f['last_line'].split('; ', 1)[-1]}",
        ))  # fmt: skip
    if lo := r.get("loss"):
        w = lo["after"]
        z = sum(lo["recorded"].values())
        out.append((
            f"{100 * lo['loss']:.0f}% peer-message loss for {w['seconds']:.0f} s",
            "did not stop the flight",
            f"{bp._alive(lo)}; phases {sorted(set(w['phases_end'].values()))}; {bp._gap(w)}; "
            f"{bp._size(lo)}; {bp._scale(w)}",
        ))  # fmt: skip
        out.append((
            "a recorder stopped with SIGTERM",
            "lost 0 of 9,864 samples",
            f"recorded {z:,} ({', '.join(f'{k}={v}' for k, v in lo['recorded'].items())}), read "
            f"back {lo['read_back']:,} ({'complete' if lo['complete'] else 'unfinished'} file, "
            f"{lo['unreadable']} unreadable); exit {lo['recorder_exit']}",
        ))  # fmt: skip
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parts = ("malformed", "mavlink-fuzz", "loss")
    parser.add_argument("--only", nargs="+", choices=parts, default=None)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rate", type=float, default=2000.0, help="malformed samples per s")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    bp.run_this_tree()
    run = {
        "malformed": lambda: part_malformed(args.seed, ISSUE_MALFORMED, args.rate, 10.0),
        "mavlink-fuzz": lambda: part_mavlink_fuzz(args.seed, ISSUE_FRAMES, 10_000.0, 5.0),
        "loss": lambda: part_loss(ISSUE_LOSS, ISSUE_LOSS_S),
    }
    results: dict[str, dict] = {}
    for name in args.only or parts:
        print(f"{name} ...", flush=True)
        t0 = time.monotonic()
        try:
            results[name] = run[name]()
        except Exception as exc:  # one part's failure is reported, the others still run
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
            print(f"  {name} failed: {results[name]['error']}", flush=True)
        print(f"  {name} done in {time.monotonic() - t0:.0f} s", flush=True)
    ok = {k: v for k, v in results.items() if "error" not in v}
    print("\n| what held (issue 23's first line) | issue | measured |\n| --- | --- | --- |")
    for a, b, c in rows(ok):
        print(f"| {a} | {b} | {c} |")
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=str))
    return 1 if len(ok) < len(results) else 0


if __name__ == "__main__":
    raise SystemExit(main())
