"""The machinery of ``wtml bench stability`` (:mod:`wtml.bench.stability`): a task's
conditions and methods (:class:`Suite`), scoring every method on every condition against its
own mid-domain error (:func:`run_suite`), the verdicts and the tables.

A method *loses* accuracy in a condition where its error exceeds :data:`LOSS_FACTOR` × its
mid-domain error, and its flag *catches* that where it marks at least :data:`CAUGHT_SHARE` of
the records; inside the trained ranges a flag above :data:`FALSE_ALARM` is a false alarm. The
float32 comparison: the classical path as a device runs it (its ONNX graph, float32) against the
same path in float64 numpy on identical inputs; it blows up where the largest relative
difference exceeds :data:`BLOWUP`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

LOSS_FACTOR = 2.0
"""A condition where a method's error is more than this times its mid-domain error is one
where it loses accuracy."""
CAUGHT_SHARE = 0.9
"""A method's domain flag catches a loss where it marks at least this share of the records."""
FALSE_ALARM = 0.1
"""Inside the trained ranges, a flagged share above this is reported as false alarms."""
BLOWUP = 1e-2
"""A float32 path blows up where its largest relative difference from float64 exceeds this."""
KINDS = ("mid", "edge", "beyond", "extreme")
"""Where a condition lies: the middle of the trained domain, the end of a trained range (still
inside it), just beyond a trained range, a physical extreme (free, clamped, at resonance)."""


@dataclass(frozen=True)
class Condition:
    """One row group: ``make(n, rng)`` returns ``n`` fresh records of the task's scene.

    Attributes:
        name: the row's label, with the ranges it draws from.
        kind: one of :data:`KINDS`.
        make: the records.
    """

    name: str
    kind: str
    make: Callable[[int, np.random.Generator], dict]

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"kind: one of {KINDS}, got {self.kind!r}")


@dataclass(frozen=True)
class Method:
    """A method behind one call: ``run(records)`` returns its answers (the task's outputs, and
    ``in_domain`` (bool ``(n,)``) where it has a domain flag)."""

    name: str
    run: Callable[[dict], dict]


@dataclass(frozen=True)
class Suite:
    """A task's conditions and methods (built by :mod:`wtml.bench.stability_suites`).

    Attributes:
        task: the task's name.
        metric: what the error is (e.g. "η median relative error").
        unit: the table's unit of it, and ``scale``: the factor from the metric's SI value.
        conditions: exactly one of kind ``mid`` among them.
        methods: in the table's order.
        error: ``(records, answers) -> error`` (SI; NaN where the records hold nothing true
            to find).
        answer: ``(records, answers) -> text``: what a method answered, for rows without a
            truth (and the note of those with one, e.g. records it found nothing in).
        answered: ``(records, answers) -> share`` of the records a method gave an answer for
            (where there is nothing to find, answering nothing is right: a record without a
            wall); default every record.
        pairs: the float32 comparisons by name: ``(float32 method, float64 method,
            ((output, floor), ...))``, each output's difference relative to the larger of the
            float64 answer's magnitude and ``floor`` (SI; 0: purely relative).
        notes: lines for the report under the task's rows.
    """

    task: str
    metric: str
    unit: str
    scale: float
    conditions: list[Condition]
    methods: list[Method]
    error: Callable[[dict, dict], float]
    answer: Callable[[dict, dict], str]
    pairs: tuple[tuple[str, str, tuple[tuple[str, float], ...]], ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)
    answered: Callable[[dict, dict], float] = lambda records, answers: 1.0

    def __post_init__(self) -> None:
        mids = [c.name for c in self.conditions if c.kind == "mid"]
        if len(mids) != 1:
            raise ValueError(f"{self.task}: exactly one condition of kind 'mid', got {mids}")
        names = {m.name for m in self.methods}
        for f32, f64, _ in self.pairs:
            if not {f32, f64} <= names:
                raise ValueError(f"{self.task}: pairs: {f32!r} and {f64!r} must be methods")


def relative_difference(low: np.ndarray, high: np.ndarray, floor: float = 0.0) -> np.ndarray:
    """``|low - high| / max(|high|, floor)`` elementwise (the float32 answer ``low`` against
    the float64 ``high``; ``floor`` >= 0 in their unit); inf where the denominator is 0 and
    ``low`` differs, 0 where they are equal; NaN where either is NaN."""
    low, high = np.asarray(low, float), np.asarray(high, float)
    diff = np.abs(low - high)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = diff / np.maximum(np.abs(high), floor)
    return np.where(diff == 0, 0.0, out)


def verdict(kind: str, ratio: float, flagged: float | None, answered: float = 1.0) -> str:
    """The row's verdict (module docstring) from its kind, its error over the mid-domain one
    (NaN: nothing true to find), the share its flag marks (None: no flag) and, where there
    is nothing to find, the share of records it answered for anyway."""
    if np.isnan(ratio) and answered == 0:
        return "holds: answers nothing"
    if kind == "mid":
        return "reference" + (" (false alarms)" if flagged is not None and flagged > FALSE_ALARM
                              else "")
    lost = not ratio <= LOSS_FACTOR  # NaN: answering where there is nothing to find
    alarms = kind == "edge" and flagged is not None and flagged > FALSE_ALARM
    if not lost:
        return "holds" + ("; false alarms" if alarms else "")
    loss = (f"answers {100 * answered:.0f} %, nothing to find" if np.isnan(ratio)
            else f"loses ×{ratio:.3g}")
    if kind == "edge":  # inside the trained ranges: no flag is owed
        return f"{loss} inside the trained range" + ("; false alarms" if alarms else "")
    if flagged is None:
        return f"{loss}; no flag"
    return f"{loss}; {'caught' if flagged >= CAUGHT_SHARE else 'NOT caught'}"


def run_suite(suite: Suite, records: int, seed: int, progress=None) -> dict:
    """Score every method on every condition's ``records`` fresh records (drawn from
    ``seed`` and the condition's index, so a row is reproducible alone). Returns ``rows``
    (one per condition and method), ``float32`` (one per condition, pair and output) and
    ``seconds`` (per condition: simulating, scoring)."""
    rows, f32_rows, seconds = [], [], []
    mid_error: dict[str, float] = {}
    order = sorted(range(len(suite.conditions)), key=lambda k: suite.conditions[k].kind != "mid")
    for k in order:  # the mid-domain rows first: every ratio needs them
        cond = suite.conditions[k]
        if progress:
            progress(f"{suite.task}: {cond.name} ({records} records)")
        t0 = time.perf_counter()
        rec = cond.make(records, np.random.default_rng([seed, k]))
        t1 = time.perf_counter()
        answers = {m.name: m.run(rec) for m in suite.methods}
        for m in suite.methods:
            pred = answers[m.name]
            err = float(suite.error(rec, pred))
            if cond.kind == "mid":
                mid_error[m.name] = err
            mid = mid_error[m.name]
            ratio = err / mid if mid > 0 else (1.0 if err == 0 else float("inf"))
            flagged = (float(1 - np.mean(pred["in_domain"])) if "in_domain" in pred
                       else None)
            answered = float(suite.answered(rec, pred)) if np.isnan(err) else 1.0
            rows.append({"task": suite.task, "condition": cond.name, "kind": cond.kind,
                         "index": k, "method": m.name, "error": err, "ratio": ratio,
                         "flagged": flagged, "answered": answered,
                         "answer": suite.answer(rec, pred),
                         "verdict": verdict(cond.kind, ratio, flagged, answered)})
        for f32, f64, outputs in suite.pairs:
            for out, floor in outputs:
                rel = relative_difference(answers[f32][out], answers[f64][out], floor)
                finite = rel[np.isfinite(rel)]
                f32_rows.append({"task": suite.task, "condition": cond.name, "index": k,
                                 "float32": f32, "float64": f64, "output": out,
                                 "max": float(np.max(rel)) if len(rel) else float("nan"),
                                 "median": float(np.median(finite)) if len(finite)
                                 else float("nan"),
                                 "nonfinite": int(np.sum(~np.isfinite(rel)))})
        seconds.append({"condition": cond.name, "simulate_s": t1 - t0,
                        "score_s": time.perf_counter() - t1})
    index = {c.name: k for k, c in enumerate(suite.conditions)}
    rows.sort(key=lambda r: index[r["condition"]])
    f32_rows.sort(key=lambda r: index[r["condition"]])
    return {"rows": rows, "float32": f32_rows, "seconds": seconds}


def format_rows(suite: Suite, result: dict) -> list[str]:
    """The task's rows of the stability table (markdown lines, without the header)."""
    lines = []
    for r in result["rows"]:
        err = ("-" if np.isnan(r["error"])
               else f"{suite.scale * r['error']:.3g} {suite.unit}")
        ratio = "-" if not np.isfinite(r["ratio"]) else f"{r['ratio']:.2f}"
        flagged = "-" if r["flagged"] is None else f"{100 * r['flagged']:.0f} %"
        lines.append(f"| {suite.task} | {r['condition']} | {r['method']} | {err} | {ratio} | "
                     f"{flagged} | {r['verdict']} | {r['answer']} |")
    return lines


def format_float32(rows: list[dict]) -> list[str]:
    """The float32 table's rows (markdown lines, without the header)."""
    lines = []
    for r in rows:
        blows = "BLOWS UP" if not r["max"] <= BLOWUP else "no"
        extra = f" ({r['nonfinite']} not finite)" if r["nonfinite"] else ""
        lines.append(f"| {r['task']} | {r['condition']} | {r['float32']} vs {r['float64']} | "
                     f"{r['output']} | {r['max']:.2g}{extra} | {r['median']:.2g} | {blows} |")
    return lines


def strict_json(x):
    """``x`` (nested dicts, lists, tuples, arrays, numbers) with NaN and inf as None, so that
    strict JSON holds it."""
    if isinstance(x, dict):
        return {k: strict_json(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [strict_json(v) for v in x]
    if isinstance(x, np.ndarray):
        return strict_json(x.tolist())
    if isinstance(x, float | np.floating):
        return float(x) if np.isfinite(x) else None
    if isinstance(x, np.integer):
        return int(x)
    return x


