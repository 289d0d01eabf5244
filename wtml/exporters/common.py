"""Checkpoint -> ONNX: the decoder and, beside it, the classical path as its own graph.

Both graphs take ``ze_re, ze_im`` (float32, ``(batch, n_freq)``, Ω, dynamic batch) and what
the task's metadata's ``references`` names: fluid the user's calibrated T as ``t_re, t_im``,
``(batch, n_freq, 4)``; radial ``ref_re, ref_im``, ``(batch, n_freq)``, the free whisker's Ze
of the user's device at the same tones (a sample ``sample_reference.npz`` of the nominal
device is written beside them). They return
the task's outputs (``scene.OUTPUTS``), each ``(batch,)``: fluid ``eta`` (Pa·s) and ``rho``
(kg/m³); radial ``distance`` (m from the tip) and ``sigma`` (m, the decoder's own
uncertainty; 0 where it has none), then ``in_domain`` (bool) and ``domain_score`` (float,
``<= 1`` inside the trained domain): the decoder's domain gate (``wtml.decoders.domain``)
is part of both graphs. The decoder's ``in_domain`` also requires its answer inside the
trained range; the classical graph's judges the input only (its answers are checked against
the physically possible range by ``wtml predict``). The fluid classical graph is the thesis's
closed form, calibrated T -> Zm -> band least squares; the radial one is the thesis's
classical decoder, the 9th-degree polynomial of d in Im Ze, of the ratio to the reference
(``wtml.baselines.radial.PolynomialRadial``). The metadata of each model
carries what a device needs: names and units, the frequency grid, the scene and its hash,
the trained domain and its measured false-alarm rate, the package version. A device needs
onnxruntime only.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from wtml import __version__
from wtml.baselines.fluid_classical import band_pseudo_inverse
from wtml.decoders.checkpoint import load_decoder
from wtml.decoders.domain import Gated
from wtml.decoders.layers import StandardPolynomial, ZmFromZe
from wtml.devices import identity
from wtml.exporters.graphs import domain_metadata, export_graph, false_alarm_rate
from wtml.physics.twoport import flat_parts
from wtml.runtime.metadata import (
    FLUID_INPUTS,
    INPUTS,
    MANIFEST,
    RADIAL_INPUTS,
    write_manifest,
)
from wtml.scenes import config_hash, device_of, scene_from_dict, to_dict
from wtml.tasks import TASKS

REFERENCES = {
    "fluid": {"calibration": "the device's calibrated T (whisker with its sphere) at the "
                             "sweep frequencies, measured with the calibration loads of "
                             "physics.md §4: inputs t_re, t_im"},
    "radial": {"reference": "the free (untouched) whisker's Ze of this device at the "
                            "model's frequencies, measured when it is set up "
                            "(ref_re, ref_im; wtml predict --reference)"}}
"""What each task's export needs besides the measurement (the metadata's ``references``)."""
FRESH_SAMPLES = 20000
"""Fresh samples of the scene (not the training data) on which the exported decoder's
false-alarm rate is measured and stated in its metadata."""


class ClassicalFluidNet(nn.Module):
    """The classical path in float32 real arithmetic: the user's calibrated T -> Zm -> band LS
    (η, ρ) with the nominal sphere radius.

    Args:
        omega: ``(n_freq,)`` rad/s; radius: m.

    Forward: ``ze_re, ze_im`` ``(batch, n_freq)`` Ω, ``t_re, t_im`` ``(batch, n_freq, 4)`` ->
    ``eta, rho`` ``(batch,)``.
    """

    def __init__(self, omega: np.ndarray, radius: float) -> None:
        super().__init__()
        self.zm = ZmFromZe()
        pinv = band_pseudo_inverse(np.asarray(omega, float), radius)[:2]  # rows η, ρ
        self.register_buffer("pinv", torch.tensor(pinv.T, dtype=torch.float32))

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        zm_re, zm_im = self.zm(ze_re, ze_im, t_re, t_im)
        u = torch.cat([zm_re, zm_im], -1) @ self.pinv
        return u[:, 0], u[:, 1]


class PolynomialNet(nn.Module):
    """A fitted ``PolynomialRadial`` as a graph: ``(distance, zeros)`` from Ze and the
    reference."""

    def __init__(self, poly) -> None:
        super().__init__()
        self.part, self.reference = poly.part, poly.reference
        self.poly = StandardPolynomial(poly.model.steps[1][1].degree).load_pipeline(poly.model)

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, ref_re: torch.Tensor,
                ref_im: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        from wtml.decoders.radial import ratio

        z = ratio(ze_re, ze_im, ref_re, ref_im) if self.reference else (ze_re, ze_im)
        y = self.poly(z[0 if self.part == "real" else 1][:, 0])
        return y, torch.zeros_like(y)


def export_model(checkpoint: str | Path, out: str | Path) -> dict[str, Path]:
    """Write ``model.onnx`` (decoder) and ``classical.onnx`` for the checkpoint's task into
    ``out`` (radial: and ``sample_reference.npz``; onset: and ``stream.onnx``), then
    ``manifest.json`` listing them with their sha256 and size
    (:func:`wtml.runtime.metadata.write_manifest`); returns the paths.

    Raises:
        CheckpointError: the checkpoint is missing, unreadable, unsafe or not wtml's.
        ValueError: ``out`` is an existing file.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out}: is a file; give a folder (e.g. export/<task>)")
    module = load_decoder(checkpoint)
    scene = scene_from_dict(module.scene)
    task = scene.task
    out.mkdir(parents=True, exist_ok=True)
    (out / MANIFEST).unlink(missing_ok=True)  # until the new one is written: no export here
    paths = TASKS[task].load("export")(module, scene, out)
    metadata = {p.name: {m.key: m.value for m in onnx.load(str(p)).metadata_props}
                for p in paths.values() if p.suffix == ".onnx"}
    paths["manifest"] = write_manifest(out, paths, metadata, task=task,
                                       scene_hash=config_hash(scene),
                                       device=identity(device_of(scene)), version=__version__)
    return paths


def export_matrix_task(module, scene, out: Path) -> dict[str, Path]:
    """The fluid and radial graphs (and radial's sample reference) into ``out``."""
    task = scene.task
    freq = (scene.excitation.frequency_hz if task == "fluid"
            else np.asarray(scene.excitation.frequencies_hz))
    uncertain = tuple(k for k, name in enumerate(scene.OUTPUTS) if name == "sigma")
    decoder = Gated(module.net, module.gate, uncertain).eval()
    if task == "fluid":
        classical = ClassicalFluidNet(scene.excitation.omega, scene.sphere.radius)
        label = "thesis closed form"
    else:
        from wtml.baselines.radial import PolynomialRadial

        train = scene.simulate(20000, np.random.default_rng([scene.seed, 10**6]))
        poly = PolynomialRadial("imag").fit(train["ze"], train["ref"], train["distance"])
        classical = PolynomialNet(poly)
        label = poly.name  # fitted on 20000 fresh samples of the scene
    fresh = scene.simulate(FRESH_SAMPLES, np.random.default_rng([scene.seed, 10**6 + 1]))
    inputs, widths = INPUTS, None
    fresh_inputs = (fresh["ze"].real, fresh["ze"].imag)
    if task == "fluid":
        inputs, widths = FLUID_INPUTS, (len(freq),) * 2 + ((len(freq), 4),) * 2
        fresh_inputs += flat_parts(fresh["t"])
    elif task == "radial":
        inputs = RADIAL_INPUTS
        fresh_inputs += (fresh["ref"].real, fresh["ref"].imag)
    domain = domain_metadata(scene, false_alarm_rate(decoder, *fresh_inputs), FRESH_SAMPLES)
    meta = {
        "wtml_version": __version__,
        "task": task,
        "inputs": json.dumps(list(inputs)),
        "references": json.dumps(REFERENCES.get(task, {})),
        "outputs": json.dumps(list(scene.OUTPUTS)),
        "units": json.dumps(scene.UNITS | {name: "ohm" for name in inputs}),
        "frequency_hz": json.dumps(freq.tolist()),
        "scene": json.dumps(to_dict(scene), sort_keys=True),
        "scene_hash": config_hash(scene),
        "domain": json.dumps(domain),
    }
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    if task == "radial":  # the nominal device's free Ze, noise-free: a --reference example
        paths["sample reference"] = out / "sample_reference.npz"
        np.savez(paths["sample reference"], frequency_hz=freq, ze=scene.free_ze())
    n_freq = len(freq)
    export_graph(decoder, n_freq, paths["decoder"], meta | {"kind": "decoder", "label": "decoder"},
            inputs, widths)
    export_graph(Gated(classical, module.gate.inputs_only()).eval(), n_freq, paths["classical"],
            meta | {"kind": "classical", "label": label}, inputs, widths)
    return paths
