"""The device runtime alone: ``pip install wtml`` (numpy, onnxruntime, pyyaml) runs the four
tasks' exports made earlier in this session and gives the full install's rows; ``wtml
stream`` there gives the offline path's contacts; the runtime's modules import none of the
training stack even where it is installed.

One runtime venv per CI run (``runtime_python``: made once per session, or reused from
``WTML_RUNTIME_VENV``)."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ONSET_SMALL, ROOT
from tests.fuzz import bases as base_files
from wtml.bench.runtime import runtime_venv
from wtml.cli import main
from wtml.exporters.onset import calibration_file
from wtml.physics.spread import DeviceSpread
from wtml.scenes import load_scene

HEAVY = ("torch", "lightning", "numba", "sklearn", "scipy", "onnx", "aeon", "ruptures")
"""What the runtime must not import (scipy only where a record is resampled)."""


@pytest.fixture(scope="session")
def runtime_python(tmp_path_factory) -> Path:
    """The runtime venv's python (a fresh venv with ``pip install`` of this checkout)."""
    where = os.environ.get("WTML_RUNTIME_VENV") or tmp_path_factory.mktemp("runtime") / "venv"
    return runtime_venv(where)


@pytest.fixture(scope="session")
def four_tasks(flow, radial_flow, onset_export, texture_export, tmp_path_factory) -> dict:
    """Each task's export folder and ``wtml predict``'s arguments for an input of it."""
    root = tmp_path_factory.mktemp("runtime_inputs")
    fluid = base_files.fluid(flow, root / "fluid")
    radial = base_files.radial(radial_flow, root / "radial")
    tasks = {t.name: ["--model", str(t.files["export"]), "--input",
                      str(t.files["input.npz"]), t.predict_args[0],
                      str(t.files[t.predict_args[1]])]
             for t in (fluid, radial)}
    onset = dataclasses.replace(load_scene(ROOT / "configs/scenes/onset.yaml"), **ONSET_SMALL,
                                spread=DeviceSpread())
    rec = onset.simulate(2, np.random.default_rng(3))
    (root / "onset").mkdir()
    np.savez(root / "onset/rec.npz", e=rec["e"], i=rec["i"],
             sample_rate_hz=onset.acquisition.sample_rate_hz)
    calibration_file(root / "onset/cal.npz", onset, rec)
    tasks["onset"] = ["--model", str(onset_export["model"]), "--input",
                      str(root / "onset/rec.npz"), "--calibration", str(root / "onset/cal.npz")]
    texture = load_scene(ROOT / "configs/scenes/texture.yaml")
    rec = texture.simulate(2, np.random.default_rng(8))
    (root / "texture").mkdir()
    np.savez(root / "texture/rec.npz", e=rec["e"], i=rec["i"],
             sample_rate_hz=texture.acquisition.sample_rate_hz)
    np.savez(root / "texture/cal.npz", frequency_hz=texture.calibration_hz, t=rec["t"])
    tasks["texture"] = ["--model", str(texture_export["model"]), "--input",
                        str(root / "texture/rec.npz"), "--calibration",
                        str(root / "texture/cal.npz")]
    return {"root": root, "args": tasks, "onset_scene": onset}


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def _same(a: list[dict], b: list[dict], task: str) -> None:
    assert len(a) == len(b) and a, task
    for ra, rb in zip(a, b, strict=True):
        assert ra.keys() == rb.keys(), task
        for key in ra:
            try:
                x, y = float(ra[key]), float(rb[key])
            except ValueError:
                assert ra[key] == rb[key], (task, key)
                continue
            assert (np.isnan(x) and np.isnan(y)) or abs(x - y) <= 1e-6 * max(abs(y), 1e-30), \
                (task, key, x, y)


def test_the_runtime_install_gives_the_full_installs_rows(runtime_python, four_tasks, tmp_path):
    """``wtml predict`` in a venv with numpy, onnxruntime and pyyaml only (torch, lightning,
    numba, scipy, sklearn not installed) on each task's export: the full install's rows to
    1e-6."""
    venv_bin = runtime_python.parent
    found = subprocess.run([str(runtime_python), "-c", "import importlib.util as u, json; "
                            f"print(json.dumps([m for m in {list(HEAVY)!r} if u.find_spec(m)]))"],
                           capture_output=True, text=True, check=True)
    assert json.loads(found.stdout) == [], "the runtime venv holds the training stack"
    for task, args in four_tasks["args"].items():
        lean, full = tmp_path / f"{task}-lean.csv", tmp_path / f"{task}-full.csv"
        done = subprocess.run([str(venv_bin / "wtml"), "predict", *args, "--out", str(lean)],
                              capture_output=True, text=True)
        assert done.returncode == 0, (task, done.stderr[-2000:])
        assert main(["predict", *args, "--out", str(full)]) == 0
        _same(_rows(lean), _rows(full), task)


def test_the_runtime_imports_no_training_stack(four_tasks):
    """In the full install (where torch and the rest could be imported), running every
    task's ``wtml predict`` and the stream loads none of :data:`HEAVY`."""
    script = ("import sys, contextlib, io; from wtml.cli import main\n"
              f"for args in {list(four_tasks['args'].values())!r}:\n"
              "    with contextlib.redirect_stdout(io.StringIO()):\n"
              "        assert main(['predict', *args]) == 0\n"
              "import wtml.runtime.stream, wtml.runtime.recordings, wtml.runtime.instruments\n"
              f"print(sorted({{m.split('.')[0] for m in sys.modules}} & {set(HEAVY)!r}))")
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=ROOT)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip().splitlines()[-1] == "[]", done.stdout


def test_stream_gives_the_offline_contacts(runtime_python, four_tasks, tmp_path):
    """``wtml stream`` in the runtime venv, fed one record as interleaved float32 on stdin in
    reads of four probe periods: every chunk run, and the contacts of the offline rule on the
    streaming graph's frames, each printed once. (How they compare with ``wtml predict``'s,
    whose detachment level is the record's final one, is measured by ``wtml bench runtime``
    on a trained decoder; the session's export is trained for 3 epochs and may find no
    contact: tests/test_contacts.py runs the same loop on a stand-in graph with contacts.)"""
    from wtml.runtime.contacts import Timing, contacts_from
    from wtml.runtime.onset import read_onset_calibration, stream_record
    from wtml.runtime.predict import load_export
    from wtml.runtime.recordings import read_record

    model = four_tasks["args"]["onset"][1]
    scene = four_tasks["onset_scene"]
    rec = scene.simulate(1, np.random.default_rng(5))
    one = tmp_path / "one.npz"
    np.savez(one, e=rec["e"], i=rec["i"], sample_rate_hz=scene.acquisition.sample_rate_hz)
    cal = calibration_file(tmp_path / "cal.npz", scene, rec)
    _, _, stream = load_export(model, stream=True)
    x = read_record(one, stream.meta.sample_rate_hz, stream.meta.n_samples)
    frames = stream_record(stream, x[0], x[1], *read_onset_calibration(
        cal, float(stream.frequency_hz[0]), 1))
    on, off = contacts_from(frames, Timing.of(stream.meta))
    found = np.isfinite(on[0])
    pairs = np.stack([rec["e"][0], rec["i"][0]], -1).astype("<f4").tobytes()
    done = subprocess.run([str(runtime_python.parent / "wtml"), "stream", "--model", model,
                           "--calibration", str(cal), "--chunk-samples",
                           str(4 * stream.meta.chunk_samples)], input=pairs, capture_output=True)
    assert done.returncode == 0, done.stderr.decode()[-2000:]
    chunks = stream.meta.n_samples // stream.meta.chunk_samples
    assert f"wtml stream: {chunks} chunks, " in done.stderr.decode()
    lines = [dict(kv.split("=") for kv in line.split()[1:]) | {"kind": line.split()[0]}
             for line in done.stdout.decode().splitlines()]
    onsets = [float(x["t_s"]) for x in lines if x["kind"] == "onset"]
    ends = [float(x["t_s"]) for x in lines if x["kind"] == "detachment"]
    np.testing.assert_allclose(onsets, on[0, found], atol=1e-6)
    np.testing.assert_allclose(ends, off[0, found], atol=1e-6)
    assert all(float(x["latency_ms"]) >= 0 for x in lines)
    (record,) = [x for x in lines if x["kind"] == "record"]  # the record's answer, once
    for key in ("gap", "sigma", "domain_score"):  # printed to 6 and 3 digits
        np.testing.assert_allclose(float(record.get(key + "_m", record.get(key))),
                                   frames[key][0], rtol=2e-3)
    assert record["in_domain"] == str(int(frames["in_domain"][0]))


def test_instrument_formats_give_the_npz_rows(four_tasks, tmp_path):
    """The onset record as a TDMS of the I-V converter's volts (read through a profile), a
    float32 WAV and a CSV of full-precision times: ``wtml predict`` gives the ``.npz``'s rows
    (the WAV's from float32 samples, as the graphs take them)."""
    import nptdms

    args = dict(zip(four_tasks["args"]["onset"][::2], four_tasks["args"]["onset"][1::2],
                    strict=True))
    rec = np.load(args["--input"])
    rate = float(rec["sample_rate_hz"])
    e, i = rec["e"][0].astype(np.float32), rec["i"][0].astype(np.float32)
    cal = np.load(args["--calibration"])
    np.savez(tmp_path / "cal.npz", frequency_hz=cal["frequency_hz"], t=cal["t"][:1],
             hue0=cal["hue0"][:1])
    np.savez(tmp_path / "rec.npz", e=e, i=i, sample_rate_hz=rate)
    with nptdms.TdmsWriter(tmp_path / "rec.tdms") as w:
        w.write_segment([nptdms.ChannelObject("WT", name, x.astype(float),
                                              properties={"wf_increment": 1 / rate})
                         for name, x in (("drive", e), ("converter", i.astype(float) * 1e5))])
    (tmp_path / "pxi.yaml").write_text("group: WT\ne_channel: drive\ni_channel: converter\n"
                                       "i_scale: 1.0e-5\n")
    body = np.stack([e, i], -1).astype("<f4").tobytes()
    header = (b"RIFF" + (36 + len(body)).to_bytes(4, "little") + b"WAVEfmt "
              + (16).to_bytes(4, "little") + (3).to_bytes(2, "little") + (2).to_bytes(2, "little")
              + int(rate).to_bytes(4, "little") + (int(rate) * 8).to_bytes(4, "little")
              + (8).to_bytes(2, "little") + (32).to_bytes(2, "little") + b"data"
              + len(body).to_bytes(4, "little"))
    (tmp_path / "rec.wav").write_bytes(header + body)
    with open(tmp_path / "rec.csv", "w") as fh:
        fh.write("time_s,e,i\n")
        fh.writelines(f"{k / rate!r},{float(a)!r},{float(b)!r}\n"
                      for k, (a, b) in enumerate(zip(e, i, strict=True)))
    rows = {}
    for name, extra in (("rec.npz", []), ("rec.tdms", ["--profile", str(tmp_path / "pxi.yaml")]),
                        ("rec.wav", ["--i-scale", "1"]), ("rec.csv", [])):
        out = tmp_path / f"{name}.rows.csv"
        assert main(["predict", "--model", args["--model"], "--input", str(tmp_path / name),
                     "--calibration", str(tmp_path / "cal.npz"), *extra, "--out",
                     str(out)]) == 0, name
        rows[name] = _rows(out)
    for name in ("rec.tdms", "rec.wav", "rec.csv"):
        _same(rows[name], rows["rec.npz"], name)
