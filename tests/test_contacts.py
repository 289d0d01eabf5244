"""The contact timing rule online (ContactTracker, what ``wtml stream`` runs) against the
offline rule (contacts_from) on the same frames: the same contacts, each decided no later
than it can be."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wtml.cli import main
from wtml.runtime import stream as stream_module
from wtml.runtime.contacts import ContactTracker, Timing, contacts_from
from wtml.runtime.predict import InputError


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


class FakeStream:
    """A streaming graph's stand-in: frames of ``chunk`` samples, a frame's contact
    probability 0.9 where its mean e passes 0, its margin the mean i, a touch where e's mean
    jumps by more than 0.5 from the frame before (the state carries the last mean), the
    running gap the mean of the frames' mean i so far (the state carries their count and
    sum): no wall from 5 on (NaN, in domain), in domain below 0.5 (σ 0.05; NaN outside), the
    score the frames seen; records of ``record`` samples (default: the test's whole stream)
    and a limit of ``limit`` σ for two of them."""

    def __init__(self, chunk: int, record: int = 960, limit: float = 3.0) -> None:
        from types import SimpleNamespace

        self.meta = SimpleNamespace(task="onset", sample_rate_hz=1000.0, chunk_samples=chunk,
                                    state_size=3, frame_s=chunk / 1000.0, onset_offset_s=0.0,
                                    detach_offset_s=0.0, merge_s=2 * chunk / 1000.0,
                                    touch_lookback=3, scene={"max_contacts": 8},
                                    n_samples=record,
                                    domain=SimpleNamespace(pieces_limit=limit))
        self.frequency_hz = np.array([1000.0 / chunk])

    def frames(self, e: np.ndarray, i: np.ndarray, last: float) -> dict:
        me, mi = e.reshape(-1, self.meta.chunk_samples).mean(1), i.reshape(
            -1, self.meta.chunk_samples).mean(1)
        step = np.abs(np.diff(np.concatenate([[last], me])))
        return {"contact": np.where(me > 0, 0.9, 0.1)[None], "detach_margin": mi[None],
                "touch": (step > 0.5)[None] * 2.0}

    def run(self, e, i, t_re, t_im, hue0, state):
        out = self.frames(e[0], i[0], state[0, 0])
        n = state[0, 1] + out["contact"].shape[1]
        total = state[0, 2] + out["detach_margin"].sum()
        wall, inside = total / n < 5.0, total / n < 0.5
        return {**out, "gap": np.array([total / n if wall else np.nan]),
                "sigma": np.array([0.05 if inside else np.nan]),
                "in_domain": np.array([inside or not wall]), "domain_score": np.array([n]),
                "next_state": np.array([[e[0, -self.meta.chunk_samples:].mean(), n, total]])}

    def half_widths(self, out: dict) -> dict:
        """The 95 % half-width: 1.5 × the running gap (a stand-in's, not σ's)."""
        return {"sigma_95": 1.5 * out["gap"]}


def _stream_data(chunk: int, n_frames: int, offsets: list[float]) -> tuple[np.ndarray, ...]:
    """A stand-in's stream: e at +-1 in blocks of six frames (contacts where +1), plus noise;
    i (the margin) 0.02 x e's level a frame later, plus each record's offset (``offsets``, one
    per record of ``n_frames / len(offsets)`` frames)."""
    rng = np.random.default_rng(4)
    level = np.repeat(np.where(rng.random(n_frames // 6) < 0.4, 1.0, -1.0), 6)
    e = np.repeat(level, chunk) + 0.1 * rng.standard_normal(n_frames * chunk)
    i = 0.02 * np.roll(np.repeat(level, chunk), chunk) + np.repeat(offsets, n_frames * chunk
                                                                    // len(offsets))
    return e, i


def _serve(fake: FakeStream, monkeypatch, tmp_path: Path) -> Path:
    """``wtml stream`` loading ``fake`` for any model folder; the calibration file it reads."""
    monkeypatch.setattr(stream_module, "task_of", lambda model_dir: "onset")
    monkeypatch.setattr(stream_module, "load_export", lambda *a, **k: (None, None, fake))
    np.savez(tmp_path / "cal.npz", frequency_hz=fake.frequency_hz, t=np.eye(2)[None] + 0j,
             hue0=1.0)
    return tmp_path / "cal.npz"


OFFSETS = [1.0, 0.0, 0.01, 0.3, 0.31, 10.0, 10.0, 0.0]
"""Eight records' margins (the stand-in's gaps): out of domain, in, alike, moved 4 σ, alike,
no wall, none again, a wall back."""

@pytest.mark.parametrize("first_alone", [True, False])
@pytest.mark.parametrize("records", [1, 8])
def test_run_stream_carries_its_state_across_reads_of_any_size(tmp_path, monkeypatch, records,
                                                               first_alone):
    """``wtml stream``'s loop (run_stream) on a stand-in graph, read in chunks of one, three
    and seven graph chunks (a trailing piece shorter than a chunk left out), as one record or
    eight: the offline rule's contacts on the frames of each record from a fresh state, every
    time; each record's answer after its last chunk's contact lines, judged with the record
    before as two pieces (:data:`OFFSETS`: in domain where both are and their walls lie within
    3 σ, or neither finds one). The first record: answered at its end, alone, with
    ``first_alone``; otherwise held, then answered after the second with the pair's verdict
    (a stream of one record: alone, at its end)."""
    chunk, n_frames = 8, 120
    e, i = _stream_data(chunk, n_frames, OFFSETS if records > 1 else [0.0])
    fake = FakeStream(chunk, record=n_frames * chunk // records)
    cal = _serve(fake, monkeypatch, tmp_path)
    per = fake.meta.n_samples
    frames = [fake.frames(e[k:k + per], i[k:k + per], 0.0) for k in range(0, len(e), per)]
    frames = {key: np.concatenate([f[key] for f in frames], 1) for key in frames[0]}
    on, off = contacts_from(frames, Timing.of(fake.meta))
    want = on[0][np.isfinite(on[0])], off[0][np.isfinite(on[0])]
    assert len(want[0]) >= 3
    gaps = frames["detach_margin"][0].reshape(records, -1).mean(1)
    if records > 1:
        inside = [False, False, True, False, True, False, True, False]
        step = np.abs(np.diff(gaps[1:5])) / np.hypot(0.05, 0.05)
        apart = [np.nan, *step, np.inf, 0.0, np.inf]
        assert list(step > 3.0) == [False, True, False]
        gaps[gaps > 5] = np.nan
    else:
        inside, apart = [True], []
    data = np.stack([e, i], -1).astype("<f4").tobytes() + b"\0" * 20  # a trailing piece
    for reads in (1, 3, 7):
        emitted: list = []
        got = stream_module.run_stream("fake", io.BytesIO(data), cal, emit=emitted.append,
                                       chunk_samples=reads * chunk, first_alone=first_alone)
        onsets = [x.event.time for x in got.events if x.event.kind == "onset"]
        ends = [x.event.time for x in got.events if x.event.kind == "detachment"]
        np.testing.assert_allclose(onsets, want[0], atol=1e-12)
        np.testing.assert_allclose(ends, want[1], atol=1e-12)
        # the wall is the record's: no contact line claims one; each record's line comes
        # after the contacts its last chunk decided
        assert all("gap_m" not in x.line() for x in got.events)
        order = [(x.decided_s, hasattr(x, "end_s")) for x in emitted]
        assert order == sorted(order) and len(emitted) == len(got.events) + records
        assert got.chunks == n_frames and abs(got.signal_s - n_frames * chunk / 1e3) < 1e-12
        assert got.unanswered_s == 0 and "not answered" not in got.text()
        assert [r.number for r in got.records] == list(range(records))
        np.testing.assert_allclose([r.gap_m for r in got.records], gaps, rtol=1e-6)
        np.testing.assert_allclose([r.end_s for r in got.records],
                                   np.arange(1, records + 1) * per / 1e3)
        np.testing.assert_allclose([r.apart_sigma for r in got.records[1:]], apart, rtol=1e-3)
        assert [r.apart for r in got.records[1:]] == [a > 3.0 for a in apart]
        assert [r.in_domain for r in got.records[1:]] == inside[1:]
        # a pair's score: the larger of the records' (the frames seen) and its spread over
        # the limit
        np.testing.assert_allclose([r.domain_score for r in got.records[1:]], np.fmax(
            n_frames / records, np.array(apart, float) / 3.0), rtol=1e-3)
        first = got.records[0]
        if first_alone or records == 1:  # judged alone, at its own end
            assert np.isnan(first.apart_sigma) and not first.apart
            assert first.in_domain == inside[0] and first.domain_score == n_frames / records
            assert first.decided_s == first.end_s
        else:  # held, then judged with the second: the pair's verdict, the second's end
            second = got.records[1]
            np.testing.assert_equal(
                (first.apart_sigma, first.apart, first.in_domain, first.domain_score),
                (second.apart_sigma, second.apart, second.in_domain, second.domain_score))
            assert first.decided_s == second.end_s == second.decided_s
            assert emitted.index(first) == emitted.index(second) - 1
        assert got.stats()["records_apart"] == (3 if records > 1 else 0)
        assert "apart=" in got.records[-1].line() and "sigma_95_m=" in got.records[-1].line()
        assert [r.sigma_95_m for r in got.records] == pytest.approx(
            list(1.5 * gaps), rel=1e-6, nan_ok=True)


def test_a_stream_past_one_record_needs_the_exports_limit_for_two(tmp_path, monkeypatch):
    """An export without ``domain.pieces_limit`` answers one record of a stream: the loop
    stops at its end, saying why, its contacts and its answer given."""
    chunk, n_frames = 8, 120
    e, i = _stream_data(chunk, n_frames, [0.0])
    fake = FakeStream(chunk, record=n_frames * chunk // 4, limit=0.0)
    cal = _serve(fake, monkeypatch, tmp_path)
    got = stream_module.run_stream("fake", io.BytesIO(np.stack([e, i], -1).astype(
        "<f4").tobytes()), cal, chunk_samples=7 * chunk)
    assert got.chunks == n_frames // 4 and len(got.records) == 1
    assert abs(got.signal_s - n_frames * chunk / 4e3) < 1e-12 and got.unanswered_s == 0
    assert "domain.pieces_limit" in got.stopped and "stopped:" in got.text()
    path = tmp_path / "stream.f32"
    path.write_bytes(np.stack([e, i], -1).astype("<f4").tobytes())
    assert main(["stream", "--model", "fake", "--calibration", str(cal),
                 "--input", str(path)]) == 1  # stopped before the input's end


def test_a_stream_says_what_it_left_unanswered(tmp_path, monkeypatch):
    """A stream that ends inside a record: its contacts printed, the whole records answered,
    the rest named in the summary."""
    chunk, n_frames = 8, 120
    e, i = _stream_data(chunk, n_frames, [0.0])
    fake = FakeStream(chunk, record=50 * chunk)
    cal = _serve(fake, monkeypatch, tmp_path)
    got = stream_module.run_stream("fake", io.BytesIO(np.stack([e, i], -1).astype(
        "<f4").tobytes()), cal)
    assert len(got.records) == 2 and got.chunks == n_frames
    assert got.unanswered_s == pytest.approx(20 * chunk / 1e3)
    assert "the last 0.160 s, less than a record, not answered" in got.text()
    fake.meta.n_samples = 50 * chunk + 3  # no chunk ends a record
    with pytest.raises(InputError, match="not whole chunks of its streaming graph"):
        stream_module.run_stream("fake", io.BytesIO(b""), cal)


def test_the_first_record_held_is_flagged_by_a_wall_that_moved(tmp_path, monkeypatch, capsys):
    """Two records whose walls lie 4 σ apart (a floor that moved): judged alone, the first is
    in domain; held (the default), it takes the pair's verdict, apart and out of domain, and
    its line comes after the second's last chunk (``wtml stream``; ``--first-alone`` prints
    it at its end, judged alone)."""
    chunk, n_frames = 8, 120
    e, i = _stream_data(chunk, n_frames, [0.0, 0.3])
    fake = FakeStream(chunk, record=n_frames * chunk // 2)
    cal = _serve(fake, monkeypatch, tmp_path)
    path = tmp_path / "stream.f32"
    path.write_bytes(np.stack([e, i], -1).astype("<f4").tobytes())
    lines = {}
    for flag in ([], ["--first-alone"]):
        assert main(["stream", "--model", "fake", "--calibration", str(cal), "--input",
                     str(path), *flag]) == 0
        out = capsys.readouterr()
        lines[bool(flag)] = [x for x in out.out.splitlines() if x.startswith("record")]
        # the moved floor counts once: the second record is apart from the one before
        assert "2 records, 1 apart from the one before" in out.err
    alone, held = lines[True][0], lines[False][0]
    assert "number=0" in alone and "in_domain=1" in alone and "apart=0" in alone
    assert "decided_s=0.480000" in alone and "apart_sigma=nan" in alone
    assert "number=0" in held and "in_domain=0" in held and "apart=1" in held
    assert "decided_s=0.960000" in held
    assert lines[True][1] == lines[False][1].replace(
        lines[False][1].split("latency_ms=")[1].split()[0],
        lines[True][1].split("latency_ms=")[1].split()[0])  # the second's line alike


def test_a_held_first_record_is_answered_alone_where_the_stream_ends_in_the_second(
        tmp_path, monkeypatch):
    """A stream that ends part-way into the second record: the held first record is answered
    once, judged alone, decided at the stream's end (after the second record's contact lines,
    whose decided_s stay below it); the rest is named unanswered."""
    chunk, n_frames = 8, 120
    e, i = _stream_data(chunk, n_frames, [0.0])
    fake = FakeStream(chunk, record=80 * chunk)  # a record and a half
    cal = _serve(fake, monkeypatch, tmp_path)
    emitted: list = []
    got = stream_module.run_stream("fake", io.BytesIO(np.stack([e, i], -1).astype(
        "<f4").tobytes()), cal, emit=emitted.append)
    (first,) = got.records
    assert first.number == 0 and np.isnan(first.apart_sigma) and first.in_domain
    assert first.end_s == pytest.approx(0.64) and first.decided_s == pytest.approx(0.96)
    assert emitted[-1] is first and all(x.decided_s <= first.decided_s for x in emitted)
    assert any(x.decided_s > first.end_s for x in got.events)  # the second's contacts first
    assert got.unanswered_s == pytest.approx(0.32) and got.stats()["records_apart"] == 0
