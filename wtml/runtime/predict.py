"""Run exported models with onnxruntime on measured data.

Input files (one or many measurements on the model's frequency grid):

- ``.npz`` with ``frequency_hz`` ``(n_freq,)`` and either ``ze`` (complex, ``(n_freq,)`` or
  ``(n, n_freq)``) or ``ze_real`` and ``ze_imag``; or raw signals of a stepped sweep:
  ``e`` and ``i`` of shape ``(n_freq, n_t)`` or ``(n, n_freq, n_t)`` in V and A, sampled at
  ``sample_rate_hz``; phasors are fitted by least squares at each grid frequency.
- ``.csv`` with a header naming ``frequency_hz``, ``ze_real``, ``ze_imag`` and optionally
  ``sample`` (an integer id, for several measurements in one file), one row per frequency.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import onnxruntime as ort

from wtml.signals import phasor_lsq


class InputError(ValueError):
    """An input file that does not fit the model."""


class OnnxModel:
    """An exported wtml model (decoder or classical path) behind the predict interface:
    ``predict(ze) -> {output name: (n,) array}``, names and units from its metadata.

    Args:
        path: ``model.onnx`` or ``classical.onnx``.
        threads: intra-op threads (0: onnxruntime's default).
    """

    def __init__(self, path: str | Path, threads: int = 0) -> None:
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)
        if "task" not in self.metadata or "frequency_hz" not in self.metadata:
            raise InputError(f"{path}: not a wtml model (no task or frequency grid in metadata)")
        self.task = self.metadata["task"]
        self.frequency_hz = np.array(json.loads(self.metadata["frequency_hz"]))
        self.outputs = json.loads(self.metadata["outputs"])
        self.units = json.loads(self.metadata["units"])
        self.name = f"{self.metadata.get('label', self.metadata['kind'])} ONNX"

    def predict(self, ze: np.ndarray) -> dict[str, np.ndarray]:
        ze = np.asarray(ze)
        values = self.session.run(None, {"ze_re": ze.real.astype(np.float32),
                                         "ze_im": ze.imag.astype(np.float32)})
        return {k: v.astype(float) for k, v in zip(self.outputs, values, strict=True)}


def _from_npz(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with np.load(path, allow_pickle=False) as data:
        keys = set(data.files)
        if "frequency_hz" not in keys:
            raise InputError(f"{path}: needs 'frequency_hz'; has {sorted(keys)}")
        freq = data["frequency_hz"].astype(float)
        if "ze" in keys:
            ze = data["ze"].astype(complex)
        elif {"ze_real", "ze_imag"} <= keys:
            ze = data["ze_real"] + 1j * data["ze_imag"]
        elif {"e", "i", "sample_rate_hz"} <= keys:
            e, i, fs = data["e"], data["i"], float(data["sample_rate_hz"])
            if e.shape != i.shape or e.ndim < 2 or e.shape[-2] != freq.size:
                raise InputError(f"{path}: e and i must both have shape (..., n_freq={freq.size},"
                                 f" n_t); got {e.shape} and {i.shape}")
            t = np.arange(e.shape[-1]) / fs
            ze = np.stack([phasor_lsq(e[..., k, :], t, f) / phasor_lsq(i[..., k, :], t, f)
                           for k, f in enumerate(freq)], -1)
        else:
            raise InputError(f"{path}: needs 'ze', or 'ze_real' and 'ze_imag', or 'e', 'i' "
                             f"and 'sample_rate_hz'; has {sorted(keys)}")
    return freq, ze


def _from_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    need = {"frequency_hz", "ze_real", "ze_imag"}
    if not rows or not need <= set(rows[0]):
        raise InputError(f"{path}: CSV needs columns {sorted(need)} (and optionally 'sample')")
    try:
        sample = np.array([int(r.get("sample") or 0) for r in rows])
        freq = np.array([float(r["frequency_hz"]) for r in rows])
        ze = np.array([float(r["ze_real"]) + 1j * float(r["ze_imag"]) for r in rows])
    except ValueError as err:
        raise InputError(f"{path}: a value is not a number: {err}") from err
    ids = np.unique(sample)
    grids = [freq[sample == s] for s in ids]
    if any(g.shape != grids[0].shape or not np.array_equal(g, grids[0]) for g in grids):
        raise InputError(f"{path}: every sample must list the same frequencies in the same order")
    return grids[0], np.stack([ze[sample == s] for s in ids])


def read_input(path: str | Path, frequency_hz: np.ndarray) -> np.ndarray:
    """Measured Ze as complex ``(n, n_freq)`` on ``frequency_hz``, checked.

    Raises:
        InputError: unknown format, wrong shapes, a grid other than the model's, NaN or inf.
    """
    path = Path(path)
    if path.suffix == ".npz":
        freq, ze = _from_npz(path)
    elif path.suffix == ".csv":
        freq, ze = _from_csv(path)
    else:
        raise InputError(f"{path}: input must be .npz or .csv")
    ze = np.atleast_2d(ze)
    if ze.ndim != 2 or ze.shape[-1] != freq.size:
        raise InputError(f"{path}: Ze must have shape (n, n_freq={freq.size}), got {ze.shape}")
    if freq.shape != frequency_hz.shape or not np.allclose(freq, frequency_hz, rtol=1e-9):
        raise InputError(
            f"{path}: frequency grid {freq.min():g}-{freq.max():g} Hz ({freq.size} points) is "
            f"not the model's {frequency_hz.min():g}-{frequency_hz.max():g} Hz "
            f"({frequency_hz.size} points)")
    bad = ~np.isfinite(ze)
    if bad.any():
        n, k = np.argwhere(bad)[0]
        raise InputError(f"{path}: Ze is NaN or inf at sample {n}, {freq[k]:g} Hz")
    return ze


def predict_file(model_dir: str | Path, input_path: str | Path) -> list[dict[str, float]]:
    """Decoder and classical predictions side by side, one row per measurement; keys are
    ``{output}_{decoder|classical} ({unit})``."""
    model_dir = Path(model_dir)
    decoder = OnnxModel(model_dir / "model.onnx")
    classical = OnnxModel(model_dir / "classical.onnx")
    if decoder.metadata["scene_hash"] != classical.metadata["scene_hash"]:
        raise InputError(f"{model_dir}: model.onnx and classical.onnx come from different scenes")
    ze = read_input(input_path, decoder.frequency_hz)
    rows: list[dict[str, float]] = [{"sample": k} for k in range(len(ze))]
    for label, model in (("decoder", decoder), ("classical", classical)):
        for key, values in model.predict(ze).items():
            for k, v in enumerate(values):
                rows[k][f"{key}_{label} ({model.units[key]})"] = float(v)
    return rows
