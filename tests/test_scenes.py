"""Scenes: validation with key paths, the fluid preset's resonances, the generator's physics."""

import numpy as np
import pytest

from wtml.physics import cascade, tip_mass, ze_from_zm, zm_from_ze
from wtml.physics.fluids import water
from wtml.physics.loads import stokes_sphere
from wtml.physics.lumped import LumpedTransducer
from wtml.physics.presets import FLUID_SPHERE_MASS, FLUID_SPHERE_RADIUS, fluid_lumped
from wtml.scenes import FluidScene, SceneError, config_hash, load_scene
from wtml.schema import build


def write(tmp_path, text):
    path = tmp_path / "scene.yaml"
    path.write_text(text)
    return path


def test_the_shipped_scene_loads():
    scene = load_scene("configs/scenes/fluid.yaml")
    assert isinstance(scene, FluidScene)
    assert scene.excitation.n_freq == 31 and scene.sphere.radius == pytest.approx(1.9e-3)
    assert len(config_hash(scene)) == 64


@pytest.mark.parametrize("text,match", [
    ("excitation:\n  n_freq: 0\n", r"excitation.n_freq: must be in \[1, 4096\], got 0"),
    ("excitation:\n  n_fre: 31\n", r"excitation.n_fre: unknown key; allowed keys here"),
    ("fluid:\n  volume_fraction: [0.5, 0.2]\n", r"fluid.volume_fraction: low 0.5 is above high"),
    ("fluid:\n  temperature_c: [10, 120]\n", r"fluid.temperature_c\[1\]: must be in \[0, 100\]"),
    ("noise:\n  ze_relative: high\n", r"noise.ze_relative: must be a number"),
    ("transducer:\n  preset: nano\n", r"transducer.device: unknown device 'nano': not a shipped"),
    ("transducer:\n  device: micro\n", r"transducer.device: this scene needs a lumped device; "
                                       r"'micro' is a beam one"),
    ("transducer:\n  overrides: {q: 3}\n", r"transducer.overrides.q: unknown parameter"),
    ("transducer:\n  overrides: {phi: -1.0}\n", r"transducer.overrides.phi: must be a number >= 0"),
    ("samples: 4\nshards: 8\n", r"shards: 8 shards for 4 samples"),
    ("excitation:\n  f_start_hz: 120\n  f_stop_hz: 90\n", r"excitation.f_stop_hz: 90 is below"),
])
def test_bad_scenes_name_the_key_path(tmp_path, text, match):
    with pytest.raises(SceneError, match=match):
        load_scene(write(tmp_path, text))


def test_a_texture_scenes_acquisition_mapping_changes_only_the_keys_it_names():
    """A texture scene's ``acquisition:`` lays its keys over the texture acquisition (51.2
    kS/s, 20 V and 100 µA full scale), nested mappings alike; a bad key or value in it is
    still refused by its path; a scene without the mapping is the default's."""
    from wtml.scenes.texture import TextureScene

    default = build(TextureScene, {}).acquisition
    got = build(TextureScene, {"acquisition": {"adc_bits": 16,
                                               "effects": {"hum": {"enabled": True}}}})
    a = got.acquisition
    assert (a.sample_rate_hz, a.e_full_scale_v, a.i_full_scale_a) == (51200.0, 20.0, 1e-4)
    assert a.adc_bits == 16 and a.effects.hum.enabled and not a.effects.iv.enabled
    assert a.effects.hum.mains_hz == default.effects.hum.mains_hz
    assert a != default and build(TextureScene, {"acquisition": {}}).acquisition == default
    with pytest.raises(SceneError, match=r"acquisition.effects.hum.level: must be in"):
        build(TextureScene, {"acquisition": {"effects": {"hum": {"level": -1.0}}}})
    with pytest.raises(SceneError, match=r"acquisition.sample_rate: unknown key"):
        build(TextureScene, {"acquisition": {"sample_rate": 1e5}})


def test_fluid_preset_resonates_at_100_hz_free_and_96_hz_in_water():
    """The two thesis numbers the preset was built from (presets.py explains how)."""
    tr = fluid_lumped()
    f = np.linspace(85, 110, 25001)
    omega = 2 * np.pi * f
    t = cascade(tr.transduction_matrix(omega), tip_mass(omega, FLUID_SPHERE_MASS))
    def peak(zm):
        motional = np.abs(1 / ze_from_zm(t, zm) - 1j * omega * tr.capacitance())
        return f[np.argmax(motional)]
    assert abs(peak(0.0) - 100.0) < 0.01
    assert abs(peak(stokes_sphere(*water(25.0), FLUID_SPHERE_RADIUS, omega)) - 96.0) < 0.05


def test_overrides_reach_the_transducer():
    scene = build(FluidScene, {"transducer": {"overrides": {"c0": 1e-8}}})
    assert scene.transducer.build().c0 == 1e-8


def test_generator_physics_and_nuisance(rng):
    """Noise-free, the calibrated T reports (1 + α) Zm + β Zref: the stated error model."""
    scene = build(FluidScene, {"noise": {"ze_relative": 0.0}})
    d = scene.simulate(50, rng)
    zm_true = stokes_sphere(d["eta"][:, None], d["rho"][:, None], scene.sphere.radius,
                            scene.excitation.omega)
    seen = zm_from_ze(scene.calibrated_t(), d["ze"])
    offset = d["cal_offset"][:, None] * scene.reference_zm()
    expected = (1 + d["cal_gain"][:, None]) * zm_true + offset
    np.testing.assert_allclose(seen, expected, rtol=1e-8)
    assert 0.003 < np.std(d["cal_gain"]) < 0.02  # 1 % complex: 0.7 % per component
    assert d["eta"].min() > 5e-4 and d["eta"].max() < 2.4


def test_generator_builds_t_once_per_call(monkeypatch, rng):
    calls = []
    original = LumpedTransducer.transduction_matrix

    def counting(self, omega):
        calls.append(np.shape(omega))
        return original(self, omega)

    monkeypatch.setattr(LumpedTransducer, "transduction_matrix", counting)
    scene = build(FluidScene, {})
    scene.simulate(500, rng)
    assert calls == [(31,)]


def test_generator_is_deterministic():
    scene = build(FluidScene, {})
    a = scene.simulate(100, np.random.default_rng([0, 3]))
    b = scene.simulate(100, np.random.default_rng([0, 3]))
    for k in a:
        np.testing.assert_array_equal(a[k], b[k])


def test_a_shard_beyond_the_memory_ceiling_is_refused_before_any_work():
    """A scene whose shards would take more than wtml.files.MEMORY_CEILING to simulate (30000
    texture records of 1 s in 3 shards: ~65 GB each; the fuzz harness found it as a
    MemoryError half-way into `wtml generate`) is refused when it is read, naming shards and
    how many it needs; the shipped time-domain scenes fit (their shards take < 0.6 GB)."""
    from wtml.files import MEMORY_CEILING
    from wtml.scenes import load_scene, scene_from_dict
    from wtml.scenes.onset import BYTES_PER_SAMPLE
    from wtml.schema import to_dict

    for name in ("texture", "texture_fepa", "onset", "onset_full"):
        s = load_scene(f"configs/scenes/{name}.yaml")
        per_shard = -(-s.samples // s.shards) * s.n_samples * BYTES_PER_SAMPLE
        assert per_shard * getattr(s, "oversample", 1) < 0.3 * MEMORY_CEILING
    d = to_dict(load_scene("configs/scenes/texture.yaml"))
    d.update(samples=30000, shards=3)
    with pytest.raises(SceneError, match=r"^shards: 10000 records .* use at least 92 shards"):
        scene_from_dict(d)
    d.update(shards=92)
    assert scene_from_dict(d).shards == 92
