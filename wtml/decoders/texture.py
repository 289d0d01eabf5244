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
   1-32 samples (a coarse spectrum), relative to |I|; and, in the decoder, the residual's
   band powers (:class:`BandPowers`: eight bands per octave from 0.95 kHz to the Nyquist, a
   framed real DFT as one matmul), each over |F|² (the unknown normal force scales both).
   The grade lives in the asperity impulses (4-33 kHz, physics.md §11): the lags' coarse
   spectrum left the decoder behind band powers read by gradient boosting (issue 25 §3).
2. A standardised MLP with two heads: grade logits (the thesis's five grades) and the mean
   and log std of ln(grain size / 1 m); and, with ``high_band_hz``, a second such MLP that
   reads the whisk cues and the bands from that frequency up alone, the two answering as an
   ensemble (:class:`TextureNet`): held-out LuGre moved the residual's RMS, its lags and its
   bands below ~3 kHz most (a bristle that rings at the reversals, 1.4-14 kHz over the
   prior, much of it below the asperities' 4-33 kHz).

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
BANDS_PER_OCTAVE = 8
BAND_ANCHOR_HZ = 25600.0
"""Band edges are ``BAND_ANCHOR_HZ · 2^(k / BANDS_PER_OCTAVE)`` for whole k: every rate's bands
are the same below its Nyquist, and 51.2 kS/s's Nyquist is an edge. Eight per octave (and
Welch segments of 40 ms) against four (20 ms): 86.4 % against 84.2 % for the band-power peer
(:class:`~wtml.baselines.texture_peers.BandPowerPeer`) in 5-fold cross-validation over 640
training specimens of the texture scene (grouped by specimen; 12 per octave 86.2 %, from
300 Hz 86.6 %)."""
BAND_LOW_HZ = 1000.0
"""The lowest band's bottom is the edge at or below this: 951 Hz."""


def band_edges(rate_hz: float, low_hz: float = BAND_LOW_HZ, top_hz: float | None = None
               ) -> np.ndarray:
    """The band edges (Hz) ``(n_bands + 1,)``: :data:`BAND_ANCHOR_HZ` ``· 2^(k/8)`` from the
    last at or below ``low_hz`` to the last at or below ``min(top_hz, rate_hz / 2)`` (the
    Nyquist; ``top_hz`` None: the Nyquist alone)."""
    top = rate_hz / 2 if top_hz is None else min(top_hz, rate_hz / 2)
    if top <= low_hz:
        raise ValueError(f"top_hz: {top:g} Hz (at most the Nyquist) must exceed low_hz "
                         f"{low_hz:g} Hz")
    lo = int(np.floor(BANDS_PER_OCTAVE * np.log2(low_hz / BAND_ANCHOR_HZ) + 1e-9))
    hi = int(np.floor(BANDS_PER_OCTAVE * np.log2(top / BAND_ANCHOR_HZ) + 1e-9))
    return BAND_ANCHOR_HZ * 2.0 ** (np.arange(lo, hi + 1) / BANDS_PER_OCTAVE)


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


class BandPowers(nn.Module):
    """A signal's power in the bands of :func:`band_edges`, averaged over Hann frames at half
    overlap: one matmul by a fixed real DFT (the window and the scale folded in; no complex
    tensors, no FFT, so it exports to ONNX as two MatMuls), the bins' powers averaged over
    the frames, then one matmul by a fixed pooling matrix.

    Args:
        rate_hz: the sampling rate, Hz.
        frame: the DFT frame, samples (even; ``rate_hz / frame`` Hz bins). A bin lends each
            band the fraction of its span ``[f - df/2, f + df/2]`` inside the band, so bands
            narrower than a bin (the lowest, at coarse frames) share their bins' power.

    Forward: x ``(batch, n)`` (any unit u; ``n >= frame``) -> ``(batch, n_bands)`` u²: the
    one-sided power in each band (white noise of variance σ² gives σ² over all bands to the
    Nyquist from 0; a tone of amplitude A inside a band gives A²/2 there).
    """

    def __init__(self, rate_hz: float, frame: int) -> None:
        super().__init__()
        if isinstance(frame, bool) or not isinstance(frame, int) or frame < 16 or frame % 2:
            raise ValueError(f"frame: an even number of samples >= 16, got {frame!r}")
        self.frame = frame
        self.edges = band_edges(rate_hz)
        df = rate_hz / frame
        freq = np.arange(frame // 2 + 1) * df
        lo, hi = freq - df / 2, freq + df / 2
        overlap = (np.minimum(hi[:, None], self.edges[None, 1:])
                   - np.maximum(lo[:, None], self.edges[None, :-1])).clip(0) / df  # (bins, bands)
        used = np.flatnonzero(overlap.sum(1) > 0)  # the bins that reach a band
        n = np.arange(frame)
        hann = 0.5 - 0.5 * np.cos(2 * np.pi * n / frame)  # periodic, as scipy's welch
        # power 2|X_k|² / (L Σw²): one-sided, the frame's variance summed over all bins
        arg = 2 * np.pi * np.outer(n, used) / frame
        gain = hann[:, None] * np.sqrt(2 / (frame * (hann**2).sum()))
        dft = np.concatenate([gain * np.cos(arg), gain * np.sin(arg)], 1)  # (L, 2 bins)
        pool = np.concatenate([overlap[used], overlap[used]])  # (2 bins, bands): re² + im²
        self.register_buffer("dft", torch.tensor(dft, dtype=torch.float32), persistent=False)
        self.register_buffer("pool", torch.tensor(pool, dtype=torch.float32), persistent=False)

    @property
    def n_bands(self) -> int:
        return len(self.edges) - 1

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size, hop = self.frame, self.frame // 2
        count = (x.shape[1] - size) // hop + 1  # frames starting at 0, hop, 2 hop, ...
        if count < 1:
            raise ValueError(f"BandPowers: windows of {x.shape[1]} samples, shorter than a "
                             f"frame ({size})")
        # the even frames tile x from 0, the odd ones from hop: two reshapes, no gather
        frames = [x[:, :(count + 1) // 2 * size].reshape(x.shape[0], -1, size)]
        if count > 1:
            frames.append(x[:, hop:hop + count // 2 * size].reshape(x.shape[0], -1, size))
        spectrum = torch.cat(frames, 1) @ self.dft  # (B, frames, 2 bins): re, im
        return (spectrum**2).mean(1) @ self.pool


class WhiskFeatures(nn.Module):
    """``(e, i)`` windows ``(batch, n)`` (V, A) and the user's calibrated T ``t_re, t_im``
    ``(batch, K, 4)`` at ``calibration_hz`` (:class:`CalibratedT`) -> features
    ``(batch, n_features)``: see the module docstring. Columns: ω/ω_ref, ln|E|, ln|I|,
    ln|F|, ln|V|, Re Zm/z, Im Zm/z (z = :attr:`Z_REF`), Re and Im of
    ``I_k conj(E/|E|)^k / |I|`` for k = 2..3 (harmonics in the drive's phase, the same for
    any window start), ln of the residual's RMS and of its differences' at :data:`LAGS`,
    relative to |I| (:attr:`N_FEATURES` columns so far); then, with ``band_frame``, ln of the
    residual's power in each band of :class:`BandPowers` over |F|² (A²/N²; the residual: i
    less its fitted fundamental). :meth:`cues` gives the thesis's four.

    Args:
        calibration_hz: the frequencies of the calibrated T ``(K,)``, Hz.
        sample_rate_hz: the windows' rate, Hz.
        band_frame: the band powers' DFT frame, samples (even); None: no band powers (the
            peers and the thesis's cues read the first columns alone).
    """

    CUE_COLUMNS = 7 + 2 * (HARMONICS - 1)
    """The whisk cues' columns: ω to the harmonics."""
    N_FEATURES = CUE_COLUMNS + 1 + len(LAGS)
    Z_REF = 1e-3
    W_REF = 2 * np.pi * 36.0

    def __init__(self, calibration_hz, sample_rate_hz: float, band_frame: int | None = None
                 ) -> None:
        super().__init__()
        self.t = CalibratedT(calibration_hz)
        self.rate = float(sample_rate_hz)
        self.lag = max(1, int(round(self.rate / (4 * self.W_REF / (2 * np.pi)))))
        self.bands = None if band_frame is None else BandPowers(self.rate, band_frame)
        self.n_features = self.N_FEATURES + (0 if self.bands is None else self.bands.n_bands)

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
        x = torch.stack(cols, 1)
        if self.bands is None:
            return x
        # on the residual over |I| (float32's range), then over |F|² rather than |I|²
        power = self.bands(resid / ii.sqrt()[:, None]).clamp_min(1e-30)  # (B, bands)
        shift = torch.log(ii / (f_re**2 + f_im**2))
        return torch.cat([x, torch.log(power) + shift[:, None]], 1)

    @classmethod
    def cues_from(cls, x: torch.Tensor) -> torch.Tensor:
        """The thesis's four cues ``(batch, 4)``: |F| (N), |V| (m/s), Re Zm, Im Zm (N·s/m),
        from features ``(batch, n_features)``."""
        return torch.stack([torch.exp(x[:, 3]), torch.exp(x[:, 4]), x[:, 5] * cls.Z_REF,
                            x[:, 6] * cls.Z_REF], 1)


def crop(e: torch.Tensor, i: torch.Tensor, start: torch.Tensor, n: int,
         rows: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Windows ``(m, n)`` of records ``e``, ``i`` ``(records, length)``: window k holds the
    ``n`` samples of record ``rows[k]`` from sample ``start[k]`` on (``start``, ``rows``
    ``(m,)``; ``rows`` None: record k). Only the windows are copied, not their records."""
    start = start.to(e.device)
    rows = (torch.arange(len(start), device=e.device) if rows is None
            else rows.to(e.device))
    idx = (rows * e.shape[1] + start)[:, None] + torch.arange(n, device=e.device)
    return e.reshape(-1)[idx], i.reshape(-1)[idx]


class TextureNet(nn.Module):
    """Features -> standardised MLP -> (grain m, log std, probabilities ``(batch, 5)``).

    With ``high_columns`` ``(cues, first)`` a second MLP of the same widths, with its own
    heads, reads the first ``cues`` feature columns and those from ``first`` on alone, and the
    net answers for the pair (:meth:`heads`); each is trained on its own loss, as members of an
    ensemble (:meth:`branches`).
    """

    def __init__(self, features: WhiskFeatures, scale: torch.Tensor, hidden: list[int],
                 n_classes: int = 5, high_columns: tuple[int, int] | None = None) -> None:
        super().__init__()
        self.features = features
        self.register_buffer("scale", scale)  # (2, n_features): mean, std
        self.high_columns = high_columns
        self.body, self.classes, self.grain = self._mlp(features.n_features, hidden, n_classes)
        self.high = None
        if high_columns is not None:
            cues, first = high_columns
            self.high = nn.ModuleList(self._mlp(cues + features.n_features - first, hidden,
                                                n_classes))
        self.register_buffer("log_grain", torch.tensor([np.log(30e-6), 0.5]))  # mean, spread

    @staticmethod
    def _mlp(width: int, hidden: list[int], n_classes: int) -> tuple[nn.Module, ...]:
        """A branch: its body, class head and grain head (mean, log std)."""
        layers = []
        for h in hidden:
            layers += [nn.Linear(width, h), nn.GELU()]
            width = h
        return nn.Sequential(*layers), nn.Linear(width, n_classes), nn.Linear(width, 2)

    def branches(self, x: torch.Tensor) -> list[tuple[torch.Tensor, ...]]:
        """Features ``(batch, n_features)`` -> per branch (the full columns first, then the
        high ones): logits ``(batch, 5)``, ln grain mean and log std ``(batch,)``."""
        z = (x - self.scale[0]) / self.scale[1]
        pairs = [((self.body, self.classes, self.grain), z)]
        if self.high is not None:
            cues, first = self.high_columns
            pairs.append((self.high, torch.cat([z[:, :cues], z[:, first:]], 1)))
        out = []
        for (body, classes, grain), zb in pairs:
            h = body(zb)
            g = grain(h)
            out.append((classes(h), self.log_grain[0] + self.log_grain[1] * g[:, 0],
                        g[:, 1] + torch.log(self.log_grain[1])))
        return out

    def heads(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Features ``(batch, n_features)`` -> logits ``(batch, 5)``, ln grain mean and
        log std ``(batch,)``. Two branches answer together: the mean of their log
        probabilities as logits (the normalised geometric mean of their probabilities), and
        the moments of the equal mixture of their ln-grain Gaussians."""
        out = self.branches(x)
        if len(out) == 1:
            return out[0]
        (la, ma, sa), (lb, mb, sb) = out
        logits = 0.5 * (fn.log_softmax(la, -1) + fn.log_softmax(lb, -1))
        var = 0.5 * (torch.exp(2 * sa) + torch.exp(2 * sb)) + 0.25 * (ma - mb) ** 2
        return logits, 0.5 * (ma + mb), 0.5 * torch.log(var)

    def from_features(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The outputs from features ``(batch, n_features)`` already computed."""
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
        band_frame_s: the band powers' DFT frame, s (:class:`BandPowers`; rounded to an even
            number of samples, at most the window); None: no band powers (the decoder before
            issue 25 §3). Measured on 240 held-out specimens of the texture scene, 640
            training (per window, 0.25 s): none 86.1 %, 10 ms 89.3 %, 20 ms 89.3 %, 40 ms
            89.2 %; 10 ms costs the least (half the multiply-adds of 20 ms).
        high_band_hz: a second branch (:class:`TextureNet`) reads the whisk cues and the band
            powers whose bands start at or above this frequency, Hz, alone (not the residual's
            RMS, its lags or the lower bands), and the decoder answers for both branches: the
            asperities' impulses arrive at 4-33 kHz (physics.md §11), and held-out LuGre
            moved the residual's RMS, lags and bands below ~3 kHz most (its bristle rings at
            the reversals at 1.4-14 kHz over the prior, much of it lower).
            ``configs/texture.yaml`` trained on 1280 specimens (29 Nov; windows of 300
            held-out specimens a row): one branch 87.3 % in family, 69.5 % on LuGre (held
            out), 80.2 % with a pre-sliding compliance (held out); two 88.5, 80.6 and 85.7 %.
            A stand-in (the features, sklearn's MLP) read the high branch alone at 86.0 % in
            family: alone it would cost. None, or no band powers: one branch (the decoder
            before 29 Nov).
        lr, weight_decay: as every decoder.
    """

    TASK = "texture"
    LEGACY_HPARAMS = {"band_frame_s": None, "high_band_hz": None}

    def __init__(self, hidden: list[int] | None = None, window_s: float = 0.25,
                 grain_weight: float = 0.5, band_frame_s: float | None = 0.01,
                 high_band_hz: float | None = 4000.0,
                 lr: float = 3e-3, weight_decay: float = 1e-4) -> None:
        super().__init__(lr, weight_decay)
        hidden = [64, 64] if hidden is None else list(hidden)
        check_widths("model.hidden", hidden)
        check_positive("model.window_s", window_s, 100.0)
        check_positive("model.grain_weight", grain_weight, 1e6)
        if band_frame_s is not None:
            check_positive("model.band_frame_s", band_frame_s, 100.0)
        if high_band_hz is not None:
            check_positive("model.high_band_hz", high_band_hz, 1e7)
        self.save_hyperparameters()

    def feature_layer(self, scene) -> WhiskFeatures:
        """A new feature layer for ``scene``'s rate, calibration and this decoder's frame.

        Raises:
            ConfigError: ``band_frame_s`` under 16 samples at the scene's rate."""
        rate = scene.acquisition.sample_rate_hz
        frame_s = self.hparams.band_frame_s
        frame = None if frame_s is None else 2 * int(round(frame_s * rate / 2))
        if frame is not None and frame < 16:
            raise ConfigError(f"model.band_frame_s must be at least 16 samples "
                              f"({16 / rate:.3g} s at {rate:g} S/s), got {frame_s:g}")
        return WhiskFeatures(scene.calibration_hz, rate, frame)

    def window(self, scene) -> int:
        """The window in samples at the scene's rate: at least one period of the scene's
        slowest whisk (the features fit the whisk's harmonics over it; shorter windows
        also multiply the domain gate's windows, one per window of every training record,
        until they exhaust memory: 1e-5 s made 16 M), at most a record."""
        rate = scene.acquisition.sample_rate_hz
        n = int(round(self.hparams.window_s * rate))
        feats = self.feature_layer(scene)
        frame = 0 if feats.bands is None else feats.bands.frame
        shortest = max(math.ceil(rate / scene.drive.whisk_hz[0]), 3 * feats.lag + 1, frame)
        if not shortest <= n <= scene.n_samples:
            raise ConfigError(f"model.window_s must be in [{shortest / rate:.4g}, "
                              f"{scene.n_samples / rate:g}] s for this scene (one period of "
                              f"its slowest whisk, {scene.drive.whisk_hz[0]:g} Hz, and a band "
                              f"frame, to a whole record), got {self.hparams.window_s:g}")
        return n

    def domain_features(self, scene) -> tuple[nn.Module, int]:
        """The net's own feature layer, the same module, so the exported graph computes the
        features once for the net and its gate (a new one before the net exists)."""
        features = self.net.features if self.net is not None else self.feature_layer(scene)
        return features, features.n_features

    def build_net(self, scene, e, i, t_re, t_im, targets) -> nn.Module:
        feats = self.feature_layer(scene)
        self._n = self.window(scene)
        with torch.no_grad():
            x = torch.cat([feats(e[s:s + 64, :self._n], i[s:s + 64, :self._n],
                                 t_re[s:s + 64], t_im[s:s + 64])
                           for s in range(0, len(e), 64)])
        return self.net_on(feats, x, targets)

    def net_on(self, feats: WhiskFeatures, x: torch.Tensor, targets: torch.Tensor
               ) -> TextureNet:
        """A new net on feature layer ``feats``, standardised over ``x`` ``(n, n_features)``
        (the features of the first window of every training record), its ln-grain prior
        from the targets ``(n, 2)`` (grade, grain m); its weights drawn from torch's RNG."""
        scale = torch.stack([x.mean(0), x.std(0).clamp_min(1e-6)])
        net = TextureNet(feats, scale, list(self.hparams.hidden),
                         high_columns=self.high_columns(feats))
        logd = torch.log(targets[:, 1])
        net.log_grain.copy_(torch.stack([logd.mean(), logd.std().clamp_min(1e-3)]))
        return net

    def high_columns(self, feats: WhiskFeatures) -> tuple[int, int] | None:
        """The high branch's columns of ``feats`` (:class:`TextureNet`'s ``high_columns``):
        the whisk cues and the first band starting at or above ``high_band_hz``; None without
        that branch (or without band powers).

        Raises:
            ConfigError: no band starts at or above ``high_band_hz`` at the scene's rate."""
        top = self.hparams.high_band_hz
        if top is None or feats.bands is None:
            return None
        starts = feats.bands.edges[:-1]
        above = np.flatnonzero(starts >= top * (1 - 1e-9))
        if not len(above):
            raise ConfigError(f"model.high_band_hz must leave a band below the Nyquist "
                              f"({starts[-1]:g} Hz at {feats.rate:g} S/s is the last band's "
                              f"start), got {top:g}")
        return WhiskFeatures.CUE_COLUMNS, WhiskFeatures.N_FEATURES + int(above[0])

    def gate_inputs(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor,
                    t_im: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """Every whole window of the training records, ``(n · per, window)`` each, with its
        record's T."""
        n = self._n
        per = e.shape[1] // n
        return (e[:, :per * n].reshape(-1, n), i[:, :per * n].reshape(-1, n),
                t_re.repeat_interleave(per, 0), t_im.repeat_interleave(per, 0))

    def net_shape(self) -> dict:
        bands = self.net.features.bands
        return {"window": self._n, "band_frame": None if bands is None else bands.frame,
                "high_band_hz": self.hparams.high_band_hz}

    def build_from_checkpoint(self, shape: dict) -> None:
        """The net's shape as trained: its window, its band frame (samples; a checkpoint
        from before the band powers has none, and is rebuilt without them) and its high
        branch (a checkpoint from before 29 Nov has none)."""
        from wtml.scenes import scene_from_dict

        scene = scene_from_dict(self.scene)
        self._n = int(shape["window"])
        frame = shape.get("band_frame")
        if frame is None:
            self.hparams.band_frame_s = None
        self.hparams.high_band_hz = shape.get("high_band_hz")
        feats = WhiskFeatures(scene.calibration_hz, scene.acquisition.sample_rate_hz, frame)
        self.net = TextureNet(feats, torch.ones(2, feats.n_features), list(self.hparams.hidden),
                              high_columns=self.high_columns(feats))

    def loss(self, batch) -> torch.Tensor:
        """Training: a random window of every record (uniform start, from torch's RNG);
        otherwise its first window."""
        e, i, t_re, t_im, targets = batch
        n = self._n
        if self.training and e.shape[1] > n:
            e, i = crop(e, i, torch.randint(0, e.shape[1] - n + 1, (len(e),)), n)
        else:
            e, i = e[:, :n], i[:, :n]
        return self.feature_loss(self.net.features(e, i, t_re, t_im), targets)

    def feature_loss(self, x: torch.Tensor, targets: torch.Tensor) -> torch.Tensor:
        """The loss of the windows' features ``x`` ``(batch, n_features)`` against their
        targets ``(batch, 2)`` (grade, grain m): the grade's cross-entropy plus
        ``grain_weight`` times the Gaussian NLL of ln grain, summed over the net's branches
        (each learns alone, as an ensemble's members do)."""
        total = 0.0
        for logits, mu, log_sd in self.net.branches(x):
            ce = fn.cross_entropy(logits, targets[:, 0].long())
            z = (torch.log(targets[:, 1]) - mu) / torch.exp(log_sd)
            nll = (0.5 * z**2 + log_sd).mean()
            total = total + ce + self.hparams.grain_weight * nll
        return total
