"""The contact timing rule online (ContactTracker, what ``wtml stream`` runs) against the
offline rule (contacts_from) on the same frames: the same contacts, each decided no later
than it can be."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from wtml.runtime.contacts import ContactTracker, Timing, contacts_from


def online(pred: dict, timing: Timing, max_contacts: int | None) -> tuple[list, list, list]:
    """Onsets, detachments and the (event, frame that decided it) pairs of one record fed
    frame by frame."""
    tracker = ContactTracker(timing, max_contacts)
    events = []
    for k in range(pred["contact"].shape[1]):
        events += tracker.push(pred["contact"][0, k], pred["detach_margin"][0, k],
                               pred["touch"][0, k])
    events += tracker.finish()
    onsets = [e.time for e in events if e.kind == "onset"]
    detach = [e.time for e in events if e.kind == "detachment"]
    return onsets, detach, events


frames = st.integers(20, 160).flatmap(lambda n: st.tuples(
    st.lists(st.sampled_from([0.1, 0.9]), min_size=n, max_size=n),
    st.lists(st.sampled_from([-1.0, 1.0]), min_size=n, max_size=n),
    st.lists(st.sampled_from([0.0, 2.0]), min_size=n, max_size=n)))


@settings(max_examples=300, deadline=None)
@given(frames, st.integers(0, 6), st.integers(0, 5), st.integers(1, 4))
def test_the_tracker_finds_the_offline_contacts(frames, merge, lookback, max_contacts):
    """Random runs of probability, margin and touches, every merge gap and lookback: the
    online events are the offline contacts (onset and detachment, NaN for one still open at
    the end), in order, each decided on or after its own frame."""
    contact, margin, touch = (np.array(x, float)[None] for x in frames)
    timing = Timing(frame_s=1e-3, onset_offset_s=2e-4, detach_offset_s=7e-4,
                    merge_s=merge * 1e-3, touch_lookback=lookback, max_contacts=max_contacts)
    pred = {"contact": contact, "detach_margin": margin, "touch": touch}
    on, off = contacts_from(pred, timing)
    found = np.isfinite(on[0])
    onsets, detach, events = online(pred, timing, max_contacts)
    np.testing.assert_allclose(onsets, on[0, found], rtol=0, atol=1e-12)
    np.testing.assert_allclose(detach, off[0, found], rtol=0, atol=1e-12)
    for e in events:  # decided on or after the event's own frame, never before
        offset = timing.onset_offset_s if e.kind == "onset" else timing.detach_offset_s
        if np.isfinite(e.time):
            assert e.decided_frame >= round((e.time - offset) / timing.frame_s), e


def test_a_detachment_waits_for_the_merge_gap_and_an_onset_for_its_first_rise():
    """A run of margin alone starts a contact whose onset is decided at its first frame with
    contact > 0.5; its detachment is decided once merge_s has passed without a new run."""
    n = 40
    contact, margin, touch = np.full((1, n), 0.1), np.full((1, n), -1.0), np.zeros((1, n))
    margin[0, 10:20] = 1.0
    contact[0, 13:18] = 0.9
    timing = Timing(1e-3, 0.0, 0.0, merge_s=3e-3, touch_lookback=2, max_contacts=8)
    _, _, events = online({"contact": contact, "detach_margin": margin, "touch": touch},
                          timing, None)
    assert [(e.kind, e.decided_frame) for e in events] == [("onset", 13), ("detachment", 23)]
    np.testing.assert_allclose([e.time for e in events], [0.013, 0.019])
