"""One frontier for every task (issue 25 §2): the speed–accuracy trade of every method of a
task on the same held-out data, in one run, with the same threads.

A task hands the frontier a :class:`Problem`: its held-out inputs, its metric (a value with its
interval from the rows' own resampling), the unit its costs are counted in (a sample, or a
second of signal), its methods that are not decoders (classical path, peers, the best
achievable) and an adapter that turns an ONNX graph of the task into a predictor. The frontier
adds the decoder variants (one export folder each, trained from their own configs by
:mod:`wtml.bench.variants`) and, for every decoder, onnxruntime's own quantisations
(:func:`quantise`): int8 dynamic, int8 static and float16, each kept as a method only where it
is measured faster here, side by side with its decoder (:func:`wtml.bench.timing.paired_ratio`),
at equal accuracy. Every method gets: the metric with its interval,
p50 latency at batch 1 (per unit), throughput at a large batch, the ONNX file's size and the
ONNX session's memory (peak RSS of a fresh process that opens it and runs the large batch,
over that of the same process before; :func:`session_memory`).

The report answers, per task: for a budget of 10 µs, 100 µs, 1 ms and 10 ms per unit, which
method is the most accurate on this machine (:func:`budget_rows`), with a Pareto plot.

This module imports only numpy and the runtime at the top: the session-memory probe runs it in
a child process that must not load the training stack.
"""

from __future__ import annotations

import json
import logging
import os
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from wtml.bench.timing import (
    BUSY_SHARE,
    busy_elsewhere,
    cpu_snapshot,
    latency_p50,
    paired_ratio,
    throughput,
)

BUDGETS_S = (10e-6, 100e-6, 1e-3, 10e-3)
"""The budgets of the report, seconds per unit (a sample, or a second of signal)."""
KINDS = ("decoder", "quantised", "classical", "peer", "reference", "bound")
"""What a row is: a trained decoder (a variant), one of its quantisations, the task's classical
path, a peer library, the best achievable computed like a method (Bayes, an oracle) and an
information bound (no method: accuracy only)."""
QUANTISATIONS = ("int8 dynamic", "int8 static", "float16")
LAYER_OPS = ("MatMul", "Gemm")
"""The ops quantised: the nets' layers (those whose weight is a ``*.weight`` initializer
outside the domain gate). The physics in front of them (Zm through the calibrated T, the
features) and the domain gate stay float32: int8 there would be another method, and a gate
that flags half of its own trained domain."""


@dataclass
class Method:
    """One row of the frontier.

    Attributes:
        name: as the report prints it.
        kind: one of :data:`KINDS`.
        predictor: ``predict(*Problem.inputs) -> {output: (n, ...)}``; None for a bound.
        onnx: its graph, for the size and session-memory columns (None: not a graph).
        note: one line for the report.
        score: a bound's (value, low, high), when it has no predictor.
    """

    name: str
    kind: str
    predictor: Any = None
    onnx: Path | None = None
    note: str = ""
    score: tuple[float, float, float] | None = None


@dataclass
class Problem:
    """What a task hands the frontier.

    Attributes:
        task: its name.
        metric: what the value is, e.g. ``"η median relative error"``.
        unit: the value's unit as printed (``"%"``, ``"µm"``).
        higher_is_better: accuracy (True) or an error (False).
        per: the unit of cost, ``"sample"`` or ``"s of signal"``.
        per_row: units in one row of ``inputs`` (1 for a sample; a record's seconds).
        inputs: the held-out inputs, each ``(n, ...)``.
        score: ``predictions -> (value, low, high)``, the interval from the rows' resampling,
            or ``(value, low, high, detail)``: ``detail`` a line of the task's other metrics.
        graph: ``"measurements"``, ``"windows"`` or ``"records"``: how an ONNX graph of the
            task is called (:data:`ADAPTERS`).
        big_batch: rows of the throughput call.
        calibration: inputs for static quantisation (training data, not ``inputs``).
        methods: the methods that are not decoder variants.
        notes: lines for the report.
        data: where the held-out set comes from, for the report.
        speed_target: ``(p50 latency at batch 1, s per unit; throughput at the large batch,
            units/s)`` that the default decoder should meet (None: no target), stated against
            the measurements with the most accurate decoder or quantisation that meets both
            (:func:`speed_verdict`).
    """

    task: str
    metric: str
    unit: str
    higher_is_better: bool
    per: str
    per_row: float
    inputs: tuple
    score: Callable[[dict], tuple[float, float, float]]
    graph: str
    big_batch: int
    calibration: tuple
    methods: list[Method] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    data: str = ""
    speed_target: tuple[float, float] | None = None


class MeasurementGraph:
    """An ONNX graph of a matrix task (fluid, radial) as a predictor: ``predict(ze, ref)``."""

    def __init__(self, model) -> None:
        self.model, self.name = model, model.name

    def predict(self, ze: np.ndarray, reference: np.ndarray) -> dict[str, np.ndarray]:
        return self.model.predict(ze, reference)


class WindowGraph:
    """A texture graph on windows: ``predict(e, i, t) -> {"grade", "grain", "in_domain",
    "probabilities"}``; ``t`` the windows' calibrated T (complex ``(n, K, 2, 2)``)."""

    def __init__(self, model) -> None:
        self.model, self.name = model, model.name

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        from wtml.runtime.texture import run_windows

        out = run_windows(self.model, e, i, t)
        return out | {"grade": np.argmax(out["probabilities"], 1)}


class RecordGraph:
    """An onset graph on whole records: ``predict(e, i, t_re, t_im, hue0)`` -> its outputs
    (``gap``: the wall's location, m) and each record's contact onsets and detachments by the
    runtime's rule (``onsets``, ``detachments``: lists of arrays of seconds)."""

    def __init__(self, model) -> None:
        self.model, self.name = model, model.name

    def predict(self, *inputs: np.ndarray) -> dict:
        from wtml.runtime.contacts import Timing, contacts_from

        out = self.model.run(*inputs)
        out["onsets"], out["detachments"] = contacts_from(out, Timing.of(self.model.meta))
        return out


ADAPTERS = {"measurements": MeasurementGraph, "windows": WindowGraph, "records": RecordGraph}


def open_graph(path: Path, graph: str, threads: int):
    """The ONNX file ``path`` of a task whose graphs are called as ``graph``, as a
    predictor (its metadata checked like ``wtml predict`` checks it)."""
    from wtml.runtime.predict import OnnxModel

    return ADAPTERS[graph](OnnxModel(path, threads))


class _FeedRecorder:
    """Stands in for an onnxruntime session and keeps every feed it is given."""

    def __init__(self, session) -> None:
        self.session, self.feeds = session, []

    def run(self, names, feed):
        self.feeds.append(feed)
        return self.session.run(names, feed)

    def __getattr__(self, name: str):
        return getattr(self.session, name)


def graph_feeds(predictor, inputs: tuple, rows: int = 64) -> list[dict[str, np.ndarray]]:
    """The graph-level feeds (input name -> float32 array) that ``predictor`` (an adapter of
    :data:`ADAPTERS`) gives its session for ``inputs``, ``rows`` rows per feed: the
    calibration data of static quantisation."""
    model = predictor.model
    recorder = _FeedRecorder(model.session)
    model.session = recorder
    try:
        n = len(inputs[0])
        for k in range(0, n, rows):
            predictor.predict(*(x[k:k + rows] for x in inputs))
    finally:
        model.session = recorder.session
    return recorder.feeds


def quantise(path: Path, out: Path, feeds: list[dict]) -> dict[str, Path | str]:
    """onnxruntime's own quantisations of the graph ``path`` into ``out``: ``{name: path}``
    for each of :data:`QUANTISATIONS` that it made, ``{name: reason}`` for each it could not.
    Only the layers are quantised (:data:`LAYER_OPS`); the graph's metadata is kept."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader

    class Reader(CalibrationDataReader):
        def __init__(self) -> None:
            self.items = iter(feeds)

        def get_next(self):
            return next(self.items, None)

    out.mkdir(parents=True, exist_ok=True)
    source = onnx.load(str(path))
    layers = layer_nodes(source)
    made: dict[str, Path | str] = {}
    # the quantiser logs "please consider pre-processing" on the root logger for every graph:
    # third-party advice, not this bench's output (the graphs are exported optimised)
    quiet, logging.root.level = logging.root.level, logging.ERROR
    try:
        _quantise_each(path, out, source, layers, Reader, made)
    finally:
        logging.root.level = quiet
    return made


def _quantise_each(path: Path, out: Path, source, layers: list[str], reader, made: dict
                   ) -> None:
    """:func:`quantise`'s loop: each of :data:`QUANTISATIONS` into ``made``."""
    import onnx
    from onnxruntime.quantization import QuantType, quantize_dynamic, quantize_static

    for name in QUANTISATIONS:
        target = out / f"{path.stem}.{name.replace(' ', '_')}.onnx"
        try:
            if name == "int8 dynamic":
                quantize_dynamic(path, target, weight_type=QuantType.QInt8,
                                 nodes_to_quantize=layers)
            elif name == "int8 static":
                quantize_static(path, target, reader(), nodes_to_quantize=layers,
                                op_types_to_quantize=list(LAYER_OPS),
                                activation_type=QuantType.QInt8, weight_type=QuantType.QInt8)
            else:
                onnx.save(half_layers(onnx.load(str(path)), layers), str(target))
            model = onnx.load(str(target))
            del model.metadata_props[:]
            model.metadata_props.extend(source.metadata_props)
            onnx.save(model, str(target))
            made[name] = target
        except Exception as err:  # onnxruntime's quantiser raises its own and plain errors
            made[name] = f"onnxruntime could not make it: {str(err).splitlines()[0][:120]}"


def half_layers(model, layers: list[str]):
    """``model`` (an ``onnx.ModelProto``, changed in place and returned) with the nodes
    ``layers`` in float16: their weights and biases stored in float16, their inputs cast to
    float16 and their outputs back to float32; everything else as it was. (onnxruntime's own
    converter casts the graph's inputs to float16 too, which overflows on raw Ze and
    currents.)"""
    from onnx import TensorProto, helper, numpy_helper

    initializers = {i.name: i for i in model.graph.initializer}
    nodes = []
    for node in model.graph.node:
        if node.name not in layers:
            nodes.append(node)
            continue
        for k, name in enumerate(node.input):
            if name in initializers:
                init = initializers[name]
                init.CopyFrom(numpy_helper.from_array(
                    numpy_helper.to_array(init).astype("float16"), name))
            else:
                cast = f"{name}__to_half_{node.name}"
                nodes.append(helper.make_node("Cast", [name], [cast], to=TensorProto.FLOAT16,
                                              name=f"{cast}_cast"))
                node.input[k] = cast
        result = node.output[0]
        node.output[0] = f"{result}__half"
        nodes.append(node)
        nodes.append(helper.make_node("Cast", [node.output[0]], [result], to=TensorProto.FLOAT,
                                      name=f"{result}__to_float"))
    del model.graph.node[:]
    model.graph.node.extend(nodes)
    return model


def layer_nodes(model) -> list[str]:
    """Names of the nodes of ``model`` (an ``onnx.ModelProto``) that are a net's layers:
    :data:`LAYER_OPS` whose weight is a ``*.weight`` initializer outside the domain gate."""
    weights = {i.name for i in model.graph.initializer
               if i.name.endswith(".weight") and not i.name.startswith("gate.")}
    return [n.name for n in model.graph.node
            if n.op_type in LAYER_OPS and any(x in weights for x in n.input)]


_PROBE = """
import sys
import numpy as np
from wtml.bench.frontier import open_graph
path, graph, threads, inputs = sys.argv[1], sys.argv[2], int(sys.argv[3]), sys.argv[4]
data = np.load(inputs)
args = [data[f"a{k}"] for k in range(len(data.files))]
def rss():
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:"))
before = rss()
predictor = open_graph(path, graph, threads)
predictor.predict(*(a[:1] for a in args))
predictor.predict(*args)
print(rss() - before)
"""


def session_memory(path: Path, graph: str, inputs: tuple, threads: int) -> int:
    """Bytes the ONNX session of ``path`` holds in a fresh process that opens it and runs it
    at batch 1 and on ``inputs``: its resident memory after, over that before (the imports
    and the inputs are not counted; onnxruntime's arena keeps what the batch needed)."""
    with tempfile.TemporaryDirectory() as tmp:
        npz = Path(tmp) / "inputs.npz"
        np.savez(npz, **{f"a{k}": x for k, x in enumerate(inputs)})
        env = os.environ | {"OMP_NUM_THREADS": str(threads)}
        done = subprocess.run([sys.executable, "-c", _PROBE, str(path), graph, str(threads),
                               str(npz)], capture_output=True, text=True, env=env, check=False)
    if done.returncode:
        raise RuntimeError(f"{path}: the session-memory probe failed: "
                           f"{done.stderr.strip().splitlines()[-1:]}")
    return 1024 * int(done.stdout.split()[-1])  # /proc reports KiB


def big_inputs(inputs: tuple, rows: int) -> tuple:
    """``inputs`` repeated (or cut) to ``rows`` rows."""
    return tuple(np.resize(x, (rows, *x.shape[1:])) for x in inputs)


def measure(problem: Problem, method: Method, *, threads: int, latency_repeats: int,
            throughput_repeats: int, budget_s: float = 3.0) -> dict:
    """One method's row (:func:`frontier`'s ``rows``)."""
    row = {"name": method.name, "kind": method.kind, "note": method.note,
           "latency_s": None, "throughput": None, "size_bytes": None, "memory_bytes": None}
    if method.predictor is None:
        value, low, high = method.score
        return row | {"value": value, "low": low, "high": high}
    start = time.perf_counter()
    pred = method.predictor.predict(*problem.inputs)
    rate = len(problem.inputs[0]) / (time.perf_counter() - start)
    value, low, high, *detail = problem.score(pred)
    one = tuple(x[:1] for x in problem.inputs)
    big = big_inputs(problem.inputs, problem.big_batch)
    if rate * budget_s < problem.big_batch:  # a slow method: its pass over the whole set
        row["note"] = "; ".join(x for x in (method.note, "throughput: its pass over the set")
                                if x)
        row["whole_pass"] = True
    else:
        rate = throughput(method.predictor, big, throughput_repeats, budget_s)
    row |= {"value": value, "low": low, "high": high, "detail": "".join(detail),
            "latency_s": latency_p50(method.predictor, one, latency_repeats, budget_s)
            / problem.per_row,
            "throughput": rate * problem.per_row}
    if "in_domain" in pred:
        row["flagged"] = float(1 - np.mean(pred["in_domain"]))
    if method.onnx is not None:
        row["size_bytes"] = Path(method.onnx).stat().st_size
        row["memory_bytes"] = session_memory(method.onnx, problem.graph, big, threads)
    return row


def side_by_side(problem: Problem, rows: list[dict], predictors: dict[str, Any],
                 reference: str, budget_s: float,
                 progress: Callable[[str], None] = print, clock=time.perf_counter) -> None:
    """Every timed row's time over the ``reference`` row's (a decoder), timed side by side
    (:func:`wtml.bench.timing.paired_ratio`) at batch 1 and at the large batch, into
    ``row["side_by_side"] = {"latency": (median, q25, q75), "batch": … or None}``: the
    ratios hold where the rows' own latencies, one after the other, take this machine's
    drift as a difference. A quantisation of the reference reuses its verdict's timing; a
    method too slow for the large batch in the budget (its throughput is its pass over the
    set) is paired at batch 1 only. Each round's calls are as many as fit ``budget_s``
    (one to ten). ``clock``: seconds (a test drives its own)."""
    base = next((r for r in rows if r["name"] == reference), None)
    if base is None or base["latency_s"] is None:
        return
    one = tuple(x[:1] for x in problem.inputs)
    big = big_inputs(problem.inputs, problem.big_batch)
    first = predictors[reference]
    per_call = {"latency": base["latency_s"] * problem.per_row,
                "batch": problem.big_batch * problem.per_row / base["throughput"]}
    prefix = reference.removesuffix(" ONNX") + " "
    for row in rows:
        if row["name"] == reference:
            row["side_by_side"] = {"latency": (1.0, 1.0, 1.0), "batch": (1.0, 1.0, 1.0)}
            continue
        if "paired" in row and row["name"].startswith(prefix):
            row["side_by_side"] = row["paired"]
            continue
        if row["latency_s"] is None or row["name"] not in predictors:
            continue
        progress(f"{problem.task}: {row['name']} beside {reference}")
        own = {"latency": row["latency_s"] * problem.per_row,
               "batch": problem.big_batch * problem.per_row / row["throughput"]}
        slow = row.get("whole_pass", False)
        row["side_by_side"] = {
            kind: None if kind == "batch" and slow else paired_ratio(
                first, predictors[row["name"]], args, budget_s=budget_s, clock=clock,
                calls=int(np.clip(budget_s / (6 * (own[kind] + per_call[kind])), 1, 10)))
            for kind, args in (("latency", one), ("batch", big))}


def better(problem: Problem, a: float, b: float) -> bool:
    """Whether value ``a`` is better than ``b`` under the task's metric."""
    return a > b if problem.higher_is_better else a < b


def quantised_verdict(problem: Problem, row: dict, base: dict, margin: float = 0.05) -> str:
    """Why a quantisation ``row`` of decoder row ``base`` is kept or not: kept only where it
    is faster by more than ``margin`` at batch 1 or at the large batch, slower by no more
    than ``margin`` at the other, and its value lies within the decoder's interval (equal
    accuracy at this test set's resolution) or beyond it on the better side.

    Where the row holds ``paired`` (its time over the decoder's, timed side by side:
    :func:`wtml.bench.timing.paired_ratio`, ``{"latency": …, "batch": …}`` each (median,
    25th, 75th percentile)), that decides: faster where three rounds in four were (the 75th
    percentile below ``1 - margin``), not slower where the median is below ``1 + margin``.
    Otherwise the rows' own latency and throughput, measured one after the other."""
    if not np.isfinite(row["value"]):
        return "dropped: its answers are not finite"
    if "paired" in row:
        lat, big = row["paired"]["latency"], row["paired"]["batch"]
        faster = ((lat[2] < 1 - margin and big[0] < 1 + margin)
                  or (big[2] < 1 - margin and lat[0] < 1 + margin))
        ratios = (f"side by side, time ×{lat[0]:.2f} ({lat[1]:.2f}–{lat[2]:.2f}) at batch 1, "
                  f"×{big[0]:.2f} ({big[1]:.2f}–{big[2]:.2f}) at batch {problem.big_batch}")
    else:
        latency = row["latency_s"] / base["latency_s"]
        rate = row["throughput"] / base["throughput"]
        faster = ((latency < 1 - margin and rate > 1 - margin)
                  or (rate > 1 + margin and latency < 1 + margin))
        ratios = f"latency ×{latency:.2f}, throughput ×{rate:.2f}"
    equal = base["low"] <= row["value"] <= base["high"] or better(problem, row["value"],
                                                                   base["value"])
    if faster and equal:
        return f"kept: faster at equal accuracy ({ratios})"
    if not faster:
        return f"dropped: not faster here ({ratios})"
    return (f"dropped: less accurate ({_value(problem, row)} against "
            f"{_value(problem, base)} [{base['low']:.3g}, {base['high']:.3g}])")


def usable(rows: list[dict]) -> list[dict]:
    """The rows a user can pick: methods with a measured cost and finite answers; a
    quantisation only where it was kept (bounds are not methods)."""
    return [r for r in rows if r["latency_s"] is not None and np.isfinite(r["value"])
            and (r["kind"] != "quantised" or r["verdict"].startswith("kept"))]


def _unmeasured(name: str, verdict: str) -> dict:
    """The row of a quantisation that could not be made or run."""
    nan = float("nan")
    return {"name": name, "kind": "quantised", "value": nan, "low": nan, "high": nan,
            "latency_s": None, "throughput": None, "size_bytes": None, "memory_bytes": None,
            "note": "", "verdict": verdict}


def budget_rows(problem: Problem, rows: list[dict], budgets=BUDGETS_S) -> list[dict]:
    """Per budget (s per unit), the most accurate of the :func:`usable` rows whose p50
    latency at batch 1 fits: ``{"budget_s", "name", "value", "low", "high", "latency_s"}``
    (name None: none fits)."""
    out = []
    for budget in budgets:
        fits = [r for r in usable(rows) if r["latency_s"] <= budget]
        best = None
        for r in fits:
            if best is None or better(problem, r["value"], best["value"]):
                best = r
        out.append({"budget_s": budget, "name": best and best["name"],
                    "value": best and best["value"], "low": best and best["low"],
                    "high": best and best["high"], "latency_s": best and best["latency_s"]})
    return out


def pareto(problem: Problem, rows: list[dict]) -> list[str]:
    """The names on the Pareto front of ``rows`` (:func:`usable` ones): no other method both
    as fast and more accurate."""
    timed = [r for r in rows if r["latency_s"] is not None]
    return [r["name"] for r in timed
            if not any(o is not r and o["latency_s"] <= r["latency_s"]
                       and better(problem, o["value"], r["value"]) for o in timed)]


def speed_verdict(problem: Problem, rows: list[dict], variant: str = "default") -> str:
    """One line: the decoder ``variant``'s p50 latency and throughput against the task's
    :attr:`Problem.speed_target`, and where it misses, the most accurate decoder or kept
    quantisation that meets both and what it costs in accuracy ("" without a target)."""
    if problem.speed_target is None:
        return ""
    latency, rate = problem.speed_target
    base = next((r for r in rows if r["name"] == f"decoder {variant} ONNX"), None)
    if base is None:
        return f"Speed target: no decoder {variant!r} on this frontier."

    def meets(r: dict) -> bool:
        return r["latency_s"] <= latency and r["throughput"] >= rate

    fast_enough = ("met" if base["latency_s"] <= latency else "MISSED",
                   "met" if base["throughput"] >= rate else "MISSED")
    said = (f"Speed target for the {variant} decoder: p50 {_time(base['latency_s'])} at "
            f"batch 1 (target ≤ {_time(latency)}: {fast_enough[0]}), "
            f"{base['throughput']:.3g} {problem.per}s/s at a batch of {problem.big_batch} "
            f"(target ≥ {rate:.3g}: {fast_enough[1]}).")
    if meets(base):
        return said
    fast = [r for r in usable(rows) if r["kind"] in ("decoder", "quantised") and meets(r)]
    if not fast:
        return said + " No decoder variant or quantisation meets both here."
    best = fast[0]
    for r in fast[1:]:
        if better(problem, r["value"], best["value"]):
            best = r
    return (said + f" The most accurate that meets both: {best['name']}, "
            f"{_value(problem, best)} against {_value(problem, base)} "
            f"(p50 {_time(best['latency_s'])}, {best['throughput']:.3g}/s).")


def _value(problem: Problem, row: dict) -> str:
    return f"{row['value']:.3g} {problem.unit}"


def _time(seconds: float | None) -> str:
    if seconds is None:
        return ""
    if seconds < 1e-3:
        return f"{1e6 * seconds:.1f} µs"
    return f"{1e3 * seconds:.2f} ms" if seconds < 1 else f"{seconds:.2f} s"


def _bytes(n: int | None) -> str:
    if n is None:
        return ""
    return f"{n / 1024:.0f} KiB" if n < 2**20 else f"{n / 2**20:.1f} MiB"


def _ratios(paired: dict | None) -> str:
    """``×0.52 (0.50–0.55); ×0.81 (0.78–0.85)`` from a row's ``side_by_side``."""
    if paired is None:
        return ""
    return "; ".join("" if paired[k] is None else
                     f"×{paired[k][0]:.2f} ({paired[k][1]:.2f}–{paired[k][2]:.2f})"
                     for k in ("latency", "batch"))


def _budget(seconds: float) -> str:
    return f"{1e6 * seconds:.0f} µs" if seconds < 1e-3 else f"{1e3 * seconds:.0f} ms"


def report_lines(problem: Problem, result: dict) -> list[str]:
    """One task's section of the report (markdown lines)."""
    rows, direction = result["rows"], "higher" if problem.higher_is_better else "lower"
    lines = [f"## {problem.task}: {problem.metric} ({problem.unit}, {direction} is better)", "",
             f"Held-out data: {problem.data}. Latency: p50 at batch 1, per {problem.per}; "
             f"throughput: {problem.per}s per second at a batch of {problem.big_batch}; "
             f"{result['threads']} threads (torch and onnxruntime); memory: the ONNX session's "
             "peak RSS over a fresh process's, running that batch.", "",
             f"Side by side: each row's time over the {result['reference'] or 'reference'}'s, "
             "timed in alternating rounds (median, quartiles), at batch 1 and at the large "
             "batch: the ratios hold where this machine's speed drifts between rows.", "",
             f"| method | kind | {problem.metric} [95 % interval] | p50 latency / {problem.per} "
             f"| throughput ({problem.per}s/s) | time, side by side (batch 1; batch "
             f"{problem.big_batch}) | size | session memory | flagged | note |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    front = set(result["pareto"])
    for r in rows:
        name = f"**{r['name']}**" if r["name"] in front else r["name"]
        flagged = "" if r.get("flagged") is None else f"{100 * r['flagged']:.1f} %"
        note = "; ".join(x for x in (r.get("detail"), r.get("verdict") or r["note"]) if x)
        lines.append(
            f"| {name} | {r['kind']} | {r['value']:.3g} [{r['low']:.3g}, {r['high']:.3g}] | "
            f"{_time(r['latency_s'])} | "
            f"{'' if r['throughput'] is None else format(r['throughput'], '.3g')} | "
            f"{_ratios(r.get('side_by_side'))} | {_bytes(r['size_bytes'])} | "
            f"{_bytes(r['memory_bytes'])} | {flagged} | {note} |")
    lines += ["", "Bold: the Pareto front (no other method both faster and more accurate).",
              "", f"| budget per {problem.per} | most accurate method within it | "
              f"{problem.metric} | its p50 latency |", "|---|---|---|---|"]
    for b in result["budgets"]:
        if b["name"] is None:
            lines.append(f"| {_budget(b['budget_s'])} | none fits | | |")
        else:
            lines.append(f"| {_budget(b['budget_s'])} | {b['name']} | {b['value']:.3g} "
                         f"[{b['low']:.3g}, {b['high']:.3g}] {problem.unit} | "
                         f"{_time(b['latency_s'])} |")
    verdict = speed_verdict(problem, rows)
    return lines + ["", *([verdict, ""] if verdict else []), *busy_lines(result),
                    *problem.notes, ""]


def busy_lines(result: dict) -> list[str]:
    """What else ran while the task was timed (:func:`~wtml.bench.timing.busy_elsewhere`):
    a line, and a warning above :data:`~wtml.bench.timing.BUSY_SHARE`; none where unknown."""
    share, cores = result.get("busy_elsewhere"), result.get("cores")
    if share is None:
        return []
    if share <= BUSY_SHARE:
        return [f"While this task was timed, other processes kept {100 * share:.0f} % of the "
                f"{cores} cores busy.", ""]
    return [f"**Busy machine:** while this task was timed, other processes kept "
            f"{100 * share:.0f} % of the {cores} cores busy (more than "
            f"{100 * BUSY_SHARE:.0f} %): its times and the speed target's verdict are not this "
            "machine's own. Re-run it alone.", ""]


def plot(problem: Problem, result: dict, path: Path) -> None:
    """The task's Pareto plot: value against p50 latency per unit, the bounds as lines."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = result["rows"]
    fig, ax = plt.subplots(figsize=(7, 4.5), constrained_layout=True)
    markers = {"decoder": "o", "quantised": "s", "classical": "^", "peer": "D",
               "reference": "*"}
    for r in rows:
        if r["latency_s"] is None:
            ax.axhline(r["value"], color="grey", ls=":", lw=1)
            ax.annotate(r["name"], (0.01, r["value"]), xycoords=("axes fraction", "data"),
                        fontsize=7, color="grey")
            continue
        ax.errorbar(r["latency_s"], r["value"],
                    yerr=[[r["value"] - r["low"]], [r["high"] - r["value"]]],
                    fmt=markers.get(r["kind"], "o"), ms=6, capsize=2,
                    alpha=1.0 if r["name"] in result["pareto"] else 0.45, label=r["name"])
    front = sorted((r for r in rows if r["name"] in result["pareto"]),
                   key=lambda r: r["latency_s"])
    ax.step([r["latency_s"] for r in front], [r["value"] for r in front], where="post",
            color="k", lw=0.8)
    for b in BUDGETS_S:
        ax.axvline(b, color="C7", lw=0.5, ls="--")
    ax.set(xscale="log", yscale="linear" if problem.higher_is_better else "log",
           xlabel=f"p50 latency at batch 1 per {problem.per} (s)",
           ylabel=f"{problem.metric} ({problem.unit})", title=f"{problem.task}: the frontier")
    ax.legend(fontsize=6, loc="best")
    fig.savefig(path, dpi=120)
    plt.close(fig)


def frontier(problem: Problem, decoders: dict[str, Path], out: Path, *, threads: int = 2,
             latency_repeats: int = 2000, throughput_repeats: int = 30, budget_s: float = 3.0,
             progress: Callable[[str], None] = print) -> dict:
    """Measure every method of ``problem`` and every decoder variant (``{variant: its ONNX
    decoder graph}``) with its quantisations; write ``out/<task>.png`` and return
    ``{"task", "threads", "rows", "reference", "budgets", "pareto", "busy_elsewhere",
    "cores", "lines"}`` (``reference``: the row the side-by-side times are over;
    ``busy_elsewhere``: the share of ``cores`` other processes kept busy meanwhile,
    :func:`~wtml.bench.timing.busy_elsewhere`). ``budget_s``: the most seconds one latency or
    throughput measurement runs (:mod:`wtml.bench.timing`)."""
    out.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    methods: list[Method] = []
    for variant, path in decoders.items():
        methods.append(Method(f"decoder {variant} ONNX", "decoder",
                              open_graph(path, problem.graph, threads), path))
    rows = []
    start = cpu_snapshot()
    for m in [*methods, *problem.methods]:
        progress(f"{problem.task}: {m.name}")
        rows.append(measure(problem, m, threads=threads, latency_repeats=latency_repeats,
                            throughput_repeats=throughput_repeats, budget_s=budget_s))
    one = tuple(x[:1] for x in problem.inputs)
    big = big_inputs(problem.inputs, problem.big_batch)
    quantised: dict[str, Any] = {}
    for variant, path in decoders.items():
        base = next(r for r in rows if r["name"] == f"decoder {variant} ONNX")
        predictor = next(m.predictor for m in methods if m.onnx == path)
        feeds = graph_feeds(predictor, problem.calibration)
        for name, made in quantise(path, out / "quantised" / problem.task / variant,
                                   feeds).items():
            label = f"decoder {variant} {name} ONNX"
            if isinstance(made, str):
                rows.append(_unmeasured(label, f"not made: {made}"))
                continue
            progress(f"{problem.task}: {label}")
            try:
                m = Method(label, "quantised", open_graph(made, problem.graph, threads), made)
                row = measure(problem, m, threads=threads, latency_repeats=latency_repeats,
                              throughput_repeats=throughput_repeats, budget_s=budget_s)
                row["paired"] = {
                    "latency": paired_ratio(predictor, m.predictor, one, budget_s=budget_s),
                    "batch": paired_ratio(predictor, m.predictor, big, budget_s=budget_s)}
                quantised[label] = m.predictor
            except Exception as err:  # a quantised graph onnxruntime cannot run on this CPU
                rows.append(_unmeasured(label, "dropped: does not run here "
                                               f"({str(err).splitlines()[0][:100]})"))
                continue
            rows.append(row | {"verdict": quantised_verdict(problem, row, base)})
    result = {"task": problem.task, "threads": threads, "rows": rows, "reference": None}
    if decoders:
        variant = "default" if "default" in decoders else next(iter(decoders))
        result["reference"] = f"decoder {variant} ONNX"
        predictors = {m.name: m.predictor for m in methods + problem.methods} | quantised
        side_by_side(problem, rows, predictors, result["reference"], budget_s, progress)
    end = cpu_snapshot()
    result["busy_elsewhere"] = busy_elsewhere(start, end)
    result["cores"] = None if end is None else end[3]
    result["pareto"] = pareto(problem, usable(rows))
    result["budgets"] = budget_rows(problem, rows)
    result["lines"] = report_lines(problem, result)
    plot(problem, result, out / f"{problem.task}.png")
    return result


def write_report(results: list[dict], out: Path, title: str) -> str:
    """``out/report.md`` and ``out/summary.json`` of one or more tasks' frontiers."""
    head = [f"# {title}", "",
            f"Machine: {platform.machine()}, {os.cpu_count()} cores; every row of a task "
            "measured side by side in one run. Each task's Pareto plot: "
            + ", ".join(f"`{r['task']}.png`" for r in results) + ".", ""]
    text = "\n".join(head + [line for r in results for line in r["lines"]])
    (out / "report.md").write_text(text)
    (out / "summary.json").write_text(json.dumps(
        [{k: v for k, v in r.items() if k != "lines"} for r in results], indent=1,
        default=float))
    return text
