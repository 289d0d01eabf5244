"""The lumped transducer's identification (issue 23 §4's fluid rows): a hidden fluid device
fitted back from free sweeps and calibration loads, and what each measurement cannot show."""

import numpy as np
import pytest

from wtml.bench.device import FLUID_RADIUS, FLUID_TRUTH, fluid_measurements
from wtml.physics.identify_lumped import LUMPED_PARAMETERS, fit_lumped, scaled
from wtml.scenes import load_scene

SCENE = load_scene("configs/scenes/fluid.yaml")
START = SCENE.transducer.build()
FREE = {p: (0.5, 2.0) for p in LUMPED_PARAMETERS} | {"sphere_radius": (0.8, 1.2)}


def _measure(which, noise, seed):
    return fluid_measurements(scaled(START, FLUID_TRUTH), SCENE.sphere.radius * FLUID_RADIUS,
                              SCENE.sphere.density, which, noise,
                              SCENE.excitation.frequency_hz, SCENE.reference_zm(),
                              np.random.default_rng(seed))


def test_sweeps_with_and_without_the_sphere_and_loads_give_back_the_hidden_device():
    """Every factor within 3 standard errors of the truth, the sphere's radius too (1 % over
    nominal), the reduced χ² near 1; the fitted transducer's parameters are the truth's."""
    fit = fit_lumped(START, SCENE.sphere.radius, SCENE.sphere.density,
                     _measure("sweeps with and without the sphere + loads", 1e-4, 0), FREE)
    truth = FLUID_TRUTH | {"sphere_radius": FLUID_RADIUS}
    for name, value in truth.items():
        assert abs(fit.factors[name] - value) < 3 * fit.standard_errors[name], name
        assert fit.standard_errors[name] < 1e-3, name
    assert 0.7 < fit.reduced_chi2 < 1.3
    assert abs(fit.radius / (SCENE.sphere.radius * FLUID_RADIUS) - 1) < 1e-4


@pytest.mark.parametrize(("which", "blind"), [
    ("sweep with the sphere + loads", {"m", "sphere_radius"}),  # only m + m_s is seen
])
def test_what_the_measurements_cannot_show_has_an_infinite_standard_error(which, blind):
    fit = fit_lumped(START, SCENE.sphere.radius, SCENE.sphere.density,
                     _measure(which, 1e-4, 1), FREE)
    assert {k for k, v in fit.standard_errors.items() if not np.isfinite(v)} == blind


def test_free_sweeps_alone_cannot_tell_the_coupling():
    """Without a load of known Zm, Ze sees (k, m, c, m_s) / phi² only: phi is blind, and with
    it everything mechanical; c0 and tanδ are not."""
    m = _measure("sweeps with and without the sphere + loads", 1e-4, 2)[:2]
    fit = fit_lumped(START, SCENE.sphere.radius, SCENE.sphere.density, m, FREE)
    blind = {k for k, v in fit.standard_errors.items() if not np.isfinite(v)}
    assert blind == {"phi", "k", "m", "c", "sphere_radius"}
