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


def test_the_whiskers_mesh_converges_and_the_texture_scene_keeps_its_band_converged():
    """Doubling the whisker's elements moves the macro WT's modes below 25.6 kHz by 11 % at
    the 8 elements every scene had (modes 14-21), by under 0.1 % at texture's 32; the micro
    WT's below 500 Hz (onset's and radial's band) not at all at 8. The lowest two modes,
    which the thesis fit matched, stay within 1e-5 of 8 at 32. The texture scene reduces the
    beam of its own mesh to its modes and refuses a mesh that does not hold its Nyquist,
    naming ``whisker_elements``."""
    import dataclasses

    from wtml.physics.beam_presets import whisker_mesh_error
    from wtml.scenes import SceneError
    from wtml.scenes.texture import MESH_TOLERANCE, TextureScene
    from wtml.schema import build as build_config

    coarse, fine = whisker_mesh_error("macro", 25600.0, 8), whisker_mesh_error("macro", 25600.0, 32)
    assert coarse > 0.1 > 1e-3 > fine and whisker_mesh_error("macro", 5000.0, 8) < 5e-3
    assert whisker_mesh_error("micro", 500.0, 8) < 1e-6
    low = [build("macro", whisker_elements=k).natural_frequencies(2) for k in (8, 32)]
    np.testing.assert_allclose(low[0], low[1], rtol=1e-5)
    scene = build_config(TextureScene, {})
    assert scene.whisker_elements == scene.beam().segments[-1].elements == 32
    ours = scene.transducer().omega_n
    theirs = dataclasses.replace(scene, whisker_elements=8).transducer().omega_n
    assert abs(theirs[13] / ours[13] - 1) > 0.01 and abs(theirs[0] / ours[0] - 1) < 1e-5
    assert whisker_mesh_error("macro", 25600.0, 16) > MESH_TOLERANCE
    with pytest.raises(SceneError, match=r"whisker_elements: at 16 the modes below 25600 Hz "
                                         r"move by 0.86 % .* raise whisker_elements"):
        build_config(TextureScene, {"whisker_elements": 16})
    from wtml.scenes import scene_from_dict, to_dict

    stored = to_dict(scene)  # a manifest's or export's scene of before the key: 8 elements
    stored.pop("whisker_elements")
    with pytest.raises(SceneError, match="at 8 the modes .* stored before 30 Nov had 8"):
        scene_from_dict(stored)
    assert scene_from_dict({"task": "texture"}).whisker_elements == 32  # a file: the default
