"""What every exported graph goes through: ``torch.onnx.export`` with a dynamic batch and the
metadata added and checked (:func:`export_graph`), and the trained domain as the metadata
states it (:func:`domain_metadata`, :func:`false_alarm_rate`)."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from wtml.decoders.domain import QUANTILE, Gated
from wtml.runtime.metadata import GATE_OUTPUTS, INPUTS

OPSET = 18
"""The ONNX opset of every exported graph."""


def export_graph(module: nn.Module, n_freq: int, path: Path, metadata: dict[str, str],
                 inputs: tuple[str, ...] = INPUTS,
                 widths: tuple[int | tuple[int, ...], ...] | None = None) -> None:
    """Write ``module`` (inputs ``inputs``, each ``(batch, n_freq)`` float32, or
    ``(batch, widths[k])`` where given, ``(batch, *widths[k])`` for a tuple; dynamic batch)
    to ``path`` with ``metadata``, and check the file.

    Through torch's TorchScript-based exporter (``dynamo=False``), which torch 2.13 deprecates
    but keeps: it traces the main job's graphs in 0.1-1 s each where the torch.export-based
    one took 3-15 s and 0.95 GB (36 s for the onset task's three, 20 s for texture's two),
    for graphs that run as fast in onnxruntime (batch 1 and 4096, side by side: within 5 %).
    Every graph's batch is dynamic (no shape is read from it but through ``x.shape``), which
    the parity tests check at batches other than the traced one."""
    example = tuple(torch.ones(2, *np.atleast_1d(w).tolist())
                    for w in (widths or (n_freq,) * len(inputs)))
    names = json.loads(metadata["outputs"]) + list(GATE_OUTPUTS)
    with warnings.catch_warnings():
        # "You are using the legacy TorchScript-based ONNX export" and its helpers' notices
        for notice in ("You are using the legacy TorchScript-based ONNX export",
                       "The feature will be removed"):
            warnings.filterwarnings("ignore", message=notice, category=DeprecationWarning)
        # buffers' lengths and constants built in forward are traced as constants, as meant
        warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)
        # strided slices (the onset decoder's frames) are left to onnxruntime to fold
        warnings.filterwarnings("ignore", message="Constant folding - Only steps=1")
        torch.onnx.export(module.eval(), example, str(path), input_names=list(inputs),
                          output_names=names, dynamo=False, opset_version=OPSET,
                          dynamic_axes={name: {0: "batch"} for name in (*inputs, *names)})
    model = onnx.load(str(path))
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))


@torch.no_grad()
def false_alarm_rate(model: Gated, *inputs: np.ndarray) -> float:
    """The fraction of in-domain measurements (the graph's ``inputs``, e.g. ``Re Ze, Im Ze``
    each ``(n, n_freq)``) that ``model`` flags as out of domain."""
    out = model(*(torch.tensor(np.asarray(x), dtype=torch.float32) for x in inputs))
    return float(1.0 - out[-2].float().mean())


def domain_metadata(scene, false_alarm: float, n_fresh: int) -> dict:
    """The trained domain as the exported metadata states it (JSON-ready)."""
    outputs = {}
    for name, r in scene.output_ranges().items():
        outputs[name] = {"trained": [r.low, r.high], "in_domain": list(r.widened()),
                         "physical": list(r.physical), "log": r.log,
                         "absent_ok": r.absent_ok}
    return {"score": "the larger of the squared whitened distance of the input features from "
                     "the training mean over its training quantile, and the distance outside "
                     "the training features' box in units of 5 % of each span; <= 1 inside",
            "quantile": QUANTILE,
            "false_alarm_fresh": false_alarm, "n_fresh": n_fresh, "outputs": outputs}
