"""The LightningCLI behind ``python train.py`` (and ``wtml pipeline``).

The config names the LightningModule (``model.class_path``), the LightningDataModule
(``data.class_path``) and the run's folder, ``trainer.default_root_dir`` (``runs/<task>``):
the checkpoint goes to ``<root>/checkpoints/last.ckpt`` (after every epoch) and CSV logs to
``<root>/logs/``, so ``--trainer.default_root_dir runs/trial`` makes a trial run that leaves
the trained one alone. A folder that already holds a run is refused unless the command
resumes it (``--ckpt_path``) or asks to replace it (``--overwrite true``).

Progress: epoch lines with the losses, the time spent and an estimate of what is left
(readable in a log); Lightning's progress bar only on a terminal and never under CI.

Bad input ends the command with exit code 2 and one line on stderr, ``train.py: error:
<key>: <what it expects>`` (with the config file's path where the value came from one),
never a usage dump or a traceback: a value of the wrong type, an unknown key or class, a
config file that is missing or not a YAML mapping, a value out of range, a missing or damaged
dataset, a model config for another task than the dataset's, an accelerator this machine does
not have, and a ``--ckpt_path`` that is missing, damaged, of another task or scene, or of a
run already finished. A loss that stops being finite stops the run the same way, naming the
epoch and step, and leaves the last good checkpoint as it was.

A resumed run is the run it resumes: each epoch's data order and torch random state are
drawn from the run's seed and the epoch alone (``wtml.data.datamodule.epoch_seed``), and the
seed comes from the checkpoint, so a run killed after epoch k and resumed ends with the same
weights, bit for bit on CPU, as the run never killed.

Distributed: the same config trains under Lightning's DDP, e.g. ``--trainer.strategy ddp
--trainer.devices 2 --trainer.accelerator cpu`` (gloo) or ``--trainer.num_nodes N`` under
Slurm (``docs/cluster.md``). Every process loads the whole training split, so every one
builds the same net and domain gate from the same statistics; each trains on every
``world_size``-th batch (Lightning's sampler around ``EpochBatches``, the last batches repeated
to even the count), the logged losses are means over all processes, ``train_samples`` their
sum, and only the first process prints progress, writes the logs and the checkpoint. The
radial decoder's two stages each leave the other's weights without a gradient: train it with
``--trainer.strategy ddp_find_unused_parameters_true``.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import logging
import os
import re
import shutil
import sys
import time
import warnings
from pathlib import Path

import lightning as L
import torch
import yaml
from jsonargparse._deprecated import JsonargparseDeprecationWarning
from lightning.fabric.utilities.exceptions import MisconfigurationException
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.loggers import CSVLogger

from wtml.bench.timing import duration
from wtml.cores import available_cores
from wtml.data.shards import DatasetError
from wtml.decoders.base import ConfigError, DivergedError
from wtml.decoders.checkpoint import CheckpointError, read_checkpoint, resume_checkpoint
from wtml.files import FileError, regular_file
from wtml.scenes import SceneError, scene_from_dict, to_dict
from wtml.schema import SchemaError, yaml_load

DEFAULT_ROOT = "runs/default"
CONFIG_MAX_BYTES = 1024**2
"""The largest training config file read (the shipped ones are under 2 kB)."""


class EpochProgress(L.Callback):
    """Prints a line every ``max_epochs // lines`` epochs (and the last): losses, elapsed
    time and an estimate of what is left, flushed, so a log shows it as it happens."""

    def __init__(self, lines: int = 10) -> None:
        self.lines = lines
        self.start = 0.0
        self.first_epoch = 0

    def on_train_start(self, trainer, module) -> None:
        self.start, self.first_epoch = time.perf_counter(), trainer.current_epoch
        if not trainer.is_global_zero:  # DDP: one process speaks for all
            return
        tensors = getattr(trainer.datamodule, "train_tensors", None)
        size = f"{len(tensors()[0])} training samples, " if tensors else ""
        if trainer.world_size > 1:
            size += f"{trainer.world_size} processes, "
        print(f"training {type(module).__name__}: {size}epochs {trainer.current_epoch + 1}-"
              f"{trainer.max_epochs}, checkpoint {Path(trainer.default_root_dir)}/checkpoints/"
              "last.ckpt", flush=True)

    def on_train_epoch_end(self, trainer, module) -> None:
        epoch, total = trainer.current_epoch + 1, trainer.max_epochs
        every = max(1, total // self.lines)
        if not trainer.is_global_zero or epoch % every and epoch != total:
            return
        elapsed = time.perf_counter() - self.start
        done = epoch - self.first_epoch
        left = elapsed / done * (total - epoch) if done else float("nan")
        metrics = sorted(trainer.callback_metrics.items())
        losses = "  ".join(f"{k} {float(v):.4g}" for k, v in metrics if k.endswith("_loss"))
        print(f"epoch {epoch:>4}/{total}  {losses}  {duration(elapsed)} elapsed, "
              f"~{duration(left)} left", flush=True)


class WtmlCLI(LightningCLI):
    """LightningCLI with the run folder, its guard, range checks and progress (module
    docstring)."""

    def add_arguments_to_parser(self, parser) -> None:
        parser.add_argument("--overwrite", type=bool, default=False,
                            help="replace a run already in trainer.default_root_dir "
                                 "(default: refuse, and say how to resume it)")

    def _parse_ckpt_path(self) -> None:
        """``--ckpt_path`` read through :func:`resume_checkpoint` (one line for a file that is
        missing, damaged, unsafe, not wtml's or of another task than the model's), then as
        LightningCLI does: the model's arguments are the checkpoint's. The run's seed is
        the checkpoint's too, so each epoch draws what the interrupted run would have."""
        sub = self.config.get("subcommand")
        if not sub or not self.config[sub].get("ckpt_path"):
            return
        config = self.config[sub]
        path = config["ckpt_path"]
        task = getattr(_model_class(config), "TASK", "") or None
        state = (resume_checkpoint if sub == "fit" else read_checkpoint)(path, task)
        self._resumed = state
        seed = state["wtml"].get("seed", -1)
        if seed >= 0 and config.get("seed_everything") is not False:
            config["seed_everything"] = seed
        hparams = state.get("hyper_parameters") or {}
        if not isinstance(hparams, dict):
            raise CheckpointError(f"{path}: hyper_parameters: must be a mapping of the model's "
                                  f"arguments, got {type(hparams).__name__}")
        hparams = dict(hparams)
        hparams.pop("_instantiator", None)
        hparams.pop("_class_path", None)
        if hparams:
            hparams = resumed_arguments(_model_class(config), hparams)
            try:
                self.config = self.parser.parse_object({sub: {"model": {
                    "class_path": config["model"]["class_path"], "init_args": hparams}}},
                    self.config)
            except (argparse.ArgumentError, TypeError, KeyError, ValueError) as err:
                raise CheckpointError(f"{path}: hyper_parameters: "
                                      f"{usage_line(str(err), [], [])}") from None

    def fit(self, **kwargs) -> None:
        """``trainer.fit``; a resumed checkpoint whose trainer state Lightning cannot restore
        (a crafted or damaged ``loops``, ``optimizer_states``, ...) ends in one line naming
        it, not in Lightning's traceback."""
        path = kwargs.get("ckpt_path")
        try:
            self.trainer.fit(**kwargs)
        except (KeyError, IndexError, TypeError, ValueError, RuntimeError, AttributeError) as err:
            if not path or _our_error(err) is not None \
                    or self.trainer.global_step > self._resumed["global_step"]:
                raise
            first = (str(err).splitlines() or [""])[0][:160]
            raise CheckpointError(f"{path}: its trainer state cannot be restored "
                                  f"({type(err).__name__}: {first}); resume from another "
                                  "checkpoint or start a new run") from None

    def before_instantiate_classes(self) -> None:
        config = self.config.get(str(self.subcommand), self.config)
        trainer = config.get("trainer", {})
        epochs = trainer.get("max_epochs")
        if epochs is not None and not 1 <= epochs <= 10**6:
            raise ConfigError(f"trainer.max_epochs must be in [1, 1000000], got {epochs}")
        trainer["default_root_dir"] = str(trainer.get("default_root_dir") or DEFAULT_ROOT)
        _check_accelerator(trainer.get("accelerator"))
        if self.subcommand in ("fit", "validate", "test") and config.get("data") is None:
            raise ConfigError("data: missing; a training config names its dataset "
                              "(data.class_path: wtml.data.ShardDataModule, "
                              "data.init_args.data_dir: a folder of wtml generate)")

    def after_instantiate_classes(self) -> None:
        """The model's task against the dataset's, a resumed checkpoint against the run, and
        the run folder's guard, once every value has passed its own check."""
        config = self.config.get(str(self.subcommand), self.config)
        model, data = self.model, self.datamodule
        scene = getattr(data, "scene", None)
        task = getattr(model, "TASK", "")
        if scene is not None and task and scene.task != task:
            raise ConfigError(
                f"model.class_path: {type(model).__module__}.{type(model).__name__} decodes "
                f"the {task} task, but data.init_args.data_dir {data.data_dir} holds a "
                f"{scene.task} dataset; train it with configs/{scene.task}.yaml, or give "
                f"{task} data")
        if self.subcommand != "fit":
            return
        if config.get("ckpt_path"):
            self._check_resume(config)
            return
        root = Path(config["trainer"]["default_root_dir"])
        last = root / "checkpoints" / "last.ckpt"
        if not last.exists():
            return
        if config.get("overwrite"):
            if self.trainer.is_global_zero:  # one remover: DDP processes that srun starts
                shutil.rmtree(root / "checkpoints")
            return
        try:
            state = read_checkpoint(last)
            done = f"epoch {state.get('epoch', -1) + 1} of {state['wtml'].get('max_epochs')}"
        except CheckpointError:
            done = "unreadable"
        raise ConfigError(
            f"{last}: a run is already there ({done}); resume it with --ckpt_path {last}, "
            "start another with --trainer.default_root_dir runs/<name>, or replace it with "
            "--overwrite true")

    def _check_resume(self, config) -> None:
        """The checkpoint's scene is the dataset's, and its run is the one asked for and not
        finished."""
        path, state = config["ckpt_path"], self._resumed
        info = state["wtml"]
        data = self.datamodule
        if to_dict(scene_from_dict(info["scene"])) != getattr(data, "scene_dict", None):
            raise CheckpointError(
                f"{path}: trained on another scene than data.init_args.data_dir "
                f"{data.data_dir}'s; resume it on the dataset it was trained on, or start "
                "a new run (--trainer.default_root_dir runs/<name>)")
        epochs = config["trainer"].get("max_epochs")
        if epochs != info["max_epochs"]:
            raise CheckpointError(
                f"{path}: trainer.max_epochs: {epochs} here, {info['max_epochs']} in the run "
                "it resumes (its learning-rate schedule is laid out over that); resume with "
                f"--trainer.max_epochs {info['max_epochs']}")
        processes, here = info.get("world_size", 1), self.trainer.world_size
        if processes != here:
            raise CheckpointError(
                f"{path}: trained on {processes} process(es), resumed on {here} (an epoch's "
                "steps, and so its learning-rate schedule, depend on it); resume with as many "
                "(--trainer.devices times --trainer.num_nodes)")
        if state["epoch"] + 1 >= info["max_epochs"]:
            raise CheckpointError(
                f"{path}: a finished run (epoch {state['epoch'] + 1} of {info['max_epochs']}): "
                "nothing to resume; instead of --ckpt_path, start a new run with "
                "--trainer.default_root_dir runs/<name>, or train this one again with "
                "--overwrite true")

    def instantiate_trainer(self, **kwargs):
        config = self._get(self.config_init, "trainer", default={})
        root = Path(config["default_root_dir"])  # set by before_instantiate_classes
        if config.get("logger") in (None, True):
            kwargs["logger"] = CSVLogger(save_dir=root, name="logs")
        callbacks = [self._get(self.config_init, c)
                     for c in self._parser(self.subcommand).callback_keys]
        callbacks += [ModelCheckpoint(dirpath=root / "checkpoints", filename="last",
                                      save_top_k=1, enable_version_counter=False),
                      EpochProgress()]
        try:
            return self._instantiate_trainer({**config, **kwargs}, callbacks)
        except (MisconfigurationException, ValueError, TypeError, RuntimeError) as err:
            if isinstance(err, ConfigError):
                raise
            text = " ".join(str(err).split())
            names = inspect.signature(L.Trainer.__init__).parameters
            key = next((k for pattern in (r"[`(]{}\b|\b{}=", r"\b{}\b") for k in names
                        if re.search(pattern.format(k, k), text)), None)
            raise ConfigError(f"trainer{'.' + key if key else ''}: {text[:300]}") from None


def resumed_arguments(cls: type, hparams: dict) -> dict:
    """The model arguments of a run resumed from a checkpoint whose ``hyper_parameters`` are
    ``hparams``: those, and for an argument the decoder gained after the checkpoint was saved
    the value it was trained without (``cls.LEGACY_HPARAMS``), not the config's default."""
    return {**getattr(cls, "LEGACY_HPARAMS", {}), **hparams}


def _model_class(config) -> type:
    """The LightningModule class the config names (``model.class_path``)."""
    path = str(config["model"]["class_path"])
    module, _, name = path.rpartition(".")
    return getattr(importlib.import_module(module), name)


def _check_accelerator(accelerator) -> None:
    """Refuse an accelerator this machine does not have, in one line naming it."""
    if not isinstance(accelerator, str):
        return
    name = accelerator.lower()
    have = {"gpu": torch.cuda.is_available() or torch.backends.mps.is_available(),
            "cuda": torch.cuda.is_available(), "mps": torch.backends.mps.is_available()}
    if name in have and not have[name]:
        raise ConfigError(f"trainer.accelerator: {accelerator!r} asks for a GPU, and torch "
                          "finds none on this machine; use cpu (or auto: a GPU where there is "
                          "one)")


def _our_error(err: BaseException) -> BaseException | None:
    """The wtml error behind ``err`` (jsonargparse wraps what a class raises when it is
    instantiated), or None when it is none of ours."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, ConfigError | DatasetError | SceneError | CheckpointError
                      | DivergedError | FileError | SchemaError):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None


def _config_files(argv: list[str]) -> list[str]:
    """The config files ``argv`` names with ``-c``/``--config``, in order."""
    files = []
    for k, arg in enumerate(argv):
        if arg in ("-c", "--config") and k + 1 < len(argv):
            files.append(argv[k + 1])
        elif arg.startswith("--config="):
            files.append(arg.split("=", 1)[1])
    return files


def check_config_file(path: str) -> dict:
    """A training config file as a mapping: a regular file of at most
    :data:`CONFIG_MAX_BYTES` holding a YAML mapping.

    Raises:
        FileError: one line naming the file and what is wrong.
    """
    regular_file(path, what="training config", max_bytes=CONFIG_MAX_BYTES)
    try:
        data = yaml_load(Path(path).read_text())
    except UnicodeDecodeError:
        raise FileError(f"{path}: not a text file; a training config is YAML "
                        "(configs/<task>.yaml)") from None
    except yaml.YAMLError as err:
        mark = getattr(err, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(err, "problem", None) or "cannot be parsed"
        raise FileError(f"{path}: not YAML ({problem}{where})") from None
    if not isinstance(data, dict):
        raise FileError(f"{path}: a training config is a YAML mapping of model, data, trainer "
                        f"and seed_everything (configs/<task>.yaml), got {type(data).__name__}")
    return data


_KEY = re.compile(r'^\s*(?:- )?Parser key "([^"]+)":')
_CLASS = re.compile(r"^\s*(?:- )?Problem with given class_path '([^']+)':")


def _tree(lines: list[str]) -> list:
    """Lines nested by indentation: ``[(text, children), ...]``."""
    root: list = []
    stack = [(-1, root)]
    for line in lines:
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip(" -"))
        while stack[-1][0] >= indent:
            stack.pop()
        node = (line.strip(), [])
        stack[-1][1].append(node)
        stack.append((indent, node[1]))
    return root


def _walk(nodes: list):
    for text, children in nodes:
        yield text, children
        yield from _walk(children)


def _type_name(text: str) -> str:
    """``<class 'int'>`` as ``int``, NoneType as null, a class path by its last name."""
    text = re.sub(r"<class '(?:[\w.]+\.)?(\w+)'>", r"\1", text)
    text = re.sub(r"typing\.Literal\[([^\]]*)\]", r"one of \1", text)
    text = re.sub(r"\b(?:[a-z_]\w*\.)+([A-Z]\w*)", r"\1", text)
    return text.replace("NoneType", "null")


def _given(text: str) -> str:
    """A 'Given value' as the user wrote it (NestedArg's ``val``)."""
    nested = re.fullmatch(r"NestedArg\(key='[^']*', val='(.*)'\)", text)
    return repr(nested[1] if nested else text)[:80]


def _explain(nodes: list, key: list[str]) -> tuple[list[str], str]:
    """The deepest key of a jsonargparse error tree and what it expects."""
    for text, children in _walk(nodes):
        found = _KEY.match(text)
        if found:
            return _explain(children, [*key, *found[1].split(".")])
        cls = _CLASS.match(text)
        if cls:
            inner = [t for t, _ in _walk(children)]
            if any(_KEY.match(t) for t in inner):
                return _explain(children, [*key, "init_args"])
            option = re.search(r"Option '([^']+)' is not accepted", " ".join(inner))
            if option:
                return ([*key, "init_args", option[1]],
                        f"not an argument of {cls[1]}")
            return [*key, "class_path"], f"cannot use {cls[1]!r}: {' '.join(inner)[:200]}"
    texts = [t for t, _ in _walk(nodes)]
    subtypes = next((t.split(":", 1)[1].strip()[1:-1] for t in texts
                     if t.startswith("Subtypes:")), None)
    given = next((t.split(":", 1)[1].strip() for t in texts if t.startswith("Given value:")),
                 None)
    if subtypes is not None:
        kinds = [_type_name(k.strip()) for k in re.split(r",\s*(?![^\[]*\])", subtypes)]
        return key, f"expected {' or '.join(kinds)}" + (f", got {_given(given)}" if given else "")
    for text in texts:
        m = re.match(r"Expected a (.*?)\. Got value: (.*)", text)
        if m:
            return key, f"expected {_type_name(m[1])}, got {_given(m[2])}"
    return key, "; ".join(texts)[:300] or "invalid value"


def usage_line(message: str, argv: list[str], configs: list[str]) -> str:
    """jsonargparse's error ``message`` (a usage error: unknown key, wrong type, bad class
    path, ...) as one line, ``<key>: <what it expects>``, prefixed with the config file the
    key came from when it did not come from the command line ``argv``."""
    lines = message.strip().splitlines() or ["invalid arguments"]
    first = lines[0]
    unknown = re.match(r"unrecognized arguments: (.*)", first)
    if unknown:
        words = unknown[1].split()
        option = next((w for w in words if w.startswith("-")), words[0] if words else "?")
        return (f"{option.split('=')[0]}: not an option of train.py "
                f"{argv[0] if argv else ''}; see train.py fit --help".replace("  ", " "))
    refused = re.match(r"Subcommand '(\w+)' does not accept option '([^']+)'", first)
    if refused:
        key, what = refused[2].split("."), f"not an option of train.py {refused[1]}"
    elif (m := re.match(r"argument (\S+): (.*)", first)):
        option = m[1]
        if m[2].startswith("expected one argument"):  # jsonargparse names the group only
            option = next((a for k, a in enumerate(argv) if a.startswith(option) and (
                k + 1 == len(argv) or argv[k + 1].startswith("--"))), option)
        key, what = option.lstrip("-").split("="), m[2]
        key = key[0].split(".")
    elif (m := re.match(r"the following arguments are required: (.*)", first)):
        keys = [k.strip().removeprefix("fit.") for k in m[1].split(",")]
        where = f"{configs[-1]}: " if configs else ""
        return (f"{where}{keys[0]}: missing; a training config names its model and data "
                "(model.class_path, data.class_path and data.init_args.data_dir: see "
                "configs/<task>.yaml)")
    elif (m := re.match(r'expected "subcommand" to be one of \{([^}]*)\}', first)):
        return (f"subcommand: expected one of {m[1]} (train.py fit --config "
                "configs/<task>.yaml)")
    elif _KEY.match(first):
        key, what = _explain(_tree(lines), [])
    else:
        return " ".join(" ".join(lines).split())[:300]
    dotted = ".".join(key)
    return f"{_source(key, argv, configs)}{dotted}: {what}"


def _source(key: list[str], argv: list[str], configs: list[str]) -> str:
    """``"<config file>: "`` when the value of ``key`` came from a config file: the last of
    ``argv``'s options and config files that sets it."""
    short = [k for k in key if k != "init_args"]
    source = ""
    for k, arg in enumerate(argv):
        if arg in ("-c", "--config") or arg.startswith("--config="):
            path = arg.split("=", 1)[1] if "=" in arg else argv[k + 1] if k + 1 < len(argv) else ""
            if _sets(path, key):
                source = f"{path}: "
        elif arg.startswith("--"):
            given = [w for w in arg[2:].split("=")[0].split(".") if w != "init_args"]
            n = min(len(given), len(short))
            if given[:n] == short[:n]:
                source = ""
    return source


def _sets(path: str, key: list[str]) -> bool:
    """Whether the YAML file ``path`` sets ``key`` (``init_args`` levels optional)."""
    try:
        node = yaml_load(Path(path).read_text())
    except (OSError, ValueError, yaml.YAMLError):
        return False
    for k in key:
        if isinstance(node, dict) and k in node:
            node = node[k]
        elif k != "init_args":
            return False
    return True


def cli_main(args: list[str] | None = None, run: bool = True) -> WtmlCLI:
    """Run the CLI with wtml's trainer defaults; ``args`` as on the command line.

    Raises:
        SystemExit: code 2 with one line on stderr (the module docstring's cases).
    """
    trainer_defaults = {
        "enable_progress_bar": sys.stderr.isatty() and not os.environ.get("CI"),
        "enable_model_summary": False,
    }
    given = list(sys.argv[1:] if args is None else args)
    try:  # torch's own default is the machine's cores, whatever a container's quota allows
        torch.set_num_threads(min(torch.get_num_threads(), available_cores()))
    except ValueError as err:  # $WTML_THREADS not a positive integer
        print(f"train.py: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    configs = _config_files(given)
    try:
        for path in configs:
            check_config_file(path)
    except FileError as err:
        print(f"train.py: error: {err}", file=sys.stderr)
        raise SystemExit(2) from None
    argv, sys.argv = sys.argv, sys.argv[:1] if args is not None else sys.argv
    # Lightning's info lines (GPU/TPU availability, tips, "Seed set to 0"): not our output
    quiet = [logging.getLogger(name) for name in ("lightning.pytorch.utilities.rank_zero",
                                                  "lightning.fabric.utilities.seed")]
    levels = [q.level for q in quiet]
    for q in quiet:
        q.setLevel(logging.WARNING)
    try:
        with warnings.catch_warnings():
            # lightning 2.6's LightningCLI calls an API that jsonargparse deprecates
            warnings.filterwarnings("ignore", category=JsonargparseDeprecationWarning)
            # lightning's pytree helper calls a torch API that torch 2.13 deprecates
            warnings.filterwarnings("ignore", message=r"`isinstance\(treespec, LeafSpec\)`",
                                    category=FutureWarning)
            # a small dataset has fewer batches than the logging interval: not a problem
            warnings.filterwarnings("ignore", message=r"The number of training batches .* is "
                                                      r"smaller than the logging interval")
            # a run resumed into another folder than its own: its best-model bookkeeping,
            # which wtml does not use (one last.ckpt), starts afresh there
            warnings.filterwarnings("ignore", message=r"The dirpath has changed from")
            # a resumed run writes into its own checkpoint folder, as it should
            warnings.filterwarnings("ignore", message=r"Checkpoint directory .* exists and is "
                                                      r"not empty")
            return WtmlCLI(subclass_mode_model=True, subclass_mode_data=True,
                           trainer_defaults=trainer_defaults, args=args, run=run,
                           parser_kwargs={"exit_on_error": False})
    except argparse.ArgumentError as err:
        print(f"train.py: error: {usage_line(str(err), given, configs)}", file=sys.stderr)
        raise SystemExit(2) from None
    except ValueError as err:
        ours = _our_error(err)
        if ours is None:
            raise
        print(f"train.py: error: {ours}", file=sys.stderr)
        raise SystemExit(2) from None
    finally:
        sys.argv = argv
        for q, level in zip(quiet, levels, strict=True):
            q.setLevel(level)
