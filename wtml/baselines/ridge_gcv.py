"""scikit-learn's ``RidgeClassifierCV`` for long features, in row blocks (MiniRocket's ridge).

:class:`BlockRidgeClassifierCV` is ``RidgeClassifierCV(alphas)`` with its defaults (an
unpenalised intercept, leave-one-out squared error over the ±1 targets, the first best
penalty on ties) where there are more rows than features: scikit-learn's ``cov`` mode, the
same algebra (the eigendecomposition ``Xcᵀ Xc = V L Vᵀ`` of the centred features), computed
``block`` rows at a time. scikit-learn's ``cov`` mode holds a centred copy of the features
and, for each of the penalties, a product of their size (``X @ H⁻¹``): at MiniRocket's 9996
features and 40960 windows that was 15.6 GB and 31 min on two cores, and at 81920 windows
about twice that, beyond this 24 GB machine. Here the features are read twice, in blocks,
and never copied whole: once for the centred ``Xcᵀ Xc`` and ``Xcᵀ Y``, once for
``Z = Xc V``, from which every penalty's leave-one-out errors follow (with
``D = 1/(L + α)``, ``b = Vᵀ Xcᵀ Yc``, ``u = Vᵀ Xcᵀ 1``):

- the fit's residual ``α c = Yc − Z (D b)``, and ``α d = 1 − Σ_j Z_ij² D_j − (1 − Z (D u))/n``
  (the intercept's correction), ``looe = α c / α d``;
- the coefficients ``w = V (D b)``, the intercept ``ȳ − x̄ · w``.

Held at once: the features (the caller's), two ``p × p`` float64 matrices (0.8 GB at 9996
features) and one block of ``Z``. ``tests/test_texture_bench.py`` holds it to scikit-learn's
penalty, coefficients, scores and predictions.
"""

from __future__ import annotations

import numpy as np
from sklearn.base import BaseEstimator, ClassifierMixin

BLOCK = 4096
"""Rows of the features per step of both passes (a block of ``Z``: 330 MB at 9996 features)."""


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
        """``y`` as scikit-learn's ``LabelBinarizer(neg_label=-1)``: ``(n, t)`` float64 ±1."""
        self.classes_, index = np.unique(y, return_inverse=True)
        if len(self.classes_) < 2:
            raise ValueError(f"y: at least two classes, got {len(self.classes_)}")
        targets = -np.ones((len(y), len(self.classes_)))
        targets[np.arange(len(y)), index] = 1.0
        return targets[:, 1:] if len(self.classes_) == 2 else targets

    @staticmethod
    def _blocks(n: int, block: int):
        return (slice(s, min(s + block, n)) for s in range(0, n, block))

    def fit(self, x: np.ndarray, y: np.ndarray) -> BlockRidgeClassifierCV:
        """Fit on features ``x`` ``(n, p)`` (float64, not changed) of classes ``y`` ``(n,)``.

        Raises:
            ValueError: a penalty or block out of range (:meth:`_checked`); ``n <= p``
                (scikit-learn's ``gram`` mode is the lean one there); rows of ``x`` and ``y``
                that differ in number; a feature that is not finite.
        """
        alphas, block = self._checked()
        n, p = x.shape
        if n <= p:
            raise ValueError(f"x: more rows than features for the blockwise ridge, got {n} "
                             f"rows of {p} (use sklearn's RidgeClassifierCV)")
        if len(y) != n:
            raise ValueError(f"y: one class per row of x ({n}), got {len(y)}")
        targets = self._targets(np.asarray(y))
        x_mean = np.zeros(p)
        for rows in self._blocks(n, block):
            if not np.isfinite(x[rows]).all():
                raise ValueError(f"x: features must be finite; rows {rows.start}-"
                                 f"{rows.stop - 1} hold NaN or inf")
            x_mean += x[rows].sum(0)
        x_mean /= n
        y_mean = targets.mean(0)
        centred_y = targets - y_mean
        cov, xt_y, xt_one = np.zeros((p, p)), np.zeros((p, targets.shape[1])), np.zeros(p)
        for rows in self._blocks(n, block):
            xc = x[rows] - x_mean
            cov += xc.T @ xc
            xt_y += xc.T @ centred_y[rows]
            xt_one += xc.sum(0)
        eigvals, v = np.linalg.eigh(cov)
        del cov
        b, u = v.T @ xt_y, v.T @ xt_one
        d = 1.0 / (eigvals[None, :] + np.array(alphas)[:, None])  # (a, p)
        squared = np.zeros(len(alphas))
        for rows in self._blocks(n, block):
            z = (x[rows] - x_mean) @ v
            leverage = (z * z) @ d.T  # (rows, a): diag(Xc H⁻¹ Xcᵀ)
            for a in range(len(alphas)):
                alpha_c = centred_y[rows] - z @ (d[a][:, None] * b)
                alpha_d = 1.0 - leverage[:, a] - (1.0 - z @ (d[a] * u)) / n
                squared[a] += ((alpha_c / alpha_d[:, None]) ** 2).sum()
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
