"""``wtml bench radial``: every radial method on the nominal device and over the device's
manufacturing spread, in one run.

Thesis decoder (2-10-1 sigmoid on Ze alone) and ours, each in torch and ONNX; the polynomials
in Re and Im of Ze (the thesis's) and of Ze / ref (numpy, and Im Ze / ref as the exported
classical ONNX); the physics inversion
(a converged, damped and bounded solve on the preset's beam model, of Ze corrected by the
reference). Each reads the measurement and the device's free reference. On the first
``max_samples`` of the test shard (10000 by default; the shipped scene: the preset's device):
RMSE, max error and RMSE / CRLB by range of d, p50 latency at batch 1 and throughput at batch
4096. The device-spread table (:func:`run_bench`'s ``spread_*``): the shipped decoder, the
spread-trained one, the thesis decoder, the classical ONNX and the inversion on the nominal
device, over the spread and with each parameter of the spread alone (``spread_samples``
each): RMSE, max error, the share of in-domain answers within 2σ and the share flagged out of
domain; the parameter alone that costs the spread decoder most is what a user must measure
better. Then the invalid-contact variant (thesis §5.5.4) and the generation throughput of the
beam path against the 2×2 path. Writes ``report.md``, ``error_vs_latency.png`` and
``error_vs_d.png``.
"""

from __future__ import annotations

import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from wtml.baselines.radial import BayesRadial, InversionRadial, PolynomialRadial
from wtml.bench.bounds import radial_crlb
from wtml.bench.frontier import Method, Problem, open_graph
from wtml.bench.resampling import statistic_interval
from wtml.bench.timing import latency_p50, throughput
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.decoders.domain import QUANTILE
from wtml.decoders.radial import TorchRadial, load_radial_net
from wtml.physics import ze_from_zm
from wtml.runtime.predict import OnnxModel, load_export

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


def spread_sets(scene, nominal: dict, spread: dict, n_each: int) -> dict[str, dict]:
    """The device-spread table's record sets: ``"nominal device"`` (``nominal``: records of
    the preset's device), ``"spread"`` (``spread``: records over the spread of ``scene``, a
    scene with a device spread), one per parameter of that spread with a nonzero width,
    alone, and, where the whisker has tolerances, ``"spread, whisker measured"``: every
    parameter but the whisker's (``n_each`` fresh records each). The whisker's length and
    bending stiffness set what a contact on its shaft reads (the clamped span's EI/(L - d)³
    and mass) and the free reference hardly shows them, so that row is what a user who
    measures the whisker gets."""
    rng = np.random.default_rng([scene.seed, 10**6 + 2])
    sets = {"nominal device": nominal, "spread": spread}
    widths = scene.spread.widths(scene.device)
    for name, width in widths.items():
        if width:
            sets[f"{name} ±{100 * width:g} % alone"] = scene.simulate(
                n_each, rng, widths=scene.spread.only(name, scene.device))
    if any(w and name.startswith("whisker.") for name, w in widths.items()):
        sets["spread, whisker measured"] = scene.simulate(
            n_each, rng, widths={p: 0.0 if p.startswith("whisker.") else w
                                 for p, w in widths.items()})
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

    def um(x: float) -> str:
        return f"{1e6 * x:.2f}" if x < 1e-3 else f"{1e6 * x:.3g}"

    for name, row in table.items():
        cells = [f"{um(r['rmse'])} / {um(r['max'])}{pct(r['cover'])}{pct(r['flagged'])}"
                 for r in row.values()]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def evaluate_checkpoint(checkpoint: str | Path, data_dir: str | Path, scene,
                        split: dict[str, list[int]], test: dict[str, np.ndarray],
                        where: str) -> str:
    """``wtml evaluate``'s report (markdown) of a radial checkpoint: the decoder (torch) and
    the polynomial in Im Ze (fitted on the ``split``'s training shards of ``data_dir``), RMSE
    (µm) and RMSE / CRLB by range of d on ``test`` (the test shard's arrays, ``where`` naming
    it)."""
    net, _ = load_radial_net(str(checkpoint))
    train = load_shards(data_dir, split["train"])
    d, crlb = test["distance"], radial_crlb(scene, test["distance"], test["stiffness"])
    results = []
    for p in (TorchRadial(net),
              PolynomialRadial("imag").fit(train["ze"], train["ref"], train["distance"])):
        err = p.predict(test["ze"], test["ref"])["distance"] - d
        results.append({"name": p.name, "rows": range_rows(err, d, crlb)})
    return f"RMSE (µm) by range of d and RMSE / CRLB, on {where}\n\n" + format_ranges(results)


def run_bench(data_dir, checkpoint, thesis_checkpoint, model_dir, thesis_model_dir, out, *,
              invalid_dir=None, spread_dir=None, spread_model_dir=None, spread_scene=None,
              threads: int = 2, latency_repeats: int = 2000, throughput_repeats: int = 30,
              max_samples: int = 10000, spread_samples: int = 2000) -> str:
    """Run the radial benchmark (module docstring); returns the report (also written under
    ``out``).

    The device-spread table draws its devices from the scene of ``spread_dir`` (the
    spread-trained decoder's dataset: its test shard is the table's "spread" row) or, where
    that folder does not exist, from the scene file ``spread_scene`` (fresh records); with
    neither, there is no device-spread table. ``spread_model_dir``: the spread-trained
    decoder's export, a column of that table where it exists."""
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
    ze, ref, d, k = (test[key] for key in ("ze", "ref", "distance", "stiffness"))
    crlb = radial_crlb(scene, d, k)
    ours, _ = load_radial_net(str(checkpoint))
    thesis, _ = load_radial_net(str(thesis_checkpoint))
    ours_onnx, classical_onnx = load_export(model_dir, threads=threads)
    methods = [
        TorchRadial(thesis, "thesis 2-10-1 torch"),
        _named(load_export(thesis_model_dir, threads=threads)[0], "thesis 2-10-1 ONNX"),
        TorchRadial(ours, "ours torch"),
        _named(ours_onnx, "ours ONNX"),
        *(PolynomialRadial(part, reference=reference).fit(train["ze"], train["ref"],
                                                          train["distance"])
          for reference in (False, True) for part in ("real", "imag")),
        _named(classical_onnx, "polynomial Im Ze/ref ONNX"),
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
    spread, spread_source = _spread_table(
        scene, test, methods, spread_dir, spread_model_dir, spread_scene, threads, len(d),
        spread_samples)
    gen = generation_throughput(scene)
    best_poly = min(r["rows"][-1]["rmse"] for r in results if r["name"].startswith("polynomial"))
    lines = [
        "# wtml bench radial", "",
        f"Dataset `{data_dir}` (scene `{manifest['scene_hash'][:12]}`), test shard(s) "
        f"{split['test']}, the first {len(d)} of its {n_test} samples; {scene.device.name} device "
        f"(device: {_spread_text(scene)}; beam model) at "
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
    lines += ["", "## RMSE by range of d (µm) and RMSE / CRLB", "", format_ranges(results)]
    spread_summary = {}
    if spread:
        spread_summary = _spread_summary(spread)
        lines += ["", "## Device spread", "", spread_source, "", format_spread(spread), "",
                  *_spread_verdict(spread_summary)]
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
               "spread": spread, **spread_summary,
               "best_polynomial_rmse": best_poly, "ours_onnx_latency_s": ours_onnx["latency"],
               "inversion_latency_s": inv["latency"], "false_alarm": false_alarm,
               "worst_range_ratio": max(r["ratio"] for r in ours_onnx["rows"][:-1]),
               "n_test": len(d)}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plots(results, d, crlb, out)
    return report


NOMINAL_ONNX, SPREAD_ONNX = "ours ONNX", "ours spread ONNX"
"""The device-spread table's names of the shipped (nominal) decoder and the spread-trained
one."""


def _spread_table(scene, nominal: dict, methods: list, spread_dir, spread_model_dir,
                  spread_scene, threads: int, n_spread: int, n_each: int
                  ) -> tuple[dict[str, dict[str, dict]], str]:
    """The device-spread table (``{records: {method: spread_row}}``, empty without a spread
    scene) and the sentence that says where its records come from. Methods: the shipped
    decoder's ONNX, the spread-trained one's where its export exists, the thesis decoder's
    ONNX, the classical ONNX and the physics inversion (on the preset's beam model, of Ze
    corrected by the reference)."""
    if spread_dir is not None and Path(spread_dir).is_dir():
        other = dataset_scene(spread_dir)
        shards = split_shards(read_manifest(spread_dir)["n_shards"], 1, 1)["test"]
        records = load_shards(spread_dir, shards)
        records = {key: records[key][:n_spread] for key in ("ze", "ref", "distance")}
        where = f"the first {n_spread} records of `{spread_dir}`'s test shard(s) {shards}"
    elif spread_scene is not None:
        from wtml.scenes import load_scene

        other = load_scene(spread_scene)
        records = other.simulate(n_spread, np.random.default_rng([other.seed, 10**6 + 3]))
        where = f"{n_spread} fresh records of `{spread_scene}`"
    else:
        return {}, ""
    if other.spread.none or other.device != scene.device \
            or other.excitation.frequencies_hz != scene.excitation.frequencies_hz:
        raise ValueError(f"the device-spread scene ({spread_dir or spread_scene}) must draw "
                         f"devices of the {scene.device.name} device from a spread, at the "
                         f"frequencies {list(scene.excitation.frequencies_hz)} Hz")
    columns = [methods[3]]
    if spread_model_dir is not None and (Path(spread_model_dir) / "model.onnx").is_file():
        columns.append(_named(load_export(spread_model_dir, threads=threads)[0], SPREAD_ONNX))
    columns += [methods[1], methods[8], methods[9]]
    sets = spread_sets(other, nominal, records, n_each)
    table = {name: {m.name: spread_row(m.predict(s["ze"], s["ref"]), s["distance"])
                    for m in columns}
             for name, s in sets.items()}
    source = (f"Devices drawn from the manufacturing spread (relative half-widths of uniform "
              f"tolerance bands): {_spread_text(other)}; each record's free Ze is its "
              f"reference (noise {other.noise.reference_relative:g}). Rows: the nominal "
              f"device (the first table's records), the spread ({where}), each parameter "
              f"alone ({n_each} fresh records each). Per method: RMSE / max error (µm), the "
              f"share of in-domain answers within 2σ (decoders with a std), the share flagged "
              f"out of domain (ONNX graphs). `{NOMINAL_ONNX}` is the shipped decoder, trained "
              f"on the preset's device; `{SPREAD_ONNX}` the one trained over the spread.")
    return table, source


def _spread_summary(spread: dict[str, dict[str, dict]]) -> dict:
    """The summary's device-spread entries: each decoder's row over the spread and on the
    nominal device, and the parameter alone that costs the spread decoder (else the shipped
    one) most."""
    out = {"nominal_spread": spread["spread"][NOMINAL_ONNX]}
    best = SPREAD_ONNX if SPREAD_ONNX in spread["spread"] else NOMINAL_ONNX
    if best == SPREAD_ONNX:
        out["ours_spread"] = spread["spread"][SPREAD_ONNX]
        out["ours_spread_nominal"] = spread["nominal device"][SPREAD_ONNX]
        if "spread, whisker measured" in spread:
            out["ours_spread_whisker"] = spread["spread, whisker measured"][SPREAD_ONNX]
    alone = {name: row[best] for name, row in spread.items() if "alone" in name}
    if alone:
        limit = max(alone, key=lambda name: alone[name]["rmse"])
        out["spread_limit"] = f"{limit.removesuffix(' alone')}: {1e6 * alone[limit]['rmse']:.1f} µm"
    return out


def _spread_verdict(s: dict) -> list[str]:
    """The device-spread table's closing lines."""
    def row(r: dict) -> str:
        cover = "" if np.isnan(r["cover"]) else f", {100 * r['cover']:.0f} % within 2σ"
        return f"{1e6 * r['rmse']:.2f} µm{cover}, {100 * r['flagged']:.1f} % flagged"

    lines = [f"The shipped decoder over the spread: {row(s['nominal_spread'])} (it knows the "
             f"preset's device only; its gate flags other devices)."]
    if "ours_spread" in s:
        o = s["ours_spread"]
        lines.append(f"The spread-trained decoder over the spread: {row(o)} (targets: ≤ 5 µm "
                     f"{_met(o['rmse'] <= 5e-6)}, ≥ 90 % within 2σ "
                     f"{_met(o['cover'] >= 0.9)}); on the nominal device "
                     f"{row(s['ours_spread_nominal'])}"
                     + (f"; over the spread with the whisker measured (its tolerances off) "
                        f"{row(s['ours_spread_whisker'])}" if "ours_spread_whisker" in s
                        else "") + ".")
    if "spread_limit" in s:
        lines.append(f"The parameter that limits it, alone: {s['spread_limit']}: what a user "
                     f"must measure better.")
    return lines


def _met(ok: bool) -> str:
    return "met" if ok else "MISSED"


def _spread_text(scene) -> str:
    s = scene.spread
    if s.none:
        return "the preset's own, no spread"
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


SPEED_TARGET = (50e-6, 1e6)
"""The default decoder's speed on the frontier (issue 25 §2): p50 ≤ 50 µs at batch 1 and
≥ 1e6 samples/s at a batch of 4096."""


def frontier_problem(data_dir: str | Path, model_dir: str | Path, *, threads: int = 2,
                     max_samples: int = 4000, thesis_model_dir: str | Path = "export/radial_thesis"
                     ) -> Problem:
    """The radial task for :mod:`wtml.bench.frontier`: the RMSE of d (µm) on the first
    ``max_samples`` of the test shard, each with its device's free reference; the polynomial
    in Im Ze/ref (numpy, fitted on the training shards, and as ``model_dir``'s ONNX graph),
    the thesis's 2-10-1 decoder (``thesis_model_dir``, where it exists), the physics
    inversion, the Bayes posterior mean (:class:`~wtml.baselines.radial.BayesRadial`, the
    best achievable; left out for a scene with a device spread, which it does not integrate
    over) and the Cramér–Rao bound, as rows."""
    manifest, scene = read_manifest(data_dir), dataset_scene(data_dir)
    split = split_shards(manifest["n_shards"], 1, 1)
    test = load_shards(data_dir, split["test"])
    ze, ref, d, k = (test[key][:max_samples] for key in ("ze", "ref", "distance", "stiffness"))
    train = load_shards(data_dir, split["train"])

    def rms(values):
        return np.sqrt(np.mean(values**2, -1))

    def score(pred: dict) -> tuple[float, float, float]:
        err = 1e6 * (pred["distance"] - d)
        return (float(rms(err)), *statistic_interval(err, rms))

    crlb = 1e6 * radial_crlb(scene, d, k)
    drawn = crlb * np.random.default_rng(0).standard_normal(len(crlb))
    classical = Path(model_dir) / "classical.onnx"
    methods = [
        Method("polynomial Im Ze/ref numpy", "classical", PolynomialRadial("imag").fit(
            train["ze"], train["ref"], train["distance"])),
        Method("polynomial Im Ze/ref ONNX", "classical",
               open_graph(classical, "measurements", threads), classical),
    ]
    thesis = Path(thesis_model_dir) / "model.onnx"
    if thesis.is_file():
        methods.append(Method("thesis 2-10-1 decoder ONNX", "peer",
                              open_graph(thesis, "measurements", threads), thesis,
                              note="the thesis's network on Ze alone"))
    if not any(scene.spread.widths(scene.device).values()) and not scene.spread.posterior:
        methods.append(Method("Bayes posterior mean", "reference", BayesRadial(scene),
                              note="the best achievable under the scene's prior "
                                   "(importance sampling about the MAP)"))
    methods += [
        Method("physics inversion", "classical", InversionRadial(scene),
               note="MAP: damped, bounded Gauss–Newton on the beam model"),
        Method("Cramér–Rao bound", "bound", score=(float(rms(drawn)), *statistic_interval(
            drawn, rms)), note="RMS of one error drawn from each sample's bound"),
    ]
    return Problem(
        "radial", "RMSE of d", "µm", False, "sample", 1.0, (ze, ref), score, "measurements",
        4096, (train["ze"][:512], train["ref"][:512]), methods,
        data=f"`{data_dir}` test shard {split['test']}, {len(d)} samples ({scene.device.name} "
             f"device, noise {scene.noise.ze_relative:g} on Ze)",
        speed_target=SPEED_TARGET)
