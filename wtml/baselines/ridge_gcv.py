"""scikit-learn's ``RidgeClassifierCV`` for long features, in row blocks (MiniRocket's ridge).

:class:`BlockRidgeClassifierCV` is ``RidgeClassifierCV(alphas)`` with its defaults (an
unpenalised intercept, leave-one-out squared error over the ±1 targets, the first best
penalty on ties) where there are more rows than features: scikit-learn's ``cov`` mode, the
same algebra (the eigendecomposition ``Xcᵀ Xc = V L Vᵀ`` of the centred features), computed
``block`` rows at a time. scikit-learn's ``cov`` mode holds a centred copy of the features
and, for each of the penalties, a product of their size (``X @ H⁻¹``): at MiniRocket's 9996
features and 40960 windows that was 15.6 GB and 31 min on two cores, and at 81920 windows
about twice that, beyond this 24 GB machine. Here the features are read in three passes, a
block of rows at a time in float64, and never copied whole: their mean (and that they are
finite); the centred ``Xcᵀ Xc`` and ``Xcᵀ Yc``; ``Z = Xc V``, from which every penalty's
leave-one-out errors follow, with ``D = 1/(L + α)`` and ``b = Vᵀ Xcᵀ Yc``:

- the fit's residual ``α c = Yc − Z (D b)``, and ``α d = 1 − Σ_j Z_ij² D_j − 1/n`` (the last
  term is the intercept's: scikit-learn's ``(1 − Z D Vᵀ Xcᵀ 1)/n``, whose ``Xcᵀ 1`` is zero
  but for rounding), ``looe = α c / α d``;
- the coefficients ``w = V (D b)``, the intercept ``ȳ − x̄ · w``.

Held at once beside the features (the caller's, left as they are): ``Xcᵀ Xc`` (0.8 GB at
9996 features), overwritten by its eigendecomposition (SciPy's ``evr``, which adds ``V`` and
a workspace of order ``p``: numpy's ``eigh`` holds two ``p × p`` more), and about three
blocks of rows. At 81920 windows (``wtml bench texture-scale``, 30 Nov): ~295 s on two
cores, 9.5 GB of RSS with the 6.5 GB of features. ``tests/test_texture_bench.py`` holds it
to scikit-learn's scores, penalty, coefficients and predictions.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import eigh
from sklearn.base import BaseEstimator, ClassifierMixin

BLOCK = 4096
"""Rows of the features per step of each pass (a block of ``Z``: 330 MB at 9996 features)."""


class BlockRidgeClassifierCV(ClassifierMixin, BaseEstimator):
    """``sklearn.linear_model.RidgeClassifierCV(alphas)`` for features ``(n, p)``, ``n > p``,
    in row blocks (module docstring); ``block`` None: :data:`BLOCK`, read at the fit. A
    scikit-learn estimator: it ends a ``Pipeline``, its parameters are checked at the fit.

    After :meth:`fit`: ``classes_ (k,)``, ``cv_scores_ (a,)`` (each penalty's minus mean
    leave-one-out squared error), ``alpha_`` and its ``best_score_``, ``coef_`` and
    ``intercept_``: ``(k, p)`` and ``(k,)``, or for two classes ``(p,)`` and ``(1,)``, as
    scikit-learn's.
    """

    def __init__(self, alphas=(0.1, 1.0, 10.0), block: int | None = None) -> None:
        self.alphas, self.block = alphas, block

    def _checked(self) -> tuple[list[float], int]:
        """The penalties and the block, checked.

        Raises:
            ValueError: a penalty that is not finite and > 0, none, a block below 1 row."""
        alphas = [float(a) for a in np.atleast_1d(self.alphas)]
        if not alphas or not all(np.isfinite(a) and a > 0 for a in alphas):
            raise ValueError(f"alphas: finite penalties > 0, got {self.alphas!r}")
        block = BLOCK if self.block is None else self.block
        if isinstance(block, bool) or not isinstance(block, int) or block < 1:
            raise ValueError(f"block: a whole number of rows >= 1, got {block!r}")
        return alphas, block

    def _targets(self, y: np.ndarray) -> np.ndarray:
        """``y`` ``(n,)`` as scikit-learn's ``LabelBinarizer(neg_label=-1)``: ``(n, t)``
        float64 ±1, ``t`` 1 for two classes (the second's column), else one per class."""
        self.classes_, index = np.unique(y, return_inverse=True)
        if len(self.classes_) < 2:
            raise ValueError(f"y: at least two classes, got {len(self.classes_)}")
        targets = -np.ones((len(y), len(self.classes_)))
        targets[np.arange(len(y)), index] = 1.0
        return targets[:, 1:] if len(self.classes_) == 2 else targets

    @staticmethod
    def _blocks(x: np.ndarray, block: int):
        """``(rows, x[rows] in float64)`` for each block of ``block`` rows of ``x``."""
        for s in range(0, len(x), block):
            rows = slice(s, min(s + block, len(x)))
            yield rows, x[rows].astype(np.float64, copy=False)

    def fit(self, x: np.ndarray, y: np.ndarray) -> BlockRidgeClassifierCV:
        """Fit on features ``x`` ``(n, p)`` (any real dtype, computed in float64; not
        changed) of classes ``y`` ``(n,)``.

        Raises:
            ValueError: a penalty or block out of range (:meth:`_checked`); ``x`` not 2-D or
                ``n <= p`` (scikit-learn's ``gram`` mode is the lean one there); ``y`` not
                one class per row of ``x``; a feature that is not finite.
        """
        alphas, block = self._checked()
        if np.ndim(x) != 2:
            raise ValueError(f"x: features (n, p), got shape {np.shape(x)}")
        n, p = x.shape
        if n <= p:
            raise ValueError(f"x: more rows than features for the blockwise ridge, got {n} "
                             f"rows of {p} (use sklearn's RidgeClassifierCV)")
        y = np.asarray(y)
        if y.shape != (n,):
            raise ValueError(f"y: one class per row of x, shape ({n},), got {y.shape}")
        targets = self._targets(y)
        x_mean = np.zeros(p)
        for rows, part in self._blocks(x, block):
            if not np.isfinite(part).all():
                raise ValueError(f"x: features must be finite; rows {rows.start}-"
                                 f"{rows.stop - 1} hold NaN or inf")
            x_mean += part.sum(0)
        x_mean /= n
        y_mean = targets.mean(0)
        centred_y = targets - y_mean
        cov, xt_y = np.zeros((p, p)), np.zeros((p, targets.shape[1]))
        for rows, part in self._blocks(x, block):
            part = part - x_mean
            cov += part.T @ part
            xt_y += part.T @ centred_y[rows]
        del part
        eigvals, v = eigh(cov, overwrite_a=True, check_finite=False)
        del cov
        b = v.T @ xt_y
        d = 1.0 / (eigvals[None, :] + np.array(alphas)[:, None])  # (a, p)
        squared = np.zeros(len(alphas))
        for rows, part in self._blocks(x, block):
            z = (part - x_mean) @ v
            leverage = (z * z) @ d.T  # (rows, a): diag(Xc H⁻¹ Xcᵀ)
            for a in range(len(alphas)):
                alpha_c = centred_y[rows] - z @ (d[a][:, None] * b)
                alpha_d = 1.0 - leverage[:, a] - 1.0 / n
                squared[a] += ((alpha_c / alpha_d[:, None]) ** 2).sum()
            del z
        self.cv_scores_ = -squared / centred_y.size
        best = int(np.argmax(self.cv_scores_))  # the first of equal scores, as scikit-learn's
        self.alpha_, self.best_score_ = alphas[best], float(self.cv_scores_[best])
        coef = (v @ (d[best][:, None] * b)).T
        self.intercept_ = y_mean - coef @ x_mean
        self.coef_ = coef.ravel() if len(coef) == 1 else coef  # as scikit-learn's
        return self

    def decision_function(self, x: np.ndarray) -> np.ndarray:
        """Each row's score ``(n,)`` for two classes, else ``(n, k)``."""
        if not hasattr(self, "coef_"):
            raise RuntimeError("BlockRidgeClassifierCV.decision_function before fit")
        return x @ self.coef_.T + self.intercept_

    def predict(self, x: np.ndarray) -> np.ndarray:
        """The class of each row of features ``x`` ``(n, p)``, ``(n,)``."""
        scores = self.decision_function(x)
        return self.classes_[(scores > 0).astype(int) if scores.ndim == 1
                             else scores.argmax(1)]
