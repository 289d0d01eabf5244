"""A preset's manufacturing spread (wtml/physics/spread.py) and the radial scene drawing its
devices from it."""

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from wtml.physics.beam import BeamTransducer
from wtml.physics.beam_presets import PRESETS, build, device_parameters
from wtml.physics.spread import DeviceSpread, device_ze, devices, draw_factors
from wtml.scenes import RadialScene, SceneError
from wtml.schema import build as build_config
from wtml.signals import complex_noise

SPREAD = DeviceSpread(length=0.01, thickness=0.01, modulus=0.03, loss_factor=0.25,
                      tan_delta=0.25, coupling=0.03)
OMEGA = 2 * np.pi * np.array([420.0, 380.0, 460.0])


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_zero_spread_is_the_preset_exactly(preset):
    """Every factor of a zero spread is exactly 1, and the device built from it has the
    preset's matrices, coupling, capacitance and tanδ bit for bit."""
    factors = draw_factors(preset, DeviceSpread().widths(preset), 3, np.random.default_rng(0))
    assert all(np.array_equal(f, np.ones(3)) for f in factors.values())
    nominal = build(preset)
    for device in devices(preset, factors):
        for a, b in zip(device.matrices(), nominal.matrices(), strict=True):
            np.testing.assert_array_equal(a, b)
        assert device.capacitance == nominal.capacitance and device.length == nominal.length


def test_drawn_factors_have_the_stated_spread():
    """Uniform on 1 ± w: inside the band, std w/√3 (20000 draws: within 3 %), mean 1, each
    parameter independent of the others, and each class's width on each of its parameters."""
    widths = SPREAD.widths("macro")
    assert set(widths) == set(device_parameters("macro"))
    factors = draw_factors("macro", widths, 20000, np.random.default_rng(1))
    for name, f in factors.items():
        w = widths[name]
        assert w == getattr(SPREAD, device_parameters("macro")[name]) and w > 0
        assert np.all(np.abs(f - 1) <= w)
        assert np.std(f) == pytest.approx(w / np.sqrt(3), rel=0.03)
        assert abs(np.mean(f) - 1) < 4 * w / np.sqrt(3 * 20000)
    corr = np.corrcoef(np.stack(list(factors.values())))
    assert np.max(np.abs(corr - np.eye(len(factors)))) < 0.05


def test_a_named_parameters_width_replaces_its_classs_and_is_checked():
    """``parameters`` widens one named parameter past its class (texture's whisker EI ±10 %,
    the other moduli ±3 %): its factors span its own band, the class's others theirs; a
    spread of named widths alone is not ``none``; an unknown name or a width out of [0, 0.3]
    is refused naming ``spread.parameters.<name>`` and its class's range; an empty mapping
    leaves the scene's identity (``config_hash``) as it was before the key existed;
    a named whisker length widens the radial scene's whisker margin."""
    spread = dataclasses.replace(SPREAD, parameters={"whisker.modulus": 0.1})
    widths = spread.widths("macro")
    assert widths["whisker.modulus"] == 0.1 and widths["bimorph.modulus"] == 0.03
    f = draw_factors("macro", widths, 20000, np.random.default_rng(1))
    assert 0.099 < np.abs(f["whisker.modulus"] - 1).max() <= 0.1
    assert np.abs(f["bimorph.modulus"] - 1).max() <= 0.03
    alone = DeviceSpread(parameters={"whisker.modulus": 0.1})
    assert not alone.none and alone.tolerances and DeviceSpread().none
    alone.check_device("", build_config(RadialScene, {}).device)
    for name, width, match in (("whisker.radius", 0.1, "not a parameter of device"),
                               ("whisker.modulus", 0.5, r"must be a number in \[0, 0.3\] "
                                                        r"\(its class modulus's range\)"),
                               ("whisker.length", 0.2, r"must be a number in \[0, 0.1\]"),
                               ("whisker.modulus", "wide", "must be a number")):
        with pytest.raises(SceneError, match=rf"spread.parameters.{name}: {match}"):
            build_config(RadialScene, {"spread": {"parameters": {name: width}}})
    from wtml.schema import config_hash, to_dict

    radial = build_config(RadialScene, {})
    assert "parameters" not in to_dict(radial)["spread"]
    assert config_hash(radial) == config_hash(build_config(RadialScene, {"spread": {
        "parameters": {}}}))
    assert "parameters" in to_dict(dataclasses.replace(radial, spread=alone))["spread"]
    device = radial.device
    assert DeviceSpread(length=0.005, parameters={"whisker.length": 0.02}
                        ).whisker_margin(device) == 0.02


def test_drawn_devices_carry_their_factors():
    """The built device's segments scale as drawn: EI of the whisker (square) with
    E t⁴, its length with L, the bimorph's free length, tanδ, the loss factor and the
    coupling."""
    factors = draw_factors("micro", SPREAD.widths("micro"), 4, np.random.default_rng(2))
    nominal = build("micro")
    for i, device in enumerate(devices("micro", factors)):
        f = {k: v[i] for k, v in factors.items()}
        whisker, bimorph = device.segments[-1], device.segments[0]
        assert whisker.bending_stiffness == pytest.approx(
            nominal.segments[-1].bending_stiffness * f["whisker.modulus"]
            * f["whisker.thickness"] ** 4, rel=1e-12)
        assert whisker.length == pytest.approx(nominal.segments[-1].length
                                               * f["whisker.length"], rel=1e-12)
        assert bimorph.length == pytest.approx(nominal.segments[0].length * f["bimorph.length"],
                                               rel=1e-12)
        assert device.tan_delta == pytest.approx(nominal.tan_delta * f["tan_delta"], rel=1e-12)
        assert bimorph.loss_factor == pytest.approx(0.02 * f["loss_factor"], rel=1e-12)
        # Γ = e31 b z with e31 = d31/s11E and z the layers' mid-plane: d31 E t
        assert bimorph.coupling == pytest.approx(nominal.segments[0].coupling * f["coupling"]
                                                 * f["bimorph.modulus"]
                                                 * f["bimorph.thickness"], rel=1e-12)


def test_unknown_factor_and_parameter_are_named():
    with pytest.raises(ValueError, match="'block.length' is not a parameter of device 'micro'"):
        build("micro", factors={"block.length": 1.01})
    with pytest.raises(ValueError, match="parameter must be one of"):
        SPREAD.only("sphere.radius", "micro")
    assert SPREAD.only("whisker.modulus", "micro") == {
        p: 0.03 if p == "whisker.modulus" else 0.0 for p in device_parameters("micro")}


@settings(max_examples=10, deadline=None)
@given(st.integers(0, 2**32 - 1), st.sampled_from(sorted(PRESETS)), st.integers(1, 4))
def test_perturbed_devices_are_reciprocal_and_the_batched_path_agrees(seed, preset, chunk):
    """At the spread's widest bands: det T = 1 for every drawn device, free and with a
    contact anywhere on its shaft (stiff, soft or rigid), and the batched evaluation of
    every record's device agrees with each device's own (1e-9), Rayleigh damping included.
    The two paths differ in algorithm (a batched inverse for the rank-one contact updates,
    against an LU solve per frequency since 12eb545), so they agree to the dynamic stiffness's
    condition number times the rounding: hypothesis found 1.5e-10 (seed 12771, micro-fluid).
    ``chunk`` devices at a time (1 or 2 of the 3, each group's indices its own) or all at
    once."""
    rng = np.random.default_rng(seed)
    wide = DeviceSpread(length=0.1, thickness=0.1, modulus=0.3, loss_factor=0.9,
                        tan_delta=0.9, coupling=0.3)
    trs = devices(preset, draw_factors(preset, wide.widths(preset), 3, rng))
    trs[1] = BeamTransducer(trs[1].segments, trs[1].masses, trs[1].tan_delta, (3.0, 1e-5))
    which = rng.integers(0, 3, 12)
    lengths = np.array([t.length for t in trs])
    d = rng.uniform(0.0, 0.9, 12) * lengths[which]
    k = np.where(rng.random(12) < 0.2, np.inf, np.exp(rng.uniform(0, np.log(1e6), 12)))
    free, ze = device_ze(trs, OMEGA, which, d, k, chunk)
    for i, tr in enumerate(trs):
        t = tr.transduction_matrix(OMEGA)
        np.testing.assert_allclose(np.linalg.det(t), 1.0, atol=1e-9)
        np.testing.assert_allclose(free[i], t[:, 0, 1] / t[:, 1, 1], rtol=1e-10)
        sel = which == i
        if sel.any():
            tc = tr.contact_transduction_matrix(OMEGA, tr.length - d[sel], k[sel])
            np.testing.assert_allclose(np.linalg.det(tc), 1.0, atol=1e-9)
            np.testing.assert_allclose(ze[sel], tc[..., 0, 1] / tc[..., 1, 1], rtol=1e-9)


def test_devices_taken_a_few_at_a_time_give_the_same_ze_and_a_bad_index_is_refused():
    """``device_ze`` in groups of 2 of 5 devices, one of them with no record, is the all-at-once
    evaluation to the bit; a record's device index outside the list is refused by name (not
    left as uninitialised memory)."""
    rng = np.random.default_rng(8)
    trs = devices("micro", draw_factors("micro", SPREAD.widths("micro"), 5, rng))
    which = np.array([0, 1, 1, 4, 0, 4, 1, 0])  # devices 2 and 3: none (3 alone in its group)
    lengths = np.array([t.length for t in trs])
    d = rng.uniform(0.0, 0.9, len(which)) * lengths[which]
    k = np.exp(rng.uniform(0, np.log(1e6), len(which)))
    whole, parts = device_ze(trs, OMEGA, which, d, k, 5), device_ze(trs, OMEGA, which, d, k, 2)
    for a, b in zip(whole, parts, strict=True):
        np.testing.assert_array_equal(a, b)
    for bad in (5, -1):
        with pytest.raises(ValueError, match=r"which: device indices must be in \[0, 4\]"):
            device_ze(trs, OMEGA, np.append(which, bad), np.append(d, 1e-4), np.append(k, 1e3))


def test_radial_scene_without_spread_is_the_preset_draw_for_draw():
    """The default (no spread): ze, distance and stiffness are the preset's, drawn in the
    order of the scene before the device block existed; the reference is the preset's free
    Ze with its own noise, drawn last."""
    scene = build_config(RadialScene, {"samples": 100, "shards": 1})
    assert scene.spread == DeviceSpread() and scene.spread.none
    got = scene.simulate(50, np.random.default_rng(3))
    rng = np.random.default_rng(3)
    d = 1e-6 * rng.uniform(*scene.contact.distance_um, 50)
    k = np.exp(rng.uniform(*np.log(scene.contact.stiffness), 50))
    ze = complex_noise(scene.ze_of(d, k), scene.noise.ze_relative, rng)
    ref = complex_noise(np.broadcast_to(scene.free_ze(), ze.shape),
                        scene.noise.reference_relative, rng)
    for key, value in (("ze", ze), ("distance", d), ("stiffness", k), ("ref", ref)):
        np.testing.assert_array_equal(got[key], value)


def test_radial_scene_with_spread_draws_devices_per_record():
    """With the spread on, records share a device only by chance, each record's reference
    is its own device's free Ze (records of one device: the same reference, to its noise),
    and a parameter alone moves only what it moves."""
    scene = build_config(RadialScene, {"samples": 100, "shards": 1,
                                       "noise": {"reference_relative": 0.0},
                                       "spread": dataclasses.asdict(SPREAD) | {"devices": 5}})
    data = scene.simulate(200, np.random.default_rng(4))
    refs = np.unique(data["ref"][:, 0])
    assert 2 <= len(refs) <= 5
    nominal = scene.free_ze()
    assert not np.any(np.all(np.isclose(data["ref"], nominal, rtol=1e-12), -1))
    alone = scene.simulate(100, np.random.default_rng(5),
                           widths=SPREAD.only("whisker.modulus", "micro"))
    # the free Ze hardly sees the whisker's modulus (its first mode is 4× the tones)
    np.testing.assert_allclose(alone["ref"], np.broadcast_to(nominal, alone["ref"].shape),
                               rtol=2e-3)
    bad = {"contact": {"distance_um": [0.0, 4990.0]}, "spread": {"length": 0.01}}
    with pytest.raises(SceneError, match="must stay below the whisker length 4950 µm"):
        build_config(RadialScene, bad)
    with pytest.raises(SceneError, match=r"spread.modulus: must be in \[0, 0.3\]"):
        build_config(RadialScene, {"spread": {"modulus": 0.5}})

