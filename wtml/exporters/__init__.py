"""Checkpoint -> ONNX export folder (the training stack's side: torch, onnx, the scenes).

``wtml.exporters.common``: :func:`~wtml.exporters.common.export_model`, which has the
checkpoint's task (``wtml.tasks``) write its graphs; ``wtml.exporters.matrix``: the graphs of
the tasks that read measurements, each declared in its own module (``wtml.exporters.fluid``,
``wtml.exporters.radial``); ``wtml.exporters.onset`` and ``wtml.exporters.texture``: those
tasks' graphs.
What a device runs them with is :mod:`wtml.runtime`, which imports none of this.
"""
