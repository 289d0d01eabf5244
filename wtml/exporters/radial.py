"""The radial task's export (:func:`export_radial`): the decoder and the thesis's classical
decoder, the 9th-degree polynomial of d in Im Ze of the ratio to the reference
(``wtml.baselines.radial.PolynomialRadial``, as :class:`PolynomialNet`), as two graphs
(:mod:`wtml.exporters.matrix`), and ``sample_reference.npz``, the nominal device's free Ze, a
``wtml predict --reference`` example. Both graphs take ``ze_re, ze_im`` and ``ref_re,
ref_im`` (the free whisker's Ze of the user's device at the same tones), each
``(batch, n_freq)`` Ω, and return ``distance`` (m from the tip) and ``sigma`` (m: the
decoder's std, recalibrated per range of d; the classical graph's 0: it has none), each
``(batch,)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from wtml.decoders.layers import StandardPolynomial
from wtml.exporters.matrix import MatrixTask, export_matrix
from wtml.runtime.metadata import RADIAL_INPUTS

CLASSICAL_SAMPLES = 20000
"""Fresh samples of the scene (seed ``[scene.seed, 10**6]``) the classical polynomial is fitted
on."""


class PolynomialNet(nn.Module):
    """A fitted ``PolynomialRadial`` as a graph: ``(distance, zeros)`` from Ze and the
    reference.

    Forward: ``ze_re, ze_im, ref_re, ref_im`` ``(batch, n_freq)`` Ω -> ``distance`` (m) and
    ``sigma`` (0), each ``(batch,)``.
    """

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


def classical_graph(scene) -> tuple[nn.Module, str]:
    """The polynomial in Im Ze / ref fitted on :data:`CLASSICAL_SAMPLES` fresh samples of the
    scene, as a graph, and its label."""
    from wtml.baselines.radial import PolynomialRadial

    train = scene.simulate(CLASSICAL_SAMPLES, np.random.default_rng([scene.seed, 10**6]))
    poly = PolynomialRadial("imag").fit(train["ze"], train["ref"], train["distance"])
    return PolynomialNet(poly), poly.name


def interval_specs(net: nn.Module) -> list[dict]:
    """The radial decoder's σ, per range of d: its σ head's, recalibrated, where it has one
    (the thesis's 2-10-1 has none: its σ becomes one per range of d)."""
    return [{"sigma": "sigma", "value": "distance", "by": "distance", "log_value": False,
             "stored": "std" if net.uncertainty else "none"}]


RADIAL = MatrixTask(
    inputs=RADIAL_INPUTS, reference_shape=(), reference="reference",
    reference_text="the free (untouched) whisker's Ze of this device at the model's "
                   "frequencies, measured when it is set up (ref_re, ref_im; wtml predict "
                   "--reference)",
    reference_file="sample_input_reference.npz", reference_key="ze", reference_array="ref",
    truth={"distance": "true_distance_m"}, n_ranges=8,
    classical=classical_graph, intervals=interval_specs)
"""The radial task's export and sample measurements (``wtml.tasks``' ``measurement`` part)."""


SAMPLE_REFERENCE = "sample_reference.npz"
"""The export's own reference file, listed in its manifest (``wtml pipeline``'s sample
measurements bring theirs beside them: ``RADIAL.reference_file``)."""


def export_radial(module, scene, out: Path) -> dict[str, Path]:
    """The radial graphs, ``model.onnx`` and ``classical.onnx``
    (:func:`wtml.exporters.matrix.export_matrix`), and ``sample_reference.npz`` (the nominal
    device's free Ze, noise-free: ``frequency_hz`` ``(n_freq,)`` Hz, ``ze`` ``(n_freq,)``
    Ω) into ``out``; returns ``{kind: path}``."""
    paths = export_matrix(module, scene, out, RADIAL)
    paths["sample reference"] = out / SAMPLE_REFERENCE
    np.savez(paths["sample reference"], frequency_hz=scene.excitation.frequency_hz,
             ze=scene.free_ze())
    return paths
