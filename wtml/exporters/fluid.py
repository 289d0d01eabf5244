"""The fluid task's export (:func:`export_fluid`): the decoder and the thesis's closed form,
calibrated T -> Zm -> band least squares (:class:`ClassicalFluidNet`), as two graphs
(:mod:`wtml.exporters.matrix`). Both take ``ze_re, ze_im`` ``(batch, n_freq)`` Ω and the
user's calibrated T as ``t_re, t_im`` ``(batch, n_freq, 4)``, and return ``eta`` (Pa·s) and
``rho`` (kg/m³), each ``(batch,)``; the decoder also ``eta_log_sigma`` (the std of ln η) and
``rho_sigma`` (kg/m³), recalibrated per decade of η.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from wtml.baselines.fluid_classical import band_pseudo_inverse
from wtml.decoders.layers import ZmFromZe
from wtml.exporters.matrix import MatrixTask, export_matrix
from wtml.runtime.metadata import FLUID_INPUTS, FLUID_SIGMAS

SIGMA_UNITS = dict(zip(FLUID_SIGMAS, ("1", "kg/m^3"), strict=True))
"""The units of the σ outputs the fluid decoder's graph adds: the std of ln η, of ρ."""


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


def classical_graph(scene) -> tuple[nn.Module, str]:
    """The thesis's closed form on the scene's grid and nominal sphere, and its label."""
    return ClassicalFluidNet(scene.excitation.omega, scene.sphere.radius), "thesis closed form"


def interval_specs(net: nn.Module) -> list[dict]:
    """The σ outputs the fluid decoder's graph adds (its net has none): the std of ln η and of
    ρ, each per range of η (the η decade sets both errors: ρ's median error is 0.5 % below
    1e-2 Pa·s and 0.04 % above 1 Pa·s)."""
    return [{"sigma": FLUID_SIGMAS[0], "value": "eta", "by": "eta", "log_value": True,
             "stored": "none"},
            {"sigma": FLUID_SIGMAS[1], "value": "rho", "by": "eta", "log_value": False,
             "stored": "none"}]


FLUID = MatrixTask(
    inputs=FLUID_INPUTS, reference_shape=(4,), reference="calibration",
    reference_text="the device's calibrated T (whisker with its sphere) at the sweep "
                   "frequencies, measured with the calibration loads of physics.md §4: "
                   "inputs t_re, t_im",
    reference_file="calibration.npz", reference_key="t", reference_array="t",
    truth={"eta": "true_eta_pa_s", "rho": "true_rho_kg_m3"}, n_ranges=10,
    classical=classical_graph, intervals=interval_specs, units=SIGMA_UNITS)
"""The fluid task's export and sample measurements (``wtml.tasks``' ``measurement`` part)."""


def export_fluid(module, scene, out: Path) -> dict[str, Path]:
    """The fluid graphs, ``model.onnx`` and ``classical.onnx``, into ``out``
    (:func:`wtml.exporters.matrix.export_matrix`); returns ``{kind: path}``."""
    return export_matrix(module, scene, out, FLUID)
