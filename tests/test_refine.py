"""Our radial decoder's second stage: the tabulated forward model and the learned
Gauss–Newton step's inputs (wtml/decoders/radial.py)."""

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from wtml.decoders.layers import HermiteTable
from wtml.decoders.radial import RadialDecoder, RefinedRadialNet, contact_table, one_cycle
from wtml.scenes import RadialScene
from wtml.schema import build

SCENE = build(RadialScene, {"samples": 1600, "shards": 4,
                            "excitation": {"frequencies_hz": [420.0, 380.0, 460.0]}})
N_FREQ = 3


def _cubic(x):
    return (1 + 2j) + (0.5 - 1j) * x - 3 * x**2 + (2 + 0.25j) * x**3


def _cubic_slope(x):
    return (0.5 - 1j) - 6 * x + 3 * (2 + 0.25j) * x**2


@given(st.lists(st.floats(-0.2, 1.4), min_size=1, max_size=20))
def test_hermite_table_is_exact_for_cubics_and_clamps_outside(xs):
    """Cubic Hermite interpolation reproduces a cubic and its slope exactly (to float32);
    outside the grid it returns the end values."""
    grid = np.linspace(0.0, 1.2, 7)[:, None]
    table = HermiteTable(0.0, 0.2, _cubic(grid), _cubic_slope(grid))
    x = np.asarray(xs)
    f_re, f_im, g_re, g_im = (a[:, 0].double().numpy() for a in
                              table(torch.tensor(x, dtype=torch.float32)))
    xc = np.clip(x, 0.0, 1.2)
    np.testing.assert_allclose(f_re + 1j * f_im, _cubic(xc), atol=2e-5)
    inside = (x >= 0.0) & (x <= 1.2)
    np.testing.assert_allclose((g_re + 1j * g_im)[inside], _cubic_slope(x[inside]), atol=1e-4)


def _written_out(rows, x0, step, x):
    """Cubic Hermite interpolation of a table's ``rows`` (``HermiteTable.rows``' layout) with
    each basis function written out, in the dtype of ``rows`` and ``x``."""
    n, w = len(rows), rows.shape[1] // 2
    u = ((x - x0) / step).clamp(0.0, n - 1.0)
    i = torch.floor(u).clamp(max=n - 2)
    t = (u - i)[:, None]
    row = i.long().clamp(0, n - 2)
    a, b = rows[row], rows[row + 1]
    t2, t3 = t * t, t * t * t
    h00, h10, h01, h11 = 2 * t3 - 3 * t2 + 1, t3 - 2 * t2 + t, 3 * t2 - 2 * t3, t3 - t2
    g00, g10, g11 = 6 * t2 - 6 * t, 3 * t2 - 4 * t + 1, 3 * t2 - 2 * t
    f = h00 * a[:, :w] + h10 * a[:, w:] + h01 * b[:, :w] + h11 * b[:, w:]
    df = (g00 * (a[:, :w] - b[:, :w]) + g10 * a[:, w:] + g11 * b[:, w:]) / step
    return torch.cat([f, df], 1)


@given(st.lists(st.floats(-0.3, 1.5), min_size=1, max_size=30), st.integers(0, 2**31))
def test_hermite_table_weights_as_one_product_are_the_written_out_form(xs, seed):
    """The weights as a product of the powers of t with constant matrices (the graph's few
    operations) against the basis functions written out in float64 on the same float32 table
    and positions, on and off the grid, at its edges and outside. A table like the radial
    one (values ~1, neighbours 1e-4 to 1e-2 apart): f to a few roundings of f, and the
    slope to a few roundings of f's change over a step (the neighbours' difference comes
    before any product: a product of each first would lose ε|f|/h, 100× more here). A NaN
    position gives NaN values and slopes (the graph must not read another row)."""
    rng = np.random.default_rng(seed)
    n, cols, step = 9, 3, 2.0**-17  # ~7.6 µm, a power of two: the position's t is exact
    grid = step * np.arange(n)[:, None]
    k = rng.uniform(50, 2000, cols) * np.exp(1j * rng.uniform(0, 2 * np.pi, cols))
    values = (1 + 2j) * np.exp(k * grid)  # slopes 50-2000 /m, as the radial table's R'
    table = HermiteTable(0.0, step, values, k * values)
    on = step * np.array([0, 1, n - 1])
    x = torch.tensor(np.concatenate([step * (n - 1) * np.asarray(xs), on]),
                     dtype=torch.float32)
    got = torch.cat(table(x), 1).double()
    want = _written_out(table.rows.double(), 0.0, step, x.double())
    eps = float(np.finfo(np.float32).eps)
    w = 2 * cols
    rows = table.rows.double()
    change = max(float((rows[1:, :w] - rows[:-1, :w]).abs().max()),
                 float(rows[:, w:].abs().max()))
    np.testing.assert_allclose(got[:, :w], want[:, :w], rtol=0,
                               atol=8 * eps * float(rows[:, :w].abs().max()))
    np.testing.assert_allclose(got[:, w:], want[:, w:], rtol=0, atol=16 * eps * change / step)
    assert torch.isnan(torch.cat(table(torch.tensor([float("nan")])), 1)).all()


def test_a_table_loaded_from_a_state_dict_reads_its_rows():
    """A checkpoint brings ``rows`` only (the state dict of before the intervals): an empty
    table of the same shape, loaded from it, reads the same values and slopes."""
    grid = np.linspace(0.0, 1.2, 7)[:, None]
    table = HermiteTable(0.0, 0.2, _cubic(grid), _cubic_slope(grid))
    assert list(table.state_dict()) == ["rows"]
    empty = HermiteTable.empty(0.0, 0.2, 7, 1)
    empty.load_state_dict(table.state_dict())
    x = torch.linspace(-0.1, 1.3, 29)
    for got, want in zip(empty(x), table(x), strict=True):
        assert torch.equal(got, want)


def test_hermite_table_converges_at_fourth_order():
    """Error of sin on halving the step: ratio ~16 (O(h⁴)), float64 reference."""
    errors = []
    for n in (9, 17, 33):
        grid = np.linspace(0, 2, n)[:, None]
        table = HermiteTable(0.0, 2 / (n - 1), np.exp(1j * grid), 1j * np.exp(1j * grid))
        x = np.linspace(0.01, 1.99, 997)
        f_re, f_im, _, _ = table(torch.tensor(x, dtype=torch.float32))
        errors.append(np.abs(f_re[:, 0].numpy() + 1j * f_im[:, 0].numpy() - np.exp(1j * x)).max())
    assert 12 < errors[0] / errors[1] < 20


def test_hermite_table_rejects_bad_shapes():
    with pytest.raises(ValueError, match="HermiteTable"):
        HermiteTable(0.0, 1.0, np.zeros((1, 2)), np.zeros((1, 2)))
    with pytest.raises(ValueError, match="step > 0"):
        HermiteTable(0.0, 0.0, np.zeros((3, 2)), np.zeros((3, 2)))


def test_contact_table_matches_the_beam_model_between_its_nodes():
    """Off-grid, the float32 table of the ratio Ze / Ze_free is within 4e-6 of the noise-free
    model (noise: 2e-5). The interpolation itself is good to 2.5e-7; the rest is float32's
    resolution of the position (~2e-10 m at 3 mm, and the steepest tone moves Ze by
    1.2 %/µm)."""
    table = contact_table(SCENE)
    d = np.random.default_rng(0).uniform(0, 3.2e-3, 400).astype(np.float32).astype(float)
    k = np.full_like(d, SCENE.reference_stiffness())
    ze = SCENE.ze_of(d, k) / SCENE.free_ze()
    f_re, f_im, _, _ = table(torch.tensor(d, dtype=torch.float32))
    got = f_re.double().numpy() + 1j * f_im.double().numpy()
    assert np.max(np.abs(got - ze) / np.abs(ze)) < 4e-6


def _net():
    table = contact_table(SCENE)
    return RefinedRadialNet(N_FREQ, [8], [8], table, 3e-6)


def test_residual_is_the_distance_step_at_the_reference_stiffness():
    """Noise-free Ze at the reference stiffness with the nominal device's free reference:
    p = 0 at the true d, and a start off by δ gives Re p = δ to first order (error O(δ²)).
    The reference scaled by any complex factor scales Ze alike on a device that only differs
    by it (a gain): p is unchanged. (6e-9 m, was 2e-9 m with Ze alone: p from the float32
    ratio ze/ref adds one rounding of its size. Measured: at δ = 0, 2.6–3.0e-9 m; at δ = 0.2
    µm, 2.8–4.4e-9 m, as p from ze - R ref before it; the noise allows ~4e-7 m.)"""
    net = _net()
    d = np.linspace(100e-6, 3100e-6, 31)
    ze = SCENE.ze_of(d, np.full_like(d, SCENE.reference_stiffness()))
    ref = np.broadcast_to(SCENE.free_ze(), ze.shape)
    n = N_FREQ
    for gain in (1.0, 0.97 + 0.02j):
        parts = [torch.tensor(p, dtype=torch.float32) for z in (gain * ze, gain * ref)
                 for p in (z.real, z.imag)]
        for delta, tol in ((0.0, 6e-9), (0.2e-6, 6e-9), (1e-6, 3e-8)):
            p = net.residual(*parts, torch.tensor(d - delta, dtype=torch.float32))
            p = p.double().numpy()
            np.testing.assert_allclose(p[:, :n], delta, atol=tol)
            np.testing.assert_allclose(p[:, n:2 * n], 0.0, atol=tol)
            np.testing.assert_allclose(p[:, 2 * n + 1:3 * n + 1], parts[2].numpy())


def test_refined_net_shapes_and_errors():
    net = _net()
    d, s = net(*(torch.ones(4, N_FREQ) * 1e5 for _ in range(4)))
    assert d.shape == s.shape == (4,) and torch.all(s > 0) and torch.all(torch.isfinite(d))
    with pytest.raises(ValueError, match="frequencies"):
        RefinedRadialNet(N_FREQ + 1, [8], [8], contact_table(SCENE), 3e-6)
    with pytest.raises(ValueError, match="scale"):
        RefinedRadialNet(N_FREQ, [8], [8], contact_table(SCENE), 0.0)
    with pytest.raises(ValueError, match="used_frequencies"):
        RadialDecoder(refine_hidden=[8], used_frequencies=1)
    with pytest.raises(ValueError, match="model.reference false applies to a plain RadialNet"):
        RadialDecoder(refine_hidden=[8], reference=False)
    with pytest.raises(ValueError, match=r"model.table_step_um must be in \(0, 1e4\) µm"):
        RadialDecoder(refine_hidden=[8], table_step_um=0.0)
    with pytest.raises(ValueError, match="model.refine_scale_um"):
        RadialDecoder(refine_hidden=[8], refine_scale_um=-1.0)


def test_one_cycle_runs_only_inside_its_phase():
    f = [one_cycle(s, 10, 110) for s in range(0, 120)]
    assert f[:10] == [0.0] * 10 and f[110:] == [0.0] * 10
    assert f[10] == pytest.approx(1 / 25) and max(f) == pytest.approx(1.0)
    assert int(np.argmax(f)) == 40 and f[109] < 1e-3
    assert np.all(np.abs(np.diff(f[10:110])) < 0.06)  # no jumps inside the phase
