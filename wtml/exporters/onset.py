"""Onset models to ONNX: the decoder (``model.onnx``), the thesis's pipeline
(``classical.onnx``) and the decoder's streaming form (``stream.onnx``), each with the
decoder's domain gate; what the graphs take and return is :mod:`wtml.runtime.onset`'s.

The metadata carries everything a device needs to turn the graphs' frames into contacts
(:mod:`wtml.runtime.contacts`): ``frame_s``, ``onset_offset_s``, ``detach_offset_s``,
``merge_s``, ``touch_lookback``, and the stream's ``chunk_samples`` and ``state_size``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import torch

from wtml import __version__
from wtml.baselines.onset_classical import ThesisOnset
from wtml.decoders.domain import QUANTILE, Gated
from wtml.decoders.onset import MOTION_LIMIT, SELF_CHECKS, TOUCH_LOOKBACK, frame_period
from wtml.decoders.onset_stream import StreamingOnset
from wtml.decoders.recalibration import Recalibrated, fit_uncertainty, metadata
from wtml.exporters.graphs import domain_metadata, export_graph
from wtml.runtime.metadata import (
    DECODER_OUTPUTS,
    GATE_OUTPUTS,
    ONSET_INPUTS,
    ONSET_OUTPUTS,
    STREAM_INPUTS,
    STREAM_OUTPUTS,
)
from wtml.runtime.onset import combine_pieces, cut_pieces, pieces_spread
from wtml.scenes import config_hash, to_dict
from wtml.scenes.onset import onset_calibration

ONSET_REFERENCES = {"calibration": "the device's calibrated T at the probe frequency and its "
                                   "HUE(0) (the calibration of physics.md §4 on the user's own "
                                   "device): inputs t_re, t_im (T.reshape(4): t11, t12, t21, "
                                   "t22) and hue0 (m/V)"}
"""What the onset graphs need besides the record (the metadata's ``references``)."""
STREAM_TOUCH_LOOKBACK = 40
"""Frames (95 ms at the 420 Hz probe) ahead of a streamed contact's first frame in which its
run of touches is looked for (the stream's metadata ``touch_lookback``). The streaming graph
knows no detachment level before a record's first contact probability passes 0.5, so its
contact runs start there, where the offline graph's start up to tens of frames earlier, where
the reach passes the record's final level; looked for over ``TOUCH_LOOKBACK`` only, the
streamed onsets of the main job's decoder fall 14 ms late (F1 0.25, against 0.88 offline),
over 12 frames F1 is 0.72, over 40 it is the offline 0.88 with the same onset error (64
records of its scene; the offline rule's figures are the same over 4 to 1000 frames, a run
of touches being successive frames)."""
STREAM_CHUNK_FRAMES = 1
"""Probe periods per chunk of the exported streaming graph (2.4 ms at the defaults)."""
FRESH_RECORDS = 1536
"""Fresh records of the scene (its own seed, not the training data) on which the exported
decoder's false-alarm rate is measured, its σ recalibrated (:data:`GAP_RANGES` ranges: a scale
and a 95 % width in each; ~1350 records with a wall; :mod:`wtml.decoders.recalibration`) and
the looks' limit fitted (:func:`spread_limit`: the 0.999 quantile of ~1350, not nearly the
largest of ~450). On 128 (~115 with a wall) the 68 % interval's true coverage scattered by
4.2 points between draws, on 512 (one range, until 1 Dec) by 2.3; they are simulated
:data:`FRESH_CHUNK` at a time (~1 s each on the main job's scene: `wtml export` 40 s in all,
27 s on 512)."""
GAP_RANGES = 3
"""Equal-count ranges of the answered gap, each with its own σ scale and 95 % width. One range
left the far walls short (the top fifth of the test shard's gaps, 8.8–11.2 µm, grazing
contacts): on 3587 fresh walls of the main job's decoder (1 Dec; 100 random splits, fit
on 1345 walls, scored on the rest), ±1σ covered the five fifths 70.6, 67.9, 67.0, 69.2 and
**65.1 %** (95 %: 96.7 … **93.0 %**) with one range, 69.5, 67.3, 66.5, 70.0 and 68.2 %
(95.7 … 94.9 %) with three; on 448 walls, three ranges scattered ±3.8–4.9 points a fifth
against one range's ±2.3–3.3, hence the records above."""
FRESH_CHUNK = 64
"""Records simulated and answered at once among the :data:`FRESH_RECORDS` (each chunk its own
seed; 128 had held ~0.19 GB more at the export's peak, its records' noise being drawn)."""
SPREAD_QUANTILE = QUANTILE
"""The fresh records' quantile of :func:`~wtml.decoders.onset.touch_spread` (over those with a
wall) that the exported graphs take as its limit, as the domain gate takes its own."""


SPREAD_MIN_WALLS = 20
"""Fewer fresh records than this with a wall answered (a net trained a few epochs answers
none): the limit is :data:`SPREAD_DEFAULT`."""
SPREAD_DEFAULT = 1.0
"""The limit (σ) without enough walls to fit it: two cycles' wholes 2σ apart, with equal shares
and no approach–retreat disagreement (the main job's decoder's fitted limit was 0.56σ on
1 Dec, on 1536 fresh records)."""


def spread_limit(spread: np.ndarray) -> float:
    """The limit of the looks' disagreement (σ; :func:`~wtml.decoders.onset.touch_spread`)
    from the fresh records with a wall answered, ``(n,)``: their :data:`SPREAD_QUANTILE`
    (:data:`SPREAD_DEFAULT` with fewer than :data:`SPREAD_MIN_WALLS`, or where they are all
    0: records of one whisk cycle)."""
    if not np.all(np.isfinite(spread)):
        raise ValueError(f"touch_spread: {int(np.sum(~np.isfinite(spread)))} of {len(spread)} "
                         "fresh answers with a wall are not finite")
    limit = float(np.quantile(spread, SPREAD_QUANTILE)) if len(spread) >= SPREAD_MIN_WALLS else 0
    return limit if limit > 0 else SPREAD_DEFAULT  # 0: a record of one cycle, no check


PIECE_RECORDS = 256
"""Fresh records of twice the scene's whisk cycles (their own seeds) on which the limit of a
record's pieces' agreement is fitted (:func:`pieces_limit`): ~9 s of the export on the main
job's scene, simulated :data:`PIECE_CHUNK` at a time."""
PIECE_CHUNK = 32
"""Records of two pieces simulated at once: as many samples as :data:`FRESH_CHUNK` records."""


def twice_as_long(scene):
    """``scene`` with records of twice its whisk cycles."""
    return dataclasses.replace(scene, drive=dataclasses.replace(
        scene.drive, cycles=2 * scene.drive.cycles))


def piece_inputs(records: dict, scene) -> tuple[np.ndarray, ...]:
    """A graph's inputs (:func:`record_inputs`) from records of :func:`twice_as_long`
    ``scene``, each cut into its two pieces (:func:`wtml.runtime.onset.cut_pieces`: record
    r's at rows 2r, 2r + 1), each piece with its record's calibration."""
    x, _ = cut_pieces(np.stack([records["e"], records["i"]]), scene.n_samples, "records",
                      scene.acquisition.sample_rate_hz)
    return tuple(np.asarray(v, np.float32) for v in x) + tuple(
        np.repeat(c, 2, 0) for c in record_inputs(records)[2:])


def whole_pieces(scene) -> bool:
    """Whether a record of twice ``scene``'s whisk cycles is two of its records one after the
    other: whole whisk cycles, a whole number of probe periods per record, and twice the
    samples (else a second piece would start at another phase, and the export states no
    limit: such recordings are refused)."""
    probe = scene.n_samples * scene.drive.probe_hz / scene.acquisition.sample_rate_hz
    return (float(scene.drive.cycles).is_integer() and abs(probe - round(probe)) < 1e-9
            and twice_as_long(scene).n_samples == 2 * scene.n_samples)


@torch.no_grad()
def pieces_limit(decoder, scene) -> tuple[float, float]:
    """The limit (σ) of how far the two pieces of a record of twice the scene's whisk cycles
    may locate the wall apart (:func:`wtml.runtime.onset.pieces_spread`), and the share of
    :data:`PIECE_RECORDS` fresh such records it flags, by the exported ``decoder`` (the gated,
    recalibrated module): the :data:`SPREAD_QUANTILE` of the spread over the records whose
    pieces both answer in domain with a wall (:func:`spread_limit`: its default with too few).
    A still wall is met alike in every piece (the device's calibration and the wall's law
    make most of an answer's error, and the pieces share them); a wall that moves with the
    floor is met elsewhere in each. ``(0, 0)``: no limit, for a scene whose records do not
    hold whole cycles (:func:`whole_pieces`)."""
    if not whole_pieces(scene):
        return 0.0, 0.0
    longer = twice_as_long(scene)
    pred: dict[str, list] = {"gap": [], "sigma": [], "in_domain": [], "domain_score": []}
    for k in range(0, PIECE_RECORDS, PIECE_CHUNK):
        fresh = longer.simulate(min(PIECE_CHUNK, PIECE_RECORDS - k),
                                np.random.default_rng([scene.seed, 10**6 + 2, k]))
        inputs = piece_inputs(fresh, scene)
        out = decoder(*(torch.tensor(v) for v in inputs))
        for key, v in zip(pred, (out[0], out[1], out[-2], out[-1]), strict=True):
            pred[key].append(v.double().numpy())
        del fresh, inputs
    per = {key: np.concatenate(v).reshape(-1, 2) for key, v in pred.items()}
    spread = pieces_spread(per["gap"], per["sigma"])
    answered = per["in_domain"].all(1) & np.isfinite(per["gap"]).all(1)
    limit = spread_limit(spread[answered])
    flagged = combine_pieces({key: v.ravel() for key, v in per.items()}, 2, limit)
    return limit, float(1 - flagged["in_domain"].mean())


GAP_INTERVAL = {"sigma": "sigma", "value": "gap", "by": "gap", "log_value": False,
                "stored": "std"}
"""The onset graphs' interval: σ, the std of the wall's location g (m)."""


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
    """Write the calibration ``wtml predict --calibration`` reads
    (:func:`wtml.runtime.onset.read_onset_calibration`) to ``path``: each record's
    (``t_probe``, ``hue0`` of ``records``), or the preset's."""
    if records is None:
        t, hue0 = scene.calibrated(scene.transducer())
        t, hue0 = t[None], np.float64(hue0)
    else:
        t, hue0 = np.asarray(records["t_probe"])[:, None], np.asarray(records["hue0"])
    np.savez(path, frequency_hz=np.array([scene.drive.probe_hz]), t=t, hue0=hue0)
    return Path(path)


@torch.no_grad()
def export_onset(module, scene, out: Path) -> dict[str, Path]:
    """Write the onset decoder and the thesis pipeline, each with the decoder's domain gate,
    to ``out/model.onnx`` and ``out/classical.onnx``, and the decoder's streaming form to
    ``out/stream.onnx`` (inputs ``e``, ``i`` of one chunk and ``state``, zeros at a record's
    start; outputs :data:`STREAM_OUTPUTS` then ``in_domain``, ``domain_score``). The decoder's
    and the stream's σ are recalibrated on :data:`FRESH_RECORDS` fresh records
    (:data:`GAP_RANGES` ranges of the answer: a scale and a 95 % width in each)."""
    raw = Gated(module.net, module.gate, (1,)).eval()
    answers, truth = [], []
    for k in range(0, FRESH_RECORDS, FRESH_CHUNK):
        fresh = scene.simulate(min(FRESH_CHUNK, FRESH_RECORDS - k),
                               np.random.default_rng([scene.seed, 10**6 + 1, k]))
        inputs = record_inputs(fresh)
        answers += [raw(*(torch.tensor(x[s:s + 32]) for x in inputs))
                    for s in range(0, len(fresh["gap"]), 32)]
        truth.append(fresh["gap"])
        del fresh, inputs  # not beside the next chunk's simulation
    gap, sigma, motion, spread, inside = (torch.cat([a[k] for a in answers])
                                          for k in (0, 1, 5, 6, -2))
    limit = spread_limit(spread[torch.isfinite(gap)].double().numpy())
    uncertainty = fit_uncertainty(
        {"gap": gap.double().numpy(), "sigma": sigma.double().numpy()},
        {"gap": np.concatenate(truth)}, [GAP_INTERVAL], GAP_RANGES,
        f"{FRESH_RECORDS} fresh records of the trained scene (seeds [{scene.seed}, 1000001, "
        f"k] for chunks from record k; not the training data)")
    calibrated = Recalibrated(module.net, DECODER_OUTPUTS + SELF_CHECKS, uncertainty)
    decoder = Gated(calibrated, module.gate, (1,), checks=(MOTION_LIMIT, limit)).eval()
    pieces, pieces_flagged = pieces_limit(decoder, scene)
    # the classical graph has the gate alone; the decoder's and the stream's also the check
    domain = domain_metadata(scene, float(1 - inside.float().mean()), FRESH_RECORDS)
    checked = {"domain": json.dumps(domain | {
        "false_alarm_fresh": float((inside & (spread <= limit) & (motion <= MOTION_LIMIT)
                                    ).logical_not().float().mean()),
        "self_check": "touch_spread: how far each whisk cycle's approach and retreat locate "
                      "the wall from the record's approach and retreat, in its sigma (a still "
                      "wall is met at one place in every look); its limit is the "
                      f"{SPREAD_QUANTILE} quantile over the fresh records with a wall "
                      f"({SPREAD_DEFAULT} with fewer than "
                      f"{SPREAD_MIN_WALLS}); and wall_motion: the wall's own motion read from "
                      "the whisk cycles' currents (rms over sqrt(looks), in sigma with it in "
                      f"quadrature) as a share of the net's sigma, its limit {MOTION_LIMIT:g}; "
                      "the domain score is the largest of the gate's and each over its limit",
        "self_check_limit": limit,
        "pieces_limit": pieces, "pieces_false_alarm_fresh": pieces_flagged})}
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
            "merge_s": json.dumps(merge), "touch_lookback": json.dumps(TOUCH_LOOKBACK),
            "scene": json.dumps(to_dict(scene), sort_keys=True), "scene_hash": config_hash(scene),
            "domain": json.dumps(domain)}
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    recalibrated = {"uncertainty": metadata(uncertainty)}
    frames = {"frame_s": json.dumps(period / rate), "onset_offset_s": json.dumps(on_off[0]),
              "detach_offset_s": json.dumps(on_off[1])}
    samples = {"frame_s": json.dumps(1 / rate), "onset_offset_s": "0.0",
               "detach_offset_s": "0.0"}
    widths = (scene.n_samples,) * 2 + (4, 4, ())
    export_graph(decoder, scene.n_samples, paths["decoder"],
            meta | frames | recalibrated | checked | {"kind": "decoder", "label": "decoder",
                                            "outputs": json.dumps(list(DECODER_OUTPUTS))},
            ONSET_INPUTS, widths)
    classical = Gated(thesis_pipeline(scene), module.gate.inputs_only()).eval()
    export_graph(classical, scene.n_samples, paths["classical"],
            meta | samples | {"kind": "classical", "label": "thesis pipeline"}, ONSET_INPUTS,
            widths)
    stream = StreamingOnset(module.net, module.gate, STREAM_CHUNK_FRAMES,
                            check_limit=limit).eval()
    paths["stream"] = out / "stream.onnx"
    export_graph(Recalibrated(stream, STREAM_OUTPUTS + GATE_OUTPUTS, uncertainty).eval(),
            stream.chunk_samples, paths["stream"],
            meta | frames | recalibrated | checked | {"kind": "stream",
                                                      "label": "decoder (streaming)",
                             "outputs": json.dumps(list(STREAM_OUTPUTS)),
                             "inputs": json.dumps(list(STREAM_INPUTS)),
                             "chunk_samples": json.dumps(stream.chunk_samples),
                             "state_size": json.dumps(stream.state_size),
                             "touch_lookback": json.dumps(STREAM_TOUCH_LOOKBACK)},
            STREAM_INPUTS, (stream.chunk_samples,) * 2 + (4, 4, (), stream.state_size))
    return paths
