"""The task registry (wtml.tasks) and the house rules it serves: every task declared once and
each of its parts importable; the package's modules free of import cycles (function-level
imports counted) and of imports of another module's private names."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from tests.conftest import ROOT
from wtml.scenes import SCENES
from wtml.tasks import TASKS, task


def test_every_task_is_declared_once_and_its_parts_load():
    """The registry's tasks are the scenes' (same order as the main job), each part imports,
    the scene's ``task`` is the task's name and the decoder is a LightningModule."""
    import lightning

    assert list(TASKS) == ["fluid", "radial", "onset", "texture"]
    assert set(TASKS) == set(SCENES)
    for name, spec in TASKS.items():
        assert spec.name == name and spec.reads in ("measurements", "recordings")
        assert spec.load("scene") is SCENES[name]
        assert SCENES[name]().task == name
        assert issubclass(spec.load("decoder"), lightning.LightningModule)
        for part in ("export", "rows", "pipeline"):
            assert callable(spec.load(part)), (name, part)
        scene = spec.load("scene")
        assert len(scene.INPUT_KEYS) and callable(scene.decoder_inputs)
        assert callable(scene.targets) and callable(scene.target_keys)
        if spec.evaluate:
            assert callable(spec.load("evaluate")), name
        # a task that reads measurements declares its export and sample measurements
        assert bool(spec.measurement) == (spec.reads == "measurements"), name
        if spec.measurement:
            from wtml.exporters.matrix import MatrixTask

            assert isinstance(spec.load("measurement"), MatrixTask), name
    with pytest.raises(ValueError, match="the onset task has no 'measurement' part"):
        TASKS["onset"].load("measurement")
    with pytest.raises(ValueError, match="'stress' is not a task of this wtml "
                                         "\\(tasks: fluid, radial, onset, texture\\)"):
        task("stress")


def _imports() -> dict[str, list[tuple[str, str]]]:
    """Each wtml module's imports of wtml (module, name), at any level of its code."""
    modules = {}
    for f in (ROOT / "wtml").rglob("*.py"):
        name = ".".join(f.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
        modules[name] = f
    found: dict[str, list[tuple[str, str]]] = {}
    for name, f in modules.items():
        found[name] = []
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("wtml"):
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    found[name].append((sub if sub in modules else node.module, alias.name))
            elif isinstance(node, ast.Import):
                found[name] += [(a.name, "") for a in node.names if a.name.startswith("wtml")]
    return found


def test_no_import_cycles_and_no_private_names():
    """No module imports itself through others (Tarjan's strongly connected components of
    the import graph), and none imports another module's ``_private`` name."""
    imports = _imports()
    graph = {m: {target for target, _ in deps if target in imports}
             for m, deps in imports.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                cycles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert cycles == []
    private = [(m, target, name) for m, deps in imports.items() for target, name in deps
               if name.startswith("_") and not name.startswith("__")]
    assert private == []


def _task_names(node: ast.AST) -> set[str]:
    """The task names written as string constants anywhere in ``node``."""
    return {n.value for n in ast.walk(node) if isinstance(n, ast.Constant)} & set(TASKS)


def test_the_entry_points_do_not_switch_on_a_task_name():
    """``wtml predict``, ``wtml export``, checkpoint loading and the main job's loop look a
    task up in the registry (a new task touches its own modules and one registry entry)."""
    for path, function in ((ROOT / "wtml/cli.py", "_predict"),
                           (ROOT / "wtml/exporters/common.py", "export_model"),
                           (ROOT / "wtml/decoders/checkpoint.py", "load_decoder"),
                           (ROOT / "wtml/pipeline.py", "run_all")):
        tree = ast.parse(Path(path).read_text())
        body = next(n for n in ast.walk(tree)
                    if isinstance(n, ast.FunctionDef) and n.name == function)
        assert not _task_names(body), (path, function, _task_names(body))


def test_the_shared_modules_do_not_switch_on_a_task_name():
    """The data module, ``wtml evaluate``, the export and the main job's shared helpers get
    each task's part from its scene or the registry: no task name in them at all (the data
    module, ``wtml evaluate``, the export), or none compared with (``==``, ``!=``, ``in``)
    nor in a shared helper of the main job (its ``run_<task>`` stages and summary are its
    tasks')."""
    for path in ("wtml/data/datamodule.py", "wtml/bench/evaluate.py",
                 "wtml/exporters/common.py", "wtml/exporters/matrix.py"):
        tree = ast.parse((ROOT / path).read_text())
        assert not _task_names(tree), (path, _task_names(tree))
    tree = ast.parse((ROOT / "wtml/pipeline.py").read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Compare):
            assert not _task_names(node), ("wtml/pipeline.py", node.lineno, ast.unparse(node))
    for function in ("write_sample_csv", "_export_and_predict", "_export_and_predict_records"):
        body = next(n for n in ast.walk(tree)
                    if isinstance(n, ast.FunctionDef) and n.name == function)
        assert not _task_names(body), ("wtml/pipeline.py", function, _task_names(body))
