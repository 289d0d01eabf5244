"""Contacts from an onset graph's frames: the one timing rule, offline over whole records
(:func:`contacts_from`) and online frame by frame (:class:`ContactTracker`, what ``wtml
stream`` runs), which give the same contacts. Numpy only.

A frame is *active* where the contact probability passes 0.5 or, for the decoder, the free
tip's reach passes its detachment level (``detach_margin >= 0``); runs of active frames closer
than ``merge_s`` are one contact. The decoder's contact starts where the last run of
successive frames with ``touch >= 1`` starts, of those from ``touch_lookback`` frames ahead of
the run (not reaching back into the contact before) up to the run's first frame with
``contact > 0.5`` (on that frame if none): a touch steps Zm on each frame as it deepens, while
a noise step over the threshold stands alone; it ends on its last frame with ``detach_margin
>= 0``. The classical path's contact is a run of ``contact > 0.5``. A contact's onset and
detachment lie ``onset_offset_s`` and ``detach_offset_s`` into their frames (the metadata's).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def intervals(active: np.ndarray, rate: float, merge_s: float, max_count: int
              ) -> tuple[np.ndarray, np.ndarray]:
    """Start and end times (s) of the runs of ``True`` in each row of ``active``
    ``(n, n_samples)``, runs closer than ``merge_s`` merged; each ``(n, max_count)``,
    NaN-padded (extra runs dropped). A run still open at the end has end NaN."""
    n = len(active)
    starts = np.full((n, max_count), np.nan)
    ends = np.full((n, max_count), np.nan)
    pad = np.zeros((n, 1), bool)
    edges = np.diff(np.concatenate([pad, active.astype(bool), pad], 1).astype(np.int8), axis=1)
    for r in range(n):
        on = np.flatnonzero(edges[r] == 1)
        off = np.flatnonzero(edges[r] == -1)
        apart = on[1:] - off[:-1] > merge_s * rate
        on = on[np.concatenate([[True], apart])] if len(on) else on
        off = off[np.concatenate([apart, [True]])] if len(off) else off
        m = min(len(on), max_count)
        starts[r, :m] = on[:m] / rate
        ends[r, :m] = np.where(off[:m] >= active.shape[1], np.nan, off[:m] / rate)
    return starts, ends


@dataclass(frozen=True)
class Timing:
    """An onset graph's frame timing from its metadata (s): frames of ``frame_s``, onset and
    detachment at ``onset_offset_s`` and ``detach_offset_s`` into their frames, runs closer
    than ``merge_s`` one contact, touches looked for ``touch_lookback`` frames ahead of a run,
    at most ``max_contacts`` per record."""

    frame_s: float
    onset_offset_s: float
    detach_offset_s: float
    merge_s: float
    touch_lookback: int
    max_contacts: int

    @classmethod
    def of(cls, meta) -> Timing:
        """From a graph's checked metadata (:class:`wtml.runtime.metadata.OnsetMetadata`)."""
        return cls(meta.frame_s, meta.onset_offset_s, meta.detach_offset_s, meta.merge_s,
                   meta.touch_lookback, meta.scene.get("max_contacts", 8))


def first_touch(touch: np.ndarray, lo: int, first: int) -> int:
    """The frame where the last run of successive ``touch`` frames in ``[lo, first]``
    starts, or ``first`` when none touches (``touch``: one record's bool frames)."""
    hit = np.flatnonzero(touch[lo:first + 1])
    if not len(hit):
        return first
    j = len(hit) - 1
    while j and hit[j - 1] == hit[j] - 1:
        j -= 1
    return lo + int(hit[j])


def contacts_from(pred: dict, timing: Timing) -> tuple[np.ndarray, np.ndarray]:
    """Onset and detachment times (s) of each record's contacts from a graph's outputs
    (``contact``, and for the decoder ``detach_margin`` and ``touch``, each ``(n,
    n_frames)``); each ``(n, max_contacts)``, NaN-padded (module docstring)."""
    frame_s = timing.frame_s
    if "detach_margin" not in pred:
        start, end = intervals(pred["contact"] > 0.5, 1 / frame_s, timing.merge_s,
                               timing.max_contacts)
    else:
        rise, fall = pred["contact"] > 0.5, pred["detach_margin"] >= 0
        touch = pred["touch"] >= 1
        start, end = intervals(rise | fall, 1 / frame_s, timing.merge_s, timing.max_contacts)
        n_frames = rise.shape[1]
        before = np.zeros(len(start), int)  # where the record's previous run ended
        for r, k in zip(*np.nonzero(np.isfinite(start)), strict=True):
            a = int(round(start[r, k] / frame_s))
            b = n_frames if np.isnan(end[r, k]) else int(round(end[r, k] / frame_s))
            on, off = np.flatnonzero(rise[r, a:b]), np.flatnonzero(fall[r, a:b])
            first = a + (on[0] if len(on) else 0)
            start[r, k] = first_touch(touch[r], max(a - timing.touch_lookback, before[r]),
                                      first) * frame_s
            before[r] = b
            if np.isfinite(end[r, k]):
                end[r, k] = (a + (off[-1] + 1 if len(off) else b - a)) * frame_s
    # intervals() gives frame boundaries; the contact starts/ends at a fixed phase in a frame
    onset = start + timing.onset_offset_s
    detach = end - frame_s + timing.detach_offset_s
    return onset, detach


@dataclass
class Event:
    """A contact's onset (``kind="onset"``, ``time`` its onset) or end (``"detachment"``,
    ``time`` its detachment; NaN for a contact still open when the stream ended), with the
    frame whose arrival decided it."""

    kind: str
    contact: int
    time: float
    decided_frame: int


class ContactTracker:
    """:func:`contacts_from`'s decoder rule, one frame at a time: feed each frame's
    ``contact`` probability, ``detach_margin`` and ``touch`` (:meth:`push`), get each onset as
    soon as no later frame can move it and each detachment once ``merge_s`` has passed
    without a new run; :meth:`finish` closes the stream. On a record the events are
    :func:`contacts_from`'s contacts (``max_contacts``: drop runs past that many, as a
    record does; None: keep every one)."""

    def __init__(self, timing: Timing, max_contacts: int | None = None) -> None:
        self.timing = timing
        self.max_contacts = max_contacts
        self.merge_frames = timing.merge_s * (1 / timing.frame_s)  # as intervals() rounds it
        self.frame = 0          # frames seen
        self.count = 0          # contacts started
        self.history: list[bool] = []  # touch flags from `history_start` on
        self.history_start = 0
        self.before = 0         # where the previous contact's last run ended
        self.run_start: int | None = None   # the open contact's first frame
        self.first_rise: int | None = None  # its first frame with contact > 0.5
        self.last_fall: int | None = None   # its last frame with detach_margin >= 0
        self.run_end: int | None = None     # where its last run ended (inactive since)
        self.onset_sent = False

    def _keep(self, frame: int) -> None:
        """Forget touch flags before ``frame``."""
        drop = frame - self.history_start
        if drop > 0:
            del self.history[:drop]
            self.history_start = frame

    def _onset(self, first: int) -> float:
        lo = max(self.run_start - self.timing.touch_lookback, self.before)
        start = self.history_start  # <= lo: the flags from lo on are kept
        touch = np.array(self.history[lo - start:first + 1 - start], bool)
        at = lo + first_touch(touch, 0, first - lo)
        return at * self.timing.frame_s + self.timing.onset_offset_s

    def _close(self, decided: int, open_end: bool) -> list[Event]:
        events = []
        b = self.frame if open_end else self.run_end
        if not self.onset_sent:
            first = self.first_rise if self.first_rise is not None else self.run_start
            events.append(Event("onset", self.count - 1, self._onset(first), decided))
        if open_end:
            detach = float("nan")
        else:
            end = self.last_fall + 1 if self.last_fall is not None else b
            detach = (end - 1) * self.timing.frame_s + self.timing.detach_offset_s
        events.append(Event("detachment", self.count - 1, detach, decided))
        self.before = b
        self.run_start = self.first_rise = self.last_fall = self.run_end = None
        self.onset_sent = False
        self._keep(max(self.frame - self.timing.touch_lookback, self.before))
        return events

    def push(self, contact: float, detach_margin: float, touch: float) -> list[Event]:
        """One frame's outputs in; the events it decides out."""
        k = self.frame
        rise, fall = contact > 0.5, detach_margin >= 0
        self.history.append(touch >= 1)
        self.frame += 1
        events: list[Event] = []
        if rise or fall:
            if self.run_start is None:
                if self.max_contacts is not None and self.count >= self.max_contacts:
                    self._keep(self.frame - self.timing.touch_lookback)
                    return events
                self.run_start, self.count = k, self.count + 1
            self.run_end = None
            if fall:
                self.last_fall = k
            if rise and self.first_rise is None:
                self.first_rise = k
                events.append(Event("onset", self.count - 1, self._onset(k), k))
                self.onset_sent = True
        elif self.run_start is not None:
            if self.run_end is None:
                self.run_end = k
            if k + 1 - self.run_end > self.merge_frames:  # no later run can merge with it
                events += self._close(k, open_end=False)
        if self.run_start is None:
            self._keep(max(self.frame - self.timing.touch_lookback, self.before))
        elif self.onset_sent:  # the next contact looks back no further than this one's end
            self._keep(self.run_end if self.run_end is not None else self.frame)
        return events

    def finish(self) -> list[Event]:
        """The stream has ended: close the open contact (detachment NaN if its last run
        reached the end)."""
        if self.run_start is None:
            return []
        return self._close(self.frame - 1, open_end=self.run_end is None)
