"""Checkpoint -> ONNX export folder (the training stack's side: torch, onnx, the scenes).

``wtml.exporters.common``: :func:`~wtml.exporters.common.export_model` and the fluid and
radial graphs; ``wtml.exporters.onset`` and ``wtml.exporters.texture``: those tasks' graphs.
What a device runs them with is :mod:`wtml.runtime`, which imports none of this.
"""
