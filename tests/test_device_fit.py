"""`wtml device fit` (issue 23 §2) on the shipped example of one's own device
(examples/own_device): simulated measurements of a hidden device near start.yaml, fitted back;
the fitted device file; refusals in one line."""

import importlib.util
import json
import re
from pathlib import Path

import numpy as np
import pytest

from wtml.cli import main
from wtml.devices import load_device
from wtml.physics.beam_presets import build
from wtml.physics.identify import free_ze
from wtml.physics.measured import read_sweep

EXAMPLE = Path(__file__).resolve().parent.parent / "examples/own_device"
PINS = [f"--contact={mm}:{EXAMPLE}/pin_{mm}mm.csv" for mm in (1, 2, 3)]


def _example():
    spec = importlib.util.spec_from_file_location("make_measurements",
                                                  EXAMPLE / "make_measurements.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_shipped_measurements_are_what_the_script_makes(tmp_path, monkeypatch):
    """The files in examples/own_device come from make_measurements.py: the same layout and
    the same numbers to 1e-8 relative (the beam solve's rounding differs between numpy and
    LAPACK builds by ~1e-9 of Ze; the files' own noise is 1e-4): the example is reproducible
    and its truth is the script's."""
    example = _example()
    monkeypatch.setattr(example, "HERE", tmp_path)
    (tmp_path / "start.yaml").write_text((EXAMPLE / "start.yaml").read_text())
    example.main()
    number = re.compile(r"-?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?")
    for name in ("free.csv", "free.s1p", "pin_1mm.csv", "pin_2mm.csv", "pin_3mm.csv"):
        made, shipped = ((folder / name).read_text() for folder in (tmp_path, EXAMPLE))
        assert number.sub("#", made) == number.sub("#", shipped), name
        np.testing.assert_allclose(np.array(number.findall(made), float),
                                   np.array(number.findall(shipped), float), rtol=1e-8,
                                   atol=0, err_msg=name)
    for name in ("contacts.npz", "reference.npz"):
        made, shipped = (np.load(folder / name) for folder in (tmp_path, EXAMPLE))
        assert sorted(made.files) == sorted(shipped.files), name
        for key in shipped.files:
            np.testing.assert_allclose(made[key], shipped[key], rtol=1e-8, atol=0,
                                       err_msg=f"{name} {key}")


def test_the_example_is_fitted_back_and_written_as_a_device_file(tmp_path, capsys):
    """Free sweep (.s1p) and three pins at 1e-4, the seven parameters of start.yaml's
    identify block free: each comes back within 3 standard errors of the hidden truth (the
    whisker's own loss factor too: 0.035 against the rest's 0.024), the reduced χ² near 1. The
    written file reads back to a device whose free Ze is the fit's."""
    example = _example()
    truth = example.TRUTH | {"whisker.loss_factor": example.WHISKER_LOSS
                             / (0.02 * example.TRUTH["loss_factor"])}
    out = tmp_path / "fitted.yaml"
    assert main(["device", "fit", "--device", str(EXAMPLE / "start.yaml"), "--sweep",
                 str(EXAMPLE / "free.s1p"), *PINS, "--sigma", "1e-4", "--out", str(out),
                 "--plot", str(tmp_path / "bode.png"), "--report",
                 str(tmp_path / "report.json")]) == 0
    printed = capsys.readouterr().out
    assert "| resonance | 337." in printed and "reduced chi2" in printed
    report = json.loads((tmp_path / "report.json").read_text())
    params = report["parameters"]
    assert sorted(params) == sorted(truth)
    for name, p in params.items():
        assert abs(p["factor"] - truth[name]) < 3 * p["standard_error"], (name, p)
    assert 0.7 < report["reduced_chi2"] < 1.3
    assert (tmp_path / "bode.png").stat().st_size > 10_000
    fitted = load_device(out)
    assert fitted.name == "my-wt-fitted" and "wtml device fit of my-wt" in \
        fitted.provenance.source
    f = read_sweep(EXAMPLE / "free.csv").frequency_hz
    start = load_device(EXAMPLE / "start.yaml")
    factors = {k: params[k]["factor"] for k in params}
    np.testing.assert_allclose(free_ze(build(fitted), 2 * np.pi * f),
                               free_ze(build(start, factors=factors), 2 * np.pi * f),
                               rtol=1e-9)


def test_the_calibration_loads_enter_the_fit(tmp_path, capsys):
    """`--loads` (wtml calibrate's file: Ze under tip loads of known Zm at five tones) is
    fitted beside the free sweep, start.yaml's seven parameters free: the loads shrink the
    standard errors (measured: whisker.modulus 1.9e-4 to 9.1e-5, coupling 1.0e-5 to 8e-6),
    and the truth stays within 3 of them."""
    example = _example()
    reports = {}
    for tag, extra in (("sweep", []), ("loads", ["--loads", str(EXAMPLE / "loads.csv")])):
        assert main(["device", "fit", "--device", str(EXAMPLE / "start.yaml"), "--sweep",
                     str(EXAMPLE / "free.s1p"), "--sigma", "1e-4", *extra, "--out",
                     str(tmp_path / f"{tag}.yaml"), "--report",
                     str(tmp_path / f"{tag}.json")]) == 0
        reports[tag] = json.loads((tmp_path / f"{tag}.json").read_text())
    assert "load 7 " in capsys.readouterr().out
    se = {k: {n: p["standard_error"] for n, p in r["parameters"].items()}
          for k, r in reports.items()}
    assert se["loads"]["whisker.modulus"] < 0.7 * se["sweep"]["whisker.modulus"]
    assert se["loads"]["coupling"] < 0.9 * se["sweep"]["coupling"]
    for name in ("coupling", "bimorph.length", "whisker.length", "whisker.modulus"):
        p = reports["loads"]["parameters"][name]
        assert abs(p["factor"] - example.TRUTH[name]) < 3 * p["standard_error"], name


@pytest.mark.parametrize(("extra", "needle"), [
    (["--free", "whisker.length=0.9:1.1", "--free", "whisker.modulus=0.8:1.2",
      "--free", "whisker.thickness=0.8:1.2", "--free", "bimorph.length=0.85:1.15"],
     "whisker.modulus: standard error"),
    (["--free", "sphere.radius=0.9:1.1"], "'sphere.radius' is not a parameter of device"),
    (["--free", "coupling=1.1:1.3"], "coupling: the range must be 0 < low < 1 < high"),
    (["--free", "coupling"], "--free 'coupling': write NAME=LOW:HIGH"),
    (["--contact", "x:pin.csv"], "--contact 'x:pin.csv': write DISTANCE_MM:FILE"),
])
def test_a_request_it_cannot_answer_is_one_line(tmp_path, capsys, extra, needle):
    """Refusals name what is wrong: a parameter the free sweep cannot pin (the whisker's
    modulus and thickness trade against each other without contacts), an unknown parameter, a
    range without factor 1 inside, a malformed option."""
    argv = ["device", "fit", "--device", str(EXAMPLE / "start.yaml"), "--sweep",
            str(EXAMPLE / "free.csv"), "--sigma", "1e-4", "--out", str(tmp_path / "x.yaml"),
            *extra]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and needle in err, err
    assert not (tmp_path / "x.yaml").exists()


def test_the_identify_block_is_validated_like_the_rest(tmp_path):
    text = (EXAMPLE / "start.yaml").read_text().replace(
        "{parameter: coupling, low: 0.7, high: 1.3}", "{parameter: coupling, low: 1.1, high: 1.3}")
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError, match=r"identify.free\[1\]: the range must hold factor 1"):
        load_device(path)


def test_from_a_measured_sweep_to_an_exported_decoder_for_that_device(tmp_path, capsys,
                                                                        monkeypatch):
    """The README's four commands, smaller: fit the device, generate the radial scene on it
    (its `device: fitted.yaml` read beside the scene file), train, export; then predict the
    hidden device's contacts with --device: answered in domain, near the truth; an export for
    the start device is refused for it."""
    from wtml.training import cli_main

    work = tmp_path / "own"
    work.mkdir()
    scene = (EXAMPLE / "radial.yaml").read_text().replace("samples: 60000", "samples: 24000")
    (work / "radial.yaml").write_text(scene.replace("devices: 2048", "devices: 256"))
    monkeypatch.chdir(tmp_path)
    assert main(["device", "fit", "--device", str(EXAMPLE / "start.yaml"), "--sweep",
                 str(EXAMPLE / "free.csv"), *PINS, "--sigma", "1e-4",
                 "--out", str(work / "fitted.yaml")]) == 0
    assert main(["generate", "--config", str(work / "radial.yaml"), "--out", "data",
                 "--quiet"]) == 0
    cli_main(["fit", "--config", str(EXAMPLE / "train.yaml"), "--data.data_dir", "data",
              "--trainer.default_root_dir", "run", "--trainer.max_epochs", "14",
              "--model.init_args.coarse_epochs", "6", "--trainer.enable_progress_bar", "false"])
    assert main(["export", "--checkpoint", "run/checkpoints/last.ckpt", "--out", "ex"]) == 0
    capsys.readouterr()
    predict = ["predict", "--model", "ex", "--input", str(EXAMPLE / "contacts.npz"),
               "--reference", str(EXAMPLE / "reference.npz"), "--out", "rows.csv"]
    assert main([*predict, "--device", str(work / "fitted.yaml")]) == 0
    import csv

    with open("rows.csv") as fh:
        rows = list(csv.DictReader(fh))
    truth = np.load(EXAMPLE / "contacts.npz")["distance_m"]
    got = np.array([float(r["distance_decoder (m)"]) for r in rows])
    assert all(r["in_domain"] == "1" for r in rows)
    assert np.sqrt(np.mean((got - truth) ** 2)) < 5e-6  # measured 1.13 µm; the README's run 0.20
    capsys.readouterr()
    assert main([*predict, "--device", str(EXAMPLE / "start.yaml")]) == 2
    err = capsys.readouterr().err
    assert "was trained for device 'my-wt-fitted'" in err and "this is 'my-wt'" in err
