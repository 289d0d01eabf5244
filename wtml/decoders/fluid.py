"""Fluid decoder: Ze on the sweep grid and the user's calibrated T -> (η, ρ).

:class:`FluidNet` is the plain module that is exported: Ze through the user's calibrated T (an
input, one per measurement: each device has its own) -> Zm (by hand, real arithmetic) ->
``sign(Zm) log(1 + |Zm|/z_scale)`` (:class:`SignedLogZm`) standardised -> MLP -> (log10 η, ρ),
de-standardised. Zm through the device's own T does not depend on the device, so the MLP sees
Zm only; the domain gate also sees the device's features (``SignedLogZm.device``).
All normalisation lives in buffers, so the ONNX graph takes raw Ze and T. :class:`FluidDecoder` is
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
from wtml.physics.twoport import flat_parts


class FluidNet(nn.Module):
    """(Ze, calibrated T) -> (η in Pa·s, ρ in kg/m³).

    Args:
        n_freq: points of the sweep grid.
        z_scale: the feature knee in N·s/m (Zm well below it is linear, above logarithmic).
        hidden: widths of the hidden layers.

    Forward: ``ze_re, ze_im`` ``(batch, n_freq)`` float32 in Ω and ``t_re, t_im``
    ``(batch, n_freq, 4)`` (T flattened as t11, t12, t21, t22) -> ``eta (batch,)``,
    ``rho (batch,)``.
    """

    def __init__(self, n_freq: int, z_scale: float, hidden: list[int]) -> None:
        super().__init__()
        self.n_freq = n_freq
        self.features = SignedLogZm(z_scale, n_freq)
        self.register_buffer("feature_mean", torch.zeros(2 * n_freq))
        self.register_buffer("feature_std", torch.ones(2 * n_freq))
        self.register_buffer("target_mean", torch.zeros(2))
        self.register_buffer("target_std", torch.ones(2))
        self.mlp = MLP(2 * n_freq, hidden, 2)

    def head(self, x: torch.Tensor) -> torch.Tensor:
        """Features (:class:`SignedLogZm`'s) -> standardised (log10 η, ρ) ``(batch, 2)``: the
        MLP sees the Zm part (what the loss sees, on features computed once per sample)."""
        return self.mlp((x[:, :2 * self.n_freq] - self.feature_mean) / self.feature_std)

    def from_features(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """η, ρ ``(batch,)`` from features already computed (shared with the domain gate)."""
        y = self.head(x) * self.target_std + self.target_mean
        return torch.pow(10.0, y[:, 0]), y[:, 1]

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.from_features(self.features(ze_re, ze_im, t_re, t_im))

    @torch.no_grad()
    def fit_normalization(self, ze_re: torch.Tensor, ze_im: torch.Tensor, t_re: torch.Tensor,
                          t_im: torch.Tensor, targets: torch.Tensor) -> None:
        """Set feature and target statistics from training data (targets: log10 η, ρ)."""
        x = self.features(ze_re, ze_im, t_re, t_im)[:, :2 * self.n_freq]
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

    TASK = "fluid"

    def __init__(self, hidden: list[int] | None = None, lr: float = 3e-3,
                 weight_decay: float = 1e-5) -> None:
        super().__init__(lr, weight_decay)
        self.save_hyperparameters()
        self.hidden = list(hidden or [128, 128])
        check_widths("model.hidden", self.hidden)

    def build_net(self, scene, *tensors) -> FluidNet:
        net = FluidNet(scene.excitation.n_freq, 0.01 * scene.reference_zm(), self.hidden)
        net.fit_normalization(*tensors)
        return net

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        """The decoder's own feature layer (signed-log Zm through the calibrated T, and the
        device's features), the same module, so the exported graph computes Zm once for both
        (a new one before the net exists)."""
        features = (self.net.features if self.net is not None
                    else SignedLogZm(0.01 * scene.reference_zm(), scene.excitation.n_freq))
        return features, 2 * scene.excitation.n_freq + SignedLogZm.N_DEVICE

    def net_shape(self) -> dict:
        return {"n_freq": self.net.n_freq}

    def build_from_checkpoint(self, shape: dict) -> None:
        self.net = FluidNet(shape["n_freq"], 1.0, self.hidden)

    def setup(self, stage: str) -> None:
        """The net as :class:`DecoderModule` builds it; then the data module hands the
        batches as the net's features (its feature layer has no parameters: Zm through each
        record's T is computed once per sample, not in every step)."""
        super().setup(stage)
        self.trainer.datamodule.map_inputs(self.net.features)

    def loss(self, batch) -> torch.Tensor:
        """On batches ``(features, targets)`` (:meth:`setup`)."""
        x, target = batch
        y = (target - self.net.target_mean) / self.net.target_std
        return nn.functional.mse_loss(self.net.head(x), y)


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
    def predict(self, ze: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        ze = np.asarray(ze)
        eta, rho = self.net(torch.tensor(ze.real, dtype=torch.float32),
                            torch.tensor(ze.imag, dtype=torch.float32),
                            *(torch.from_numpy(p) for p in flat_parts(t)))
        return {"eta": eta.numpy().astype(float), "rho": rho.numpy().astype(float)}
