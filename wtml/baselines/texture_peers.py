"""Three texture references beside the decoder and the thesis's cues (thesis §4.6).

- :class:`MiniRocketPeer`: the strong off-the-shelf baseline, MiniRocket (aeon) on the raw
  e(t), i(t) windows, each channel scaled by its training std (multivariate MiniRocket sums
  the channels' convolutions: unscaled, the current, ~1e-5 A beside ~10 V, would not count),
  then aeon's ridge classifier.
- :class:`KineticSignature`: the hypothesis the thesis refuted: sweeping at speed v over grains
  of size d puts a spectral peak at ``f = v/d``. It takes the strongest peak of the current's
  spectrum above ``low_hz`` and the RMS tip speed (``|V|/√2`` through the calibrated T), and
  names the grade whose ``v/d`` is nearest the peak (in log frequency); its grain size is
  ``v/f``.
- :class:`BandPowerPeer`: the asperities' spectrum read directly: log band powers of the
  current in log-spaced bands from ~1 kHz up to the Nyquist of whatever rate it is given,
  each divided by ``|F1|²`` (the fundamental's force through the calibrated T: the unknown
  normal force scales both), beside the decoder's whisk features; gradient boosting
  (scikit-learn's HistGradientBoostingClassifier).

All predict from ``(n, window)`` arrays of e (V) and i (A): ``{"grade": (n,) int,
"grain": (n,) m}`` (MiniRocket and the band powers name no grain size: NaN).
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.signal import welch

from wtml.baselines.ridge_gcv import BlockRidgeClassifierCV
from wtml.cores import available_cores
from wtml.decoders.texture import WhiskFeatures, band_edges
from wtml.physics.twoport import flat_parts
from wtml.runtime.predict import rows_per_run

TRANSFORM_WINDOWS = 64
"""Windows that :class:`MiniRocketPeer`'s fit transforms at once (aeon copies them), and
rows of their features per step of its scaler's fit."""


class MiniRocketPeer:
    """MiniRocket on raw windows. ``n_kernels`` as aeon's default (10000).

    The classifier is aeon's ``MiniRocketClassifier``, its pipeline built here from the same
    three parts (aeon's ``MiniRocket`` transform, ``StandardScaler(with_mean=False)``, ridge
    over ``logspace(-3, 3, 10)``) so that its fit can go in two steps that hold less at once:
    :meth:`fit_transform_stacked` (the transform, :data:`TRANSFORM_WINDOWS` windows at a time,
    into one float64 array: the ridge computes in float64) and :meth:`fit_features` (the
    scaler, row blocks at a time, in place; the ridge: with more windows than features,
    :class:`~wtml.baselines.ridge_gcv.BlockRidgeClassifierCV`, scikit-learn's own computed in
    row blocks), the training windows free in between.
    aeon's own fit held +0.36 GB beside the main job's 1280 windows (131 MB): a float32 copy
    of them, the features, their float64 copy and its centred copy. The same model: its
    predictions and decision function are aeon's up to float rounding (its ridge sees float64
    features scaled in float64, where aeon scales float32 ones; ``tests/test_texture_bench.py``).
    """

    name = "MiniRocket (aeon)"

    def __init__(self, n_kernels: int = 10000, seed: int = 0) -> None:
        self.n_kernels, self.seed = n_kernels, seed
        self.model, self.scale, self._transform = None, None, None

    @staticmethod
    def _stack(e: np.ndarray, i: np.ndarray) -> np.ndarray:
        """Windows as aeon's MiniRocket computes on them, ``(n, 2 channels, window)`` float32
        (one copy: at float64 the main job's 1280 training windows took 0.8 GB in copies)."""
        return np.stack([e, i], 1).astype(np.float32, copy=False)

    def fit(self, e: np.ndarray, i: np.ndarray, grade: np.ndarray) -> MiniRocketPeer:
        """Fit on windows ``(n, window)`` of known grade ``(n,)``; each channel is divided by
        its std over them."""
        return self.fit_stacked(self._stack(e, i), grade)

    def fit_stacked(self, x: np.ndarray, grade: np.ndarray) -> MiniRocketPeer:
        """:meth:`fit` on windows already stacked as MiniRocket reads them, ``(n, 2, window)``
        float32 (e then i), which are divided in place by each channel's std: ``x`` is
        consumed, and the training set is not copied once more (131 MB in the main job)."""
        return self.fit_features(self.fit_transform_stacked(x), grade)

    @staticmethod
    def _refuse_copies(x: np.ndarray) -> None:
        """Stacked windows must be float32: aeon copies any other dtype (``TypeError``)."""
        if x.dtype != np.float32:
            raise TypeError(f"MiniRocketPeer: the stacked windows x must be float32, got "
                            f"{x.dtype}")

    @staticmethod
    def _channel_std(x: np.ndarray) -> np.ndarray:
        """Each channel's std over every window and sample of ``x`` ``(n, c, m)``, ``(1, c,
        1)`` float32: numpy's two passes (the mean, then the mean squared deviation) in
        float64, :data:`TRANSFORM_WINDOWS` windows at a time (``x.std(dtype=float64)`` made
        a float64 copy of ``x``: 8.4 GB at 40960 windows)."""
        parts = range(0, len(x), TRANSFORM_WINDOWS)
        count = x.shape[0] * x.shape[2]
        mean = sum(x[s:s + TRANSFORM_WINDOWS].sum((0, 2), dtype=np.float64)
                   for s in parts)[None, :, None] / count
        square = sum(((x[s:s + TRANSFORM_WINDOWS] - mean) ** 2).sum((0, 2)) for s in parts)
        return np.sqrt(square / count).astype(np.float32)[None, :, None]

    def fit_transform_stacked(self, x: np.ndarray) -> np.ndarray:
        """The first step of :meth:`fit_stacked`: scale ``x`` in place (consumed), fit the
        transform on it and return its features, ``(n, ~n_kernels)`` float64 (to
        :meth:`fit_features`; ``x`` can be freed before that step).

        Raises:
            TypeError: ``x`` is not float32 (it would be copied after all)."""
        from aeon.transformations.collection.convolution_based import MiniRocket

        self._refuse_copies(x)
        self.scale = self._channel_std(x)
        x /= self.scale
        self._transform = MiniRocket(n_kernels=self.n_kernels, random_state=self.seed,
                                     n_jobs=available_cores()).fit(x)
        features = None
        for start in range(0, len(x), TRANSFORM_WINDOWS):
            part = self._transform.transform(x[start:start + TRANSFORM_WINDOWS])
            if features is None:
                features = np.empty((len(x), part.shape[1]))
            features[start:start + len(part)] = part
        return features

    def fit_features(self, features: np.ndarray, grade: np.ndarray) -> MiniRocketPeer:
        """The second step of :meth:`fit_stacked`: the scaler and the ridge on the features
        of :meth:`fit_transform_stacked` (scaled in place: consumed) of windows of known
        grade ``(n,)``."""
        from sklearn.linear_model import RidgeClassifierCV
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler

        if self._transform is None:
            raise RuntimeError("MiniRocketPeer.fit_features before fit_transform_stacked")
        scaler = StandardScaler(with_mean=False, copy=False)
        for start in range(0, len(features), TRANSFORM_WINDOWS):
            scaler.partial_fit(features[start:start + TRANSFORM_WINDOWS])
        features = scaler.transform(features)
        alphas = np.logspace(-3, 3, 10)
        long = features.shape[0] > features.shape[1]
        ridge = (BlockRidgeClassifierCV(alphas) if long else RidgeClassifierCV(alphas=alphas)
                 ).fit(features, np.asarray(grade))
        scaler.set_params(copy=True)  # aeon's: predicting leaves a caller's features alone
        self.model = make_pipeline(self._transform, scaler, ridge)
        return self

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray | None = None
                ) -> dict[str, np.ndarray]:
        """The grade of each window; ``t`` (the device's calibrated T) is not used: MiniRocket
        reads the raw samples, so it cannot adapt to the device."""
        return self.predict_stacked(self._stack(e, i))

    def predict_stacked(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """:meth:`predict` on windows stacked as :meth:`fit_stacked` takes them,
        ``(n, 2, window)`` float32, which are divided in place by the training std
        (consumed).

        Raises:
            TypeError: ``x`` is not float32 (aeon would copy it)."""
        if self.model is None:
            raise RuntimeError("MiniRocketPeer.predict before fit")
        self._refuse_copies(x)
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
        calibrated T ``t`` (complex ``(n, K, 2, 2)``); :data:`~wtml.runtime.predict.RUN_BYTES`
        of windows at a time (the fit's intermediates are several times the windows)."""
        t_re, t_im = flat_parts(t)
        step = rows_per_run(8 * e.shape[1])
        v = []
        for k in range(0, len(e), step):
            _, (_, _, v_re, v_im, _, _), _ = self.features.cues(
                torch.tensor(e[k:k + step], dtype=torch.float32),
                torch.tensor(i[k:k + step], dtype=torch.float32),
                torch.tensor(t_re[k:k + step]), torch.tensor(t_im[k:k + step]))
            v.append(np.hypot(v_re.double().numpy(), v_im.double().numpy()))
        return np.concatenate(v) / np.sqrt(2)

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        peak, v = self.peaks(i), self.speed(e, i, t)
        expected = v[:, None] / self.sizes[None, :]  # (n, 5): v/d of each grade
        grade = np.argmin(np.abs(np.log(expected / peak[:, None])), axis=1)
        return {"grade": grade, "grain": v / peak}


FEATURE_CHUNK = 128
"""Windows whose band-power features are computed at once."""
WHISK_COLUMNS = 7 + 2 * 2
"""The whisk features kept from :class:`~wtml.decoders.texture.WhiskFeatures` (its first
columns: ω/ω_ref, ln|E|, ln|I|, ln|F|, ln|V|, Re Zm, Im Zm and the 2nd and 3rd harmonics of
i): those that do not depend on the sampling rate (its residual's lags are in samples)."""


class BandPowerPeer:
    """Band powers of the current over ``|F1|²`` and the whisk features -> gradient boosting.

    Args:
        calibration_hz: the frequencies of the calibrated T each window carries ``(K,)``, Hz.
        rate_hz: the windows' sampling rate, Hz.
        low_hz: the lowest band's bottom edge (about: the edge at or below it), Hz.
        top_hz: the highest band's top (at most the Nyquist; None: the Nyquist), Hz.
        segment_s: Welch's segment (Hann, half overlap), s: 40 ms, 25 Hz resolution (the
            narrowest band, at ~1 kHz, holds 3 bins).
        max_iter, seed: the classifier's boosting iterations and random state.

    Features per window ``(n, n_bands + WHISK_COLUMNS)``: ``ln(P_b / |F1|²)`` with ``P_b`` the
    current's power in band b (A², Welch's PSD summed over the band's bins times their width)
    and ``|F1|`` the fundamental's force amplitude (N) through the window's calibrated T, then
    the rate-free whisk features (:data:`WHISK_COLUMNS`).
    """

    def __init__(self, calibration_hz, rate_hz: float, *, low_hz: float = 1000.0,
                 top_hz: float | None = None, segment_s: float = 0.04, max_iter: int = 300,
                 seed: int = 0) -> None:
        self.rate = float(rate_hz)
        self.edges = band_edges(self.rate, low_hz, top_hz)
        self.features_layer = WhiskFeatures(calibration_hz, self.rate)
        self.segment = max(16, int(round(segment_s * self.rate)))
        self.max_iter, self.seed = max_iter, seed
        self.model = None
        top = self.edges[-1] / 1e3
        self.name = f"band powers ({self.rate / 1e3:g} kS/s, to {top:g} kHz)"

    def band_powers(self, i: np.ndarray) -> np.ndarray:
        """The current's power in each band, A², ``(n, n_bands)``, from windows ``(n, m)``."""
        freq, psd = welch(np.asarray(i, np.float64), fs=self.rate,
                          nperseg=min(self.segment, np.shape(i)[1]), axis=-1)
        which = np.searchsorted(self.edges, freq, side="right") - 1  # the band of each bin
        inside = (which >= 0) & (which < len(self.edges) - 1)
        if len(np.unique(which[inside])) < len(self.edges) - 1:
            raise ValueError(f"windows of {np.shape(i)[1]} samples resolve {freq[1]:g} Hz: "
                             f"too coarse for the narrowest band "
                             f"({self.edges[1] - self.edges[0]:.0f} Hz); use longer windows")
        power = np.zeros((len(psd), len(self.edges) - 1))
        np.add.at(power.T, which[inside], psd[:, inside].T * (freq[1] - freq[0]))
        return power

    def features(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Windows e (V), i (A) ``(n, m)`` and their calibrated T (complex ``(n, K, 2, 2)``)
        -> features ``(n, n_bands + WHISK_COLUMNS)`` (see the class docstring), computed
        :data:`FEATURE_CHUNK` windows at a time (Welch's segments of all 1280 training windows
        at once took 0.6 GB).

        Raises:
            ValueError: no windows."""
        if len(e) == 0:
            raise ValueError("BandPowerPeer: no windows (e has 0 rows)")
        return np.concatenate([self._features(e[k:k + FEATURE_CHUNK], i[k:k + FEATURE_CHUNK],
                                              t[k:k + FEATURE_CHUNK])
                               for k in range(0, len(e), FEATURE_CHUNK)])

    @torch.no_grad()
    def _features(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> np.ndarray:
        t_re, t_im = flat_parts(t)
        args = (torch.tensor(np.asarray(e, np.float32)), torch.tensor(np.asarray(i, np.float32)),
                torch.tensor(t_re), torch.tensor(t_im))
        whisk = self.features_layer(*args)[:, :WHISK_COLUMNS].numpy()
        f1 = 2 * whisk[:, 3]  # ln |F1|²
        bands = np.log(np.clip(self.band_powers(i), 1e-300, None)) - f1[:, None]
        return np.concatenate([bands, whisk], 1)

    def fit_features(self, x: np.ndarray, grade: np.ndarray) -> BandPowerPeer:
        """Fit on features ``(n, n_features)`` (:meth:`features`) of known grade ``(n,)``."""
        from sklearn.ensemble import HistGradientBoostingClassifier

        self.model = HistGradientBoostingClassifier(max_iter=self.max_iter,
                                                    random_state=self.seed)
        self.model.fit(x, np.asarray(grade))
        return self

    def fit(self, e: np.ndarray, i: np.ndarray, t: np.ndarray, grade: np.ndarray
            ) -> BandPowerPeer:
        """Fit on windows e, i ``(n, m)`` with their calibrated T of known grade ``(n,)``."""
        return self.fit_features(self.features(e, i, t), grade)

    def predict_features(self, x: np.ndarray) -> dict[str, np.ndarray]:
        """The grade of each row of features ``(n, n_features)``; no grain size (NaN)."""
        if self.model is None:
            raise RuntimeError("BandPowerPeer.predict before fit")
        grade = self.model.predict(x).astype(int)
        return {"grade": grade, "grain": np.full(len(grade), np.nan)}

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        """The grade of each window e, i ``(n, m)`` with its calibrated T."""
        return self.predict_features(self.features(e, i, t))
