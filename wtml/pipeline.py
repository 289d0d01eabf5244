"""The main job, end to end on small defaults, for the fluid slice and then the radial slice:
generate -> train -> export -> predict -> bench.

Each stage prints the command that does it alone. Work already done is kept: complete shards
are skipped, and training resumes from ``last.ckpt`` when it belongs to the same dataset.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np
import torch
import yaml

from wtml.bench.fluid import run_bench
from wtml.data import dataset_scene, generate, load_shards, read_manifest
from wtml.data.datamodule import split_shards
from wtml.runtime.export import export_model
from wtml.runtime.predict import predict_file
from wtml.scenes import config_hash, load_scene, scene_from_dict
from wtml.training import cli_main


def _say(text: str) -> None:
    print(f"\n== {text}", flush=True)


def checkpoint_matches(ckpt: Path, scene_hash: str, config: str,
                       max_epochs: int | None = None) -> bool:
    """Whether ``ckpt`` can resume ``config`` on the dataset of ``scene_hash``: same scene,
    the model arguments of the config are those the checkpoint was made with (an edited
    config starts afresh rather than failing on the old weights' shapes), and so is the run
    length (``max_epochs``, else the config's): the learning-rate schedules are laid out over
    it."""
    if not ckpt.exists():
        return False
    state = torch.load(ckpt, map_location="cpu", weights_only=False)
    info, hparams = state.get("wtml", {}), state.get("hyper_parameters", {})
    if not info.get("scene") or config_hash(scene_from_dict(info["scene"])) != scene_hash:
        return False
    cfg = yaml.safe_load(Path(config).read_text())
    epochs = max_epochs if max_epochs is not None else cfg.get("trainer", {}).get("max_epochs")
    if info.get("max_epochs") != epochs:
        return False
    wanted = cfg["model"].get("init_args", {})
    return all(hparams.get(key) == value for key, value in wanted.items())


def write_sample_csv(data_dir: Path, path: Path, n: int = 3) -> None:
    """A few test-shard measurements as a CSV that ``wtml predict`` reads."""
    manifest = read_manifest(data_dir)
    data = load_shards(data_dir, split_shards(manifest["n_shards"], 1, 1)["test"])
    scene = dataset_scene(data_dir)
    if scene.task == "fluid":
        freq, truth = scene.excitation.frequency_hz, {"eta": "true_eta_pa_s",
                                                      "rho": "true_rho_kg_m3"}
    else:
        freq, truth = np.asarray(scene.excitation.frequencies_hz), {"distance": "true_distance_m"}
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["sample", "frequency_hz", "ze_real", "ze_imag", *truth.values()])
        for s in range(n):
            for f, z in zip(freq, data["ze"][s], strict=True):
                w.writerow([s, repr(float(f)), repr(float(z.real)), repr(float(z.imag))]
                           + [repr(float(data[k][s])) for k in truth])


def _train(config: str, data: Path, ckpt: Path, scene_hash: str, max_epochs: int | None) -> None:
    args = ["fit", "--config", config, "--data.init_args.data_dir", str(data)]
    if max_epochs is not None:
        args += ["--trainer.max_epochs", str(max_epochs)]
    if checkpoint_matches(ckpt, scene_hash, config, max_epochs):
        args += ["--ckpt_path", str(ckpt)]
    elif ckpt.exists():
        print(f"{ckpt} is for another scene, model config or run length: training afresh")
    _say("train: python train.py " + " ".join(args))
    cli_main(args)


def run_radial(*, max_epochs: int | None = None) -> str:
    """The radial slice end to end; returns the benchmark report."""
    from wtml.bench.radial import run_bench as run_radial_bench

    data, invalid = Path("datasets/radial"), Path("datasets/radial_invalid")
    for scene_path, out in (("configs/scenes/radial.yaml", data),
                            ("configs/scenes/radial_invalid.yaml", invalid)):
        _say(f"generate: wtml generate --config {scene_path} --out {out}")
        manifest = generate(load_scene(scene_path), out)
        print(f"{manifest['samples']} samples in {manifest['n_shards']} shards")
    scene_hash = read_manifest(data)["scene_hash"]
    ckpts = {}
    for name in ("radial", "radial_thesis"):
        ckpts[name] = Path(f"runs/{name}/checkpoints/last.ckpt")
        _train(f"configs/{name}.yaml", data, ckpts[name], scene_hash, max_epochs)
        _say(f"export: wtml export --checkpoint {ckpts[name]} --out export/{name}")
        export_model(ckpts[name], Path("export") / name)
    sample = Path("export/radial/sample_input.csv")
    write_sample_csv(data, sample)
    _say(f"predict: wtml predict --model export/radial --input {sample}")
    print(format_predictions(predict_file("export/radial", sample)))
    bench = Path("runs/radial/bench")
    _say(f"bench: wtml bench radial --out {bench}")
    report = run_radial_bench(data, ckpts["radial"], ckpts["radial_thesis"], "export/radial",
                              "export/radial_thesis", bench, invalid_dir=invalid)
    print(report)
    print(f"full report: {bench / 'report.md'}; plots: {bench}/error_vs_latency.png, "
          f"{bench}/error_vs_d.png")
    return report


def run_pipeline(*, scene_path: str = "configs/scenes/fluid.yaml",
                 train_config: str = "configs/fluid.yaml", data_dir: str = "datasets/fluid",
                 model_dir: str = "export/fluid", bench_dir: str = "runs/fluid/bench",
                 max_epochs: int | None = None) -> str:
    """Run the fluid slice end to end; returns its benchmark report."""
    data, model, bench = Path(data_dir), Path(model_dir), Path(bench_dir)
    _say(f"generate: wtml generate --config {scene_path} --out {data}")
    manifest = generate(load_scene(scene_path), data)
    print(f"{manifest['samples']} samples in {manifest['n_shards']} shards")

    ckpt = Path("runs/fluid/checkpoints/last.ckpt")
    _train(train_config, data, ckpt, manifest["scene_hash"], max_epochs)

    _say(f"export: wtml export --checkpoint {ckpt} --out {model}")
    for kind, path in export_model(ckpt, model).items():
        print(f"{kind}: {path}")

    sample = model / "sample_input.csv"
    write_sample_csv(data, sample)
    _say(f"predict: wtml predict --model {model} --input {sample}")
    print(format_predictions(predict_file(model, sample)))

    _say(f"bench: wtml bench fluid --data {data} --checkpoint {ckpt} --model {model} "
         f"--out {bench}")
    report = run_bench(data, ckpt, model, bench)
    print(report.split("\n## By viscosity decade")[0])
    print(f"full report: {bench / 'report.md'}; plot: {bench / 'error_vs_latency.png'}")
    sys.stdout.flush()
    return report


def format_predictions(rows: list[dict]) -> str:
    """Prediction rows as an aligned table, units in the headers."""
    keys = list(rows[0])
    width = [max(len(k), 12) for k in keys]
    lines = ["  ".join(k.rjust(w) for k, w in zip(keys, width, strict=True))]
    for r in rows:
        lines.append("  ".join((f"{r[k]:d}" if k == "sample" else f"{r[k]:.5g}").rjust(w)
                               for k, w in zip(keys, width, strict=True)))
    return "\n".join(lines)
