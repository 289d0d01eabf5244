"""Two texture references beside the decoder and the thesis's cues (thesis §4.6).

- :class:`MiniRocketPeer`: the strong off-the-shelf baseline, MiniRocket (aeon) on the raw
  e(t), i(t) windows, each channel scaled by its training std (multivariate MiniRocket sums
  the channels' convolutions: unscaled, the current, ~1e-5 A beside ~10 V, would not count),
  then aeon's ridge classifier.
- :class:`KineticSignature`: the hypothesis the thesis refuted: sweeping at speed v over grains
  of size d puts a spectral peak at ``f = v/d``. It takes the strongest peak of the current's
  spectrum above ``low_hz`` and the RMS tip speed (``|V|/√2`` through the calibrated T), and
  names the grade whose ``v/d`` is nearest the peak (in log frequency); its grain size is
  ``v/f``.

Both predict from ``(n, window)`` arrays of e (V) and i (A): ``{"grade": (n,) int,
"grain": (n,) m}`` (MiniRocket names no grain size: NaN).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.signal import welch

from wtml.cores import available_cores
from wtml.decoders.texture import WhiskFeatures
from wtml.physics.twoport import flat_parts


class MiniRocketPeer:
    """MiniRocket on raw windows. ``n_kernels`` as aeon's default (10000)."""

    name = "MiniRocket (aeon)"

    def __init__(self, n_kernels: int = 10000, seed: int = 0) -> None:
        self.n_kernels, self.seed = n_kernels, seed
        self.model, self.scale = None, None

    @staticmethod
    def _stack(e: np.ndarray, i: np.ndarray) -> np.ndarray:
        """Windows as aeon's MiniRocket computes on them, ``(n, 2 channels, window)`` float32
        (one copy: at float64 the main job's 1280 training windows took 0.8 GB in copies)."""
        return np.stack([e, i], 1).astype(np.float32, copy=False)

    def fit(self, e: np.ndarray, i: np.ndarray, grade: np.ndarray) -> MiniRocketPeer:
        """Fit on windows ``(n, window)`` of known grade ``(n,)``; each channel is divided by
        its std over them."""
        from aeon.classification.convolution_based import MiniRocketClassifier

        x = self._stack(e, i)
        self.scale = x.std(axis=(0, 2), dtype=np.float64, keepdims=True).astype(np.float32)
        x /= self.scale
        self.model = MiniRocketClassifier(n_kernels=self.n_kernels, random_state=self.seed,
                                          n_jobs=available_cores())
        self.model.fit(x, np.asarray(grade))
        return self

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray | None = None
                ) -> dict[str, np.ndarray]:
        """The grade of each window; ``t`` (the device's calibrated T) is not used: MiniRocket
        reads the raw samples, so it cannot adapt to the device."""
        if self.model is None:
            raise RuntimeError("MiniRocketPeer.predict before fit")
        x = self._stack(e, i)
        x /= self.scale
        grade = self.model.predict(x).astype(int)
        return {"grade": grade, "grain": np.full(len(grade), np.nan)}


class KineticSignature:
    """The peak nearest ``v/d`` (module docstring).

    Args:
        features: the decoder's feature layer (for |V| through the calibrated T).
        sizes_m: the classes' mean grain sizes ``(5,)``, m.
        rate_hz: the sampling rate; ``low_hz``: peaks below are the whisking's own.
    """

    name = "kinetic signature (peak nearest v/d)"

    def __init__(self, features: WhiskFeatures, sizes_m: np.ndarray, rate_hz: float,
                 low_hz: float = 1000.0) -> None:
        self.features, self.sizes = features, np.asarray(sizes_m, float)
        self.rate, self.low = float(rate_hz), float(low_hz)

    def peaks(self, i: np.ndarray) -> np.ndarray:
        """The frequency (Hz) of the strongest peak of each window's current above
        ``low_hz``, ``(n,)`` (Welch, 2048-sample segments: 25 Hz bins at 51.2 kS/s)."""
        freq, psd = welch(i, fs=self.rate, nperseg=min(2048, i.shape[1]), axis=-1)
        band = freq >= self.low
        return freq[band][np.argmax(psd[:, band], axis=1)]

    @torch.no_grad()
    def speed(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> np.ndarray:
        """RMS tip speed ``|V|/√2`` (m/s) at the fundamental, ``(n,)``, through each window's
        calibrated T ``t`` (complex ``(n, K, 2, 2)``)."""
        t_re, t_im = flat_parts(t)
        _, (_, _, v_re, v_im, _, _), _ = self.features.cues(
            torch.tensor(e, dtype=torch.float32), torch.tensor(i, dtype=torch.float32),
            torch.tensor(t_re), torch.tensor(t_im))
        return np.hypot(v_re.double().numpy(), v_im.double().numpy()) / np.sqrt(2)

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        peak, v = self.peaks(i), self.speed(e, i, t)
        expected = v[:, None] / self.sizes[None, :]  # (n, 5): v/d of each grade
        grade = np.argmin(np.abs(np.log(expected / peak[:, None])), axis=1)
        return {"grade": grade, "grain": v / peak}
