"""Checkpoint -> ONNX: the decoder and, beside it, the classical path as its own graph.

Both graphs take ``ze_re, ze_im`` (float32, ``(batch, n_freq)``, Ω, dynamic batch) and return
the task's outputs, each ``(batch,)``: fluid ``eta`` (Pa·s) and ``rho`` (kg/m³); radial
``distance`` (m from the tip) and ``sigma`` (m, the decoder's own uncertainty; 0 where it has
none). The fluid classical graph is calibrated T -> Zm -> band least squares; the radial one
is the thesis's classical decoder, the 9th-degree polynomial of d in Im Ze. The metadata of
each model carries what a device needs: names and units, the frequency grid, the scene and
its hash, the package version. A device needs onnxruntime only.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from wtml import __version__
from wtml.baselines.fluid_classical import band_pseudo_inverse
from wtml.decoders.fluid import load_fluid_net
from wtml.decoders.layers import StandardPolynomial, ZmFromZe
from wtml.scenes import config_hash, scene_from_dict

INPUTS = ("ze_re", "ze_im")
OUTPUTS = {"fluid": ("eta", "rho"), "radial": ("distance", "sigma")}
UNITS = {"ze_re": "ohm", "ze_im": "ohm", "eta": "Pa*s", "rho": "kg/m^3", "distance": "m",
         "sigma": "m"}


class ClassicalFluidNet(nn.Module):
    """The classical path in float32 real arithmetic: calibrated T -> Zm -> band LS (η, ρ).

    Args:
        t_cal: complex ``(n_freq, 2, 2)``; omega: ``(n_freq,)`` rad/s; radius: m.
    """

    def __init__(self, t_cal: np.ndarray, omega: np.ndarray, radius: float) -> None:
        super().__init__()
        self.zm = ZmFromZe(t_cal)
        pinv = band_pseudo_inverse(np.asarray(omega, float), radius)[:2]  # rows η, ρ
        self.register_buffer("pinv", torch.tensor(pinv.T, dtype=torch.float32))

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        zm_re, zm_im = self.zm(ze_re, ze_im)
        u = torch.cat([zm_re, zm_im], -1) @ self.pinv
        return u[:, 0], u[:, 1]


class PolynomialNet(nn.Module):
    """A fitted ``PolynomialRadial`` as a graph: ``(distance, zeros)`` from Ze."""

    def __init__(self, poly) -> None:
        super().__init__()
        self.part = poly.part
        self.poly = StandardPolynomial(poly.model.steps[1][1].degree).load_pipeline(poly.model)

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        y = self.poly((ze_re if self.part == "real" else ze_im)[:, 0])
        return y, torch.zeros_like(y)


def _export(module: nn.Module, n_freq: int, path: Path, metadata: dict[str, str]) -> None:
    example = (torch.ones(2, n_freq), torch.ones(2, n_freq))
    batch = torch.export.Dim("batch", min=1)
    with warnings.catch_warnings():
        # both inputs share the one batch dimension, which the exporter remarks on
        warnings.filterwarnings("ignore", message=r"# The axis name: batch will not be used")
        torch.onnx.export(module.eval(), example, str(path), input_names=list(INPUTS),
                          output_names=json.loads(metadata["outputs"]), dynamo=True,
                          external_data=False,
                          dynamic_shapes={"ze_re": {0: batch}, "ze_im": {0: batch}},
                          verbose=False)
    model = onnx.load(str(path))
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))


def export_model(checkpoint: str | Path, out: str | Path) -> dict[str, Path]:
    """Write ``model.onnx`` (decoder) and ``classical.onnx`` for the checkpoint's task into
    ``out``; returns the paths."""
    info = torch.load(str(checkpoint), map_location="cpu", weights_only=False).get("wtml")
    if not info or not info.get("scene"):
        raise ValueError(f"{checkpoint}: not a wtml checkpoint (no scene inside)")
    scene = scene_from_dict(info["scene"])
    task = scene.task
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    freq = (scene.excitation.frequency_hz if task == "fluid"
            else np.asarray(scene.excitation.frequencies_hz))
    meta = {
        "wtml_version": __version__,
        "task": task,
        "inputs": json.dumps(list(INPUTS)),
        "outputs": json.dumps(list(OUTPUTS[task])),
        "units": json.dumps(UNITS),
        "frequency_hz": json.dumps(freq.tolist()),
        "scene": json.dumps(info["scene"], sort_keys=True),
        "scene_hash": config_hash(scene),
    }
    if task == "fluid":
        net, _ = load_fluid_net(str(checkpoint))
        classical = ClassicalFluidNet(scene.calibrated_t(), scene.excitation.omega,
                                      scene.sphere.radius)
        label = "classical"
    else:
        from wtml.baselines.radial import PolynomialRadial
        from wtml.decoders.radial import load_radial_net

        net, _ = load_radial_net(str(checkpoint))
        train = scene.simulate(20000, np.random.default_rng([scene.seed, 10**6]))
        classical = PolynomialNet(PolynomialRadial("imag").fit(train["ze"], train["distance"]))
        label = "polynomial 9 in Im Ze"  # fitted on 20000 fresh samples of the scene
    paths = {"decoder": out / "model.onnx", "classical": out / "classical.onnx"}
    n_freq = len(freq)
    _export(net, n_freq, paths["decoder"], meta | {"kind": "decoder", "label": "decoder"})
    _export(classical, n_freq, paths["classical"], meta | {"kind": "classical", "label": label})
    return paths
