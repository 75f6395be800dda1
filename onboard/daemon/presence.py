"""Which graph neighbours are lost: no liveliness token, or silent (issue 23, defect 6).

A vehicle whose daemon stalls (SIGSTOP, a frozen machine) keeps its Zenoh liveliness token
while its session's lease holds (and a router may keep it longer), yet sends nothing: its peers
must not wait for the token to go. :class:`PeerPresence` is the daemon's rule, pure logic over
the daemon's clock (no link, no threads; ``tests/onboard/test_presence.py``):

* a peer is *seen* once its token was present (ids never seen are not expected yet);
* a seen peer is **lost** after ``hold_s`` without its token, or ``hold_s`` after the last
  peer payload the daemon received from it (only peers it heard at least once: graph ids whose
  payloads it does not subscribe to are judged by their token alone);
* it rejoins as soon as its token is present and a payload of it arrived within ``hold_s``.

Times are the receiver's own clock at receipt, never the sender's stamps (a stalled sender's
stamps say nothing about now). After the daemon itself stalled, or its clock went back, the
ages restart (:meth:`PeerPresence.restart`): its peers were not silent, it was.
"""

from __future__ import annotations

from collections.abc import Iterable


class PeerPresence:
    """Lost and present graph neighbours of agent ``own_id`` (module docstring)."""

    def __init__(self, graph_ids: Iterable[int], own_id: int, hold_s: float) -> None:
        self.ids = frozenset(graph_ids) - {own_id}
        self.hold_s = hold_s
        self._seen: set[int] = set()
        self._gone_since: dict[int, float] = {}
        self._heard_s: dict[int, float] = {}

    def heard(self, sender: int, now_s: float) -> None:
        """A peer payload of ``sender`` was admitted at ``now_s``."""
        if sender in self.ids:
            self._heard_s[sender] = now_s

    def update(self, alive: Iterable[int], now_s: float) -> None:
        """This tick's liveliness tokens (``alive``: agents whose token is present)."""
        alive_set = set(alive) & self.ids
        self._seen |= alive_set
        for j in self._seen:
            if j in alive_set:
                self._gone_since.pop(j, None)
            else:
                self._gone_since.setdefault(j, now_s)

    def lost(self, now_s: float) -> list[int]:
        """Seen peers without a token for ``hold_s``, or silent for ``hold_s``; sorted."""
        out = []
        for j in self._seen:
            gone = self._gone_since.get(j)
            heard = self._heard_s.get(j)
            if (gone is not None and now_s - gone >= self.hold_s) or (
                heard is not None and now_s - heard >= self.hold_s
            ):
                out.append(j)
        return sorted(out)

    def silent(self, now_s: float) -> list[int]:
        """Of :meth:`lost`, those whose token is still present (a stalled vehicle)."""
        return [j for j in self.lost(now_s) if j not in self._gone_since]

    def restart(self, now_s: float) -> None:
        """The daemon itself stalled or its clock went back: every age starts at ``now_s``."""
        self._gone_since = {j: now_s for j in self._gone_since}
        self._heard_s = {j: now_s for j in self._heard_s}
