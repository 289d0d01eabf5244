"""Export-safe building blocks: complex algebra written out in real arithmetic.

ONNX has no complex tensors, so a T on the grid is held as real and imaginary parts (buffers,
or the graph's inputs where the user's calibration is one) and Eq. 3.15 is evaluated by hand.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn


def t_elements(t_re: torch.Tensor, t_im: torch.Tensor) -> tuple[tuple, ...]:
    """``(t11, t12, t21, t22)`` as ``(re, im)`` pairs, each ``(batch, n_freq)``, from the
    flattened T ``(batch, n_freq, 4)`` (the order of ``T.reshape(..., 4)``)."""
    return tuple(zip(t_re.unbind(-1), t_im.unbind(-1), strict=True))


class ZmFromZe(nn.Module):
    """The user's calibrated T -> load impedance, in float32 real arithmetic, one T per sample.

    Eq. 3.15 in quotient form, ``Zm = (t22 Ze - t12) / (t11 - t21 Ze)``: two complex
    multiply-adds and one division per sample and frequency, 27 graph operations (the Möbius
    form ``A + B/(Ze - c)``, cheapest with a constant T, needs its constants from each sample's
    T: three divisions more). In float32 both lose the same (the inputs' rounding: 7e-6 and
    6e-6 of the largest |Zm| on the shipped scene's devices, the noise is 1e-4). No complex
    tensors and no linear solve, which do not export.

    Forward: ``ze_re, ze_im`` ``(batch, n_freq)`` in Ω and ``t_re, t_im`` ``(batch, n_freq,
    4)`` (:func:`t_elements`) -> ``zm_re, zm_im`` ``(batch, n_freq)`` in N·s/m.
    """

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return self.from_elements(ze_re, ze_im, t_elements(t_re, t_im))

    @staticmethod
    def from_elements(ze_re: torch.Tensor, ze_im: torch.Tensor, elements: tuple[tuple, ...]
                      ) -> tuple[torch.Tensor, torch.Tensor]:
        """The same from T's elements already split (:func:`t_elements`)."""
        (a11, b11), (a12, b12), (a21, b21), (a22, b22) = elements
        n_re = a22 * ze_re - b22 * ze_im - a12  # t22 Ze - t12
        n_im = a22 * ze_im + b22 * ze_re - b12
        d_re = a11 - (a21 * ze_re - b21 * ze_im)  # t11 - t21 Ze
        d_im = b11 - (a21 * ze_im + b21 * ze_re)
        mag2 = d_re * d_re + d_im * d_im
        return (n_re * d_re + n_im * d_im) / mag2, (n_im * d_re - n_re * d_im) / mag2


class ZmFromEI(nn.Module):
    """Eq. 5.6 on analytic signals or phasors: ``Zm = (t22 E - t12 I)/(t11 I - t21 E)`` with
    the user's calibrated T at one frequency (an input: each device has its own), in float32
    real arithmetic, written out by hand (no complex tensors, no linear solve). The current
    enters in µA (T's current-side elements are scaled to match), which keeps both terms of
    each difference of similar size in float32.

    Forward: ``e_re, e_im`` (V) and ``i_re, i_im`` (µA), each ``(batch, n)``, and the T of
    each record ``t_re, t_im`` ``(batch, 4)`` (t11, t12, t21, t22: the order of
    ``T.reshape(..., 4)``, T in SI as :meth:`~wtml.physics.beam.BeamTransducer.transduction_matrix`
    gives it) -> ``zm_re, zm_im`` ``(batch, n)`` (N·s/m).
    """

    I_SCALE = 1e6
    """A -> µA."""

    def forward(self, e_re: torch.Tensor, e_im: torch.Tensor, i_re: torch.Tensor,
                i_im: torch.Tensor, t_re: torch.Tensor, t_im: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        (a11, b11), (a12, b12), (a21, b21), (a22, b22) = t_elements(t_re[:, None],
                                                                    t_im[:, None])
        a11, b11, a12, b12 = (x / self.I_SCALE for x in (a11, b11, a12, b12))
        num_re = a22 * e_re - b22 * e_im - (a12 * i_re - b12 * i_im)
        num_im = a22 * e_im + b22 * e_re - (a12 * i_im + b12 * i_re)
        den_re = a11 * i_re - b11 * i_im - (a21 * e_re - b21 * e_im)
        den_im = a11 * i_im + b11 * i_re - (a21 * e_im + b21 * e_re)
        mag2 = den_re * den_re + den_im * den_im
        return ((num_re * den_re + num_im * den_im) / mag2,
                (num_im * den_re - num_re * den_im) / mag2)


class SignedLogZm(nn.Module):
    """Zm through the user's calibrated T as ``sign(x) log(1 + |x|)``, ``x = Zm / z_scale``,
    for Re and Im side by side (linear below ``z_scale``, logarithmic above: loads that span
    decades), then the device's own features (:meth:`device`): what the domain gate needs to
    tell a device outside the trained spread. Written with Abs/Log/Sign, which onnxruntime
    vectorises (its Asinh cost as much as an MLP).

    Args:
        z_scale: the knee, N·s/m.
        n_freq: points of the sweep grid (the device features' columns, as constants: read
            from the traced shapes, they took the graph eight operations more).

    Forward: ``ze_re, ze_im`` ``(batch, n_freq)`` in Ω, ``t_re, t_im`` ``(batch, n_freq, 4)``
    -> ``(batch, 2 n_freq + N_DEVICE)``.
    """

    N_DEVICE = 6
    """The device features (:meth:`device`)."""

    def __init__(self, z_scale: float, n_freq: int) -> None:
        super().__init__()
        self.zm = ZmFromZe()
        self.n_freq = n_freq
        self.register_buffer("z_scale", torch.tensor(float(z_scale)))

    def device(self, elements: tuple[tuple, ...]) -> torch.Tensor:
        """The lumped device as T shows it (physics.md §3: ``t11 = 1/φ``, ``t12 = Zt/φ`` with
        the sphere's mass in Zt, ``t21 = jω C0 (1 - j tanδ)/φ``), elements of T as they are
        (the gate whitens them; over a few % of spread they are near linear in the
        parameters): Re t11 at the first frequency (the coupling), Re and Im t12 there
        (damping; mass against stiffness), Im t12 at the last (stiffness against mass), Re
        and Im t21 at the middle one (C0 tanδ and C0), ``(batch, N_DEVICE)``. Only elements
        that the spread moves: one that is zero in every training record (Im t11) would flag
        any measured T. ``elements``: :func:`t_elements`' (columns of the parts it splits
        anyway: a Gather of a few columns of the flat T, or a concat of its two parts, cost
        onnxruntime as much as an MLP layer)."""
        (a11, _), (a12, b12), (a21, b21), _ = elements
        mid, n = self.n_freq // 2, self.n_freq
        return torch.cat([a11[:, :1], a12[:, :1], a21[:, mid:mid + 1], b12[:, :1],
                          b12[:, n - 1:], b21[:, mid:mid + 1]], -1)

    def forward(self, ze_re: torch.Tensor, ze_im: torch.Tensor, t_re: torch.Tensor,
                t_im: torch.Tensor) -> torch.Tensor:
        elements = t_elements(t_re, t_im)
        x = torch.cat(self.zm.from_elements(ze_re, ze_im, elements), -1) / self.z_scale
        return torch.cat([torch.sign(x) * torch.log1p(torch.abs(x)), self.device(elements)], -1)


class StandardPolynomial(nn.Module):
    """``p((x - mean) / scale)`` in Horner form, coefficients lowest degree first: the
    scikit-learn pipeline (StandardScaler, PolynomialFeatures, LinearRegression) of
    ``wtml.baselines.radial.PolynomialRadial`` as an exportable layer.

    Args:
        degree: polynomial degree (the buffers are set by :meth:`load_pipeline`).

    Forward: ``x (batch,)`` -> ``(batch,)``.
    """

    def __init__(self, degree: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.tensor(0.0))
        self.register_buffer("scale", torch.tensor(1.0))
        self.register_buffer("coef", torch.zeros(degree + 1))

    @torch.no_grad()
    def load_pipeline(self, pipeline) -> StandardPolynomial:
        scaler, _, linear = (step for _, step in pipeline.steps)
        coef = np.array(linear.coef_, dtype=float)
        coef[0] += linear.intercept_
        self.mean.fill_(float(scaler.mean_[0]))
        self.scale.fill_(float(scaler.scale_[0]))
        self.coef.copy_(torch.tensor(coef, dtype=torch.float32))
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        u = (x - self.mean) / self.scale
        y = torch.zeros_like(u) + self.coef[-1]
        for c in range(self.coef.shape[0] - 2, -1, -1):
            y = y * u + self.coef[c]
        return y


class HermiteTable(nn.Module):
    """A complex function of one real variable, tabulated on a uniform grid with its slopes,
    read back by cubic Hermite interpolation in float32 real arithmetic (Floor, Gather, Pow
    and MatMul: no complex tensors, exportable).

    Args:
        x0, step: the grid ``x0 + step * arange(n)`` (any unit; m for distances).
        values, slopes: complex ``(n, n_col)`` numpy, f and df/dx on the grid (n >= 2).

    Forward: ``x (batch,)`` float32 (clamped to the grid) -> ``(f_re, f_im, df_re, df_im)``,
    each ``(batch, n_col)``; the slope in units of f per unit of x.
    """

    def __init__(self, x0: float, step: float, values: np.ndarray, slopes: np.ndarray) -> None:
        super().__init__()
        values, slopes = np.asarray(values, complex), np.asarray(slopes, complex) * step
        if values.ndim != 2 or values.shape != slopes.shape or len(values) < 2 or step <= 0:
            raise ValueError(f"HermiteTable needs values and slopes of one shape (n >= 2, "
                             f"n_col) and step > 0; got {values.shape}, {slopes.shape}, {step}")
        self.n_col = values.shape[1]
        self.x0, self.step, self.n = float(x0), float(step), len(values)
        # rows: [Re f, Im f, Re f' h, Im f' h] side by side, one row per grid point (the state
        # a checkpoint holds); intervals: what forward reads, made from them
        rows = np.concatenate([values.real, values.imag, slopes.real, slopes.imag], -1)
        self.register_buffer("rows", torch.tensor(rows, dtype=torch.float32))
        self.register_buffer("intervals", self.intervals_of(self.rows), persistent=False)
        self.register_load_state_dict_post_hook(HermiteTable._reread)
        # the weights of (f(a), f'(a) h, f(b) - f(a), f'(b) h) as polynomials in t (rows 1,
        # t, t², t³): the cubic Hermite basis (h00 + h01 = 1, h10, h01, h11), then their d/dt
        # over the step (0, g10, g01, g11)
        basis = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, -2, 3, -1], [0, 1, -2, 1]], float)
        slope = np.array([[0, 1, 0, 0], [0, -4, 6, -2], [0, 3, -6, 3], [0, 0, 0, 0]],
                         float) / self.step
        self.register_buffer("basis", torch.tensor(np.concatenate([basis, slope], 1),
                                                   dtype=torch.float32), persistent=False)
        self.register_buffer("exponents", torch.arange(4, dtype=torch.float32),
                             persistent=False)

    @staticmethod
    def intervals_of(rows: torch.Tensor) -> torch.Tensor:
        """Per interval of the grid, ``(n - 1, 4, 2 n_col)``: f at its start, f'h there,
        f's change over it (a difference of neighbours, exact in float32 where they are
        close, before any product: the slope's ``g00 (f(a) - f(b))`` would lose ε|f|/h
        otherwise), f'h at its end."""
        w = rows.shape[1] // 2
        a, b = rows[:-1], rows[1:]
        return torch.stack([a[:, :w], a[:, w:], b[:, :w] - a[:, :w], b[:, w:]], 1)

    @staticmethod
    def _reread(module: HermiteTable, incompatible) -> None:
        """After a state dict is loaded: the intervals of its rows."""
        module.intervals = module.intervals_of(module.rows)

    @classmethod
    def empty(cls, x0: float, step: float, n: int, n_col: int) -> HermiteTable:
        """A table of zeros with these shapes (a checkpoint's state dict brings the values)."""
        zeros = np.zeros((n, n_col), complex)
        return cls(x0, step, zeros, zeros)

    def forward(self, x: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        u = ((x - self.x0) / self.step).clamp(0.0, self.n - 1.0)
        i = torch.floor(u).clamp(max=self.n - 2)
        row = i.long().clamp(0, self.n - 2)  # a NaN x (cast to any integer) stays NaN in t
        # the powers (1, t, t², t³) by one Pow, the four Hermite weights and their d/dt by one
        # product, applied to the interval's four rows by another: the table is 16
        # operations of onnxruntime's optimised radial graph, with the row's index, where
        # the weights written out took 48 (a call at batch 1 pays ~0.25 µs for each)
        powers = torch.pow((u - i)[:, None], self.exponents)
        weights = (powers @ self.basis).reshape(-1, 2, 4)  # (batch, [f, df/dx], 4)
        out = weights @ self.intervals[row]  # (batch, 2, 2 n_col)
        n = self.n_col
        return out[:, 0, :n], out[:, 0, n:], out[:, 1, :n], out[:, 1, n:]
