"""``wtml bench radial``: every radial method on the nominal device and over the device's
manufacturing spread, in one run.

Thesis decoder (2-10-1 sigmoid on Ze alone) and ours, each in torch and ONNX; the polynomials
in Re and Im of Ze / ref (numpy, and Im as the exported classical ONNX); the physics inversion
(a converged, damped and bounded solve on the preset's beam model, of Ze corrected by the
reference). Each reads the measurement and the device's free reference. On the nominal
device (``max_samples`` fresh records of the scene with no spread, 10000 by default): RMSE,
max error and RMSE / CRLB by range of d, p50 latency at batch 1 and throughput at batch 4096.
The device-spread table: each method on the nominal device, on the test shard's devices
(the scene's spread, its first ``max_samples``) and on fresh records with each parameter of
the spread alone (``spread_samples`` each): RMSE, max error, the share of in-domain answers
within 2σ and the share flagged out of domain; the parameter alone that costs the decoder
most is what a user must measure better. Then the invalid-contact variant (thesis §5.5.4) and
the generation throughput of the beam path against the 2×2 path. Writes ``report.md``,
``error_vs_latency.png`` and ``error_vs_d.png``.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from wtml.baselines.radial import InversionRadial, PolynomialRadial
from wtml.bench.bounds import radial_crlb
from wtml.bench.timing import latency_p50, throughput
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.decoders.domain import QUANTILE
from wtml.decoders.radial import TorchRadial, load_radial_net
from wtml.physics import ze_from_zm
from wtml.runtime.predict import OnnxModel

BINS_UM = (0, 800, 1600, 2400, 3200)


def range_rows(err: np.ndarray, d: np.ndarray, crlb: np.ndarray) -> list[dict]:
    """RMSE, max error and RMSE / CRLB per range of ``BINS_UM`` and overall (all in m)."""
    rows = []
    edges = list(zip(BINS_UM[:-1], BINS_UM[1:], strict=True)) + [(BINS_UM[0], BINS_UM[-1])]
    for lo, hi in edges:
        sel = (d >= lo * 1e-6) & (d <= hi * 1e-6)
        rmse = float(np.sqrt(np.mean(err[sel] ** 2)))
        rows.append({"range": f"{lo}-{hi} µm" if (lo, hi) != edges[-1] else "all",
                     "rmse": rmse, "max": float(np.abs(err[sel]).max()),
                     "ratio": rmse / float(np.sqrt(np.mean(crlb[sel] ** 2)))})
    return rows


def format_ranges(results: list[dict]) -> str:
    """A markdown table of each result's :func:`range_rows`: RMSE in µm and (ratio×)."""
    lines = ["| method | " + " | ".join(row["range"] for row in results[0]["rows"]) + " |",
             "|---|" + "---|" * len(results[0]["rows"])]
    for r in results:
        lines.append(f"| {r['name']} | " + " | ".join(
            f"{1e6 * row['rmse']:.2f} ({row['ratio']:.1f}×)" for row in r["rows"]) + " |")
    return "\n".join(lines)


def generation_throughput(scene, n: int = 20000) -> dict[str, float]:
    """Samples/s of Ze for contacts on the shaft (beam path) and, on the same structure, for
    loads at the tip (2×2 path: T once per frequency, then the bilinear map)."""
    rng = np.random.default_rng(0)
    d = 1e-6 * rng.uniform(*scene.contact.distance_um, n)
    k = np.exp(rng.uniform(*np.log(scene.contact.stiffness), n))
    tr = scene.transducer()
    t0 = time.perf_counter()
    scene.ze_of(d, k, tr)
    beam = n / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    t = tr.transduction_matrix(scene.excitation.omega)
    ze_from_zm(t, k[:, None] / (1j * scene.excitation.omega))
    matrix = n / (time.perf_counter() - t0)
    return {"beam": beam, "matrix": matrix}


def spread_sets(scene, test: dict, n_nominal: int, n_each: int) -> dict[str, dict]:
    """The device-spread table's record sets: ``"nominal device"`` (``n_nominal`` fresh
    records with no spread), ``"spread (test shard)"`` (``test``) and one per parameter of
    the scene's spread with a nonzero width, alone (``n_each`` fresh records each)."""
    rng = np.random.default_rng([scene.seed, 10**6 + 2])
    sets = {"nominal device": scene.simulate(n_nominal, rng, widths={}),
            "spread (test shard)": test}
    for name, width in scene.device.widths(scene.preset).items():
        if width:
            sets[f"{name} ±{100 * width:g} % alone"] = scene.simulate(
                n_each, rng, widths=scene.device.only(name, scene.preset))
    return sets


def spread_row(pred: dict, d: np.ndarray) -> dict:
    """RMSE and max error (m) of ``pred["distance"]`` against ``d``; where the method has a
    domain gate, the flagged share, and where it has a std, the share of in-domain answers
    within 2σ (NaN where not applicable)."""
    err = pred["distance"] - d
    inside = pred.get("in_domain", np.ones(len(d), bool))
    sigma = pred.get("sigma")
    cover = (float(np.mean(np.abs(err[inside]) <= 2 * sigma[inside]))
             if sigma is not None and inside.any() and np.any(sigma > 0) else float("nan"))
    return {"rmse": float(np.sqrt(np.mean(err**2))), "max": float(np.abs(err).max()),
            "cover": cover,
            "flagged": float(1 - inside.mean()) if "in_domain" in pred else float("nan")}


def format_spread(table: dict[str, dict[str, dict]]) -> str:
    """The device-spread table: one row per record set, per method RMSE / max (µm), within
    2σ and flagged (%)."""
    methods = list(next(iter(table.values())))
    lines = ["| records | " + " | ".join(methods) + " |", "|---|" + "---|" * len(methods)]

    def pct(x: float) -> str:
        return "" if np.isnan(x) else f", {100 * x:.0f} %"

    for name, row in table.items():
        cells = [f"{1e6 * r['rmse']:.2f} / {1e6 * r['max']:.1f}{pct(r['cover'])}"
                 f"{pct(r['flagged'])}" for r in row.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def run_bench(data_dir, checkpoint, thesis_checkpoint, model_dir, thesis_model_dir, out, *,
              invalid_dir=None, threads: int = 2, latency_repeats: int = 2000,
              throughput_repeats: int = 30, max_samples: int = 10000,
              spread_samples: int = 2000) -> str:
    """Run the radial benchmark (module docstring); returns the report (also written under
    ``out``)."""
    for name, value in (("max_samples", max_samples), ("spread_samples", spread_samples)):
        if value < 1:
            raise ValueError(f"{name} must be >= 1, got {value}")
    torch.set_num_threads(threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    manifest = read_manifest(data_dir)
    scene = dataset_scene(data_dir)
    split = split_shards(manifest["n_shards"], 1, 1)
    train, test = load_shards(data_dir, split["train"]), load_shards(data_dir, split["test"])
    n_test = len(test["distance"])
    test = {key: test[key][:max_samples] for key in ("ze", "ref", "distance", "stiffness")}
    sets = spread_sets(scene, test, max_samples, spread_samples)
    nominal = sets["nominal device"]
    ze, ref, d, k = (nominal[key] for key in ("ze", "ref", "distance", "stiffness"))
    crlb = radial_crlb(scene, d, k)
    ours, _ = load_radial_net(str(checkpoint))
    thesis, _ = load_radial_net(str(thesis_checkpoint))
    methods = [
        TorchRadial(thesis, "thesis 2-10-1 torch"),
        _named(OnnxModel(Path(thesis_model_dir) / "model.onnx", threads), "thesis 2-10-1 ONNX"),
        TorchRadial(ours, "ours torch"),
        _named(OnnxModel(Path(model_dir) / "model.onnx", threads), "ours ONNX"),
        PolynomialRadial("real").fit(train["ze"], train["ref"], train["distance"]),
        PolynomialRadial("imag").fit(train["ze"], train["ref"], train["distance"]),
        _named(OnnxModel(Path(model_dir) / "classical.onnx", threads),
               "polynomial Im Ze/ref ONNX"),
        InversionRadial(scene),
    ]
    big = tuple(np.resize(x, (4096, ze.shape[1])) for x in (ze, ref))
    results = []
    for m in methods:
        pred = m.predict(ze, ref)
        if m is methods[3]:  # ours ONNX: its graph's domain gate, on this in-domain test set
            false_alarm = float(1 - pred["in_domain"].mean())
        err = pred["distance"] - d
        results.append({"name": m.name, "err": err, "rows": range_rows(err, d, crlb),
                        "latency": latency_p50(m, (ze[:1], ref[:1]), latency_repeats),
                        "throughput": throughput(m, big, throughput_repeats)})
    spread = {name: {m.name: spread_row(m.predict(s["ze"], s["ref"]), s["distance"])
                     for m in (methods[3], methods[1], methods[6], methods[7])}
              for name, s in sets.items()}
    gen = generation_throughput(scene)
    best_poly = min(r["rows"][-1]["rmse"] for r in results if r["name"].startswith("polynomial"))
    lines = [
        "# wtml bench radial", "",
        f"Dataset `{data_dir}` (scene `{manifest['scene_hash'][:12]}`); the first table on "
        f"{len(d)} fresh records of the nominal device (the preset; the scene with no "
        f"spread), the device-spread table also on the first {len(test['distance'])} of the "
        f"{n_test} samples of test shard(s) {split['test']}; {scene.preset} preset "
        f"(beam model) at "
        f"{list(scene.excitation.frequencies_hz)} Hz; noise {scene.noise.ze_relative:g} "
        f"relative on Ze; contact stiffness {scene.contact.stiffness[0]:g}–"
        f"{scene.contact.stiffness[1]:g} N/m (log-uniform nuisance).",
        f"Machine: {platform.machine()}; torch and onnxruntime with {threads} threads; latency "
        f"= p50 of up to {latency_repeats} calls at batch 1; throughput = median of up to "
        f"{throughput_repeats} calls at batch 4096 (each measurement stops after 3 s). "
        f"CRLB rms over the set: "
        f"{1e6 * np.sqrt(np.mean(crlb**2)):.2f} µm.", "",
        "| method | RMSE | max error | RMSE / CRLB | vs best polynomial | p50 latency | "
        "throughput |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results:
        a = r["rows"][-1]
        lines.append(f"| {r['name']} | {1e6 * a['rmse']:.2f} µm | {1e6 * a['max']:.1f} µm | "
                     f"{a['ratio']:.2f} | {best_poly / a['rmse']:.2f}× | "
                     f"{1e6 * r['latency']:.1f} µs | {r['throughput']:.3g} /s |")
    lines += ["", "## RMSE by range of d (µm) and RMSE / CRLB, nominal device", "",
              format_ranges(results)]
    ours_spread = spread["spread (test shard)"][methods[3].name]
    alone = {name: row[methods[3].name] for name, row in spread.items() if "alone" in name}
    limit = max(alone, key=lambda name: alone[name]["rmse"]) if alone else None
    lines += ["", "## Device spread", "",
              f"The scene's manufacturing spread (relative half-widths of uniform tolerance "
              f"bands): {_spread_text(scene)}; each record's device drawn from it, its free "
              f"Ze the reference (noise {scene.noise.reference_relative:g}). Per method: RMSE "
              f"/ max error (µm), share of in-domain answers within 2σ (ours), share flagged "
              f"out of domain (the ONNX graphs).", "", format_spread(spread), "",
              f"Ours over the spread: {1e6 * ours_spread['rmse']:.2f} µm RMSE (target ≤ 5), "
              f"{100 * ours_spread['cover']:.0f} % of in-domain answers within 2σ (target ≥ "
              f"90 %), {100 * ours_spread['flagged']:.1f} % flagged."
              + (f" The parameter that limits it: {limit} "
                 f"({1e6 * alone[limit]['rmse']:.2f} µm alone): what a user must measure "
                 f"better." if limit else "")]
    inv, ours_onnx = results[-1], results[3]
    lines += ["", f"The physics inversion (grid start, then Levenberg–Marquardt in (d, 1/k) on "
              f"the beam model) costs {1e3 * inv['latency']:.1f} ms at batch 1 and "
              f"{1e3 / inv['throughput']:.2f} ms a measurement at batch 4096; ours ONNX matches "
              f"its accuracy ({1e6 * ours_onnx['rows'][-1]['rmse']:.2f} against "
              f"{1e6 * inv['rows'][-1]['rmse']:.2f} µm) at "
              f"{inv['latency'] / ours_onnx['latency']:.0f}× less latency.",
              f"Domain gate: {100 * false_alarm:.2f} % of this in-domain test set flagged out "
              f"of domain by ours ONNX (stated rate {100 * (1 - QUANTILE):.1f} %)."]
    if invalid_dir is not None:
        lines += ["", "## Invalid contacts (thesis §5.5.4: 1.8 %, 0.33 %, 0.12 %)", "",
                  _invalid(invalid_dir, [TorchRadial(ours, "ours"),
                                         TorchRadial(thesis, "thesis 2-10-1")])]
    lines += ["", f"Generation: beam path (shaft contacts) {gen['beam']:.3g} samples/s, 2×2 "
              f"path (tip loads on the same structure) {gen['matrix']:.3g} samples/s "
              f"(ratio {gen['matrix'] / gen['beam']:.1f})."]
    report = "\n".join(lines)
    (out / "report.md").write_text(report)
    summary = {"ours_onnx": ours_onnx["rows"][-1], "inversion": inv["rows"][-1],
               "spread": spread, "ours_spread": ours_spread, "spread_limit": limit,
               "best_polynomial_rmse": best_poly, "ours_onnx_latency_s": ours_onnx["latency"],
               "inversion_latency_s": inv["latency"], "false_alarm": false_alarm,
               "worst_range_ratio": max(r["ratio"] for r in ours_onnx["rows"][:-1]),
               "n_test": len(d)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plots(results, d, crlb, out)
    return report


def _spread_text(scene) -> str:
    s = scene.device
    if s.none:
        return "none"
    return ", ".join(f"{c.replace('_', ' ')} ±{100 * getattr(s, c):g} %"
                     for c in ("length", "thickness", "modulus", "loss_factor", "tan_delta",
                               "coupling")) + f" ({s.devices} devices per shard)"


def _named(model: OnnxModel, name: str) -> OnnxModel:
    model.name = name
    return model


def _invalid(invalid_dir, models) -> str:
    data = load_shards(invalid_dir)
    lines = ["| method | " + " | ".join(f"d = {1e3 * v:.1f} mm" for v in
                                        np.unique(data["distance"])) + " |",
             "|---|" + "---|" * len(np.unique(data["distance"]))]
    for m in models:
        pred = m.predict(data["ze"], data["ref"])["distance"]
        cells = []
        for v in np.unique(data["distance"]):
            sel = data["distance"] == v
            cells.append(f"{100 * np.mean(np.abs(pred[sel] - v)) / v:.3f} %")
        lines.append(f"| {m.name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _plots(results, d, crlb, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4), constrained_layout=True)
    for r in results:
        ax.scatter(1e6 * r["latency"], 1e6 * r["rows"][-1]["rmse"], label=r["name"])
    ax.set(xscale="log", yscale="log", xlabel="p50 latency at batch 1 (µs)",
           ylabel="RMSE (µm)", title="radial: error against latency")
    ax.legend(fontsize=7)
    fig.savefig(out / "error_vs_latency.png", dpi=120)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(7, 4), constrained_layout=True)
    order = np.argsort(d)
    edges = np.linspace(0, d.max(), 33)
    centres = 0.5 * (edges[1:] + edges[:-1])
    idx = np.digitize(d, edges[1:-1])
    for r in results:
        rms = [np.sqrt(np.mean(r["err"][idx == k] ** 2)) for k in range(len(centres))]
        ax.plot(1e6 * centres, 1e6 * np.array(rms), label=r["name"])
    ax.plot(1e6 * d[order], 1e6 * crlb[order], "k.", ms=1, alpha=0.3, label="CRLB (per sample)")
    ax.set(yscale="log", xlabel="contact distance from the tip d (µm)", ylabel="RMS error (µm)",
           title="radial: error against d")
    ax.legend(fontsize=7)
    fig.savefig(out / "error_vs_d.png", dpi=120)
    plt.close(fig)
