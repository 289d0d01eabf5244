"""The base files every case mutates a copy of, built once per session: for each task a
small dataset, a checkpoint, an export, a scene YAML, measured inputs and the device's
calibration (or the free reference).

Fluid and radial reuse the session fixtures ``flow`` and ``radial_flow`` (tests/conftest.py);
onset and texture are made here as tests/test_onset.py and tests/test_texture.py make theirs
(the same small scenes), in-process, only when a test needs them.
"""

from __future__ import annotations

import csv
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import yaml

from tests.fuzz.cases import Task, train_config
from wtml.schema import to_dict


def _inputs(folder: Path, freq: np.ndarray, ze: np.ndarray) -> None:
    np.savez(folder / "input.npz", frequency_hz=freq, ze=ze)
    with open(folder / "input.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["sample", "frequency_hz", "ze_real", "ze_imag"])
        for n, row in enumerate(ze):
            for f, z in zip(freq, row, strict=True):
                w.writerow([n, repr(float(f)), repr(float(z.real)), repr(float(z.imag))])


def fluid(flow, folder: Path) -> Task:
    from tests.conftest import FLUID_SMALL

    tmp, ckpt = flow
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.yaml").write_text(yaml.safe_dump(to_dict(FLUID_SMALL)))
    rec = FLUID_SMALL.simulate(3, np.random.default_rng(1))
    freq = FLUID_SMALL.excitation.frequency_hz
    _inputs(folder, freq, rec["ze"])
    np.savez(folder / "cal.npz", frequency_hz=freq, t=rec["t"])
    # the same Ze as the raw signals of a stepped sweep (3 V, 10 kHz, 40 ms per tone)
    rate, t = 1e4, np.arange(400) / 1e4
    phase = np.exp(2j * np.pi * freq[:, None] * t)
    np.savez(folder / "rec.npz", frequency_hz=freq, sample_rate_hz=rate,
             e=np.broadcast_to((3.0 * phase).real, (3, *phase.shape)),
             i=(3.0 * phase[None] / rec["ze"][:, :, None]).real)
    task = Task("fluid", {"scene.yaml": folder / "scene.yaml", "data": tmp / "data",
                          "last.ckpt": ckpt, "export": tmp / "export",
                          "input.npz": folder / "input.npz", "input.csv": folder / "input.csv",
                          "cal.npz": folder / "cal.npz", "rec.npz": folder / "rec.npz"},
                ("--calibration", "cal.npz"), epochs=2)
    # the training config's keys (a case folder writes its own, pointing at its copies)
    (folder / "config.yaml").write_text(yaml.safe_dump(train_config(task, folder)))
    task.files["config.yaml"] = folder / "config.yaml"
    return task


def radial(tmp: Path, folder: Path) -> Task:
    from tests.conftest import RADIAL_SMALL

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.yaml").write_text(yaml.safe_dump(to_dict(RADIAL_SMALL)))
    rec = RADIAL_SMALL.simulate(3, np.random.default_rng(1))
    freq = np.asarray(RADIAL_SMALL.excitation.frequencies_hz)
    _inputs(folder, freq, rec["ze"])
    shutil.copy(tmp / "export/radial/sample_reference.npz", folder / "ref.npz")
    return Task("radial", {"scene.yaml": folder / "scene.yaml", "data": tmp / "data",
                           "last.ckpt": tmp / "runs/radial/checkpoints/last.ckpt",
                           "export": tmp / "export/radial", "input.npz": folder / "input.npz",
                           "ref.npz": folder / "ref.npz"},
                ("--reference", "ref.npz"), epochs=2)


def _flow(folder: Path, scene_map: dict, config: str, epochs: int) -> None:
    """generate, train, export, in-process (as the tests' fixtures do in subprocesses)."""
    from tests.conftest import ROOT
    from wtml.cli import main
    from wtml.training import cli_main

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "scene.yaml").write_text(yaml.safe_dump(scene_map))
    assert main(["generate", "--config", str(folder / "scene.yaml"), "--out",
                 str(folder / "data"), "--quiet"]) == 0
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        with warnings.catch_warnings():  # the tests' fixtures run this in a subprocess
            warnings.simplefilter("ignore")
            cli_main(["fit", "--config", config, "--data.init_args.data_dir",
                      str(folder / "data"), "--trainer.max_epochs", str(epochs),
                      "--trainer.default_root_dir", str(folder / "run")])
    finally:
        os.chdir(cwd)
    assert main(["export", "--checkpoint", str(folder / "run/checkpoints/last.ckpt"), "--out",
                 str(folder / "export")]) == 0


def onset(folder: Path) -> Task:
    """The onset flow of tests/test_onset.py's ``onset_export`` (3 epochs) and two records
    of its nominal device with their calibration."""
    import dataclasses

    from tests.conftest import ROOT
    from tests.test_onset import SMALL
    from wtml.exporters.onset import calibration_file
    from wtml.physics.spread import DeviceSpread
    from wtml.scenes import load_scene

    shipped = yaml.safe_load((ROOT / "configs/scenes/onset.yaml").read_text())
    _flow(folder, {"name": "onset", "task": "onset", **SMALL,
                   "acquisition": shipped["acquisition"], "wall": {"free_fraction": 0.25}},
          "configs/onset.yaml", 3)
    scene = dataclasses.replace(load_scene(ROOT / "configs/scenes/onset.yaml"), **SMALL,
                                spread=DeviceSpread())
    rec = scene.simulate(2, np.random.default_rng(3))
    np.savez(folder / "input.npz", e=rec["e"], i=rec["i"],
             sample_rate_hz=scene.acquisition.sample_rate_hz)
    calibration_file(folder / "cal.npz", scene, rec)
    return Task("onset", {"scene.yaml": folder / "scene.yaml", "data": folder / "data",
                          "last.ckpt": folder / "run/checkpoints/last.ckpt",
                          "export": folder / "export", "input.npz": folder / "input.npz",
                          "cal.npz": folder / "cal.npz"},
                ("--calibration", "cal.npz"), epochs=3)


def texture(folder: Path) -> Task:
    """The texture flow of tests/test_texture.py's ``texture_export`` (2 epochs) and two
    records of the shipped scene with their calibrated T."""
    from tests.conftest import ROOT
    from tests.test_texture import ISSUE_SPREAD, SMALL
    from wtml.scenes import load_scene

    _flow(folder, {"name": "texture", "task": "texture", **SMALL, "spread": ISSUE_SPREAD},
          "configs/texture.yaml", 2)
    scene = load_scene(ROOT / "configs/scenes/texture.yaml")
    rec = scene.simulate(2, np.random.default_rng(8))
    np.savez(folder / "input.npz", e=rec["e"], i=rec["i"],
             sample_rate_hz=scene.acquisition.sample_rate_hz)
    np.savez(folder / "cal.npz", frequency_hz=scene.calibration_hz, t=rec["t"])
    return Task("texture", {"scene.yaml": folder / "scene.yaml", "data": folder / "data",
                            "last.ckpt": folder / "run/checkpoints/last.ckpt",
                            "export": folder / "export", "input.npz": folder / "input.npz",
                            "cal.npz": folder / "cal.npz"},
                ("--calibration", "cal.npz"), epochs=2)
