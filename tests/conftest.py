"""Shared fixtures: seeded generators, hypothesis profiles, and transducers of realistic size."""

import dataclasses
import os
import shutil
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from lightning.pytorch.callbacks import Callback

from wtml.cli import main
from wtml.data import generate
from wtml.physics import LumpedTransducer
from wtml.physics.beam_presets import build as build_preset
from wtml.physics.modal import ModalTransducer
from wtml.scenes import FluidScene, RadialScene
from wtml.schema import build
from wtml.training import cli_main

settings.register_profile("ci", max_examples=60, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow])
settings.register_profile("thorough", max_examples=1000, deadline=None)
settings.load_profile("ci")


@pytest.fixture
def rng(request):
    """A generator seeded from the test's name: reproducible, different per test."""
    return np.random.default_rng(zlib.crc32(request.node.nodeid.encode()))


MACRO = LumpedTransducer.from_resonance(c0=7.27e-9, phi=1e-5, m=2e-5, f0=36.0, q=30.0,
                                        tan_delta=0.02)
"""Macro-size bimorph: Ze ~ 1e5-1e6 Ω around 36 Hz."""

MICRO = LumpedTransducer.from_resonance(c0=5e-12, phi=2e-7, m=2e-8, f0=400.0, q=50.0,
                                        tan_delta=0.01)
"""Micro-size bimorph with a small electrode: Ze ~ 1e7-1e9 Ω over 20-800 Hz."""


@pytest.fixture(params=["macro", "micro"])
def transducer(request):
    return {"macro": MACRO, "micro": MICRO}[request.param]


def generate_and_train(tmp_path, scene_yaml: str, config_yaml: str, *extra: str):
    """Generate a shipped scene into ``tmp_path/data`` and train a shipped config on it from
    ``tmp_path`` (its runs/ land there); returns the scene."""
    from wtml.scenes import load_scene

    root = ROOT
    scene = load_scene(root / scene_yaml)
    generate(scene, tmp_path / "data", progress=False)
    cwd = os.getcwd()
    os.chdir(tmp_path)
    try:
        cli_main(["fit", "--config", str(root / config_yaml),
                  "--data.init_args.data_dir", str(tmp_path / "data"), *extra])
    finally:
        os.chdir(cwd)
    return scene


ROOT = Path(__file__).resolve().parents[1]
FLUID_SMALL = build(FluidScene, {"samples": 1200, "shards": 4})
RADIAL_SMALL = build(RadialScene, {"samples": 1600, "shards": 4})
ONSET_SMALL = {"samples": 24, "shards": 3}
"""The small onset scene's size (tests/test_onset.py, the ``onset_export`` flow)."""
TEXTURE_SMALL = {"samples": 30, "shards": 3, "specimens_per_grade": 2}
"""The small texture scene's size (tests/test_texture.py, the ``texture_export`` flow)."""
TEXTURE_SPREAD = {"length": 0.005, "thickness": 0.005, "modulus": 0.03, "loss_factor": 0.25,
                  "tan_delta": 0.25, "coupling": 0.03}
"""Issue 21's device spread of the texture flow."""


def train_args(tmp, *extra, subcommand=True):
    return ["fit"] * subcommand + ["--config", str(ROOT / "configs/fluid.yaml"),
            "--data.init_args.data_dir", str(tmp / "data"), "--trainer.max_epochs", "3",
            "--model.init_args.hidden", "[32, 32]", "--trainer.log_every_n_steps", "1", *extra]


class StopAfterEpoch(Callback):
    """Interrupt training as a kill would, after epoch ``n`` has been checkpointed."""

    def __init__(self, n: int) -> None:
        self.n = n

    def on_train_epoch_start(self, trainer, pl_module):
        if trainer.current_epoch == self.n + 1:
            raise KeyboardInterrupt


@pytest.fixture(scope="session")
def flow(tmp_path_factory):
    """Dataset, a training run from configs/fluid.yaml interrupted after 2 of 3 epochs, and
    the export of its last checkpoint."""
    tmp = tmp_path_factory.mktemp("flow")
    generate(FLUID_SMALL, tmp / "data", progress=False)
    cwd = os.getcwd()
    os.chdir(tmp)  # the config's runs/ paths land here
    try:
        cli = cli_main(train_args(tmp, subcommand=False), run=False)
        cli.trainer.callbacks.append(StopAfterEpoch(1))
        with pytest.raises(SystemExit):  # lightning shuts down gracefully, then exits
            cli.trainer.fit(cli.model, cli.datamodule)
        assert cli.trainer.interrupted
    finally:
        os.chdir(cwd)
    ckpt = tmp / "exported.ckpt"  # a copy: the resume test goes on writing last.ckpt
    shutil.copy(tmp / "runs/fluid/checkpoints/last.ckpt", ckpt)
    assert main(["export", "--checkpoint", str(ckpt), "--out", str(tmp / "export")]) == 0
    return tmp, ckpt


@pytest.fixture(scope="session")
def radial_flow(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("radial")
    generate(RADIAL_SMALL, tmp / "data", progress=False)
    invalid = build(RadialScene, {"samples": 60, "shards": 1,
                                  "contact": {"distances_um": [500.0, 1500.0, 2500.0]}})
    generate(invalid, tmp / "invalid", progress=False)
    cwd = os.getcwd()
    os.chdir(tmp)
    try:
        for name, extra in (("radial", ["--model.init_args.coarse_epochs", "1"]),
                            ("radial_thesis", [])):
            cli_main(["fit", "--config", str(ROOT / f"configs/{name}.yaml"),
                      "--data.init_args.data_dir", str(tmp / "data"),
                      "--trainer.max_epochs", "2", "--trainer.log_every_n_steps", "1"] + extra)
            assert main(["export", "--checkpoint", f"runs/{name}/checkpoints/last.ckpt",
                         "--out", f"export/{name}"]) == 0
    finally:
        os.chdir(cwd)
    return tmp


@pytest.fixture(scope="session")
def onset_export(tmp_path_factory):
    """A tiny onset flow: generate, train 3 epochs, export. Its acquisition is the shipped
    scene's (bench-top), which tests/test_onset.py's ``scene`` fixture's records also have."""
    import yaml

    root = tmp_path_factory.mktemp("onset")
    cfg = root / "scene.yaml"
    shipped = yaml.safe_load((ROOT / "configs/scenes/onset.yaml").read_text())
    cfg.write_text(yaml.safe_dump({"name": "onset", "task": "onset", **ONSET_SMALL,
                                   "acquisition": shipped["acquisition"],
                                   "wall": {"free_fraction": 0.25}}))
    data, run, model = root / "data", root / "run", root / "export"
    subprocess.run([sys.executable, "-m", "wtml.cli", "generate", "--config", str(cfg),
                    "--out", str(data)], check=True, capture_output=True, cwd=ROOT)
    subprocess.run([sys.executable, "train.py", "fit", "--config", "configs/onset.yaml",
                    "--data.init_args.data_dir", str(data), "--trainer.max_epochs", "3",
                    "--trainer.default_root_dir", str(run)], check=True, capture_output=True,
                   cwd=ROOT)
    subprocess.run([sys.executable, "-m", "wtml.cli", "export", "--checkpoint",
                    str(run / "checkpoints/last.ckpt"), "--out", str(model)], check=True,
                   capture_output=True, cwd=ROOT)
    return {"data": data, "run": run, "model": model}


@pytest.fixture(scope="session")
def texture_export(tmp_path_factory):
    """A tiny texture flow: generate, train 2 epochs, export."""
    import yaml

    root = tmp_path_factory.mktemp("texture")
    cfg = root / "scene.yaml"
    cfg.write_text(yaml.safe_dump({"name": "texture", "task": "texture", **TEXTURE_SMALL,
                                   "spread": TEXTURE_SPREAD}))
    data, run, model = root / "data", root / "run", root / "export"
    for args in (["-m", "wtml.cli", "generate", "--config", str(cfg), "--out", str(data)],
                 ["train.py", "fit", "--config", "configs/texture.yaml",
                  "--data.init_args.data_dir", str(data), "--trainer.max_epochs", "2",
                  "--trainer.default_root_dir", str(run)],
                 ["-m", "wtml.cli", "export", "--checkpoint",
                  str(run / "checkpoints/last.ckpt"), "--out", str(model)]):
        subprocess.run([sys.executable, *args], check=True, capture_output=True, cwd=ROOT)
    return {"data": data, "run": run, "model": model}


W_H = 2 * np.pi * 420.0
"""The onset probe's ω, rad/s."""


@pytest.fixture(scope="module")
def micro():
    """The micro preset's modal model without dielectric loss: the loss current is linear in E,
    added after stepping (tested in test_modal), and has nothing to do with the wall."""
    return dataclasses.replace(ModalTransducer.from_beam(build_preset("micro"), 3),
                               loss_tangent=0.0)


def whisk(fs, seconds=0.05, whisk_hz=10.0):
    """The onset drive sped up (10 Hz whisk, 9.5 V; 20 mV probe at 420 Hz): E and dE/dt."""
    t = np.arange(int(round(seconds * fs))) / fs
    wl = 2 * np.pi * whisk_hz
    return (-9.5 * np.cos(wl * t) + 0.02 * np.sin(W_H * t),
            9.5 * wl * np.sin(wl * t) + 0.02 * W_H * np.cos(W_H * t))


def pytest_terminal_summary(terminalreporter):
    """The fuzz harness's counts per file kind, when it ran (tests/test_fuzz.py)."""
    import sys

    stats = sys.modules.get("tests.fuzz.stats")
    if stats is not None and stats.STATS:
        terminalreporter.write_sep("=", "fuzz harness: outcomes per file kind")
        terminalreporter.write_line(stats.table())
