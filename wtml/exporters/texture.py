"""Texture models to ONNX: the decoder and the classical path, each with the decoder's domain
gate; what the graphs take and return, and how ``wtml predict`` runs them, is
:mod:`wtml.runtime.texture`'s.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from wtml import __version__
from wtml.baselines.texture_classical import ClassicalTexture
from wtml.decoders.domain import Gated
from wtml.decoders.recalibration import Recalibrated, fit_uncertainty, metadata
from wtml.exporters.graphs import domain_metadata, export_graph
from wtml.physics.twoport import flat_parts
from wtml.runtime.metadata import TEXTURE_INPUTS
from wtml.scenes import config_hash, to_dict
from wtml.scenes.texture import THESIS_GRADES

TEXTURE_REFERENCES = {"calibration": "the device's calibrated T (the macro WT with its whisker, "
                                     "tip free) at calibration_hz, measured with the "
                                     "calibration loads of physics.md §4: inputs t_re, t_im"}
FRESH_RECORDS = 100
"""Fresh records of the scene (its own seed, not the training data; each record its own
specimen, :meth:`~wtml.scenes.texture.TextureScene.simulate_independent`) on which the
classical path is fitted and the exported decoder's false-alarm rate is measured."""
CALIBRATION_RECORDS = 1900
"""Fresh records more (another seed, each its own specimen) on whose every whole window,
with the :data:`FRESH_RECORDS`', the decoder's probabilities and grain σ are recalibrated
(:mod:`wtml.decoders.recalibration`: a temperature and the top label's map, and a scale and
a 95 % width per :data:`GRAIN_RANGES` range of the answer, and each grade's thresholds):
2000 specimens, 400 a grade. The grain's coverage per grade is a conformal quantile over
that grade's specimens (their windows share their errors), ±3.7 points (1σ) at 68 % on 160
a grade: calibrated on 800 specimens, the main job's decoder covered P320 76 % and P280 62 %
at ±1σ on 1200 fresh specimens; on 2000 (its 800 and 1200 more), 71 % and 65 %, every
grade within 65–72 % and 93–97 % (1 Dec). On 400 specimens the temperature ranged
0.87–1.20 between draws (30 draws from 1900 fresh specimens, 29 Nov), on 800 0.95–1.08."""
CHUNK_RECORDS = 60
"""The calibration records are simulated and run this many at a time: 300 at once took the
main job's texture slice to 2.2 GB."""
GRAIN_INTERVAL = {"sigma": "log_sigma", "value": "grain", "by": "grain", "log_value": True,
                  "stored": "log_std", "classes": "probabilities"}
"""The texture decoder's interval: ``log_sigma``, the log of the std of ln grain size, also
reaching each grade as likely as its threshold (the grades' grain sizes, the scene's
``class_values``: :func:`grain_interval`)."""
def grain_interval(scene) -> dict:
    """:data:`GRAIN_INTERVAL` with the scene's classes' grain sizes (m, in the order of
    :meth:`~wtml.scenes.texture.TextureScene.class_names`)."""
    return GRAIN_INTERVAL | {"class_values": tuple(
        THESIS_GRADES[name] * 1e-6 for name in scene.class_names())}


GRAIN_RANGES = 5
"""Equal-count ranges of the answered grain size, each with its own σ scale and 95 % width:
on 400 independent specimens a row, the σ's one scale left the middle grades at 60–63 % at
±1σ (8 ✗ of 48 cells on the trained physics, chance 1–3); five ranges, 5 ✗ (29 Nov)."""


def calibration_file(path: str | Path, scene, records: dict[str, np.ndarray]) -> Path:
    """Write the calibration ``wtml predict --calibration`` reads to ``path``: each record's
    calibrated T on the scene's ``calibration_hz``, ``t`` ``(n, n_cal, 2, 2)`` (of
    ``records``), and ``frequency_hz`` ``(n_cal,)`` Hz."""
    np.savez(path, t=records["t"], frequency_hz=scene.calibration_hz)
    return Path(path)


def _window_answers(module, raw, records: dict) -> tuple:
    """The gated decoder ``raw`` on every whole window of ``records``, record after record:
    ``(grain, log_sigma, probabilities, in_domain, grade, grain_m, windows per record)``,
    the first six numpy arrays over the windows (float64; the truth repeated per window)."""
    e, i, t_re, t_im = module.gate_inputs(*(torch.tensor(np.asarray(x)) for x in (
        records["e"], records["i"], *flat_parts(records["t"]))))
    per = len(e) // len(records["e"])
    answers = [raw(e[s:s + 100], i[s:s + 100], t_re[s:s + 100], t_im[s:s + 100])
               for s in range(0, len(e), 100)]
    out = tuple(torch.cat([a[k] for a in answers]).double().numpy() for k in (0, 1, 2, -2))
    return (*out, np.repeat(records["grade"], per), np.repeat(records["grain_m"], per), per)


def decoder_graph(module, outputs: tuple[str, ...], uncertainty) -> Gated:
    """The decoder's graph as ``model.onnx`` holds it: ``module``'s net with its recalibration
    (``uncertainty``: the grain σ's scales, the probabilities' temperature and top-label map)
    behind its domain gate, in eval mode; ``(e, i, t_re, t_im) -> (grain, log_sigma,
    probabilities, in_domain)`` at any window length. ``outputs``: the net's outputs' names."""
    return Gated(Recalibrated(module.net, outputs, uncertainty), module.gate, (1,)).eval()


@torch.no_grad()
def export_texture(module, scene, out: Path) -> dict[str, Path]:
    """Write ``out/model.onnx`` (decoder; its probabilities recalibrated and its grain σ scaled,
    both fitted on the fresh records' windows) and ``out/classical.onnx`` (the thesis's
    cues)."""
    window = module._n
    raw = Gated(module.net, module.gate, (1,)).eval()
    fresh = scene.simulate_independent(FRESH_RECORDS,
                                       np.random.default_rng([scene.seed, 10**6 + 1]))
    parts = [_window_answers(module, raw, fresh)]
    for k, start in enumerate(range(0, CALIBRATION_RECORDS, CHUNK_RECORDS)):
        # a chunk at a time: the records' windows as tensors are ~6 MB a record
        more = scene.simulate_independent(min(CHUNK_RECORDS, CALIBRATION_RECORDS - start),
                                          np.random.default_rng([scene.seed, 10**6 + 3, k]))
        parts.append(_window_answers(module, raw, more))
        del more
    per = parts[0][-1]
    grain, log_sigma, probabilities, inside, labels, grains = (
        np.concatenate([part[k] for part in parts]) for k in range(6))
    uncertainty = fit_uncertainty(
        {"grain": grain, "log_sigma": log_sigma, "probabilities": probabilities},
        {"grain": grains}, [grain_interval(scene)], GRAIN_RANGES,
        f"{len(labels)} windows of {FRESH_RECORDS + CALIBRATION_RECORDS} fresh records of the "
        f"trained scene (seeds [{scene.seed}, 1000001] and [{scene.seed}, 1000003, k] for "
        f"chunks k of {CHUNK_RECORDS}; not the training data)", "probabilities", labels)
    decoder = decoder_graph(module, scene.OUTPUTS, uncertainty)
    # the false-alarm rate on the first window of each of the first FRESH_RECORDS
    domain = domain_metadata(scene, float(1 - inside[:FRESH_RECORDS * per:per].mean()),
                             FRESH_RECORDS)
    classical = ClassicalTexture.fit(module.net.features, fresh["e"], fresh["i"], fresh["t"],
                                     fresh["grade"], fresh["grain_m"], window)
    meta = {"wtml_version": __version__, "task": "texture",
            "inputs": json.dumps(list(TEXTURE_INPUTS)),
            "outputs": json.dumps(list(scene.OUTPUTS)),
            "units": json.dumps(scene.UNITS | {"e": "V", "i": "A"}),
            "classes": json.dumps(list(scene.class_names())),
            "frequency_hz": json.dumps(list(scene.drive.whisk_hz)),
            "sample_rate_hz": json.dumps(scene.acquisition.sample_rate_hz),
            "n_samples": json.dumps(window), "window_s": json.dumps(module.hparams.window_s),
            "calibration_hz": json.dumps(scene.calibration_hz.tolist()),
            "references": json.dumps(TEXTURE_REFERENCES),
            "scene": json.dumps(to_dict(scene), sort_keys=True), "scene_hash": config_hash(scene),
            "domain": json.dumps(domain)}
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    widths = (window, window, (len(scene.calibration_hz), 4), (len(scene.calibration_hz), 4))
    export_graph(decoder, window, paths["decoder"],
                 meta | {"kind": "decoder", "label": "decoder",
                         "uncertainty": metadata(uncertainty)},
                 TEXTURE_INPUTS, widths)
    export_graph(Gated(classical, module.gate.inputs_only()).eval(), window, paths["classical"],
            meta | {"kind": "classical", "label": "thesis cues (|F|, |V|, Zm)"}, TEXTURE_INPUTS,
            widths)
    return paths
