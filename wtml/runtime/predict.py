"""Run exported models with onnxruntime on measured data, and say where to trust them.

Every row that :func:`predict_file` returns carries ``in_domain`` (the decoder's graph says
the input lies inside its trained domain and its answer inside the trained range) and
``domain_score`` (``<= 1`` inside), and a ``flags`` text naming each reason for doubt: an
input outside the trained domain, or any method's answer outside the physically possible
range (a negative viscosity, a contact beyond the whisker). Nothing is hidden: every value is
printed as computed, and an out-of-domain decoder's predicted uncertainty is NaN.

The input formats are documented in :data:`INPUT_FORMATS` (``wtml predict --help`` shows it).
"""

from __future__ import annotations

import csv
import json
import zipfile
from pathlib import Path

import numpy as np
import onnxruntime as ort

from wtml.physics.twoport import flat_parts
from wtml.signals import phasor_lsq

INPUT_FORMATS = """\
--input: one or many measurements on the model's frequency grid (the grid is in the
model's metadata; another grid is refused, never interpolated):
  .csv  a header with frequency_hz, ze_real, ze_imag (Ω) and optionally sample (an
        integer id for several measurements in one file); one row per frequency.
  .npz  frequency_hz (n_freq,) and either ze (complex, (n_freq,) or (n, n_freq)), or
        ze_real and ze_imag; or the raw signals of a stepped sweep: e and i, each
        (n_freq, n_t) or (n, n_freq, n_t), in V and A, sampled at sample_rate_hz
        (phasors are fitted by least squares at each grid frequency).
--reference (radial models: required): the free (untouched) whisker's Ze of the device,
  taken when it is set up, on the same grid: .npz with frequency_hz (n_freq,) and ze
  (complex, (n_freq,) for every measurement, or (n, n_freq) one per measurement).
Fluid models return eta (Pa*s) and rho (kg/m^3); radial models distance (m from the tip)
and sigma (m, the decoder's std; NaN out of domain).
Fluid and texture models also need the device's calibration (--calibration): .npz with
frequency_hz (n_freq,) on the model's grid (texture: its metadata's calibration_hz) and t, the
calibrated T (complex, (n_freq, 2, 2) for every measurement, or (n, n_freq, 2, 2) one per
measurement or record).
Onset models take a recording instead: .npz with e (V) and i (A), each (n_samples,) or
(n_records, n_samples), and sample_rate_hz (another rate than trained is resampled when the
ratio is one of whole numbers, else refused) and the device's calibration (--calibration:
.npz with frequency_hz [the probe's], t, its calibrated T there, complex (1, 2, 2) or
(n_records, 1, 2, 2), and hue0, its HUE(0) in m/V); they return one row per contact: onset and
detachment (s), the wall's location gap (m) and sigma (m)."""


class InputError(ValueError):
    """An input file or model folder that cannot be used (the message says what to do)."""


class OnnxModel:
    """An exported wtml model (decoder or classical path) behind the predict interface:
    ``predict(ze) -> {output name: (n,) array, "in_domain": (n,) bool,
    "domain_score": (n,)}``, names and units from its metadata.

    Args:
        path: ``model.onnx`` or ``classical.onnx``.
        threads: intra-op threads (0: onnxruntime's default).

    Raises:
        InputError: the file is missing, empty, truncated or not a wtml model.
    """

    def __init__(self, path: str | Path, threads: int = 0) -> None:
        path = Path(path)
        redo = "export it again with `wtml export --checkpoint <last.ckpt> --out <folder>`"
        if not path.is_file():
            raise InputError(f"{path}: no such model file; {redo}")
        if path.stat().st_size == 0:
            raise InputError(f"{path}: empty file; {redo}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3  # onnxruntime's own warnings are not ours to print
        try:
            self.session = ort.InferenceSession(str(path), opts,
                                                providers=["CPUExecutionProvider"])
        except Exception as err:  # onnxruntime raises its own classes for a bad protobuf
            raise InputError(f"{path}: not a readable ONNX model (truncated or corrupt: "
                             f"{str(err).splitlines()[0][:100]}); {redo}") from None
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)
        need = ("task", "frequency_hz", "outputs", "units", "domain")
        if any(k not in self.metadata for k in need):
            raise InputError(f"{path}: not a wtml model of this version (its metadata lacks "
                             f"{[k for k in need if k not in self.metadata]}); {redo}")
        self.task = self.metadata["task"]
        self.frequency_hz = np.array(json.loads(self.metadata["frequency_hz"]))
        self.outputs = json.loads(self.metadata["outputs"])
        self.units = json.loads(self.metadata["units"])
        self.domain = json.loads(self.metadata["domain"])
        self.references = json.loads(self.metadata.get("references", "{}"))
        """What the graph needs besides the measurement, ``{name: description}``."""
        self.name = f"{self.metadata.get('label', self.metadata['kind'])} ONNX"

    def run(self, *inputs: np.ndarray) -> dict[str, np.ndarray]:
        """The graph on float32 inputs (in the order of its metadata's ``inputs``): each
        output by name, ``in_domain`` (bool) and ``domain_score``."""
        names = [i.name for i in self.session.get_inputs()]
        values = self.session.run(None, {n: np.asarray(x, np.float32)
                                         for n, x in zip(names, inputs, strict=True)})
        out = {k: v.astype(float) for k, v in zip(self.outputs, values, strict=False)}
        out["in_domain"] = values[-2].astype(bool)
        out["domain_score"] = values[-1].astype(float)
        return out

    def predict(self, ze: np.ndarray, reference: np.ndarray | None = None
                ) -> dict[str, np.ndarray]:
        """The graph on Ze (complex ``(n, n_freq)``) and, for a model that needs one (its
        metadata's ``references``), its reference: the calibrated T (complex ``(n, n_freq, 2,
        2)``, ``"calibration"``: fluid) or the free whisker's Ze (complex ``(n, n_freq)``,
        ``"reference"``: radial)."""
        ze = np.asarray(ze)
        if bool(self.references) != (reference is not None):
            raise InputError(f"{self.name}: needs a reference ({', '.join(self.references)})"
                             if reference is None else f"{self.name}: takes no reference")
        if reference is None:
            extra = ()
        elif "calibration" in self.references:
            extra = flat_parts(reference)
        else:
            extra = (np.asarray(reference).real, np.asarray(reference).imag)
        return self.run(ze.real, ze.imag, *extra)


def _npz_signals(path: Path, data, freq: np.ndarray) -> np.ndarray:
    e, i, fs = data["e"], data["i"], float(data["sample_rate_hz"])
    if e.shape != i.shape or e.ndim < 2 or e.shape[-2] != freq.size:
        raise InputError(f"{path}: e and i must both have shape (..., n_freq={freq.size}, n_t);"
                         f" got {e.shape} and {i.shape}")
    if not np.isfinite(fs) or fs <= 0:
        raise InputError(f"{path}: sample_rate_hz must be > 0, got {fs}")
    t = np.arange(e.shape[-1]) / fs
    return np.stack([phasor_lsq(e[..., k, :], t, f) / phasor_lsq(i[..., k, :], t, f)
                     for k, f in enumerate(freq)], -1)


def _from_npz(path: Path) -> tuple[np.ndarray, np.ndarray]:
    try:
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
                ze = _npz_signals(path, data, freq)
            else:
                raise InputError(f"{path}: needs 'ze', or 'ze_real' and 'ze_imag', or 'e', 'i' "
                                 f"and 'sample_rate_hz'; has {sorted(keys)}")
    except InputError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as err:
        # np.load's own message for a non-archive suggests unsafe loading: never pass it on
        raise InputError(f"{path}: not a readable .npz of numeric arrays (empty, truncated, "
                         f"or holding objects: {type(err).__name__}); write it with "
                         "numpy.savez from float or complex arrays") from None
    return freq, ze


def _from_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    try:
        with open(path, newline="") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise InputError(f"{path}: not a readable CSV ({err})") from None
    need = ("frequency_hz", "ze_real", "ze_imag")
    if not rows or not set(need) <= set(rows[0]):
        raise InputError(f"{path}: CSV needs a header with columns {list(need)} (and "
                         "optionally 'sample') and at least one row")
    values = {k: [] for k in ("sample", *need)}
    for line, row in enumerate(rows, start=2):  # line 1 is the header
        for key in values:
            cell = row.get(key)
            if cell is None or cell.strip() == "":
                if key == "sample":
                    values[key].append(0)
                    continue
                raise InputError(f"{path}: line {line} has no value for '{key}'")
            try:
                values[key].append(int(cell) if key == "sample" else float(cell))
            except ValueError:
                raise InputError(f"{path}: line {line}: '{key}' = {cell!r} is not a "
                                 f"{'whole number' if key == 'sample' else 'number'}") from None
    sample, freq = np.array(values["sample"]), np.array(values["frequency_hz"])
    ze = np.array(values["ze_real"]) + 1j * np.array(values["ze_imag"])
    ids = np.unique(sample)
    grids = [freq[sample == s] for s in ids]
    if any(g.shape != grids[0].shape or not np.array_equal(g, grids[0]) for g in grids):
        raise InputError(f"{path}: every sample must list the same frequencies in the same order")
    return grids[0], np.stack([ze[sample == s] for s in ids])


def read_input(path: str | Path, frequency_hz: np.ndarray) -> np.ndarray:
    """Measured Ze as complex ``(n, n_freq)`` on ``frequency_hz``, checked.

    Raises:
        InputError: missing or unreadable file, unknown format, wrong shapes, a grid other
            than the model's, NaN or inf.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such input file")
    if path.suffix == ".npz":
        freq, ze = _from_npz(path)
    elif path.suffix == ".csv":
        freq, ze = _from_csv(path)
    else:
        raise InputError(f"{path}: input must be .npz or .csv (see wtml predict --help)")
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


def read_calibration(path: str | Path | None, frequency_hz: np.ndarray, n: int,
                     task: str) -> np.ndarray:
    """The device's calibrated T as complex ``(n, n_freq, 2, 2)`` on ``frequency_hz`` (one T
    in the file is every measurement's), checked; ``task`` names the export in the errors.

    Raises:
        InputError: no calibration given, or a missing or unreadable file, another grid, a
            wrong shape, NaN or inf.
    """
    grid = ", ".join(f"{f:g}" for f in frequency_hz[:3]) + f", ... {frequency_hz[-1]:g} Hz"
    if path is None:
        raise InputError(f"this {task} export needs --calibration: the device's calibrated T at "
                         f"{grid} (npz with frequency_hz and t, complex (n_freq, 2, 2))")
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such calibration file")
    try:
        with np.load(path, allow_pickle=False) as data:
            if not {"frequency_hz", "t"} <= set(data.files):
                raise InputError(f"{path}: a calibration needs 'frequency_hz' and 't'; has "
                                 f"{sorted(data.files)}")
            freq, t = data["frequency_hz"].astype(float), data["t"].astype(complex)
    except InputError:
        raise
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as err:
        raise InputError(f"{path}: not a readable .npz of numeric arrays "
                         f"({type(err).__name__}); write it with numpy.savez") from None
    if freq.shape != frequency_hz.shape or not np.allclose(freq, frequency_hz, rtol=1e-9):
        raise InputError(f"{path}: calibration grid {freq.min():g}-{freq.max():g} Hz "
                         f"({freq.size} points) is not the model's {grid}")
    if t.shape not in ((freq.size, 2, 2), (n, freq.size, 2, 2)):
        raise InputError(f"{path}: t must have shape (n_freq={freq.size}, 2, 2) or "
                         f"(n={n}, n_freq, 2, 2), got {t.shape}")
    if not np.all(np.isfinite(t)):
        raise InputError(f"{path}: t is NaN or inf")
    return np.broadcast_to(t, (n, freq.size, 2, 2))
def read_reference(path: str | Path | None, model: OnnxModel, n: int) -> np.ndarray | None:
    """The free reference a radial export needs, complex ``(n, n_freq)`` (one row is
    broadcast to all ``n`` measurements), or None for an export that needs none.

    Raises:
        InputError: the export needs a reference and none is given (naming ``--reference``),
            or one is given that it does not take; the file unreadable, without
            ``frequency_hz`` and ``ze``, on another grid, of another row count, NaN or inf.
    """
    freq = model.frequency_hz
    if "reference" not in model.references:
        if path is not None:
            raise InputError(f"--reference {path}: this {model.task} export takes no reference")
        return None
    if path is None:
        raise InputError(f"this {model.task} export needs --reference: the free whisker's Ze at "
                         f"{', '.join(f'{f:g}' for f in freq)} Hz (npz with frequency_hz and "
                         "ze), measured on the device when it is set up")
    path = Path(path)
    if path.suffix != ".npz" or not path.is_file():
        raise InputError(f"--reference {path}: no such .npz file (frequency_hz and ze)")
    got, ref = _from_npz(path)
    ref = np.atleast_2d(ref)
    if got.shape != freq.shape or not np.allclose(got, freq, rtol=1e-9):
        raise InputError(f"--reference {path}: frequencies {got.tolist()} Hz are not the "
                         f"model's {freq.tolist()} Hz")
    if ref.ndim != 2 or ref.shape[-1] != freq.size or len(ref) not in (1, n):
        raise InputError(f"--reference {path}: ze must have shape ({freq.size},), "
                         f"(1, {freq.size}) or ({n}, {freq.size}) for {n} measurements, "
                         f"got {ref.shape}")
    if not np.all(np.isfinite(ref)):
        raise InputError(f"--reference {path}: ze is NaN or inf")
    return np.broadcast_to(ref, (n, freq.size))


def load_export(model_dir: str | Path) -> tuple[OnnxModel, OnnxModel]:
    """The decoder and the classical model of an export folder, checked to belong together."""
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise InputError(f"{model_dir}: no such model folder; make one with "
                         "`wtml export --checkpoint <last.ckpt> --out <folder>`")
    decoder = OnnxModel(model_dir / "model.onnx")
    classical = OnnxModel(model_dir / "classical.onnx")
    if decoder.metadata["scene_hash"] != classical.metadata["scene_hash"]:
        raise InputError(f"{model_dir}: model.onnx and classical.onnx come from different scenes;"
                         " export the folder again")
    return decoder, classical


def task_of(model_dir: str | Path) -> str:
    """The task of an export folder's decoder (reads its metadata only)."""
    return load_export(model_dir)[0].task


def impossible(model: OnnxModel, predictions: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per output that has a physical range, where ``predictions`` fall outside it."""
    return {name: ~((predictions[name] >= lo) & (predictions[name] <= hi))
            for name, spec in model.domain["outputs"].items()
            for lo, hi in [spec["physical"]]}


def predict_file(model_dir: str | Path, input_path: str | Path, *,
                 calibration: str | Path | None = None,
                 reference: str | Path | None = None) -> list[dict]:
    """Decoder and classical predictions side by side, one row per measurement: ``sample``,
    ``in_domain``, ``domain_score``, ``{output}_{decoder|classical} ({unit})`` and ``flags``
    (module docstring). ``calibration``: the device's calibrated T (npz, see
    :data:`INPUT_FORMATS`), which a fluid export needs (:class:`InputError` without it);
    ``reference``: the free reference file a radial export needs (:func:`read_reference`)."""
    decoder, classical = load_export(model_dir)
    ze = read_input(input_path, decoder.frequency_hz)
    if "calibration" in decoder.references:
        if reference is not None:
            raise InputError(f"--reference {reference}: this {decoder.task} export takes no "
                             "reference (it takes --calibration)")
        extra = read_calibration(calibration, decoder.frequency_hz, len(ze), decoder.task)
    else:
        if calibration is not None:
            raise InputError(f"--calibration {calibration}: this {decoder.task} export takes "
                             "no calibration")
        extra = read_reference(reference, decoder, len(ze))
    rows: list[dict] = [{"sample": k} for k in range(len(ze))]
    flags: list[list[str]] = [[] for _ in rows]
    for label, model in (("decoder", decoder), ("classical", classical)):
        pred = model.predict(ze, extra)
        if label == "decoder":
            for k, row in enumerate(rows):
                row["in_domain"] = bool(pred["in_domain"][k])
                row["domain_score"] = float(pred["domain_score"][k])
                if not row["in_domain"]:
                    flags[k].append("outside the trained domain" if row["domain_score"] > 1
                                    else "decoder answer outside the trained range")
        for key in model.outputs:
            for k, v in enumerate(pred[key]):
                rows[k][f"{key}_{label} ({model.units[key]})"] = float(v)
        for name, bad in impossible(model, pred).items():
            for k in np.flatnonzero(bad):
                flags[k].append(f"{label} {name} physically impossible")
    for row, f in zip(rows, flags, strict=True):
        row["flags"] = "; ".join(f)
    return rows


def domain_warning(rows: list[dict]) -> str | None:
    """One line counting the rows out of domain and the impossible answers, or None."""
    out = sum(not r["in_domain"] for r in rows)
    odd = sum("impossible" in r["flags"] for r in rows)
    if not out and not odd:
        return None
    parts = []
    if out:
        parts.append(f"{out} of {len(rows)} rows outside the trained domain (in_domain = 0: "
                     "the decoder's answer is an extrapolation)")
    if odd:
        parts.append(f"{odd} row{'s' * (odd > 1)} with a physically impossible answer")
    return "warning: " + "; ".join(parts) + "; see the flags column"


def format_predictions(rows: list[dict]) -> str:
    """Prediction rows as an aligned table, units in the headers."""
    keys = list(rows[0])
    width = [max(len(k), 12) for k in keys]

    def cell(value) -> str:
        if isinstance(value, bool):
            return str(int(value))
        if isinstance(value, int):
            return f"{value:d}"
        if isinstance(value, float):
            return f"{value:.5g}"
        return str(value)

    lines = ["  ".join(k.rjust(w) for k, w in zip(keys, width, strict=True))]
    for r in rows:
        lines.append("  ".join(cell(r[k]).rjust(w) for k, w in zip(keys, width, strict=True)))
    return "\n".join(lines)
