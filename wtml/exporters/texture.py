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
from wtml.exporters.graphs import domain_metadata, export_graph
from wtml.physics.twoport import flat_parts
from wtml.runtime.metadata import TEXTURE_INPUTS
from wtml.scenes import config_hash, to_dict

TEXTURE_REFERENCES = {"calibration": "the device's calibrated T (the macro WT with its whisker, "
                                     "tip free) at calibration_hz, measured with the "
                                     "calibration loads of physics.md §4: inputs t_re, t_im"}
FRESH_RECORDS = 100
"""Fresh records of the scene (its own seed, not the training data) on which the classical
path is fitted and the exported decoder's false-alarm rate is measured."""


@torch.no_grad()
def export_texture(module, scene, out: Path) -> dict[str, Path]:
    """Write ``out/model.onnx`` (decoder) and ``out/classical.onnx`` (the thesis's cues)."""
    window = module._n
    decoder = Gated(module.net, module.gate, (1,)).eval()
    fresh = scene.simulate(FRESH_RECORDS, np.random.default_rng([scene.seed, 10**6 + 1]))
    inside = decoder(torch.tensor(fresh["e"][:, :window]), torch.tensor(fresh["i"][:, :window]),
                     *(torch.tensor(x) for x in flat_parts(fresh["t"])))[-2]
    domain = domain_metadata(scene, float(1 - inside.float().mean()), FRESH_RECORDS)
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
    export_graph(decoder, window, paths["decoder"], meta | {"kind": "decoder", "label": "decoder"},
            TEXTURE_INPUTS, widths, optimize=False)
    export_graph(Gated(classical, module.gate.inputs_only()).eval(), window, paths["classical"],
            meta | {"kind": "classical", "label": "thesis cues (|F|, |V|, Zm)"}, TEXTURE_INPUTS,
            widths, optimize=False)
    return paths
