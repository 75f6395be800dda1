"""Replay protection: a per-sender, per-kind window on the payloads' sequence numbers.

Every payload carries its sender's ``seq`` (:class:`messages.codec.Payload`); an agent core
numbers its steps, so each kind of payload a neighbour publishes comes with strictly
increasing numbers (gaps are normal: only the newest of each kind goes out per publish period,
and the network loses some). Without a check, samples captured from a vehicle and replayed
under its key (issue 23: at 8x its rate) were taken as new: their old stamps made the
receivers flag the sender's clock and hold.

:class:`SeqWindow` accepts a sample of ``(sender, kind)`` when its ``seq`` is ahead of the last
accepted one by at most ``window``; a duplicate or older number is dropped as ``seq_replay``,
one too far ahead as ``seq_window`` (a forged huge number would otherwise lock the real sender
out). A sender that restarted (its numbers start again at 0) or was silent for long is
followed again after ``resync_samples`` consecutive out-of-window samples that are consistent
with each other, freshly stamped by the receiver's clock and newer than the last accepted one
(a replay of captured samples is neither; after the receiver's own clock went back, a restarted
simulator, the stamps only need to be fresh): counted as ``seq_resync``. The table holds one entry per (known sender, payload type).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from messages.limits import stamp_ahead
from messages.vocabulary import DropReason

SEQ_WINDOW = 10_000
"""Largest accepted step of ``seq`` between two samples of one kind: 100 s of a 100 Hz core (a
kind can pause: ``SfmEstimate`` while the edge's other end is lost)."""
RESYNC_SAMPLES = 5
"""Consecutive consistent out-of-window samples before the window follows them."""
RESYNC_MAX_AGE_S = 0.5
"""A sample counts towards a resynchronization only if stamped at most this long ago."""


@dataclass
class _Track:
    last_seq: int
    last_stamp_s: float = -math.inf
    candidate_seq: int | None = None
    candidates: int = 0


@dataclass
class SeqWindow:
    """Per ``(sender, kind)`` sequence-number window (module docstring)."""

    window: int = SEQ_WINDOW
    resync_samples: int = RESYNC_SAMPLES
    resync_max_age_s: float = RESYNC_MAX_AGE_S
    _tracks: dict[tuple[int, type], _Track] = field(default_factory=dict)

    def admit(
        self, sender: int, kind: type, seq: int, stamp_s: float, now_s: float
    ) -> DropReason | None:
        """``None`` to accept the sample, else the reason to drop it (``seq_replay``,
        ``seq_window``); ``seq_resync`` when it is accepted on a new timeline."""
        key = (sender, kind)
        track = self._tracks.get(key)
        if track is None:
            self._tracks[key] = _Track(seq, stamp_s)
            return None
        step = seq - track.last_seq
        if 0 < step <= self.window:
            track.last_seq, track.candidate_seq, track.candidates = seq, None, 0
            track.last_stamp_s = stamp_s
            return None
        newer = stamp_s > track.last_stamp_s or stamp_ahead(track.last_stamp_s, now_s)
        if newer and now_s - stamp_s <= self.resync_max_age_s:
            prev = track.candidate_seq
            if prev is not None and 0 < seq - prev <= self.window:
                track.candidates += 1
            else:
                track.candidates = 1
            track.candidate_seq = seq
            if track.candidates >= self.resync_samples:
                track.last_seq, track.candidate_seq, track.candidates = seq, None, 0
                track.last_stamp_s = stamp_s
                return DropReason.SEQ_RESYNC
        return DropReason.SEQ_REPLAY if step <= 0 else DropReason.SEQ_WINDOW

    def __len__(self) -> int:
        return len(self._tracks)
