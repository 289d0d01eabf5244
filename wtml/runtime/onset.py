"""Onset models on a device: the calibration, ``wtml predict``'s rows and the streaming graph.

Both graphs (``model.onnx``: the decoder; ``classical.onnx``: the thesis's pipeline) take
``e`` (V) and ``i`` (A), float32 ``(batch, n_samples)`` at the trained sampling rate, and the
user's calibration of their own device (the metadata's ``references``): ``t_re, t_im``
``(batch, 4)``, its T at the probe frequency flattened as (t11, t12, t21, t22), and ``hue0``
``(batch,)``, its HUE(0) in m/V (``wtml predict --calibration cal.npz``:
:func:`read_onset_calibration`); and they return ``gap`` (m), ``sigma`` (m; NaN for the
classical path and out of domain), ``contact`` (``(batch, n_frames)``: a probability per
probe frame for the decoder, a 0/1 state per sample for the classical path), the decoder also
``detach_margin`` (m per frame: the free tip's reach past its detachment level) and ``touch``
(per frame: Zm's step from the frame before over the size that marks a touch), then
``in_domain`` and ``domain_score``. The metadata says how frames map to time (``frame_s``,
``onset_offset_s``, ``detach_offset_s``, ``merge_s``, ``touch_lookback``), so every device
turns these into contacts the same way (:mod:`wtml.runtime.contacts`). A third graph,
``stream.onnx``, is the decoder's streaming form: one chunk of e and i and the carried state
in, the chunk's frames and the running answers out (:func:`stream_record`; ``wtml stream``:
:mod:`wtml.runtime.stream`).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from wtml.files import check_array
from wtml.runtime.contacts import Timing, contacts_from
from wtml.runtime.instruments import RecordingProfile
from wtml.runtime.predict import (
    InputError,
    float32_range,
    impossible,
    load_export,
    read_calibration_arrays,
)
from wtml.runtime.recordings import read_record


def read_onset_calibration(path: str | Path | None, probe_hz: float, n: int
                           ) -> tuple[np.ndarray, ...]:
    """The device's calibration for ``n`` records as the onset graphs take it, ``(t_re, t_im,
    hue0)`` float32 (``(n, 4)``, ``(n, 4)``, ``(n,)``), from an .npz with ``frequency_hz``
    (the probe's, ``(1,)``), ``t`` (complex T there, ``(1, 2, 2)`` for every record or ``(n,
    1, 2, 2)`` one per record) and ``hue0`` (m/V, scalar or ``(n,)``).

    Raises:
        InputError: no calibration given (an onset export needs one: never a default), a
            missing or unreadable file, another probe frequency, a wrong shape, NaN or inf,
            HUE(0) not > 0.
    """
    if path is None:
        raise InputError(f"this onset export needs --calibration: the device's calibrated T at "
                         f"the probe ({probe_hz:g} Hz) and its HUE(0) (npz with frequency_hz "
                         f"[{probe_hz:g}], t complex (1, 2, 2) and hue0 in m/V); "
                         "physics.md §4")
    t, extra = read_calibration_arrays(path, np.array([float(probe_hz)]), n, ("hue0",))
    if "hue0" not in extra:
        raise InputError(f"{path}: an onset calibration needs 'hue0' (the device's HUE(0), "
                         f"m/V) beside 'frequency_hz' and 't'")
    hue0 = check_array(str(path), "hue0", extra["hue0"], finite=False)
    if hue0.shape not in ((), (1,), (n,)):
        raise InputError(f"{path}: hue0 must be a scalar or have shape (n={n},), got "
                         f"{hue0.shape}")
    if not np.all(np.isfinite(hue0) & (hue0 > 0)):
        raise InputError(f"{path}: hue0 must be finite and > 0 (m/V), got {hue0.ravel()[:3]}")
    float32_range(str(path), "hue0", hue0)
    hue0 = np.broadcast_to(hue0.reshape(-1) if hue0.ndim else hue0, (n,))
    t = t[:, 0].reshape(n, 4)
    return tuple(np.asarray(x, np.float32) for x in (t.real, t.imag, hue0))


MAX_PIECES = 8
"""The most records of the trained length one recording may hold (one after the other). Each
piece is judged with the one before (the nearest before it with a σ), as the export's
``domain.pieces_limit`` was fitted (on two records one after the other), so a recording of
k pieces is judged on k − 1 pairs: a still wall's false alarms grow about k − 1 times (0.8 %
a pair at the main job's export), and k times those of one piece's own domain flag, since
every piece must be in domain. Longer recordings are for ``wtml stream``, which answers each
record."""


def pieces_of(length: int, n_samples: int, where: str, rate_hz: float) -> int:
    """How many records of ``n_samples`` a recording of ``length`` samples at ``rate_hz``
    holds, one after the other: 1 to :data:`MAX_PIECES`.

    Raises:
        InputError: another length (``where`` names the file).
    """
    k = length // n_samples
    if length % n_samples or not 1 <= k <= MAX_PIECES:
        raise InputError(f"{where}: records of {length / rate_hz:g} s ({length} samples at "
                         f"{rate_hz:g} Hz); the model takes records of {n_samples / rate_hz:g} "
                         f"s ({n_samples} samples) or of 2 to {MAX_PIECES} of them one after "
                         f"the other (up to {MAX_PIECES * n_samples} samples): cut a longer "
                         "recording into such records, or stream it (wtml stream)")
    return k


def cut_pieces(x: np.ndarray, n_samples: int, where: str, rate_hz: float
               ) -> tuple[np.ndarray, int]:
    """Records of ``k`` times the decoder's length as ``k`` records each: ``x`` ``(..., n,
    k · n_samples)`` at ``rate_hz`` -> ``(..., n · k, n_samples)``, record r's piece j at row
    ``r · k + j``, and ``k`` (:func:`pieces_of`). A piece starts where the one before
    ends, at the same phase of the whisk and the probe (the export fits its limit only for a
    scene whose records hold whole cycles of both).

    Raises:
        InputError: a length that is not 1 to :data:`MAX_PIECES` times ``n_samples``
            (``where`` names the file).
    """
    n, length = x.shape[-2:]
    k = pieces_of(length, n_samples, where, rate_hz)
    return x.reshape(*x.shape[:-2], n * k, n_samples), k


def pieces_spread(gap: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """How far a record's pieces locate the wall apart, in their σ: ``gap``, ``sigma`` ``(n,
    k)`` (m), the pieces in their order -> ``(n,)``, the largest ``|g_a − g_b| / sqrt(σ_a² +
    σ_b²)`` over each piece b with a σ and the nearest piece a before it with one (a piece
    without σ, out of domain, hides nothing across it); 0 for one piece or where every piece
    finds no wall (NaN gap); +inf where some find a wall and others none; NaN where no such
    pair is (a path without σ, the classical one, or pieces out of domain)."""
    k = gap.shape[1]
    has = np.isfinite(sigma)
    last = np.maximum.accumulate(np.where(has, np.arange(k), -1), axis=1)
    before = np.concatenate([np.full((len(gap), 1), -1), last[:, :-1]], axis=1)
    rows = np.arange(len(gap))[:, None]
    at = np.maximum(before, 0)
    with np.errstate(invalid="ignore", divide="ignore"):
        apart = np.abs(gap - gap[rows, at]) / np.hypot(sigma, sigma[rows, at])
    measured = has & (before >= 0) & ~np.isnan(apart)
    out = np.where(measured.any(1), np.max(np.where(measured, apart, -np.inf), 1,
                                           initial=-np.inf), np.nan)
    walls = np.isfinite(gap).sum(1)
    out = np.where((walls == 0) | (k == 1), 0.0, out)
    return np.where((walls > 0) & (walls < k), np.inf, out)


def combine_pieces(pred: dict[str, np.ndarray], k: int, limit: float) -> dict[str, np.ndarray]:
    """One answer per record from its ``k`` pieces' (``pred``: ``gap``, ``sigma``,
    ``in_domain`` and optional ``sigma_95``, ``domain_score``, each ``(n · k,)``, record r's
    pieces at rows ``r · k ...``): ``gap`` their mean (m); ``sigma`` (and ``sigma_95``) their
    mean, not over √k, since a record's pieces share their errors (the device's calibration,
    the wall's law: in the trained scene two pieces' gaps lie 0.05σ apart at the median);
    ``pieces_spread`` (:func:`pieces_spread`) and ``pieces_apart`` (that spread over the
    limit, or a wall in some pieces only); ``in_domain`` where every piece is in domain
    and the spread is within ``limit`` (σ; 0: none, a wall in some pieces only still out;
    a NaN spread, nothing to measure it by, is not checked);
    ``domain_score`` the larger of the pieces' and the spread over the limit. Each ``(n,)``."""
    per = {key: np.asarray(v).reshape(-1, k) for key, v in pred.items()
           if key in ("gap", "sigma", "sigma_95", "in_domain", "domain_score")}
    spread = pieces_spread(per["gap"], per["sigma"])
    with np.errstate(invalid="ignore"):
        over = spread / limit if limit > 0 else np.where(np.isinf(spread), np.inf, 0.0)
    over = np.where(np.isnan(over), 0.0, over)  # no σ to measure the pieces by
    out = {"pieces_spread": spread, "pieces_apart": over > 1,
           "in_domain": per["in_domain"].all(1) & (over <= 1)}
    for key in ("gap", "sigma", "sigma_95"):  # a wall in some pieces only: theirs, flagged
        if key in per:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)  # no piece found a wall: NaN
                out[key] = np.nanmean(per[key], 1)
    if "domain_score" in per:
        out["domain_score"] = np.maximum(per["domain_score"].max(1), over)
    return out


def predict_records(model_dir: str | Path, input_path: str | Path, *,
                    calibration: str | Path | None = None,
                    profile: RecordingProfile | None = None) -> list[dict]:
    """One row per contact (and one per record without any) for the decoder and the
    classical path: ``record``, ``method``, ``contact``, ``onset (s)``, ``detachment (s)``,
    ``gap (m)``, ``sigma (m)``, ``sigma_95 (m)`` (the 95 % half-width; NaN for the classical
    path, which is not recalibrated), ``in_domain``, ``domain_score``, ``flags``. ``calibration``:
    the device's (:func:`read_onset_calibration`), which an export whose metadata names it
    needs (:class:`InputError` without it); ``profile``: how to read an instrument's recording
    (:mod:`wtml.runtime.instruments`)."""
    decoder, classical = load_export(model_dir)
    meta = decoder.meta
    # per sample beyond the record: the classical path's per-sample contact state (float32
    # from the graph, float64 after), and the masks the timing rule makes of it
    x = read_record(input_path, meta.sample_rate_hz, meta.n_samples, at_least=True,
                    rows_per_record=2 * MAX_PIECES * (1 + meta.scene.get("max_contacts", 8)),
                    work_per_sample=24, profile=profile,
                    length_check=lambda where, length: pieces_of(
                        length, meta.n_samples, where, meta.sample_rate_hz))
    n = x.shape[1]
    x, k = cut_pieces(x, meta.n_samples, str(input_path), meta.sample_rate_hz)
    limit = meta.domain.pieces_limit
    if k > 1 and not limit:
        raise InputError(f"{input_path}: records of {k} times the model's {meta.n_samples} "
                         f"samples need an export that states how far its pieces may locate "
                         f"the wall apart (metadata domain.pieces_limit: exports of format 4, "
                         f"since 30 Nov, of a scene whose records hold whole whisk and probe "
                         f"cycles): export it again, or give records of {meta.n_samples} "
                         f"samples")
    cal = (read_onset_calibration(calibration, float(decoder.frequency_hz[0]), n)
           if "calibration" in decoder.references else ())
    cal = tuple(np.repeat(c, k, 0) for c in cal)
    # each piece's start in its record (s)
    shift = (np.arange(n * k) % k * (meta.n_samples / meta.sample_rate_hz))[:, None]
    rows = []
    for label, model in (("decoder", decoder), ("classical", classical)):
        pred = model.run(x[0], x[1], *cal)
        pred |= model.half_widths(pred)
        onset, detach = contacts_from(pred, Timing.of(model.meta))
        onset, detach = (t + shift for t in (onset, detach))
        odd = impossible(model, pred)["gap"] & np.isfinite(pred["gap"])
        record = combine_pieces(pred, k, limit)
        outside = ("outside the trained domain (its inputs, or its whisk cycles' approaches "
                   "and retreats locate the wall apart: an object that moves?)"
                   if model.meta.domain.self_check
                   else "outside the trained domain")
        for r in range(n):
            doubts: dict[str, list[int]] = {}  # each reason, the pieces it holds for
            for p in range(r * k, (r + 1) * k):
                if not pred["in_domain"][p]:
                    # the looks' check speaks only where a wall was answered (else it is 0)
                    doubts.setdefault(("outside the trained domain" if np.isnan(pred["gap"][p])
                                       else outside) if pred["domain_score"][p] > 1
                                      else "answer outside the trained range", []).append(
                        p - r * k + 1)
            flags = [text + ("" if k == 1 else f" (piece {pieces[0]} of {k})" if len(pieces) == 1
                             else f" (pieces {', '.join(map(str, pieces))} of {k})")
                     for text, pieces in doubts.items()]
            spread = record["pieces_spread"][r]
            if record["pieces_apart"][r]:
                flags.append((f"its {k} pieces locate the wall in some and none in others"
                              if np.isinf(spread) else
                              (f"its {k} pieces" if k == 2 else
                               f"two of its {k} pieces, one after the other,")
                              + f" locate the wall {spread:.2g} sigma apart (limit {limit:.2g})")
                             + ": an object that moves?")
            if odd[r * k:(r + 1) * k].any():
                flags.append("gap physically impossible")
            base = {"record": r, "method": label, "gap (m)": float(record["gap"][r]),
                    "sigma (m)": float(record["sigma"][r]),
                    "sigma_95 (m)": float(record["sigma_95"][r]) if "sigma_95" in record
                    else float("nan"),
                    "in_domain": bool(record["in_domain"][r]),
                    "domain_score": float(record["domain_score"][r]),
                    "flags": "; ".join(flags)}
            found = [(p, c) for p in range(r * k, (r + 1) * k)
                     for c in np.flatnonzero(np.isfinite(onset[p]))]
            for number, (p, c) in enumerate(found) if found else [(-1, (None, None))]:
                rows.append({"record": r, "method": label, "contact": number,
                             "onset (s)": float("nan") if p is None else float(onset[p, c]),
                             "detachment (s)": float("nan") if p is None
                             else float(detach[p, c]),
                             **{key: v for key, v in base.items()
                                if key not in ("record", "method")}})
    return rows


def stream_record(stream, e: np.ndarray, i: np.ndarray, *calibration: np.ndarray
                  ) -> dict[str, np.ndarray]:
    """Feed records through the streaming graph chunk by chunk, as a device would.

    Args:
        stream: the loaded ``stream.onnx`` (:class:`wtml.runtime.predict.OnnxModel`).
        e, i: V and A, ``(n, n_samples)``; ``n_samples`` a multiple of the chunk.
        calibration: the records' ``t_re, t_im, hue0`` (every chunk gets them).

    Returns:
        ``contact``, ``detach_margin`` and ``touch``, each ``(n, n_frames)`` (the chunks'
        frames side by side), and the running ``gap``, ``sigma``, ``sigma_95``,
        ``in_domain``, ``domain_score`` after the last chunk.
    """
    chunk = stream.meta.chunk_samples
    if e.shape[1] % chunk:
        raise InputError(f"records of {e.shape[1]} samples do not split into chunks of {chunk}")
    state = np.zeros((len(e), stream.meta.state_size), np.float32)
    frames: dict[str, list] = {"contact": [], "detach_margin": [], "touch": []}
    for k in range(0, e.shape[1], chunk):
        out = stream.run(e[:, k:k + chunk], i[:, k:k + chunk], *calibration, state)
        state = out["next_state"].astype(np.float32)
        for key, parts in frames.items():
            parts.append(out[key])
    out |= stream.half_widths(out)
    return {**{key: np.concatenate(parts, 1) for key, parts in frames.items()},
            **{key: out[key] for key in ("gap", "sigma", "sigma_95", "in_domain",
                                         "domain_score")}}
