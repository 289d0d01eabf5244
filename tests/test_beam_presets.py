"""Beam presets: fits inside their stated ranges, and the thesis numbers they predict."""

import numpy as np
import pytest

from wtml.devices import load_device
from wtml.physics.beam_presets import PRESETS, build, fidelity_table, refit, resonance
from wtml.physics.presets import fluid_lumped


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_fit_hits_its_targets_inside_the_allowed_ranges(name):
    """The shipped file's fitted lengths are what its provenance's fit gives (to 1e-9 m), not
    pinned to a bound, and hit the file's target resonances."""
    device = load_device(name)
    for free, value in zip(device.provenance.free, refit(device), strict=True):
        assert free.low < value < free.high  # not pinned to a bound
        assert abs(device.length_of(free.name) - value) < 1e-9
    for t in device.provenance.targets:
        assert abs(resonance(device, t.condition) / t.hz - 1) < 1e-6


def test_predictions_against_the_thesis():
    """Not fitted: micro static displacement (thesis 1.20 µm/V) and the fluid preset's second
    resonance (≈500 Hz) come within 12 % and 5 %."""
    assert abs(build("micro").static_tip_displacement_per_volt() / 1.20e-6 - 1) < 0.12
    rows = {(r["preset"], r["quantity"]): r["computed"] for r in fidelity_table()}
    second = float(rows[("fluid", "2nd resonance with the sphere")].split()[0])
    assert abs(second / 500 - 1) < 0.05


def test_lumped_fluid_model_checked_against_the_beam_preset():
    """The fluid slice's lumped model was built from 100 Hz free and 96 Hz in water; the beam
    preset, fitted to 100 Hz only, predicts the water resonance within 3 % of it."""
    rows = {(r["preset"], r["quantity"]): r["computed"] for r in fidelity_table()}
    beam_water = float(rows[("fluid", "resonance in water, 25 °C")].split()[0])
    assert abs(beam_water / 96.0 - 1) < 0.03
    assert fluid_lumped().k > 0  # the lumped model stays the fluid slice's cheap path


def test_unknown_preset():
    with pytest.raises(ValueError, match="unknown device 'nano': not a shipped device"):
        build("nano")
    with pytest.raises(ValueError, match="'fluid-lumped' is a lumped device; a beam one"):
        build("fluid-lumped")
    assert np.isfinite(build("macro").length)
