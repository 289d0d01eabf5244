"""The thesis's onset pipeline (Figure 5.11, physics.md §10), as an exportable torch module,
and a change-point peer (ruptures) on the same |Zm(t)|.

Equal-length linear-phase FIR filters split e and i into the whisking band (a low-pass) and
the probe band; the probe band's filter is complex, ``h(n) e^{jωH n/fs}`` with ``h`` a
low-pass prototype: its real part is the band-pass and its imaginary part the band-pass's FIR
Hilbert transform, so it yields the analytic signals ``E_H(t), I_H(t)`` directly, with the
same delay as the low-pass (all filters applied centred: offline, zero delay). Then
``Zm(t) = (t22 E_H - t12 I_H)/(t11 I_H - t21 E_H)`` with the calibrated T at ωH (the user's
calibration of their device: an input, as the decoder's), contact
where ``|Zm(t)|`` exceeds half of ``k_ref/ωH`` (k_ref: the middle of the scene's contact
stiffness range), and the location ``u(t_c) = HUE(0) e_L(t_c)`` averaged over every rising
(onset) and falling (detachment) edge. The filters' first and last half-lengths (19 ms at
the defaults) see the record's edges and are left undecided (no contact).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.signal import firwin
from torch import nn
from torch.nn import functional as fn

from wtml.decoders.layers import ZmFromEI


def band_filters(sample_rate: float, probe_hz: float, taps: int = 1025, low_cut_hz: float = 150.0,
                 half_band_hz: float = 60.0) -> np.ndarray:
    """``(3, taps)``: the whisking low-pass, and the probe band's real (band-pass) and
    imaginary (its Hilbert transform) parts; Kaiser windows, ~100 dB stop band."""
    low = firwin(taps, low_cut_hz, window=("kaiser", 10.0), fs=sample_rate)
    proto = firwin(taps, half_band_hz, window=("kaiser", 10.0), fs=sample_rate)
    n = np.arange(taps) - (taps - 1) / 2
    carrier = np.exp(2j * np.pi * probe_hz * n / sample_rate)
    analytic = 2 * proto * carrier
    # correlation (conv1d) with the time-reversed taps is convolution with the taps
    return np.stack([low, analytic.real, analytic.imag])[:, ::-1].copy()


class ThesisOnset(nn.Module):
    """``(e, i)`` ``(batch, n)`` (V, A) and each record's calibration ``t_re, t_im`` ``(batch,
    4)`` (T at the probe) and ``hue0`` ``(batch,)`` (m/V) -> ``(gap, sigma, contact)``: the
    wall location (m; NaN without an edge), NaN (no uncertainty), and the contact state per
    sample ``(batch, n)``.

    Args:
        sample_rate, probe_hz: Hz.
        threshold: on |Zm|, N·s/m.
        taps: FIR length (odd).
    """

    def __init__(self, sample_rate: float, probe_hz: float, threshold: float,
                 taps: int = 1025) -> None:
        super().__init__()
        self.register_buffer("fir", torch.tensor(band_filters(sample_rate, probe_hz, taps)[:, None],
                                                 dtype=torch.float32))
        self.zm = ZmFromEI()
        self.threshold, self.pad = float(threshold), (taps - 1) // 2

    def bands(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor,
              hue0: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``u_L`` (m) and ``|Zm|`` (N·s/m) per sample, each ``(batch, n)``."""
        fe = fn.conv1d(fn.pad(e[:, None], (self.pad, self.pad)), self.fir)
        fi = fn.conv1d(fn.pad(i[:, None] * ZmFromEI.I_SCALE, (self.pad, self.pad)), self.fir[1:])
        zm_re, zm_im = self.zm(fe[:, 1], fe[:, 2], fi[:, 0], fi[:, 1], t_re, t_im)
        return hue0[:, None] * fe[:, 0], torch.sqrt(zm_re * zm_re + zm_im * zm_im)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor,
                hue0: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        u, zm = self.bands(e, i, t_re, t_im, hue0)
        # the filters' first and last half-lengths see the record's edges: no decision there
        inner = (zm[:, self.pad:-self.pad] > self.threshold).float()
        edge = torch.zeros_like(zm[:, :self.pad])
        contact = torch.cat([edge, inner, edge], -1)
        edges = torch.abs(contact[:, 1:] - contact[:, :-1])
        count = edges.sum(-1)
        gap = (edges * u[:, 1:]).sum(-1) / count
        nan = torch.full_like(gap, float("nan"))
        return torch.where(count > 0, gap, nan), nan, contact


def ruptures_contacts(zm_frames: np.ndarray, u_frames: np.ndarray, threshold: float,
                      penalty: float) -> tuple[float, np.ndarray]:
    """The peer: PELT change points (ruptures, l2 cost: ``KernelCPD`` with the linear kernel,
    ruptures's compiled PELT, which finds the same points as ``Pelt(model="l2")`` about a
    thousand times faster) on one record's |Zm| per probe frame;
    segments whose mean |Zm| exceeds ``threshold`` are contacts. Returns the location (mean
    ``u_L`` at every contact's two ends, m; NaN if none) and the per-frame contact state
    ``(n_frames,)`` bool."""
    import ruptures

    x = np.asarray(zm_frames, dtype=float)
    bkps = ruptures.KernelCPD(kernel="linear", min_size=2).fit(x).predict(pen=penalty)
    state = np.zeros(len(x), bool)
    start = 0
    for stop in bkps:
        if x[start:stop].mean() > threshold:
            state[start:stop] = True
        start = stop
    # the ends of each contact (adjacent contact segments are one contact: a segment end
    # inside a contact lies deep past the wall)
    edges = np.diff(np.concatenate([[0], state.astype(np.int8), [0]]))
    ends = np.concatenate([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1])
    gap = float(np.mean(u_frames[ends])) if len(ends) else float("nan")
    return gap, state
