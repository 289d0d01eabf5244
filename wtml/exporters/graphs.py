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
FROZEN = tuple(f"Converting a tensor to a Python {kind}"
               for kind in ("integer", "index", "float", "complex", "number", "list")
               ) + ("Iterating over a tensor",)
"""The tracer's warnings that :func:`export_graph` refuses: what they name is fixed in the
graph as the value it had in the trace. A boolean is not among them: it is a branch taken
while tracing, as the band powers' checks of a window's fixed width are. The tracer's other
warnings (buffers' lengths, constants built in forward: traced as constants, as meant) are
let go."""
QUIET = ("You are using the legacy TorchScript-based ONNX export",
         "The feature will be removed", "Constant folding - Only steps=1")
"""The exporter's own notices, let go; any other warning from the export is passed on."""


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
    Tracing fixes whatever Python reads of the batch but ``x.shape``: a tensor turned into a
    Python number or iterated over during the trace is refused (:data:`FROZEN`), and the
    graph is run here at batch 3 and at batch 1 on each of those rows (:func:`check_batch`);
    the parity tests compare it with torch at other batches.

    Raises:
        ValueError: ``module`` turns a tensor into a Python number while traced, or the
            graph's answers depend on the batch's size.
    """
    example = tuple(torch.ones(2, *np.atleast_1d(w).tolist())
                    for w in (widths or (n_freq,) * len(inputs)))
    names = json.loads(metadata["outputs"]) + list(GATE_OUTPUTS)
    with warnings.catch_warnings(record=True) as heard:
        warnings.simplefilter("always")
        torch.onnx.export(module.eval(), example, str(path), input_names=list(inputs),
                          output_names=names, dynamo=False, opset_version=OPSET,
                          dynamic_axes={name: {0: "batch"} for name in (*inputs, *names)})
    for w in heard:
        text = str(w.message)
        if issubclass(w.category, torch.jit.TracerWarning) and text.startswith(FROZEN):
            raise ValueError(f"{path.name}: {w.filename}:{w.lineno} turns a tensor into a "
                             "Python number or iterates over it while traced, which would fix "
                             f"it in the graph (the batch's size, or data): {text.split('.')[0]}")
        if not (issubclass(w.category, torch.jit.TracerWarning) or text.startswith(QUIET)):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    model = onnx.load(str(path))
    for key, value in metadata.items():
        model.metadata_props.add(key=key, value=value)
    onnx.checker.check_model(model, full_check=True)
    onnx.save(model, str(path))
    check_batch(path, tuple(x[:1] for x in example))


def check_batch(path: Path, row: tuple[torch.Tensor, ...]) -> None:
    """Run the graph at ``path`` (onnxruntime) on three rows (``row``, each input's one row,
    scaled by 1, 1.1 and 1.2) at once and one row at a time: every output has the three
    rows, each its row's own answer (to 1e-4 of the output's largest; NaN where NaN).

    Raises:
        ValueError: an output's batch is not 3, or its rows differ.
    """
    import onnxruntime as ort

    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    rows = [tuple(x.numpy().astype(np.float32) * (1 + 0.1 * k) for x in row) for k in range(3)]
    batch = session.run(None, {n: np.concatenate([r[j] for r in rows])
                               for j, n in enumerate(names)})
    single = [session.run(None, dict(zip(names, r, strict=True))) for r in rows]
    for k, out in enumerate(session.get_outputs()):
        got = batch[k].astype(np.float64)
        want = np.concatenate([s[k] for s in single]).astype(np.float64)
        if got.shape != want.shape:
            raise ValueError(f"{path.name}: output {out.name} has {got.shape[0]} rows for a "
                             "batch of 3: the export fixed the batch's size")
        scale = float(np.abs(want[np.isfinite(want)]).max(initial=0.0))
        if not np.allclose(got, want, rtol=1e-4, atol=1e-4 * scale, equal_nan=True):
            raise ValueError(f"{path.name}: output {out.name} differs between a batch of 3 "
                             "and its rows one by one: the export fixed the batch's size")


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
