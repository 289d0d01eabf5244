"""Device files (issue 23 §1): the thesis's transducers as shipped YAML, validated, named and
hashed; scenes take ``device:`` (a shipped name or a path) and keep reading ``preset:``."""

import dataclasses
import json

import numpy as np
import pytest

from wtml.data import generate
from wtml.data.shards import read_manifest
from wtml.devices import (
    DEVICES_DIR,
    BeamDevice,
    LumpedDevice,
    device_hash,
    load_device,
    shipped_devices,
)
from wtml.physics.beam_presets import build, fidelity_table, format_fidelity
from wtml.physics.presets import FLUID_SPHERE_MASS, FLUID_TOTAL_MASS, MACRO_C0
from wtml.scenes import load_scene, scene_from_dict
from wtml.schema import SchemaError, config_hash, to_dict

# Measured before the presets moved into device files (the Python dictionary of 8e7e7cf):
# the first three natural frequencies (Hz) of each preset's beam model, and T11 at 123 Hz.
BEFORE = {
    "macro": ([36.00000002055992, 63.03100846811287, 366.0261842303918],
              190729.47900488303 + 4316.558117072079j),
    "micro": ([399.99999930304494, 1560.0830654858255, 2528.746221771197],
              318089.46334434487 + 525.7053224521666j),
    "fluid": ([167.87838033060302, 732.8434348093449, 1965.8022815892175],
              6279.352224432026 + 1.33791664977129j),
    "micro-fluid": ([404.2799335125977, 2493.741652141534, 5918.179983552106],
                    21862.992119768274 + 4.077569677425592j),
}
FIDELITY_BEFORE = """\
| preset | quantity | computed | thesis |
|---|---|---|---|
| macro | bimorph free length (fitted) | 39.60 mm | not given; range allowed 23–46 mm |
| macro | whisker free length (fitted) | 54.85 mm | not given; range allowed 50–61 mm |
| macro | 1st resonance (fit target) | 53.50 Hz (+0.00 %) | ≈53.5 Hz |
| macro | 1st resonance with the clamp (fit target) | 36.00 Hz (+0.00 %) | ≈36 Hz |
| micro | bimorph free length (fitted) | 23.89 mm | not given; range allowed 16–32 mm |
| micro | 1st resonance (fit target) | 400.00 Hz (-0.00 %) | ≈400 Hz |
| micro | static tip displacement per volt | 1.331 µm/V | 1.20 µm/V |
| fluid | bimorph free length (fitted) | 31.99 mm | not given; range allowed 23–46 mm |
| fluid | 1st resonance with the sphere (fit target) | 100.00 Hz (-0.00 %) | ≈100 Hz |
| fluid | 2nd resonance with the sphere | 519.3 Hz | ≈500 Hz |
| fluid | resonance in water, 25 °C | 93.31 Hz | ≈96 Hz |
| micro-fluid | bimorph free length (fitted) | 23.53 mm | not given; range allowed 16–32 mm |
| micro-fluid | 1st resonance with the sphere (fit target) | 400.00 Hz (+0.00 %) | ≈400 Hz |"""


def test_the_shipped_thesis_devices_build_todays_beams():
    """Each shipped beam file builds the beam the preset dictionary built (the files hold the
    fitted lengths' reprs): natural frequencies to 5e-8 relative, T to 1e-11. On the machine
    that printed BEFORE they agreed to the last bit and to 4e-16 (since 12eb545 solved the
    free and contact forms by LU instead of an inverse); another CPU's OpenBLAS kernels move
    the generalised eigensolver's lowest frequency by up to 8.6e-9 and T by 6e-13 (measured
    27 Nov), while a changed digit in a file moves them by far more."""
    for name, (freqs, t11) in BEFORE.items():
        tr = build(name)
        np.testing.assert_allclose([float(f) for f in tr.natural_frequencies(3)], freqs,
                                   rtol=5e-8, atol=0, err_msg=name)
        got = complex(tr.transduction_matrix(np.array([2 * np.pi * 123.0]))[0, 0, 0])
        assert abs(got / t11 - 1) < 1e-11, (name, got, t11)


def test_the_fidelity_table_is_unchanged():
    assert format_fidelity(fidelity_table()) == FIDELITY_BEFORE


def test_the_lumped_devices_hold_the_numbers_their_derivation_gives():
    """fluid-lumped and macro-lumped (wtml/physics/presets.py derives each number): the file's
    values equal the derivation's, so the fluid slice is unchanged."""
    fluid = load_device("fluid-lumped")
    assert fluid.c0 == MACRO_C0 and fluid.phi == 1.5e-4 and fluid.q == 50.0
    assert fluid.m == FLUID_TOTAL_MASS - FLUID_SPHERE_MASS
    assert fluid.f0 == 100.0 * np.sqrt(FLUID_TOTAL_MASS / (FLUID_TOTAL_MASS - FLUID_SPHERE_MASS))
    macro = load_device("macro-lumped")
    assert (macro.c0, macro.phi, macro.m, macro.f0, macro.q) == (MACRO_C0, 1e-5, 2e-5, 36.0, 30.0)


def test_every_shipped_device_loads_and_says_where_it_comes_from():
    names = shipped_devices()
    assert {"macro", "micro", "fluid", "micro-fluid", "fluid-lumped", "macro-lumped"} <= set(names)
    for name in names:
        device = load_device(name)
        assert device.name == name and device.provenance.source
        assert isinstance(device, BeamDevice if device.kind == "beam" else LumpedDevice)


@pytest.mark.parametrize(("edit", "needle"), [
    (("whisker:\n  section: square", "whisker:\n  section: hex"),
     "whisker.section: must be one of ['round', 'square'], got 'hex'"),
    (("  size: 5.0e-05", "  size: -5.0e-05"), "whisker.size: must be in [1e-07, 0.01], got -5e-05"),
    (("  free_length: 0.02388610904660932", "  free_length: 0.05"),
     "bimorph.free_length: 0.05 m is longer than the bimorph, length 0.032 m"),
    (("losses:\n", "losses:\n  loss_fator: 0.1\n"), "losses.loss_fator: unknown key"),
    (("kind: beam", "kind: shell"), "kind: must be one of ['beam', 'lumped'], got 'shell'"),
    (("name: micro", "name: ../micro"), "name: must be 1-64 letters, digits"),
    (("  d31: -2.74e-10", "  d31: 0"), "piezo.d31: must not be 0"),
    (("{name: bimorph.free_length, low: 0.016", "{name: bimorph.free_length, low: 0.025"),
     "provenance.free[0]: bimorph.free_length = 0.0238861 m is outside its fitted range"),
])
def test_a_bad_device_file_is_one_line_naming_the_key(tmp_path, edit, needle):
    text = (DEVICES_DIR / "micro.yaml").read_text()
    assert edit[0] in text
    path = tmp_path / "mine.yaml"
    path.write_text(text.replace(edit[0], edit[1], 1))
    with pytest.raises(SchemaError) as err:
        load_device(path)
    line = str(err.value)
    assert line.startswith(f"{path}: ") and needle in line and "\n" not in line, line


def test_a_device_is_named_by_its_contents_not_its_spelling(tmp_path):
    micro = load_device("micro")
    text = (DEVICES_DIR / "micro.yaml").read_text()
    same = tmp_path / "same.yaml"
    same.write_text("# mine\n" + text.replace("width: 0.0005", "width: 5.0e-4"))
    assert device_hash(load_device(same)) == device_hash(micro)
    other = tmp_path / "other.yaml"
    other.write_text(text.replace("width: 0.0005", "width: 0.00051"))
    assert device_hash(load_device(other)) != device_hash(micro)


def test_scenes_take_a_device_by_name_or_path_and_still_read_preset(tmp_path):
    """`device: micro`, `device: <path to a copy>` and the old `preset: micro` give the same
    scene (and hash); the old `device:` block of spread half-widths is read as `spread:`; a
    lumped device where a beam is needed, or an unknown name, is one line naming the key."""
    base = {"task": "radial", "samples": 8, "shards": 1}
    by_name = scene_from_dict(base | {"device": "micro"})
    copy = tmp_path / "micro_copy.yaml"
    copy.write_text((DEVICES_DIR / "micro.yaml").read_text())
    by_path = scene_from_dict(base | {"device": str(copy)})
    legacy = scene_from_dict(base | {"preset": "micro", "device": {"modulus": 0.01}})
    new = scene_from_dict(base | {"device": "micro", "spread": {"modulus": 0.01}})
    assert config_hash(by_name) == config_hash(by_path) == config_hash(scene_from_dict(base))
    assert legacy == new and new.spread.modulus == 0.01
    # a scene stored in a manifest holds the device itself: rebuilt without the file
    assert scene_from_dict(json.loads(json.dumps(to_dict(by_path)))) == by_path
    longer = tmp_path / "longer.yaml"
    longer.write_text((DEVICES_DIR / "micro.yaml").read_text().replace(
        "  length: 0.005 ", "  length: 0.006 "))
    off = scene_from_dict(base | {"device": str(longer)})
    assert off.whisker_length_m() == 0.006 and config_hash(off) != config_hash(by_name)
    with pytest.raises(SchemaError, match=r"^device: this scene needs a beam device; "
                                          r"'fluid-lumped' is a lumped one"):
        scene_from_dict(base | {"device": "fluid-lumped"})
    with pytest.raises(SchemaError, match=r"^device: unknown device 'nano': not a shipped"):
        scene_from_dict(base | {"device": "nano"})
    with pytest.raises(SchemaError, match=r"^device: .*missing.yaml: no such device file"):
        scene_from_dict(base | {"device": str(tmp_path / "missing.yaml")})


def test_the_shipped_scenes_name_their_devices():
    for scene_file, device in (("radial", "micro"), ("onset", "micro"), ("texture", "macro")):
        assert load_scene(DEVICES_DIR.parent / f"scenes/{scene_file}.yaml").device.name == device
    fluid = load_scene(DEVICES_DIR.parent / "scenes/fluid.yaml")
    assert fluid.transducer.device.name == "fluid-lumped"


def test_the_dataset_manifest_carries_the_device(tmp_path):
    scene = dataclasses.replace(scene_from_dict({"task": "radial", "samples": 8, "shards": 1}))
    generate(scene, tmp_path / "data", progress=False)
    manifest = read_manifest(tmp_path / "data")
    assert manifest["device"] == {"name": "micro", "sha256": device_hash(load_device("micro"))}
    raw = json.loads((tmp_path / "data/manifest.json").read_text())
    raw["device"]["sha256"] = "0" * 64
    (tmp_path / "data/manifest.json").write_text(json.dumps(raw))
    with pytest.raises(ValueError, match=r"manifest.json: device: micro 000000000000… is not its "
                                         r"scene's \(micro "):
        read_manifest(tmp_path / "data")


def test_a_dataset_of_an_older_wtml_is_told_apart_from_an_edited_one(tmp_path):
    """A manifest whose scene lacks a key this version's scenes hold (spread.posterior), hashed
    as written: made by an older wtml, to generate again; hashed otherwise: edited."""
    from wtml.schema import mapping_hash

    generate(scene_from_dict({"task": "radial", "samples": 8, "shards": 1}), tmp_path / "data",
             progress=False)
    path = tmp_path / "data/manifest.json"
    raw = json.loads(path.read_text())
    del raw["scene"]["spread"]["posterior"]
    raw["scene_hash"] = mapping_hash(raw["scene"])
    for shard in raw["shards"]:  # an older wtml's shards carry its hash
        shard["scene_hash"] = raw["scene_hash"]
    path.write_text(json.dumps(raw))
    with pytest.raises(ValueError, match=r"scene: written by an older wtml .* generate it again"):
        read_manifest(tmp_path / "data")
    raw["scene_hash"] = "1" * 64
    for shard in raw["shards"]:
        shard["scene_hash"] = raw["scene_hash"]
    path.write_text(json.dumps(raw))
    with pytest.raises(ValueError, match=r"scene_hash: 111111111111… is not the hash of its "
                                         r"scene .*: the manifest was edited"):
        read_manifest(tmp_path / "data")


@pytest.mark.parametrize("name", ["micro", "macro", "fluid"])
def test_a_device_off_another_written_as_a_file_builds_the_same_beam(name, tmp_path):
    """apply_factors writes factors into a device's values (what an identified device is saved
    as): its beam is the factored one's, to rounding, and it survives a YAML round trip."""
    import yaml

    from wtml.physics.beam_presets import apply_factors, device_parameters

    rng = np.random.default_rng(3)
    factors = {p: float(rng.uniform(0.9, 1.1)) for p in device_parameters(name)}
    off = apply_factors(name, factors)
    path = tmp_path / "off.yaml"
    path.write_text(yaml.safe_dump(to_dict(off)))
    for device in (off, load_device(path)):
        a, b = build(device), build(name, factors=factors)
        np.testing.assert_allclose(a.natural_frequencies(4), b.natural_frequencies(4),
                                   rtol=1e-12)
        omega = 2 * np.pi * np.array([30.0, 420.0, 3000.0])
        np.testing.assert_allclose(a.transduction_matrix(omega), b.transduction_matrix(omega),
                                   rtol=1e-10)


def test_a_scene_file_reads_a_relative_device_path_beside_itself(tmp_path):
    """`device: mine.yaml` in a scene file is the file beside the scene (not beside the
    working directory); a shipped name stays a name."""
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub/mine.yaml").write_text((DEVICES_DIR / "micro.yaml").read_text().replace(
        "name: micro", "name: mine"))
    (tmp_path / "sub/scene.yaml").write_text("task: radial\nsamples: 8\nshards: 1\n"
                                             "device: mine.yaml\n")
    assert load_scene(tmp_path / "sub/scene.yaml").device.name == "mine"
    (tmp_path / "sub/scene.yaml").write_text("task: radial\nsamples: 8\nshards: 1\n"
                                             "device: micro\n")
    assert load_scene(tmp_path / "sub/scene.yaml").device.name == "micro"
