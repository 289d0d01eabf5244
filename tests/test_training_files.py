"""``python train.py fit``'s inputs (issue 22): every bad value, config file and checkpoint
ends in exit code 2 with one line naming the key (and the file it came from); a loss that
stops being finite stops the run and keeps the last good checkpoint; and a run killed and
resumed ends with the same weights, bit for bit on CPU, as the run never killed."""

import os
import re
import shutil
import subprocess
import sys

import lightning as L
import pytest
import torch
from conftest import ROOT, StopAfterEpoch

from wtml.data import generate
from wtml.decoders.base import DivergedError
from wtml.scenes import FluidScene, RadialScene, TextureScene
from wtml.schema import build
from wtml.training import cli_main

FLUID = str(ROOT / "configs/fluid.yaml")
TEXTURE_SMALL = {"samples": 24, "shards": 3, "specimens_per_grade": 2,
                 "drive": {"record_s": 0.1, "lead_s": 0.2}}
"""24 records of 0.1 s (8 training records): 3 s to generate."""
TEXTURE_ARGS = ["--model.init_args.window_s", "0.05", "--data.init_args.batch_size", "4"]
"""Random 0.05 s crops of the 0.1 s records (texture's own randomness), 2 batches an epoch."""


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Tiny datasets of three tasks."""
    tmp = tmp_path_factory.mktemp("training_files")
    generate(build(FluidScene, {"samples": 300, "shards": 3}), tmp / "fluid", progress=False)
    generate(build(FluidScene, {"samples": 240, "shards": 3}), tmp / "fluid_other",
             progress=False)
    generate(build(RadialScene, {"samples": 60, "shards": 3}), tmp / "radial", progress=False)
    generate(build(TextureScene, TEXTURE_SMALL), tmp / "texture", progress=False)
    return tmp


def fluid_args(data, root, *extra, epochs=3):
    return ["fit", "--config", FLUID, "--data.init_args.data_dir", str(data / "fluid"),
            "--trainer.max_epochs", str(epochs), "--model.init_args.hidden", "[16, 16]",
            "--trainer.log_every_n_steps", "1", "--trainer.default_root_dir", str(root), *extra]


def texture_args(data, root, *extra, epochs=3):
    return ["fit", "--config", str(ROOT / "configs/texture.yaml"), "--data.init_args.data_dir",
            str(data / "texture"), "--trainer.max_epochs", str(epochs),
            "--trainer.log_every_n_steps", "1", "--trainer.default_root_dir", str(root),
            *TEXTURE_ARGS, *extra]


def radial_args(data, root, *extra, epochs=3):
    """The two-stage radial decoder, its coarse stage alone in epoch 1, the refiner after."""
    return ["fit", "--config", str(ROOT / "configs/radial.yaml"), "--data.init_args.data_dir",
            str(data / "radial"), "--trainer.max_epochs", str(epochs),
            "--model.init_args.hidden", "[16]", "--model.init_args.refine_hidden", "[16]",
            "--model.init_args.coarse_epochs", "1", "--data.init_args.batch_size", "8",
            "--trainer.log_every_n_steps", "1", "--trainer.default_root_dir", str(root), *extra]


def refusal(argv, capsys) -> str:
    """The one line ``cli_main(argv)`` ends with (exit code 2)."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as exit_:
        cli_main(argv)
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("train.py: error: ")
    return err[0].removeprefix("train.py: error: ")


def interrupted(argv, after: int) -> None:
    """Train ``argv`` and stop it as a kill would once epoch ``after`` (0-based) is saved."""
    cli = cli_main(argv[1:], run=False)
    cli.trainer.callbacks.append(StopAfterEpoch(after))
    with pytest.raises(SystemExit):  # lightning shuts down gracefully, then exits
        cli.trainer.fit(cli.model, cli.datamodule)
    assert cli.trainer.interrupted


def weights(path) -> dict:
    return torch.load(path, map_location="cpu", weights_only=True)["state_dict"]


# ---------------------------------------------------------------- 1. values and config files


@pytest.mark.parametrize(("extra", "line"), [
    (["--trainer.max_epochs", "abc"], "trainer.max_epochs: expected int or null, got 'abc'"),
    (["--trainer.max_epochs"], "trainer.max_epochs: expected one argument"),
    (["--model.init_args.bogus", "3"],
     "model.init_args.bogus: not an argument of wtml.decoders.fluid.FluidDecoder"),
    (["--model.class_path", "wtml.nope.X"], "model.class_path: cannot use 'wtml.nope.X'"),
    (["--model.init_args.hidden", "abc"],
     "model.init_args.hidden: expected list[int] or null, got 'abc'"),
    (["--model.init_args.lr", "abc"], "model.init_args.lr: expected float, got 'abc'"),
    (["--data.init_args.batch_size", "1.5"],
     "data.init_args.batch_size: expected int, got '1.5'"),
    (["--seed_everything", "x"], "seed_everything: expected bool or int, got 'x'"),
    (["--trainer.callbacks", "foo.Bar"], "trainer.callbacks.class_path: cannot use 'foo.Bar'"),
    (["--bogus", "1"], "--bogus: not an option of train.py fit"),
    (["--trainer.accelerator", "bogus"], "trainer.accelerator: "),
    (["--trainer.devices", "abc"], "trainer.devices: "),
    (["--trainer.limit_train_batches", "-1"], "trainer.limit_train_batches: "),
    (["--data.init_args.data_dir"], "data.init_args.data_dir: expected one argument"),
    (["--model.init_args.hidden", "[65536, 65536]"], "model.hidden [65536, 65536] makes "
                                                       "4.29e+09 weights"),
])
def test_a_bad_value_is_one_line_naming_its_key(data, tmp_path, capsys, extra, line):
    got = refusal(fluid_args(data, tmp_path / "run", *extra), capsys)
    assert got.startswith(line), got
    assert not (tmp_path / "run").exists()  # refused before Lightning started


def test_config_files_are_checked_and_named(data, tmp_path, capsys):
    def config(name: str, text: str | bytes) -> str:
        path = tmp_path / name
        path.write_bytes(text if isinstance(text, bytes) else text.encode())
        return str(path)

    cases = {
        config("broken.yaml", "model: [1\n"): "broken.yaml: not YAML (",
        config("list.yaml", "- 1\n- 2\n"): "list.yaml: a training config is a YAML mapping",
        config("passwd", "root:x:0:0:root:/root:/bin/bash\n"):
            "passwd: a training config is a YAML mapping",
        config("binary.yaml", bytes(range(256)) * 4): "binary.yaml: not a text file",
        config("unknown.yaml", "trainer:\n  nope: 1\n"):
            "unknown.yaml: trainer.nope: not an option of train.py fit",
        config("typed.yaml", "model:\n  init_args:\n    hidden: abc\n"):
            "typed.yaml: model.init_args.hidden: expected list[int] or null, got 'abc'",
        str(tmp_path / "missing.yaml"): "missing.yaml: no such training config",
        str(tmp_path): "is a folder, not a training config",
    }
    for path, line in cases.items():
        got = refusal(fluid_args(data, tmp_path / "run", "--config", path), capsys)
        assert line in got and got.startswith(str(tmp_path)), (path, got)
    # a value given on the command line names no file
    got = refusal(fluid_args(data, tmp_path / "run", "--model.init_args.hidden", "abc"), capsys)
    assert got.startswith("model.init_args.hidden: ")


def test_train_py_prints_one_line_not_a_usage_dump(data, tmp_path):
    """The real entry point (jsonargparse printed 59 lines of usage for this)."""
    run = subprocess.run([sys.executable, str(ROOT / "train.py"),
                          *fluid_args(data, tmp_path / "run", "--trainer.max_epochs", "abc")],
                         capture_output=True, text=True, cwd=tmp_path)
    assert run.returncode == 2 and run.stderr.strip().splitlines() == [
        "train.py: error: trainer.max_epochs: expected int or null, got 'abc'"]


def test_a_model_config_of_another_task_is_refused(data, tmp_path, capsys):
    got = refusal(fluid_args(data, tmp_path / "run", "--data.init_args.data_dir",
                             str(data / "radial")), capsys)
    assert got.startswith("model.class_path: wtml.decoders.fluid.FluidDecoder decodes the "
                          "fluid task") and "holds a radial dataset" in got
    assert not (tmp_path / "run").exists()


@pytest.mark.skipif(torch.cuda.is_available() or torch.backends.mps.is_available(),
                    reason="this machine has a GPU")
def test_a_gpu_this_machine_lacks_is_one_line(data, tmp_path, capsys):
    for name in ("gpu", "cuda", "mps"):
        got = refusal(fluid_args(data, tmp_path / "run", "--trainer.accelerator", name), capsys)
        assert got.startswith(f"trainer.accelerator: '{name}' asks for a GPU")


def test_a_texture_window_too_short_is_refused_before_it_costs(data, tmp_path, capsys):
    """``window_s: 1e-5`` passed the old range check, then cut each training record into
    windows of one sample for the domain gate (16 M of them on the shipped scene) and ran out
    of memory. The window must hold a period of the scene's slowest whisk (35 Hz: 1463 samples
    at 51.2 kS/s, 0.02857 s)."""
    got = refusal(texture_args(data, tmp_path / "run", "--model.init_args.window_s", "1e-5"),
                  capsys)
    assert got.startswith("model.window_s must be in [0.02857, 0.1] s for this scene"), got
    got = refusal(texture_args(data, tmp_path / "run", "--model.init_args.window_s", "0.2"),
                  capsys)
    assert got.startswith("model.window_s must be in [0.02857, 0.1] s"), got


# ---------------------------------------------------------------- 2. checkpoints to resume


@pytest.fixture(scope="module")
def runs(data, tmp_path_factory):
    """A fluid run stopped after its first of 3 epochs, a finished one, a texture one."""
    tmp = tmp_path_factory.mktemp("runs")
    interrupted(fluid_args(data, tmp / "stopped"), after=0)
    cli_main(fluid_args(data, tmp / "finished"))
    cli_main(texture_args(data, tmp / "texture", epochs=2))
    return tmp


def test_a_bad_checkpoint_to_resume_is_one_line(data, runs, tmp_path, capsys):
    good = runs / "stopped/checkpoints/last.ckpt"
    state = torch.load(good, map_location="cpu", weights_only=True)
    blob = good.read_bytes()

    def saved(name: str, content) -> str:
        path = tmp_path / name
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            torch.save(content, path)
        return str(path)

    nan = {**state, "state_dict": {**state["state_dict"]}}
    first = next(iter(nan["state_dict"]))
    nan["state_dict"][first] = torch.full_like(nan["state_dict"][first], float("nan"))
    cases = {
        str(tmp_path / "missing.ckpt"): "no such checkpoint file",
        saved("empty.ckpt", b""): "empty file",
        saved("truncated.ckpt", blob[:len(blob) // 2]): "not a readable checkpoint",
        saved("crafted.ckpt", b"\x80\x04cos\nsystem\n(S'true'\ntR."): "not a readable",
        saved("plain.ckpt", {"state_dict": {}}): "not a wtml checkpoint",
        saved("weights.ckpt", {k: v for k, v in state.items() if k != "optimizer_states"}):
            "optimizer_states: missing",
        saved("loops.ckpt", {**state, "loops": []}): "loops: must be a mapping, got list",
        saved("optimizer.ckpt", {**state, "optimizer_states": [{}]}):
            "its trainer state cannot be restored",
        saved("hparams.ckpt", {**state, "hyper_parameters": {"hidden": "wide"}}):
            "hyper_parameters: model.init_args.hidden: expected list[int]",
        saved("nan.ckpt", nan): f"state_dict.{first}: holds NaN or infinite values",
        saved("scene.ckpt", {**state, "wtml": {**state["wtml"], "scene": {
            **state["wtml"]["scene"], "samples": -5}}}): "wtml.scene.samples: must be",
        saved("epochs.ckpt", {**state, "wtml": {**state["wtml"], "max_epochs": "3"}}):
            "wtml.max_epochs: must be a number",
        str(runs / "texture/checkpoints/last.ckpt"): "a checkpoint of the 'texture' task, "
                                                     "not 'fluid'",
        str(runs / "finished/checkpoints/last.ckpt"): "a finished run (epoch 3 of 3)",
    }
    for path, line in cases.items():
        got = refusal(fluid_args(data, tmp_path / "run", "--ckpt_path", path), capsys)
        assert got.startswith(path) and line in got, (path, got)
    # the run it resumes is the one asked for: its length, its dataset
    got = refusal(fluid_args(data, tmp_path / "run", "--ckpt_path", str(good), epochs=5), capsys)
    assert got == (f"{good}: trainer.max_epochs: 5 here, 3 in the run it resumes (its "
                   "learning-rate schedule is laid out over that); resume with "
                   "--trainer.max_epochs 3")
    got = refusal(fluid_args(data, tmp_path / "run", "--ckpt_path", str(good),
                             "--data.init_args.data_dir", str(data / "fluid_other")), capsys)
    assert got.startswith(f"{good}: trained on another scene than data.init_args.data_dir")
    assert good.read_bytes() == blob


# ---------------------------------------------------------------- 3. a loss that diverges


def test_a_diverging_loss_stops_the_run_in_one_line(data, tmp_path, capsys):
    """A learning rate near the top of its range (9.9) blows texture's net up in its first
    epoch (its training or its validation loss turns NaN or infinite, depending on the
    features). The run stops there in one line, and no checkpoint of its weights is
    written."""
    got = refusal(texture_args(data, tmp_path / "run", "--model.init_args.lr", "9.9"), capsys)
    assert re.fullmatch(r"epoch 1, step \d+: the (training|validation) loss is (nan|inf); the "
                        r"run stopped and no checkpoint was written[^\n]*", got), got
    assert not (tmp_path / "run/checkpoints/last.ckpt").exists()


class Poison(L.Callback):
    """Makes the weights diverge (NaN) when epoch ``n`` (0-based) starts."""

    def __init__(self, n: int) -> None:
        self.n = n

    def on_train_epoch_start(self, trainer, module):
        if trainer.current_epoch == self.n:
            with torch.no_grad():
                next(module.net.parameters()).fill_(float("nan"))


def test_a_diverged_run_keeps_its_last_good_checkpoint(data, tmp_path):
    root = tmp_path / "run"
    cli = cli_main(fluid_args(data, root)[1:], run=False)
    cli.trainer.callbacks.append(Poison(2))
    ckpt = root / "checkpoints/last.ckpt"
    before = {}

    class Keep(L.Callback):
        def on_train_epoch_start(self, trainer, module):
            if trainer.current_epoch == 2:
                before["bytes"] = ckpt.read_bytes()

    cli.trainer.callbacks.insert(0, Keep())
    with pytest.raises(DivergedError, match=r"^epoch 3, step \d+: the training loss is nan; the "
                       rf"run stopped and {ckpt} \(after epoch 2\) is kept as it was"):
        cli.trainer.fit(cli.model, cli.datamodule)
    assert ckpt.read_bytes() == before["bytes"]
    assert all(torch.isfinite(w).all() for w in weights(ckpt).values())


# ---------------------------------------------------------------- 4. exact resume


@pytest.mark.parametrize("task", ["fluid", "radial", "texture"])
def test_a_killed_and_resumed_run_ends_with_the_same_weights(data, tmp_path, task):
    """Fluid (shuffled batches), radial's two stages (stopped where the coarse stage hands
    over to the refiner) and texture (shuffled batches and random crops of each record): 3
    epochs straight, against stopped after the first and resumed with --ckpt_path, in the same
    process (so nothing is reset between them but what resuming restores). Every state-dict
    tensor is equal, bit for bit. Before the data order and random state were drawn per
    (seed, epoch), the fluid weights differed by up to 1.2e-3 (1200 samples, [32, 32])."""
    args = {"fluid": fluid_args, "radial": radial_args, "texture": texture_args}[task]
    cli_main(args(data, tmp_path / "straight"))
    interrupted(args(data, tmp_path / "killed"), after=0)
    last = tmp_path / "killed/checkpoints/last.ckpt"
    assert torch.load(last, weights_only=True)["epoch"] == 0
    cwd = os.getcwd()
    cli_main(args(data, tmp_path / "killed", "--ckpt_path", str(last)))
    assert os.getcwd() == cwd
    a, b = weights(tmp_path / "straight/checkpoints/last.ckpt"), weights(last)
    assert a.keys() == b.keys()
    for name in a:
        assert torch.equal(a[name], b[name]), name


def test_the_seed_of_a_resumed_run_is_its_checkpoints(data, runs, tmp_path):
    """Resumed with another --seed_everything, the run goes on drawing from the seed it was
    started with, and ends as the run never stopped (``runs``' finished one, seed 0)."""
    stopped = tmp_path / "stopped.ckpt"
    shutil.copy(runs / "stopped/checkpoints/last.ckpt", stopped)
    assert torch.load(stopped, weights_only=True)["wtml"]["seed"] == 0
    cli_main(fluid_args(data, tmp_path / "resumed", "--ckpt_path", str(stopped),
                        "--seed_everything", "7"))
    a = weights(runs / "finished/checkpoints/last.ckpt")
    b = weights(tmp_path / "resumed/checkpoints/last.ckpt")
    assert all(torch.equal(a[name], b[name]) for name in a)
