"""What every exported graph goes through (:func:`wtml.exporters.graphs.export_graph`): the
TorchScript exporter traces at a batch of 2, and whatever Python reads of the batch but
``x.shape`` would be fixed in the graph. A module that turns a tensor into a Python number is
refused while tracing; one whose graph answers a batch of 3 otherwise than its rows one by one
is refused after; a module that reads the batch through ``x.shape`` exports and answers any
batch as torch does."""

from __future__ import annotations

import json

import numpy as np
import onnxruntime as ort
import pytest
import torch
from torch import nn

from wtml.exporters.graphs import export_graph

WIDTH = 4
META = {"outputs": json.dumps(["y"])}


class Toy(nn.Module):
    """``y = 2x`` per row, its rows reshaped by ``rows(x)``; the gate's two outputs."""

    def __init__(self, rows) -> None:
        super().__init__()
        self.rows = rows

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        y = (2.0 * x).reshape(self.rows(x), -1)
        return y, torch.ones_like(y[:, 0], dtype=torch.bool), y[:, 0].abs()


def test_a_batch_read_through_the_shape_exports_for_any_batch(tmp_path):
    path = tmp_path / "good.onnx"
    export_graph(Toy(lambda x: x.shape[0]), WIDTH, path, META, ("x",))
    x = np.random.default_rng(0).standard_normal((5, WIDTH)).astype(np.float32)
    got = ort.InferenceSession(str(path)).run(None, {"x": x})
    np.testing.assert_allclose(got[0], 2 * x, rtol=1e-6)
    assert got[1].shape == got[2].shape == (5,)


def test_a_batch_turned_into_a_python_number_is_refused_while_tracing(tmp_path):
    with pytest.raises(ValueError, match=r"int.onnx: .*test_graphs.py:\d+ turns a tensor into "
                                         "a Python number"):
        export_graph(Toy(lambda x: int(x.shape[0])), WIDTH,
                     tmp_path / "int.onnx", META, ("x",))


def test_a_batch_fixed_by_len_is_refused_by_its_rows(tmp_path):
    """``len(x)`` is 2 in the trace: the graph reshapes a batch of 3 into 2 rows."""
    with pytest.raises(ValueError, match="y has 2 rows for a batch of 3: the export fixed"):
        export_graph(Toy(len), WIDTH, tmp_path / "len.onnx", META, ("x",))


def _runtime_operations(path, tmp_path) -> list:
    """The operations of ``path``'s graph as onnxruntime runs it on any CPU (its own
    hardware-independent optimisations applied)."""
    import onnx

    opts = ort.SessionOptions()
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_EXTENDED
    opts.optimized_model_filepath = str(tmp_path / "optimised.onnx")
    ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
    return list(onnx.load(str(tmp_path / "optimised.onnx")).graph.node)


def test_the_matrix_decoders_graphs_keep_their_few_operations(flow, radial_flow, tmp_path):
    """At batch 1 onnxruntime pays ~0.25 µs per operation, whatever it computes
    (docs/frontier.md, "Where batch 1's time goes"): the radial decoder's graph computes ze/ref
    once (the coarse stage reads its inputs unsliced, so the refiner's and the gate's ratio is
    the same subexpression) and its table in a few products, 112 operations where it took 180
    (114 with the 3-layer coarse stage before 30 Nov); the fluid one reads its device columns as
    constants (no Shape of an input), 94 where 102."""
    radial = _runtime_operations(radial_flow / "export/radial/model.onnx", tmp_path)
    inputs = {"ze_re", "ze_im", "ref_re", "ref_im"}
    assert not [n.name for n in radial if n.op_type == "Slice" and set(n.input) & inputs]
    assert len(radial) <= 112
    fluid = _runtime_operations(flow[0] / "export/model.onnx", tmp_path)
    assert not [n.name for n in fluid if n.op_type == "Shape"]
    assert len(fluid) <= 94
