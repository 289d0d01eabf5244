"""Onset models on a device: export, reading records, and contacts from the graphs' outputs.

Both graphs (``model.onnx``: the decoder; ``classical.onnx``: the thesis's pipeline) take
``e`` (V) and ``i`` (A), float32 ``(batch, n_samples)`` at the trained sampling rate, and the
user's calibration of their own device (:data:`ONSET_REFERENCES`; the metadata's
``references``): ``t_re, t_im`` ``(batch, 4)``, its T at the probe frequency flattened as
(t11, t12, t21, t22), and ``hue0`` ``(batch,)``, its HUE(0) in m/V (``wtml predict
--calibration cal.npz``: :func:`read_onset_calibration`); and they
return ``gap`` (m), ``sigma`` (m; NaN for the classical path and out of domain), ``contact``
(``(batch, n_frames)``: a probability per probe frame for the decoder, a 0/1 state per sample
for the classical path), the decoder also ``detach_margin`` (m per frame: the free tip's
reach past its detachment level) and ``touch`` (per frame: Zm's step from the frame before
over the size that marks a touch), then ``in_domain`` and
``domain_score``. The metadata says how frames map to time (``frame_s``, ``onset_offset_s``,
``detach_offset_s``, ``merge_s``), so every device turns these into intervals the same way
(:func:`contacts_from`). A third graph, ``stream.onnx``, is the decoder's streaming form
(:class:`wtml.decoders.onset_stream.StreamingOnset`): one chunk of e and i and the carried
state in, the chunk's frames and the running answers out (:func:`stream_record`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from wtml import __version__
from wtml.baselines.onset_classical import ThesisOnset
from wtml.data.datamodule import onset_calibration
from wtml.decoders.domain import Gated
from wtml.decoders.onset import TOUCH_LOOKBACK, frame_period
from wtml.decoders.onset_stream import StreamingOnset
from wtml.files import (
    check_array,
    check_header,
    npz_headers,
    read_npz,
    regular_file,
    scalar,
    within_ceiling,
)
from wtml.runtime.export import _export, domain_metadata
from wtml.runtime.metadata import (  # noqa: F401  (the names this module has always had)
    DECODER_OUTPUTS,
    ONSET_CALIBRATION,
    ONSET_INPUTS,
    ONSET_OUTPUTS,
    STREAM_INPUTS,
    STREAM_OUTPUTS,
)
from wtml.runtime.predict import (
    ROW_BYTES,
    InputError,
    float32_range,
    read_calibration_arrays,
)
from wtml.scenes import config_hash, to_dict
from wtml.scenes.onset import intervals

ONSET_REFERENCES = {"calibration": "the device's calibrated T at the probe frequency and its "
                                   "HUE(0) (the calibration of physics.md §4 on the user's own "
                                   "device): inputs t_re, t_im (T.reshape(4): t11, t12, t21, "
                                   "t22) and hue0 (m/V)"}
"""What the onset graphs need besides the record (the metadata's ``references``)."""
STREAM_CHUNK_FRAMES = 1
"""Probe periods per chunk of the exported streaming graph (2.4 ms at the defaults)."""
FRESH_RECORDS = 64
"""Fresh records of the scene on which the exported decoder's false-alarm rate is measured."""


def thesis_pipeline(scene) -> ThesisOnset:
    """The classical path for ``scene`` (each record's calibrated T at the probe and HUE(0)
    its inputs), threshold at half of ``k_ref/ωH``."""
    wh = 2 * np.pi * scene.drive.probe_hz
    return ThesisOnset(scene.acquisition.sample_rate_hz, scene.drive.probe_hz,
                       0.5 * scene.reference_stiffness() / wh)


def record_inputs(records: dict) -> tuple[np.ndarray, ...]:
    """A graph's inputs from records of an onset scene (``e``, ``i``, ``t_probe``, ``hue0``):
    ``(e, i, t_re, t_im, hue0)`` float32, in the order of :data:`ONSET_INPUTS`."""
    return tuple(np.asarray(x, np.float32)
                 for x in (records["e"], records["i"], *onset_calibration(records)))


def calibration_file(path: str | Path, scene, records: dict | None = None) -> Path:
    """Write the calibration ``wtml predict --calibration`` reads (:func:`read_onset_calibration`)
    to ``path``: each record's (``t_probe``, ``hue0`` of ``records``), or the preset's."""
    if records is None:
        t, hue0 = scene.calibrated(scene.transducer())
        t, hue0 = t[None], np.float64(hue0)
    else:
        t, hue0 = np.asarray(records["t_probe"])[:, None], np.asarray(records["hue0"])
    np.savez(path, frequency_hz=np.array([scene.drive.probe_hz]), t=t, hue0=hue0)
    return Path(path)


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


@torch.no_grad()
def export_onset(module, scene, out: Path) -> dict[str, Path]:
    """Write the onset decoder and the thesis pipeline, each with the decoder's domain gate,
    to ``out/model.onnx`` and ``out/classical.onnx``, and the decoder's streaming form to
    ``out/stream.onnx`` (inputs ``e``, ``i`` of one chunk and ``state``, zeros at a record's
    start; outputs :data:`STREAM_OUTPUTS` then ``in_domain``, ``domain_score``)."""
    decoder = Gated(module.net, module.gate, (1,)).eval()
    fresh = scene.simulate(FRESH_RECORDS, np.random.default_rng([scene.seed, 10**6 + 1]))
    inside = decoder(*(torch.tensor(x) for x in record_inputs(fresh)))[-2]
    domain = domain_metadata(scene, float(1 - inside.float().mean()), FRESH_RECORDS)
    rate = scene.acquisition.sample_rate_hz
    period = frame_period(scene)
    merge = scene.merge_periods / scene.drive.probe_hz
    on_off = [float(x) for x in module.offsets]
    meta = {"wtml_version": __version__, "task": "onset",
            "inputs": json.dumps(list(ONSET_INPUTS)), "outputs": json.dumps(list(ONSET_OUTPUTS)),
            "units": json.dumps({"gap": "m", "sigma": "m", "contact": "1", "e": "V", "i": "A",
                                 "t_re": "SI (T)", "t_im": "SI (T)", "hue0": "m/V",
                                 "detach_margin": "m", "touch": "1", "state": "1",
                                 "next_state": "1"}),
            "references": json.dumps(ONSET_REFERENCES),
            "frequency_hz": json.dumps([scene.drive.probe_hz]),
            "sample_rate_hz": json.dumps(rate), "n_samples": json.dumps(scene.n_samples),
            "merge_s": json.dumps(merge),
            "scene": json.dumps(to_dict(scene), sort_keys=True), "scene_hash": config_hash(scene),
            "domain": json.dumps(domain)}
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    frames = {"frame_s": json.dumps(period / rate), "onset_offset_s": json.dumps(on_off[0]),
              "detach_offset_s": json.dumps(on_off[1])}
    samples = {"frame_s": json.dumps(1 / rate), "onset_offset_s": "0.0",
               "detach_offset_s": "0.0"}
    widths = (scene.n_samples,) * 2 + (4, 4, ())
    _export(decoder, scene.n_samples, paths["decoder"],
            meta | frames | {"kind": "decoder", "label": "decoder",
                             "outputs": json.dumps(list(DECODER_OUTPUTS))}, ONSET_INPUTS, widths)
    classical = Gated(thesis_pipeline(scene), module.gate.inputs_only()).eval()
    _export(classical, scene.n_samples, paths["classical"],
            meta | samples | {"kind": "classical", "label": "thesis pipeline"}, ONSET_INPUTS,
            widths)
    stream = StreamingOnset(module.net, module.gate, STREAM_CHUNK_FRAMES).eval()
    paths["stream"] = out / "stream.onnx"
    _export(stream, stream.chunk_samples, paths["stream"],
            meta | frames | {"kind": "stream", "label": "decoder (streaming)",
                             "outputs": json.dumps(list(STREAM_OUTPUTS)),
                             "inputs": json.dumps(list(STREAM_INPUTS)),
                             "chunk_samples": json.dumps(stream.chunk_samples),
                             "state_size": json.dumps(stream.state_size)},
            STREAM_INPUTS, (stream.chunk_samples,) * 2 + (4, 4, (), stream.state_size))
    return paths


def contacts_from(pred: dict, metadata: dict) -> tuple[np.ndarray, np.ndarray]:
    """Onset and detachment times (s) of each record's contacts from a graph's outputs and
    its metadata; each ``(n, max_contacts)``, NaN-padded.

    With a margin (the decoder), a contact is a run of frames where the contact probability
    passes 0.5 or ``detach_margin >= 0``; it starts where the last run of successive frames
    with ``touch >= 1`` starts, of those from :data:`TOUCH_LOOKBACK` frames ahead of the run
    (not reaching back into the contact before) up to the run's first frame with ``contact >
    0.5`` (on that frame if none): a touch steps Zm on each frame as it deepens, while a noise
    step over the threshold stands alone (on the bench-top acquisition 4 % of free whisking's
    frames, the main job's test shards: over 4 frames of lookback, the first such frame
    would call ~1 onset in 6 early), and
    ends on its last frame with ``detach_margin >= 0``. Without (the classical path), a run
    of ``contact > 0.5``.
    Runs closer than ``merge_s`` are one contact.
    """
    frame_s = json.loads(metadata["frame_s"])
    max_count = json.loads(metadata["scene"]).get("max_contacts", 8)
    merge = json.loads(metadata["merge_s"])
    if "detach_margin" not in pred:
        start, end = intervals(pred["contact"] > 0.5, 1 / frame_s, merge, max_count)
    else:
        rise, fall = pred["contact"] > 0.5, pred["detach_margin"] >= 0
        touch = pred["touch"] >= 1
        start, end = intervals(rise | fall, 1 / frame_s, merge, max_count)
        n_frames = rise.shape[1]
        before = np.zeros(len(start), int)  # where the record's previous run ended
        for r, k in zip(*np.nonzero(np.isfinite(start)), strict=True):
            a = int(round(start[r, k] / frame_s))
            b = n_frames if np.isnan(end[r, k]) else int(round(end[r, k] / frame_s))
            on, off = np.flatnonzero(rise[r, a:b]), np.flatnonzero(fall[r, a:b])
            first = a + (on[0] if len(on) else 0)
            lo = max(a - TOUCH_LOOKBACK, before[r])
            hit = np.flatnonzero(touch[r, lo:first + 1])
            if len(hit):  # the start of the last run of touches: a deepening contact steps Zm
                # on every frame, a noise step before it stands alone
                j = len(hit) - 1
                while j and hit[j - 1] == hit[j] - 1:
                    j -= 1
                first = lo + hit[j]
            start[r, k] = first * frame_s
            before[r] = b
            if np.isfinite(end[r, k]):
                end[r, k] = (a + (off[-1] + 1 if len(off) else b - a)) * frame_s
    # intervals() gives frame boundaries; the contact starts/ends at a fixed phase in a frame
    onset = start + json.loads(metadata["onset_offset_s"])
    detach = end - frame_s + json.loads(metadata["detach_offset_s"])
    return onset, detach


def record_cost(n: int, n_in: int, n_out: int, itemsize: int) -> int:
    """Bytes that reading ``n`` records of ``n_in`` samples per channel (stored with
    ``itemsize`` bytes a sample) and resampling them to ``n_out`` take at their peak: the
    float32 answer ``(2, n, n_out)``, then per channel the loaded array, its float64 copy, and
    the resampled array with scipy's working copy of it."""
    return 8 * n * n_out + n * n_in * (itemsize + 8) + 16 * n * n_out * (n_out != n_in)


def read_record(path: str | Path, sample_rate_hz: float, n_samples: int, *,
                at_least: bool = False, rows_per_record: int = 2,
                work_per_sample: int = 0) -> np.ndarray:
    """``e`` and ``i`` of a ``rec.npz`` as float32 ``(2, n, n_samples)`` at the trained rate
    (``at_least``: any length from ``n_samples`` up, for models fed windows).

    The file holds ``e`` (V) and ``i`` (A), each ``(n_samples,)`` or ``(n_records,
    n_samples)``, real, and ``sample_rate_hz`` (one number). Another rate is resampled
    (polyphase, when the two rates have a ratio of small whole numbers) or refused; the
    duration must match the trained record's (or reach it, ``at_least``). Everything is
    checked from the file's headers before any array is read, the work's memory
    (:func:`record_cost`, ``rows_per_record`` rows of the answer per record and
    ``work_per_sample`` bytes per sample of what the caller makes of the records) against
    :data:`wtml.files.MEMORY_CEILING` included.

    Raises:
        InputError: missing keys, complex or mismatched arrays, no records, NaN, an unusable
            rate or length, more memory than the ceiling.
    """
    from fractions import Fraction

    from scipy.signal import resample_poly

    path = regular_file(path, what="input file")
    where = str(path)
    heads = npz_headers(path, what="record")
    missing = {"e", "i", "sample_rate_hz"} - set(heads)
    if missing:
        raise InputError(f"{path}: a record needs 'e' (V), 'i' (A) and "
                         f"'sample_rate_hz'; missing {sorted(missing)}")
    for key in ("e", "i"):
        check_header(where, key, *heads[key], ndim=(1, 2))
    shape = heads["e"][0]
    if shape != heads["i"][0]:
        raise InputError(f"{path}: e and i must have the same shape (n_samples,) or "
                         f"(n_records, n_samples); got {shape} and {heads['i'][0]}")
    n, n_in = (1, *shape) if len(shape) == 1 else shape
    if n == 0 or n_in == 0:
        raise InputError(f"{path}: holds no records (e and i have shape {shape}); give "
                         "(n_samples,) or (n_records, n_samples) with both at least 1")
    rate = scalar(where, "sample_rate_hz", read_npz(path, keys=("sample_rate_hz",))[
        "sample_rate_hz"], low=1e-3, high=1e12)
    up = down = 1
    if rate != sample_rate_hz:
        ratio = Fraction(sample_rate_hz / rate).limit_denominator(1000)
        if abs(float(ratio) - sample_rate_hz / rate) > 1e-9 * sample_rate_hz / rate:
            raise InputError(f"{path}: recorded at {rate:g} Hz; the model was trained at "
                             f"{sample_rate_hz:g} Hz and the ratio is not a ratio of whole "
                             "numbers up to 1000: resample it first")
        up, down = ratio.numerator, ratio.denominator
    n_out = -(-n_in * up // down)
    if n_out < n_samples if at_least else n_out != n_samples:
        raise InputError(f"{path}: {n_out} samples at {sample_rate_hz:g} Hz "
                         f"({n_out / sample_rate_hz:g} s); the model takes records of "
                         f"{'at least ' if at_least else ''}{n_samples} "
                         f"({n_samples / sample_rate_hz:g} s)")
    need = (record_cost(n, n_in, n_out, heads["e"][1].itemsize)
            + rows_per_record * n * ROW_BYTES + work_per_sample * n * n_out)
    within_ceiling(f"{path}: e and i {shape} at sample_rate_hz {rate:g}", need,
                   f"reading {n} record(s)" + (f" resampled to {sample_rate_hz:g} Hz "
                                               f"({n_out} samples each)" if up != down else ""))
    out = np.empty((2, n, n_out), np.float32)
    for k, key in enumerate(("e", "i")):
        x = check_array(where, key, read_npz(path, keys=(key,))[key], ndim=(1, 2))
        x = np.atleast_2d(x)
        if up != down:
            x = resample_poly(x, up, down, axis=1)
        float32_range(where, key, x)
        out[k] = x[:, :n_out]
        del x
    return out


def predict_records(model_dir: str | Path, input_path: str | Path, *,
                    calibration: str | Path | None = None) -> list[dict]:
    """One row per contact (and one per record without any) for the decoder and the
    classical path: ``record``, ``method``, ``contact``, ``onset (s)``, ``detachment (s)``,
    ``gap (m)``, ``sigma (m)``, ``in_domain``, ``domain_score``, ``flags``. ``calibration``:
    the device's (:func:`read_onset_calibration`), which an export whose metadata names it
    needs (:class:`InputError` without it)."""
    from wtml.runtime.predict import impossible, load_export

    decoder, classical = load_export(model_dir)
    meta = decoder.meta
    # per sample beyond the record: the classical path's per-sample contact state (float32
    # from the graph, float64 after), and the masks the timing rule makes of it
    x = read_record(input_path, meta.sample_rate_hz, meta.n_samples,
                    rows_per_record=2 * (1 + meta.scene.get("max_contacts", 8)),
                    work_per_sample=24)
    cal = (read_onset_calibration(calibration, float(decoder.frequency_hz[0]), x.shape[1])
           if "calibration" in decoder.references else ())
    rows = []
    for label, model in (("decoder", decoder), ("classical", classical)):
        pred = model.run(x[0], x[1], *cal)
        onset, detach = contacts_from(pred, model.metadata)
        odd = impossible(model, pred)["gap"]
        for r in range(x.shape[1]):
            flags = []
            if not pred["in_domain"][r]:
                flags.append("outside the trained domain" if pred["domain_score"][r] > 1
                             else "answer outside the trained range")
            if odd[r] and np.isfinite(pred["gap"][r]):
                flags.append("gap physically impossible")
            base = {"record": r, "method": label, "gap (m)": float(pred["gap"][r]),
                    "sigma (m)": float(pred["sigma"][r]),
                    "in_domain": bool(pred["in_domain"][r]),
                    "domain_score": float(pred["domain_score"][r]), "flags": "; ".join(flags)}
            found = np.flatnonzero(np.isfinite(onset[r]))
            for k in found if len(found) else [None]:
                rows.append({"record": r, "method": label,
                             "contact": -1 if k is None else int(k),
                             "onset (s)": float("nan") if k is None else float(onset[r, k]),
                             "detachment (s)": float("nan") if k is None else float(detach[r, k]),
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
        ``contact`` ``(n, n_frames)`` (the chunks' probabilities side by side), and the
        running ``gap``, ``sigma``, ``in_domain``, ``domain_score`` after the last chunk.
    """
    chunk = json.loads(stream.metadata["chunk_samples"])
    if e.shape[1] % chunk:
        raise InputError(f"records of {e.shape[1]} samples do not split into chunks of {chunk}")
    state = np.zeros((len(e), json.loads(stream.metadata["state_size"])), np.float32)
    probs = []
    for k in range(0, e.shape[1], chunk):
        out = stream.run(e[:, k:k + chunk], i[:, k:k + chunk], *calibration, state)
        state = out["next_state"].astype(np.float32)
        probs.append(out["contact"])
    return {"contact": np.concatenate(probs, 1),
            **{key: out[key] for key in ("gap", "sigma", "in_domain", "domain_score")}}
