"""Two-port algebra: round trips, exact limits, broadcasting, power, transfer functions."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from tests.conftest import MACRO, MICRO
from wtml.physics import (
    cascade,
    det_error,
    displacement_per_charge,
    displacement_per_voltage,
    drive_velocity,
    drive_voltage,
    efficiency,
    electrical_from_mechanical,
    force_per_charge,
    force_per_voltage,
    mechanical_from_electrical,
    tip_mass,
    ym_from_ze,
    ze_from_zm,
    zm_from_ze,
)

EPS = np.finfo(float).eps
OMEGA = 2 * np.pi * np.geomspace(5, 2000, 41)

log_magnitude = st.floats(min_value=-15, max_value=15)
phase = st.floats(min_value=-np.pi, max_value=np.pi)
freq_hz = st.floats(min_value=1.0, max_value=3e4)
which = st.sampled_from([MACRO, MICRO])


def det_floor(t):
    """Rounding floor of |det T - 1|: det T is a difference of two products."""
    return 8 * EPS * (np.abs(t[..., 0, 0] * t[..., 1, 1]) + np.abs(t[..., 0, 1] * t[..., 1, 0]))


def zm_of(log_mag, ph):
    return 10.0**log_mag * np.exp(1j * ph)


def test_free_and_clamped_limits_are_exact(transducer):
    t = transducer.transduction_matrix(OMEGA)
    np.testing.assert_array_equal(ze_from_zm(t, 0.0), t[:, 0, 1] / t[:, 1, 1])
    np.testing.assert_array_equal(ze_from_zm(t, np.inf), t[:, 0, 0] / t[:, 1, 0])
    np.testing.assert_array_equal(ze_from_zm(t, complex(np.inf, 0)), t[:, 0, 0] / t[:, 1, 0])
    # the inverse maps give the limits to within the rounding of Ze itself:
    # |dZm| = eps |Ze| / |t11 - t21 Ze|^2, and likewise |dYm| = eps |Ze| / |t22 Ze - t12|^2
    t11, t12, t21, t22 = t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1]
    ze_free, ze_clamped = t12 / t22, t11 / t21
    assert np.all(np.abs(zm_from_ze(t, ze_free))
                  <= 8 * EPS * np.abs(ze_free) / np.abs(t11 - t21 * ze_free) ** 2)
    assert np.all(np.abs(ym_from_ze(t, ze_clamped))
                  <= 8 * EPS * np.abs(ze_clamped) / np.abs(t22 * ze_clamped - t12) ** 2)


def test_clamped_ze_gives_infinite_zm_without_warnings():
    t = np.array([[2.0, 3.0], [1.0, 2.0]], dtype=complex)  # det = 1, t11/t21 exact in binary
    assert np.isinf(zm_from_ze(t, 2.0))
    assert np.isinf(ym_from_ze(t, 1.5))  # the free value t12/t22 = 1.5


@given(log_mag=log_magnitude, ph=phase, f=freq_hz, tr=which)
def test_ze_zm_round_trip_within_condition_bound(log_mag, ph, f, tr):
    """Zm -> Ze -> Zm for |Zm| in 1e-15..1e15: finite, and the error is what rounding of Ze
    allows: |dZm| <= c eps (|Ze| / |t11 - t21 Ze|^2 + |Zm|), since dZm/dZe = 1/(t11 - t21 Ze)^2,
    where the exact t11 - t21 Ze = 1/(t21 Zm + t22) (det T = 1): near clamped it is far
    below the rounding of t11, which is why the clamped side loses digits."""
    t = tr.transduction_matrix(np.array(2 * np.pi * f))
    zm = zm_of(log_mag, ph)
    ze = ze_from_zm(t, zm)  # numpy RuntimeWarnings are errors under pytest here
    back = zm_from_ze(t, ze)
    assert np.isfinite(ze) and np.isfinite(back)
    t21, t22 = t[1, 0], t[1, 1]
    bound = 64 * EPS * (abs(ze) * abs(t21 * zm + t22) ** 2 + abs(zm))
    assert abs(back - zm) <= bound


@given(log_mag=log_magnitude, ph=phase, f=freq_hz, tr=which)
def test_admittance_form_agrees(log_mag, ph, f, tr):
    t = tr.transduction_matrix(np.array(2 * np.pi * f))
    zm = zm_of(log_mag, ph)
    ze = ze_from_zm(t, zm)
    zm_back, ym_back = zm_from_ze(t, ze), ym_from_ze(t, ze)
    assert abs(zm_back * ym_back - 1) < 1e-9 or not np.isfinite(zm_back * ym_back)


@given(e_mag=st.floats(-3, 3), e_ph=phase, i_mag=st.floats(-12, -3), i_ph=phase, f=freq_hz,
       tr=which)
def test_electrical_mechanical_round_trip(e_mag, e_ph, i_mag, i_ph, f, tr):
    t = tr.transduction_matrix(np.array(2 * np.pi * f))
    e, i = 10**e_mag * np.exp(1j * e_ph), 10**i_mag * np.exp(1j * i_ph)
    fv = mechanical_from_electrical(t, e, i)
    e2, i2 = electrical_from_mechanical(t, *fv)
    # each recovered variable to rounding of the largest term that makes it
    assert abs(e2 - e) <= 1e3 * EPS * (abs(t[0, 0] * fv[0]) + abs(t[0, 1] * fv[1]))
    assert abs(i2 - i) <= 1e3 * EPS * (abs(t[1, 0] * fv[0]) + abs(t[1, 1] * fv[1]))


def test_broadcasting_loads_against_frequency_grid(transducer):
    t = transducer.transduction_matrix(OMEGA)  # (41, 2, 2)
    zm = np.geomspace(1e-6, 1e-1, 5)[:, None] * np.ones(OMEGA.size)  # (5, 41)
    ze = ze_from_zm(t, zm)
    assert ze.shape == (5, OMEGA.size)
    for k in range(5):
        np.testing.assert_allclose(ze[k], ze_from_zm(t, zm[k]), rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"\(\.\.\., 2, 2\)"):
        ze_from_zm(t[..., 0], zm)


def test_mechanical_port_recovered_for_any_load(transducer, rng):
    """Using both E and I with all four elements removes the load dependence (§2)."""
    t = transducer.transduction_matrix(OMEGA)
    zm = 10 ** rng.uniform(-6, -1, (7, OMEGA.size)) * np.exp(1j * rng.uniform(-1.5, 1.5, (7, 1)))
    f, v, i = drive_voltage(t, zm, 10.0)
    np.testing.assert_allclose(f / v, zm, rtol=1e-12)
    f2, v2 = mechanical_from_electrical(t, 10.0, i)
    # F = t22 E - t12 I is a difference of nearly equal terms: exact to their rounding
    t11, t12, t21, t22 = t[:, 0, 0], t[:, 0, 1], t[:, 1, 0], t[:, 1, 1]
    assert np.all(np.abs(f2 - f) <= 16 * EPS * (np.abs(t22 * 10.0) + np.abs(t12 * i)))
    assert np.all(np.abs(v2 - v) <= 16 * EPS * (np.abs(t21 * 10.0) + np.abs(t11 * i)))


def test_transfer_functions_match_driven_ports_and_limits(transducer):
    t = transducer.transduction_matrix(OMEGA)
    zl = 3e-4 - 2e-4j
    f, v, i = drive_voltage(t, zl, 1.0)
    q, u = i / (1j * OMEGA), v / (1j * OMEGA)
    np.testing.assert_allclose(force_per_voltage(t, zl), f, rtol=1e-12)
    np.testing.assert_allclose(displacement_per_voltage(t, zl, OMEGA), u, rtol=1e-12)
    np.testing.assert_allclose(force_per_charge(t, zl, OMEGA), f / q, rtol=1e-12)
    np.testing.assert_allclose(displacement_per_charge(t, zl), u / q, rtol=1e-12)
    # ideal loads: no force on a free tip, no motion of a clamped one
    assert np.all(force_per_voltage(t, 0.0) == 0)
    assert np.all(force_per_charge(t, 0.0, OMEGA) == 0)
    assert np.all(displacement_per_voltage(t, np.inf, OMEGA) == 0)
    assert np.all(displacement_per_charge(t, np.inf) == 0)
    np.testing.assert_allclose(force_per_voltage(t, np.inf), 1 / t[:, 0, 0], rtol=1e-15)


def test_reciprocity_actuator_equals_sensor(transducer):
    """Free displacement per volt equals the short-circuit charge per unit external force
    (the external force on the tip is -F): the physical content of det T = 1."""
    t = transducer.transduction_matrix(OMEGA)
    u_per_e = displacement_per_voltage(t, 0.0, OMEGA)
    f, e, i = drive_velocity(t, 1.0, "short")
    assert np.all(e == 0)
    q_per_external_force = (i / (1j * OMEGA)) / (-f)
    # I = t21 F + t22 V cancels to ~1e-11 relative; a 1 % break of det T = 1 fails by 1 %
    np.testing.assert_allclose(u_per_e, q_per_external_force, rtol=1e-9)


def test_open_and_short_velocity_drive():
    t = MACRO.transduction_matrix(OMEGA)
    f, e, i = drive_velocity(t, 1e-3, "open")
    assert np.all(i == 0)
    # the current it implies is zero to the rounding of its two terms
    resid = np.abs(t[:, 1, 0] * f + t[:, 1, 1] * 1e-3)
    assert np.all(resid <= 8 * EPS * np.abs(t[:, 1, 1] * 1e-3))
    f, e, i = drive_velocity(t, 1e-3, "short")
    assert np.all(e == 0)
    np.testing.assert_allclose(f, -t[:, 0, 1] / t[:, 0, 0] * 1e-3, rtol=1e-15)
    with pytest.raises(ValueError, match="termination"):
        drive_velocity(t, 1e-3, "grounded")


def test_cascade_with_tip_mass_shifts_the_load():
    t = MACRO.transduction_matrix(OMEGA)
    ms = 6.3e-5  # a 1.9 mm glass sphere, kg
    tc = cascade(t, tip_mass(OMEGA, ms))
    zm = 1e-4 + 5e-4j
    np.testing.assert_allclose(ze_from_zm(tc, zm), ze_from_zm(t, zm + 1j * OMEGA * ms),
                               rtol=1e-12)
    assert np.all(det_error(tc) <= det_floor(tc))
    assert np.all(det_error(tip_mass(OMEGA, ms)) == 0)
    # associativity
    a, b = tip_mass(OMEGA, 1e-5), tip_mass(OMEGA, 2e-5)
    np.testing.assert_allclose(cascade(t, a, b), cascade(t, cascade(a, b)), rtol=1e-13)
    np.testing.assert_allclose(cascade(a, b), tip_mass(OMEGA, 3e-5), rtol=1e-15)
    with pytest.raises(ValueError, match="tip mass"):
        tip_mass(OMEGA, -1.0)
    with pytest.raises(ValueError):
        cascade()


def test_det_error_detects_non_reciprocal():
    t = MACRO.transduction_matrix(OMEGA)
    assert np.all(det_error(t) <= det_floor(t))
    assert np.allclose(det_error(1.01 * t), 0.0201, rtol=1e-9)


@given(log_r=st.floats(-9, 2), f=freq_hz, tr=which)
def test_efficiency_is_passive(log_r, f, tr):
    t = tr.transduction_matrix(np.array(2 * np.pi * f))
    eff = efficiency(t, 10.0**log_r)
    assert 0 < eff < 1


def test_efficiency_zero_for_lossless_loads(transducer):
    t = transducer.transduction_matrix(OMEGA)
    for zl in (0.0, np.inf, 1e-3j, -4e-4j):
        np.testing.assert_allclose(efficiency(t, zl), 0.0, atol=1e-12)
