"""What every task's LightningModule shares: building the net and its domain gate at
``setup``, steps, logging, the optimiser and its schedule, and rebuilding shapes from a
checkpoint."""

from __future__ import annotations

from abc import ABC, abstractmethod

import lightning as L
import torch

from wtml.decoders.domain import DomainGate


class ConfigError(ValueError):
    """A training-config value out of its allowed range (the message names the key)."""


def check_positive(name: str, value: float, high: float = float("inf")) -> None:
    """Raise :class:`ConfigError` unless ``0 < value < high`` (``name`` as in the config)."""
    if isinstance(value, bool) or not isinstance(value, int | float) or not 0 < value < high:
        raise ConfigError(f"{name} must be in (0, {high:g}), got {value!r}")


def check_widths(name: str, widths: list[int]) -> None:
    """Raise :class:`ConfigError` unless ``widths`` is a list of layer widths in [1, 65536]."""
    if not isinstance(widths, list | tuple) or not all(
            isinstance(w, int) and not isinstance(w, bool) and 1 <= w <= 65536 for w in widths):
        raise ConfigError(f"{name} must be a list of layer widths in [1, 65536], got {widths!r}")


class DecoderModule(L.LightningModule, ABC):
    """Subclasses build their net in :meth:`build_net` (from the training data) and in
    :meth:`build_from_checkpoint` (shapes only), name the gate's input features in
    :meth:`domain_features`, and implement :meth:`loss`.

    Args:
        lr: peak learning rate (one-cycle schedule over the run).
        weight_decay: AdamW weight decay.
    """

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

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["wtml"] = {"scene": self.scene, "shape": self.net_shape(),
                              "max_epochs": self.trainer.max_epochs}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        from wtml.scenes import scene_from_dict

        self.scene = checkpoint["wtml"]["scene"]
        if self.net is None:  # shapes only: the state dict brings the values
            self.build_from_checkpoint(checkpoint["wtml"]["shape"])
            self.gate = self.make_gate(scene_from_dict(self.scene))

    def _step(self, batch, stage: str) -> torch.Tensor:
        loss = self.loss(batch)
        self.log(f"{stage}_loss", loss, prog_bar=stage == "val", on_epoch=True,
                 on_step=False, batch_size=len(batch[0]))
        return loss

    def training_step(self, batch, batch_idx):
        return self._step(batch, "train")

    def validation_step(self, batch, batch_idx):
        self._step(batch, "val")

    def test_step(self, batch, batch_idx):
        self._step(batch, "test")

    def configure_optimizers(self):
        opt = torch.optim.AdamW(self.parameters(), lr=self.hparams.lr,
                                weight_decay=self.hparams.weight_decay)
        sched = torch.optim.lr_scheduler.OneCycleLR(
            opt, max_lr=self.hparams.lr, total_steps=self.trainer.estimated_stepping_batches)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "step"}}
