"""``wtml stream``: the onset export's streaming graph (``stream.onnx``) on a live acquisition.

Samples arrive as interleaved little-endian float32 pairs ``(e, i)`` (V, and A or the volts
of the I–V converter scaled by ``i_scale``) at the model's sampling rate, from standard input
(a pipe from the acquisition program) or a file. They are read in fixed chunks of
``chunk_samples`` pairs (the graph's chunk, or a whole multiple of it); each graph chunk runs
with the state the previous one left (zeros at the start), and its frames go through
:class:`wtml.runtime.contacts.ContactTracker`, the offline timing rule run online. Each
contact is printed as soon as it is decided: its onset, then its detachment with the wall's
location (the running ``gap`` and ``sigma`` after the chunk that ended it) and the domain
flag; each line says when, in signal time, the frame that decided it ended and how long after
the arrival of the read that held that frame it was printed. A stream has no record: its
contacts are not capped at the scene's ``max_contacts``. Numpy and onnxruntime only.
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
from wtml.runtime.onset import read_onset_calibration
from wtml.runtime.predict import InputError, load_export, task_of

PAIR_BYTES = 8
"""Bytes of one sample pair: float32 e, float32 i."""


@dataclass
class StreamEvent:
    """One printed contact event: the tracker's :class:`~wtml.runtime.contacts.Event`, the
    signal time (s) at the end of the frame that decided it, the wall-clock seconds from the
    arrival of the read that held that frame to the event (the graph's work on the read's
    earlier chunks included), and (detachment only) the running answers then."""

    event: Event
    decided_s: float
    latency_s: float
    gap_m: float = math.nan
    sigma_m: float = math.nan
    sigma_95_m: float = math.nan
    in_domain: bool = True

    def line(self) -> str:
        """The event as one ``key=value`` line."""
        e = self.event
        text = (f"{e.kind:<10} contact={e.contact} t_s={e.time:.6f} "
                f"decided_s={self.decided_s:.6f} latency_ms={1e3 * self.latency_s:.3f}")
        if e.kind == "detachment":
            text += (f" gap_m={self.gap_m:.6g} sigma_m={self.sigma_m:.3g} "
                     f"sigma_95_m={self.sigma_95_m:.3g} in_domain={int(self.in_domain)}")
        return text


@dataclass
class StreamSummary:
    """What a stream took: graph chunks run, seconds of signal, wall seconds spent in the
    graph and the tracker per graph chunk (``(n_chunks,)``), the events in order, and whether
    it ended by Ctrl-C."""

    chunks: int = 0
    signal_s: float = 0.0
    per_chunk_s: list[float] = field(default_factory=list)
    events: list[StreamEvent] = field(default_factory=list)
    interrupted: bool = False

    def stats(self) -> dict:
        """``chunks``, ``signal_s``, ``work_s`` (s), ``real_time_factor`` (work over signal),
        ``median_chunk_ms``, ``p99_chunk_ms`` and ``contacts``; at least one chunk run."""
        busy = np.array(self.per_chunk_s)
        return {"chunks": self.chunks, "signal_s": self.signal_s, "work_s": float(busy.sum()),
                "real_time_factor": float(busy.sum() / self.signal_s),
                "median_chunk_ms": 1e3 * float(np.median(busy)),
                "p99_chunk_ms": 1e3 * float(np.quantile(busy, 0.99)),
                "contacts": sum(e.event.kind == "onset" for e in self.events)}

    def text(self) -> str:
        """One line: chunks, signal, real-time factor, per-chunk latency."""
        if not self.chunks:
            return "no whole chunk arrived"
        end = " (stopped by Ctrl-C)" if self.interrupted else ""
        s = self.stats()
        return (f"{s['chunks']} chunks, {s['signal_s']:.3f} s of signal in {s['work_s']:.3f} s "
                f"of work: real-time factor {s['real_time_factor']:.4f}; per chunk median "
                f"{s['median_chunk_ms']:.3f} ms, 99th percentile {s['p99_chunk_ms']:.3f} ms; "
                f"{s['contacts']} contacts{end}")


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

    Raises:
        InputError: not an onset export, another rate, a chunk that is not a whole multiple of
            the graph's or whose read would pass the memory ceiling, a scale that is not a
            positive finite number, a bad calibration.
    """

    def __init__(self, model_dir: str | Path, calibration: str | Path | None, *,
                 chunk_samples: int | None = None, e_scale: float = 1.0, i_scale: float = 1.0,
                 sample_rate_hz: float | None = None, threads: int = 1) -> None:
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

    def run(self, source: BinaryIO, emit: Callable[[StreamEvent], None] | None = None
            ) -> StreamSummary:
        """Run the graph over ``source`` (interleaved float32 ``(e, i)`` pairs) until its end
        or Ctrl-C (either closes the open contact), calling ``emit`` with each event as it is
        decided.

        Raises:
            InputError: NaN or inf in the stream (naming the sample).
        """
        meta, frame_s = self.model.meta, self.timing.frame_s
        tracker = ContactTracker(self.timing)
        state = np.zeros((1, meta.state_size), np.float32)
        summary = StreamSummary()
        out: dict = {}

        def report(events: list[Event], arrived: float) -> None:
            for event in events:
                item = StreamEvent(event, (event.decided_frame + 1) * frame_s,
                                   time.perf_counter() - arrived)
                if event.kind == "detachment":
                    item.gap_m, item.sigma_m = float(out["gap"][0]), float(out["sigma"][0])
                    wide = self.model.half_widths(out)
                    item.sigma_95_m = float(wide["sigma_95"][0]) if wide else math.nan
                    item.in_domain = bool(out["in_domain"][0])
                summary.events.append(item)
                if emit is not None:
                    emit(item)

        read, step = 0, self.graph_chunk
        try:
            while True:
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
                    start = time.perf_counter() if k else arrived
                    out = self.model.run(e[None, k:k + step], i[None, k:k + step],
                                         *self.calibration, state)
                    state = out["next_state"].astype(np.float32)
                    events = []
                    for f in range(out["contact"].shape[1]):
                        events += tracker.push(out["contact"][0, f], out["detach_margin"][0, f],
                                               out["touch"][0, f])
                    report(events, arrived)
                    summary.per_chunk_s.append(time.perf_counter() - start)
                    summary.chunks += 1
                read += whole
                summary.signal_s = read / meta.sample_rate_hz
                if whole < self.chunk:
                    break
        except KeyboardInterrupt:
            summary.interrupted = True
        report(tracker.finish(), time.perf_counter())
        return summary


def run_stream(model_dir: str | Path, source: BinaryIO, calibration: str | Path | None, *,
               emit: Callable[[StreamEvent], None] | None = None, **options) -> StreamSummary:
    """:class:`Streamer` (``options``: its keyword arguments) run over ``source``."""
    return Streamer(model_dir, calibration, **options).run(source, emit)
