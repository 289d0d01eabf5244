"""Glycerol–water properties against the thesis's literature columns (Tables 6.1, 6.2)."""

import numpy as np
import pytest

from wtml.physics.fluids import TABLES_6_1_6_2, glycerol_water, water

CV, ETA_LIT, RHO_LIT = (TABLES_6_1_6_2[k] for k in ("cv", "eta", "rho"))


def test_table_6_1_viscosity_within_one_percent():
    eta, _ = glycerol_water(CV, 25.0)
    np.testing.assert_allclose(eta, ETA_LIT, rtol=0.01)


def test_table_6_2_density_within_rounding():
    """Table 6.2 prints three digits (±0.5 %); Volk & Kähler's model is within 1.1 %."""
    _, rho = glycerol_water(CV, 25.0)
    np.testing.assert_allclose(rho, RHO_LIT, rtol=0.011)


def test_endpoints_are_the_pure_fluids():
    eta_w, rho_w = water(25.0)
    eta, rho = glycerol_water(np.array([0.0, 1.0]), 25.0)
    assert eta[0] == eta_w and rho[0] == rho_w
    np.testing.assert_allclose(eta[1], 0.906, rtol=0.01)  # thesis §6.5.2: 9.06e-1 Pa·s
    np.testing.assert_allclose(rho[1], 1277 - 0.654 * 25, rtol=1e-12)


def test_monotone_in_fraction_and_temperature():
    cv = np.linspace(0, 1, 101)
    for t in (0.0, 25.0, 60.0, 100.0):
        eta, rho = glycerol_water(cv, t)
        assert np.all(np.diff(eta) > 0) and np.all(np.diff(rho) > 0)
    eta_t, _ = glycerol_water(0.5, np.linspace(0, 100, 101))
    assert np.all(np.diff(eta_t) < 0)


def test_fluid_slice_range():
    """0–100 % at 15–40 °C spans η ≈ 5e-4 to ≈ 1.5 Pa·s (the fluid scene's range)."""
    eta, _ = glycerol_water(np.array([[0.0], [1.0]]), np.array([15.0, 40.0]))
    assert 6e-4 < eta[0, 1] < 7e-4 and 1.4 < eta[1, 0] < 2.4


def test_out_of_range_inputs_are_named():
    with pytest.raises(ValueError, match=r"volume_fraction must be in \[0, 1\]; got 1.2"):
        glycerol_water(1.2, 25.0)
    with pytest.raises(ValueError, match=r"temperature_c must be in \[0, 100\] °C"):
        glycerol_water(0.5, 120.0)
