"""The LightningCLI behind ``python train.py`` (and ``wtml pipeline``).

The config names the LightningModule (``model.class_path``), the LightningDataModule
(``data.class_path``) and the run's folder, ``trainer.default_root_dir`` (``runs/<task>``):
the checkpoint goes to ``<root>/checkpoints/last.ckpt`` (after every epoch) and CSV logs to
``<root>/logs/``, so ``--trainer.default_root_dir runs/trial`` makes a trial run that leaves
the trained one alone. A folder that already holds a run is refused unless the command
resumes it (``--ckpt_path``) or asks to replace it (``--overwrite true``).

Progress: epoch lines with the losses, the time spent and an estimate of what is left
(readable in a log); Lightning's progress bar only on a terminal and never under CI. Values
out of range and a missing dataset end the command with one line naming the key, exit code 2.
"""

from __future__ import annotations

import logging
import os
import shutil
import sys
import time
import warnings
from pathlib import Path

import lightning as L
from jsonargparse._deprecated import JsonargparseDeprecationWarning
from lightning.pytorch.callbacks import ModelCheckpoint
from lightning.pytorch.cli import LightningCLI
from lightning.pytorch.loggers import CSVLogger

from wtml.data.shards import DatasetError
from wtml.decoders.base import ConfigError
from wtml.decoders.checkpoint import CheckpointError, read_checkpoint
from wtml.scenes import SceneError

DEFAULT_ROOT = "runs/default"


def duration(seconds: float) -> str:
    """``12.3 s`` or ``4 min 05 s``."""
    if not seconds < 60:
        return f"{int(seconds // 60)} min {int(seconds % 60):02d} s" if seconds == seconds else "?"
    return f"{seconds:.1f} s"


class EpochProgress(L.Callback):
    """Prints a line every ``max_epochs // lines`` epochs (and the last): losses, elapsed
    time and an estimate of what is left, flushed, so a log shows it as it happens."""

    def __init__(self, lines: int = 10) -> None:
        self.lines = lines
        self.start = 0.0
        self.first_epoch = 0

    def on_train_start(self, trainer, module) -> None:
        self.start, self.first_epoch = time.perf_counter(), trainer.current_epoch
        tensors = getattr(trainer.datamodule, "train_tensors", None)
        size = f"{len(tensors()[0])} training samples, " if tensors else ""
        print(f"training {type(module).__name__}: {size}epochs {trainer.current_epoch + 1}-"
              f"{trainer.max_epochs}, checkpoint {Path(trainer.default_root_dir)}/checkpoints/"
              "last.ckpt", flush=True)

    def on_train_epoch_end(self, trainer, module) -> None:
        epoch, total = trainer.current_epoch + 1, trainer.max_epochs
        every = max(1, total // self.lines)
        if epoch % every and epoch != total:
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

    def before_instantiate_classes(self) -> None:
        config = self.config.get(str(self.subcommand), self.config)
        trainer = config.get("trainer", {})
        epochs = trainer.get("max_epochs")
        if epochs is not None and not 1 <= epochs <= 10**6:
            raise ConfigError(f"trainer.max_epochs must be in [1, 1000000], got {epochs}")
        trainer["default_root_dir"] = str(trainer.get("default_root_dir") or DEFAULT_ROOT)

    def after_instantiate_classes(self) -> None:
        """The run folder's guard, once every value has passed its own check."""
        config = self.config.get(str(self.subcommand), self.config)
        if self.subcommand != "fit":
            return
        root = Path(config["trainer"]["default_root_dir"])
        last = root / "checkpoints" / "last.ckpt"
        if not last.exists() or config.get("ckpt_path"):
            return
        if config.get("overwrite"):
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
        return self._instantiate_trainer({**config, **kwargs}, callbacks)


def _our_error(err: BaseException) -> BaseException | None:
    """The wtml error behind ``err`` (jsonargparse wraps what a class raises when it is
    instantiated), or None when it is none of ours."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, ConfigError | DatasetError | SceneError | CheckpointError):
            return err
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return None


def cli_main(args: list[str] | None = None, run: bool = True) -> WtmlCLI:
    """Run the CLI with wtml's trainer defaults; ``args`` as on the command line.

    Raises:
        SystemExit: code 2 with one line on stderr for a value out of range, a missing or
            damaged dataset or scene, or a run folder that is taken.
    """
    trainer_defaults = {
        "enable_progress_bar": sys.stderr.isatty() and not os.environ.get("CI"),
        "enable_model_summary": False,
    }
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
            # a resumed run writes into its own checkpoint folder, as it should
            warnings.filterwarnings("ignore", message=r"Checkpoint directory .* exists and is "
                                                      r"not empty")
            return WtmlCLI(subclass_mode_model=True, subclass_mode_data=True,
                           trainer_defaults=trainer_defaults, args=args, run=run)
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
