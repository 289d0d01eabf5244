"""The thesis's texture cues as the classical path (thesis §4.5): |F|, |V|, Re Zm, Im Zm at
the fundamental through the calibrated T, a quadratic fit of grain size in Re Zm (Figure 4.30:
Re Zm rises quadratically with d) and a nearest-class rule on the four cues (standardised, the
class centroids of the fitting data). Same outputs as the decoder; exported to ONNX.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from wtml.decoders.texture import WhiskFeatures
from wtml.physics.twoport import flat_parts


def cue_matrix(features: WhiskFeatures, e: np.ndarray, i: np.ndarray, t: np.ndarray,
               window: int, batch: int = 64) -> np.ndarray:
    """The four cues ``(n, 4)`` (N, m/s, N·s/m, N·s/m) of the first ``window`` samples, each
    record through its device's calibrated T ``t`` (complex ``(n, K, 2, 2)``)."""
    t_re, t_im = flat_parts(t)
    rows = []
    with torch.no_grad():
        for s in range(0, len(e), batch):
            x = features(torch.tensor(e[s:s + batch, :window]),
                         torch.tensor(i[s:s + batch, :window]),
                         torch.tensor(t_re[s:s + batch]), torch.tensor(t_im[s:s + batch]))
            rows.append(features.cues_from(x).double().numpy())
    return np.concatenate(rows)


class ClassicalTexture(nn.Module):
    """``(e, i)`` windows and the calibrated T (``t_re, t_im``, as the decoder's) ->
    ``(grain m, log_sigma (0: none), probabilities (batch, 5))``.

    Args:
        features: the shared feature layer (the cues are four of its columns).
        poly: coefficients of ``d = p0 + p1 x + p2 x²`` in ``x = Re Zm / 1e-3`` (d in µm).
        centroids: ``(5, 4)`` class centroids of the standardised cues; ``scale``: ``(2, 4)``.
    """

    def __init__(self, features: WhiskFeatures, poly: np.ndarray, centroids: np.ndarray,
                 scale: np.ndarray) -> None:
        super().__init__()
        self.features = features
        self.register_buffer("poly", torch.tensor(poly, dtype=torch.float32))
        self.register_buffer("centroids", torch.tensor(centroids, dtype=torch.float32))
        self.register_buffer("scale", torch.tensor(scale, dtype=torch.float32))

    @classmethod
    def fit(cls, features: WhiskFeatures, e: np.ndarray, i: np.ndarray, t: np.ndarray,
            grade: np.ndarray, grain_m: np.ndarray, window: int) -> ClassicalTexture:
        """Fit the quadratic and the centroids on records ``(n, >= window)`` of known grade
        and their devices' calibrated T ``(n, K, 2, 2)``."""
        cues = cue_matrix(features, e, i, t, window)
        poly = np.polyfit(cues[:, 2] / 1e-3, grain_m * 1e6, 2)[::-1].copy()
        scale = np.stack([cues.mean(0), cues.std(0) + 1e-30])
        z = (cues - scale[0]) / scale[1]
        centroids = np.stack([z[grade == k].mean(0) for k in range(5)])
        return cls(features, poly, centroids, scale)

    def from_features(self, features: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """The outputs from :class:`WhiskFeatures` ``(batch, N_FEATURES)`` already computed."""
        cues = WhiskFeatures.cues_from(features)
        z = (cues - self.scale[0]) / self.scale[1]
        dist = ((z[:, None, :] - self.centroids[None]) ** 2).sum(-1)
        x = cues[:, 2] / 1e-3
        d_um = self.poly[0] + self.poly[1] * x + self.poly[2] * x * x
        grain = d_um.clamp_min(1e-3) * 1e-6
        return grain, torch.zeros_like(grain), torch.softmax(-1e3 * dist, -1)

    def forward(self, e: torch.Tensor, i: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor
                ) -> tuple[torch.Tensor, ...]:
        return self.from_features(self.features(e, i, t_re, t_im))
