"""``wtml bench stability``: every method of every task at the extremes of its task (issue 25 §5).

For each task with an export (``<models>/<task>``), fresh records of the scene its decoder was
trained on (the graph's metadata) under named conditions (:mod:`wtml.bench.stability_suites`):
the middle of the trained domain (kind ``mid``), the ends of the trained ranges (``edge``),
just beyond them (``beyond``) and the physical extremes (``extreme``: a free and a clamped
tip, contacts far softer or stiffer than trained, the transducer at its resonance where the
scene's band holds it). Each method scores each condition with its task's metric. The table
gives the error, its ratio to the method's own mid-domain error, the share of records its
domain flag (the ONNX graphs') marks out of domain, and a verdict: a method *loses* accuracy
where its error exceeds :data:`LOSS_FACTOR` × its mid-domain error, and its flag *catches*
that where it marks at least :data:`CAUGHT_SHARE` of the records; inside the trained ranges a
flag above :data:`FALSE_ALARM` is a false alarm.

The float32 table: the classical path as a device runs it (its ONNX graph, float32 inside)
against the same path in float64 numpy on identical inputs, per condition: the largest and
the median relative difference of each output, and where it blows up (largest above
:data:`BLOWUP`). The scoring and the tables: :mod:`wtml.bench.extremes`. Writes ``report.md``
and ``summary.json``.
"""

from __future__ import annotations

import json
import platform
import sys
import time
from pathlib import Path

from wtml.bench.extremes import (
    BLOWUP,
    CAUGHT_SHARE,
    FALSE_ALARM,
    LOSS_FACTOR,
    format_float32,
    format_rows,
    run_suite,
    strict_json,
)


def run_stability(models: str | Path, out: str | Path, *, records: int = 48, seed: int = 2025,
                  threads: int = 2, tasks: tuple[str, ...] | None = None) -> str:
    """The whole bench (module docstring); returns the report (also ``out/report.md``).

    Args:
        models: the folder of the task exports (``<models>/<task>``, as ``wtml pipeline``
            writes them under ``export``); a task without its export is skipped, and said so.
        out: ``report.md`` and ``summary.json`` go here.
        records: fresh records per condition (every task).
        seed: of every condition's records.
        threads: onnxruntime's and torch's threads.
        tasks: the tasks to run (default every task with a suite, in the registry's order).
    """
    from wtml.bench.stability_suites import SUITES
    from wtml.tasks import TASKS

    if records < 2:
        raise ValueError(f"records must be >= 2, got {records}")
    unknown = sorted(set(tasks or ()) - set(SUITES))
    if unknown:
        raise ValueError(f"tasks: {unknown} have no stability suite (tasks: {list(SUITES)})")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    models = Path(models)
    lines = ["# wtml bench stability", "",
             f"Fresh records of each export's own scene, {records} per condition (seed {seed}); "
             f"machine {platform.machine()}, onnxruntime with {threads} threads. Error / mid: "
             "the method's error over its own mid-domain error. Flagged: the share its domain "
             f"flag marks out of domain (ONNX graphs). A method loses accuracy above "
             f"{LOSS_FACTOR:g}× its mid-domain error; its flag catches that at ≥ "
             f"{100 * CAUGHT_SHARE:.0f} % flagged; inside the trained ranges a flag above "
             f"{100 * FALSE_ALARM:.0f} % is a false alarm.", "",
             "| task | condition | method | error | error / mid | flagged | verdict | "
             "answer |", "|---|---|---|---|---|---|---|---|"]
    f32_lines, notes, summary, skipped = [], [], {}, []
    for name in TASKS:
        if name not in SUITES or (tasks and name not in tasks):
            continue
        folder = models / name
        if not folder.is_dir():
            skipped.append(f"{name} (no export at {folder})")
            continue
        t0 = time.perf_counter()
        suite = SUITES[name](folder, threads)
        result = run_suite(suite, records, seed, _progress)
        lines += format_rows(suite, result)
        f32_lines += format_float32(result["float32"])
        notes += [f"- {name}: {suite.metric} ({suite.unit}). " + " ".join(suite.notes)]
        summary[name] = {"metric": suite.metric, "unit": suite.unit, "scale": suite.scale,
                         **result, "wall_s": time.perf_counter() - t0}
    lines += ["", *notes]
    if skipped:
        lines += ["", "Skipped: " + "; ".join(skipped) + "."]
    if f32_lines:
        lines += ["", "## float32 on the device path against float64", "",
                  "The classical ONNX graph (float32) against the classical path in float64 "
                  "numpy on the same inputs: difference of each output relative to the float64 "
                  "answer (radial: to at least 1 % of the trained range of d), largest and "
                  f"median over the records; it blows up above {BLOWUP:g}.", "",
                  "| task | condition | paths | output | max rel. diff | median | blows up |",
                  "|---|---|---|---|---|---|---|", *f32_lines]
    report = "\n".join(lines) + "\n"
    (out / "report.md").write_text(report)
    (out / "summary.json").write_text(json.dumps(strict_json(
        {"records": records, "seed": seed, "threads": threads, "tasks": summary,
         "skipped": skipped, "loss_factor": LOSS_FACTOR, "caught_share": CAUGHT_SHARE,
         "false_alarm": FALSE_ALARM, "blowup": BLOWUP}), indent=1, allow_nan=False))
    return report


def _progress(text: str) -> None:
    print(f"bench stability: {text}", file=sys.stderr, flush=True)
