"""``wtml stream``: the onset export's streaming graph (``stream.onnx``) on a live acquisition.

Samples arrive as interleaved little-endian float32 pairs ``(e, i)`` (V, and A or the volts
of the I–V converter scaled by ``i_scale``) at the model's sampling rate, from standard input
(a pipe from the acquisition program) or a file. They are read in fixed chunks of
``chunk_samples`` pairs (the graph's chunk, or a whole multiple of it); each graph chunk runs
with the state the previous one left, and its frames go through
:class:`wtml.runtime.contacts.ContactTracker`, the offline timing rule run online. Each
contact is printed as soon as it is decided: its onset, then its detachment; each line says
when, in signal time, the frame that decided it ended and how long after the arrival of the
read that held that frame it was printed. A stream has no cap on its contacts (the scene's
``max_contacts`` is a record's).

The graph answers records of the trained length (``n_samples``: whole whisk cycles), so a
stream is read as such records one after the other: the state starts from zeros at each
record's first sample (the whisk's phase then is the trained record's), and after its last
chunk the record's answer is printed (:class:`RecordAnswer`: the offline graph's on that
record), the wall's location with its σ and domain flag. Each record is judged with its
neighbour as ``wtml predict`` judges the two pieces of a recording of twice the trained
length (:func:`wtml.runtime.onset.combine_pieces`, the export's ``domain.pieces_limit``): a
still wall is met alike in both, one that moves with the floor elsewhere. From the second
record on the neighbour is the record before; the first is held until the second ends and
judged with it (judged alone, it answered 15 of 86 streams at a floor moving 0.8 µm rms, 2
of those 15 within ±1σ), unless ``first_alone`` asks for its answer at once, or the stream
ends first. An export without that limit (before format 4, or a scene whose records do not
hold whole cycles) answers the first record only, alone. Numpy and onnxruntime only.
"""

from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

import numpy as np

from wtml.files import within_ceiling
from wtml.runtime.contacts import ContactTracker, Event, Timing
from wtml.runtime.onset import combine_pieces, read_onset_calibration
from wtml.runtime.predict import InputError, load_export, task_of

PAIR_BYTES = 8
"""Bytes of one sample pair: float32 e, float32 i."""


@dataclass
class StreamEvent:
    """One printed contact event: the tracker's :class:`~wtml.runtime.contacts.Event`, the
    signal time (s) at the end of the frame that decided it, and the wall-clock seconds from
    the arrival of the read that held that frame to the event (the graph's work on the read's
    earlier chunks included). The wall's location is its record's (:class:`RecordAnswer`):
    the graph's running answer before a record's end is not one it was trained to give (at a
    record's first detachment it lies many of its σ from the wall: docs/runtime.md, "Streams
    read record by record")."""

    event: Event
    decided_s: float
    latency_s: float

    def line(self) -> str:
        """The event as one ``key=value`` line."""
        e = self.event
        return (f"{e.kind:<10} contact={e.contact} t_s={e.time:.6f} "
                f"decided_s={self.decided_s:.6f} latency_ms={1e3 * self.latency_s:.3f}")


@dataclass
class RecordAnswer:
    """One record's answer, printed once decided (after the contact lines of the chunk that
    decided it): its number (from 0), its start and end in signal time (s), when it was
    decided (s: its end; the second record's for a first record held to be judged with it,
    or the stream's end where none came), the wall-clock seconds from the arrival of the
    read that held the deciding chunk (its own last for a first record answered alone at the
    stream's end: the wait for the end included), and the graph's ``gap``,
    ``sigma`` and ``sigma_95`` at the record's end (m; ``gap`` NaN where it found no wall,
    ``sigma`` NaN there and out of domain). It and its neighbour (the record before; for the
    first record, the second) are judged as the two pieces of a
    recording of twice the trained length (:func:`~wtml.runtime.onset.combine_pieces`, the
    export's limit): ``apart_sigma``, how far they locate the wall apart in their σ (0 where
    neither found a wall; inf where one found a wall and the other none; NaN where either has
    no σ, and for a record judged alone); ``apart``, that over the limit (a wall that moved,
    came or went between them); ``in_domain``, both records in the graph's domain and not
    ``apart``; ``domain_score``, the larger of theirs and the spread over the limit (a record
    judged alone: its own flag and score)."""

    number: int
    start_s: float
    end_s: float
    decided_s: float
    latency_s: float
    gap_m: float
    sigma_m: float
    sigma_95_m: float
    domain_score: float
    apart_sigma: float
    apart: bool
    in_domain: bool

    def line(self) -> str:
        """The answer as one ``key=value`` line."""
        return (f"record     number={self.number} t_s={self.start_s:.6f} "
                f"decided_s={self.decided_s:.6f} latency_ms={1e3 * self.latency_s:.3f} "
                f"gap_m={self.gap_m:.6g} sigma_m={self.sigma_m:.3g} "
                f"sigma_95_m={self.sigma_95_m:.3g} domain_score={self.domain_score:.3g} "
                f"apart_sigma={self.apart_sigma:.3g} apart={int(self.apart)} "
                f"in_domain={int(self.in_domain)}")


@dataclass
class StreamSummary:
    """What a stream took: graph chunks run, seconds of signal, wall seconds spent in the
    graph and the tracker per graph chunk (``(n_chunks,)``), the contact events in order, the
    records' answers in order, whether it ended by Ctrl-C, why it stopped before the end of
    its input (empty: it did not), and the seconds of signal run after the last whole record
    (less than a record: their contacts printed, no answer)."""

    chunks: int = 0
    signal_s: float = 0.0
    per_chunk_s: list[float] = field(default_factory=list)
    events: list[StreamEvent] = field(default_factory=list)
    records: list[RecordAnswer] = field(default_factory=list)
    interrupted: bool = False
    stopped: str = ""
    unanswered_s: float = 0.0

    def stats(self) -> dict:
        """``chunks``, ``signal_s``, ``work_s`` (s), ``real_time_factor`` (work over signal),
        ``median_chunk_ms``, ``p99_chunk_ms``, ``contacts``, ``records`` (whole records
        answered) and ``records_apart``; at least one chunk run."""
        busy = np.array(self.per_chunk_s)
        return {"chunks": self.chunks, "signal_s": self.signal_s, "work_s": float(busy.sum()),
                "real_time_factor": float(busy.sum() / self.signal_s),
                "median_chunk_ms": 1e3 * float(np.median(busy)),
                "p99_chunk_ms": 1e3 * float(np.quantile(busy, 0.99)),
                "contacts": sum(e.event.kind == "onset" for e in self.events),
                "records": len(self.records),
                "records_apart": sum(r.apart for r in self.records if r.number)}

    def text(self) -> str:
        """One line: chunks, signal, real-time factor, per-chunk latency."""
        if not self.chunks:
            return "no whole chunk arrived"
        end = (f"; the last {self.unanswered_s:.3f} s, less than a record, not answered"
               if self.unanswered_s else "")
        end += (" (stopped by Ctrl-C)" if self.interrupted
                else f" (stopped: {self.stopped})" if self.stopped else "")
        s = self.stats()
        return (f"{s['chunks']} chunks, {s['signal_s']:.3f} s of signal in {s['work_s']:.3f} s "
                f"of work: real-time factor {s['real_time_factor']:.4f}; per chunk median "
                f"{s['median_chunk_ms']:.3f} ms, 99th percentile {s['p99_chunk_ms']:.3f} ms; "
                f"{s['contacts']} contacts; {s['records']} records, {s['records_apart']} "
                f"apart from the one before{end}")


def read_chunk(source: BinaryIO, size: int) -> bytes:
    """Up to ``size`` bytes from ``source``, fewer only at its end (a pipe may deliver a chunk
    in pieces)."""
    parts, got = [], 0
    while got < size:
        piece = source.read(size - got)
        if not piece:
            break
        parts.append(piece)
        got += len(piece)
    return b"".join(parts)


class Streamer:
    """An onset export's streaming graph, checked and ready before any sample is read (so that
    a named pipe is opened only once the model and the calibration are known good).

    Args:
        model_dir: the onset export folder (its ``stream.onnx``).
        calibration: the device's calibration (:func:`read_onset_calibration`).
        chunk_samples: pairs per read, a whole multiple of the graph's chunk (default: the
            graph's).
        e_scale, i_scale: V per recorded unit and A per recorded unit (the I–V converter's).
        sample_rate_hz: the acquisition's rate, checked against the model's (no resampling
            on a stream); None: taken to be the model's.
        threads: onnxruntime's intra-op threads (1: one core).
        first_alone: answer the first record at its end, judged alone, instead of holding it
            until the second ends to judge the two together.

    Raises:
        InputError: not an onset export, another rate, a chunk that is not a whole multiple of
            the graph's or whose read would pass the memory ceiling, a graph whose chunks do
            not make whole records, a scale that is not a positive finite number, a bad
            calibration.
    """

    def __init__(self, model_dir: str | Path, calibration: str | Path | None, *,
                 chunk_samples: int | None = None, e_scale: float = 1.0, i_scale: float = 1.0,
                 sample_rate_hz: float | None = None, threads: int = 1,
                 first_alone: bool = False) -> None:
        task = task_of(model_dir)
        if task != "onset":
            raise InputError(f"{model_dir}: a {task} export; wtml stream runs onset exports "
                             "(their stream.onnx)")
        self.model = load_export(model_dir, stream=True, threads=threads)[2]
        meta = self.model.meta
        if sample_rate_hz is not None and sample_rate_hz != meta.sample_rate_hz:
            raise InputError(f"--sample-rate {sample_rate_hz:g}: the model takes "
                             f"{meta.sample_rate_hz:g} Hz and a stream is not resampled")
        for name, value in (("--e-scale", e_scale), ("--i-scale", i_scale)):
            if not (math.isfinite(value) and value > 0):
                raise InputError(f"{name}: must be a finite number > 0, got {value:g}")
        self.graph_chunk = meta.chunk_samples
        self.chunk = chunk_samples or self.graph_chunk
        if self.chunk < 1 or self.chunk % self.graph_chunk:
            raise InputError(f"--chunk-samples {self.chunk}: must be a whole multiple of the "
                             f"graph's chunk, {self.graph_chunk} samples "
                             f"({self.graph_chunk / meta.sample_rate_hz:g} s)")
        # the read, its float32 view's two scaled copies
        within_ceiling(f"--chunk-samples {self.chunk}", 3 * self.chunk * PAIR_BYTES,
                       "reading one chunk")
        self.scales = np.float32(e_scale), np.float32(i_scale)
        self.calibration = read_onset_calibration(calibration, float(self.model.frequency_hz[0]),
                                                  1)
        self.timing = Timing.of(meta)
        self.record = meta.n_samples
        if self.record % self.graph_chunk:
            raise InputError(f"{model_dir}: its records ({self.record} samples) are not whole "
                             f"chunks of its streaming graph ({self.graph_chunk} samples), so "
                             "no chunk ends a record: export it again from a scene whose "
                             "records hold whole probe periods")
        self.limit = meta.domain.pieces_limit  # for two records one after the other
        self.first_alone = first_alone

    def run(self, source: BinaryIO, emit: Callable[[StreamEvent | RecordAnswer], None] | None
            = None) -> StreamSummary:
        """Run the graph over ``source`` (interleaved float32 ``(e, i)`` pairs), record after
        record, until its end, Ctrl-C (either closes the open contact) or, for an export
        without a limit for records one after the other, the end of the first record;
        calling ``emit`` with each contact event as it is decided and each record's answer
        once decided: after its last chunk; the first record's after the second's (or at
        the stream's end, judged alone, where no second came) unless ``first_alone``.

        Raises:
            InputError: NaN or inf in the stream (naming the sample).
        """
        meta, frame_s, rate = self.model.meta, self.timing.frame_s, self.model.meta.sample_rate_hz
        tracker = ContactTracker(self.timing)
        zeros = np.zeros((1, meta.state_size), np.float32)
        summary = StreamSummary()
        out: dict = {}
        previous: dict = {}  # the record before's own gap, sigma, in_domain, domain_score
        held: list[tuple[dict, float]] = []  # the first record's answer and its last read's
        # arrival, held to be judged with the second

        def send(item: StreamEvent | RecordAnswer) -> None:
            (summary.records if isinstance(item, RecordAnswer) else summary.events).append(item)
            if emit is not None:
                emit(item)

        def report(events: list[Event], arrived: float) -> None:
            for event in events:
                send(StreamEvent(event, (event.decided_frame + 1) * frame_s,
                                 time.perf_counter() - arrived))

        def answer(number: int, arrived: float) -> None:
            """The record's answer after its last chunk, judged with the one before as the
            two pieces of a longer recording are (:func:`combine_pieces`); the first record
            held (module docstring), then answered with the second's verdict."""
            wide = self.model.half_widths(out)
            own = {key: np.asarray(out[key][:1], float if key != "in_domain" else bool)
                   for key in ("gap", "sigma", "in_domain", "domain_score")}
            pair = (combine_pieces({key: np.concatenate([previous[key], own[key]])
                                    for key in own}, 2, self.limit)
                    if previous else None)
            previous.update(own)
            end = (number + 1) * self.record / rate
            this = {"number": number, "start_s": number * self.record / rate, "end_s": end,
                    "gap_m": float(own["gap"][0]), "sigma_m": float(own["sigma"][0]),
                    "sigma_95_m": float(wide["sigma_95"][0]) if wide else math.nan}
            verdict = ({"domain_score": float(pair["domain_score"][0]),
                        "apart_sigma": float(pair["pieces_spread"][0]),
                        "apart": bool(pair["pieces_apart"][0]),
                        "in_domain": bool(pair["in_domain"][0])} if pair else
                       {"domain_score": float(own["domain_score"][0]), "apart_sigma": math.nan,
                        "apart": False, "in_domain": bool(own["in_domain"][0])})
            if pair is None and self.limit and not self.first_alone:
                held.append((this | verdict, arrived))  # alone only if no second comes
                return
            firsts, held[:] = held[:], []  # taken before printing: Ctrl-C prints none twice
            for first, _ in firsts:  # judged with this one: the pair's verdict
                send(RecordAnswer(**first | verdict, decided_s=end,
                                  latency_s=time.perf_counter() - arrived))
            send(RecordAnswer(**this | verdict, decided_s=end,
                              latency_s=time.perf_counter() - arrived))

        read, step, state = 0, self.graph_chunk, zeros
        try:
            while not summary.stopped:
                data = read_chunk(source, self.chunk * PAIR_BYTES)
                arrived = time.perf_counter()
                whole = len(data) // (step * PAIR_BYTES) * step
                if len(data) > whole * PAIR_BYTES:
                    print(f"wtml stream: the last {len(data) // PAIR_BYTES - whole} sample "
                          f"pairs (and {len(data) % PAIR_BYTES} bytes) are less than a chunk: "
                          "not run", file=sys.stderr)
                if not whole:
                    break
                pairs = np.frombuffer(data, "<f4", 2 * whole).reshape(whole, 2)
                bad = ~np.isfinite(pairs)
                if bad.any():
                    k, c = np.argwhere(bad)[0]
                    raise InputError(f"stream: {'ei'[c]} is NaN or inf at sample {read + k}")
                e, i = pairs[:, 0] * self.scales[0], pairs[:, 1] * self.scales[1]
                for k in range(0, whole, step):
                    at = read + k  # the chunk's first sample in the stream
                    if not self.limit and at + step > self.record:
                        summary.stopped = (
                            f"this export answers one record of {self.record / rate:g} s: "
                            "records one after the other need an export that states how far "
                            "two of them may locate the wall apart (metadata "
                            "domain.pieces_limit: exports of format 4, since 30 Nov, of a "
                            "scene whose records hold whole whisk and probe cycles)")
                        break
                    if at and at % self.record == 0:  # a new record, from the trained phase
                        state = zeros
                    start = time.perf_counter() if k else arrived
                    out = self.model.run(e[None, k:k + step], i[None, k:k + step],
                                         *self.calibration, state)
                    state = out["next_state"].astype(np.float32)
                    events = []
                    for f in range(out["contact"].shape[1]):
                        events += tracker.push(out["contact"][0, f], out["detach_margin"][0, f],
                                               out["touch"][0, f])
                    report(events, arrived)
                    if (at + step) % self.record == 0:
                        answer((at + step) // self.record - 1, arrived)
                    summary.per_chunk_s.append(time.perf_counter() - start)
                    summary.chunks += 1
                    summary.signal_s = (at + step) / rate
                read += whole
                if whole < self.chunk:
                    break
        except KeyboardInterrupt:
            summary.interrupted = True
        for first, arrived in held:  # no second record came: the first judged alone, now
            send(RecordAnswer(**first, decided_s=summary.signal_s,
                              latency_s=time.perf_counter() - arrived))
        report(tracker.finish(), time.perf_counter())
        ran = summary.chunks * step  # samples
        summary.unanswered_s = max(0, ran - len(summary.records) * self.record) / rate
        return summary


def run_stream(model_dir: str | Path, source: BinaryIO, calibration: str | Path | None, *,
               emit: Callable[[StreamEvent], None] | None = None, **options) -> StreamSummary:
    """:class:`Streamer` (``options``: its keyword arguments) run over ``source``."""
    return Streamer(model_dir, calibration, **options).run(source, emit)
