"""The export of a task that reads measurements (Ze on its scene's frequency grid,
``scene.excitation.frequency_hz``, with one reference of the user's device beside it): the
decoder and its classical path as two graphs, made the same way for every such task from what
the task declares in its own module, a :class:`MatrixTask` (:mod:`wtml.exporters.fluid`,
:mod:`wtml.exporters.radial`; ``wtml.tasks``' ``measurement`` part).

Both graphs take ``ze_re, ze_im`` (float32, ``(batch, n_freq)``, Ω, dynamic batch) and the
reference's two parts (the task's ``inputs``), and return the task's outputs
(``scene.OUTPUTS``, each ``(batch,)``), the decoder's with its σ recalibrated per range of its
answer on :data:`FRESH_SAMPLES` fresh samples of the scene (:mod:`wtml.decoders.recalibration`),
then ``in_domain`` and ``domain_score``: the decoder's domain gate
(:mod:`wtml.decoders.domain`) is part of both graphs.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from wtml import __version__
from wtml.decoders.domain import Gated
from wtml.decoders.recalibration import Recalibrated, fit_uncertainty, metadata
from wtml.exporters.graphs import domain_metadata, export_graph, false_alarm_rate
from wtml.scenes import config_hash, to_dict

FRESH_SAMPLES = 20000
"""Fresh samples of the scene (not the training data) on which the exported decoder's
false-alarm rate is measured and stated in its metadata, and its σ recalibrated."""


@dataclass(frozen=True)
class MatrixTask:
    """What one measurement task's export and sample measurements are made of.

    Attributes:
        inputs: the graphs' input names (:mod:`wtml.runtime.metadata`): ``ze_re, ze_im``, then
            the reference's real and imaginary parts, in the order of the scene's
            ``decoder_inputs``.
        reference_shape: the shape of each reference part at one frequency: ``(4,)`` for a
            T flattened as (t11, t12, t21, t22), ``()`` for a Ze.
        reference: ``wtml predict``'s keyword (and ``--`` flag) for the user's reference:
            ``"calibration"`` or ``"reference"``.
        reference_text: what that reference is and how it is measured (the metadata's
            ``references``).
        reference_file: the name of the file of references ``wtml pipeline`` writes beside its
            sample measurements (:func:`wtml.pipeline.write_sample_csv`); none of the
            export's own files (a manifest lists those with their hashes).
        reference_key: that file's array of them, ``(n, n_freq, *reference_shape)``.
        reference_array: the dataset's array they come from.
        truth: the sample measurements' truth columns: ``{dataset array: CSV column}``.
        n_ranges: ranges of the answer in which the decoder's σ is recalibrated (equal counts
            of the :data:`FRESH_SAMPLES` held-out answers).
        units: the units of the outputs the decoder's graph adds to ``scene.UNITS`` (the σ
            its net has none of).
        classical: ``scene -> (graph, label)``: the classical path as a module taking the
            decoder's inputs and returning the scene's outputs (σ: 0 where it has none), and
            the label its metadata gives it.
        intervals: ``net -> specs``: the σ outputs of the decoder's graph and what each is
            the std of (:func:`wtml.decoders.recalibration.fit_uncertainty`).
    """

    inputs: tuple[str, ...]
    reference_shape: tuple[int, ...]
    reference: str
    reference_text: str
    reference_file: str
    reference_key: str
    reference_array: str
    truth: dict[str, str]
    n_ranges: int
    classical: Callable[[Any], tuple[nn.Module, str]]
    intervals: Callable[[nn.Module], list[dict]]
    units: dict[str, str] = field(default_factory=dict)


def export_matrix(module, scene, out: Path, spec: MatrixTask) -> dict[str, Path]:
    """Write the decoder (``model.onnx``) and the classical path (``classical.onnx``) of a
    measurement task, declared by ``spec``, into ``out``; returns ``{kind: path}``.

    Args:
        module: the task's trained decoder (a ``LightningModule`` with ``net`` and ``gate``).
        scene: its scene (the frequency grid, the outputs, the fresh samples).
        out: an existing folder.
        spec: the task's :class:`MatrixTask`.
    """
    freq = scene.excitation.frequency_hz
    n_freq = len(freq)
    uncertain = tuple(k for k, name in enumerate(scene.OUTPUTS) if name == "sigma")
    raw = Gated(module.net, module.gate, uncertain).eval()
    classical, label = spec.classical(scene)
    fresh = scene.simulate(FRESH_SAMPLES, np.random.default_rng([scene.seed, 10**6 + 1]))
    fresh_inputs = scene.decoder_inputs(fresh)
    widths = (n_freq, n_freq, *((n_freq, *spec.reference_shape),) * 2)
    with torch.no_grad():
        answers = raw(*(torch.tensor(np.asarray(x), dtype=torch.float32)
                        for x in fresh_inputs))
    uncertainty = fit_uncertainty(
        {name: a.double().numpy() for name, a in zip(scene.OUTPUTS, answers, strict=False)},
        fresh, spec.intervals(module.net), spec.n_ranges,
        f"{FRESH_SAMPLES} fresh samples of the trained scene (seed [{scene.seed}, 1000001]; "
        f"not the training data)")
    calibrated = Recalibrated(module.net, scene.OUTPUTS, uncertainty)
    decoder = Gated(calibrated, module.gate, tuple(
        k for k, name in enumerate(calibrated.outputs)
        if name in {r.sigma for r in uncertainty.intervals})).eval()
    domain = domain_metadata(scene, false_alarm_rate(decoder, *fresh_inputs), FRESH_SAMPLES)
    meta = {
        "wtml_version": __version__,
        "task": scene.task,
        "inputs": json.dumps(list(spec.inputs)),
        "references": json.dumps({spec.reference: spec.reference_text}),
        "outputs": json.dumps(list(scene.OUTPUTS)),
        "units": json.dumps(scene.UNITS | spec.units | {name: "ohm" for name in spec.inputs}),
        "frequency_hz": json.dumps(freq.tolist()),
        "scene": json.dumps(to_dict(scene), sort_keys=True),
        "scene_hash": config_hash(scene),
        "domain": json.dumps(domain),
    }
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    export_graph(decoder, n_freq, paths["decoder"],
                 meta | {"kind": "decoder", "label": "decoder",
                         "outputs": json.dumps(list(calibrated.outputs)),
                         "uncertainty": metadata(uncertainty)}, spec.inputs, widths)
    export_graph(Gated(classical, module.gate.inputs_only()).eval(), n_freq, paths["classical"],
                 meta | {"kind": "classical", "label": label}, spec.inputs, widths)
    return paths

