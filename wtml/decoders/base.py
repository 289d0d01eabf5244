"""What every task's LightningModule shares: building the net and its domain gate at
``setup``, steps, logging, the optimiser and its schedule, and rebuilding shapes from a
checkpoint."""

from __future__ import annotations

import math
import os
from abc import ABC, abstractmethod
from pathlib import Path

import lightning as L
import torch

from wtml.data.datamodule import epoch_seed
from wtml.decoders.domain import DomainGate


class ConfigError(ValueError):
    """A training-config value out of its allowed range (the message names the key)."""


class DivergedError(ValueError):
    """A training or validation loss that is not finite: the run stops, and its last good
    checkpoint stays as it was."""


PARAMETER_CEILING = 2 * 1024**3 // 16
"""The most parameters a net may have: each costs 16 bytes in training (float32 weight,
gradient and AdamW's two moments), and the stated memory ceiling is 2 GiB
(``wtml.files.MEMORY_CEILING``)."""


def check_positive(name: str, value: float, high: float = float("inf")) -> None:
    """Raise :class:`ConfigError` unless ``0 < value < high`` (``name`` as in the config)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < high:
        raise ConfigError(f"{name} must be in (0, {high:g}), got {value!r}")


def check_widths(name: str, widths: list[int]) -> None:
    """Raise :class:`ConfigError` unless ``widths`` is a list of layer widths in [1, 65536]
    whose weights between them stay under :data:`PARAMETER_CEILING`."""
    if not isinstance(widths, list | tuple) or not all(
            isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= 65536 for w in widths):
        raise ConfigError(f"{name} must be a list of layer widths in [1, 65536], "
                          f"got {widths!r:.80}")
    weights = sum(a * b for a, b in zip(widths[:-1], widths[1:], strict=True))
    if weights > PARAMETER_CEILING:
        raise ConfigError(f"{name} {list(widths)!r:.80} makes {weights:.3g} weights between "
                          f"its layers, over the {PARAMETER_CEILING:.3g} that train in the 2 GiB "
                          "memory ceiling (16 bytes each with AdamW)")


class DecoderModule(L.LightningModule, ABC):
    """Subclasses build their net in :meth:`build_net` (from the training data) and in
    :meth:`build_from_checkpoint` (shapes only), name the gate's input features in
    :meth:`domain_features`, and implement :meth:`loss`; ``TASK`` names the scene task
    whose datasets they train on.

    Each training epoch starts from a torch random state drawn from the run's seed and the
    epoch (:func:`wtml.data.datamodule.epoch_seed`), as the training data's order is: a run
    resumed from a checkpoint continues as the run never interrupted would have. A loss that
    is not finite stops the run (:class:`DivergedError`) before anything is saved.

    Args:
        lr: peak learning rate (one-cycle schedule over the run).
        weight_decay: AdamW weight decay.
    """

    TASK = ""
    LEGACY_HPARAMS: dict = {}
    """Model arguments that a checkpoint saved before they existed was trained without, and
    the value that rebuilds it so (``{argument: value}``): a run resumed from such a
    checkpoint takes these, not the config's (:func:`wtml.training.resumed_arguments`)."""

    def __init__(self, lr: float, weight_decay: float) -> None:
        super().__init__()
        check_positive("model.lr", lr, 10.0)
        if isinstance(weight_decay, bool) or not 0 <= weight_decay < 1:
            raise ConfigError(f"model.weight_decay must be in [0, 1), got {weight_decay!r}")
        self.net: torch.nn.Module | None = None
        self.gate: DomainGate | None = None
        self.scene: dict | None = None

    @abstractmethod
    def build_net(self, scene, *tensors: torch.Tensor) -> torch.nn.Module:
        """The net for ``scene``, its normalisation fitted to the training tensors (the
        inputs, then the targets)."""

    @abstractmethod
    def domain_features(self, scene) -> tuple[torch.nn.Module, int]:
        """The domain gate's input-feature layer for ``scene`` and its number of features."""

    @abstractmethod
    def loss(self, batch) -> torch.Tensor:
        """The training loss of a batch ``(*inputs, targets)`` (``ze_re, ze_im`` and the task's
        references: ``t_re, t_im`` for fluid, ``ref_re, ref_im`` for radial; or ``e, i``)."""

    @abstractmethod
    def net_shape(self) -> dict:
        """What ``build_from_checkpoint`` needs to rebuild the net's shapes."""

    @abstractmethod
    def build_from_checkpoint(self, shape: dict) -> None:
        """Create ``self.net`` with the shapes of ``net_shape()`` (values come after)."""

    def make_gate(self, scene) -> DomainGate:
        """An unfitted :class:`DomainGate` for ``scene``: this task's features, and the
        trained range (with its margin) of each output the scene declares a range for."""
        features, n_feat = self.domain_features(scene)
        declared = scene.output_ranges()
        ranges = {k: declared[name].widened() for k, name in enumerate(scene.OUTPUTS)
                  if name in declared}
        absent = tuple(k for k, name in enumerate(scene.OUTPUTS)
                       if name in declared and declared[name].absent_ok)
        return DomainGate(features, n_feat, ranges, absent)

    def setup(self, stage: str) -> None:
        if self.net is not None:
            return
        dm = self.trainer.datamodule
        *inputs, targets = dm.train_tensors()
        self.net = self.build_net(dm.scene, *inputs, targets)
        self.scene = dm.scene_dict
        self.gate = self.make_gate(dm.scene).fit(*self.gate_inputs(*inputs))

    def gate_inputs(self, *inputs: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The training inputs the domain gate is fitted on (after :meth:`build_net`): the
        training tensors themselves, unless a task feeds its net pieces of them."""
        return inputs

    def on_train_epoch_start(self) -> None:
        torch.manual_seed(epoch_seed(self.current_epoch))

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        for name, value in checkpoint["state_dict"].items():
            if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                raise DivergedError(self._diverged(f"the weights' {name} hold NaN or infinite "
                                                   "values"))
        checkpoint["wtml"] = {"scene": self.scene, "shape": self.net_shape(),
                              "max_epochs": self.trainer.max_epochs,
                              "seed": int(os.environ.get("PL_GLOBAL_SEED", -1)),
                              "world_size": self.trainer.world_size}

    def _diverged(self, what: str) -> str:
        """The one line a diverged run ends with: where, what, and the checkpoint kept."""
        last = Path(self.trainer.default_root_dir) / "checkpoints" / "last.ckpt"
        kept = (f"{last} (after epoch {self.current_epoch}) is kept as it was"
                if last.exists() else "no checkpoint was written")
        return (f"epoch {self.current_epoch + 1}, step {self.global_step}: {what}; the run "
                f"stopped and {kept}. Lower model.init_args.lr ({self.hparams.lr:g}) or check "
                "the data")

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """Shapes from the checkpoint (its state dict, loaded next, brings the values), and
        the outputs' trained ranges as this version states them for the checkpoint's scene:
        a range is the scene's and its margin, not something training learns, so a
        checkpoint saved before a margin changed exports the range its metadata states."""
        from wtml.scenes import scene_from_dict

        self.scene = checkpoint["wtml"]["scene"]
        if self.net is None:  # resuming, setup has built both from the same scene
            self.build_from_checkpoint(checkpoint["wtml"]["shape"])
            self.gate = self.make_gate(scene_from_dict(self.scene))
        state = checkpoint.get("state_dict", {})
        for name in ("low", "high"):
            if f"gate.{name}" in state:
                state[f"gate.{name}"] = getattr(self.gate, name).clone()

    def _step(self, batch, stage: str) -> torch.Tensor:
        loss = self.loss(batch)
        # L-BFGS's line search may try a step whose loss overflows, and step back from it
        search = stage == "train" and isinstance(self.optimizers(use_pl_optimizer=False),
                                                 torch.optim.LBFGS)
        if stage != "test" and not search and not math.isfinite(float(loss.detach())):
            which = "training" if stage == "train" else "validation"
            raise DivergedError(self._diverged(f"the {which} loss is {float(loss.detach())}"))
        # sync_dist: under DDP, the mean over every process's batches, not rank 0's alone
        self.log(f"{stage}_loss", loss, prog_bar=stage == "val", on_epoch=True,
                 on_step=False, batch_size=len(batch[0]), sync_dist=True)
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def on_train_batch_end(self, outputs, batch, batch_idx) -> None:
        """Logs ``train_samples``: the samples of the epoch's batches, summed over the DDP
        processes (once per batch, however many times L-BFGS evaluates it)."""
        self.log("train_samples", float(len(batch[0])), on_epoch=True, on_step=False,
                 reduce_fx="sum", sync_dist=True)

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def test_step(self, batch, batch_idx):
        self._step(batch, "test")

    def one_cycle(self, total_steps: int) -> tuple[torch.optim.Optimizer,
                                                   torch.optim.lr_scheduler.LRScheduler]:
        """AdamW over the module's parameters (``lr``, ``weight_decay``) and its one-cycle
        schedule of ``total_steps`` steps, peaking at ``lr``: every decoder's recipe (also
        run outside Lightning, by ``wtml bench texture-scale``)."""
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr,
                                weight_decay=self.hparams.weight_decay)
        sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=self.hparams.lr,
                                                    total_steps=total_steps)
        return opt, sched

    def configure_optimizers(self):
        opt, sched = self.one_cycle(self.trainer.estimated_stepping_batches)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
