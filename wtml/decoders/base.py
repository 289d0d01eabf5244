"""What every task's LightningModule shares: steps, logging, the optimiser and its schedule,
and rebuilding the plain net's shapes from a checkpoint."""

from __future__ import annotations

from abc import ABC, abstractmethod

import lightning as L
import torch


class DecoderModule(L.LightningModule, ABC):
    """Subclasses set ``self.net`` in ``setup`` (from the data module) and in
    ``build_from_checkpoint`` (shapes only), and implement ``loss(batch)``.

    Args:
        lr: peak learning rate (one-cycle schedule over the run).
        weight_decay: AdamW weight decay.
    """

    def __init__(self, lr: float, weight_decay: float) -> None:
        super().__init__()
        self.net: torch.nn.Module | None = None
        self.scene: dict | None = None

    @abstractmethod
    def loss(self, batch) -> torch.Tensor:
        """The training loss of a batch ``(ze_re, ze_im, targets)``."""

    @abstractmethod
    def net_shape(self) -> dict:
        """What ``build_from_checkpoint`` needs to rebuild the net's shapes."""

    @abstractmethod
    def build_from_checkpoint(self, shape: dict) -> None:
        """Create ``self.net`` with the shapes of ``net_shape()`` (values come after)."""

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["wtml"] = {"scene": self.scene, "shape": self.net_shape(),
                              "max_epochs": self.trainer.max_epochs}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        self.scene = checkpoint["wtml"]["scene"]
        if self.net is None:  # shapes only: the state dict brings the values
            self.build_from_checkpoint(checkpoint["wtml"]["shape"])

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
