"""Beam model: convergence to closed-form cantilever frequencies, exact statics, agreement
with the 2×2 path for tip loads, reciprocity, contacts on the shaft."""

import numpy as np
import pytest
from scipy.optimize import brentq

from wtml.physics import det_error, ze_from_zm
from wtml.physics.beam import BeamTransducer, PointMass, Segment, bimorph, round_rod

EPS = np.finfo(float).eps
STEEL = dict(youngs_modulus=185e9, density=7900.0)
CLAMPED_FREE_ROOTS = (1.8751040687119611, 4.6940911329741745, 7.8547574382376126)


def uniform(elements):
    return BeamTransducer((round_rod("rod", 20e-3, 0.3e-3, elements=elements, **STEEL),))


def exact_frequencies(seg, tip_mass=0.0, count=3):
    """Roots of 1 + cos x cosh x + μ x (cos x sinh x - sin x cosh x) = 0, μ = m_tip/m_beam."""
    mu = tip_mass / (seg.mass_per_length * seg.length)
    def f(x):
        return 1 + np.cos(x) * np.cosh(x) + mu * x * (np.cos(x) * np.sinh(x)
                                                      - np.sin(x) * np.cosh(x))

    grid = np.linspace(0.1, 12, 12000)
    vals = f(grid)
    brackets = zip(grid[:-1], grid[1:], vals[:-1], vals[1:], strict=True)
    roots = [brentq(f, a, b) for a, b, va, vb in brackets if va * vb < 0][:count]
    scale = np.sqrt(seg.bending_stiffness / seg.mass_per_length) / seg.length**2 / (2 * np.pi)
    return np.array(roots) ** 2 * scale


def test_closed_form_roots_are_the_textbook_ones():
    seg = uniform(4).segments[0]
    scale = np.sqrt(seg.bending_stiffness / seg.mass_per_length) / seg.length**2 / (2 * np.pi)
    np.testing.assert_allclose(exact_frequencies(seg), np.array(CLAMPED_FREE_ROOTS) ** 2 * scale,
                               rtol=1e-10)


@pytest.mark.parametrize("tip_ratio", [0.0, 0.5])
def test_frequencies_converge_at_fourth_order(tip_ratio):
    """Hermite cubics with consistent mass: eigenvalue error O(h⁴), so halving the elements
    divides the frequency error by ~16."""
    seg = uniform(4).segments[0]
    tip = tip_ratio * seg.mass_per_length * seg.length
    exact = exact_frequencies(seg, tip)
    errors = []
    for n in (4, 8, 16):
        tr = uniform(n)
        if tip:
            tr = BeamTransducer(tr.segments, (PointMass(seg.length, tip),))
        errors.append(np.abs(tr.natural_frequencies(3) / exact - 1))
    errors = np.array(errors)
    assert np.all(errors[-1] < [1e-5, 1e-5, 1e-4])
    ratios = errors[:-1, :2] / errors[1:, :2]  # the lowest two modes are in the asymptotic range
    assert np.all((ratios > 12) & (ratios < 20)), ratios


def micro_like(loss=0.0, tan_delta=0.0):
    return BeamTransducer(
        (bimorph("bimorph", 24e-3, 0.5e-3, 0.25e-3, 0.0, 1.0, 1.0, loss_factor=loss),
         Segment(5e-3, 185e9 * (50e-6) ** 4 / 12, 7900 * (50e-6) ** 2, loss, name="whisker")),
        tan_delta=tan_delta)


def test_static_tip_displacement_is_the_closed_form():
    """A uniform moment ΓE on the bimorph: tip of the bimorph moves ΓE L²/(2EI) and turns by
    ΓE L/EI, which the rigid-in-statics-free whisker carries on: U/E = Γ(L²/2 + L Lw)/EI."""
    tr = micro_like()
    b, w = tr.segments
    expected = b.coupling * (b.length**2 / 2 + b.length * w.length) / b.bending_stiffness
    np.testing.assert_allclose(tr.static_tip_displacement_per_volt(), expected, rtol=1e-10)


def test_det_is_one_by_construction():
    tr = micro_like(loss=0.01, tan_delta=0.02)
    omega = 2 * np.pi * np.geomspace(1, 5000, 60)
    t = tr.transduction_matrix(omega)
    floor = 8 * EPS * (np.abs(t[:, 0, 0] * t[:, 1, 1]) + np.abs(t[:, 0, 1] * t[:, 1, 0]))
    assert np.all(det_error(t) <= floor)
    tc = tr.contact_transduction_matrix(omega, tr.length - np.array([0.5e-3, 2e-3]), [1.0, np.inf])
    floor = 64 * EPS * (np.abs(tc[..., 0, 0] * tc[..., 1, 1])
                        + np.abs(tc[..., 0, 1] * tc[..., 1, 0]))
    assert np.all(det_error(tc) <= floor)


@pytest.mark.parametrize("stiffness", [1e-4, 0.3, 50.0, np.inf])
def test_tip_load_beam_path_equals_matrix_path(stiffness):
    """A spring to ground at the tip, in the beam model, gives the Ze that the free structure's
    T gives for Zm = k/(jω) (clamped for k = inf): to 1e-9."""
    tr = micro_like(loss=0.01, tan_delta=0.02)
    omega = 2 * np.pi * np.linspace(50, 1500, 40)
    t = tr.transduction_matrix(omega)
    tc = tr.contact_transduction_matrix(omega, [tr.length], stiffness)[0]
    ze_beam = tc[:, 0, 1] / tc[:, 1, 1]  # the contact is part of the structure; tip free
    zm = np.full(omega.shape, np.inf) if np.isinf(stiffness) else stiffness / (1j * omega)
    ze_matrix = ze_from_zm(t, zm)
    np.testing.assert_allclose(ze_beam, ze_matrix, rtol=1e-9)


def test_shaft_contact_is_not_a_tip_load():
    """A contact 1 mm from the tip changes T itself; it is no Zm at the tip of the free T
    (the radial task needs the beam model)."""
    tr = micro_like(loss=0.01)
    omega = np.array([2 * np.pi * 420.0])
    tc = tr.contact_transduction_matrix(omega, [tr.length - 1e-3], np.inf)[0]
    t = tr.transduction_matrix(omega)
    assert np.abs(tc[0, 0, 0] / t[0, 0, 0] - 1) > 1e-2
    # and the nearer the contact to the clamp, the stiffer the whisker: |Ze| moves monotonically
    d = np.linspace(0, 3.2e-3, 17)
    tcs = tr.contact_transduction_matrix(omega, tr.length - d, np.inf)[:, 0]
    ze = tcs[:, 0, 1] / tcs[:, 1, 1]
    assert np.all(np.diff(ze.imag) != 0)


def test_contact_positions_are_checked():
    tr = micro_like()
    with pytest.raises(ValueError, match="contact position"):
        tr.contact_transduction_matrix(np.array([100.0]), [tr.length + 1e-3], 1.0)
    with pytest.raises(ValueError, match="poling"):
        bimorph("b", 1e-2, 1e-3, 1e-4, 0.0, 1.0, 1.0, poling="diagonal")
