"""The file kinds, the commands that read them, and the replay of one case.

A *case* is a JSON-ready mapping (what ``tests/fuzz_corpus/<kind>/<name>.json`` holds)::

    {"kind": "manifest", "task": "fluid", "command": "evaluate",
     "target": "data/manifest.json", "mutation": {"op": "set", "path": ["n_shards"],
     "value": 1000000000}}

:func:`replay` copies the task's base files (built once per session, :class:`Bases`) into a
fresh folder, applies the mutation to ``target`` (relative to that folder), runs the command
in a forked child (:mod:`tests.fuzz.runner`) and classifies the outcome.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import torch
import yaml

from tests.fuzz import mutate
from tests.fuzz.runner import Result, run

KINDS = ("scene", "config", "manifest", "sidecar", "shard", "checkpoint", "export", "input",
         "calibration", "reference", "record")
"""The file kinds, in the order the report lists them."""


@dataclass
class Task:
    """One task's base files: ``files`` maps a name in the case folder to the file or folder
    copied there (``scene.yaml``, ``data``, ``last.ckpt``, ``export``, ``input.npz``,
    ``input.csv``, ``cal.npz``, ``ref.npz``, ``config.yaml``)."""

    name: str
    files: dict[str, Path]
    predict_args: tuple[str, ...] = ()
    """``--calibration cal.npz`` and such, relative to the case folder."""
    epochs: int = 0
    """Epochs the base checkpoint has run (a resume asks for one more)."""


@dataclass
class Bases:
    tasks: dict[str, Task]
    baselines: dict[tuple[str, str], str] = field(default_factory=dict)
    """(task, command) -> the untampered run's stdout."""

    def foreign(self) -> dict[str, Path]:
        """Every base file by a ``task/name`` key (another kind's file, for ``foreign``)."""
        out = {}
        for t in self.tasks.values():
            for name, p in t.files.items():
                if p.is_file():
                    out[f"{t.name}/{name}"] = p
            export = t.files.get("export")
            if export is not None:
                for p in sorted(export.iterdir()):
                    if p.is_file():
                        out[f"{t.name}/export/{p.name}"] = p
            data = t.files.get("data")
            if data is not None:
                for name in ("manifest.json", "shard-00000.json", "shard-00000.npz"):
                    out[f"{t.name}/data/{name}"] = data / name
        return out


def train_config(task: Task, root: Path, epochs: int = 1) -> dict:
    """The shipped training config of ``task`` made small: its dataset in the case folder,
    ``epochs`` epochs, runs under the case folder."""
    cfg = mutate.copy.deepcopy(yaml.safe_load((ROOT / f"configs/{task.name}.yaml").read_text()))
    cfg["data"]["init_args"]["data_dir"] = str(root / "data")
    cfg["trainer"]["max_epochs"] = epochs
    cfg["trainer"]["default_root_dir"] = str(root / "runs")
    cfg["trainer"]["log_every_n_steps"] = 1
    if "hidden" in cfg["model"].get("init_args", {}):
        cfg["model"]["init_args"]["hidden"] = [32, 32]
    return cfg


ROOT = Path(__file__).resolve().parents[2]

COMMANDS = {
    # command: (entry, files it needs, argv given the case folder)
    "generate": ("wtml", ("scene.yaml", "data"),
                 lambda w, t: ["generate", "--config", str(w / "scene.yaml"), "--out",
                               str(w / "data"), "--quiet"]),
    "generate_new": ("wtml", ("scene.yaml",),
                     lambda w, t: ["generate", "--config", str(w / "scene.yaml"), "--out",
                                   str(w / "new"), "--quiet"]),
    "evaluate": ("wtml", ("last.ckpt", "data"),
                 lambda w, t: ["evaluate", "--checkpoint", str(w / "last.ckpt"), "--data",
                               str(w / "data")]),
    "export": ("wtml", ("last.ckpt",),
               lambda w, t: ["export", "--checkpoint", str(w / "last.ckpt"), "--out",
                             str(w / "new_export")]),
    "predict": ("wtml", ("export", "input.npz", "cal.npz", "ref.npz"),
                lambda w, t: ["predict", "--model", str(w / "export"), "--input",
                              str(w / "input.npz"),
                              *[a if a.startswith("--") else str(w / a)
                                for a in t.predict_args]]),
    "predict_rec": ("wtml", ("export", "rec.npz", "cal.npz"),
                    lambda w, t: ["predict", "--model", str(w / "export"), "--input",
                                  str(w / "rec.npz"),
                                  *[a if a.startswith("--") else str(w / a)
                                    for a in t.predict_args]]),
    "predict_csv": ("wtml", ("export", "input.csv", "cal.npz"),
                    lambda w, t: ["predict", "--model", str(w / "export"), "--input",
                                  str(w / "input.csv"),
                                  *[a if a.startswith("--") else str(w / a)
                                    for a in t.predict_args]]),
    "fit": ("train", ("data", "config.yaml"),
            lambda w, t: ["fit", "--config", str(w / "config.yaml")]),
    "resume": ("train", ("data", "config.yaml", "last.ckpt"),
               lambda w, t: ["fit", "--config", str(w / "config.yaml"), "--ckpt_path",
                             str(w / "last.ckpt")]),
}

# kind -> task -> (commands, targets): targets relative to the case folder
PLAN: dict[str, dict[str, tuple[tuple[str, ...], tuple[str, ...]]]] = {
    "scene": {t: (("generate_new",), ("scene.yaml",))
              for t in ("fluid", "radial", "onset", "texture")},
    "config": {"fluid": (("fit",), ("config.yaml",))},
    "manifest": {"fluid": (("evaluate", "generate", "fit"), ("data/manifest.json",
                                                           "data/scene.json")),
                 "radial": (("evaluate",), ("data/manifest.json", "data/scene.json"))},
    "sidecar": {"fluid": (("generate",), ("data/shard-00000.json", "data/shard-00003.json"))},
    "shard": {"fluid": (("evaluate", "fit"), ("data/shard-00003.npz", "data/shard-00000.npz")),
              "radial": (("evaluate",), ("data/shard-00003.npz",))},
    "checkpoint": {"fluid": (("evaluate", "export", "resume"), ("last.ckpt",)),
                   "radial": (("evaluate",), ("last.ckpt",))},
    "export": {t: (("predict",), ("export/model.onnx", "export/classical.onnx",
                                   "export/manifest.json"))
               for t in ("fluid", "radial", "onset", "texture")},
    "input": {"fluid": (("predict", "predict_csv"), ("input.npz", "input.csv")),
              "radial": (("predict",), ("input.npz",))},
    "calibration": {t: (("predict",), ("cal.npz",)) for t in ("fluid", "onset", "texture")},
    "reference": {"radial": (("predict",), ("ref.npz",))},
    "record": {"fluid": (("predict_rec",), ("rec.npz",)),
               **{t: (("predict",), ("input.npz",)) for t in ("onset", "texture")}},
}
"""Which commands read which files of each kind, per task (the case draws one of each)."""

OWNERS = {"scene": "data", "config": "train", "manifest": "data", "sidecar": "data",
          "shard": "data", "checkpoint": "train", "export": "export", "input": "export",
          "calibration": "export", "reference": "export", "record": "export"}
"""Which of issue 22's branches fixes the reader of each kind (the corpus notes it)."""

SLOW_COMMANDS = ("fit", "resume", "export")
"""Commands of several seconds each (Lightning, the ONNX exporter): drawn in the slow run."""


def time_limit(command: str) -> float:
    """Seconds a command may take on one input before it counts as a hang: 20 for reading a
    small file, 90 for a small training run, 300 for an export (an onset checkpoint's graphs
    under tracemalloc take minutes; a checkpoint swapped for another task's is a right
    input there)."""
    return {"export": 300.0}.get(command, 90.0 if command in SLOW_COMMANDS else 20.0)


def workspace(bases: Bases, task: str, command: str, where: Path) -> Path:
    """A fresh case folder with copies of the files ``command`` needs."""
    t = bases.tasks[task]
    where.mkdir(parents=True, exist_ok=True)
    need = COMMANDS[command][1]
    for name, src in t.files.items():  # the files (small) always, the folders it needs
        if name not in need and src.is_dir():
            continue
        dst = where / name
        if src.is_dir():
            shutil.copytree(src, dst)
        else:
            shutil.copy(src, dst)
    if "config.yaml" in need:
        cfg = train_config(t, where, epochs=t.epochs + 1 if command == "resume" else 1)
        (where / "config.yaml").write_text(yaml.safe_dump(cfg))
    return where


# ---------------------------------------------------------------- reading and writing


def load_doc(path: Path) -> Any:
    """The structured contents of ``path`` (YAML, JSON, a checkpoint's ``wtml`` block or
    an ONNX model's metadata with JSON values parsed)."""
    if path.suffix == ".yaml":
        return yaml.safe_load(path.read_text())
    if path.suffix == ".json":
        return json.loads(path.read_text())
    if path.suffix == ".ckpt":
        return torch.load(path, map_location="cpu", weights_only=True)["wtml"]
    if path.suffix == ".onnx":
        model = onnx.load(str(path))
        doc = {}
        for p in model.metadata_props:
            try:
                doc[p.key] = json.loads(p.value)
            except ValueError:
                doc[p.key] = p.value
        return doc
    raise ValueError(path)


def save_doc(path: Path, doc: Any) -> None:
    if path.suffix == ".yaml":
        path.write_text(yaml.safe_dump(doc))
    elif path.suffix == ".json":
        path.write_text(json.dumps(doc))  # NaN and inf as JSON's non-standard tokens
    elif path.suffix == ".ckpt":
        state = torch.load(path, map_location="cpu", weights_only=True)
        state["wtml"] = doc
        torch.save(state, path)
    elif path.suffix == ".onnx":
        model = onnx.load(str(path))
        strings = {p.key for p in model.metadata_props if not _is_json(p.value)}
        del model.metadata_props[:]
        if isinstance(doc, dict):
            for k, v in doc.items():
                model.metadata_props.add(key=str(k), value=v if k in strings and isinstance(
                    v, str) else json.dumps(v))
        else:
            model.metadata_props.add(key="doc", value=json.dumps(doc))
        onnx.save(model, str(path))
    else:
        raise ValueError(path)


def _is_json(s: str) -> bool:
    try:
        json.loads(s)
        return True
    except ValueError:
        return False


def resign(root: Path, target: Path) -> None:
    """Write ``target``'s new sha256 wherever a manifest or sidecar beside it records one."""
    from wtml.files import sha256

    if not target.is_file():
        return
    new, size = sha256(target), target.stat().st_size
    for doc_path in (target.with_suffix(".json"), target.parent / "manifest.json"):
        if doc_path == target or not doc_path.is_file():
            continue
        try:
            doc = json.loads(doc_path.read_text())
        except ValueError:
            continue
        if _resign(doc, target.name, new, size):
            doc_path.write_text(json.dumps(doc, indent=1))


def _resign(doc: Any, name: str, new: str, size: int) -> bool:
    changed = False
    if isinstance(doc, dict):
        if "sha256" in doc and name in {str(v) for v in doc.values()}:
            doc["sha256"] = new
            for key in ("bytes", "size"):
                if key in doc:
                    doc[key] = size
            changed = True
        for k, v in doc.items():
            if k == name and isinstance(v, str) and len(v) == 64:
                doc[k] = new
                changed = True
            elif k == name and isinstance(v, dict) and "sha256" in v:
                v["sha256"] = new
                changed = True
            else:
                changed |= _resign(v, name, new, size)
    elif isinstance(doc, list):
        for v in doc:
            changed |= _resign(v, name, new, size)
    return changed


def apply(bases: Bases, where: Path, case: dict) -> Path:
    """Apply ``case['mutation']`` to its target in the case folder; returns the target."""
    target = where / case["target"]
    m = case["mutation"]
    op = m["op"]
    if op in mutate.STRUCTURED_OPS:
        value = m.get("value")
        if isinstance(value, str) and value.startswith("$base:"):
            task_name, _, name = value.removeprefix("$base:").partition("/")
            m = {**m, "value": str(base_file(bases, task_name, name))}
        save_doc(target, mutate.apply_structured(load_doc(target), m))
    elif op in mutate.NPZ_OPS:
        mutate.apply_npz(target, m)
    elif op in mutate.CSV_OPS:
        mutate.apply_csv(target, m)
    elif op == "swap":  # another task's file of the same kind
        shutil.copy(bases.tasks[m["with"]].files[target.name], target)
    else:
        mutate.apply_file(target, m, bases.foreign())
    if m.get("resign"):
        resign(where, target)
    return target


# ---------------------------------------------------------------- running


def names_for(case: dict, where: Path, target: Path) -> tuple[str, ...]:
    """What a clear error must contain one of: the file (path or name) or its folder; for a
    training config, also the key."""
    names = [str(target), target.name]
    if target.parent != where:
        names.append(str(target.parent))
    path = case["mutation"].get("path")
    if case["kind"] == "config" and path:
        names.append(".".join(str(p) for p in path if not isinstance(p, int)))
        names.append(str(path[-1]))
    return tuple(names)


def replay(bases: Bases, case: dict, tmp: Path, limit_s: float = 60.0) -> Result:
    """Run one case in the fresh folder ``tmp``; the outcome as :mod:`runner` classifies it,
    ``silent`` where an export's untampered answer changed without a word, or a training
    run ended 0 with a non-finite checkpoint."""
    entry, _, argv = COMMANDS[case["command"]]
    t = bases.tasks[case["task"]]
    where = workspace(bases, case["task"], case["command"], tmp)
    target = apply(bases, where, case)
    result = run(entry, argv(where, t), cwd=where, limit_s=limit_s,
                 names=names_for(case, where, target))
    if result.outcome in ("ok", "flagged"):
        base = bases.baselines.get((case["task"], case["command"]))
        if (case["kind"] == "export" and not case["mutation"].get("resign")
                and base is not None and result.stdout != base):
            result.outcome = "silent"
            result.error = "an edited export answered differently, unflagged and unrefused"
        if case["command"] in ("fit", "resume"):
            last = where / "runs/checkpoints/last.ckpt"
            if last.is_file():
                state = torch.load(last, map_location="cpu", weights_only=True)
                if not all(torch.isfinite(v).all() for v in state["state_dict"].values()
                           if v.is_floating_point()):
                    result.outcome = "silent"
                    result.error = "training ended 0 with a non-finite checkpoint"
    return result


def baseline(bases: Bases, task: str, command: str, tmp: Path) -> Result:
    """The untampered run (its stdout is what an edited export must not change silently)."""
    where = workspace(bases, task, command, tmp)
    entry, _, argv = COMMANDS[command]
    result = run(entry, argv(where, bases.tasks[task]), cwd=where, limit_s=120.0)
    bases.baselines[(task, command)] = result.stdout
    return result


# ---------------------------------------------------------------- drawing cases

FOCUS = ("n_shards", "shards", "file", "index", "sha256", "complete", "scene", "count",
         "samples", "task", "format", "scene_hash", "frame_s", "onset_offset_s",
         "detach_offset_s", "outputs", "domain", "frequency_hz", "n_samples", "sample_rate_hz",
         "classes", "calibration_hz", "inputs", "references", "physical", "max_epochs",
         "shape", "window_s", "data_dir", "accelerator", "hidden", "batch_size", "lr")
"""Keys the readers index: drawn more often."""

SPECIAL = {"accelerator": ["gpu", "tpu", "mps", "auto"],
           "devices": [0, 64, "x"],
           "window_s": [1e-5, 1e-9, 1e3],
           "data_dir": ["$base:radial/data", "$base:fluid/export", "$base:fluid/input.npz",
                        "$base:onset/data", "$base:texture/data"],
           "max_epochs": [0, 10**7, -1],
           "batch_size": [0, 1, 10**9],
           "hidden": [[], [0], [10**6, 10**6]],
           "lr": [-1.0, 0.0, 1e9],
           "val_shards": [0, 3, 100], "test_shards": [0, 3, 100],
           "n_shards": [10**9, 1e9, 0, 2, 5],
           "index": [0, 3, -1, 10**9],
           "file": ["shard-00000.npz", "manifest.json", "../../x.npz", "/dev/zero"],
           "count": [0, 10**9, -1],
           "frame_s": [-1.0, 0.0, 1e9], "onset_offset_s": [mutate.NAN, -1e3],
           "detach_offset_s": [mutate.NAN, 1e3],
           "sample_rate_hz": [1, 0.5, 1e12, -1],
           "n_samples": [0, 1, 10**12, -1],
           "task": ["fluid", "radial", "onset", "texture", "other"],
           "outputs": [[], ["sigma", "distance"], ["rho", "eta"]]}
"""Values worth trying at a key of that name, besides the generic ones."""

NPZ_VALUES = {"sample_rate_hz": [1, 0.5, 1e-300, 1e12, -1, [1.0, 2.0], 4.1e4, 3.3e4],
              "hue0": [0, -1e-3, [1.0, 2.0, 3.0]],
              "frequency_hz": [[1.0], [90.0, 90.0]]}


def base_file(bases: Bases, task: str, target: str) -> Path:
    """The base file behind a case folder's ``target``."""
    head, _, rest = target.partition("/")
    src = bases.tasks[task].files[head]
    return src / rest if rest else src


_DOCS: dict[Path, Any] = {}


def _doc(path: Path) -> Any:
    if path not in _DOCS:
        _DOCS[path] = load_doc(path)
    return _DOCS[path]


def _npz_keys(path: Path) -> list[str]:
    if path not in _DOCS:
        with np.load(path, allow_pickle=False) as data:
            _DOCS[path] = list(data.files)
    return _DOCS[path]


def draw_case(data, bases: Bases, kind: str, slow: bool) -> dict:
    """One case of ``kind`` (hypothesis's ``st.data()`` draws it)."""
    from hypothesis import strategies as st

    tasks = [t for t in PLAN[kind] if t in bases.tasks]
    task = data.draw(st.sampled_from(tasks), label="task")
    commands, targets = PLAN[kind][task]
    fast = [c for c in commands if c not in SLOW_COMMANDS]
    command = data.draw(st.sampled_from(commands if slow or not fast else fast),
                        label="command")
    need = COMMANDS[command][1]
    targets = [t for t in targets if base_file(bases, task, t).exists()
               and t.split("/")[0] in need]
    target = data.draw(st.sampled_from(targets), label="target")
    path = base_file(bases, task, target)
    foreign = sorted(bases.foreign())
    whole = mutate.file_mutation(foreign)
    if path.suffix in (".yaml", ".json", ".ckpt", ".onnx"):
        choices = [mutate.structured(_doc(path), focus=FOCUS, special=SPECIAL)] * 4 + [whole]
        if path.suffix == ".ckpt":
            others = [t for t in bases.tasks if t != task and "last.ckpt" in
                      bases.tasks[t].files]
            if others:
                choices.append(st.sampled_from(others).map(lambda o: {"op": "swap", "with": o}))
    elif path.suffix == ".npz":
        choices = [mutate.npz_mutation(_npz_keys(path), extra=NPZ_VALUES)] * 3 + [whole]
    elif path.suffix == ".csv":
        lines = path.read_text().splitlines()
        choices = [mutate.csv_mutation(len(lines), len(lines[0].split(",")))] * 3 + [whole]
    else:
        choices = [whole]
    m = dict(data.draw(st.one_of(*choices), label="mutation"))
    if target.startswith(("data/", "export/")) and m["op"] not in (
            "missing", "fifo", "devzero", "folder") and data.draw(st.booleans(), label="resign"):
        m["resign"] = True
    return {"kind": kind, "task": task, "command": command, "target": target, "mutation": m}


def signature(case: dict, result: Result) -> str:
    """What tells one failure from another (for the corpus): the outcome, the command, the
    target, and where it broke (the last traceback frame) or the first words of stderr."""
    import re

    where = ""
    if result.outcome == "traceback":
        frames = re.findall(r'File "([^"]+)", line (\d+)', result.error)
        last = result.error.strip().splitlines()[-1:] or [""]
        exc = last[0].split(":")[0]
        where = f"{Path(frames[-1][0]).name}:{frames[-1][1]}:{exc}" if frames else exc
    elif result.outcome in ("multiline", "unnamed", "exit"):
        first = (result.stderr.strip().splitlines() or [""])[0]
        where = re.sub(r"[/\\\w.-]*/[\w.-]+|\d+(\.\d+)?(e-?\d+)?", "#", first)[:50]
    else:
        where = case["mutation"]["op"]
    return f"{result.outcome}|{case['task']}|{case['command']}|{case['target']}|{where}"
