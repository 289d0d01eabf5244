"""Loads: closed forms, exact limits of the beam model, the thesis's numbers, fluid inversion."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from wtml.physics.loads import (
    CantileverPoint,
    MassSpringDamper,
    SphereInFluid,
    WhiskerContact,
    fluid_from_zm,
    stokes_sphere,
)
from wtml.physics.loads.cantilever import krylov_functions

STRIP = dict(length=82e-3, width=1e-3, thickness=0.3e-3)  # thesis calibration strip

# Thesis Tables 4.3 and 4.4, "theoretical Zm" at 36 Hz (all imaginary), N·s/m
THESIS_THEORETICAL = {70: 1.04e-3, 71: 9.95e-4, 72: 9.55e-4, 73: 9.18e-4, 74: 8.83e-4,
                      75: 8.50e-4, 76: 8.19e-4, 77: 7.89e-4, 78: 7.61e-4, 79: 7.34e-4,
                      80: 7.09e-4, 81: 6.85e-4}


def test_mass_spring_damper_closed_form():
    omega = np.array([10.0, 100.0, 1000.0])
    z = MassSpringDamper(m=2e-3, k=40.0, c=0.5).impedance(omega)
    np.testing.assert_allclose(z, 0.5 + 1j * (2e-3 * omega - 40.0 / omega), rtol=1e-15)
    with pytest.raises(ValueError, match=r"k must be in \[0, inf\) N/m"):
        MassSpringDamper(k=-1.0)


def test_krylov_functions_are_continuous_across_the_series_switch():
    z = np.array([1 - 1e-12, 1 + 1e-12, 0.999999 * np.exp(0.3j), 1.000001 * np.exp(0.3j)])
    k = krylov_functions(z)
    np.testing.assert_allclose(k[0], k[1], rtol=1e-10)
    np.testing.assert_allclose(k[2], k[3], rtol=1e-5)
    # small arguments keep full relative precision: U ≈ z²/2, V ≈ z³/6
    small = krylov_functions(np.array([1e-6]))[0]
    np.testing.assert_allclose(small, [1, 1e-6, 0.5e-12, 1e-18 / 6], rtol=1e-12)


def test_cantilever_static_limit_is_3EI_over_d3():
    for d in (20e-3, 50e-3, 82e-3):
        c = CantileverPoint(distance=d, **STRIP)
        omega = np.array([1e-3])
        k_dynamic = (1j * omega * c.impedance(omega)).real
        np.testing.assert_allclose(k_dynamic, c.static_stiffness, rtol=1e-9)


def test_cantilever_tip_impedance_vanishes_at_first_natural_frequency():
    c = CantileverPoint(distance=82e-3, **STRIP)
    beta_l = 1.8751040687119611  # first root of 1 + cos x cosh x = 0
    w1 = beta_l**2 / c.length**2 * np.sqrt(c.bending_stiffness / c.mass_per_length)
    z = c.impedance(np.array([w1 * (1 - 1e-9), w1, w1 * (1 + 1e-9)]))
    assert abs(z[1]) < 1e-9 * abs(c.impedance(np.array([0.5 * w1]))[0])
    assert z[0].imag < 0 < z[2].imag  # stiffness-like below, mass-like above
    assert abs(w1 / (2 * np.pi) - 34.9) < 0.05  # the strip resonates just below 36 Hz


def test_quasi_static_model_converges_to_beam_at_fourth_order():
    """Beam minus (k/jω + jω m_eff) is O(ω³) in Zm, i.e. O(ω⁴) relative: halving ω divides
    the relative difference by 16."""
    beam = CantileverPoint(distance=71e-3, **STRIP)
    quasi = CantileverPoint(distance=71e-3, model="quasi_static", **STRIP)
    omegas = 2 * np.pi * np.array([4.0, 2.0, 1.0])
    rel = np.abs(beam.impedance(omegas) / quasi.impedance(omegas) - 1)
    ratios = rel[:-1] / rel[1:]
    np.testing.assert_allclose(ratios, 16.0, rtol=0.02)


def test_cantilever_reproduces_thesis_theoretical_column():
    """Thesis Tables 4.3/4.4 list the strip's Zm at 36 Hz for d = 70..81 mm. At 36 Hz the
    strip sits 3 % above its first resonance, where Zm is ~17x as sensitive to the
    frequency or E as they are to themselves: our values at the thesis's nominal constants
    are 2.0 % high throughout, a 0.12 % difference in E (or 0.06 % in frequency). The shape
    across d, with that one factor removed, agrees to the thesis's 3 printed digits."""
    d = np.array(sorted(THESIS_THEORETICAL))
    ours = np.array([CantileverPoint(distance=k * 1e-3, **STRIP).impedance(2 * np.pi * 36.0)
                     for k in d])
    thesis = np.array([THESIS_THEORETICAL[k] for k in d])
    assert np.all(np.abs(ours.real) < 1e-15)
    ratio = ours.imag / thesis
    assert abs(np.median(ratio) - 1) < 0.025
    np.testing.assert_allclose(ratio / np.median(ratio), 1.0, atol=3.5e-3)


def test_cantilever_contact_range_is_checked():
    with pytest.raises(ValueError, match=r"distance must be in \(0, 0.082\] m"):
        CantileverPoint(distance=0.09, **STRIP)
    with pytest.raises(ValueError, match="model"):
        CantileverPoint(distance=0.05, model="fem", **STRIP)


def test_cantilever_loss_makes_it_dissipative():
    c = CantileverPoint(distance=75e-3, loss_factor=0.01, **STRIP)
    assert np.all(c.impedance(2 * np.pi * np.linspace(5, 200, 50)).real > 0)


def test_whisker_contact_stiffness():
    w = WhiskerContact(length=5e-3, radius=25e-6, distance_from_tip=1e-3)
    k = 3 * 185e9 * np.pi * (25e-6) ** 4 / 4 / (4e-3) ** 3
    np.testing.assert_allclose(w.stiffness, k, rtol=1e-14)
    np.testing.assert_allclose(w.impedance(np.array([2 * np.pi * 420])), k / (2j * np.pi * 420))
    with pytest.raises(ValueError, match="distance_from_tip"):
        WhiskerContact(length=5e-3, radius=25e-6, distance_from_tip=5e-3)


def test_stokes_sphere_matches_eq_6_3():
    """physics.md §5: R = 1 mm in water (η = 8.9e-4 Pa·s, ρ = 1000): cf = 1.68e-5 +
    1.26e-5 √ω, mf = 2.09e-6 + 1.26e-5/√ω (three printed digits)."""
    omega = np.array([10.0, 100.0, 1000.0])
    z = stokes_sphere(8.9e-4, 1000.0, 1e-3, omega)
    np.testing.assert_allclose(z.real, 1.68e-5 + 1.26e-5 * np.sqrt(omega), rtol=5e-3)
    np.testing.assert_allclose(z.imag / omega, 2.09e-6 + 1.26e-5 / np.sqrt(omega), rtol=5e-3)
    np.testing.assert_allclose(SphereInFluid(1e-3, 8.9e-4, 1000.0).impedance(omega), z)


@given(log_eta=st.floats(-4, np.log10(2)), rho=st.floats(600, 1500),
       log_r=st.floats(-5, np.log10(3e-3)), log_f=st.floats(0, np.log10(3e4)))
def test_fluid_inversion_round_trip(log_eta, rho, log_r, log_f):
    eta, radius, omega = 10**log_eta, 10**log_r, 2 * np.pi * 10**log_f
    eta2, rho2 = fluid_from_zm(stokes_sphere(eta, rho, radius, omega), radius, omega)
    assert abs(eta2 / eta - 1) < 1e-9
    assert abs(rho2 / rho - 1) < 1e-9


def test_fluid_inversion_vectorised_and_invalid():
    eta = np.array([1e-3, 1e-2, 1.0])
    rho = np.array([998.0, 1100.0, 1260.0])
    omega = 2 * np.pi * 104.0
    zm = stokes_sphere(eta, rho, 1.9e-3, omega)
    e2, r2 = fluid_from_zm(zm, 1.9e-3, omega)
    np.testing.assert_allclose(e2, eta, rtol=1e-12)
    np.testing.assert_allclose(r2, rho, rtol=1e-12)
    bad = np.array([zm[0], -1e-4 + 1e-3j, 1e-3 + 0j])  # Re Zm < 0; no boundary layer
    with pytest.raises(ValueError, match=r"Newtonian fluid at 2 of 3 points.*Re Zm > 0"):
        fluid_from_zm(bad, 1.9e-3, omega)
    e3, r3 = fluid_from_zm(bad, 1.9e-3, omega, on_invalid="nan")
    assert np.isfinite(e3[0]) and np.all(np.isnan(e3[1:])) and np.all(np.isnan(r3[1:]))
    with pytest.raises(ValueError, match="eta must be in"):
        stokes_sphere(-1.0, 1000.0, 1e-3, omega)
