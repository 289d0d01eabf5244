"""Fluid decoder: Ze on the sweep grid -> (η, ρ).

:class:`FluidNet` is the plain module that is exported: calibrated T -> Zm (by hand, real
arithmetic) -> ``sign(Zm) log(1 + |Zm|/z_scale)`` (:class:`SignedLogZm`) standardised -> MLP
-> (log10 η, ρ), de-standardised.
All normalisation lives in buffers, so the ONNX graph takes raw Ze. :class:`FluidDecoder` is
its LightningModule: it builds the net from the data module's scene and training statistics
at ``setup`` and rebuilds its shape from the checkpoint when loaded.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from wtml.decoders.base import DecoderModule, check_widths
from wtml.decoders.checkpoint import load_module
from wtml.decoders.layers import SignedLogZm
from wtml.decoders.mlp import MLP


class FluidNet(nn.Module):
    """Ze -> (η in Pa·s, ρ in kg/m³).

    Args:
        t_cal: calibrated T on the grid, complex ``(n_freq, 2, 2)``.
        z_scale: the feature knee in N·s/m (Zm well below it is linear, above logarithmic).
        hidden: widths of the hidden layers.

    Forward: ``ze_re, ze_im`` ``(batch, n_freq)`` float32 in Ω -> ``eta (batch,)``,
    ``rho (batch,)``.
    """

    def __init__(self, t_cal: np.ndarray, z_scale: float, hidden: list[int]) -> None:
        super().__init__()
        n_freq = np.asarray(t_cal).shape[0]
        self.features = SignedLogZm(t_cal, z_scale)
        self.register_buffer("feature_mean", torch.zeros(2 * n_freq))
        self.register_buffer("feature_std", torch.ones(2 * n_freq))
        self.register_buffer("target_mean", torch.zeros(2))
        self.register_buffer("target_std", torch.ones(2))
        self.mlp = MLP(2 * n_freq, hidden, 2)

    def head(self, x: torch.Tensor) -> torch.Tensor:
        """Features ``(batch, 2 n_freq)`` -> standardised (log10 η, ρ) ``(batch, 2)``."""
        return self.mlp((x - self.feature_mean) / self.feature_std)

    def forward_normalized(self, ze_re: torch.Tensor, ze_im: torch.Tensor) -> torch.Tensor:
        """Standardised (log10 η, ρ), shape ``(batch, 2)``: what the loss sees."""
        return self.head(self.features(ze_re, ze_im))

    def from_features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """η, ρ ``(batch,)`` from features already computed (shared with the domain gate)."""
        y = self.head(x) * self.target_std + self.target_mean
        return torch.pow(10.0, y[:, 0]), y[:, 1]

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.from_features(self.features(ze_re, ze_im))

    @torch.no_grad()
    def fit_normalization(self, ze_re: torch.Tensor, ze_im: torch.Tensor,
                          targets: torch.Tensor) -> None:
        """Set feature and target statistics from training data (targets: log10 η, ρ)."""
        x = self.features(ze_re, ze_im)
        self.feature_mean.copy_(x.mean(0))
        self.feature_std.copy_(x.std(0).clamp_min(1e-6))
        self.target_mean.copy_(targets.mean(0))
        self.target_std.copy_(targets.std(0).clamp_min(1e-6))


class FluidDecoder(DecoderModule):
    """Trains :class:`FluidNet` on a ``ShardDataModule`` (MSE on standardised log10 η, ρ).

    Args:
        hidden: hidden layer widths.
        lr: peak learning rate (one-cycle schedule over the run).
        weight_decay: AdamW weight decay.
    """

    def __init__(self, hidden: list[int] | None = None, lr: float = 3e-3,
                 weight_decay: float = 1e-5) -> None:
        super().__init__(lr, weight_decay)
        self.save_hyperparameters()
        self.hidden = list(hidden or [128, 128])
        check_widths("model.hidden", self.hidden)

    def build_net(self, scene, ze_re, ze_im, targets) -> FluidNet:
        net = FluidNet(scene.calibrated_t(), 0.01 * scene.reference_zm(), self.hidden)
        net.fit_normalization(ze_re, ze_im, targets)
        return net

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        """The decoder's own feature layer (signed-log Zm through the calibrated T), the same
        module, so the exported graph computes Zm once for both (a new one before the net
        exists)."""
        features = (self.net.features if self.net is not None
                    else SignedLogZm(scene.calibrated_t(), 0.01 * scene.reference_zm()))
        return features, 2 * scene.excitation.n_freq

    def net_shape(self) -> dict:
        return {"n_freq": self.net.mlp.n_in // 2}

    def build_from_checkpoint(self, shape: dict) -> None:
        placeholder = np.array([[1, 0], [1, 1]], dtype=complex)  # any T with t21 != 0
        self.net = FluidNet(np.tile(placeholder, (shape["n_freq"], 1, 1)), 1.0, self.hidden)

    def loss(self, batch) -> torch.Tensor:
        ze_re, ze_im, target = batch
        y = (target - self.net.target_mean) / self.net.target_std
        return nn.functional.mse_loss(self.net.forward_normalized(ze_re, ze_im), y)


def load_fluid_net(checkpoint: str) -> tuple[FluidNet, dict]:
    """The trained :class:`FluidNet` (eval mode) and its scene mapping from a checkpoint."""
    module = load_module(FluidDecoder, checkpoint, "fluid")
    return module.net.eval(), module.scene


class TorchFluid:
    """A :class:`FluidNet` behind the predict interface (``wtml.interface.FluidPredictor``)."""

    name = "decoder torch"

    def __init__(self, net: FluidNet) -> None:
        self.net = net.eval()

    @torch.no_grad()
    def predict(self, ze: np.ndarray) -> dict[str, np.ndarray]:
        ze = np.asarray(ze)
        eta, rho = self.net(torch.tensor(ze.real, dtype=torch.float32),
                            torch.tensor(ze.imag, dtype=torch.float32))
        return {"eta": eta.numpy().astype(float), "rho": rho.numpy().astype(float)}
