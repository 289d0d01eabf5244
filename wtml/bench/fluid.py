"""``wtml bench fluid``: four predictors, one held-out set, one run, the same threads.

Classical numpy (float64), classical ONNX (float32), decoder torch, decoder ONNX: accuracy by
viscosity decade, p50 latency at batch 1 and throughput at batch 4096, a markdown report and a
PNG of error against latency. Also the exactness check of the classical path on noise-free data
with a perfect calibration.
"""

from __future__ import annotations

import platform
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from wtml.baselines import ClassicalFluid
from wtml.bench.accuracy import by_decade, format_decades, relative_errors
from wtml.bench.bounds import fluid_crlb
from wtml.bench.timing import latency_p50, throughput
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.decoders.fluid import TorchFluid, load_fluid_net
from wtml.runtime.predict import OnnxModel
from wtml.scenes.fluid import NoiseSpec, NuisanceSpec


def classical_exactness(scene, n: int = 2000) -> dict[str, float]:
    """Max relative error of the float64 classical path, noise-free and perfectly calibrated."""
    clean = replace(scene, noise=NoiseSpec(ze_relative=0.0),
                    nuisance=NuisanceSpec(calibration_error=0.0))
    data = clean.simulate(n, np.random.default_rng(12345))
    pred = ClassicalFluid(clean.calibrated_t(), clean.excitation.omega,
                          clean.sphere.radius).predict(data["ze"])
    err = relative_errors(pred, data["eta"], data["rho"])
    return {k: float(v.max()) for k, v in err.items()}


def run_bench(data_dir: str | Path, checkpoint: str | Path, model_dir: str | Path,
              out: str | Path, *, threads: int = 2, latency_repeats: int = 2000,
              throughput_repeats: int = 30) -> str:
    """Run the benchmark; writes ``report.md`` and ``error_vs_latency.png`` under ``out`` and
    returns the report text."""
    torch.set_num_threads(threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    manifest = read_manifest(data_dir)
    scene = dataset_scene(data_dir)
    test = split_shards(manifest["n_shards"], 1, 1)["test"]
    data = load_shards(data_dir, test)
    ze, eta, rho = data["ze"], data["eta"], data["rho"]
    net, _ = load_fluid_net(str(checkpoint))
    predictors = [
        ClassicalFluid(scene.calibrated_t(), scene.excitation.omega, scene.sphere.radius),
        OnnxModel(Path(model_dir) / "classical.onnx", threads=threads),
        TorchFluid(net),
        OnnxModel(Path(model_dir) / "model.onnx", threads=threads),
    ]
    big = np.resize(ze, (4096, ze.shape[1]))
    results = []
    for p in predictors:
        err = relative_errors(p.predict(ze), eta, rho)
        results.append({"name": p.name, "rows": by_decade(err, eta),
                        "latency": latency_p50(p, ze[:1], latency_repeats),
                        "throughput": throughput(p, big, throughput_repeats)})
    exact = classical_exactness(scene)
    bound = fluid_crlb(scene, eta, rho)
    # a Gaussian error of std σ has median |e| = 0.674σ and 95th percentile 1.96σ
    crlb_rows = by_decade({k: 0.674 * v for k, v in bound.items()}, eta)
    crlb_p95 = by_decade({k: 1.96 * v for k, v in bound.items()}, eta)
    for row, row95 in zip(crlb_rows, crlb_p95, strict=True):
        row["eta_p95"], row["rho_p95"] = row95["eta_p95"], row95["rho_p95"]
    base = results[0]["latency"]
    lines = [
        "# wtml bench fluid",
        "",
        f"Dataset `{data_dir}` (scene `{manifest['scene_hash'][:12]}`), test shard(s) {test}, "
        f"{len(ze)} samples; noise {scene.noise.ze_relative:g} relative on Ze, calibration "
        f"error {scene.nuisance.calibration_error:g} (gain and offset of Zm).",
        f"Machine: {platform.machine()}, {platform.processor() or 'cpu'}; torch and onnxruntime "
        f"with {threads} threads; latency = p50 of up to {latency_repeats} calls at batch 1; "
        f"throughput = median of up to {throughput_repeats} calls at batch 4096 (each "
        f"measurement stops after 3 s).",
        "",
        "| method | η median | η p95 | ρ median | ρ p95 | p50 latency, batch 1 | "
        "latency / classical numpy | throughput, batch 4096 |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        a = r["rows"][-1]
        lines.append(f"| {r['name']} | {100 * a['eta_median']:.2f} % | {100 * a['eta_p95']:.2f} % "
                     f"| {100 * a['rho_median']:.3f} % | {100 * a['rho_p95']:.3f} % | "
                     f"{1e6 * r['latency']:.1f} µs | {r['latency'] / base:.2f} | "
                     f"{r['throughput']:.3g} /s |")
    c = crlb_rows[-1]
    lines.append(f"| Cramér–Rao bound (Gaussian-equivalent) | {100 * c['eta_median']:.2f} % | "
                 f"{100 * c['eta_p95']:.2f} % | {100 * c['rho_median']:.3f} % | "
                 f"{100 * c['rho_p95']:.3f} % | | | |")
    lines += ["", "Noise-free with a perfect calibration, classical numpy (float64): max relative "
              f"error η {exact['eta']:.1e}, ρ {exact['rho']:.1e}.",
              "The Cramér–Rao row is the bound for this noise and calibration-error model "
              "(wtml/bench/bounds.py) as the median and 95th percentile of a Gaussian error of "
              "that std; a decoder can go below it only by using the scene's prior over (η, ρ).",
              "", "## By viscosity decade", ""]
    for r in results:
        lines += [format_decades(r["name"], r["rows"]), ""]
    lines += [format_decades("Cramér–Rao bound (Gaussian-equivalent)", crlb_rows), ""]
    report = "\n".join(lines)
    (out / "report.md").write_text(report)
    _plot(results, out / "error_vs_latency.png")
    return report


def _plot(results: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4), constrained_layout=True)
    for r in results:
        a = r["rows"][-1]
        ax.scatter(1e6 * r["latency"], 100 * a["eta_median"], marker="o", label=f"{r['name']} η")
        ax.scatter(1e6 * r["latency"], 100 * a["rho_median"], marker="x", label=f"{r['name']} ρ")
    ax.set(xscale="log", yscale="log", xlabel="p50 latency at batch 1 (µs)",
           ylabel="median relative error (%)", title="fluid: error against latency")
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=120)
    plt.close(fig)
