"""``wtml bench TASK --frontier`` and ``wtml bench all``: each task's frontier
(:mod:`wtml.bench.frontier`) with its decoder variants trained from their configs
(:data:`VARIANTS`), one report for all of them.

A variant is trained where its ``last.ckpt`` is missing or was made for another dataset,
config or run length, resumed where it stopped, kept where it finished
(:func:`wtml.pipeline.train_config`), and exported again only where its checkpoint is newer
than its export, so an interrupted ``bench all`` picks up where it stopped.
"""

from __future__ import annotations

import sys
from pathlib import Path

from wtml.bench.frontier import frontier, write_report
from wtml.schema import read_yaml
from wtml.tasks import TASKS, task

VARIANTS = "configs/frontier.yaml"
"""Each task's decoder variants: ``{task: {variant: training config}}``."""


def read_variants(path: str | Path, name: str) -> dict[str, str]:
    """The variants of task ``name`` in the file ``path`` (``{variant: config path}``).

    Raises:
        ValueError: the file lists none for the task, or a config that does not exist.
    """
    variants = read_yaml(path).get(name)
    if not isinstance(variants, dict) or not variants:
        raise ValueError(f"{path}: {name}: must map each decoder variant to its training "
                         f"config, got {variants!r}")
    for variant, config in variants.items():
        if not Path(str(config)).is_file():
            raise ValueError(f"{path}: {name}.{variant}: no such config {config!r}")
    return {str(k): str(v) for k, v in variants.items()}


def variant_exports(variants: dict[str, str], data_dir: str | Path, out: Path, *,
                    max_epochs: int | None = None) -> dict[str, Path]:
    """Train (or resume, or keep) each variant on ``data_dir`` and export it under
    ``out/<variant>``; returns ``{variant: its decoder graph}``."""
    from wtml.exporters.common import export_model
    from wtml.pipeline import train_config

    graphs = {}
    for variant, config in variants.items():
        ckpt = train_config(config, Path(data_dir), max_epochs=max_epochs,
                            begin=lambda command, v=variant: _progress(f"{v}: {command}"))
        folder = out / variant
        graph = folder / "model.onnx"
        if not graph.exists() or graph.stat().st_mtime < ckpt.stat().st_mtime:
            _progress(f"{variant}: wtml export --checkpoint {ckpt} --out {folder}")
            export_model(ckpt, folder)
        graphs[variant] = graph
    return graphs


def run_frontiers(names: list[str], out: str | Path, *, variants: str | Path = VARIANTS,
                  data: dict[str, str] | None = None, threads: int = 2,
                  latency_repeats: int = 2000, throughput_repeats: int = 30,
                  max_epochs: int | None = None) -> str:
    """The frontier of each task in ``names`` (in the registry's order), into ``out``:
    ``report.md``, ``summary.json``, a Pareto plot per task, the variants' exports under
    ``out/exports/<task>/``. ``data``: a task's dataset folder where it is not
    ``datasets/<task>``. Returns the report."""
    out = Path(out)
    results = []
    for name in [n for n in TASKS if n in names]:
        data_dir = (data or {}).get(name, f"datasets/{name}")
        if not Path(data_dir).is_dir():
            raise ValueError(f"{name}: no dataset at {data_dir}; make it with `wtml pipeline "
                             f"--task {name}` (or wtml generate)")
        graphs = variant_exports(read_variants(variants, name), data_dir,
                                 out / "exports" / name, max_epochs=max_epochs)
        default = graphs.get("default", next(iter(graphs.values()))).parent
        problem = task(name).load("frontier")(data_dir, default, threads=threads)
        results.append(frontier(problem, graphs, out, threads=threads,
                                latency_repeats=latency_repeats,
                                throughput_repeats=throughput_repeats, progress=_progress))
    title = "wtml bench all" if len(results) > 1 else f"wtml bench {names[0]} --frontier"
    return write_report(results, out, title)


def _progress(text: str) -> None:
    print(text, file=sys.stderr, flush=True)
