"""Where one daemon's CPU goes (issue 27): ``bearingflock agent --profile`` (or the environment
variable ``BEARINGFLOCK_AGENT_PROFILE=1``, which the demo's daemons inherit).

The split is by thread CPU time, cheap enough to leave on in a benchmark (two
``time.thread_time`` calls around each timed section, a microsecond each):

* ``core``: the agent core's steps (:meth:`onboard.core.agent.AgentCore.step`) less the
  rigidity layer;
* ``rigidity``: paper 003's layer (``core.rigidity.step``), eigen rounds included;
* ``codec``: decoding and validating received peer payloads (``messages.codec.decode`` in the
  Zenoh callbacks) and encoding the daemon's own peer payloads (``PeerLink.publish``);
* ``zenoh``: Zenoh's own (Rust) threads plus the rest of its Python callbacks;
* ``mavlink``: the autopilot link's threads (``autopilot-rx``/``autopilot-tx``: parsing,
  signing, the setpoint stream);
* ``loop``: the rest of the core loop's thread (guards, status, bookkeeping, sleeping's wake-ups);
* ``other``: every other thread (the flight thread, timers).

Per-thread CPU comes from ``/proc/self/task/<tid>/stat`` (Linux); Python threads are named by
``threading``, Zenoh's Rust threads by their OS names. On exit the daemon logs the split as
``cpu_split {...}`` (seconds and fractions of the process's CPU); ``benchmarks/
bench_footprint.py --profile`` reads it.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

PROFILE_ENV = "BEARINGFLOCK_AGENT_PROFILE"
CATEGORIES = ("core", "rigidity", "codec", "zenoh", "mavlink", "loop", "other")
MAVLINK_THREADS = ("autopilot-rx", "autopilot-tx")
"""Thread names of the autopilot links' loops (onboard/autopilot)."""

_TICKS_S = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


def enabled(flag: bool = False) -> bool:
    """``--profile`` or ``BEARINGFLOCK_AGENT_PROFILE`` set to a non-empty value other than 0."""
    return flag or os.environ.get(PROFILE_ENV, "") not in ("", "0")


def thread_cpu_s() -> dict[int, float]:
    """CPU seconds (user + system) of each of this process's threads, by native id."""
    out: dict[int, float] = {}
    for task in Path("/proc/self/task").iterdir():
        try:
            fields = (task / "stat").read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue  # the thread ended meanwhile
        out[int(task.name)] = (int(fields[11]) + int(fields[12])) / _TICKS_S
    return out


class CpuSplit:
    """Accumulates timed sections (thread CPU seconds) and splits the process's CPU at the end.

    Sections are timed per thread (``time.thread_time``), so a Zenoh callback's decode and the
    core loop's step never mix; the lock only guards the sums."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self.sections: dict[str, float] = {"core": 0.0, "rigidity": 0.0, "decode": 0.0,
                                           "encode": 0.0}  # fmt: skip
        self.main_native_id = threading.main_thread().native_id
        self._start = thread_cpu_s()

    def add(self, section: str, cpu_s: float) -> None:
        with self._lock:
            self.sections[section] += cpu_s

    def timed(self, section: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        """``fn`` wrapped so that its thread CPU time adds to ``section``."""
        clock = time.thread_time

        def wrapper(*args: Any, **kwargs: Any) -> Any:
            t0 = clock()
            try:
                return fn(*args, **kwargs)
            finally:
                self.add(section, clock() - t0)

        return wrapper

    def split(self) -> dict[str, Any]:
        """CPU seconds per category since construction, their fractions, and the total."""
        names = {t.native_id: t.name for t in threading.enumerate()}
        now = thread_cpu_s()
        cat = dict.fromkeys(CATEGORIES, 0.0)
        python_zenoh = 0.0
        for tid, cpu in now.items():
            used = cpu - self._start.get(tid, 0.0)
            name = names.get(tid)
            if tid == self.main_native_id:
                cat["loop"] += used
            elif name is None:  # not a Python thread: Zenoh's runtime (rx-, tx-, acc-, net-)
                cat["zenoh"] += used
            elif name.startswith(MAVLINK_THREADS):
                cat["mavlink"] += used
            elif "pyo3" in name:  # Zenoh's Python callbacks (PyO3 closures)
                python_zenoh += used
            else:
                cat["other"] += used
        with self._lock:
            s = dict(self.sections)
        # the timed sections of the main thread come out of "loop", the decode out of the
        # callbacks' time; whatever is left of the callbacks is Zenoh's glue
        rigidity = s["rigidity"]
        core = max(0.0, s["core"] - rigidity)
        cat["core"], cat["rigidity"] = core, rigidity
        cat["codec"] = s["decode"] + s["encode"]
        cat["loop"] = max(0.0, cat["loop"] - s["core"] - s["encode"])
        cat["zenoh"] += max(0.0, python_zenoh - s["decode"])
        total = sum(cat.values())
        return {
            "cpu_s": cat,
            "fraction": {k: (v / total if total > 0 else 0.0) for k, v in cat.items()},
            "total_cpu_s": total,
        }


def instrument(split: CpuSplit, core: Any, peers: Any) -> None:
    """Time ``core.step`` (and its rigidity layer's), the peer link's decode and encode."""
    core.step = split.timed("core", core.step)
    if getattr(core, "rigidity", None) is not None:
        core.rigidity.step = split.timed("rigidity", core.rigidity.step)
    peers.decode = split.timed("decode", peers.decode)
    peers.encode = split.timed("encode", peers.encode)
