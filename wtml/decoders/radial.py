"""Radial-location decoders: Ze at the touch tone(s) -> distance of the contact from the tip.

:class:`RadialNet` standardises (Re Ze, Im Ze) with buffers and maps them through an MLP to
the standardised distance, and optionally to a predicted standard deviation (a Gaussian
negative log-likelihood head). Two configs use it: the thesis's decoder, a 2-10-1 sigmoid MLP
on (Re Ze, Im Ze) at 420 Hz (``configs/radial_thesis.yaml``), and ours
(``configs/radial.yaml``): wider, SiLU, with the uncertainty head.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from wtml.decoders.base import DecoderModule
from wtml.decoders.mlp import MLP


class RadialNet(nn.Module):
    """Ze -> (distance in m, its predicted std in m).

    Args:
        n_freq: frequencies of the input.
        hidden: hidden widths.
        activation: ``"sigmoid"`` (the thesis) or ``"silu"``.
        uncertainty: add the std head (otherwise the std output is 0).
        used_frequencies: use only the first this many frequencies (the thesis decoder: 1,
            the 420 Hz tone); all by default.

    Forward: ``ze_re, ze_im`` ``(batch, n_freq)`` float32 Ω -> ``distance (batch,)``,
    ``sigma (batch,)``.
    """

    def __init__(self, n_freq: int, hidden: list[int], activation: str = "silu",
                 uncertainty: bool = True, used_frequencies: int | None = None) -> None:
        super().__init__()
        acts = {"sigmoid": nn.Sigmoid, "silu": nn.SiLU}
        if activation not in acts:
            raise ValueError(f"activation must be one of {sorted(acts)}, got {activation!r}")
        self.n_freq = n_freq
        self.used = n_freq if used_frequencies is None else used_frequencies
        if not 1 <= self.used <= n_freq:
            raise ValueError(f"used_frequencies must be in [1, {n_freq}], got {self.used}")
        self.uncertainty = uncertainty
        self.mlp = MLP(2 * self.used, hidden, 2 if uncertainty else 1,
                       activation=acts[activation])
        self.register_buffer("feature_mean", torch.zeros(2 * self.used))
        self.register_buffer("feature_std", torch.ones(2 * self.used))
        self.register_buffer("target_mean", torch.zeros(1))
        self.register_buffer("target_std", torch.ones(1))

    def forward_normalized(self, ze_re: torch.Tensor, ze_im: torch.Tensor) -> torch.Tensor:
        """Standardised distance and, with the head, log std: shape ``(batch, 1 or 2)``."""
        x = torch.cat([ze_re[:, :self.used], ze_im[:, :self.used]], -1)
        return self.mlp((x - self.feature_mean) / self.feature_std)

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        y = self.forward_normalized(ze_re, ze_im)
        distance = y[:, 0] * self.target_std + self.target_mean
        if self.uncertainty:
            return distance, torch.exp(y[:, 1]) * self.target_std
        return distance, torch.zeros_like(distance)

    def target(self, distance: torch.Tensor) -> torch.Tensor:
        """What the MLP learns: the standardised distance."""
        return (distance - self.target_mean) / self.target_std

    @torch.no_grad()
    def fit_normalization(self, ze_re: torch.Tensor, ze_im: torch.Tensor,
                          targets: torch.Tensor) -> None:
        x = torch.cat([ze_re[:, :self.used], ze_im[:, :self.used]], -1)
        self.feature_mean.copy_(x.mean(0))
        self.feature_std.copy_(x.std(0).clamp_min(1e-12))
        self.target_mean.copy_(targets.mean(0))
        self.target_std.copy_(targets.std(0).clamp_min(1e-12))


class RadialDecoder(DecoderModule):
    """Trains :class:`RadialNet`: MSE, or Gaussian NLL with the uncertainty head.

    Args:
        hidden: hidden widths ([10] for the thesis's 2-10-1).
        activation: ``"sigmoid"`` or ``"silu"``.
        uncertainty: predict a std as well.
        used_frequencies: only the first this many of the scene's frequencies (default all).
        lr, weight_decay: optimiser.
    """

    def __init__(self, hidden: list[int] | None = None, activation: str = "silu",
                 uncertainty: bool = True, used_frequencies: int | None = None,
                 lr: float = 3e-3, weight_decay: float = 0.0) -> None:
        super().__init__(lr, weight_decay)
        self.save_hyperparameters()
        self.hidden = list(hidden or [64, 64])

    def _new(self, n_freq: int) -> RadialNet:
        return RadialNet(n_freq, self.hidden, self.hparams.activation, self.hparams.uncertainty,
                         self.hparams.used_frequencies)

    def setup(self, stage: str) -> None:
        if self.net is not None:
            return
        dm = self.trainer.datamodule
        ze_re, ze_im, targets = dm.train_tensors()
        self.net = self._new(ze_re.shape[1])
        self.scene = dm.scene_dict
        self.net.fit_normalization(ze_re, ze_im, targets)

    def net_shape(self) -> dict:
        return {"n_freq": self.net.n_freq}

    def build_from_checkpoint(self, shape: dict) -> None:
        self.net = self._new(shape["n_freq"])

    def loss(self, batch) -> torch.Tensor:
        ze_re, ze_im, target = batch
        y = self.net.target(target[:, 0])
        out = self.net.forward_normalized(ze_re, ze_im)
        if not self.net.uncertainty:
            return nn.functional.mse_loss(out[:, 0], y)
        return nn.functional.gaussian_nll_loss(out[:, 0], y, torch.exp(2 * out[:, 1]))


def load_radial_net(checkpoint: str) -> tuple[RadialNet, dict]:
    """The trained :class:`RadialNet` (eval mode) and its scene mapping."""
    module = RadialDecoder.load_from_checkpoint(checkpoint, map_location="cpu")
    return module.net.eval(), module.scene


class TorchRadial:
    """A :class:`RadialNet` behind the predict interface: ``predict(ze) -> {"distance"}``."""

    def __init__(self, net: RadialNet, name: str = "decoder torch") -> None:
        self.net, self.name = net.eval(), name

    @torch.no_grad()
    def predict(self, ze: np.ndarray) -> dict[str, np.ndarray]:
        ze = np.asarray(ze)
        d, s = self.net(torch.tensor(ze.real, dtype=torch.float32),
                        torch.tensor(ze.imag, dtype=torch.float32))
        return {"distance": d.numpy().astype(float), "sigma": s.numpy().astype(float)}
