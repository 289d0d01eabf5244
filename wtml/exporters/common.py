"""Checkpoint -> ONNX: ``wtml export``'s entry (:func:`export_model`), which looks the
checkpoint's task up in ``wtml.tasks`` and has its ``export`` part write its graphs, then lists
them in ``manifest.json``.

The measurement tasks' (fluid, radial) graphs are made by :mod:`wtml.exporters.matrix` from what
each declares in its own module (:mod:`wtml.exporters.fluid`, :mod:`wtml.exporters.radial`):
the decoder and, beside it, the classical path as its own graph, both taking Ze and the
reference the metadata's ``references`` names, with the decoder's domain gate inside both. The
metadata of each model carries what a device needs: names and units, the frequency grid, the
scene and its hash, the trained domain and its measured false-alarm rate, the package version,
and the decoder's ``uncertainty``: its σ recalibrated per range of its answer on fresh samples
of the scene, the scales constants of the graph (:mod:`wtml.decoders.recalibration`). A device
needs onnxruntime only.
"""

from __future__ import annotations

from pathlib import Path

import onnx

from wtml import __version__
from wtml.decoders.checkpoint import load_decoder
from wtml.devices import identity
from wtml.exporters.fluid import ClassicalFluidNet as ClassicalFluidNet  # its old home
from wtml.runtime.metadata import MANIFEST, write_manifest
from wtml.scenes import config_hash, device_of, scene_from_dict
from wtml.tasks import TASKS


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
