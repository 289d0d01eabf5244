"""Training under Lightning's DDP from the shipped config (issue 25 §6): two CPU processes
(gloo) share an epoch, and the checkpoint the first one writes exports and predicts as its
torch net does."""

import csv
import subprocess
import sys

import numpy as np
import pytest
from conftest import FLUID_SMALL, ROOT

from wtml.cli import main
from wtml.data import generate, load_shards
from wtml.decoders.checkpoint import read_checkpoint
from wtml.decoders.fluid import TorchFluid, load_fluid_net
from wtml.runtime.predict import OnnxModel
from wtml.training import cli_main


def test_ddp_on_two_cpu_processes_trains_an_epoch_that_exports(tmp_path, capsys):
    data, run, export = tmp_path / "data", tmp_path / "run", tmp_path / "export"
    generate(FLUID_SMALL, data, progress=False)  # 4 shards of 300: 2 train, 1 val, 1 test
    # 600 training samples in 6 batches of 100: 3 for each process, none repeated
    out = subprocess.run(
        [sys.executable, "train.py", "fit", "--config", "configs/fluid.yaml",
         "--data.init_args.data_dir", str(data), "--data.init_args.batch_size", "100",
         "--model.init_args.hidden", "[32, 32]", "--trainer.max_epochs", "1",
         "--trainer.default_root_dir", str(run), "--trainer.strategy", "ddp",
         "--trainer.devices", "2", "--trainer.accelerator", "cpu"],
        capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert "600 training samples, 2 processes" in out.stdout
    assert out.stdout.count("epoch    1/1") == 1  # the first process speaks for both
    with open(run / "logs/version_0/metrics.csv") as f:
        samples = [float(row["train_samples"]) for row in csv.DictReader(f)
                   if row["train_samples"]]
    assert samples == [600.0]  # summed over both processes: one alone would log 300
    ckpt = run / "checkpoints/last.ckpt"
    assert read_checkpoint(ckpt)["global_step"] == 3  # 6 batches shared by 2 processes

    assert main(["export", "--checkpoint", str(ckpt), "--out", str(export)]) == 0
    net, _ = load_fluid_net(str(ckpt))
    shard = load_shards(data, [3])
    torch_pred = TorchFluid(net).predict(shard["ze"], shard["t"])
    onnx_pred = OnnxModel(export / "model.onnx").predict(shard["ze"], shard["t"])
    for k in ("eta", "rho"):
        assert np.isfinite(onnx_pred[k]).all()
        np.testing.assert_allclose(onnx_pred[k], torch_pred[k], rtol=1e-5)

    # resumed on one process, an epoch would have twice the steps its schedule was laid for
    with pytest.raises(SystemExit) as end:
        cli_main(["fit", "--config", str(ROOT / "configs/fluid.yaml"),
                  "--data.init_args.data_dir", str(data), "--trainer.max_epochs", "1",
                  "--trainer.default_root_dir", str(run), "--ckpt_path", str(ckpt)])
    assert end.value.code == 2
    assert "trained on 2 process(es), resumed on 1" in capsys.readouterr().err
