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
