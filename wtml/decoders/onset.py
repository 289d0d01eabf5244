"""The contact-onset decoder: wall location and contact intervals from e(t), i(t).

The graph takes the raw records and computes its own features per probe period (the frames:
64 samples at the defaults), so a device feeds it what its ADC gives:

1. :class:`ProbeFrames`: per frame, a least-squares fit of ``[1, t, t², cos ωH t, sin ωH t]``
   to e and to i (the polynomial soaks up the whisking ramp, which would otherwise leak into
   the probe's phasor): the whisking position ``u_L = HUE(0) e_L`` and the probe phasors
   ``E_H, I_H``, then ``Zm = (t22 E_H - t12 I_H)/(t11 I_H - t21 E_H)`` through the
   calibrated T at the probe frequency (real arithmetic, exportable).
2. A causal temporal convolution over the frames (dilated, so it sees ~60 frames back: the
   400 Hz mode rings for ~40 ms). Per frame: the contact logit, a vote weight, and an offset
   δ with its std. Because it is causal, the streaming form (fed chunks, its state carried)
   gives the offline answer.
3. The location ``g = Σ_t w_t (u_L(t) + δ_t)`` (softmax weights over the frames): each frame
   near an edge says where the wall is relative to the whisking position, which accounts for
   the tip touching on the probe's peaks before u_L reaches g (§10). Its std combines the
   frames' stds and their spread.

Outputs (each ``(batch,)`` unless said): ``gap`` (m, NaN where no frame is in contact),
``sigma`` (m), ``contact`` (``(batch, n_frames)``, probability per frame). Intervals come
from ``contact`` by :func:`wtml.scenes.onset.intervals` plus the onset/detachment offsets in
the metadata (the phase within a frame where contacts start and end, fitted on training
labels).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as fn

from wtml.decoders.base import ConfigError, DecoderModule, check_positive
from wtml.decoders.layers import ZmFromEI


def frame_basis(period: int) -> np.ndarray:
    """Rows that take ``(e_L, cos-coefficient, sin-coefficient)`` out of one probe period of
    ``period`` samples by least squares on ``[1, t, t², cos, sin]`` (t centred), shape
    ``(3, period)``."""
    t = np.arange(period) - (period - 1) / 2
    w = 2 * np.pi / period
    n = np.arange(period)
    basis = np.stack([np.ones(period), t / period, (t / period) ** 2,
                      np.cos(w * n), np.sin(w * n)], 1)
    pinv = np.linalg.pinv(basis)
    return pinv[[0, 3, 4]]


class ProbeFrames(nn.Module):
    """``(e, i)`` ``(batch, n_samples)`` -> frames ``(batch, n_frames, 5)``: ``u_L`` (m),
    ``Re Zm, Im Zm`` (N·s/m), ``|E_H|`` (V), ``|I_H|`` (A).

    Args:
        period: samples per probe period (an integer: the scene's rate is a multiple of the
            probe frequency).
        t_probe: complex T at the probe frequency ``(2, 2)``.
        hue0: HUE(0), m/V.
    """

    def __init__(self, period: int, t_probe: np.ndarray, hue0: float) -> None:
        super().__init__()
        self.period = int(period)
        self.register_buffer("basis", torch.tensor(frame_basis(self.period)[:, None, :],
                                                   dtype=torch.float32))
        self.zm = ZmFromEI(t_probe)
        self.hue0 = float(hue0)

    def fit(self, x: torch.Tensor) -> torch.Tensor:
        """``(batch, n_samples)`` -> ``(batch, 3, n_frames)``: frame level, cos, sin."""
        return fn.conv1d(x[:, None, :], self.basis, stride=self.period)

    def forward(self, e: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        s = ZmFromEI.I_SCALE
        fe, fi = self.fit(e), self.fit(i * s)
        # x = c cos + s sin = Re(X e^{jωt}) with X = c - j s
        e_re, e_im, i_re, i_im = fe[:, 1], -fe[:, 2], fi[:, 1], -fi[:, 2]
        zm_re, zm_im = self.zm(e_re, e_im, i_re, i_im)
        return torch.stack([self.hue0 * fe[:, 0], zm_re, zm_im,
                            torch.sqrt(e_re * e_re + e_im * e_im),
                            torch.sqrt(i_re * i_re + i_im * i_im) / s], -1)


class RecordSummary(nn.Module):
    """The domain gate's features of a record, ``(batch, 3)``: probe level |E_H| (mV),
    whisking amplitude of u_L (µm), and log10 of the mean |I_H| (A)."""

    def __init__(self, frames: ProbeFrames) -> None:
        super().__init__()
        self.frames = frames

    def forward(self, e: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
        f = self.frames(e, i)
        u = f[..., 0] * 1e6
        return torch.stack([1e3 * f[..., 3].mean(-1), (u.amax(-1) - u.amin(-1)) / 2,
                            torch.log10(f[..., 4].mean(-1))], -1)


class CausalConv(nn.Module):
    """A causal dilated 1-D convolution: output frame t sees input frames ``<= t``."""

    def __init__(self, c_in: int, c_out: int, kernel: int, dilation: int) -> None:
        super().__init__()
        self.pad = (kernel - 1) * dilation
        self.conv = nn.Conv1d(c_in, c_out, kernel, dilation=dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(fn.pad(x, (self.pad, 0)))


class OnsetNet(nn.Module):
    """Frames -> (gap m, sigma m, contact probability per frame); see the module docstring.

    Args:
        frames: the feature layer.
        scale: ``(mean, std)`` of the 5 frame features over the training data, ``(2, 5)``.
        amp: the whisking amplitude, m (the offsets' unit).
        channels, dilations, kernel: the temporal convolution.
    """

    def __init__(self, frames: ProbeFrames, scale: torch.Tensor, amp: float, channels: int,
                 dilations: tuple[int, ...], kernel: int = 3) -> None:
        super().__init__()
        self.frames = frames
        self.register_buffer("mean", scale[0].float().clone())
        self.register_buffer("std", scale[1].float().clone())
        self.amp = float(amp)
        layers, c_in = [], 6
        for d in dilations:
            layers += [CausalConv(c_in, channels, kernel, d), nn.GELU()]
            c_in = channels
        self.body = nn.Sequential(*layers)
        self.head = nn.Conv1d(channels, 4, 1)

    def per_frame(self, e: torch.Tensor, i: torch.Tensor
                  ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Contact logit, vote logit, the frame's estimate of g (m) and its log std, each
        ``(batch, n_frames)``."""
        f = self.frames(e, i)
        x = (f - self.mean) / self.std
        du = torch.cat([torch.zeros_like(x[:, :1, :1]), x[:, 1:, :1] - x[:, :-1, :1]], 1)
        h = self.head(self.body(torch.cat([x, du * 10.0], -1).transpose(1, 2)))
        est = f[..., 0] + self.amp * h[:, 2]
        return h[:, 0], h[:, 1], est, h[:, 3]

    def pooled(self, vote, est, log_sd) -> tuple[torch.Tensor, torch.Tensor]:
        w = torch.softmax(vote, -1)
        g = (w * est).sum(-1)
        var = (w * (torch.exp(2 * log_sd) * self.amp**2 + (est - g[:, None]) ** 2)).sum(-1)
        return g, torch.sqrt(var)

    def forward(self, e: torch.Tensor, i: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        contact, vote, est, log_sd = self.per_frame(e, i)
        g, sd = self.pooled(vote, est, log_sd)
        prob = torch.sigmoid(contact)
        touched = prob.amax(-1) > 0.5
        return torch.where(touched, g, torch.full_like(g, float("nan"))), sd, prob


def frame_labels(targets: torch.Tensor, n_frames: int, frame_s: float, max_contacts: int
                 ) -> torch.Tensor:
    """Whether each frame overlaps a true contact, ``(batch, n_frames)`` float, from targets
    ``[gap, onsets (max_contacts), detachments (max_contacts)]``."""
    start = torch.arange(n_frames, dtype=targets.dtype) * frame_s
    on = targets[:, 1:1 + max_contacts, None]
    off = targets[:, 1 + max_contacts:, None]
    off = torch.where(torch.isnan(off) & ~torch.isnan(on), torch.full_like(off, 1e9), off)
    hit = (start < off) & (start + frame_s > on)
    return hit.any(1).float()


def edge_offsets(targets: np.ndarray, frame_s: float, max_contacts: int) -> tuple[float, float]:
    """Median phase (s) within its frame at which training contacts start and end."""
    on = targets[:, 1:1 + max_contacts].ravel()
    off = targets[:, 1 + max_contacts:].ravel()
    on, off = on[np.isfinite(on)], off[np.isfinite(off)]
    if not len(on):
        return 0.0, frame_s
    return (float(np.median(on - np.floor(on / frame_s) * frame_s)),
            float(np.median(off - np.floor(off / frame_s) * frame_s)) if len(off) else frame_s)


class OnsetDecoder(DecoderModule):
    """The onset decoder (``configs/onset.yaml``).

    Args:
        channels: width of the temporal convolution.
        dilations: its layers' dilations (receptive field ``1 + 2 Σ d`` frames at kernel 3).
        location_weight: weight of the location's Gaussian NLL against the frames' BCE.
        lr, weight_decay: as every decoder.
    """

    def __init__(self, channels: int = 32, dilations: list[int] | None = None,
                 location_weight: float = 1.0, lr: float = 3e-3,
                 weight_decay: float = 1e-5) -> None:
        super().__init__(lr, weight_decay)
        dilations = [1, 2, 4, 8, 16] if dilations is None else list(dilations)
        if not 1 <= channels <= 1024:
            raise ConfigError(f"model.channels must be in [1, 1024], got {channels!r}")
        if not dilations or any(not 1 <= d <= 4096 for d in dilations):
            raise ConfigError(f"model.dilations must be a non-empty list of values in "
                              f"[1, 4096], got {dilations!r}")
        check_positive("model.location_weight", location_weight, 1e6)
        self.save_hyperparameters()
        self.register_buffer("offsets", torch.zeros(2))

    def _frames(self, scene) -> ProbeFrames:
        model = scene.transducer()
        t = model.transduction_matrix(np.array([2 * np.pi * scene.drive.probe_hz]))[0]
        return ProbeFrames(frame_period(scene), t, model.static_tip_displacement_per_volt())

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        return RecordSummary(self._frames(scene)), 3

    def _make(self, scene, scale: torch.Tensor) -> OnsetNet:
        h = self.hparams
        return OnsetNet(self._frames(scene), scale, scene.whisk_amplitude_m(), h.channels,
                        tuple(h.dilations))

    def build_net(self, scene, e, i, targets) -> nn.Module:
        frames = self._frames(scene)
        with torch.no_grad():
            f = torch.cat([frames(e[s:s + 64], i[s:s + 64]) for s in range(0, len(e), 64)])
        scale = torch.stack([f.mean((0, 1)), f.std((0, 1)).clamp_min(1e-12)])
        frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self.offsets.copy_(torch.tensor(edge_offsets(targets.numpy(), frame_s,
                                                     scene.max_contacts)))
        self._frame_s, self._max_contacts = frame_s, scene.max_contacts
        return self._make(scene, scale)

    def net_shape(self) -> dict:
        return {}

    def build_from_checkpoint(self, shape: dict) -> None:
        from wtml.scenes import scene_from_dict

        scene = scene_from_dict(self.scene)
        self.net = self._make(scene, torch.ones(2, 5))
        self._frame_s = frame_period(scene) / scene.acquisition.sample_rate_hz
        self._max_contacts = scene.max_contacts

    def loss(self, batch) -> torch.Tensor:
        e, i, targets = batch
        contact, vote, est, log_sd = self.net.per_frame(e, i)
        labels = frame_labels(targets, contact.shape[1], self._frame_s, self._max_contacts)
        bce = fn.binary_cross_entropy_with_logits(contact, labels)
        g, sd = self.net.pooled(vote, est, log_sd)
        has = torch.isfinite(targets[:, 0])
        if not has.any():
            return bce
        amp = self.net.amp
        z = (g[has] - targets[has, 0]) / amp
        s = sd[has] / amp
        nll = (0.5 * (z / s) ** 2 + torch.log(s)).mean()
        return bce + self.hparams.location_weight * nll


def frame_period(scene) -> int:
    """Samples per probe period; the scene's rate must be a whole multiple of the probe."""
    ratio = scene.acquisition.sample_rate_hz / scene.drive.probe_hz
    if abs(ratio - round(ratio)) > 1e-9 * ratio:
        raise ConfigError(f"acquisition.sample_rate_hz {scene.acquisition.sample_rate_hz:g} "
                          f"must be a whole multiple of drive.probe_hz {scene.drive.probe_hz:g} "
                          "for the onset decoder's probe frames")
    return int(round(ratio))
