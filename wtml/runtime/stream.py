"""``wtml stream``: the onset export's streaming graph (``stream.onnx``) on a live acquisition.

Samples arrive as interleaved little-endian float32 pairs ``(e, i)`` (V, and A or the volts
of the I–V converter scaled by ``i_scale``) at the model's sampling rate, from standard input
(a pipe from the acquisition program) or a file. They are read in fixed chunks of
``chunk_samples`` pairs (the graph's chunk, or a whole multiple of it); each graph chunk runs
with the state the previous one left (zeros at the start), and its frames go through
:class:`wtml.runtime.contacts.ContactTracker`, the offline timing rule run online. Each
contact is printed as soon as it is decided: its onset, then its detachment with the wall's
location (the running ``gap`` and ``sigma`` after the chunk that ended it) and the domain
flag; each line says which chunk decided it and how long after that chunk's arrival it was
printed. Numpy and onnxruntime only.
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

from wtml.runtime.contacts import ContactTracker, Event, Timing
from wtml.runtime.onset import read_onset_calibration
from wtml.runtime.predict import InputError, load_export

PAIR_BYTES = 8
"""Bytes of one sample pair: float32 e, float32 i."""


@dataclass
class StreamEvent:
    """One printed contact event: the tracker's :class:`~wtml.runtime.contacts.Event`, the
    signal time (s) at the end of the chunk that decided it, the wall-clock seconds from that
    chunk's arrival to the event, and (detachment only) the running answers then."""

    event: Event
    decided_s: float
    latency_s: float
    gap_m: float = math.nan
    sigma_m: float = math.nan
    in_domain: bool = True

    def line(self) -> str:
        """The event as one ``key=value`` line."""
        e = self.event
        text = (f"{e.kind:<10} contact={e.contact} t_s={e.time:.6f} "
                f"decided_s={self.decided_s:.6f} latency_ms={1e3 * self.latency_s:.3f}")
        if e.kind == "detachment":
            text += (f" gap_m={self.gap_m:.6g} sigma_m={self.sigma_m:.3g} "
                     f"in_domain={int(self.in_domain)}")
        return text


@dataclass
class StreamSummary:
    """What a stream took: graph chunks run, seconds of signal, wall seconds spent in the
    graph and the tracker per graph chunk (``(n_chunks,)``)."""

    chunks: int = 0
    signal_s: float = 0.0
    per_chunk_s: list[float] = field(default_factory=list)
    events: list[StreamEvent] = field(default_factory=list)

    def text(self) -> str:
        """One line: chunks, signal, real-time factor, per-chunk latency."""
        if not self.chunks:
            return "no whole chunk arrived"
        busy = np.array(self.per_chunk_s)
        return (f"{self.chunks} chunks, {self.signal_s:.3f} s of signal in {busy.sum():.3f} s "
                f"of work: real-time factor {busy.sum() / self.signal_s:.4f}; per chunk "
                f"median {1e3 * np.median(busy):.3f} ms, 99th percentile "
                f"{1e3 * np.quantile(busy, 0.99):.3f} ms; "
                f"{sum(e.event.kind == 'onset' for e in self.events)} contacts")


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


def run_stream(model_dir: str | Path, source: BinaryIO, calibration: str | Path | None, *,
               chunk_samples: int | None = None, e_scale: float = 1.0, i_scale: float = 1.0,
               sample_rate_hz: float | None = None, threads: int = 1,
               emit: Callable[[StreamEvent], None] | None = None) -> StreamSummary:
    """Run an onset export's streaming graph over ``source`` (module docstring).

    Args:
        model_dir: the onset export folder (its ``stream.onnx``).
        source: binary stream of interleaved float32 ``(e, i)`` pairs.
        calibration: the device's calibration (:func:`read_onset_calibration`).
        chunk_samples: pairs per read, a whole multiple of the graph's chunk (default: the
            graph's).
        e_scale, i_scale: V per recorded unit and A per recorded unit (the I–V converter's).
        sample_rate_hz: the acquisition's rate, checked against the model's (no resampling
            on a stream); None: taken to be the model's.
        threads: onnxruntime's intra-op threads (1: one core).
        emit: called with each event as it is decided (e.g. to print it).

    Raises:
        InputError: not an onset export, another rate, a chunk that is not a whole multiple of
            the graph's, a scale that is not a positive finite number, NaN or inf in the
            stream (naming the sample).
    """
    models = load_export(model_dir, stream=True, threads=threads)
    stream = models[2]
    meta = stream.meta
    if meta.task != "onset":
        raise InputError(f"{model_dir}: a {meta.task} export; wtml stream runs onset exports")
    if sample_rate_hz is not None and sample_rate_hz != meta.sample_rate_hz:
        raise InputError(f"--sample-rate {sample_rate_hz:g}: the model takes "
                         f"{meta.sample_rate_hz:g} Hz and a stream is not resampled")
    for name, value in (("--e-scale", e_scale), ("--i-scale", i_scale)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{name}: must be a finite number > 0, got {value:g}")
    graph_chunk = meta.chunk_samples
    chunk = chunk_samples or graph_chunk
    if chunk < 1 or chunk % graph_chunk:
        raise InputError(f"--chunk-samples {chunk}: must be a whole multiple of the graph's "
                         f"chunk, {graph_chunk} samples ({graph_chunk / meta.sample_rate_hz:g} s)")
    cal = read_onset_calibration(calibration, float(stream.frequency_hz[0]), 1)
    timing = Timing.of(meta)
    tracker = ContactTracker(timing)
    state = np.zeros((1, meta.state_size), np.float32)
    summary = StreamSummary()
    frame_s = timing.frame_s
    out: dict = {}

    def report(events: list[Event], arrived: float) -> None:
        for event in events:
            item = StreamEvent(event, (event.decided_frame + 1) * frame_s,
                               time.perf_counter() - arrived)
            if event.kind == "detachment":
                item.gap_m, item.sigma_m = float(out["gap"][0]), float(out["sigma"][0])
                item.in_domain = bool(out["in_domain"][0])
            summary.events.append(item)
            if emit is not None:
                emit(item)

    read = 0
    while True:
        data = read_chunk(source, chunk * PAIR_BYTES)
        arrived = time.perf_counter()
        whole = len(data) // (graph_chunk * PAIR_BYTES) * graph_chunk
        if len(data) > whole * PAIR_BYTES:
            print(f"wtml stream: the last {len(data) // PAIR_BYTES - whole} sample pairs (and "
                  f"{len(data) % PAIR_BYTES} bytes) are less than a chunk: not run",
                  file=sys.stderr)
        if not whole:
            break
        pairs = np.frombuffer(data, "<f4", 2 * whole).reshape(whole, 2)
        bad = ~np.isfinite(pairs)
        if bad.any():
            k, c = np.argwhere(bad)[0]
            raise InputError(f"stream: {'ei'[c]} is NaN or inf at sample {read + k}")
        e = pairs[:, 0] * np.float32(e_scale)
        i = pairs[:, 1] * np.float32(i_scale)
        for k in range(0, whole, graph_chunk):
            start = time.perf_counter() if k else arrived
            out = stream.run(e[None, k:k + graph_chunk], i[None, k:k + graph_chunk], *cal, state)
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
        if whole < chunk:
            break
    report(tracker.finish(), time.perf_counter())
    return summary
