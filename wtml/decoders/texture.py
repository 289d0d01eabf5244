"""The texture decoder: sandpaper grade and grain size from windows of e(t), i(t).

The graph takes raw samples (a window of ``window`` samples at the scene's rate) and computes
its own features, so a device feeds it what its ADC gives:

1. :class:`WhiskFeatures`: the whisking frequency from e alone (for a sampled tone
   ``x[n+L] + x[n-L] = 2 cos(ωL dt) x[n]`` exactly, with L a quarter of the nominal period,
   where the noise matters least, applied to ``x = e[n+L] - e[n]`` so an offset drops out);
   a least-squares fit of ``[1, cos kωt, sin kωt]`` (k = 1..3) to e and to i (normal
   equations solved by an unrolled Cholesky: ``torch.linalg.solve`` does not export); the
   fundamental phasors E, I through the user's calibrated T at that ω (:class:`CalibratedT`:
   an input of the graph, T of their own device at the scene's ``calibration_hz``,
   interpolated to ω by the polynomial through those points): ``F = t22 E - t12 I``,
   ``V = -t21 E + t11 I``, ``Zm = F/V`` (the thesis's cues); the current's harmonics
   relative to its fundamental; and the residual of the fit (what the harmonics do not
   explain: the asperities' broadband part), its RMS and that of its differences at lags
   1-32 samples (a coarse spectrum), relative to |I|.
2. A standardised MLP with two heads: grade logits (the thesis's five grades) and the mean
   and log std of ln(grain size / 1 m).

Outputs (each ``(batch,)`` unless said): ``grain`` (m), ``log_sigma`` (the std of ln grain),
``probabilities`` ``(batch, 5)``.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn
from torch.nn import functional as fn

from wtml.decoders.base import ConfigError, DecoderModule, check_positive, check_widths
from wtml.decoders.layers import t_elements

HARMONICS = 3
LAGS = (1, 2, 4, 8, 16, 32)
"""Lags (samples) of the residual's differences: each passes mostly ``rate/(2 lag)`` and up
(25.6 to 0.8 kHz at 51.2 kS/s)."""
CUES = ("|F| (N)", "|V| (m/s)", "Re Zm (N·s/m)", "Im Zm (N·s/m)")


def cholesky_solve(g: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Solve ``g x = b`` for symmetric positive definite ``g`` ``(B, m, m)`` and ``b``
    ``(B, m, c)`` by an unrolled Cholesky factorisation (exportable; m small)."""
    m = g.shape[-1]
    low = [[None] * m for _ in range(m)]
    for j in range(m):
        acc = g[:, j, j] - sum((low[j][k] ** 2 for k in range(j)), torch.zeros_like(g[:, 0, 0]))
        low[j][j] = acc.clamp_min(1e-30).sqrt()
        for r in range(j + 1, m):
            acc = g[:, r, j] - sum((low[r][k] * low[j][k] for k in range(j)),
                                   torch.zeros_like(g[:, 0, 0]))
            low[r][j] = acc / low[j][j]
    y = [None] * m
    for r in range(m):
        acc = b[:, r] - sum((low[r][k][:, None] * y[k] for k in range(r)),
                            torch.zeros_like(b[:, 0]))
        y[r] = acc / low[r][r][:, None]
    x = [None] * m
    for r in reversed(range(m)):
        acc = y[r] - sum((low[k][r][:, None] * x[k] for k in range(r + 1, m)),
                         torch.zeros_like(b[:, 0]))
        x[r] = acc / low[r][r][:, None]
    return torch.stack(x, 1)


class CalibratedT(nn.Module):
    """The user's calibrated T at the measured ω: T given at ``K`` frequencies (an input of
    the graph, one per window) interpolated by the Lagrange polynomial through all K, in
    float32 real arithmetic.

    Why T on a grid: the graph measures ω from each window and the whisking range sits on
    the macro WT's 36 Hz resonance, so one T at one frequency is not enough; T at a few
    frequencies is what a user's calibration gives (physics.md §4), needs no model of their
    device, and T is smooth there (its elements are ratios of the transducer's forms, whose
    shared modal poles cancel): degree 4 through 5 points over 34.5-37.5 Hz reproduces the
    modal model's T to 1e-7 of each element.

    Args:
        frequency_hz: the K calibration frequencies, Hz, ``(K,)`` (distinct).

    Forward: ω (rad/s) ``(batch,)``, ``t_re, t_im`` ``(batch, K, 4)`` (t11, t12, t21, t22)
    -> re and im of (t11, t12, t21, t22) at ω, eight tensors ``(batch,)``.
    """

    def __init__(self, frequency_hz) -> None:
        super().__init__()
        f = np.asarray(frequency_hz, float)
        if f.ndim != 1 or len(f) < 2 or len(np.unique(f)) != len(f):
            raise ValueError(f"frequency_hz: at least 2 distinct frequencies, got {f}")
        self.centre, self.half = float(f.mean()), float(np.ptp(f) / 2)
        x = (f - self.centre) / self.half
        self.nodes = [float(v) for v in x]
        self.denominators = [float(np.prod([x[k] - x[j] for j in range(len(x)) if j != k]))
                             for k in range(len(x))]

    def weights(self, w: torch.Tensor) -> torch.Tensor:
        """The Lagrange weights of each calibration frequency at ω, ``(batch, K)``."""
        x = (w / (2 * np.pi) - self.centre) / self.half
        cols = []
        for k, den in enumerate(self.denominators):
            num = torch.ones_like(x)
            for j, node in enumerate(self.nodes):
                if j != k:
                    num = num * (x - node)
            cols.append(num / den)
        return torch.stack(cols, -1)

    def forward(self, w: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor
                ) -> tuple[torch.Tensor, ...]:
        lw = self.weights(w)[..., None]  # (B, K, 1)
        out = []
        for re, im in t_elements((t_re * lw).sum(1, keepdim=True),
                                 (t_im * lw).sum(1, keepdim=True)):
            out += [re[:, 0], im[:, 0]]
        return tuple(out)


class WhiskFeatures(nn.Module):
    """``(e, i)`` windows ``(batch, n)`` (V, A) and the user's calibrated T ``t_re, t_im``
    ``(batch, K, 4)`` at ``calibration_hz`` (:class:`CalibratedT`) -> features
    ``(batch, N_FEATURES)``: see the module docstring. Columns: ω/ω_ref, ln|E|, ln|I|,
    ln|F|, ln|V|, Re Zm/z, Im Zm/z (z = :attr:`Z_REF`), Re and Im of
    ``I_k conj(E/|E|)^k / |I|`` for k = 2..3 (harmonics in the drive's phase, the same for
    any window start), ln of the residual's RMS and of its differences' at :data:`LAGS`,
    relative to |I|. :meth:`cues` gives the thesis's four."""

    N_FEATURES = 7 + 2 * (HARMONICS - 1) + 1 + len(LAGS)
    Z_REF = 1e-3
    W_REF = 2 * np.pi * 36.0

    def __init__(self, calibration_hz, sample_rate_hz: float) -> None:
        super().__init__()
        self.t = CalibratedT(calibration_hz)
        self.rate = float(sample_rate_hz)
        self.lag = max(1, int(round(self.rate / (4 * self.W_REF / (2 * np.pi)))))

    def fit(self, e: torch.Tensor, i: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """ω (rad/s), the LS coefficients of e and i ``(batch, 7)`` on
        ``[1, cos ωt, sin ωt, cos 2ωt, ...]``, and i's residual ``(batch, n)``."""
        n, lag = e.shape[1], self.lag
        d = e[:, lag:] - e[:, :-lag]  # a tone of the same ω, its offset gone
        mid = d[:, lag:-lag]
        c = ((d[:, 2 * lag:] + d[:, :-2 * lag]) * mid).sum(1) / (2 * (mid**2).sum(1))
        w = torch.acos(c.clamp(-1.0, 1.0)) * self.rate / lag
        t = (torch.arange(n, dtype=e.dtype, device=e.device) - (n - 1) / 2) / self.rate
        ph = w[:, None, None] * t[None, :, None] * torch.arange(
            1, HARMONICS + 1, dtype=e.dtype, device=e.device)  # (B, n, K)
        # t is symmetric about 0, so the even columns [1, cos kωt] are orthogonal to the odd
        # ones [sin kωt]: two small systems instead of one of 7
        even = torch.cat([torch.ones_like(ph[..., :1]), torch.cos(ph)], -1)  # (B, n, K+1)
        odd = torch.sin(ph)  # (B, n, K)
        scale = torch.stack([e.abs().amax(1), i.abs().amax(1)], 1).clamp_min(1e-30)  # (B, 2)
        y = torch.stack([e, i], -1) / scale[:, None, :]
        c_even, c_odd = (cholesky_solve(b.transpose(1, 2) @ b, b.transpose(1, 2) @ y)
                         for b in (even, odd))
        cols = [c_even[:, :1]]
        for k in range(HARMONICS):
            cols += [c_even[:, k + 1:k + 2], c_odd[:, k:k + 1]]
        coef = torch.cat(cols, 1) * scale[:, None, :]  # (B, 7, 2) on [1, cos ωt, sin ωt, ...]
        fitted = (even @ c_even[..., 1:2] + odd @ c_odd[..., 1:2])[..., 0] * scale[:, 1:2]
        resid = i - fitted
        return w, coef[..., 0], coef[..., 1], resid

    @staticmethod
    def _phasor(c: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
        """``a cos + b sin`` = Re{(a - jb) e^{jωt}}: the phasor of harmonic k (1-based)."""
        return c[:, 2 * k - 1], -c[:, 2 * k]

    def cues(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor
             ) -> tuple[torch.Tensor, ...]:
        """ω (rad/s) and the thesis's cues at the fundamental through the calibrated T:
        (F re, F im, V re, V im, Zm re, Zm im), each ``(batch,)``, plus the fit."""
        w, ce, ci, resid = self.fit(e, i)
        e_re, e_im = self._phasor(ce, 1)
        i_re, i_im = self._phasor(ci, 1)
        t11r, t11i, t12r, t12i, t21r, t21i, t22r, t22i = self.t(w, t_re, t_im)
        f_re = t22r * e_re - t22i * e_im - (t12r * i_re - t12i * i_im)
        f_im = t22r * e_im + t22i * e_re - (t12r * i_im + t12i * i_re)
        v_re = -(t21r * e_re - t21i * e_im) + t11r * i_re - t11i * i_im
        v_im = -(t21r * e_im + t21i * e_re) + t11r * i_im + t11i * i_re
        vv = v_re**2 + v_im**2
        z_re = (f_re * v_re + f_im * v_im) / vv
        z_im = (f_im * v_re - f_re * v_im) / vv
        return w, (f_re, f_im, v_re, v_im, z_re, z_im), (ce, ci, resid)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor
                ) -> torch.Tensor:
        w, (f_re, f_im, v_re, v_im, z_re, z_im), (ce, ci, resid) = self.cues(e, i, t_re, t_im)
        e_re, e_im = self._phasor(ce, 1)
        i_re, i_im = self._phasor(ci, 1)
        ii = i_re**2 + i_im**2
        cols = [w / self.W_REF, 0.5 * torch.log(e_re**2 + e_im**2), 0.5 * torch.log(ii),
                0.5 * torch.log(f_re**2 + f_im**2), 0.5 * torch.log(v_re**2 + v_im**2),
                z_re / self.Z_REF, z_im / self.Z_REF]
        ee = (e_re**2 + e_im**2).sqrt()
        u_re, u_im = e_re / ee, -e_im / ee  # conj(E)/|E|: the drive's phase undone
        for k in range(2, HARMONICS + 1):
            h_re, h_im = self._phasor(ci, k)
            for _ in range(k):  # I_k conj(E/|E|)^k: the same for every window start
                h_re, h_im = h_re * u_re - h_im * u_im, h_re * u_im + h_im * u_re
            cols += [h_re / ii.sqrt(), h_im / ii.sqrt()]
        cols.append(0.5 * torch.log((resid**2).mean(1) / ii))
        for lag in LAGS:  # a coarse spectrum of the residual: differences at growing lags
            r = resid[:, lag:] - resid[:, :-lag]
            cols.append(0.5 * torch.log((r**2).mean(1) / ii))
        return torch.stack(cols, 1)

    @classmethod
    def cues_from(cls, x: torch.Tensor) -> torch.Tensor:
        """The thesis's four cues ``(batch, 4)``: |F| (N), |V| (m/s), Re Zm, Im Zm (N·s/m),
        from features ``(batch, N_FEATURES)``."""
        return torch.stack([torch.exp(x[:, 3]), torch.exp(x[:, 4]), x[:, 5] * cls.Z_REF,
                            x[:, 6] * cls.Z_REF], 1)


class TextureNet(nn.Module):
    """Features -> standardised MLP -> (grain m, log std, probabilities ``(batch, 5)``)."""

    def __init__(self, features: WhiskFeatures, scale: torch.Tensor, hidden: list[int],
                 n_classes: int = 5) -> None:
        super().__init__()
        self.features = features
        self.register_buffer("scale", scale)  # (2, N_FEATURES): mean, std
        layers, width = [], WhiskFeatures.N_FEATURES
        for h in hidden:
            layers += [nn.Linear(width, h), nn.GELU()]
            width = h
        self.body = nn.Sequential(*layers)
        self.classes = nn.Linear(width, n_classes)
        self.grain = nn.Linear(width, 2)
        self.register_buffer("log_grain", torch.tensor([np.log(30e-6), 0.5]))  # mean, spread

    def heads(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Features ``(batch, N_FEATURES)`` -> logits ``(batch, 5)``, ln grain mean and
        log std ``(batch,)``."""
        h = self.body((x - self.scale[0]) / self.scale[1])
        g = self.grain(h)
        return (self.classes(h), self.log_grain[0] + self.log_grain[1] * g[:, 0],
                g[:, 1] + torch.log(self.log_grain[1]))

    def from_features(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The outputs from features ``(batch, N_FEATURES)`` already computed."""
        logits, mu, log_sd = self.heads(x)
        return torch.exp(mu), log_sd, torch.softmax(logits, -1)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor
                ) -> tuple[torch.Tensor, ...]:
        return self.from_features(self.features(e, i, t_re, t_im))


class TextureDecoder(DecoderModule):
    """The texture decoder (``configs/texture.yaml``).

    Args:
        hidden: the MLP's layer widths.
        window_s: the window length it is trained and exported for, s (random crops of the
            training records; the first window of validation records).
        grain_weight: weight of the grain size's Gaussian NLL beside the grade's cross-entropy.
        lr, weight_decay: as every decoder.
    """

    TASK = "texture"

    def __init__(self, hidden: list[int] | None = None, window_s: float = 0.25,
                 grain_weight: float = 0.5, lr: float = 3e-3, weight_decay: float = 1e-4
                 ) -> None:
        super().__init__(lr, weight_decay)
        hidden = [64, 64] if hidden is None else list(hidden)
        check_widths("model.hidden", hidden)
        check_positive("model.window_s", window_s, 100.0)
        check_positive("model.grain_weight", grain_weight, 1e6)
        self.save_hyperparameters()

    def window(self, scene) -> int:
        """The window in samples at the scene's rate: at least one period of the scene's
        slowest whisk (the features fit the whisk's harmonics over it; shorter windows
        also multiply the domain gate's windows, one per window of every training record,
        until they exhaust memory: 1e-5 s made 16 M), at most a record."""
        rate = scene.acquisition.sample_rate_hz
        n = int(round(self.hparams.window_s * rate))
        lag = WhiskFeatures(scene.calibration_hz, rate).lag
        shortest = max(math.ceil(rate / scene.drive.whisk_hz[0]), 3 * lag + 1)
        if not shortest <= n <= scene.n_samples:
            raise ConfigError(f"model.window_s must be in [{shortest / rate:.4g}, "
                              f"{scene.n_samples / rate:g}] s for this scene (one period of "
                              f"its slowest whisk, {scene.drive.whisk_hz[0]:g} Hz, to a whole "
                              f"record), got {self.hparams.window_s:g}")
        return n

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        """The net's own feature layer, the same module, so the exported graph computes the
        features once for the net and its gate (a new one before the net exists)."""
        features = (self.net.features if self.net is not None
                    else WhiskFeatures(scene.calibration_hz, scene.acquisition.sample_rate_hz))
        return features, WhiskFeatures.N_FEATURES

    def build_net(self, scene, e, i, t_re, t_im, targets) -> nn.Module:
        feats = WhiskFeatures(scene.calibration_hz, scene.acquisition.sample_rate_hz)
        self._n = self.window(scene)
        with torch.no_grad():
            x = torch.cat([feats(e[s:s + 64, :self._n], i[s:s + 64, :self._n],
                                 t_re[s:s + 64], t_im[s:s + 64])
                           for s in range(0, len(e), 64)])
        scale = torch.stack([x.mean(0), x.std(0).clamp_min(1e-6)])
        net = TextureNet(feats, scale, list(self.hparams.hidden))
        logd = torch.log(targets[:, 1])
        net.log_grain.copy_(torch.stack([logd.mean(), logd.std().clamp_min(1e-3)]))
        return net

    def gate_inputs(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                    t_im: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Every whole window of the training records, ``(n · per, window)`` each, with its
        record's T."""
        n = self._n
        per = e.shape[1] // n
        return (e[:, :per * n].reshape(-1, n), i[:, :per * n].reshape(-1, n),
                t_re.repeat_interleave(per, 0), t_im.repeat_interleave(per, 0))

    def net_shape(self) -> dict:
        return {"window": self._n}

    def build_from_checkpoint(self, shape: dict) -> None:
        from wtml.scenes import scene_from_dict

        scene = scene_from_dict(self.scene)
        self._n = int(shape["window"])
        self.net = TextureNet(WhiskFeatures(scene.calibration_hz,
                                            scene.acquisition.sample_rate_hz),
                              torch.ones(2, WhiskFeatures.N_FEATURES),
                              list(self.hparams.hidden))

    def loss(self, batch) -> torch.Tensor:
        e, i, t_re, t_im, targets = batch
        n = self._n
        if self.training and e.shape[1] > n:
            start = torch.randint(0, e.shape[1] - n + 1, (len(e),))
            idx = start[:, None] + torch.arange(n)
            e, i = e.gather(1, idx), i.gather(1, idx)
        else:
            e, i = e[:, :n], i[:, :n]
        logits, mu, log_sd = self.net.heads(self.net.features(e, i, t_re, t_im))
        ce = fn.cross_entropy(logits, targets[:, 0].long())
        z = (torch.log(targets[:, 1]) - mu) / torch.exp(log_sd)
        nll = (0.5 * z**2 + log_sd).mean()
        return ce + self.hparams.grain_weight * nll
