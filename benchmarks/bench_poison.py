"""Issue 23's attacks on a flying team, measured the way the issue measured its "before".

Every team attack starts its own real team: ``bearingflock sim`` and three daemons as
processes on loopback, real Zenoh, real MAVLink (``tests/e2e/conftest.py::running_fleet``,
the fixture of ``tests/e2e/test_poison.py``). The bench joins the fleet's Zenoh as an
attacker who holds a vehicle's key (a compromised or faulty sender: the payloads are well
formed), watches every daemon's status and the simulator's truth, and prints the issue's
numbers next to the ones measured here.

Attacks (``--only``; default all):

* ``d1-poison``: ONE ``MotionShare`` with ``v_body = 1e300`` and ONE ``LocalizationState`` with
  ``p_hat = 1e300`` from vehicle 1. Measured: daemons alive, the longest gap between two
  statuses of a daemon, the formation's size (mean true inter-vehicle distance, from the
  simulator's truth topic) at the attack and at the end, non-finite estimates.
* ``d1-bitflip``: 1,495 codec-accepted bit-flip mutations of the team's own peer payloads
  (captured, re-stamped and re-numbered as their sender would, 1-3 random bits flipped, kept
  only if ``messages.codec.decode`` accepts them), sent within 2 s under their senders' keys.
  Same measurements. The corpus is captured live, so a seed does not repeat a round exactly.
  Mechanisms of lasting damage found (fixed: a neighbour's estimate that jumps waits for its
  sender's next sample to confirm it, ``implausible_jump``, onboard/core/peers.py JumpGate): a
  flipped ``e_index`` consensus state; a flipped localization yaw; a flipped ``p_bar``
  integral state (the barycenter far away) plus a small ``E`` kick, whose fast rotation
  corrected the SfM distances by more than ``wander_max`` and reopened the active rotation.
* ``d2``: ONE sample of each peer kind vehicle 2 publishes, and ONE camera frame of vehicle
  0, stamped now + 1e6 s. Measured: the formation's size and the largest vehicle displacement
  over the watch (issue: drifting apart 8 -> 36 m in 30 s), whether ``bearings_stale`` fired,
  the future stamps counted.
* ``d4``: 20 ``ConsensusState`` payloads of 45,000 names and one ``ExcitationTable`` of 20,000
  fake edges (the issue's), then the same volume in payloads the codec accepts (220 x 4,096
  new names, 5 x 4,000 fake edges), from vehicle 1. Measured: each daemon's RSS, its core
  rate (peer payloads it publishes per second: one batch every two core ticks, so 50/s means
  the 100 Hz core and its setpoints kept up), then SIGTERM-to-exit time of every daemon.
* ``d7``: the simulator as a target (``benchmarks/bench_sim_target.py``'s attacks): 60,000
  spoofed source addresses (simulator RSS) and 1,000 spoofed ground stations sending a
  HEARTBEAT a second (simulator CPU, HEARTBEAT rate at the real ground station), on the
  bench's 2-vehicle simulator (each in a fresh simulator).
* ``d7-team``: the same two attacks on a flying team's simulator, aimed at vehicle 0's port:
  simulator RSS and CPU, and whether the team keeps flying and reporting.
* ``d12``: the issue's failing bad configuration / CLI cases (``tests/test_bad_input.py``'s
  list and ``tests/e2e/test_bad_input_processes.py``'s, plus ``demo --headless --out``) as
  real ``bearingflock`` processes: clean one-line errors, tracebacks, never exits, silently
  accepted. The issue's other 66 cases are not in the repository.

Usage: ``python benchmarks/bench_poison.py [--only d1-poison d4 ...] [--quick] [--json FILE]``
(``--quick``: 10 s watches, 20,000 sources, 300 spoofers; the attacks themselves unchanged).
The tree measured is the one this file is in (it goes first on ``sys.path`` and
``PYTHONPATH``). The machine is shared: CPU numbers are against a baseline of the same run.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime
import itertools
import json
import math
import os
import random
import re
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HERE = Path(__file__).resolve().parent
for _p in (str(HERE), str(ROOT)):  # this tree's packages and tests/, then the sibling benches
    if _p in sys.path:
        sys.path.remove(_p)
    sys.path.insert(0, _p)

from messages.codec import SCHEMA_VERSION, MessageError, decode  # noqa: E402
from messages.peer import PeerPayload  # noqa: E402
from onboard.core.config import ScaleGains  # noqa: E402

N = 3
ISSUE_BITFLIPS = 1495
ISSUE_NAMES = 45_000
ISSUE_NAME_PAYLOADS = 20
ISSUE_EDGES = 20_000
LIST_MAX = 4096  # messages.limits.LIST_MAX (checked in main)
FAST = 1.5
"""m/s: a vehicle faster than this is near the daemons' 2 m/s limit (the demo's formation
flies at a few tenths of a m/s)."""
BITFLIP_SEEDS = (23, 24, 25)


class _Envelope(msgspec.Struct):
    """A peer envelope's sender and its payloads as plain maps (the rest is ignored)."""

    sender: int
    payloads: list[Any]


_envelope = msgspec.msgpack.Decoder(_Envelope)


def envelope(sender: int, payloads: list[Any]) -> bytes:
    """Peer payloads (plain maps, or ``msgspec.Raw`` bytes) in an envelope on the wire, as a
    compromised ``sender`` puts it (:mod:`messages.envelope`: one per publish tick)."""
    return msgspec.msgpack.encode(
        {"type": "peer.envelope", "version": SCHEMA_VERSION, "sender": sender, "seq": 0,
         "stamp_s": 0.0, "payloads": payloads}
    )  # fmt: skip


# ------------------------------------------------------------------------------------ team
@dataclass
class Row:
    """One look at the team (every 0.1 s)."""

    mono: float
    stamps: dict[int, float]
    p_ned: np.ndarray | None
    phases: dict[int, str]
    finite: dict[int, bool]
    converged: dict[int, bool]
    scale_error: float
    """The largest ``|1/chihat - d| / d`` over every daemon's distance estimates (NaN: none)."""
    speed_m_s: float
    """The fastest vehicle's true speed (NaN: no truth yet)."""


@dataclass
class Team:
    """A flying team (``running_fleet``'s) with the attacker's view of it."""

    ev: Any
    procs: Any
    ports: Any
    name: str
    log_dir: Path
    rows: list[Row] = field(default_factory=list)
    peer_times: dict[int, deque] = field(default_factory=dict)
    """Wall arrival times of each sender's ``MotionShare`` (one per publish period: 50/s from
    a 100 Hz core that keeps up)."""
    seq_seen: dict[int, deque] = field(default_factory=dict)
    """(mono, seq) of each sender's recent peer payloads."""
    captured: deque = field(default_factory=lambda: deque(maxlen=3000))
    capture: bool = False
    last_seq: dict[int, int] = field(default_factory=dict)
    _mine: set[int] = field(default_factory=set)
    """Hashes of the payloads this attacker put: its own subscriber hears them too, and they
    must count neither as the team's traffic nor for its sequence numbers."""
    _lock: threading.Lock = field(default_factory=threading.Lock)
    _stop: threading.Event = field(default_factory=threading.Event)

    def start(self) -> None:
        self._sub = self.ev.session.declare_subscriber(f"bf/{self.name}/*/peer", self._on_peer)
        self._thread = threading.Thread(target=self._watch, daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        with contextlib.suppress(Exception):
            self._sub.undeclare()

    def _on_peer(self, sample: Any) -> None:
        """One peer envelope (messages.envelope): its payloads' numbers and, when capturing,
        the payloads themselves (as plain maps, with the envelope key they came on)."""
        data = sample.payload.to_bytes()
        with self._lock:
            if hash(data) in self._mine:
                self._mine.discard(hash(data))
                return
        try:
            env = _envelope.decode(data)
        except msgspec.DecodeError:
            return
        now = time.monotonic()
        key = str(sample.key_expr)
        with self._lock:
            for raw in env.payloads:
                if not isinstance(raw, dict) or not isinstance(raw.get("seq"), int):
                    continue
                if raw.get("type") == "peer.motion":  # one per publish period
                    self.peer_times.setdefault(env.sender, deque(maxlen=20000)).append(now)
                self.seq_seen.setdefault(env.sender, deque(maxlen=400)).append((now, raw["seq"]))
                if self.capture:
                    self.captured.append((key, raw))

    def _watch(self) -> None:
        while not self._stop.wait(0.1):
            st = self.ev.snapshot()
            with self.ev._lock:
                truth = dict(self.ev.truth)
            p = (
                np.array([truth[k].p_ned for k in range(N)])
                if all(k in truth for k in range(N))
                else None
            )
            self.rows.append(
                Row(
                    time.monotonic(),
                    {k: s.stamp_s for k, s in st.items()},
                    p,
                    {k: str(getattr(s.phase, "value", s.phase)) for k, s in st.items()},
                    {k: all(map(math.isfinite, s.agent.p_hat_ned)) for k, s in st.items()},
                    {k: bool(s.agent.scale_converged) for k, s in st.items()},
                    scale_error(st, p),
                    max(
                        (float(np.linalg.norm(tr.v_ned)) for tr in truth.values()),
                        default=math.nan,
                    ),
                )
            )

    # ------------------------------------------------------------------ the attacker's tools
    def now_s(self) -> float:
        """The team's simulation time (the newest truth stamp)."""
        with self.ev._lock:
            return max(tr.stamp_s for tr in self.ev.truth.values())

    def seq(self, sender: int, ahead_s: float = 0.3) -> int:
        """A sequence number ``sender``'s receivers take as new: its core's step number
        extrapolated to now (from the rate seen on the wire) plus ``ahead_s`` of steps, and
        above any number this attacker used before (a compromised sender knows its own)."""
        with self._lock:
            seen = list(self.seq_seen.get(sender, ()))
        now = time.monotonic()
        if len(seen) >= 2 and seen[-1][0] > seen[0][0]:
            rate = (seen[-1][1] - seen[0][1]) / (seen[-1][0] - seen[0][0])
        else:
            rate = 100.0
        est = seen[-1][1] + rate * (now - seen[-1][0]) if seen else 0.0
        q = max(self.last_seq.get(sender, -1) + 1, int(est + rate * ahead_s))
        self.last_seq[sender] = q
        return q

    def raw(self, tag: str, sender: int, stamp_s: float, **fields: Any) -> bytes:
        """A payload as a compromised sender puts it on the wire (no checks on encode); a peer
        payload in an envelope of its own (:func:`envelope`)."""
        body = {"type": tag, "version": SCHEMA_VERSION, "sender": sender, "seq": self.seq(sender),
                "stamp_s": stamp_s, **fields}  # fmt: skip
        return envelope(sender, [body]) if tag.startswith("peer.") else msgspec.msgpack.encode(body)

    def put(self, key: str, data: bytes) -> None:
        with self._lock:
            self._mine.add(hash(data))
        self.ev.session.put(key, data)

    def peer_key(self, sender: int) -> str:
        """Where ``sender``'s peer envelopes go (every kind)."""
        return f"bf/{self.name}/{sender}/peer"

    # ------------------------------------------------------------------ what is measured
    def wait_flying(self, timeout_s: float) -> float:
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            st = self.ev.snapshot()
            if len(st) == N and all(s.phase == "flying" and s.in_air for s in st.values()):
                return time.monotonic() - t0
            time.sleep(0.2)
        st = {k: (s.phase, s.alarms) for k, s in self.ev.snapshot().items()}
        raise RuntimeError(f"the team did not take off in {timeout_s:.0f} s: {st}")

    def wait_converged(self, timeout_s: float) -> float | None:
        """Until every daemon reports ``scale_converged`` (the issue's team was converged)."""
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout_s:
            st = self.ev.snapshot()
            if len(st) == N and all(s.agent.scale_converged for s in st.values()):
                return time.monotonic() - t0
            time.sleep(0.2)
        return None

    def agent_pids(self) -> dict[int, int]:
        return {int(n.removeprefix("agent")): p.pid for n, p in self.procs.procs if "agent" in n}

    def sim_pid(self) -> int:
        return next(p.pid for n, p in self.procs.procs if n == "sim")

    def window(self, a: float, b: float) -> dict[str, Any]:
        """What the team did between wall times ``a`` and ``b``."""
        rows = [r for r in self.rows if a <= r.mono <= b]
        gaps = {}
        for k in range(N):
            heard, last = [a], -math.inf
            for r in rows:
                s = r.stamps.get(k, -math.inf)
                if s > last:
                    if last > -math.inf:
                        heard.append(r.mono)
                    last = s
            heard.append(b)
            gaps[k] = float(max(np.diff(heard)))
        sizes = [(r.mono, formation_size_m(r.p_ned)) for r in rows if r.p_ned is not None]
        p = [r.p_ned for r in rows if r.p_ned is not None]
        drift = float(max(np.linalg.norm(x - p[0], axis=1).max() for x in p)) if p else math.nan
        with self._lock:
            rates = {k: sum(a <= t <= b for t in ts) / (b - a) for k, ts in self.peer_times.items()}
        return {
            "seconds": b - a,
            "longest_status_gap_s": gaps,
            "formation_m_start": sizes[0][1] if sizes else None,
            "formation_m_end": sizes[-1][1] if sizes else None,
            "formation_m_min": min(s for _, s in sizes) if sizes else None,
            "formation_m_max": max(s for _, s in sizes) if sizes else None,
            "largest_displacement_m": drift,
            "nonfinite_estimates": sorted({k for r in rows for k, f in r.finite.items() if not f}),
            "phases_end": rows[-1].phases if rows else {},
            "scale_converged_end": rows[-1].converged if rows else {},
            "scale_error_end": rows[-1].scale_error if rows else None,
            "fast_last_s": max((r.mono - a for r in rows if r.speed_m_s > FAST), default=None),
            "speed_max_m_s": max(
                (r.speed_m_s for r in rows if r.speed_m_s == r.speed_m_s), default=None
            ),
            "fast_s": float(
                sum(r1.mono - r0.mono for r0, r1 in itertools.pairwise(rows) if r0.speed_m_s > FAST)
            ),
            "scale_error_over_5pct_s": float(
                sum(
                    r1.mono - r0.mono
                    for r0, r1 in itertools.pairwise(rows)
                    if r0.scale_error > 0.05
                )
            ),
            "scale_error_last_over_5pct_s": max(
                (r.mono - a for r in rows if r.scale_error > 0.05), default=None
            ),
            "scale_error_max": max(
                (r.scale_error for r in rows if r.scale_error == r.scale_error), default=None
            ),
            "motion_per_s": rates,
        }

    def state(self) -> dict[str, Any]:
        st = self.ev.snapshot()
        dead = self.procs.dead()
        return {
            "dead": dead,
            "dead_exit_codes": {n: p.returncode for n, p in self.procs.procs if n in dead},
            "dead_log_tails": {n: self.log_tail(n) for n in dead},
            "dropped": {k: dict(s.dropped) for k, s in sorted(st.items())},
            "alarms_seen": {a: sorted(ids) for a, ids in sorted(self.ev.alarms_seen.items())},
        }

    def log_tail(self, name: str, lines: int = 40) -> list[str]:
        path = self.log_dir / f"{name}.log"
        text = path.read_text(errors="replace") if path.exists() else ""
        return text.splitlines()[-lines:]

    def sigterm_daemons(self, timeout_s: float = 30.0) -> dict[int, float | None]:
        """SIGTERM every daemon at once: seconds until each exited (None: not in time)."""
        procs = {int(n.removeprefix("agent")): p for n, p in self.procs.procs if "agent" in n}
        t0 = time.monotonic()
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        took: dict[int, float | None] = dict.fromkeys(procs)
        while time.monotonic() - t0 < timeout_s and any(v is None for v in took.values()):
            for k, p in procs.items():
                if took[k] is None and p.poll() is not None:
                    took[k] = time.monotonic() - t0
            time.sleep(0.02)
        return took

    def daemon_metrics(self) -> dict[int, dict]:
        """The ``metrics {...}`` line each daemon logs on exit (onboard/daemon/metrics.py)."""
        out = {}
        for k in range(N):
            path = self.log_dir / f"agent{k}.log"
            found = re.findall(r"metrics (\{.*\})", path.read_text(errors="replace"))
            if found:
                out[k] = json.loads(found[-1])
        return out


def scale_error(status: dict[int, Any], p: np.ndarray | None) -> float:
    """The largest relative error of the distances the daemons use (``1/chihat``, their own
    or received, when ``chihat`` is at least the default ``chi_min_inv_m``: below it no layer
    takes it as a distance, ``onboard/core/scale.py``) against the truth."""
    if p is None:
        return math.nan
    chi_min = ScaleGains().chi_min_inv_m
    errs = [
        abs(1.0 / chi - d) / d
        for i, s in status.items()
        for j, chi in s.agent.chi_hat_inv_m.items()
        if chi >= chi_min and 0 <= j < len(p) and (d := float(np.linalg.norm(p[j] - p[i]))) > 0
    ]
    return max(errs) if errs else math.nan


def formation_size_m(p: np.ndarray | None) -> float:
    """The formation's size: the mean distance between two vehicles (m)."""
    if p is None:
        return math.nan
    d = [np.linalg.norm(p[i] - p[j]) for i in range(len(p)) for j in range(i + 1, len(p))]
    return float(np.mean(d))


@contextlib.contextmanager
def flying_team(tag: str) -> Iterator[Team]:
    """A fresh flying team (``running_fleet``, logs in a temporary directory)."""
    from tests.e2e.conftest import running_fleet

    with tempfile.TemporaryDirectory(prefix=f"bench-poison-{tag}-") as tmp:
        with running_fleet(Path(tmp)) as (ev, procs, ports, _args, name):
            team = Team(ev, procs, ports, name, Path(tmp))
            team.start()
            try:
                t = team.wait_flying(120.0)
                print(f"  [{tag}] team flying after {t:.0f} s", flush=True)
                yield team
            finally:
                team.close()


def rss_mb(pid: int) -> float:
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return math.nan


def sample_rss(pids: dict[int, int], seconds: float, every_s: float = 0.25) -> dict[int, float]:
    """The largest VmRSS (MB) of each process over ``seconds``."""
    peak = dict.fromkeys(pids, 0.0)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for k, pid in pids.items():
            with contextlib.suppress(OSError):
                peak[k] = max(peak[k], rss_mb(pid))
        time.sleep(every_s)
    return peak


def settle(team: Team, quick: bool) -> dict[str, Any]:
    """Wait for the scale to converge (at most 40 s; the issue's team was converged), then
    a baseline window of 5 s (3 s quick)."""
    conv = team.wait_converged(20.0 if quick else 40.0)
    a = time.monotonic()
    time.sleep(3.0 if quick else 5.0)
    base = team.window(a, time.monotonic())
    base["scale_converged_after_s"] = conv
    return base


# ------------------------------------------------------------------------------- attacks
def attack_d1_poison(quick: bool) -> dict[str, Any]:
    watch = 10.0 if quick else 30.0
    with flying_team("d1-poison") as team:
        base = settle(team, quick)
        t = team.now_s()
        motion = {"yaw_rate_rad_s": 0.0, "yaw_rad": 0.0}
        team.put(
            team.peer_key(1),
            team.raw("peer.motion", 1, t, v_body=[1e300, 0.0, 0.0], **motion),
        )
        team.put(team.peer_key(1),
                 team.raw("peer.localization", 1, t, p_hat_ned=[1e300, 0.0, 0.0],
                          yaw_hat_rad=0.0))  # fmt: skip
        a = time.monotonic()
        time.sleep(watch)
        after = team.window(a, time.monotonic())
        return {"baseline": base, "after": after, **team.state()}


def _bitflip(rng: random.Random, data: bytes, bits: int) -> bytes:
    b = bytearray(data)
    for _ in range(bits):
        i = rng.randrange(len(b) * 8)
        b[i // 8] ^= 1 << (i % 8)
    return bytes(b)


def attack_d1_bitflip(
    quick: bool,
    count: int = ISSUE_BITFLIPS,
    spread_s: float = 2.0,
    kinds_only: frozenset[str] | None = None,
    seed: int = 23,
    watch_s: float | None = None,
) -> dict:
    """``kinds_only``: mutate only these payload tags (``peer.motion``, ...)."""
    watch = watch_s if watch_s is not None else 10.0 if quick else 30.0
    rng = random.Random(seed)
    with flying_team("d1-bitflip") as team:
        base = settle(team, quick)
        team.capture = True
        time.sleep(2.0)
        team.capture = False
        corpus = list(team.captured)
        if kinds_only is not None:
            corpus = [(k, raw) for k, raw in corpus if raw.get("type") in kinds_only]
        t_mono, t_sim = time.monotonic(), team.now_s()
        tried = accepted = 0
        kinds: dict[str, int] = {}
        a = time.monotonic()
        while accepted < count and time.monotonic() - a < 10 * spread_s:
            k, raw = rng.choice(corpus)
            raw = dict(raw)
            raw["seq"] = team.seq(int(raw["sender"]))
            raw["stamp_s"] = t_sim + (time.monotonic() - t_mono)
            data = _bitflip(rng, msgspec.msgpack.encode(raw), rng.randint(1, 3))
            tried += 1
            try:
                decode(data, PeerPayload)
            except MessageError:
                team.last_seq[int(raw["sender"])] -= 1  # that number was not used
                continue
            team.put(k, envelope(int(raw["sender"]), [msgspec.Raw(data)]))
            accepted += 1
            kinds[raw["type"]] = kinds.get(raw["type"], 0) + 1
            delay = a + accepted * spread_s / count - time.monotonic()
            if delay > 0:
                time.sleep(delay)
        sent_s = time.monotonic() - a
        print(f"  [d1-bitflip] {accepted} accepted of {tried} mutations, sent in {sent_s:.1f} s",
              flush=True)  # fmt: skip
        time.sleep(watch)
        after = team.window(a, time.monotonic())
        return {"baseline": base, "after": after, "mutations_tried": tried,
                "mutations_sent": accepted, "sent_in_s": sent_s, "by_kind": kinds,
                **team.state()}  # fmt: skip


def attack_d2(quick: bool) -> dict[str, Any]:
    watch = 10.0 if quick else 30.0
    with flying_team("d2") as team:
        base = settle(team, quick)
        team.capture = True
        time.sleep(1.0)
        team.capture = False
        newest: dict[str, tuple[str, dict]] = {}
        for k, raw in team.captured:
            if raw.get("sender") == 2:
                newest[raw["type"]] = (k, raw)
        future = team.now_s() + 1e6
        for k, raw in newest.values():
            raw = dict(raw, seq=team.seq(2), stamp_s=future)
            if raw["type"] == "peer.excitation":
                raw["entries"] = [[*e[:3], future] for e in raw["entries"]]
            team.put(k, envelope(2, [raw]))
        team.put(f"bf/{team.name}/0/camera/bearings",
                 team.raw("camera_bearings", 0, future, targets=[1],
                          beta_body=[[1.0, 0.0, 0.0]]))  # fmt: skip
        a = time.monotonic()
        time.sleep(watch)
        after = team.window(a, time.monotonic())
        return {"baseline": base, "after": after, "future_kinds": sorted(newest),
                **team.state()}  # fmt: skip


def attack_d4(quick: bool) -> dict[str, Any]:
    after_s = 10.0 if quick else 20.0
    per = LIST_MAX
    accepted = math.ceil(ISSUE_NAME_PAYLOADS * ISSUE_NAMES / per)  # the same number of names
    # built before the attack, so that the sending is not paced by this script's Python
    issue_names = [[[f"x{m}_{k}", [0.0], []] for k in range(ISSUE_NAMES)]
                   for m in range(ISSUE_NAME_PAYLOADS)]  # fmt: skip
    names = [[[f"y{m}_{k}", [0.0], []] for k in range(per)] for m in range(accepted)]
    with flying_team("d4") as team:
        pids = team.agent_pids()
        base = settle(team, quick)
        rss0 = {k: rss_mb(p) for k, p in pids.items()}
        t_mono, t_sim = time.monotonic(), team.now_s()

        def now() -> float:
            return t_sim + time.monotonic() - t_mono

        peak: dict[int, float] = {}
        stop = threading.Event()

        def watch_rss() -> None:
            while not stop.is_set():
                for k, v in sample_rss(pids, 0.5).items():
                    peak[k] = max(peak.get(k, 0.0), v)

        watcher = threading.Thread(target=watch_rss, daemon=True)
        watcher.start()
        ck = ek = team.peer_key(1)

        def issue() -> None:  # 20 x 45,000 names, one table of 20,000 fake edges
            for states in issue_names:
                team.put(ck, team.raw("peer.consensus", 1, now(), states=states))
            edges = [[100 + k // 200, 400 + k % 200, 1.0, now()] for k in range(ISSUE_EDGES)]
            team.put(ek, team.raw("peer.excitation", 1, now(), entries=edges))

        def codec_sized(half: int) -> Callable[[], None]:
            def send() -> None:  # half of the names in LIST_MAX payloads, 2-3 x 4,000 edges
                for states in names[half::2]:
                    team.put(ck, team.raw("peer.consensus", 1, now(), states=states))
                    time.sleep(0.01)
                for m in range(half, 5, 2):
                    edges = [[100 + m, 1000 + k, 1.0, now()] for k in range(4000)]
                    team.put(ek, team.raw("peer.excitation", 1, now(), entries=edges))

            return send

        phases = {}
        a = time.monotonic()
        for label, send in (("issue's payloads", issue), ("codec-sized, 1st half", codec_sized(0)),
                            ("codec-sized, 2nd half", codec_sized(1))):  # fmt: skip
            t0 = time.monotonic()
            send()
            sent_s = time.monotonic() - t0
            time.sleep(3.0)
            phases[label] = {"sent_in_s": sent_s, "rss_mb": {k: rss_mb(p) for k, p in pids.items()},
                             **team.window(t0, time.monotonic())}  # fmt: skip
            print(f"  [d4] {label}: sent in {sent_s:.1f} s, RSS {phases[label]['rss_mb']}, "
                  f"MotionShare/s {phases[label]['motion_per_s']}", flush=True)  # fmt: skip
        time.sleep(after_s)
        stop.set()
        watcher.join(2.0)
        after = team.window(a, time.monotonic())
        rss1 = {k: rss_mb(p) for k, p in pids.items()}
        state = team.state()
        took = team.sigterm_daemons()
        return {"baseline": base, "phases": phases, "after": after, "rss_before_mb": rss0,
                "rss_peak_mb": peak, "rss_after_mb": rss1,
                "consensus_payloads_accepted_size": accepted, "sigterm_to_exit_s": took,
                "daemon_metrics": team.daemon_metrics(), **state}  # fmt: skip


def attack_d7(quick: bool) -> dict[str, Any]:
    import bench_sim_target as bst

    sources, spoofers, seconds = (20000, 300, 3.0) if quick else (60000, 1000, 5.0)
    bst.raise_file_limit(spoofers)
    out: dict[str, Any] = {}
    held, parsers = bst.codec_memory_mb(sources)
    out["codec"] = {"sources": sources, "parsers": parsers, "held_mb": held}
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.05)
    try:
        for phase in ("memory", "cpu"):  # each in a fresh simulator (no 30 s peer expiry)
            proc, ports = bst.start_sim(gcs.getsockname()[1])
            try:
                time.sleep(1.0)
                if phase == "memory":
                    out["memory"] = bst.memory_attack(proc.pid, ports[0], sources)
                else:
                    out["cpu"] = bst.cpu_attack(proc.pid, ports[0], gcs, spoofers, seconds)
                out[f"{phase}_alive"] = proc.poll() is None
            finally:
                out[f"{phase}_sim_last_line"] = bst.stop_sim(proc)
    finally:
        gcs.close()
    return out


def attack_d7_team(quick: bool) -> dict[str, Any]:
    import bench_sim_target as bst

    sources, spoofers, seconds = (20000, 300, 3.0) if quick else (60000, 1000, 5.0)
    bst.raise_file_limit(spoofers)
    with flying_team("d7-team") as team:
        text = (team.log_dir / "sim.log").read_text()
        port = int(re.search(r"vehicle 0 .*udp 127\.0\.0\.1:(\d+)", text).group(1))
        gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        gcs.bind(("127.0.0.1", team.ports.gcs))
        gcs.settimeout(0.05)
        pid = team.sim_pid()
        try:
            a = time.monotonic()
            mem = bst.memory_attack(pid, port, sources)
            cpu = bst.cpu_attack(pid, port, gcs, spoofers, seconds)
            after = team.window(a, time.monotonic())
        finally:
            gcs.close()
        return {"memory": mem, "cpu": cpu, "after": after, **team.state()}


# ------------------------------------------------------------------------- defect 12
@dataclass
class BadCase:
    name: str
    args: Callable[[Path], list[str]]
    hold: str | None = None
    """``"tcp"``/``"udp"``: a port held by the bench, given to ``args`` as ``tmp / str(port)``."""
    timeout_s: float = 30.0


def _bad_cases() -> list[BadCase]:
    from sim.server import free_port_base
    from tests.test_bad_input import IN_PROCESS, fleet_file

    cases = [BadCase(c.name, c.args) for c in IN_PROCESS]

    def agent_zenoh(tmp: Path) -> list[str]:
        port = int(tmp.name.rsplit("-", 1)[1])  # the agent 0 listens on port_base + 1
        return ["agent", "--id", "0", "--config", str(fleet_file(tmp, "", zenoh_base=port - 1))]

    def sim_zenoh(tmp: Path) -> list[str]:
        port = int(tmp.name.rsplit("-", 1)[1])
        return ["sim", "--quiet", "--vehicles", "1", "--port-base", str(free_port_base(1)),
                "--bind-base", "0", "--gcs-port", "0", "--zenoh", f"tcp/127.0.0.1:{port}"]  # fmt: skip

    def udpin(tmp: Path) -> list[str]:
        port = int(tmp.name.rsplit("-", 1)[1])
        body = f'[mavlink]\nurl = "udpin:127.0.0.1:{port}"'
        path = fleet_file(tmp, body, zenoh_base=free_port_base(4))
        return ["agent", "--id", "0", "--config", str(path)]

    cases += [
        BadCase("agent's Zenoh port in use", agent_zenoh, "tcp"),
        BadCase("simulator's Zenoh port in use", sim_zenoh, "tcp"),
        BadCase("MAVLink udpin port in use", udpin, "udp", timeout_s=40.0),
    ]
    return cases


def _run_case(case: BadCase) -> dict[str, Any]:
    held = None
    if case.hold:
        held = socket.socket(
            socket.AF_INET, socket.SOCK_STREAM if case.hold == "tcp" else socket.SOCK_DGRAM
        )
        held.bind(("127.0.0.1", 0))
        if case.hold == "tcp":
            held.listen()
    with tempfile.TemporaryDirectory() as root:
        tmp = Path(root) / f"case-{held.getsockname()[1] if held else 0}"
        tmp.mkdir()
        try:
            args = case.args(tmp)
            t0 = time.monotonic()
            try:
                res = subprocess.run(
                    [sys.executable, "-m", "groundstation.cli", *args], capture_output=True,
                    text=True, timeout=case.timeout_s, cwd=tmp,
                )  # fmt: skip
            except subprocess.TimeoutExpired:
                return {"case": case.name, "outcome": "never exits", "seconds": case.timeout_s}
            took = time.monotonic() - t0
        finally:
            if held is not None:
                held.close()
    out = (res.stdout + res.stderr).strip()
    errors = [ln for ln in out.splitlines() if ln.startswith("error")]
    last = out.splitlines()[-1] if out else ""
    if res.returncode == 0:
        outcome = "silently accepted"
    elif not last.startswith("error"):
        outcome = "traceback" if "Traceback" in out else "no error line"
    elif "Traceback" in out:
        outcome = "error line after a logged traceback"
    else:
        outcome = "clean error" if len(errors) == 1 else f"{len(errors)} error lines"
    return {"case": case.name, "outcome": outcome, "exit": res.returncode, "seconds": took,
            "last_line": last[:160], "traceback_before_error": "Traceback" in out}  # fmt: skip


def attack_d12(quick: bool) -> dict[str, Any]:
    results = [_run_case(c) for c in _bad_cases()]
    with tempfile.TemporaryDirectory() as root:  # demo --headless --out DIR wrote nothing
        out = Path(root) / "demo"
        subprocess.run(
            [sys.executable, "-m", "groundstation.cli", "demo", "--headless", "--vehicles", "4",
             "--duration", "2", "--out", str(out)], capture_output=True, timeout=120,
        )  # fmt: skip
        wrote = (out / "summary.json").is_file()
        results.append({"case": "demo --headless --out DIR", "seconds": None,
                        "outcome": "clean (summary.json written)" if wrote else "writes nothing"})  # fmt: skip
    counts: dict[str, int] = {}
    for r in results:
        counts[r["outcome"]] = counts.get(r["outcome"], 0) + 1
    return {"cases": results, "counts": counts}


ATTACKS: dict[str, Callable[[bool], dict[str, Any]]] = {
    "d1-poison": attack_d1_poison,
    "d1-bitflip": lambda quick: {
        "rounds": [attack_d1_bitflip(quick, seed=sd) for sd in BITFLIP_SEEDS[: 1 if quick else 3]]
    },
    "d2": attack_d2,
    "d4": attack_d4,
    "d7": attack_d7,
    "d7-team": attack_d7_team,
    "d12": attack_d12,
}


# -------------------------------------------------------------------------------- report
def _f(x: float | None, fmt: str = ".1f") -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, fmt)


def _alive(r: dict) -> str:
    dead = [d for d in r["dead"] if d.startswith("agent")]
    return f"{N - len(dead)}/{N} daemons alive" + (f" (dead: {', '.join(dead)})" if dead else "")


def _gap(w: dict) -> str:
    return f"longest status gap {max(w['longest_status_gap_s'].values()):.2f} s"


def _size(r: dict) -> str:
    w = r["after"]
    return (f"formation {_f(w['formation_m_start'])} -> {_f(w['formation_m_end'])} m "
            f"(min {_f(w['formation_m_min'])}) in {w['seconds']:.0f} s")  # fmt: skip


def _scale(w: dict) -> str:
    conv = sum(w["scale_converged_end"].values())
    end, worst = (100 * (w[k] if w[k] is not None else math.nan)
                  for k in ("scale_error_end", "scale_error_max"))  # fmt: skip
    return (f"distance estimates off by {_f(end, '.1f')}% at the end (worst {_f(worst, '.1f')}%, "
            f"> 5% for {w['scale_error_over_5pct_s']:.1f} s), {conv}/{N} scale_converged")  # fmt: skip


def _fast(w: dict) -> str:
    return (f"fastest vehicle {_f(w['speed_max_m_s'], '.1f')} m/s, {w['fast_s']:.1f} s "
            f"above {FAST} m/s")  # fmt: skip


def _top_drops(r: dict, n: int = 5) -> str:
    tot: dict[str, int] = {}
    for d in r["dropped"].values():
        for x, v in d.items():
            tot[x] = tot.get(x, 0) + v
    top = sorted(tot.items(), key=lambda kv: -kv[1])[:n]
    return "receivers dropped " + ", ".join(f"{v} `{x}`" for x, v in top)


def _drops(r: dict, *reasons: str) -> str:
    tot = {x: sum(d.get(x, 0) for d in r["dropped"].values()) for x in reasons}
    return ", ".join(f"{v} `{x}`" for x, v in tot.items())


def rows(results: dict[str, dict]) -> list[tuple[str, str, str]]:
    out = []
    if r := results.get("d1-poison"):
        w = r["after"]
        out.append((
            "1: one MotionShare v_body = 1e300 + one LocalizationState p_hat = 1e300",
            "NaN estimates, status never published again; formation 10 -> 4.3 m",
            f"{_alive(r)}; {_gap(w)}; {_size(r)}; {_scale(w)}; non-finite estimates on "
            f"{w['nonfinite_estimates'] or 'none'}; {_drops(r, 'out_of_range')}; {_fast(w)}; "
            f"phases {sorted(set(w['phases_end'].values()))}",
        ))  # fmt: skip
    for n, r in enumerate(results.get("d1-bitflip", {}).get("rounds", [])):
        w = r["after"]
        out.append((
            f"1: {r['mutations_sent']:,} codec-accepted bit-flip mutations in "
            f"{r['sent_in_s']:.1f} s (round {n + 1}, fresh team; "
            f"{r['by_kind'].get('peer.consensus', 0)} ConsensusState)",
            "1,495 broke all 3 daemons within 2 s",
            f"{_alive(r)}; {_gap(w)}; {_size(r)}; {_scale(w)}; non-finite estimates on "
            f"{w['nonfinite_estimates'] or 'none'}; {_top_drops(r)}; "
            f"{_drops(r, 'core_implausible_jump')}; "
            f"phases {sorted(set(w['phases_end'].values()))}; {_fast(w)}; "
            f"alarms {sorted(r['alarms_seen'])}",
        ))  # fmt: skip
    if r := results.get("d2"):
        w = r["after"]
        stale = "bearings_stale" in r["alarms_seen"]
        out.append((
            "2: one sample of each of vehicle 2's peer kinds + one camera frame, +1e6 s",
            "peer state frozen, vehicle blind, `bearings_stale` never fires; team drifting "
            "apart 8 -> 36 m in 30 s",
            f"{_alive(r)}; {_size(r)}; largest displacement {w['largest_displacement_m']:.1f} m; "
            f"{_fast(w)}; "
            f"`bearings_stale` {'fired' if stale else 'not raised (not blind)'}; "
            f"{_drops(r, 'core_future_stamp', 'camera_future_stamp')}",
        ))  # fmt: skip
    if r := results.get("d4"):
        grow = {k: r["rss_peak_mb"][k] - r["rss_before_mb"][k] for k in r["rss_before_mb"]}
        k = max(grow, key=grow.get)
        ph = list(r["phases"].values())
        halves = ", ".join(f"{p['rss_mb'][k]:.0f}" for p in ph)
        rate0 = min(r["baseline"]["motion_per_s"].get(i, 0) for i in range(N))
        rates = [min(p["motion_per_s"].get(i, 0) for i in range(N)) for p in ph]
        gaps = [max(p["longest_status_gap_s"].values()) for p in ph]
        late = [m["tick_late"].get("p99_ms", math.nan) for m in r["daemon_metrics"].values()]
        exits = list(r["sigterm_to_exit_s"].values())
        out.append((
            f"4: {ISSUE_NAME_PAYLOADS} x {ISSUE_NAMES:,} names + {ISSUE_EDGES:,} fake edges, "
            f"then the same names in {r['consensus_payloads_accepted_size']} payloads of "
            f"{LIST_MAX:,} (the codec's bound) + 5 x 4,000 edges, in two halves",
            "daemon 130 -> 652 MB; setpoints 2/s; two daemons ignored SIGTERM for 8 s",
            f"RSS daemon {k}: {r['rss_before_mb'][k]:.0f} -> {halves} MB after each phase "
            f"(peak {r['rss_peak_mb'][k]:.0f}, {r['rss_after_mb'][k]:.0f} at the end); core "
            f"{rate0:.0f} -> {' / '.join(f'{x:.0f}' for x in rates)} MotionShare/s per phase "
            f"(slowest daemon; 50/s = the 100 Hz core, whose every tick sets the setpoint), "
            f"longest status gap {' / '.join(f'{g:.1f}' for g in gaps)} s, tick lateness p99 "
            f"{max(late):.0f} ms; SIGTERM -> exit {', '.join(_f(x, '.1f') for x in exits)} s; "
            f"{_drops(r, 'out_of_range', 'core_unknown_name', 'core_unknown_edge')}; {_alive(r)}",
        ))  # fmt: skip
    if r := results.get("d7"):
        m, c = r["memory"], r["cpu"]
        out.append((
            f"7: {m['sources']:,} spoofed sources; {c['spoofers']:,} spoofed heartbeats/s "
            "(2-vehicle simulator)",
            "simulator 62 -> 210 MB; 98.5% CPU; GCS heartbeats 2.0 -> 1.3/s",
            f"simulator {m['rss_before_mb']:.0f} -> {m['rss_after_mb']:.0f} MB; CPU "
            f"{100 * c['base_cpu']:.1f}% -> {100 * c['attacked_cpu']:.1f}% of a core; GCS "
            f"heartbeats {c['base_heartbeats_s']:.2f} -> {c['attacked_heartbeats_s']:.2f}/s; "
            f"alive {r['memory_alive'] and r['cpu_alive']}",
        ))  # fmt: skip
    if r := results.get("d7-team"):
        m, c, w = r["memory"], r["cpu"], r["after"]
        out.append((
            f"7 (flying team): {m['sources']:,} spoofed sources + {c['spoofers']:,} spoofed "
            "heartbeats/s at vehicle 0",
            "(not measured on a team)",
            f"simulator {m['rss_before_mb']:.0f} -> {m['rss_after_mb']:.0f} MB; CPU "
            f"{100 * c['base_cpu']:.1f}% -> {100 * c['attacked_cpu']:.1f}%; GCS heartbeats "
            f"{c['base_heartbeats_s']:.2f} -> {c['attacked_heartbeats_s']:.2f}/s; {_alive(r)}; "
            f"{_gap(w)}; phases {sorted(set(w['phases_end'].values()))}",
        ))  # fmt: skip
    if r := results.get("d12"):
        counts = ", ".join(f"{v} {k}" for k, v in sorted(r["counts"].items()))
        out.append((
            f"12: the issue's 19 failing bad config/CLI cases (+3 more), as processes "
            f"({len(r['cases'])})",
            "of 85: 10 tracebacks, 3 never exit, 6 silently accepted",
            counts,
        ))  # fmt: skip
    return out


def table(results: dict[str, dict]) -> str:
    lines = ["| attack | before (issue) | after (measured) |", "| --- | --- | --- |"]
    lines += [f"| {a} | {b} | {c} |" for a, b, c in rows(results)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="+", choices=sorted(ATTACKS), default=None)
    parser.add_argument("--quick", action="store_true", help="10 s watches, smaller floods")
    parser.add_argument("--json", type=Path, default=None, help="write every measurement here")
    args = parser.parse_args(argv)
    from messages import limits

    assert limits.LIST_MAX == LIST_MAX, limits.LIST_MAX
    run_this_tree()
    results: dict[str, dict] = {}
    for name in args.only or list(ATTACKS):
        print(f"{name} ...", flush=True)
        t0 = time.monotonic()
        try:
            results[name] = ATTACKS[name](args.quick)
        except Exception as exc:  # one attack's failure is reported, the others still run
            results[name] = {"error": f"{type(exc).__name__}: {exc}"}
            print(f"  {name} failed: {results[name]['error']}", flush=True)
        print(f"  {name} done in {time.monotonic() - t0:.0f} s", flush=True)
    ok = {k: v for k, v in results.items() if "error" not in v}
    print()
    print(table(ok))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1, default=str))
    return 1 if len(ok) < len(results) else 0


def run_this_tree() -> None:
    """Have the processes a bench starts run this tree (first on ``PYTHONPATH``, and the cwd:
    ``python -m`` puts it first), and print which tree, the load and the date."""
    os.environ["PYTHONPATH"] = os.pathsep.join(
        [str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])]
    )
    os.chdir(ROOT)
    print(f"tree {ROOT} ({_git_head()}); load average {os.getloadavg()[0]:.2f}; "
          f"{datetime.date.today()}", flush=True)  # fmt: skip


def _git_head() -> str:
    try:
        return subprocess.run(
            ["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"], capture_output=True,
            text=True, check=True,
        ).stdout.strip()  # fmt: skip
    except (OSError, subprocess.CalledProcessError):
        return "?"


if __name__ == "__main__":
    raise SystemExit(main())
