"""What an export folder is: its manifest (every file with its sha256 and size) and the schema
of the metadata each graph carries, checked before anything in the folder is trusted.

``wtml export`` writes ``manifest.json`` last (:func:`write_manifest`): the files it wrote
(``model.onnx``, ``classical.onnx``, onset's ``stream.onnx``, radial's
``sample_reference.npz``) each with its sha256 and size, every graph's metadata as the graph
carries it, the task, the scene hash and the package version. ``wtml predict`` reads it
(:func:`read_manifest`), checks each file's bytes against it (:func:`verified_bytes`) and
validates each graph's metadata against its task's schema (:func:`graph_metadata`) and against
the graph itself (:func:`check_graph`), so that an edited file is refused, and so is a
metadata edit made consistent with the manifest (``frame_s`` negative, ``domain.outputs``
emptied, outputs renamed, another task's ``task``): one line naming the file and the key.
Imports numpy only (with :mod:`wtml.files` and :mod:`wtml.schema`): the device runtime uses it.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from wtml import __version__, tasks
from wtml.devices import DeviceIdentity, physical_hash
from wtml.files import (
    FileError,
    atomic_write,
    inside,
    parse_json,
    read_json,
    regular_file,
    sha256,
)
from wtml.schema import SchemaError, bounded, build, mapping_hash, one_of
from wtml.tasks import UNNAMED

MANIFEST = "manifest.json"
MANIFEST_FORMAT = 5
"""The export format this wtml writes. Raised whenever a graph's metadata or the manifest
gains a key that an older runtime's schema would refuse (3: the texture decoder's
``uncertainty.top_slope``, ``top_bias``, 29 Nov; 4: the onset graphs' ``domain.pieces_limit``,
``pieces_false_alarm_fresh``, 30 Nov; 5: an interval's ``classes``, ``class_values``,
``thresholds``, ``thresholds_wide``, 1 Dec), so that an older runtime refuses a newer
export by its format, not by the first key it does not know."""
OLDEST_FORMAT = 2
"""The oldest export format this runtime reads (1 named no device)."""
MODEL_MAX_BYTES = 512 * 1024**2
"""Bytes: the largest graph or sample file an export folder may hold."""
REDO = "export it again with `wtml export --checkpoint <last.ckpt> --out <folder>`"

TASKS = tuple(tasks.TASKS)
KINDS = ("decoder", "classical", "stream")
GATE_OUTPUTS = ("in_domain", "domain_score")
"""The domain gate's outputs, after the task's in every graph."""

INPUTS = ("ze_re", "ze_im")
FLUID_INPUTS = (*INPUTS, "t_re", "t_im")
"""The fluid graphs' inputs: Ze and the user's calibrated T, ``(batch, n_freq, 4)`` flattened
as (t11, t12, t21, t22)."""
RADIAL_INPUTS = (*INPUTS, "ref_re", "ref_im")
"""The radial graphs' inputs: Ze and the free whisker's Ze of the same device, ``(batch,
n_freq)``."""
ONSET_CALIBRATION = ("t_re", "t_im", "hue0")
ONSET_INPUTS = ("e", "i", *ONSET_CALIBRATION)
STREAM_INPUTS = ("e", "i", *ONSET_CALIBRATION, "state")
ONSET_OUTPUTS = ("gap", "sigma", "contact")
DECODER_OUTPUTS = ONSET_OUTPUTS + ("detach_margin", "touch")
STREAM_OUTPUTS = ("contact", "detach_margin", "touch", "gap", "sigma", "next_state")
TEXTURE_INPUTS = ("e", "i", "t_re", "t_im")
"""The texture graphs' inputs: the window's two channels and the device's calibrated T at the
calibration frequencies, ``(batch, K, 4)`` flattened as (t11, t12, t21, t22)."""

GRAPH_INPUTS = {("fluid", "decoder"): FLUID_INPUTS, ("fluid", "classical"): FLUID_INPUTS,
                ("radial", "decoder"): RADIAL_INPUTS, ("radial", "classical"): RADIAL_INPUTS,
                ("onset", "decoder"): ONSET_INPUTS, ("onset", "classical"): ONSET_INPUTS,
                ("onset", "stream"): STREAM_INPUTS,
                ("texture", "decoder"): TEXTURE_INPUTS, ("texture", "classical"): TEXTURE_INPUTS}
"""Each task's and kind's graph inputs, in order (a kind not listed does not exist)."""
FLUID_SIGMAS = ("eta_log_sigma", "rho_sigma")
"""The fluid decoder's intervals, after η and ρ: the std of ln η (1) and of ρ (kg/m³), which
its net has none of; the export adds them (:mod:`wtml.decoders.recalibration`)."""
GRAPH_OUTPUTS = {("fluid", "decoder"): ("eta", "rho", *FLUID_SIGMAS),
                 ("fluid", "classical"): ("eta", "rho"),
                 ("radial", "decoder"): ("distance", "sigma"),
                 ("radial", "classical"): ("distance", "sigma"),
                 ("onset", "decoder"): DECODER_OUTPUTS, ("onset", "classical"): ONSET_OUTPUTS,
                 ("onset", "stream"): STREAM_OUTPUTS,
                 ("texture", "decoder"): ("grain", "log_sigma", "probabilities"),
                 ("texture", "classical"): ("grain", "log_sigma", "probabilities")}
"""Each task's and kind's outputs before the gate's (the scenes' ``OUTPUTS``; onset's graphs
add their frames'), in order: what ``wtml predict`` reads each column as."""
PHYSICAL = {"fluid": ("eta", "rho"), "radial": ("distance",), "onset": ("gap",),
            "texture": ("grain",)}
"""The outputs with a physical range (the scenes' ``output_ranges``): the metadata's
``domain.outputs`` must cover each, or the impossible-answer flag would be lost."""
REFERENCE_KEYS = {"fluid": ("calibration",), "radial": ("reference",),
                  "onset": ("calibration",), "texture": ("calibration",)}
"""What each task's graphs need besides the measurement (the metadata's ``references``):
``wtml predict --calibration`` or ``--reference``."""
WIDE = 1.96
"""The 95 % interval's half-width in σ of a Gaussian error: an export's 95 % width where its
metadata states none."""
PLAIN = ("wtml_version", "task", "kind", "label", "scene_hash")
"""Metadata keys stored as plain strings; every other key holds JSON."""

CLASS_MARGIN = 1e-3
"""A class's reach (:func:`class_reach`) is its distance from the answer times 1 + this, plus
:data:`CLASS_FLOOR` of the larger magnitude, so that a window of that class is inside its
interval in float32 too."""
CLASS_FLOOR = 1e-6
"""About eight float32 steps: ``ln`` of a grain size (~ -11) carries an absolute error of
~1e-6 in float32, which a relative margin alone does not cover for an answer at its class's
value (a reach of 0 there)."""
FLOAT32_MAX = 3e38
"""The largest magnitude a class value may take (the graph holds them as float32)."""
NEVER = 2.0
"""A class threshold above every probability: that class never widens an interval."""


def class_reach(value: np.ndarray, probabilities: np.ndarray, class_values, thresholds,
                log_value: bool) -> np.ndarray:
    """How far an interval about each answer must reach to hold every class whose probability
    is at or above its threshold: ``max_k [p_k >= τ_k] · d_k``, ``d_k`` the distance
    ``|f(value) - f(v_k)|`` with its margins (:func:`class_distance`), f = ln where
    ``log_value`` (else the identity), 0 where no class is that likely; ``value`` ``(n,)``,
    ``probabilities`` ``(n, C)``, ``class_values`` and ``thresholds`` ``(C,)``. Compared and
    computed as the graph does (float32), returned as float64 ``(n,)`` in σ's unit."""
    likely = np.asarray(probabilities, np.float32) >= np.asarray(thresholds, np.float32)
    distance = class_distance(value, class_values, log_value)
    return np.max(np.where(likely, distance, np.float32(0)), -1).astype(float)


def class_distance(value: np.ndarray, class_values, log_value: bool) -> np.ndarray:
    """Each class value's distance from each answer ``value`` ``(n,)``, ``(n, C)`` float32,
    in σ's unit, with :data:`CLASS_MARGIN` and :data:`CLASS_FLOOR` (:func:`class_reach`)."""
    value = np.asarray(value, np.float32)
    values = np.asarray(class_values, np.float32)
    if log_value:
        with np.errstate(divide="ignore", invalid="ignore"):
            value, values = np.log(np.maximum(value, np.float32(1e-30))), np.log(values)
    return (np.abs(value[..., None] - values) * np.float32(1 + CLASS_MARGIN)
            + np.float32(CLASS_FLOOR) * np.maximum(np.abs(value[..., None]), np.abs(values)))

_HEX64 = re.compile(r"^[0-9a-f]{64}$")


def _fail(key: str, text: str) -> SchemaError:
    return SchemaError(f"{key}: {text}")


def _strings(key: str, mapping: dict) -> None:
    for k, v in mapping.items():
        if not isinstance(v, str):
            raise _fail(f"{key}.{k}", f"must be a string, got {v!r:.80}")


@dataclass(frozen=True)
class OutputDomain:
    """One output's ranges (the output's unit): trained, flagged outside ``in_domain``,
    impossible outside ``physical``; ``log``: judged in log10; ``absent_ok``: NaN is an
    answer (onset's "no wall")."""

    trained: tuple[float, float]
    in_domain: tuple[float, float]
    physical: tuple[float, float]
    log: bool
    absent_ok: bool

    def check(self, path: str) -> None:
        for name in ("trained", "in_domain"):
            pair = getattr(self, name)
            if not all(math.isfinite(x) for x in pair):
                raise _fail(f"{path}.{name}", f"must be finite, got {list(pair)}")
        lo, hi = self.trained
        if not (self.in_domain[0] <= lo and hi <= self.in_domain[1]):
            raise _fail(f"{path}.in_domain", f"must contain the trained range {[lo, hi]}, got "
                        f"{list(self.in_domain)}")
        if not (self.physical[0] <= lo and hi <= self.physical[1]):
            raise _fail(f"{path}.physical", f"must contain the trained range {[lo, hi]}, got "
                        f"{list(self.physical)}")
        if self.log and lo <= 0:
            raise _fail(f"{path}.trained", f"must be > 0 for an output judged in log10, got "
                        f"{[lo, hi]}")


@dataclass(frozen=True)
class Domain:
    """The trained domain as the metadata states it (``wtml.exporters.common.domain_metadata``);
    ``outputs`` maps output names to :class:`OutputDomain`. A graph that also checks its own
    answer (the onset decoder's looks at the wall agreeing) says what in ``self_check`` and the
    limit at which its domain score reaches 1 in ``self_check_limit`` (empty and 0 without
    one). ``pieces_limit``: how far (σ) two pieces one after the other of a record of several
    times the graph's length may locate the wall apart (:func:`wtml.runtime.onset.combine_pieces`;
    0: such records are refused), and the fresh records of two pieces it flagged
    (``pieces_false_alarm_fresh``)."""

    score: str
    quantile: float = bounded(0.5, 1.0)
    false_alarm_fresh: float = bounded(0.0, 1.0)
    n_fresh: int = bounded(1, 10**9)
    outputs: dict = dataclasses.field(default_factory=dict)
    self_check: str = ""
    self_check_limit: float = bounded(0.0, 1e30, default=0.0)
    pieces_limit: float = bounded(0.0, 1e30, default=0.0)
    pieces_false_alarm_fresh: float = bounded(0.0, 1.0, default=0.0)

    def check(self, path: str) -> None:
        built = {}
        for name, spec in self.outputs.items():
            built[name] = build(OutputDomain, spec, f"{path}.outputs.{name}")
        object.__setattr__(self, "outputs", built)


@dataclass(frozen=True)
class IntervalRecalibration:
    """One σ output's recalibration (:mod:`wtml.decoders.recalibration`): output ``sigma`` is
    the std of output ``value`` (of ln ``value`` where ``log_value``), scaled by
    ``scales[k]`` in the k-th range of output ``by``'s answer (``edges`` ascending, in
    ``by``'s unit: range k is ``edges[k-1] <= by < edges[k]``, open at both ends), so that ±σ
    is the 68 % interval; ``widths[k]`` is the 95 % interval's half-width in those σ (empty:
    an export made before per-level widths, :data:`WIDE` in every range). ``stored`` is how
    the net gave σ before: ``"std"`` (σ × scale), ``"log_std"`` (a log std: + ln scale),
    ``"none"`` (no σ of its own: σ = scale). Fitted on ``n`` held-out answers in domain (too
    few: scale 1, width :data:`WIDE`), whose coverage of the 68 % and 95 % intervals was
    ``coverage_before`` (±1σ and ±1.96σ; empty without a σ) and is ``coverage_after``
    (empty without answers).

    A value that takes one value per class of a classifier output ``classes`` (texture's
    grain: each grade's mean size, ``class_values`` in the value's unit, in the classes'
    order) has each interval also reach every class at least as likely as its threshold
    (``thresholds`` for the 68 % interval, ``thresholds_wide`` for the 95 %;
    :func:`class_reach`): σ is ``max(scale·σ_net, reach68)`` and the 95 % half-width
    ``max(width·σ, reach95)`` (:meth:`wide`). Fitted per class on held-out answers of known
    class (:func:`wtml.decoders.recalibration.class_thresholds`), so that the intervals
    cover each class at their levels, not only each range of the answer."""

    sigma: str
    value: str
    by: str
    log_value: bool
    stored: str = one_of("std", "log_std", "none")
    edges: tuple[float, ...] = bounded(-1e300, 1e300, default=())
    scales: tuple[float, ...] = bounded(1e-30, 1e30, default=())
    widths: tuple[float, ...] = bounded(1.0, 1e30, default=())
    n: int = bounded(0, 10**9, default=0)
    coverage_before: tuple[float, ...] = bounded(0.0, 1.0, default=())
    coverage_after: tuple[float, ...] = bounded(0.0, 1.0, default=())
    classes: str = ""
    class_values: tuple[float, ...] = bounded(-FLOAT32_MAX, FLOAT32_MAX, default=())
    thresholds: tuple[float, ...] = bounded(0.0, NEVER, default=())
    thresholds_wide: tuple[float, ...] = bounded(0.0, NEVER, default=())

    def check(self, path: str) -> None:
        n = len(self.class_values)
        if bool(self.classes) != bool(n):
            raise _fail(f"{path}.class_values", f"must be given with classes (the output whose "
                        f"classes they are), and only then, got {n} for {self.classes!r}")
        for name in ("thresholds", "thresholds_wide"):
            if len(getattr(self, name)) != n:
                raise _fail(f"{path}.{name}", f"must hold one threshold per class value ({n}), "
                            f"got {len(getattr(self, name))}")
        if self.log_value and any(v < 1e-37 for v in self.class_values):
            raise _fail(f"{path}.class_values", f"must be >= 1e-37 (a float32's log) for a "
                        f"value of ln, got {list(self.class_values)}")
        if len(self.scales) != len(self.edges) + 1:
            raise _fail(f"{path}.scales", f"must hold one scale per range, len(edges) + 1 = "
                        f"{len(self.edges) + 1}, got {len(self.scales)}")
        if len(self.widths) not in (0, len(self.scales)):
            raise _fail(f"{path}.widths", f"must hold one 95 % width per range, len(edges) + 1 "
                        f"= {len(self.scales)}, or none, got {len(self.widths)}")
        if any(b <= a for a, b in zip(self.edges, self.edges[1:], strict=False)):
            raise _fail(f"{path}.edges", f"must ascend strictly, got {list(self.edges)}")
        for name in ("coverage_before", "coverage_after"):
            if len(getattr(self, name)) not in (0, 2):
                raise _fail(f"{path}.{name}", f"must be [68 %, 95 %] shares or empty, got "
                            f"{list(getattr(self, name))}")

    @functools.cached_property
    def _lookup(self) -> tuple[np.ndarray, np.ndarray]:
        """The edges as the graph holds them (float32) and each range's width."""
        with np.errstate(over="ignore"):  # beyond float32: ±inf, as in the graph
            edges = np.asarray(self.edges, np.float32)
        return edges, np.asarray(self.widths or (WIDE,) * len(self.scales), float)

    def range_of(self, by: np.ndarray) -> np.ndarray:
        """Each answer's range index (``by``'s shape, ints in [0, len(edges)]), found as the
        graph finds it: ``by >= edges`` counted in float32 (a NaN answer compares false: the
        first range)."""
        with np.errstate(over="ignore"):  # beyond float32: ±inf, as in the graph
            by = np.asarray(by, np.float32)
        return (by[..., None] >= self._lookup[0]).sum(-1)

    def wide(self, by: np.ndarray, outputs: dict[str, np.ndarray] | None = None
             ) -> np.ndarray:
        """The 95 % interval's half-width in σ for answers ``by`` (any shape, ``(n,)``) of
        output ``by``, in that shape: its range's width (:meth:`range_of`); with
        ``classes``, at least the reach of the classes at or above ``thresholds_wide``
        (:func:`class_reach`) over σ, from the graph's ``outputs`` by name (``(n,)`` each,
        the probabilities ``(n, C)``).

        Raises:
            ValueError: ``classes`` and no ``outputs``."""
        width = self._lookup[1][self.range_of(by)]
        if not self.classes:
            return width
        reach = self._reach_wide(outputs)
        sigma = np.asarray(outputs[self.sigma], float)
        sigma = np.exp(sigma) if self.stored == "log_std" else sigma
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return np.maximum(width, np.where(reach > 0, reach / sigma, 0.0))  # 0/0: no reach

    def _reach_wide(self, outputs: dict[str, np.ndarray] | None) -> np.ndarray:
        """The classes' reach at the 95 % thresholds (:func:`class_reach`) over the graph's
        ``outputs``.

        Raises:
            ValueError: no ``outputs``."""
        if outputs is None:
            raise ValueError(f"the 95 % width of {self.sigma!r} needs the graph's outputs "
                             f"{self.value!r}, {self.classes!r} and {self.sigma!r}")
        return class_reach(outputs[self.value], outputs[self.classes], self.class_values,
                           self.thresholds_wide, self.log_value)

    def half_width(self, sigma: np.ndarray, by: np.ndarray,
                   outputs: dict[str, np.ndarray] | None = None) -> np.ndarray:
        """The 95 % interval's half-width ``(n,)`` in the σ output's own form and unit (a log
        std where ``stored`` is ``"log_std"``) from that output ``sigma`` and output ``by``,
        each ``(n,)`` (and, with ``classes``, the graph's ``outputs``: :meth:`wide`):
        ``max(width·σ, reach95)``, or its log for a log std. A few µs per call at batch 1
        (``wtml.runtime.predict.OnnxModel.half_widths`` calls it where answers are printed)."""
        width = self._lookup[1][self.range_of(by)]
        sigma = np.asarray(sigma, float)
        half = sigma + np.log(width) if self.stored == "log_std" else sigma * width
        if not self.classes:
            return half
        reach = self._reach_wide(outputs)
        if self.stored == "log_std":  # max(width·σ, reach) without σ·(reach/σ): σ may be 0
            with np.errstate(divide="ignore"):
                return np.maximum(half, np.log(reach))
        return np.maximum(half, reach)


@dataclass(frozen=True)
class Uncertainty:
    """How a decoder graph's uncertainties were recalibrated after training, on data it did
    not train on (``fitted_on`` says which): its σ outputs (``intervals``) and, for a
    classifier, its ``probabilities`` output tempered by ``temperature``, then its top
    label's probability mapped by ``sigmoid(top_slope·logit + top_bias)`` (none in an export
    made before that map: tempered only), with the expected calibration error on those data
    before and after. The parameters are constants of the graph (its outputs are the
    recalibrated values); the metadata states them."""

    fitted_on: str
    intervals: tuple[IntervalRecalibration, ...] = ()
    probabilities: str | None = None
    temperature: float | None = bounded(1e-3, 1e3, default=None)
    top_slope: float | None = bounded(1e-3, 1e3, default=None)
    top_bias: float | None = bounded(-1e3, 1e3, default=None)
    ece_before: float | None = bounded(0.0, 1.0, default=None)
    ece_after: float | None = bounded(0.0, 1.0, default=None)

    def check(self, path: str) -> None:
        if (self.probabilities is None) != (self.temperature is None):
            raise _fail(f"{path}.temperature", "must be given with probabilities (the output "
                        "it tempers), and only then")
        if (self.top_slope is None) != (self.top_bias is None):
            raise _fail(f"{path}.top_bias", "must be given with top_slope, and only then")
        if self.top_slope is not None and self.temperature is None:
            raise _fail(f"{path}.top_slope", "must be given with a temperature (it maps the "
                        "tempered probabilities), and only then")


@dataclass(frozen=True)
class GraphMetadata:
    """The metadata every exported graph carries (each key a string in the ONNX file; all but
    :data:`PLAIN` hold JSON)."""

    wtml_version: str
    task: str = one_of(*TASKS)
    kind: str = one_of(*KINDS)
    label: str = dataclasses.field(default="")
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    units: dict = dataclasses.field(default_factory=dict)
    references: dict = dataclasses.field(default_factory=dict)
    frequency_hz: tuple[float, ...] = bounded(1e-6, 1e9, default=())
    scene: dict = dataclasses.field(default_factory=dict)
    scene_hash: str = ""
    domain: Domain = None  # type: ignore[assignment]  (REQUIRED: always given)
    uncertainty: Uncertainty | None = None
    """The decoder's and the stream's: how their σ and probabilities were recalibrated."""

    REQUIRED = ("wtml_version", "task", "kind", "inputs", "outputs", "units", "references",
                "frequency_hz", "scene", "scene_hash", "domain")

    def check(self, path: str) -> None:
        key = (self.task, self.kind)
        if key not in GRAPH_INPUTS:
            raise _fail("kind", f"a {self.task} export has no {self.kind!r} graph (kinds: "
                        f"{[k for t, k in GRAPH_INPUTS if t == self.task]})")
        for name, table in (("inputs", GRAPH_INPUTS), ("outputs", GRAPH_OUTPUTS)):
            if getattr(self, name) != table[key]:
                raise _fail(name, f"must be {list(table[key])} for a {self.task} {self.kind} "
                            f"graph, got {list(getattr(self, name))}")
        _strings("units", self.units)
        _strings("references", self.references)
        if tuple(sorted(self.references)) != REFERENCE_KEYS[self.task]:
            raise _fail("references", f"must name {list(REFERENCE_KEYS[self.task])} for a "
                        f"{self.task} graph, got {sorted(self.references)}")
        missing = [n for n in self.outputs if n not in self.units]
        if missing:
            raise _fail("units", f"no unit for output {missing[0]!r}")
        if not self.frequency_hz:
            raise _fail("frequency_hz", "must list at least one frequency (Hz)")
        if len(set(self.frequency_hz)) != len(self.frequency_hz):
            raise _fail("frequency_hz", "must not list a frequency twice")
        if self.scene.get("task", UNNAMED) != self.task:
            raise _fail("scene.task", f"must be the graph's task {self.task!r}, got "
                        f"{self.scene.get('task', 'fluid')!r}")
        if not _HEX64.match(self.scene_hash):
            raise _fail("scene_hash", f"must be 64 hex digits, got {self.scene_hash!r:.80}")
        if scene_hash(self.scene) != self.scene_hash:
            raise _fail("scene_hash", "is not the hash of the metadata's scene (one of them "
                        "was edited)")
        outputs = self.domain.outputs
        for name in PHYSICAL[self.task]:
            if name not in outputs:
                raise _fail("domain.outputs", f"must give the ranges of {name!r} (its physical "
                            f"range flags impossible answers), has {sorted(outputs)}")
        extra = sorted(set(outputs) - set(self.outputs))
        if extra:
            raise _fail("domain.outputs", f"{extra[0]!r} is not an output of this graph")
        self.check_uncertainty()

    def check_uncertainty(self) -> None:
        """A decoder or stream graph states its recalibration (an export of an older wtml,
        whose σ and probabilities were not recalibrated, does not: refused), naming outputs
        of the graph; a classical graph has none."""
        u = self.uncertainty
        if self.kind == "classical":
            if u is not None:
                raise _fail("uncertainty", "a classical graph has no recalibration")
            return
        if u is None:
            raise _fail("uncertainty", f"missing: this {self.kind} graph does not state how its "
                        f"σ and probabilities were recalibrated (exported by a wtml before issue "
                        f"25); {REDO}")
        for k, r in enumerate(u.intervals):
            for name in (r.sigma, r.value, r.by, *([r.classes] if r.classes else [])):
                if name not in self.outputs:
                    raise _fail(f"uncertainty.intervals[{k}]", f"{name!r} is not an output of "
                                f"this graph ({list(self.outputs)})")
        if u.probabilities is not None and u.probabilities not in self.outputs:
            raise _fail("uncertainty.probabilities", f"{u.probabilities!r} is not an output of "
                        f"this graph")
        for k, r in enumerate(u.intervals):
            if r.classes and r.classes != u.probabilities:
                raise _fail(f"uncertainty.intervals[{k}].classes", f"must be the recalibrated "
                            f"probabilities {u.probabilities!r}, got {r.classes!r}")


@dataclass(frozen=True)
class FluidMetadata(GraphMetadata):
    """A fluid graph's metadata: the common keys only."""


@dataclass(frozen=True)
class RadialMetadata(GraphMetadata):
    """A radial graph's metadata: the common keys only."""


@dataclass(frozen=True)
class OnsetMetadata(GraphMetadata):
    """An onset graph's metadata: records of ``n_samples`` at ``sample_rate_hz``; frames of
    ``frame_s`` (one probe period for the decoder and the stream, one sample for the classical
    path), a contact's onset and detachment at ``onset_offset_s`` and ``detach_offset_s``
    into its frame, runs closer than ``merge_s`` one contact, a touch looked for
    ``touch_lookback`` frames ahead of a run (:mod:`wtml.runtime.contacts`); the stream's chunks
    of ``chunk_samples`` and its state of ``state_size``."""

    sample_rate_hz: float = bounded(1.0, 1e9, default=0.0)
    n_samples: int = bounded(1, 10**9, default=0)
    frame_s: float = bounded(1e-9, 10.0, default=0.0)
    onset_offset_s: float = bounded(0.0, 10.0, default=0.0)
    detach_offset_s: float = bounded(0.0, 10.0, default=0.0)
    merge_s: float = bounded(0.0, 100.0, default=0.0)
    touch_lookback: int = bounded(0, 1000, default=0)
    chunk_samples: int = bounded(1, 10**9, default=0)
    state_size: int = bounded(1, 10**9, default=0)

    REQUIRED = GraphMetadata.REQUIRED + ("sample_rate_hz", "n_samples", "frame_s",
                                         "onset_offset_s", "detach_offset_s", "merge_s",
                                         "touch_lookback")

    def check(self, path: str) -> None:
        super().check(path)
        if len(self.frequency_hz) != 1:
            raise _fail("frequency_hz", f"must be the probe's one frequency, got "
                        f"{list(self.frequency_hz)}")
        period = self.frame_s * self.sample_rate_hz
        if abs(period - round(period)) > 1e-6 * period:
            raise _fail("frame_s", f"must be a whole number of samples at sample_rate_hz "
                        f"{self.sample_rate_hz:g} Hz, got {self.frame_s:g} s")
        want = (1 / self.sample_rate_hz if self.kind == "classical"
                else 1 / self.frequency_hz[0])
        if abs(self.frame_s - want) > 1e-9 * want:
            what = ("one sample (1 / sample_rate_hz) for the classical path"
                    if self.kind == "classical" else "one probe period (1 / frequency_hz)")
            raise _fail("frame_s", f"must be {what}: {want:g} s, got {self.frame_s:g}")
        if round(period) > self.n_samples:
            raise _fail("frame_s", f"must be within a record ({self.n_samples} samples), got "
                        f"{self.frame_s:g} s")
        for name in ("onset_offset_s", "detach_offset_s"):
            if getattr(self, name) > self.frame_s * (1 + 1e-9):
                raise _fail(name, f"must be in [0, frame_s = {self.frame_s:g}] s (a phase "
                            f"within the frame), got {getattr(self, name):g}")
        probe_s = 1 / self.frequency_hz[0]
        if self.merge_s > 100 * probe_s:
            raise _fail("merge_s", f"must be in [0, {100 * probe_s:g}] s (100 probe periods), "
                        f"got {self.merge_s:g}")
        if self.kind == "stream":
            for name in ("chunk_samples", "state_size"):
                if not getattr(self, name):
                    raise _fail(name, "missing (the streaming graph's)")
            if self.chunk_samples > self.n_samples:
                raise _fail("chunk_samples", f"must be in [1, n_samples = {self.n_samples}], "
                            f"got {self.chunk_samples}")
        max_contacts = self.scene.get("max_contacts", 8)
        if isinstance(max_contacts, bool) or not isinstance(max_contacts, int) or not (
                1 <= max_contacts <= 1000):
            raise _fail("scene.max_contacts", f"must be an integer in [1, 1000], got "
                        f"{max_contacts!r:.80}")


@dataclass(frozen=True)
class TextureMetadata(GraphMetadata):
    """A texture graph's metadata: windows of ``n_samples`` (``window_s``) at
    ``sample_rate_hz``, the calibrated T at ``calibration_hz``, the class names in the order
    of ``probabilities``."""

    classes: tuple[str, ...] = ()
    sample_rate_hz: float = bounded(1.0, 1e9, default=0.0)
    n_samples: int = bounded(1, 10**9, default=0)
    window_s: float = bounded(1e-9, 1e6, default=0.0)
    calibration_hz: tuple[float, ...] = bounded(1e-6, 1e9, default=())

    REQUIRED = GraphMetadata.REQUIRED + ("classes", "sample_rate_hz", "n_samples", "window_s",
                                         "calibration_hz")

    def check(self, path: str) -> None:
        super().check(path)
        if len(self.classes) < 2 or len(set(self.classes)) != len(self.classes):
            raise _fail("classes", f"must name two or more distinct classes, got "
                        f"{list(self.classes)}")
        if abs(self.window_s * self.sample_rate_hz - self.n_samples) > 1:
            raise _fail("window_s", f"must be n_samples / sample_rate_hz = "
                        f"{self.n_samples / self.sample_rate_hz:g} s, got {self.window_s:g}")
        if not self.calibration_hz:
            raise _fail("calibration_hz", "must list at least one frequency (Hz)")
        for k, r in enumerate(self.uncertainty.intervals if self.uncertainty else ()):
            if r.classes and len(r.class_values) != len(self.classes):
                raise _fail(f"uncertainty.intervals[{k}].class_values", f"must hold one value "
                            f"per class ({len(self.classes)}), got {len(r.class_values)}")


SCHEMAS = {"fluid": FluidMetadata, "radial": RadialMetadata, "onset": OnsetMetadata,
           "texture": TextureMetadata}


def scene_hash(scene: dict) -> str:
    """sha256 of a scene mapping's canonical JSON (what ``wtml.schema.config_hash`` gives for
    the scene it was made from)."""
    return mapping_hash(scene)


def graph_metadata(props: dict[str, str], where: str) -> GraphMetadata:
    """A graph's metadata (the ONNX file's ``metadata_props``: strings) checked against its
    task's schema; ``where`` (the file) starts every error's message.

    Raises:
        SchemaError: ``{where}: metadata {key}: {what is allowed}``.
    """
    task = props.get("task")
    if task not in SCHEMAS:
        raise SchemaError(f"{where}: metadata task: must be one of {list(TASKS)}, got "
                          f"{task!r:.80}; {REDO}")
    schema = SCHEMAS[task]
    missing = [k for k in schema.REQUIRED if k not in props]
    if missing:
        raise SchemaError(f"{where}: metadata {missing[0]}: missing (a {task} graph's metadata "
                          f"has {list(schema.REQUIRED)}); {REDO}")
    data: dict[str, Any] = {}
    for key, text in props.items():
        if key in PLAIN:
            data[key] = text
            continue
        try:
            data[key] = parse_json(text, key, infinity=True)
        except FileError as err:
            raise SchemaError(f"{where}: metadata {err}") from None
    try:
        return build(schema, data)
    except SchemaError as err:
        raise SchemaError(f"{where}: metadata {err}") from None


def check_graph(meta: GraphMetadata, graph_inputs: list, graph_outputs: list,
                where: str) -> None:
    """The graph as its metadata describes it: input and output names in order, and each
    input's fixed sizes (after the batch) those the metadata implies. ``graph_inputs`` and
    ``graph_outputs``: onnxruntime's ``NodeArg`` lists."""
    names = [a.name for a in graph_inputs]
    if names != list(meta.inputs):
        raise SchemaError(f"{where}: metadata inputs: {list(meta.inputs)} are not the graph's "
                          f"inputs {names}; {REDO}")
    names = [a.name for a in graph_outputs]
    if names != [*meta.outputs, *GATE_OUTPUTS]:
        raise SchemaError(f"{where}: metadata outputs: {list(meta.outputs)} (then "
                          f"{list(GATE_OUTPUTS)}) are not the graph's outputs {names}; {REDO}")
    want = input_sizes(meta)
    for arg in graph_inputs:
        shape = list(arg.shape)[1:]
        need = list(want[arg.name])
        fixed = all(isinstance(s, int) for s in shape)
        if len(shape) != len(need) or (fixed and shape != need):
            key = {"ze_re": "frequency_hz", "ze_im": "frequency_hz", "ref_re": "frequency_hz",
                   "ref_im": "frequency_hz", "state": "state_size"}.get(arg.name, "n_samples")
            if meta.task == "fluid" and arg.name.startswith("t_"):
                key = "frequency_hz"
            if meta.task == "texture" and arg.name.startswith("t_"):
                key = "calibration_hz"
            if meta.kind == "stream" and arg.name in ("e", "i"):
                key = "chunk_samples"
            raise SchemaError(f"{where}: metadata {key}: says input {arg.name!r} is "
                              f"(batch, {', '.join(map(str, need))}) but the graph takes "
                              f"{['batch', *shape]}; {REDO}")


def input_sizes(meta: GraphMetadata) -> dict[str, tuple[int, ...]]:
    """Each graph input's sizes after the batch, as the metadata implies them."""
    n = len(meta.frequency_hz)
    if meta.task == "fluid":
        return {"ze_re": (n,), "ze_im": (n,), "t_re": (n, 4), "t_im": (n, 4)}
    if meta.task == "radial":
        return {name: (n,) for name in RADIAL_INPUTS}
    if meta.task == "onset":
        width = meta.chunk_samples if meta.kind == "stream" else meta.n_samples
        return {"e": (width,), "i": (width,), "t_re": (4,), "t_im": (4,), "hue0": (),
                "state": (meta.state_size,)}
    k = len(meta.calibration_hz)
    return {"e": (meta.n_samples,), "i": (meta.n_samples,), "t_re": (k, 4), "t_im": (k, 4)}


# --------------------------------------------------------------------------- the manifest


@dataclass(frozen=True)
class ExportFile:
    """One file of an export folder: its name in the folder, what it is, its sha256 and
    size."""

    name: str
    kind: str
    sha256: str
    bytes: int = bounded(1, MODEL_MAX_BYTES)

    def check(self, path: str) -> None:
        if not _HEX64.match(self.sha256):
            raise _fail(f"{path}.sha256", f"must be 64 lowercase hex digits, got "
                        f"{self.sha256!r:.80}")


@dataclass(frozen=True)
class ExportManifest:
    """``manifest.json`` of an export folder (:func:`write_manifest`)."""

    format: int = bounded(OLDEST_FORMAT, MANIFEST_FORMAT)
    wtml_version: str
    task: str = one_of(*TASKS)
    scene_hash: str
    device: DeviceIdentity
    files: tuple[ExportFile, ...]
    metadata: dict

    def check(self, path: str) -> None:
        prefix = f"{path}." if path else ""
        names = [f.name for f in self.files]
        for k, f in enumerate(self.files):
            try:
                inside(".", f.name, where="")
            except FileError:
                raise _fail(f"{prefix}files[{k}].name", f"must be a file name in the export "
                            f"folder (letters, digits, '_', '.', '-'; no path), got "
                            f"{f.name!r:.80}") from None
            if names.count(f.name) > 1:
                raise _fail(f"{prefix}files[{k}].name", f"{f.name!r} is listed twice")
        kinds = [f.kind for f in self.files]
        for kind in ("decoder", "classical"):
            if kinds.count(kind) != 1:
                raise _fail(f"{prefix}files", f"must list one {kind!r} graph, lists "
                            f"{kinds.count(kind)}")
        for name, props in self.metadata.items():
            if name not in names:
                raise _fail(f"{prefix}metadata.{name}", "is not a file of the manifest")
            if not isinstance(props, dict):
                raise _fail(f"{prefix}metadata.{name}", "must be a mapping of strings")
            _strings(f"{prefix}metadata.{name}", props)
        if not _HEX64.match(self.scene_hash):
            raise _fail(f"{prefix}scene_hash", f"must be 64 hex digits, got "
                        f"{self.scene_hash!r:.80}")

    def entry(self, kind: str) -> ExportFile | None:
        """The file of ``kind`` (``decoder``, ``classical``, ``stream``, ...), or None."""
        return next((f for f in self.files if f.kind == kind), None)


def scene_device(scene: dict) -> dict:
    """The identity (``{"name", "sha256"}``, :func:`wtml.devices.identity`) of the device in a
    scene mapping (``scene["device"]``, the fluid scene's ``scene["transducer"]["device"]``)."""
    device = scene.get("device")
    if not isinstance(device, dict):
        device = (scene.get("transducer") or {}).get("device")
    if not isinstance(device, dict) or not isinstance(device.get("name"), str):
        raise _fail("scene.device", "must hold the device's mapping (its name and values)")
    return {"name": device["name"], "sha256": physical_hash(device)}


def write_manifest(folder: str | Path, files: dict[str, Path], metadata: dict[str, dict],
                   *, task: str, scene_hash: str, device: dict, version: str) -> Path:
    """Write ``folder/manifest.json`` listing ``files`` (``{kind: path}``, each inside
    ``folder``) with sha256 and size, the ``device`` the scene simulated (``{"name",
    "sha256"}``) and each graph's ``metadata`` (``{file name: {key: string}}``);
    atomically (a temporary file renamed), so that a folder whose export was interrupted has
    no manifest and is refused."""
    folder = Path(folder)
    listed = [{"name": Path(p).name, "kind": kind, "sha256": sha256(p),
               "bytes": Path(p).stat().st_size} for kind, p in files.items()]
    data = {"format": MANIFEST_FORMAT, "wtml_version": version, "task": task,
            "scene_hash": scene_hash, "device": device, "files": listed,
            "metadata": metadata}
    build(ExportManifest, data)  # what is written is what is read
    return atomic_write(folder / MANIFEST,
                        (json.dumps(data, indent=1, sort_keys=True) + "\n").encode())


def read_manifest(folder: str | Path) -> ExportManifest:
    """An export folder's ``manifest.json``, checked against :class:`ExportManifest`.

    Raises:
        FileError: no manifest (a folder from an older wtml: export it again), not a regular
            small file, not strict JSON; format 1 (export it again) or a format newer than
            :data:`MANIFEST_FORMAT` (install the exporting wtml's runtime).
        SchemaError: a key missing, of the wrong type or out of range (naming it; a format
            that is not an integer in [:data:`OLDEST_FORMAT`, :data:`MANIFEST_FORMAT`]).
    """
    path = Path(folder) / MANIFEST
    if not path.exists():
        raise FileError(f"{path}: missing: not an export folder of this wtml (made by an "
                        f"older one, or not by `wtml export`, or an export interrupted); {REDO}")
    data = read_json(path, what="export manifest")
    fmt = data.get("format") if isinstance(data, dict) else None
    if type(fmt) is int and fmt == 1:
        raise FileError(f"{path}: format: 1, exported by an older wtml (it names no device); "
                        f"{REDO}")
    if type(fmt) is int and fmt > MANIFEST_FORMAT:
        made = data.get("wtml_version")
        raise FileError(f"{path}: format: {fmt!r:.20}, exported by a newer wtml"
                        f"{f' ({made:.40})' if isinstance(made, str) else ''} than this one "
                        f"({__version__}, reads formats {OLDEST_FORMAT}-{MANIFEST_FORMAT}): "
                        f"install that wtml's runtime on this device, or export with this one")
    try:
        return build(ExportManifest, data)
    except SchemaError as err:
        raise SchemaError(f"{path}: {err}; {REDO}") from None


def verified_bytes(folder: str | Path, entry: ExportFile) -> bytes:
    """The bytes of an export's file after checking them against its manifest entry.

    Raises:
        FileError: missing, not a regular file, empty, or its size or sha256 not the
            manifest's (edited or damaged).
    """
    path = regular_file(Path(folder) / entry.name, what="model file", max_bytes=MODEL_MAX_BYTES)
    try:
        data = path.read_bytes()
    except OSError as err:
        raise FileError(f"{path}: cannot read this model file ({err.strerror})") from None
    if not data:
        raise FileError(f"{path}: empty file; {REDO}")
    if len(data) != entry.bytes or hashlib.sha256(data).hexdigest() != entry.sha256:
        raise FileError(f"{path}: sha256 does not match {MANIFEST}: edited or damaged; {REDO}")
    return data
