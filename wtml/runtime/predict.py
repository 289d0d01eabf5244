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
import threading
from pathlib import Path

import numpy as np
import onnxruntime as ort

from wtml.cores import available_cores
from wtml.files import (
    CSV_MAX_BYTES,
    MEMORY_CEILING,
    FileError,
    check_array,
    check_header,
    nbytes_text,
    npz_headers,
    parse_json,
    read_npz,
    regular_file,
    scalar,
    within_ceiling,
)
from wtml.physics.twoport import flat_views
from wtml.runtime.metadata import (
    MANIFEST,
    MODEL_MAX_BYTES,
    REDO,
    check_graph,
    graph_metadata,
    read_manifest,
    scene_device,
    verified_bytes,
)
from wtml.schema import SchemaError, to_dict
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
Fluid models return eta (Pa*s) and rho (kg/m^3), the decoder also eta_log_sigma (the std of
ln eta) and rho_sigma (kg/m^3); radial models distance (m from the tip) and sigma (m, the
decoder's std). A decoder's stds are recalibrated on held-out data (the metadata's
uncertainty) so that +-sigma is its 68 % interval, each with the half-width of its 95 %
interval beside it (<sigma>_95, same unit: 1.96 sigma for Gaussian errors, fitted per
range as the metadata's widths), and NaN out of domain.
Fluid and texture models also need the device's calibration (--calibration): .npz with
frequency_hz (n_freq,) on the model's grid (texture: its metadata's calibration_hz) and t, the
calibrated T (complex, (n_freq, 2, 2) for every measurement, or (n, n_freq, 2, 2) one per
measurement or record).
Onset models take a recording instead: .npz with e (V) and i (A), each (n_samples,) or
(n_records, n_samples), and sample_rate_hz (another rate than trained is resampled when the
ratio is one of whole numbers, else refused) and the device's calibration (--calibration:
.npz with frequency_hz [the probe's], t, its calibrated T there, complex (1, 2, 2) or
(n_records, 1, 2, 2), and hue0, its HUE(0) in m/V); they return one row per contact: onset and
detachment (s), the wall's location gap (m), sigma (m) and the decoder's sigma_95 (m). A
recording of 2 to 8 times the trained record (records of its whisk cycles, one after the
other) is read as that many records and answered once: the mean gap, the mean sigma (not
reduced by sqrt k: they share their errors), flagged where a record and the one before
locate the wall further apart than the export's limit (an object that moves); its contacts
are numbered and timed across the whole recording (each piece starts with the whisker
retracted). Longer recordings: wtml stream.
Texture models take recordings of any length from one window up (the same .npz as onset);
a long one is cut into whole windows, run in batches.
Recordings (onset, texture) may also be as instruments write them: LabVIEW .tdms, a
two-channel .wav, or a .csv of samples (time_s or sample, then e and i), read as a recording
profile says (--profile YAML or the options: channels, V per V and A per V of each channel,
the full scale of integer samples, a rate for a file without one); the file's own rate is
checked against the model's.
Files: an export folder is checked against its manifest.json (each file's sha256) and its
metadata against its task's schema; inputs are read from their headers first. Memory: an
input whose reading, resampling or windowing would take more than the ceiling of
{ceiling} (wtml.files.MEMORY_CEILING) is refused before the work, naming it; CSV inputs up
to {csv}, calibration and reference files up to {cal}."""


class InputError(FileError):
    """An input file or model folder that cannot be used (the message says what to do)."""


RUN_BYTES = 2 * 1024**2
"""Bytes of input per onnxruntime call: longer inputs run in batches of rows, so that the
graphs' intermediate arrays stay small whatever the number of measurements or windows.
onnxruntime's memory arena keeps its largest call's intermediates for the session's life: a
texture decoder's session held 157 MB after calls of 80 windows (8 MiB), 37 MB after calls of
20 (2 MiB), at the same time per window."""
ROW_BYTES = 4096
"""Bytes a row of ``wtml predict``'s answer may take (its Python objects and its line):
counted in each input's cost against :data:`wtml.files.MEMORY_CEILING`."""
CALIBRATION_MAX_BYTES = 256 * 1024**2
"""Bytes: the largest calibration or reference file's arrays."""
INPUT_FORMATS = INPUT_FORMATS.format(ceiling=nbytes_text(MEMORY_CEILING),
                                     csv=nbytes_text(CSV_MAX_BYTES),
                                     cal=nbytes_text(CALIBRATION_MAX_BYTES))


SCRATCH_KEPT_BYTES = 2 * RUN_BYTES
"""Bytes of float32 scratch an :class:`OnnxModel` keeps for its calls' inputs (per thread)."""
SCRATCH_FROM_BYTES = 128 * 1024
"""Bytes of input from which a call's inputs are cast into the scratch (glibc's smallest
threshold for a fresh mapping; below it a cast array is one of the heap's own blocks)."""


def rows_per_run(row_bytes: int) -> int:
    """How many rows of ``row_bytes`` input each make one call's :data:`RUN_BYTES` (at least
    one): the batch of every chunked pass over windows or measurements."""
    return max(1, RUN_BYTES // max(1, row_bytes))


class OnnxModel:
    """An exported wtml model (decoder or classical path) behind the predict interface:
    ``predict(ze) -> {output name: (n,) array, "in_domain": (n,) bool,
    "domain_score": (n,)}``, names and units from its metadata, which is checked against its
    task's schema and the graph itself (:mod:`wtml.runtime.metadata`) before it is used.

    Args:
        path: ``model.onnx``, ``classical.onnx`` or ``stream.onnx``.
        threads: intra-op threads (0: every core this process may use,
            :func:`wtml.cores.available_cores`).
        data: the file's bytes, already read and checked against the export's manifest
            (:func:`load_export`); read from ``path`` when None.

    Raises:
        InputError: the file is missing, empty, truncated or not a wtml model.
        SchemaError: its metadata is not what its task's graphs carry (naming the key).
    """

    def __init__(self, path: str | Path, threads: int = 0, *, data: bytes | None = None) -> None:
        path = Path(path)
        if data is None:
            regular_file(path, what="model file", max_bytes=MODEL_MAX_BYTES)
            data = path.read_bytes()
            if not data:
                raise InputError(f"{path}: empty file; {REDO}")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = threads or available_cores()
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 4  # onnxruntime's own messages are not ours to print
        try:
            self.session = ort.InferenceSession(data, opts, providers=["CPUExecutionProvider"])
        except Exception as err:  # onnxruntime raises its own classes for a bad protobuf
            raise InputError(f"{path}: not a readable ONNX model (truncated or corrupt: "
                             f"{str(err).splitlines()[0][:100]}); {REDO}") from None
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)
        """The graph's metadata as it carries it (strings), checked: :attr:`meta`."""
        self.meta = graph_metadata(self.metadata, str(path))
        check_graph(self.meta, self.session.get_inputs(), self.session.get_outputs(), str(path))
        self.task = self.meta.task
        self.frequency_hz = np.array(self.meta.frequency_hz)
        self.outputs = list(self.meta.outputs)
        self.units = dict(self.meta.units)
        self.domain = parse_json(self.metadata["domain"], f"{path}: domain", infinity=True)
        self.references = dict(self.meta.references)
        """What the graph needs besides the measurement, ``{name: description}``."""
        self.uncertainty = self.meta.uncertainty
        """How the graph's σ and probabilities were recalibrated (None: a classical path)."""
        self.intervals = {f"{r.sigma}_95": r for r in
                          (self.uncertainty.intervals if self.uncertainty else ())}
        """The 95 % half-widths :meth:`half_widths` makes of the graph's outputs, by name
        (``<σ output>_95``, in that σ's unit and form)."""
        self.units.update({k: self.units[r.sigma] for k, r in self.intervals.items()})
        self.name = f"{self.meta.label or self.meta.kind} ONNX"
        self._inputs = [i.name for i in self.session.get_inputs()]
        self._scratch = threading.local()
        self._first_run_at_batch_1()

    def _first_run_at_batch_1(self) -> None:
        """Run the graph once on one row of zeros before any other call. onnxruntime keeps
        something of a session's first run: a session whose first call was a large batch took
        18–25 % longer at batch 1 ever after (the radial decoder 54 against 44 µs a call, the
        fluid one 44 against 36, both classical paths alike), while one whose first call was
        one row stayed fast through large batches after it (at batch 4096 ~3 % slower). A
        graph with another dynamic axis than the batch (a record's length) is left alone."""
        feed = {}
        for i in self.session.get_inputs():
            if i.type != "tensor(float)" or not all(isinstance(d, int) for d in i.shape[1:]):
                return
            feed[i.name] = np.zeros((1, *i.shape[1:]), np.float32)
        self.session.run(None, feed)

    def run(self, *inputs: np.ndarray) -> dict[str, np.ndarray]:
        """The graph on float32 inputs (in the order of its metadata's ``inputs``, each
        ``(n, ...)``): each output by name, ``in_domain`` (bool) and ``domain_score``. Rows
        run in batches of about :data:`RUN_BYTES` of input. The 95 % half-widths are made on
        request (:meth:`half_widths`): at batch 1 they added 18–26 µs to a fluid call's 70."""
        arrays = [np.asarray(x) for x in inputs]
        if len(arrays) != len(self._inputs):
            raise InputError(f"{self.name}: takes {self._inputs}, got {len(arrays)} inputs")
        n = len(arrays[0])
        if n == 0 or any(len(a) != n for a in arrays):
            raise InputError(f"{self.name}: every input needs the same number of rows (at "
                             f"least one), got {[a.shape for a in arrays]}")
        per_row = sum(a[:1].size * 4 for a in arrays) or 1
        step = rows_per_run(per_row)
        if n <= step:
            values = self.session.run(None, self._feed(arrays))
        else:
            parts = [self.session.run(None, self._feed([a[k:k + step] for a in arrays]))
                     for k in range(0, n, step)]
            values = [np.concatenate(p) for p in zip(*parts, strict=True)]
        out = {k: v.astype(float) for k, v in zip(self.outputs, values, strict=False)}
        out["in_domain"] = values[-2].astype(bool)
        out["domain_score"] = values[-1].astype(float)
        return out

    def _feed(self, chunks: list[np.ndarray]) -> dict[str, np.ndarray]:
        """The session's feed of one call: each input's rows as C-contiguous float32, a chunk
        that is one already as it is, any other (a complex array's real or imaginary view,
        float64, broadcast) cast into this thread's scratch, reused from call to call. A fresh
        array for each call costs a page fault per 4 KiB (glibc hands a freed block of a few MiB
        straight back): a fluid batch of 4096 with its calibrated T took 1.6 times as long in
        ~1000 faults a call. A call of under :data:`SCRATCH_FROM_BYTES` of input (a few rows)
        casts afresh: its arrays come from the allocator's free lists, no faults, and fewer
        steps (a fluid call at batch 1 took 6 % longer through the scratch)."""
        if 4 * sum(c.size for c in chunks) < SCRATCH_FROM_BYTES:
            return {name: np.ascontiguousarray(c, np.float32)
                    for name, c in zip(self._inputs, chunks, strict=True)}
        ready = [c.dtype == np.float32 and c.flags.c_contiguous for c in chunks]
        need = sum(c.size for c, as_is in zip(chunks, ready, strict=True) if not as_is)
        scratch = getattr(self._scratch, "floats", None)
        if scratch is None or scratch.size < need:
            scratch = np.empty(need, np.float32)
            if 4 * need <= SCRATCH_KEPT_BYTES:
                self._scratch.floats = scratch
        feed, used = {}, 0
        for name, c, as_is in zip(self._inputs, chunks, ready, strict=True):
            if not as_is:
                view = scratch[used:used + c.size].reshape(c.shape)
                np.copyto(view, c, casting="unsafe")
                used += c.size
                c = view
            feed[name] = c
        return feed

    def half_widths(self, out: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The 95 % half-width beside each recalibrated σ of :meth:`run`'s answers ``out``,
        ``{"<σ output>_95": (n,)}`` in that σ's unit and form (the metadata's widths,
        :meth:`~wtml.runtime.metadata.IntervalRecalibration.half_width`); empty for a graph
        without recalibration (a classical path)."""
        return {name: r.half_width(out[r.sigma], out[r.by], out)
                for name, r in self.intervals.items()}

    def predict(self, ze: np.ndarray, reference: np.ndarray | None = None
                ) -> dict[str, np.ndarray]:
        """The graph on Ze (complex ``(n, n_freq)``) and, for a model that needs one (its
        metadata's ``references``), its reference: the calibrated T (complex ``(n, n_freq, 2,
        2)``, ``"calibration"``: fluid) or the free whisker's Ze (complex ``(n, n_freq)``,
        ``"reference"``: radial). A reference broadcast over the rows stays one."""
        ze = np.asarray(ze)
        if bool(self.references) != (reference is not None):
            raise InputError(f"{self.name}: needs a reference ({', '.join(self.references)})"
                             if reference is None else f"{self.name}: takes no reference")
        if reference is None:
            extra = ()
        else:
            ref = np.asarray(reference)
            shared = ref.ndim and ref.shape[0] > 1 and ref.strides[0] == 0
            one = ref[:1] if shared else ref
            if "calibration" in self.references:
                extra = flat_views(one)
            else:
                extra = (one.real, one.imag)
            if shared:
                extra = tuple(np.broadcast_to(x, (ref.shape[0], *x.shape[1:])) for x in extra)
        return self.run(ze.real, ze.imag, *extra)


def _load(path: Path, keys: tuple[str, ...], max_bytes: int = MEMORY_CEILING
          ) -> dict[str, np.ndarray]:
    """Arrays ``keys`` of an .npz (headers checked first, never unpickled)."""
    return read_npz(path, keys=keys, max_bytes=max_bytes)


def _ze_shape(path: Path, heads: dict) -> tuple[str, tuple[int, ...]]:
    """Which of the .npz input's forms it holds, and its measurements' shape ``(n,
    n_freq)`` from the headers (or ``(n, n_freq, n_t)`` for raw signals)."""
    keys = set(heads)
    if "frequency_hz" not in keys:
        raise InputError(f"{path}: needs 'frequency_hz'; has {sorted(keys)}")
    check_header(str(path), "frequency_hz", *heads["frequency_hz"], ndim=(1,))
    if "ze" in keys:
        check_header(str(path), "ze", *heads["ze"], real=False, ndim=(1, 2))
        return "ze", heads["ze"][0]
    if {"ze_real", "ze_imag"} <= keys:
        for key in ("ze_real", "ze_imag"):
            check_header(str(path), key, *heads[key], ndim=(1, 2))
        if heads["ze_real"][0] != heads["ze_imag"][0]:
            raise InputError(f"{path}: 'ze_real' and 'ze_imag' must have the same shape, got "
                             f"{heads['ze_real'][0]} and {heads['ze_imag'][0]}")
        return "parts", heads["ze_real"][0]
    if {"e", "i", "sample_rate_hz"} <= keys:
        for key in ("e", "i"):
            check_header(str(path), key, *heads[key], ndim=(2, 3))
        if heads["e"][0] != heads["i"][0]:
            raise InputError(f"{path}: 'e' and 'i' must have the same shape (..., n_freq, "
                             f"n_t), got {heads['e'][0]} and {heads['i'][0]}")
        return "signals", heads["e"][0]
    raise InputError(f"{path}: needs 'ze', or 'ze_real' and 'ze_imag', or 'e', 'i' "
                     f"and 'sample_rate_hz'; has {sorted(keys)}")


def _from_npz(path: Path, max_bytes: int = MEMORY_CEILING) -> tuple[np.ndarray, np.ndarray]:
    heads = npz_headers(path, max_bytes=max_bytes, what="input")
    form, shape = _ze_shape(path, heads)
    n_freq = heads["frequency_hz"][0][0]
    where = str(path)
    if form == "signals":
        if shape[-2] != n_freq or 0 in shape or shape[-1] < 3:
            raise InputError(f"{path}: e and i must both have shape (..., n_freq={n_freq}, "
                             f"n_t) with n_t >= 3 (a phasor fit has 3 unknowns); got {shape}")
        n = int(np.prod(shape[:-2], dtype=float)) if len(shape) > 2 else 1
        size = n * n_freq * shape[-1]
        itemsize = heads["e"][1].itemsize
        # e and i as loaded and as float64, and one frequency's least-squares fit at a time
        need = 2 * size * (itemsize + 8) + 4 * n * shape[-1] * 8 + n * ROW_BYTES
        within_ceiling(f"{path}: e and i {shape}", need, "fitting the phasors")
        data = _load(path, ("frequency_hz", "e", "i", "sample_rate_hz"), max_bytes)
        freq = check_array(where, "frequency_hz", data["frequency_hz"], ndim=(1,))
        fs = scalar(where, "sample_rate_hz", data["sample_rate_hz"], low=1e-3, high=1e12)
        e = check_array(where, "e", data.pop("e"))
        i = check_array(where, "i", data.pop("i"))
        t = np.arange(e.shape[-1]) / fs
        with np.errstate(divide="ignore", invalid="ignore"):  # a zero current: NaN, refused
            ze = np.stack([phasor_lsq(e[..., k, :], t, f) / phasor_lsq(i[..., k, :], t, f)
                           for k, f in enumerate(freq)], -1)
        return freq, ze
    n = shape[0] if len(shape) == 2 else 1
    if n == 0:
        raise InputError(f"{path}: holds no measurements (Ze has shape {shape})")
    itemsize = max(heads[k][1].itemsize for k in heads if k != "frequency_hz")
    need = (n * shape[-1] * (2 * itemsize + 32)) + n * ROW_BYTES
    within_ceiling(f"{path}: Ze {shape}", need, "reading the measurements")
    if form == "ze":
        data = _load(path, ("frequency_hz", "ze"), max_bytes)
        ze = np.asarray(data["ze"]).astype(complex, copy=False)
    else:
        data = _load(path, ("frequency_hz", "ze_real", "ze_imag"), max_bytes)
        ze = (check_array(where, "ze_real", data["ze_real"], finite=False)
              + 1j * check_array(where, "ze_imag", data["ze_imag"], finite=False))
    freq = check_array(where, "frequency_hz", data["frequency_hz"], ndim=(1,))
    return freq, ze


def _from_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    regular_file(path, what="CSV input", max_bytes=CSV_MAX_BYTES)
    need = ("frequency_hz", "ze_real", "ze_imag")
    values: dict[str, list] = {k: [] for k in ("sample", *need)}
    try:
        with open(path, newline="") as fh:
            reader = csv.reader(fh)
            header = next(reader, None)
            if header is None or not set(need) <= {h.strip() for h in header}:
                raise InputError(f"{path}: CSV needs a header with columns {list(need)} (and "
                                 "optionally 'sample') and at least one row")
            columns = {h.strip(): k for k, h in enumerate(header)}
            for line, row in enumerate(reader, start=2):  # line 1 is the header
                for key in values:
                    k = columns.get(key)
                    cell = row[k] if k is not None and k < len(row) else None
                    if cell is None or cell.strip() == "":
                        if key == "sample":
                            values[key].append(0)
                            continue
                        raise InputError(f"{path}: line {line} has no value for '{key}'")
                    try:
                        values[key].append(int(cell) if key == "sample" else float(cell))
                    except ValueError:
                        raise InputError(
                            f"{path}: line {line}: '{key}' = {cell[:40]!r} is not a "
                            f"{'whole number' if key == 'sample' else 'number'}") from None
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise InputError(f"{path}: not a readable CSV ({err})") from None
    if not values["frequency_hz"]:
        raise InputError(f"{path}: CSV needs a header with columns {list(need)} (and "
                         "optionally 'sample') and at least one row")
    sample, freq = np.array(values["sample"]), np.array(values["frequency_hz"])
    ze = np.array(values["ze_real"]) + 1j * np.array(values["ze_imag"])
    ids = np.unique(sample)
    grids = [freq[sample == s] for s in ids]
    if any(g.shape != grids[0].shape or not np.array_equal(g, grids[0]) for g in grids):
        raise InputError(f"{path}: every sample must list the same frequencies in the same order")
    if not np.isfinite(freq).all():
        raise InputError(f"{path}: 'frequency_hz' is NaN or inf")
    return grids[0], np.stack([ze[sample == s] for s in ids])


FLOAT32_MAX = float(np.finfo(np.float32).max)


def float32_range(where: str, key: str, a: np.ndarray) -> None:
    """Refuse values the float32 graphs cannot hold (beyond ±3.4e38: they would become inf
    inside the graph), naming ``where`` and ``key``; ``a`` is finite."""
    a = np.asarray(a)
    parts = (a.real, a.imag) if np.iscomplexobj(a) else (a,)
    for part in parts:
        if part.size and np.abs(part).max() > FLOAT32_MAX:
            first = np.unravel_index(np.argmax(np.abs(part) > FLOAT32_MAX), part.shape)
            raise InputError(f"{where}: '{key}' is beyond the float32 range of the graphs "
                             f"(|x| > 3.4e38) at index {tuple(map(int, first))}")


def _span(freq: np.ndarray) -> str:
    return f"{freq.min():g}-{freq.max():g}" if freq.size else "(empty)"


def _same_grid(got: np.ndarray, want: np.ndarray) -> bool:
    return got.shape == want.shape and bool(np.allclose(got, want, rtol=1e-9))


def read_input(path: str | Path, frequency_hz: np.ndarray) -> np.ndarray:
    """Measured Ze as complex ``(n, n_freq)`` on ``frequency_hz``, checked.

    Raises:
        InputError: missing or unreadable file, unknown format, wrong shapes, a grid other
            than the model's, NaN or inf, no measurements, or more than the memory ceiling
            (:data:`wtml.files.MEMORY_CEILING`) would take.
    """
    path = Path(path)
    if path.suffix == ".npz":
        regular_file(path, what="input file")
        freq, ze = _from_npz(path)
    elif path.suffix == ".csv":
        freq, ze = _from_csv(path)
    else:
        regular_file(path, what="input file")
        raise InputError(f"{path}: input must be .npz or .csv (see wtml predict --help)")
    ze = np.atleast_2d(ze)
    if ze.ndim != 2 or ze.shape[-1] != freq.size:
        raise InputError(f"{path}: Ze must have shape (n, n_freq={freq.size}), got {ze.shape}")
    if not _same_grid(freq, frequency_hz):
        raise InputError(
            f"{path}: frequency grid {_span(freq)} Hz ({freq.size} points) is "
            f"not the model's {frequency_hz.min():g}-{frequency_hz.max():g} Hz "
            f"({frequency_hz.size} points)")
    bad = ~np.isfinite(ze)
    if bad.any():
        n, k = np.argwhere(bad)[0]
        raise InputError(f"{path}: Ze is NaN or inf at sample {n}, {freq[k]:g} Hz")
    float32_range(str(path), "ze", ze)
    return ze


def read_calibration_arrays(path: str | Path, frequency_hz: np.ndarray, n: int,
                            extra: tuple[str, ...] = ()) -> tuple[np.ndarray, dict]:
    """The calibrated T of a calibration file as complex ``(n, n_freq, 2, 2)`` on
    ``frequency_hz`` (one T in the file is every measurement's: a broadcast view), and the
    file's ``extra`` arrays (those it has; checked by the caller)."""
    path = Path(path)
    where = str(path)
    grid = ", ".join(f"{f:g}" for f in frequency_hz[:3]) + f", ... {frequency_hz[-1]:g} Hz"
    heads = npz_headers(path, max_bytes=CALIBRATION_MAX_BYTES, what="calibration file")
    if not {"frequency_hz", "t"} <= set(heads):
        raise InputError(f"{path}: a calibration needs 'frequency_hz' and 't'; has "
                         f"{sorted(heads)}")
    check_header(where, "frequency_hz", *heads["frequency_hz"], ndim=(1,))
    check_header(where, "t", *heads["t"], real=False)
    shape = heads["t"][0]
    k = len(frequency_hz)
    if heads["frequency_hz"][0] != (k,) or shape not in ((k, 2, 2), (n, k, 2, 2)):
        data = _load(path, ("frequency_hz",), CALIBRATION_MAX_BYTES)
        freq = check_array(where, "frequency_hz", data["frequency_hz"], ndim=(1,))
        if not _same_grid(freq, frequency_hz):
            raise InputError(f"{path}: calibration grid {_span(freq)} Hz ({freq.size} points) "
                             f"is not the model's {grid}")
        raise InputError(f"{path}: t must have shape (n_freq={k}, 2, 2) or (n={n}, n_freq, 2, "
                         f"2), got {shape}")
    data = _load(path, ("frequency_hz", "t", *extra), CALIBRATION_MAX_BYTES)
    freq = check_array(where, "frequency_hz", data["frequency_hz"], ndim=(1,))
    if not _same_grid(freq, frequency_hz):
        raise InputError(f"{path}: calibration grid {_span(freq)} Hz "
                         f"({freq.size} points) is not the model's {grid}")
    t = np.asarray(data["t"]).astype(complex, copy=False)
    if not np.all(np.isfinite(t)):
        raise InputError(f"{path}: t is NaN or inf")
    float32_range(where, "t", t)
    return np.broadcast_to(t, (n, k, 2, 2)), {key: data[key] for key in extra if key in data}


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
    return read_calibration_arrays(path, frequency_hz, n)[0]


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
    if path.suffix != ".npz":
        raise InputError(f"--reference {path}: must be an .npz file (frequency_hz and ze)")
    regular_file(path, what="reference file", max_bytes=CALIBRATION_MAX_BYTES)
    got, ref = _from_npz(path, CALIBRATION_MAX_BYTES)
    ref = np.atleast_2d(ref)
    if not _same_grid(got, freq):
        raise InputError(f"--reference {path}: frequencies {got.tolist()[:8]} Hz are not the "
                         f"model's {freq.tolist()} Hz")
    if ref.ndim != 2 or ref.shape[-1] != freq.size or len(ref) not in (1, n):
        raise InputError(f"--reference {path}: ze must have shape ({freq.size},), "
                         f"(1, {freq.size}) or ({n}, {freq.size}) for {n} measurements, "
                         f"got {ref.shape}")
    if not np.all(np.isfinite(ref)):
        raise InputError(f"--reference {path}: ze is NaN or inf")
    float32_range(f"--reference {path}", "ze", ref)
    return np.broadcast_to(ref, (n, freq.size))


def load_export(model_dir: str | Path, *, stream: bool = False, threads: int = 0
                ) -> tuple[OnnxModel, ...]:
    """The decoder and the classical model of an export folder (and, ``stream``, its
    streaming graph; ``threads``: onnxruntime's intra-op threads, 0 every core this process
    may use), each file checked against the folder's manifest (sha256 and size) before
    onnxruntime opens it, each graph's metadata against its task's schema, and the graphs
    against each other and the manifest.

    Raises:
        InputError, FileError, SchemaError: one line naming the file (and the key).
    """
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise InputError(f"{model_dir}: no such model folder; make one with "
                         "`wtml export --checkpoint <last.ckpt> --out <folder>`")
    manifest = read_manifest(model_dir)
    kinds = ("decoder", "classical", "stream") if stream else ("decoder", "classical")
    models = []
    for kind in kinds:
        entry = manifest.entry(kind)
        if entry is None:
            raise InputError(f"{model_dir / MANIFEST}: lists no {kind} graph; {REDO}")
        path = model_dir / entry.name
        model = OnnxModel(path, threads, data=verified_bytes(model_dir, entry))
        if model.meta.kind != kind:
            raise SchemaError(f"{path}: metadata kind: must be {kind!r} (the manifest lists it "
                              f"so), got {model.meta.kind!r}; {REDO}")
        models.append(model)
    first = models[0]
    if scene_device(first.meta.scene) != to_dict(manifest.device):
        raise SchemaError(f"{model_dir / manifest.entry('decoder').name}: metadata scene's "
                          f"device is not {MANIFEST}'s {manifest.device.name} "
                          f"{manifest.device.sha256[:12]}…; {REDO}")
    for kind, model in zip(kinds, models, strict=True):
        where = model_dir / manifest.entry(kind).name
        for key, want, got in (("task", manifest.task, model.task),
                               ("scene_hash", manifest.scene_hash, model.meta.scene_hash)):
            if want != got:
                raise SchemaError(f"{where}: metadata {key}: {got!r:.20} is not {MANIFEST}'s "
                                  f"{want!r:.20}; {REDO}")
        for key in ("frequency_hz", "sample_rate_hz", "n_samples", "calibration_hz", "classes",
                    "scene"):
            if getattr(model.meta, key, None) != getattr(first.meta, key, None):
                raise SchemaError(f"{where}: metadata {key}: not the decoder's "
                                  f"({manifest.entry('decoder').name}); {REDO}")
    return tuple(models)


def check_device(model_dir: str | Path, device: str | Path) -> None:
    """Refuse an export folder trained for another device than ``device`` (a device file's
    path or a shipped name): names and content hashes compared.

    Raises:
        InputError: one line naming both devices and what to do.
    """
    from wtml.devices import identity, load_device

    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise InputError(f"{model_dir}: no such model folder; make one with "
                         "`wtml export --checkpoint <last.ckpt> --out <folder>`")
    theirs = read_manifest(model_dir).device
    mine = identity(load_device(device))
    if (theirs.name, theirs.sha256) != (mine["name"], mine["sha256"]):
        same = " (same name, other values)" if theirs.name == mine["name"] else ""
        raise InputError(f"--device {device}: {model_dir} was trained for device "
                         f"{theirs.name!r} ({theirs.sha256[:12]}…), this is {mine['name']!r} "
                         f"({mine['sha256'][:12]}…){same}; train and export a decoder on a "
                         f"scene with `device: {device}`")


def task_of(model_dir: str | Path) -> str:
    """The task of an export folder (reads its manifest only)."""
    model_dir = Path(model_dir)
    if not model_dir.is_dir():
        raise InputError(f"{model_dir}: no such model folder; make one with "
                         "`wtml export --checkpoint <last.ckpt> --out <folder>`")
    return read_manifest(model_dir).task


def impossible(model: OnnxModel, predictions: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per output that has a physical range, where ``predictions`` fall outside it."""
    return {name: ~((predictions[name] >= lo) & (predictions[name] <= hi))
            for name, spec in model.domain["outputs"].items()
            for lo, hi in [spec["physical"]]}


def predict_file(model_dir: str | Path, input_path: str | Path, *,
                 calibration: str | Path | None = None,
                 reference: str | Path | None = None) -> list[dict]:
    """Decoder and classical predictions side by side, one row per measurement: ``sample``,
    ``in_domain``, ``domain_score``, ``{output}_{decoder|classical} ({unit})`` (a recalibrated
    σ's 95 % half-width too, ``<σ>_95_decoder``: :meth:`OnnxModel.half_widths`) and ``flags``
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
        pred |= model.half_widths(pred)
        if label == "decoder":
            for k, row in enumerate(rows):
                row["in_domain"] = bool(pred["in_domain"][k])
                row["domain_score"] = float(pred["domain_score"][k])
                if not row["in_domain"]:
                    flags[k].append("outside the trained domain" if row["domain_score"] > 1
                                    else "decoder answer outside the trained range")
        for key in (*model.outputs, *model.intervals):
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
