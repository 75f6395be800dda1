"""The core's peer table: the latest payload of each kind per neighbour, its freshness, and who
may send what.

Every peer payload the core receives passes :meth:`PeerTable.receive` once: the sender check
(a kind is taken only from the senders its route names), the stamp check (a stamp in the future
would be "the newest" for good), then the route's layer, which may reject it as malformed.
What is accepted becomes its sender's latest of that kind; layers read it back with
:meth:`PeerTable.latest` / :meth:`PeerTable.fresh` instead of keeping tables of their own.
Drops are counted by reason in :class:`Drops` (the daemon reports them, the fuzz tests read
them).

:class:`JumpGate` is the layers' common rule for a neighbour's *estimate* that jumps: held back
until the sender's next sample confirms it (issue 23's bit-flip campaign, docs/flying.md).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterator, Sequence
from typing import Any, TypeVar

import msgspec

from messages.codec import Payload
from messages.limits import stamp_ahead
from messages.vocabulary import DropReason

P = TypeVar("P")


class Drops(dict[DropReason, int]):
    """Counts of dropped inputs by reason (:class:`messages.vocabulary.DropReason`)."""

    def count(self, reason: DropReason, n: int = 1) -> None:
        """Count ``n`` drops for ``reason``."""
        self[reason] = self.get(reason, 0) + n


class Route(msgspec.Struct, frozen=True):
    """Who may send a payload kind, and the layer's handler (``None``: a known kind no layer of
    this mode takes, counted as ``unknown_type`` after the checks)."""

    senders: frozenset[int]
    take: Callable[[int, Any], bool | None] | None = None
    """``take(sender, payload)``: False if malformed (counted, not kept); None if the layer
    dropped it and counted why itself (e.g. ``implausible_jump``)."""


class JumpGate:
    """A neighbour's estimate that jumps is taken only once its sender confirms it.

    Per key (a sender and a quantity) the gate keeps the last sample it let through and at most
    one *pending* sample. A sample within ``limits`` of the last one let through passes; one
    that jumped further is held pending (the caller drops it, counted ``implausible_jump``) and
    passes only if the sender's next sample agrees with it within ``limits``: a real jump is
    followed one sample late, and ONE bad sample is never taken, however large or small the
    limits, while the sample after it (compared with the last one let through) is not lost. The
    limits only need to be above what an estimate moves between two consecutive samples: real
    motion faster than that would be held back sample after sample. Components flagged in
    ``angular`` are compared wrapped to ``[-pi, pi]``. A key's first sample, and a sample of
    another length than the last, pass (the callers check lengths). Keys are bounded by the
    caller (fleet ids times known quantities)."""

    def __init__(self) -> None:
        self._passed: dict[Hashable, tuple[float, ...]] = {}
        self._pending: dict[Hashable, tuple[float, ...]] = {}

    def admit(self, key: Hashable, values: Sequence[float], limits: Sequence[float],
              angular: Sequence[bool] = ()) -> bool:  # fmt: skip
        """Whether ``values`` may be taken (see the class docstring); ``limits`` and
        ``angular`` per component (``angular`` may be shorter: the rest are not angles)."""
        v = tuple(values)
        passed = self._passed.get(key)
        if passed is None or not _jumped(v, passed, limits, angular):
            self._passed[key] = v
            self._pending.pop(key, None)
            return True
        pending = self._pending.get(key)
        if pending is not None and not _jumped(v, pending, limits, angular):
            self._passed[key] = v
            del self._pending[key]
            return True
        self._pending[key] = v
        return False

    def clear(self) -> None:
        """Forget every sample (the clock went back: samples to come are compared with none)."""
        self._passed.clear()
        self._pending.clear()


def _jumped(a: tuple[float, ...], b: tuple[float, ...], limits: Sequence[float],
            angular: Sequence[bool]) -> bool:  # fmt: skip
    """Whether any component of ``a`` is further than its limit from ``b`` (equal lengths)."""
    if len(a) != len(b):
        return False
    for k, (x, y, lim) in enumerate(zip(a, b, limits, strict=True)):
        d = math.remainder(x - y, math.tau) if k < len(angular) and angular[k] else x - y
        if abs(d) > lim:
            return True
    return False


class PeerTable:
    """Latest accepted payload of each kind per sender (module docstring)."""

    def __init__(self, neighbours: frozenset[int], timeout_s: float, drops: Drops) -> None:
        self.routes: dict[type, Route] = {}
        self.neighbours = neighbours
        """Senders checked for kinds no route names (then dropped as ``unknown_type``)."""
        self.timeout_s = timeout_s
        self.drops = drops
        self.heard: dict[int, float] = {}
        """Sender -> the core time it was last heard from (any kind past the checks)."""
        self.t_s: float | None = None
        """The core's time: that of its newest step (``None`` before the first)."""
        self._latest: dict[type, dict[int, Any]] = {}

    def route(self, kind: type, route: Route) -> None:
        """Take payloads of ``kind`` as ``route`` says (one route per kind)."""
        if kind in self.routes:
            raise ValueError(f"{kind.__name__} already has a route")
        self.routes[kind] = route
        self._latest[kind] = {}

    def receive(self, msg: Payload, t_s: float) -> None:
        """Check one payload and hand it to its route's layer; count it if dropped."""
        j = msg.sender
        kind = type(msg)
        route = self.routes.get(kind)
        if j not in (self.neighbours if route is None else route.senders):
            self.drops.count(DropReason.NOT_NEIGHBOUR)
            return
        if route is None:
            self.drops.count(DropReason.UNKNOWN_TYPE)
            return
        if stamp_ahead(msg.stamp_s, t_s):  # "the newest by stamp" would keep it for good
            self.drops.count(DropReason.FUTURE_STAMP)
            return
        self.heard[j] = t_s
        take = route.take
        if take is None:
            self.drops.count(DropReason.UNKNOWN_TYPE)
            return
        taken = take(j, msg)
        if taken:
            self._latest[kind][j] = msg
        elif taken is not None:
            self.drops.count(DropReason.MALFORMED)

    def is_fresh(self, stamp_s: float, t_s: float) -> bool:
        """Whether data stamped ``stamp_s`` is still usable at ``t_s``."""
        return t_s - stamp_s <= self.timeout_s

    def latest(self, kind: type[P], j: int) -> P | None:
        """Sender ``j``'s latest accepted payload of ``kind`` (stale or not)."""
        return self._latest[kind].get(j)

    def latest_fresh(self, kind: type[P], j: int, t_s: float) -> P | None:
        """Sender ``j``'s latest payload of ``kind`` if it is fresh at ``t_s``."""
        m = self._latest[kind].get(j)
        return m if m is not None and self.is_fresh(m.stamp_s, t_s) else None  # type: ignore[attr-defined]

    def all(self, kind: type[P]) -> dict[int, P]:
        """Every sender's latest payload of ``kind``, in the order they were first heard."""
        return self._latest[kind]

    def fresh(self, kind: type[P], t_s: float) -> Iterator[tuple[int, P]]:
        """``(sender, payload)`` of the fresh latest payloads of ``kind``, first-heard order."""
        for j, m in self._latest[kind].items():
            if self.is_fresh(m.stamp_s, t_s):  # type: ignore[attr-defined]
                yield j, m

    def heard_within(self, t_s: float, window_s: float) -> list[int]:
        """Senders heard within ``window_s`` before ``t_s``, ascending."""
        return sorted(j for j, s in self.heard.items() if t_s - s <= window_s)

    def clear(self) -> None:
        """Forget every payload and when anyone was heard (the clock went back)."""
        for table in self._latest.values():
            table.clear()
        self.heard.clear()
