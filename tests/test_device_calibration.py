"""`wtml calibrate` (issue 23 §3) on the shipped example's loads: T of the hidden device from
its own measured loads, validated on loads the fit never saw; refusals in one line."""

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

from wtml.cli import main
from wtml.device_calibration import calibrate, read_loads

EXAMPLE = Path(__file__).resolve().parent.parent / "examples/own_device"


def _truth_t(frequency_hz):
    spec = importlib.util.spec_from_file_location("make_measurements",
                                                  EXAMPLE / "make_measurements.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.truth().transduction_matrix(2 * np.pi * frequency_hz)


def test_the_calibration_finds_the_hidden_devices_t_and_measures_its_own_error(tmp_path):
    """Six loads at 1e-4: T (up to its sign, which impedances cannot see) within 1 % of the
    hidden device's, det T = 1; the two validation loads' Zm error is reported and small; the
    stored file has what `wtml predict --calibration` reads."""
    cal, summary = calibrate("micro", EXAMPLE / "loads.csv", out=tmp_path)
    f = np.asarray(summary["frequency_hz"])
    truth = _truth_t(f)
    sign = np.sign(np.real(cal.t[:, 0, 0] / truth[:, 0, 0]))[:, None, None]
    assert np.max(np.abs(sign * cal.t / truth - 1)) < 1e-2
    assert np.max(cal.det_error()) < 1e-9
    v = summary["validation_error"]
    assert 0 < v["rms"] <= v["max"] < 0.05
    with np.load(tmp_path / "micro.calibration.npz") as data:
        assert {"frequency_hz", "t"} <= set(data.files) and data["t"].shape == (5, 2, 2)
    assert json.loads((tmp_path / "micro.calibration.json").read_text())["loads"][
        "calibration"] == 6
    # the micro model is not this device: its T predicts the loads' Ze percent off
    assert summary["model_vs_calibrated_ze"] > 1e-3


@pytest.mark.parametrize(("edit", "needle"), [
    (lambda rows: rows + [rows[1]], "load 0 is given twice at 360 Hz"),
    (lambda rows: rows[:1] + rows[2:], "load 0 has no row at 360 Hz"),
    (lambda rows: [rows[0], rows[1].replace(",0,0,", ",0,1,", 1)] + rows[2:],
     "load 0 is both a calibration and a validation load"),
    (lambda rows: [rows[0]] + [r for r in rows[1:] if r.split(",")[1] in ("0", "6")],
     "1 calibration loads (validation 0); the least-squares calibration needs at least 4"),
    (lambda rows: [rows[0].replace("zm_im", "zm_imag")] + rows[1:], "the header must name"),
])
def test_a_bad_loads_file_is_one_line(tmp_path, capsys, edit, needle):
    rows = (EXAMPLE / "loads.csv").read_text().splitlines()
    path = tmp_path / "loads.csv"
    path.write_text("\n".join(edit(rows)) + "\n")
    assert main(["calibrate", "--device", "micro", "--loads", str(path), "--out",
                 str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and str(path) in err and needle in err, err


def test_the_loads_are_read_on_one_grid():
    loads = read_loads(EXAMPLE / "loads.csv")
    assert loads["zm"].shape == loads["ze"].shape == (8, 5)
    assert loads["validation"].tolist() == [False] * 6 + [True] * 2
    assert np.all(np.diff(loads["frequency_hz"]) > 0)


def _fluid_loads(path, scene, noise, rng):
    """Ze of the fluid scene's device (sphere mounted) under six calibration and two
    validation loads around the sphere's Stokes load, at 1e-4 (a user's loads file)."""
    from wtml.signals.noise import complex_noise

    f = scene.excitation.frequency_hz
    t = scene.calibrated_t()
    scale = scene.reference_zm()
    lines = ["frequency_hz,load,validation,zm_re,zm_im,ze_re,ze_im"]
    sizes = ((0.0, 0), (0.3, 0), (1.0, 0), (3.0, 0), (10.0, 0), (30.0, 0), (0.6, 1), (6.0, 1))
    for load, (size, validation) in enumerate(sizes):
        zm = size * scale * np.exp(1j * np.deg2rad(-45.0)) * np.ones(len(f))
        ze = complex_noise((t[:, 0, 0] * zm + t[:, 0, 1]) / (t[:, 1, 0] * zm + t[:, 1, 1]),
                           noise, rng)
        lines += [f"{float(a)!r},{load},{validation},{float(z.real)!r},{float(z.imag)!r},"
                  f"{float(e.real)!r},{float(e.imag)!r}" for a, z, e in zip(f, zm, ze, strict=True)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_fluid_scene_believes_its_devices_own_calibration(tmp_path):
    """`transducer.calibration:` (the .npz `wtml calibrate` wrote) is what the records' `t`
    holds, and the records still come from the device's model: the classical path's Zm error
    is then the calibration's own (measured on its validation loads), not the scene's
    nuisance model. The scene holds the calibration's values: its hash changes with them."""
    from wtml.physics.twoport import zm_from_ze
    from wtml.scenes import config_hash, load_scene
    from wtml.schema import SchemaError

    base = load_scene(Path(__file__).resolve().parent.parent / "configs/scenes/fluid.yaml")
    rng = np.random.default_rng(0)
    loads = _fluid_loads(tmp_path / "loads.csv", base, 1e-4, rng)
    cal, summary = calibrate("fluid-lumped", loads, out=tmp_path)
    text = ("task: fluid\nsamples: 400\nshards: 2\nnoise: {ze_relative: 0.0}\n"
            "nuisance: {calibration_error: 0.0}\n"
            "transducer:\n  device: fluid-lumped\n  calibration: fluid-lumped.calibration.npz\n")
    (tmp_path / "scene.yaml").write_text(text)
    scene = load_scene(tmp_path / "scene.yaml")
    np.testing.assert_allclose(scene.transducer.calibration.t_at(base.excitation.frequency_hz),
                               cal.t, rtol=1e-12)
    r = scene.simulate(400, np.random.default_rng(1))
    assert np.allclose(r["t"][0], cal.t, rtol=1e-12)
    from wtml.physics.loads import stokes_sphere

    zm = stokes_sphere(r["eta"][:, None], r["rho"][:, None], scene.sphere.radius,
                       scene.excitation.omega)
    err = np.abs(zm_from_ze(r["t"], r["ze"]) / zm - 1)
    assert 1e-6 < np.median(err) < 0.05  # the calibration's own error, no noise added
    other = tmp_path / "other.yaml"
    other.write_text(text.replace("  calibration: fluid-lumped.calibration.npz\n", ""))
    assert config_hash(load_scene(other)) != config_hash(scene)
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("calibration_error: 0.0", "calibration_error: 0.01"))
    with pytest.raises(SchemaError, match=r"nuisance.calibration_error: must be 0 with "
                                          r"transducer.calibration"):
        load_scene(bad)
    band = tmp_path / "band.yaml"
    band.write_text(text + "excitation: {f_start_hz: 80.0, f_stop_hz: 120.0, n_freq: 41}\n")
    with pytest.raises(SchemaError, match=r"transducer.calibration: the calibration covers "
                                          r"90-120 Hz"):
        load_scene(band)


def test_onset_and_texture_scenes_believe_a_stored_calibration(tmp_path, capsys):
    """`wtml calibrate --hue0` stores HUE(0) with T; an onset scene's `calibration:` (read
    beside the scene file) is then what every record's `t_probe` and `hue0` hold, and a
    texture scene's is its records' `t`, while the records come from the device's model.
    Refused in one line: a calibration error of the scene's own beside it, a spread, a probe
    outside the calibrated band, an onset calibration without HUE(0)."""
    from wtml.scenes import load_scene
    from wtml.schema import SchemaError

    assert main(["calibrate", "--device", str(EXAMPLE / "start.yaml"), "--loads",
                 str(EXAMPLE / "loads.csv"), "--out", str(tmp_path), "--hue0", "1.1e-6"]) == 0
    assert "HUE(0) stored with it: 1.1e-06 m/V" in capsys.readouterr().out
    npz = tmp_path / "my-wt.calibration.npz"
    with np.load(npz) as data:
        stored_t, f = data["t"], data["frequency_hz"]
        assert float(data["hue0"]) == 1.1e-6
    onset = ("task: onset\nsamples: 2\nshards: 1\ndevice: " + str(EXAMPLE / "start.yaml")
             + "\ncalibration: my-wt.calibration.npz\ncalibration_error: 0.0\n"
             "drive: {probe_hz: 350.0, cycles: 0.5, whisk_hz: 5.0, lead_s: 0.05}\n"
             "acquisition: {sample_rate_hz: 22400.0}\n")
    (tmp_path / "onset.yaml").write_text(onset)
    scene = load_scene(tmp_path / "onset.yaml")
    r = scene.simulate(2, np.random.default_rng(0))
    want = np.stack([np.interp(350.0, f, stored_t[:, i // 2, i % 2].real)
                     + 1j * np.interp(350.0, f, stored_t[:, i // 2, i % 2].imag)
                     for i in range(4)]).reshape(2, 2)
    np.testing.assert_allclose(r["t_probe"], np.broadcast_to(want, (2, 2, 2)), rtol=1e-12)
    assert np.all(r["hue0"] == 1.1e-6)
    # the model's own calibration differs: the records believe the stored one
    model = scene.transducer()
    model_t = model.transduction_matrix(np.array([2 * np.pi * 350.0]))[0]
    model_hue0 = model.static_tip_displacement_per_volt()
    assert np.max(np.abs(model_t / want - 1)) > 1e-3 and abs(model_hue0 / 1.1e-6 - 1) > 1e-3
    for edit, needle in (
            (("calibration_error: 0.0", "calibration_error: 0.01"),
             "calibration_error: must be 0 with calibration"),
            (("calibration_error: 0.0\n", "calibration_error: 0.0\nspread: {coupling: 0.01}\n"),
             "spread: must be none with calibration"),
            (("probe_hz: 350.0", "probe_hz: 420.0"), "calibration: the calibration covers "
                                                     "320-400 Hz")):
        (tmp_path / "bad.yaml").write_text(onset.replace(*edit))
        with pytest.raises(SchemaError, match=needle):
            load_scene(tmp_path / "bad.yaml")
    np.savez(tmp_path / "nohue.npz", frequency_hz=f, t=stored_t)
    (tmp_path / "bad.yaml").write_text(onset.replace("my-wt.calibration.npz", "nohue.npz"))
    with pytest.raises(SchemaError, match=r"calibration: .*nohue.npz .* holds no HUE\(0\)"):
        load_scene(tmp_path / "bad.yaml")

    texture = load_scene(Path(__file__).resolve().parent.parent / "configs/scenes/texture.yaml")
    hz = texture.calibration_hz
    t_tex = texture.transducer().transduction_matrix(2 * np.pi * hz) * (1 + 0.01j)
    np.savez(tmp_path / "macro.npz", frequency_hz=hz, t=t_tex)
    (tmp_path / "texture.yaml").write_text(
        "task: texture\nsamples: 5\nshards: 1\nspecimens_per_grade: 1\ncalibration: macro.npz\n"
        "calibration_error: 0.0\ndrive: {record_s: 0.05, lead_s: 0.1}\n")
    scene = load_scene(tmp_path / "texture.yaml")
    r = scene.simulate(5, np.random.default_rng(0))
    np.testing.assert_allclose(r["t"], np.broadcast_to(t_tex, r["t"].shape), rtol=1e-12)
