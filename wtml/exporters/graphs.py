"""What every exported graph goes through: ``torch.onnx.export`` with a dynamic batch and the
metadata added and checked (:func:`export_graph`), and the trained domain as the metadata
states it (:func:`domain_metadata`, :func:`false_alarm_rate`)."""

from __future__ import annotations

import json
import logging
import warnings
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from wtml.decoders.domain import QUANTILE, Gated
from wtml.runtime.metadata import GATE_OUTPUTS, INPUTS


def export_graph(module: nn.Module, n_freq: int, path: Path, metadata: dict[str, str],
            inputs: tuple[str, ...] = INPUTS,
            widths: tuple[int | tuple[int, ...], ...] | None = None,
            optimize: bool = True) -> None:
    """Write ``module`` (inputs ``inputs``, each ``(batch, n_freq)`` float32, or
    ``(batch, widths[k])`` where given, ``(batch, *widths[k])`` for a tuple; dynamic batch)
    to ``path`` with ``metadata``, and check the file. ``optimize=False`` skips the exporter's
    graph optimisation (for graphs of thousands of small nodes, where it takes minutes and
    gains little)."""
    example = tuple(torch.ones(2, *np.atleast_1d(w).tolist())
                    for w in (widths or (n_freq,) * len(inputs)))
    batch = torch.export.Dim("batch", min=1)
    names = json.loads(metadata["outputs"]) + list(GATE_OUTPUTS)
    registry = logging.getLogger("torch.onnx._internal.exporter._registration")
    level = registry.level
    registry.setLevel(logging.ERROR)  # "torchvision is not installed. Skipping ..." (4 lines)
    with warnings.catch_warnings():
        # both inputs share the one batch dimension, which the exporter remarks on
        warnings.filterwarnings("ignore", message=r"# The axis name: batch will not be used")
        # torch's own exporter calls a pytree API that torch 2.13 deprecates
        warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)`",
                                category=FutureWarning)
        torch.onnx.export(module.eval(), example, str(path), input_names=list(inputs),
                          output_names=names, dynamo=True, external_data=False,
                          optimize=optimize,
                          dynamic_shapes=batch_dims(module, len(example), batch),
                          verbose=False)
    registry.setLevel(level)
    model = onnx.load(str(path))
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))


def batch_dims(module: nn.Module, n_inputs: int, batch) -> dict | tuple:
    """The exporter's ``dynamic_shapes``: dimension 0 of each of ``module.forward``'s
    ``n_inputs`` tensor arguments is ``batch`` (keyed by name, or one tuple for ``*inputs``)."""
    import inspect

    params = inspect.signature(module.forward).parameters.values()
    if any(p.kind is p.VAR_POSITIONAL for p in params):
        return (tuple({0: batch} for _ in range(n_inputs)),)
    return {p.name: {0: batch} for p in params}


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
