"""``wtml bench texture-rate``: does sampling faster name the sandpaper better? (issue 25 §3)

The asperities' impulses arrive at ``|v|/d``: 4.1–23.6 kHz at the grades' RMS speeds, up to
~33 kHz at the finest grade's peak speed, beside 51.2 kS/s's 25.6 kHz Nyquist. This study
simulates PAIRED held-out and training specimens at two acquisition rates, the texture scene's
(``configs/scenes/texture.yaml``, 51.2 kS/s) and the NI PXI-4461's top rate
(``configs/scenes/texture_pxi.yaml``, 204.8 kS/s): one seed per chunk of specimens, the same
for both scenes, so both rates record the same specimens (law, μ, asperities, grains), the
same nuisance and the same devices; only the noise is drawn anew (per sample, at each rate's
own rms of one density). The band-power peer
(:class:`~wtml.baselines.texture_peers.BandPowerPeer`: the current's band powers over |F1|²
from ~1 kHz to the Nyquist, and the whisk features; gradient boosting) is trained at each
rate on the same training specimens and scored on the same held-out specimens, windows of
``window_s``; a third row restricts it to the bands below 25.6 kHz on the 204.8 kS/s records
(what the bandwidth adds, apart from the records' lesser aliasing). Beside them the amplitude
and every-grain oracles (:func:`wtml.bench.texture.oracles`, which do not depend on the rate).

Accuracy intervals: 95 %, bootstrap over the held-out specimens
(:func:`~wtml.bench.resampling.group_interval`); the rates' difference is paired (the same
windows of the same specimens). Writes ``report.md``, ``summary.json`` and ``rate.png``.
"""

from __future__ import annotations

import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

from wtml.baselines.texture_peers import BandPowerPeer
from wtml.bench.rate_axis import STUDY_TAG
from wtml.bench.resampling import group_interval, span
from wtml.bench.texture import confusion, oracles
from wtml.runtime.texture import windows
from wtml.scenes import load_scene
from wtml.scenes.texture import THESIS_GRADES, TextureScene

SCENES = ("configs/scenes/texture.yaml", "configs/scenes/texture_pxi.yaml")
"""The two scenes compared: the texture scene and its 204.8 kS/s variant."""
PAIRED = ("grade", "grain_m", "mu", "asperity", "friction_law", "viscous", "whisk_v", "whisk_hz",
          "normal_force", "angle", "coupling")
"""The labels and nuisance each pair of records must share (checked, exactly)."""
PAIR = ("P320", "P280")
"""The pair every method confuses."""


def _progress(text: str) -> None:
    print(f"bench texture-rate: {text}", file=sys.stderr, flush=True)


def grade_scores(pred: np.ndarray, grade: np.ndarray, specimen: np.ndarray) -> dict:
    """How well predicted grades ``pred`` ``(n_windows,)`` name the true ``grade``:
    ``accuracy``, its 95 % ``interval`` (bootstrap over the windows' ``specimen``:
    :func:`~wtml.bench.resampling.group_interval`), the ``confusion`` ``(5, 5)`` (rows true)
    and :data:`PAIR`'s two confusions (``p320_as_p280``, ``p280_as_p320``: of each one's
    windows)."""
    correct = (np.asarray(pred) == np.asarray(grade)).astype(float)
    conf = confusion(grade, pred, len(THESIS_GRADES))
    first, second = pair_rates(conf)
    return {"accuracy": float(correct.mean()), "interval": group_interval(correct, specimen),
            "confusion": conf.tolist(), "p320_as_p280": first, "p280_as_p320": second}


def pair_rates(confusion) -> tuple[float, float]:
    """How often :data:`PAIR`'s first grade is read as its second, and the reverse (each of
    that grade's windows), from a confusion ``(5, 5)`` (rows the true grade)."""
    conf = np.asarray(confusion, float)
    a, b = (list(THESIS_GRADES).index(p) for p in PAIR)
    return float(conf[a, b] / conf[a].sum()), float(conf[b, a] / conf[b].sum())


def _scene(path: str, per_grade: int, record_s: float | None) -> TextureScene:
    scene = load_scene(path)
    if not isinstance(scene, TextureScene) or scene.grades != "thesis":
        raise ValueError(f"{path}: a texture scene of the thesis grades is needed")
    drive = scene.drive if record_s is None else dataclasses.replace(scene.drive,
                                                                     record_s=record_s)
    return dataclasses.replace(scene, specimens_per_grade=per_grade, drive=drive)


def check_paired(low: TextureScene, high: TextureScene) -> None:
    """Refuse two scenes that differ in more than the acquisition, the oversampling and the
    modes and mesh (each keeps those below its own Nyquist, converged): the paired draws
    would then not be the same specimens."""
    same = dataclasses.replace(high, name=low.name, acquisition=low.acquisition,
                               oversample=low.oversample, n_modes=low.n_modes,
                               whisker_elements=low.whisker_elements)
    if same != low:
        diff = [f.name for f in dataclasses.fields(low)
                if getattr(same, f.name) != getattr(low, f.name)]
        raise ValueError(f"the two scenes differ in {diff}, not only in the acquisition")
    for scene in (low, high):
        top = scene.transducer().omega_n[-1] / (2 * np.pi)
        if top < scene.acquisition.sample_rate_hz / 2:
            raise ValueError(f"{scene.name}: n_modes: its {scene.n_modes} modes end at "
                             f"{top:.0f} Hz, below its Nyquist "
                             f"({scene.acquisition.sample_rate_hz / 2:g} Hz): the grains ring "
                             "every mode the records hold")


def paired_features(scenes: dict[str, TextureScene], peers: dict[str, tuple[str, BandPowerPeer]],
                    n_specimens: int, seed: tuple[int, ...], window_s: float) -> dict:
    """Simulate ``n_specimens`` specimens (one record each, in chunks of the scenes'
    ``specimens_per_grade`` × 5) at every scene with the same seeds and compute every peer's
    features on their windows.

    Args:
        scenes: label -> scene (their draws must pair: :func:`check_paired`).
        peers: label -> (the label of the scene it reads, the peer).
        n_specimens: how many (rounded up to whole chunks).
        seed: the seed's first words; chunk c draws from ``default_rng([*seed, c])``.
        window_s: the windows' length, s.

    Returns:
        ``features`` (peer label -> ``(n_windows, n_features)``), ``grade`` and ``specimen``
        (the pair's index, the same at every rate) ``(n_windows,)``, ``seconds`` (scene label
        -> simulation wall time, s) and ``records``.
    """
    first = next(iter(scenes.values()))
    per_chunk = 5 * first.specimens_per_grade
    chunks = -(-n_specimens // per_chunk)
    feats = {k: [] for k in peers}
    grade, specimen, seconds = [], [], dict.fromkeys(scenes, 0.0)
    for c in range(chunks):
        records = {}
        for label, scene in scenes.items():
            t0 = time.perf_counter()
            records[label] = scene.simulate(per_chunk, np.random.default_rng([*seed, c]))
            seconds[label] += time.perf_counter() - t0
        ref = records[next(iter(scenes))]
        for label, r in records.items():
            for key in PAIRED:
                if not np.array_equal(r[key], ref[key]):
                    raise RuntimeError(f"{label}: {key} differs from the paired draw's")
        cut = {label: windows(np.stack([r["e"], r["i"]]),
                              int(round(window_s * scenes[label].acquisition.sample_rate_hz)))
               for label, r in records.items()}  # label -> ((2, n_windows, m), owner)
        for name, (label, peer) in peers.items():
            (e, i), owner = cut[label]
            feats[name].append(peer.features(e, i, records[label]["t"][owner]))
        owner = cut[next(iter(scenes))][1]
        grade.append(ref["grade"][owner])
        specimen.append(c * per_chunk + owner)
        _progress(f"chunk {c + 1}/{chunks}: {(c + 1) * per_chunk} specimens, simulated "
                  + ", ".join(f"{k} {v:.0f} s" for k, v in seconds.items()))
    return {"features": {k: np.concatenate(v) for k, v in feats.items()},
            "grade": np.concatenate(grade), "specimen": np.concatenate(specimen),
            "seconds": seconds, "records": chunks * per_chunk}


def run_rate(out: str | Path = "runs/texture/rate", *, scenes: tuple[str, str] = SCENES,
             train_specimens: int = 640, test_specimens: int = 200, window_s: float = 0.25,
             record_s: float | None = None, per_grade: int = 4, oracle_draws: int = 100_000,
             max_iter: int = 300) -> str:
    """The study (module docstring); returns the markdown report (also ``out/report.md``).

    Args:
        out: the folder for ``report.md``, ``summary.json`` and ``rate.png``.
        scenes: the lower and the higher rate's scene YAML.
        train_specimens, test_specimens: specimens (one record each) to train on and to score.
        window_s: the windows' length, s.
        record_s: each record's length, s (None: the scenes').
        per_grade: specimens of each grade per simulated chunk (memory: a 204.8 kS/s chunk of
            20 one-second records: the default study peaks at 1.7 GB).
        oracle_draws: draws of each oracle's prior.
        max_iter: the peers' boosting iterations.
    """
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    low, high = (_scene(p, per_grade, record_s) for p in scenes)
    check_paired(low, high)
    rates = [s.acquisition.sample_rate_hz for s in (low, high)]
    if rates[1] <= rates[0]:
        raise ValueError(f"scenes: the second's rate must be the higher, got {rates}")
    labels = [f"{r / 1e3:g} kS/s" for r in rates]
    pair = dict(zip(labels, (low, high), strict=True))
    cal = low.calibration_hz
    peers = {labels[0]: (labels[0], BandPowerPeer(cal, rates[0], max_iter=max_iter)),
             labels[1]: (labels[1], BandPowerPeer(cal, rates[1], max_iter=max_iter)),
             f"{labels[1]}, bands below {rates[0] / 2e3:g} kHz":
                 (labels[1], BandPowerPeer(cal, rates[1], top_hz=rates[0] / 2,
                                           max_iter=max_iter))}
    _progress(f"training set: {train_specimens} paired specimens")
    train = paired_features(pair, peers, train_specimens, (low.seed, STUDY_TAG, 0), window_s)
    _progress(f"held-out set: {test_specimens} paired specimens")
    test = paired_features(pair, peers, test_specimens, (low.seed, STUDY_TAG, 1), window_s)
    rows, correct = [], {}
    for name, (label, peer) in peers.items():
        t0 = time.perf_counter()
        peer.fit_features(train["features"][name], train["grade"])
        fit_s = time.perf_counter() - t0
        pred = peer.predict_features(test["features"][name])["grade"]
        correct[name] = (pred == test["grade"]).astype(float)
        rows.append({"name": name, "scene": label, "rate_hz": peer.rate,
                     "bands": len(peer.edges) - 1, "top_hz": float(peer.edges[-1]),
                     **grade_scores(pred, test["grade"], test["specimen"]), "fit_s": fit_s})
        _progress(f"{name}: {100 * rows[-1]['accuracy']:.1f} %")
    restricted = list(peers)[2]
    differences = []
    for hi, lo in ((labels[1], labels[0]), (restricted, labels[0]), (labels[1], restricted)):
        gain = correct[hi] - correct[lo]
        differences.append({"name": f"{hi} minus {lo}", "difference": float(gain.mean()),
                            "interval": group_interval(gain, test["specimen"])})
    _progress("the oracles")
    amplitude, grain = oracles(low, oracle_draws)
    gap = grain["accuracy"] - amplitude["accuracy"]
    main = differences[0]
    closed = {"fraction": main["difference"] / gap,
              "interval": [x / gap for x in main["interval"]]}
    cost = {label: {"records": train["records"] + test["records"],
                    "seconds": train["seconds"][label] + test["seconds"][label],
                    "record_s": pair[label].drive.record_s,
                    "lead_s": pair[label].drive.lead_s,
                    "oversample": pair[label].oversample}
            for label in labels}
    for c in cost.values():
        c["s_per_record"] = c["seconds"] / c["records"]
    summary = {"scenes": list(scenes), "rates_hz": rates, "window_s": window_s,
               "train_specimens": train["records"], "test_specimens": test["records"],
               "train_windows": len(train["grade"]), "test_windows": len(test["grade"]),
               "methods": rows, "differences": differences,
               "oracle": amplitude | {"confusion": amplitude["confusion"].tolist()},
               "grain_oracle": grain | {"confusion": grain["confusion"].tolist()},
               "gap_closed": closed, "generation": cost, "max_iter": max_iter}
    report = _report(summary)
    (out / "report.md").write_text(report)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plot(summary, out)
    return report


def pct(x: float) -> str:
    """A fraction as a percentage with one decimal."""
    return f"{100 * x:.1f} %"


def difference_lines(differences: list[dict]) -> list[str]:
    """The paired differences' table (each ``name``, ``difference`` and its ``interval``,
    fractions), with its heading."""
    return ["", "Paired differences (the same held-out windows):", "",
            "| difference | points | 95 % interval |", "|---|---|---|"] + [
        f"| {d['name']} | {100 * d['difference']:+.1f} | {span(d['interval'], signed=True)} |"
        for d in differences]


def _report(s: dict) -> str:
    o, g, closed = s["oracle"], s["grain_oracle"], s["gap_closed"]
    lines = ["# wtml bench texture-rate", "",
             f"The band-power peer trained on {s['train_specimens']} specimens "
             f"({s['train_windows']} windows of {s['window_s']:g} s) and scored on "
             f"{s['test_specimens']} held-out specimens ({s['test_windows']} windows), the same "
             "specimens, nuisance and devices at each rate (paired draws of "
             + " and ".join(f"`{p}`" for p in s["scenes"]) + "). Intervals: 95 %, bootstrap "
             "over the held-out specimens.", "",
             f"| method | bands | top (kHz) | accuracy | 95 % interval | {PAIR[0]} as {PAIR[1]} "
             f"| {PAIR[1]} as {PAIR[0]} |", "|---|---|---|---|---|---|---|"]
    for r in s["methods"]:
        lines.append(f"| band powers, {r['name']} | {r['bands']} | {r['top_hz'] / 1e3:.1f} | "
                     f"{pct(r['accuracy'])} | {span(r['interval'])} | "
                     f"{pct(r['p320_as_p280'])} | {pct(r['p280_as_p320'])} |")
    for label, x in (("amplitude oracle", o), ("every-grain oracle", g)):
        lines.append(f"| {label} ({x['n']} draws of the prior; no rate) | - | - | "
                     f"{pct(x['accuracy'])} | - | " + " | ".join(map(pct, pair_rates(
                         x["confusion"]))) + " |")
    lines += difference_lines(s["differences"])
    lo, hi = closed["interval"]
    lines += ["", f"Of the oracles' gap ({pct(o['accuracy'])} → {pct(g['accuracy'])}), the "
              f"faster rate closes {100 * closed['fraction']:+.0f} % (95 % interval "
              f"{100 * lo:+.0f} to {100 * hi:+.0f} %).", "",
              "| scene | oversample | record (s) + lead-in (s) | records | simulation (s) | "
              "s per record |", "|---|---|---|---|---|---|"]
    for label, c in s["generation"].items():
        lines.append(f"| {label} | {c['oversample']} | {c['record_s']:g} + {c['lead_s']:g} | "
                     f"{c['records']} | {c['seconds']:.0f} | {c['s_per_record']:.3f} |")
    lines += ["", "Simulation wall time on one thread of this machine, both rates in one run.",
              "", "Plot: rate.png."]
    return "\n".join(lines)


def _plot(s: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4.8))
    for r, marker, shift in zip(s["methods"], ("o", "o", "s"), (1.0, 1.0, 1.1), strict=True):
        acc, (low, high) = 100 * r["accuracy"], r["interval"]
        ax.errorbar(shift * r["rate_hz"] / 1e3, acc,
                    yerr=[[acc - 100 * low], [100 * high - acc]], fmt=marker, capsize=4,
                    label=f"band powers, {r['name']}")
    ax.axhline(100 * s["oracle"]["accuracy"], color="k", ls=":", label="amplitude oracle")
    ax.axhline(100 * s["grain_oracle"]["accuracy"], color="k", ls="--",
               label="every-grain oracle")
    rates = np.array(s["rates_hz"]) / 1e3
    ax.set_xscale("log")
    ax.minorticks_off()
    ax.set(xticks=rates, xticklabels=[f"{r:g}" for r in rates],
           xlim=(rates[0] / 1.6, rates[-1] * 1.6), xlabel="sampling rate (kS/s)",
           ylabel="accuracy (%)",
           title=f"{s['test_specimens']} held-out specimens, {s['window_s']:g} s windows")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    fig.savefig(out / "rate.png", dpi=110)
    plt.close(fig)
