"""Lumped single-mode model: det T = 1, its closed-form port impedances, input checks."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from wtml.physics import LumpedTransducer, det_error, ze_from_zm

EPS = np.finfo(float).eps


@given(c0=st.floats(-12, -7), phi=st.floats(-8, -3), m=st.floats(-9, -3), f0=st.floats(1, 4),
       q=st.floats(1, 1000), tan_delta=st.floats(0, 0.1), f=st.floats(0, 4.5))
def test_det_is_one_to_rounding(c0, phi, m, f0, q, tan_delta, f):
    tr = LumpedTransducer.from_resonance(c0=10**c0, phi=10**phi, m=10**m, f0=10**f0, q=q,
                                         tan_delta=tan_delta)
    t = tr.transduction_matrix(np.array([2 * np.pi * 10**f]))
    floor = 8 * EPS * (np.abs(t[..., 0, 0] * t[..., 1, 1]) + np.abs(t[..., 0, 1] * t[..., 1, 0]))
    assert np.all(det_error(t) <= floor)


def test_port_impedances_have_the_closed_forms(transducer):
    """Free: Ze = 1/(jωC0 + φ²/Zt) (motional branch beside C0); clamped: Ze = 1/(jωC0)."""
    omega = 2 * np.pi * np.linspace(10, 1000, 200)
    t = transducer.transduction_matrix(omega)
    jwc = 1j * omega * transducer.capacitance()
    zt = transducer.mechanical_impedance(omega)
    np.testing.assert_allclose(ze_from_zm(t, 0.0), 1 / (jwc + transducer.phi**2 / zt), rtol=1e-12)
    np.testing.assert_allclose(ze_from_zm(t, np.inf), 1 / jwc, rtol=1e-12)
    # a load adds in series with the mechanical branch
    zm = 2e-4 + 3e-4j
    np.testing.assert_allclose(ze_from_zm(t, zm), 1 / (jwc + transducer.phi**2 / (zt + zm)),
                               rtol=1e-10)


def test_free_resonance_is_the_admittance_peak():
    tr = LumpedTransducer.from_resonance(c0=7e-9, phi=1e-5, m=2e-5, f0=36.0, q=30.0)
    f = np.linspace(30, 42, 12001)
    t = tr.transduction_matrix(2 * np.pi * f)
    motional = np.abs(1 / ze_from_zm(t, 0.0) - 1j * 2 * np.pi * f * tr.c0)
    assert abs(f[np.argmax(motional)] - 36.0) < 2e-3


@pytest.mark.parametrize("field,value,match", [
    ("c0", 0.0, r"c0 must be in \(0, inf\) F"),
    ("phi", -1e-5, "phi"),
    ("m", float("nan"), "m must be"),
    ("tan_delta", 2.0, r"tan_delta must be in \[0, 1\]"),
])
def test_bad_parameters_name_the_field(field, value, match):
    kw = dict(c0=7e-9, phi=1e-5, k=1.0, m=2e-5, c=1e-4)
    kw[field] = value
    with pytest.raises(ValueError, match=match):
        LumpedTransducer(**kw)


def test_bad_frequency_is_refused():
    tr = LumpedTransducer(c0=7e-9, phi=1e-5, k=1.0, m=2e-5, c=1e-4)
    with pytest.raises(ValueError, match="omega must be in"):
        tr.transduction_matrix(np.array([100.0, 0.0]))
    with pytest.raises(ValueError, match="omega"):
        tr.transduction_matrix(np.array([np.nan]))
