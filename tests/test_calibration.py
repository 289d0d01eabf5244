"""Calibration: recovery of T at realistic magnitudes, its sign rule, its failure mode,
the direct methods, and saving without pickle."""

import numpy as np
import pytest

from tests.conftest import MACRO, MICRO
from wtml.physics import (
    Calibration,
    CalibrationError,
    calibrate_free_clamped,
    calibrate_least_squares,
    calibrate_open_short,
    drive_velocity,
    drive_voltage,
    ze_from_zm,
)
from wtml.physics.loads import MassSpringDamper
from wtml.signals import complex_noise

GRID = {"macro": 2 * np.pi * np.linspace(20, 60, 81),
        "micro": 2 * np.pi * np.linspace(20, 800, 157)}
TABLE_3_4 = [MassSpringDamper(m, k, c) for m, k, c in (
    (0, 0, 0), (6.1e-5, 2.5, 1.0e-2), (6.2e-5, 2.6, 1.1e-2), (6.3e-5, 2.7, 1.2e-2),
    (6.4e-5, 2.8, 1.3e-2))]


LOADS = {  # mass–spring–damper loads around each transducer's own |Zt|
    "macro": [MassSpringDamper(m=2e-5, c=1e-3), MassSpringDamper(k=1.0),
              MassSpringDamper(m=3e-5, k=1.0, c=1e-4), MassSpringDamper(c=3e-3),
              MassSpringDamper(k=10.0)],
    "micro": [MassSpringDamper(m=2e-8, c=1e-5), MassSpringDamper(k=0.1),
              MassSpringDamper(m=3e-8, k=0.1, c=1e-6), MassSpringDamper(c=3e-5),
              MassSpringDamper(c=1e-6)],
}


def setup(name):
    """T, the grid, Zm of (free, five loads, clamped) of shape (7, n_freq), and Ze."""
    tr, omega = {"macro": MACRO, "micro": MICRO}[name], GRID[name]
    zm = np.array([ld.impedance(omega) for ld in LOADS[name]])
    zm = np.concatenate([np.zeros((1, omega.size)), zm, np.full((1, omega.size), np.inf)])
    t = tr.transduction_matrix(omega)
    return t, omega, zm, ze_from_zm(t, zm)


@pytest.mark.parametrize("name", ["macro", "micro"])
def test_recovers_t_at_realistic_magnitudes(name):
    t, omega, zm, ze = setup(name)
    finite = np.isfinite(zm)
    assert 1e5 <= np.abs(ze).min() and np.abs(ze).max() <= 1e10
    assert np.abs(zm[finite]).max() <= 1e-1 and np.abs(zm[finite & (zm != 0)]).min() >= 1e-6
    cal = calibrate_least_squares(zm, ze, omega)
    np.testing.assert_allclose(cal.t, t, rtol=1e-9)  # the sign rule picks the true sign here
    assert cal.n_loads == 7 and cal.method == "least_squares"
    assert np.all(cal.condition < 1e3) and np.all(cal.residual < 1e-12)
    np.testing.assert_array_equal(cal.omega, omega)
    # the calibrated T maps the loads back
    np.testing.assert_allclose(cal.zm_from_ze(ze[1:6]), zm[1:6], rtol=1e-7)


def test_column_scaling_is_what_makes_it_solvable():
    """Unscaled, the micro set's system has a condition number ~2e11 (Zm ~ 1e-6-1e-3 against
    Ze ~ 1e7-1e9; physics.md quotes up to 1e16); weighted and scaled, it is the load set's
    own conditioning, < 1e3."""
    t, omega, zm, ze = setup("micro")
    k = 10
    finite = np.isfinite(zm[:, k])
    a = np.stack([zm[finite, k], zm[finite, k] * ze[finite, k], np.ones(finite.sum())], -1)
    s = np.linalg.svd(a, compute_uv=False)
    cal = calibrate_least_squares(zm, ze, omega)
    assert s[0] / s[-1] > 1e10 and cal.condition[k] < 1e3


def test_sign_rules():
    """T and -T give the same Ze; the rules pick Re t11 > 0 and continuity along the grid."""
    t, omega, zm, ze = setup("macro")
    cal_neg = calibrate_least_squares(zm, ze_from_zm(-t, zm), omega)
    np.testing.assert_allclose(cal_neg.t, t, rtol=1e-9)
    indep = calibrate_least_squares(zm, ze, omega, sign_rule="re_t11_positive")
    assert np.all(indep.t[:, 0, 0].real > 0)
    # a T whose t11 phase winds through ±90° along the grid: continuity follows it,
    # the per-frequency rule flips where Re t11 changes sign
    phase = np.exp(1j * np.linspace(0, 0.9 * np.pi, omega.size))
    t_rot = t.copy()
    t_rot[:, 0, :] *= phase[:, None]
    t_rot[:, 1, :] /= phase[:, None]  # diag(p, 1/p) @ T: det 1, t11 winds by 0.9π
    ze_rot = ze_from_zm(t_rot, zm)
    cont = calibrate_least_squares(zm, ze_rot, omega)
    np.testing.assert_allclose(cont.t, t_rot, rtol=1e-9)
    per_freq = calibrate_least_squares(zm, ze_rot, omega, sign_rule="re_t11_positive")
    flipped = np.abs(per_freq.t[:, 0, 0] + t_rot[:, 0, 0]) < 1e-9 * np.abs(t_rot[:, 0, 0])
    assert flipped.any() and not flipped.all()
    with pytest.raises(ValueError, match="sign_rule"):
        calibrate_least_squares(zm, ze, omega, sign_rule="positive")


def test_near_identical_loads_are_refused():
    """Thesis Table 3.4: five loads differing by ~2 % are nearly degenerate."""
    omega = GRID["macro"]
    zm = np.array([ld.impedance(omega) for ld in TABLE_3_4])
    ze = ze_from_zm(MACRO.transduction_matrix(omega), zm)
    with pytest.raises(CalibrationError, match=r"condition number [\d.e+]+ at frequency index "
                                               r"\d+ exceeds max_condition=1e\+04"):
        calibrate_least_squares(zm, ze, omega)
    # accepted when the user knowingly raises the threshold; the number says why it is bad
    cal = calibrate_least_squares(zm, ze, omega, max_condition=1e12)
    assert cal.condition.max() > 1e4


def test_identical_loads_are_refused():
    omega = GRID["macro"][:3]
    zm = np.vstack([np.zeros(3)] + [MassSpringDamper(k=2.0).impedance(omega)] * 4)
    ze = ze_from_zm(MACRO.transduction_matrix(omega), zm)
    with pytest.raises(CalibrationError, match="loads too alike"):
        calibrate_least_squares(zm, ze, omega)


def test_error_grows_as_condition_times_noise(rng):
    t, omega, zm, ze = setup("macro")
    noise = 1e-6
    cal = calibrate_least_squares(zm, complex_noise(ze, noise, rng), omega)
    rel = np.max(np.abs(cal.t - t), axis=(1, 2)) / np.max(np.abs(t), axis=(1, 2))
    assert np.all(rel < 10 * cal.condition * noise)
    assert np.all(rel > 1e-3 * noise)  # the noise did reach T
    # the residual estimates the noise: sqrt((7 - 3)/7) x 1e-6 in expectation
    np.testing.assert_allclose(np.median(cal.residual), np.sqrt(4 / 7) * noise, rtol=0.3)


def test_bad_inputs():
    t, omega, zm, ze = setup("macro")
    with pytest.raises(CalibrationError, match=">= 4 loads, got 3"):
        calibrate_least_squares(zm[:3], ze[:3], omega)
    bad = ze.copy()
    bad[2, 3] = np.nan
    with pytest.raises(CalibrationError, match="ze contains NaN"):
        calibrate_least_squares(zm, bad, omega)
    with pytest.raises(CalibrationError, match="shape"):
        calibrate_least_squares(zm, ze[:, :-1], omega)


def test_single_frequency_shape():
    t, omega, zm, ze = setup("macro")
    cal = calibrate_least_squares(zm[:, 5], ze[:, 5], omega[5])
    assert cal.t.shape == (1, 2, 2)
    np.testing.assert_allclose(cal.t[0], t[5], rtol=1e-9)


def test_save_load_round_trip(tmp_path):
    t, omega, zm, ze = setup("micro")
    cal = calibrate_least_squares(zm, ze, omega)
    path = cal.save(tmp_path / "cal.npz")
    back = Calibration.load(path)
    for name in ("t", "omega", "condition", "residual"):
        np.testing.assert_array_equal(getattr(back, name), getattr(cal, name))
    assert (back.method, back.sign_rule, back.n_loads) == (cal.method, cal.sign_rule, 7)
    with np.load(path, allow_pickle=False) as data:  # no object arrays inside
        assert all(data[k].dtype != object for k in data.files)
    np.savez(tmp_path / "other.npz", t=cal.t)
    with pytest.raises(ValueError, match="not a wtml calibration"):
        Calibration.load(tmp_path / "other.npz")


def test_direct_methods_recover_t():
    for tr, omega in ((MACRO, GRID["macro"]), (MICRO, GRID["micro"])):
        t = tr.transduction_matrix(omega)
        e = np.full(omega.size, 10.0 + 0j)
        f_free, v_free, i_free = drive_voltage(t, 0.0, e)
        f_cl, v_cl, i_cl = drive_voltage(t, np.inf, e)
        assert np.all(f_free == 0) and np.all(v_cl == 0)
        cal = calibrate_free_clamped((e, i_free, v_free), (e, i_cl, f_cl), omega)
        np.testing.assert_allclose(cal.t, t, rtol=1e-12)
        v = np.full(omega.size, 1e-3 + 0j)
        f_o, e_o, i_o = drive_velocity(t, v, "open")
        f_s, e_s, i_s = drive_velocity(t, v, "short")
        cal2 = calibrate_open_short((f_o, v, e_o), (f_s, v, i_s), omega)
        np.testing.assert_allclose(cal2.t, t, rtol=1e-9)
        assert cal.method == "free_clamped" and np.all(np.isnan(cal.condition))
    with pytest.raises(CalibrationError, match="not finite"):
        calibrate_free_clamped((e, i_free, np.zeros_like(e)), (e, i_cl, f_cl), omega)
