"""``wtml bench fluid``: every fluid method on one held-out set, in one run, the same threads.

The thesis's closed form in numpy (float64) and ONNX (float32), the decoder in torch and
ONNX, and the best achievable estimate (the Bayes posterior mean under the scene's prior,
``wtml.baselines.fluid_bayes``): accuracy by viscosity decade, p50 latency at batch 1 and
throughput, beside the Cramér–Rao bound (its rows made like the methods'). Also the exactness
check of the closed form on noise-free data with a perfect calibration, and the domain gate's
false alarms on the test set. Every method gets each record's calibrated T (the user's
calibration of their own device).

The device-spread table: the decoder (ONNX), the classical path (ONNX) and the Bayes reference
on fresh records of the nominal device, of devices drawn from the trained spread (the scene's
``spread`` block), from issue 21's spread (:data:`REFERENCE_SPREAD`, the sphere's radius
included) and from each of its parameters alone: median η and ρ errors and the share flagged
out of domain, so the report says which parameter limits the task. Writes a markdown report,
``summary.json`` and a PNG of error against latency.
"""

from __future__ import annotations

import json
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from wtml.baselines import ClassicalFluid
from wtml.baselines.fluid_bayes import BayesFluid
from wtml.bench.accuracy import by_decade, format_decades, relative_errors, sampled_errors
from wtml.bench.bounds import fluid_crlb
from wtml.bench.frontier import Method, Problem, busy_lines, open_graph
from wtml.bench.resampling import statistic_interval
from wtml.bench.timing import busy_elsewhere, cpu_snapshot, latency_p50, throughput
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.decoders.domain import QUANTILE
from wtml.decoders.fluid import TorchFluid, load_fluid_net
from wtml.runtime.predict import OnnxModel, load_export
from wtml.scenes.fluid import DeviceSpread, NoiseSpec, NuisanceSpec

BOUND_DRAWS = 200
"""Errors drawn from each sample's Cramér–Rao bound for the bound's rows."""
REFERENCE_SPREAD = DeviceSpread(k=0.03, m=0.01, c=0.25, phi=0.03, c0=0.03, tan_delta=0.25,
                                sphere_radius=0.01)
"""Issue 21's manufacturing spread (uniform half-widths), an unmeasured ±1 % sphere
included."""
BAYES_GRID = {"n_fraction": 200, "n_temperature": 50}
"""The Bayes reference's grid in the device-spread table (a quarter of the main table's; its
medians move by less than the rows' sampling error)."""


def device_spread(scene, decoder: OnnxModel, classical: OnnxModel, n: int,
                  seed: int = 2024) -> list[dict]:
    """The device-spread table's rows (module docstring): per device set, ``{"device",
    "methods": [{"name", "eta_median", "rho_median", "flagged"}]}`` on ``n`` fresh records."""
    spread = REFERENCE_SPREAD
    sets = [("nominal device", DeviceSpread()), ("trained spread", scene.spread),
            ("issue 21 spread", spread)]
    sets += [(f"{name} ±{100 * getattr(spread, name):g} % only",
              DeviceSpread(**{name: getattr(spread, name)}))
             for name in DeviceSpread.FIELDS if getattr(spread, name) > 0]
    rows = []
    for k, (label, device) in enumerate(sets):
        variant = replace(scene, spread=device)
        data = variant.simulate(n, np.random.default_rng([seed, k]))
        methods = []
        for p in (decoder, classical, BayesFluid(variant, **BAYES_GRID)):
            pred = p.predict(data["ze"], data["t"])
            err = relative_errors(pred, data["eta"], data["rho"])
            flagged = float(1 - pred["in_domain"].mean()) if "in_domain" in pred else None
            methods.append({"name": p.name, "eta_median": float(np.median(err["eta"])),
                            "rho_median": float(np.median(err["rho"])), "flagged": flagged})
        rows.append({"device": label, "methods": methods})
    return rows


def format_device_spread(rows: list[dict], n: int) -> list[str]:
    """The device-spread table as markdown lines."""
    names = [m["name"] for m in rows[0]["methods"]]
    head = " | ".join(f"{name} η, ρ median, flagged" for name in names)
    lines = [f"## Device spread ({n} fresh records per row; parameters uniform in ±half-width)",
             "", f"| device | {head} |", "|---|" + "---|" * len(names)]
    for r in rows:
        cells = [f"{100 * m['eta_median']:.2f} %, {100 * m['rho_median']:.3f} %"
                 + ("" if m["flagged"] is None else f", {100 * m['flagged']:.1f} %")
                 for m in r["methods"]]
        lines.append(f"| {r['device']} | " + " | ".join(cells) + " |")
    return lines


def classical_exactness(scene, n: int = 2000) -> dict[str, float]:
    """Max relative error of the float64 classical path, noise-free and perfectly calibrated."""
    clean = replace(scene, noise=NoiseSpec(ze_relative=0.0),
                    nuisance=NuisanceSpec(calibration_error=0.0))
    data = clean.simulate(n, np.random.default_rng(12345))
    pred = ClassicalFluid(clean.excitation.omega, clean.sphere.radius).predict(data["ze"],
                                                                               data["t"])
    err = relative_errors(pred, data["eta"], data["rho"])
    return {k: float(v.max()) for k, v in err.items()}


def evaluate_checkpoint(checkpoint: str | Path, data_dir: str | Path, scene,
                        split: dict[str, list[int]], test: dict[str, np.ndarray],
                        where: str) -> str:
    """``wtml evaluate``'s report (markdown) of a fluid checkpoint: the decoder (torch) and
    the thesis's closed form, median and worst relative errors of η and ρ by viscosity decade
    on ``test`` (the test shard's arrays, ``where`` naming it; ``split``, ``data_dir``: the
    dataset's, unused here) with each record's calibrated T."""
    net, _ = load_fluid_net(str(checkpoint))
    parts = []
    for p in (TorchFluid(net), ClassicalFluid(scene.excitation.omega, scene.sphere.radius)):
        err = relative_errors(p.predict(test["ze"], test["t"]), test["eta"], test["rho"])
        parts.append(format_decades(f"{p.name} on {where}", by_decade(err, test["eta"])))
    return "\n\n".join(parts)


def run_bench(data_dir: str | Path, checkpoint: str | Path, model_dir: str | Path,
              out: str | Path, *, threads: int = 2, latency_repeats: int = 2000,
              throughput_repeats: int = 30, device_records: int = 1000) -> str:
    """Run the benchmark; writes ``report.md``, ``summary.json`` (the key numbers) and
    ``error_vs_latency.png`` under ``out`` and returns the report text.
    ``device_records``: fresh records per row of the device-spread table."""
    torch.set_num_threads(threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    manifest = read_manifest(data_dir)
    scene = dataset_scene(data_dir)
    test = split_shards(manifest["n_shards"], 1, 1)["test"]
    data = load_shards(data_dir, test)
    ze, t, eta, rho = data["ze"], data["t"], data["eta"], data["rho"]
    net, _ = load_fluid_net(str(checkpoint))
    decoder_onnx, classical_onnx = load_export(model_dir, threads=threads)
    predictors = [
        ClassicalFluid(scene.excitation.omega, scene.sphere.radius),
        classical_onnx,
        TorchFluid(net),
        decoder_onnx,
    ]
    big = np.resize(ze, (4096, ze.shape[1]))
    big_t = np.resize(t, (4096, *t.shape[1:]))
    results = []
    start = cpu_snapshot()
    for p in predictors:
        pred = p.predict(ze, t)
        if p is decoder_onnx:  # its graph's domain gate, on this in-domain test set
            false_alarm = float(1 - pred["in_domain"].mean())
        err = relative_errors(pred, eta, rho)
        results.append({"name": p.name, "rows": by_decade(err, eta),
                        "latency": latency_p50(p, (ze[:1], t[:1]), latency_repeats),
                        "throughput": throughput(p, (big, big_t), throughput_repeats)})
    end = cpu_snapshot()
    timed = {"threads": threads, "busy_elsewhere": busy_elsewhere(start, end),
             "cores": end[3] if end else None}
    bayes = BayesFluid(scene)
    start = time.perf_counter()
    best = bayes.predict(ze, t)
    bayes_rate = len(ze) / (time.perf_counter() - start)  # its accuracy pass, batch = all
    results.append({"name": bayes.name, "rows": by_decade(relative_errors(best, eta, rho), eta),
                    "latency": latency_p50(bayes, (ze[:1], t[:1]), latency_repeats),
                    "throughput": bayes_rate})
    spread_rows = device_spread(scene, decoder_onnx, classical_onnx, device_records)
    exact = classical_exactness(scene)
    bound = fluid_crlb(scene, eta, rho)
    crlb_rows = by_decade(*sampled_errors(bound, eta, draws=BOUND_DRAWS))
    for row in crlb_rows:
        row["n"] //= BOUND_DRAWS  # samples, not draws
    base = results[0]["latency"]
    ref = results[-1]["rows"][-1]
    lines = [
        "# wtml bench fluid",
        "",
        f"Dataset `{data_dir}` (scene `{manifest['scene_hash'][:12]}`), test shard(s) {test}, "
        f"{len(ze)} samples; noise {scene.noise.ze_relative:g} relative on Ze, calibration "
        f"error {scene.nuisance.calibration_error:g} (gain and offset of Zm).",
        f"Machine: {platform.machine()}, {platform.processor() or 'cpu'}; torch and onnxruntime "
        f"with {threads} threads; latency = p50 of up to {latency_repeats} calls at batch 1; "
        f"throughput = median of up to {throughput_repeats} calls at batch 4096 (each "
        "measurement stops after 3 s; the Bayes row: its pass over the whole set).",
        "", *busy_lines(timed),
        "| method | η median | η p95 | ρ median | ρ p95 | η, ρ median / Bayes | "
        "p50 latency, batch 1 | latency / closed form numpy | throughput |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in results:
        a = r["rows"][-1]
        lines.append(f"| {r['name']} | {100 * a['eta_median']:.2f} % | {100 * a['eta_p95']:.2f} % "
                     f"| {100 * a['rho_median']:.3f} % | {100 * a['rho_p95']:.3f} % | "
                     f"{a['eta_median'] / ref['eta_median']:.2f}×, "
                     f"{a['rho_median'] / ref['rho_median']:.2f}× | "
                     f"{1e6 * r['latency']:.1f} µs | {r['latency'] / base:.2f} | "
                     f"{r['throughput']:.3g} /s |")
    c = crlb_rows[-1]
    lines.append(f"| Cramér–Rao bound (no prior) | {100 * c['eta_median']:.2f} % | "
                 f"{100 * c['eta_p95']:.2f} % | {100 * c['rho_median']:.3f} % | "
                 f"{100 * c['rho_p95']:.3f} % | | | | |")
    dec = results[3]["rows"][-1]
    lines += [
        "",
        f"The decoder (ONNX) is {dec['eta_median'] / ref['eta_median']:.2f}× (η) and "
        f"{dec['rho_median'] / ref['rho_median']:.2f}× (ρ) from the best achievable, the Bayes "
        "posterior mean under the scene's own prior (glycerol–water, uniform in volume fraction "
        "and temperature), noise and calibration error (wtml/baselines/fluid_bayes.py: exact, "
        f"on a 400×100 grid; {1e3 / bayes_rate:.1f} ms a measurement).",
        "The thesis's closed form (calibrated T -> Zm -> band least squares) ignores the "
        "calibration error and the prior; noise-free with a perfect calibration it is exact "
        f"(float64): max relative error η {exact['eta']:.1e}, ρ {exact['rho']:.1e}.",
        "The Cramér–Rao row is the bound for this noise and calibration-error model without the "
        "prior (wtml/bench/bounds.py), as percentiles of errors drawn from each sample's bound "
        f"({BOUND_DRAWS} draws each), the way the methods' rows are made; the prior ties ρ to η, "
        "so it is no floor for an estimator that knows the prior (the Bayes row is).",
        f"Domain gate: {100 * false_alarm:.2f} % of this in-domain test set flagged out of "
        f"domain by decoder ONNX (stated rate {100 * (1 - QUANTILE):.1f} %).",
        "The Bayes row is the posterior mean, which minimises the mean squared error; a method "
        "can have a lower median relative error in some rows below.",
        "", *format_device_spread(spread_rows, device_records), "",
        "Each record carries its own device's calibrated T (the user's calibration, with the "
        "sphere mounted); the sphere's radius is not measured: it enters only the Stokes law, "
        "where a radius R(1 + ε) is exactly a fluid with η(1 + ε) and ρ(1 + ε)³ (physics.md "
        "§5): the classical path reads that; only the fluid's prior (glycerol-water) tells part "
        "of it apart. The Bayes reference integrates the radius out over the spread (grid "
        f"{BAYES_GRID['n_fraction']}×{BAYES_GRID['n_temperature']}).",
        "", "## By viscosity decade", ""]
    for r in results:
        lines += [format_decades(r["name"], r["rows"]), ""]
    lines += [format_decades("Cramér–Rao bound (no prior)", crlb_rows), ""]
    report = "\n".join(lines)
    (out / "report.md").write_text(report)
    summary = {"decoder_onnx": {k: dec[k] for k in ("eta_median", "rho_median")},
               "bayes": {k: ref[k] for k in ("eta_median", "rho_median")},
               "closed_form": {k: results[0]["rows"][-1][k] for k in ("eta_median",
                                                                    "rho_median")},
               "crlb": {k: c[k] for k in ("eta_median", "rho_median")},
               "decoder_onnx_latency_s": results[3]["latency"],
               "decoder_onnx_throughput": results[3]["throughput"],
               "timing": timed, "false_alarm": false_alarm, "n_test": len(ze),
               "device_spread": spread_rows, "device_records": device_records}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
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


SPEED_TARGET = (50e-6, 1e6)
"""The default decoder's speed on the frontier (issue 25 §2): p50 ≤ 50 µs at batch 1 and
≥ 1e6 samples/s at a batch of 4096."""


def frontier_problem(data_dir: str | Path, model_dir: str | Path, *, threads: int = 2,
                     max_samples: int = 3000):
    """The fluid task for :mod:`wtml.bench.frontier`: η's median relative error (%) on the
    test shard (its first ``max_samples``), each record with its calibrated T; the classical
    path in numpy and as ``model_dir``'s ONNX graph, the Bayes posterior mean (the best
    achievable under the scene's prior) and the Cramér–Rao bound (no prior), as rows."""
    manifest, scene = read_manifest(data_dir), dataset_scene(data_dir)
    split = split_shards(manifest["n_shards"], 1, 1)
    data = load_shards(data_dir, split["test"])
    ze, t, eta, rho = (data[k][:max_samples] for k in ("ze", "t", "eta", "rho"))
    train = load_shards(data_dir, split["train"][:1])

    def median(values):
        return np.median(values, -1)

    def score(pred: dict) -> tuple[float, float, float]:
        err = 100 * np.abs(pred["eta"] / eta - 1)
        return (float(np.median(err)), *statistic_interval(err, median))

    bound = fluid_crlb(scene, eta, rho)
    drawn, _ = sampled_errors(bound, eta, draws=BOUND_DRAWS)
    crlb = 100 * drawn["eta"]
    classical = Path(model_dir) / "classical.onnx"
    methods = [
        Method("thesis closed form numpy (float64)", "classical",
               ClassicalFluid(scene.excitation.omega, scene.sphere.radius)),
        Method("thesis closed form ONNX", "classical",
               open_graph(classical, "measurements", threads), classical),
        Method("Bayes posterior mean", "reference", BayesFluid(scene),
               note="the best achievable under the scene's prior (exact, by grid)"),
        Method("Cramér–Rao bound (no prior)", "bound",
               score=(float(np.median(crlb)), *statistic_interval(
                   crlb[::BOUND_DRAWS // 10], median)),
               note=f"median of errors drawn from each sample's bound ({BOUND_DRAWS} each)"),
    ]
    return Problem(
        "fluid", "η median relative error", "%", False, "sample", 1.0, (ze, t), score,
        "measurements", 4096, (train["ze"][:512], train["t"][:512]), methods,
        data=f"`{data_dir}` test shard {split['test']}, {len(ze)} samples (noise "
             f"{scene.noise.ze_relative:g} on Ze, calibration error "
             f"{scene.nuisance.calibration_error:g})",
        speed_target=SPEED_TARGET)
