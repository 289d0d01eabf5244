"""``wtml bench texture``: every texture method on held-out specimens, in one run.

Methods, each on the test shard's windows (its specimens were never seen in training: every
shard draws its own): our decoder (``model.onnx``), the thesis's cues (``classical.onnx``),
the MiniRocket peer (fitted here on the training shards' windows) and the kinetic-signature
classifier (the hypothesis the thesis refuted). For each: accuracy and confusion matrix,
accuracy by range of each nuisance (robustness), p50 latency at batch 1 and throughput.
Beside them the best achievable from the friction's amplitudes, and from those and a count of
every grain swept (:func:`amplitude_oracle`).
Also: accuracy and grain size against window length (the decoder's graph in torch, the one
exported, whose features take any length, with its domain gate; and for whole multiples of
the trained window, the ONNX graph's windows pooled per record as ``wtml predict`` pools
them), grain size on the unseen FEPA grades (interpolated and extrapolated, with the fraction the
domain gate flags), and an ablation: fresh held-out specimens simulated with both cues, with
asperities only (every grade the middle grade's mean friction) and with mean friction only
(no grains). And the transfer table (:mod:`wtml.bench.texture_transfer`): every method
(MiniRocket unless left out: the main job's small tables) on fresh records of each friction
law alone (those the training mixture leaves out held out), of a
pre-sliding compliance (held out), of each acquisition effect alone and of more viscous
friction with the laws fitted to Table 4.10 again (held out); and the
device-spread table (the same module): every method on fresh records of the nominal device,
of devices drawn from the trained spread and of each class of parameter alone, each record
through its own device's calibrated T. Writes
``report.md``, ``summary.json`` and PNGs.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from wtml.baselines.texture_peers import BandPowerPeer, KineticSignature, MiniRocketPeer
from wtml.bench.frontier import Method, Problem, open_graph
from wtml.bench.rate_axis import SUMMARY as RATE_SUMMARY
from wtml.bench.rate_axis import frontier_lines
from wtml.bench.resampling import group_interval, span
from wtml.bench.texture_transfer import (
    DEVICE_TARGET,
    device_table,
    device_variants,
    device_verdict,
    texture_variants,
    transfer_table,
)
from wtml.bench.texture_transfer import scorer as transfer_scorer
from wtml.bench.timing import latency_p50, throughput
from wtml.bench.transfer import run_variants
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.decoders.checkpoint import load_decoder
from wtml.decoders.texture import WhiskFeatures
from wtml.exporters.texture import decoder_graph
from wtml.memory import release_memory
from wtml.physics.twoport import flat_parts
from wtml.runtime.predict import load_export, rows_per_run
from wtml.runtime.texture import pool, run_windows, windows
from wtml.scenes.texture import (
    FEPA_GRADES,
    NOMINAL_HZ,
    NOMINAL_V,
    THESIS_GRADES,
    nominal_response,
)

WINDOWS_S = (0.05, 0.1, 0.25, 0.5, 1.0)
ORACLE_DRAWS = 100_000
"""Draws of the scene's prior for each oracle's fit, and as many to score it."""
TIMING_BUDGET_S = 1.0
"""Seconds each latency or throughput measurement may run: every method takes milliseconds
per window, so a second holds at least 15 calls at batch 1."""
NUISANCES = {"whisk_v": ("whisking amplitude", "V", 1.0),
             "whisk_hz": ("whisking frequency", "Hz", 1.0),
             "normal_force": ("normal force", "mN", 1e3),
             "angle": ("contact angle", "deg", 180 / np.pi),
             "coupling": ("device coupling / calibrated", "1", 1.0)}
"""Label -> (name, unit, factor from the stored SI value) of the robustness plot."""


def _progress(text: str) -> None:
    print(f"bench texture: {text}", file=sys.stderr, flush=True)


def amplitude_oracle(scene, n: int = 200_000, seed: int = 0, *,
                     sweep_m: np.ndarray | None = None) -> dict:
    """The best accuracy from the friction's two amplitudes, known exactly, under the scene's
    prior: the mean friction ``μ N cosθ`` (what the thesis's cues measure) and the asperities'
    strength ``a N cosθ √(d (1 + cv²))`` (the RMS of their impulse train per √(speed):
    impulses ``a N cosθ d_j`` at the rate ``v/d``, sizes of spread cv). N, θ, and each
    specimen's μ, a and cv are drawn as the scene draws them (μ about the Coulomb line at
    ``friction.viscous``: the mixture's laws and a ``viscous_span``'s c are not drawn; their
    lines give the same in-phase force at the nominal set-up, which this cue stands for); a
    gradient-boosted classifier on ``n`` draws approximates the Bayes rule on what it knows
    (scored on ``n`` more draws).

    With ``sweep_m`` (m, per grade: the path the tip sweeps at 10 V), the observer also sees
    every grain it sweeps, ``sweep · V/10 / d`` of them (V the drive drawn from the scene's
    range): the mean of their spacings (gamma of mean d and spread cv), the mean log of their
    impulses (``log(a N cosθ) + `` the mean log of their own sizes, log-normal about d of
    spread cv) and the specimen's cv itself. The grains swept are the same in every whisk, so
    a longer window sees no more of them. This is the most the grains (the kinetic signature
    and the impulse sizes) can add: a bound on any decoder of these records.

    Returns ``accuracy``, ``confusion`` ``(5, 5)`` (rows true) and ``n``."""
    from sklearn.ensemble import HistGradientBoostingClassifier

    rng = np.random.default_rng(seed)
    f, c = scene.friction, scene.contact
    sizes = np.array(list(scene.grade_table.values()))

    def draw(m: int) -> tuple[np.ndarray, np.ndarray]:
        grade = rng.integers(0, len(sizes), m)
        d = sizes[grade]
        mu = scene.mu(d) + f.mu_spread * rng.standard_normal(m)
        a = scene.asperity(d) * np.exp(f.asperity_spread * rng.standard_normal(m))
        cv = rng.uniform(*f.grain_spread, m)
        press = rng.uniform(*c.normal_force, m) * np.cos(np.deg2rad(rng.uniform(*c.angle_deg,
                                                                                m)))
        cols = [np.log(np.clip(mu, 1e-9, None) * press),
                np.log(a * press * np.sqrt(d * (1 + cv**2)))]
        if sweep_m is not None:
            swept = (np.asarray(sweep_m)[grade] * rng.uniform(*scene.drive.whisk_v, m)
                     / NOMINAL_V)
            count = np.maximum(1, np.round(swept / (d * 1e-6)))
            shape = 1 / cv**2  # a sum of `count` gamma(shape, d/shape) spacings
            own = np.log(d) - cv**2 / 2 + cv * rng.standard_normal(m) / np.sqrt(count)
            cols += [np.log(d * rng.gamma(count * shape) / (count * shape)),
                     np.log(a * press) + own, cv]
        return np.stack(cols, 1), grade

    x, y = draw(n)
    model = HistGradientBoostingClassifier(max_iter=300, random_state=seed).fit(x, y)
    x, y = draw(n)
    pred = model.predict(x)
    return {"accuracy": float(np.mean(pred == y)), "confusion": confusion(y, pred, len(sizes)),
            "n": n}


def oracles(scene, draws: int = ORACLE_DRAWS) -> tuple[dict, dict]:
    """Both bounds of :func:`amplitude_oracle` under ``scene``'s prior on ``draws`` draws: the
    amplitude oracle's answer and the every-grain oracle's (the sweep at 10 V from the nominal
    response's tip speed; its answer also holds ``sweep_mm``, peak to peak per grade, mm)."""
    nominal = nominal_response(scene)
    sweep = 2 * np.abs(nominal["velocity"]) / (2 * np.pi * NOMINAL_HZ)  # peak to peak, m
    return (amplitude_oracle(scene, draws),
            amplitude_oracle(scene, draws, sweep_m=sweep) | {"sweep_mm": (1e3 * sweep).tolist()})


def cached_oracles(scene, draws: int, path: str | Path) -> tuple[dict, dict]:
    """:func:`oracles` of ``scene`` on ``draws`` draws, kept in ``path``: a pure function of
    the scene (two gradient-boosted fits on ``draws`` draws each), so the main job's warm-up
    computes it ahead (:func:`wtml.pipeline.warm_texture`) and the texture bench reads it.
    ``path`` holds its key (the scene's hash, the draws, and the oracles' code: a hash of
    their source and scikit-learn's version) and both answers (strict JSON); one of another
    key, or whose answers are not valid (:func:`_oracle_answers`), is computed again and
    replaced. Holds ``path`` + ``.lock`` meanwhile: a bench that gets there first waits for
    the warm-up's answer instead of computing its own beside it."""
    from wtml.files import FileError, atomic_write, locked, read_json

    path, key = Path(path), oracle_key(scene, draws)
    with locked(path.with_name(path.name + ".lock")):
        try:
            kept = read_json(path, what="oracles file") if path.exists() else None
        except FileError:
            kept = None
        answers = _oracle_answers(kept, key, len(scene.grade_table))
        if answers is not None:
            return answers
        oracle, grain = oracles(scene, draws)
        atomic_write(path, json.dumps(key | {"oracle": _listed(oracle),
                                             "grain_oracle": _listed(grain)}).encode())
        return oracle, grain


def oracle_key(scene, draws: int) -> dict:
    """What :func:`cached_oracles`' answers are a function of: the scene's hash, the draws,
    the oracles' code (sha256 of the source of :func:`amplitude_oracle`, :func:`oracles` and
    :func:`~wtml.scenes.texture.nominal_response`) and scikit-learn's version."""
    import hashlib
    import inspect

    import sklearn

    from wtml.scenes import config_hash

    code = "".join(inspect.getsource(f) for f in (amplitude_oracle, oracles, nominal_response))
    return {"scene_hash": config_hash(scene), "draws": int(draws),
            "code": hashlib.sha256(code.encode()).hexdigest(), "sklearn": sklearn.__version__}


def _listed(answer: dict) -> dict:
    """An oracle's answer as JSON holds it: its confusion as lists."""
    return answer | {"confusion": np.asarray(answer["confusion"]).tolist()}


def _oracle_answers(kept, key: dict, k: int) -> tuple[dict, dict] | None:
    """Both oracles' answers from a :func:`cached_oracles` file's contents ``kept`` if it is
    of ``key`` and each answer is what :func:`amplitude_oracle` gives (a ``(k, k)``
    confusion of integer counts summing to ``n`` = the key's draws, the accuracy its trace
    over ``n``; the every-grain oracle's ``sweep_mm``, k positive numbers), rebuilt from
    those checked values alone; else None."""
    def count(x) -> bool:
        return type(x) is int and x >= 0

    if not isinstance(kept, dict) or any(kept.get(name) != value for name, value in key.items()):
        return None
    answers = []
    for name in ("oracle", "grain_oracle"):
        answer = kept.get(name)
        if not isinstance(answer, dict):
            return None
        table, n, accuracy = answer.get("confusion"), answer.get("n"), answer.get("accuracy")
        if not (isinstance(table, list) and len(table) == k and all(
                isinstance(row, list) and len(row) == k and all(map(count, row))
                for row in table)):
            return None
        table = np.array(table, dtype=np.int64)
        if not (n == key["draws"] and count(n) and table.sum() == n and type(accuracy) is float
                and accuracy == float(np.trace(table) / n)):
            return None
        rebuilt = {"accuracy": accuracy, "confusion": table, "n": n}
        if name == "grain_oracle":
            sweep = answer.get("sweep_mm")
            if not (isinstance(sweep, list) and len(sweep) == k and all(
                    type(x) is float and 0 < x < 1e3 for x in sweep)):
                return None
            rebuilt["sweep_mm"] = sweep
        answers.append(rebuilt)
    return answers[0], answers[1]


def confusion(true: np.ndarray, pred: np.ndarray, k: int) -> np.ndarray:
    """Counts ``(k, k)``, rows the true class."""
    out = np.zeros((k, k), int)
    np.add.at(out, (np.asarray(true, int), np.asarray(pred, int)), 1)
    return out


class _Timed:
    """A method behind the timing helpers' ``predict(x)``, with x a :class:`_Batch`."""

    def __init__(self, fn) -> None:
        self.fn = fn

    def predict(self, x: _Batch):
        return self.fn(x.e, x.i, x.t)


class _Batch:
    """Windows e, i ``(n, window)`` and their calibrated T ``(n, K, 2, 2)`` as one argument;
    its length is n."""

    def __init__(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> None:
        self.e, self.i, self.t = e, i, t

    def __len__(self) -> int:
        return len(self.e)


def _onnx(model):
    def run(e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        out = run_windows(model, e, i, t)
        return {"grade": np.argmax(out["probabilities"], 1), "grain": out["grain"],
                "in_domain": out["in_domain"]}
    return run


def _cut(data: dict, seconds: float, rate: float) -> tuple[np.ndarray, ...]:
    """Whole windows of ``seconds``: e, i ``(n_windows, window)`` (a copy, of the records'
    dtype: float32 from shards), each one's record and its record's calibrated T
    ``(n_windows, K, 2, 2)``."""
    cut, owner = windows(np.stack([data["e"], data["i"]]), int(round(seconds * rate)))
    return cut[0], cut[1], owner, data["t"][owner]


def _training_windows(data_dir, split: dict, window_s: float, rate: float
                      ) -> tuple[np.ndarray, ...]:
    """The training shards' whole windows as MiniRocket reads them, ``(n, 2, window)``
    float32 (e then i: the precision MiniRocket and the whisk features compute in; the main
    job's 1280 windows take 131 MB), their records' calibrated T ``(n, K, 2, 2)`` and grades
    ``(n,)``. Read a shard at a time: at most one shard's float64 records beside them."""
    window = int(round(window_s * rate))
    records = {s["index"]: s["count"] for s in read_manifest(data_dir)["shards"]}
    total = sum(records[k] for k in split["train"])
    x = t = grade = None
    row = 0
    for k in split["train"]:
        shard = load_shards(data_dir, [k])
        cut, owner = windows(np.stack([shard["e"], shard["i"]]), window)
        if x is None:
            n = total * (len(owner) // records[k])
            x = np.empty((n, 2, window), np.float32)
            t = np.empty((n, *shard["t"].shape[1:]), shard["t"].dtype)
            grade = np.empty(n, shard["grade"].dtype)
        rows = slice(row, row + len(owner))
        x[rows] = cut.transpose(1, 0, 2)
        t[rows], grade[rows] = shard["t"][owner], shard["grade"][owner]
        row += len(owner)
    return x, t, grade


def _peers(scene, data_dir, split: dict, window_s: float, kernels: int
           ) -> tuple[MiniRocketPeer, BandPowerPeer, float, int]:
    """The peers fitted on the training shards' windows (:func:`_training_windows`): the
    band-power peer, MiniRocket with ``kernels`` kernels, MiniRocket's fitting time (s) and
    the number of training windows. The windows are freed once MiniRocket has transformed
    them, before its ridge (the fit's largest step: 0.31 GB beside them in the main job)."""
    x, t, grade = _training_windows(data_dir, split, window_s, scene.acquisition.sample_rate_hz)
    n = len(x)
    _progress(f"fitting the band-power peer on {n} training windows")
    bands = BandPowerPeer(scene.calibration_hz, scene.acquisition.sample_rate_hz).fit(
        x[:, 0], x[:, 1], t, grade)
    _progress(f"fitting MiniRocket ({kernels} kernels) on {n} training windows")
    start = time.perf_counter()
    peer = MiniRocketPeer(kernels)
    features = peer.fit_transform_stacked(x)
    del x, t
    peer.fit_features(features, grade)
    fit_s = time.perf_counter() - start
    del features
    release_memory()  # the fit's transforms and ridge: freed but kept by the heap
    return peer, bands, fit_s, n


def _grain_errors(pred: np.ndarray, true: np.ndarray) -> dict[str, float]:
    return {"rmse_um": float(np.sqrt(np.mean((pred - true) ** 2)) * 1e6),
            "rms_pct": float(100 * np.sqrt(np.mean((pred / true - 1) ** 2)))}


def run_bench(data_dir: str | Path, fepa_dir: str | Path, checkpoint: str | Path,
              model_dir: str | Path, out: str | Path, *, peer_kernels: int = 10000,
              ablation_records: int = 40, oracle_draws: int = ORACLE_DRAWS,
              transfer_records: int = 24, device_records: int = 24,
              oracle_file: str | Path | None = None, fresh_minirocket: bool = True) -> str:
    """The whole bench; returns the markdown report (also written to ``out/report.md``).
    ``device_records``: fresh records per row of the device-spread table; ``oracle_file``:
    where the oracles are kept (:func:`cached_oracles`; None: computed here);
    ``fresh_minirocket`` False: MiniRocket on the test shard only, not on the transfer and
    device rows (there it takes twice the other methods' time together: ~35 s of the main
    job's critical lane, on rows of 4 and 16 records that cannot rank it)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene = dataset_scene(data_dir)
    rate = scene.acquisition.sample_rate_hz
    split = split_shards(read_manifest(data_dir)["n_shards"], 1, 1)
    decoder, classical = load_export(model_dir)
    window_s = json.loads(decoder.metadata["window_s"])
    peer, bands, peer_fit_s, n_train_windows = _peers(scene, data_dir, split, window_s,
                                                      peer_kernels)
    test = load_shards(data_dir, split["test"])  # after the peers' fit, the bench's peak
    e, i, owner, t = _cut(test, window_s, rate)
    truth = test["grade"][owner]
    sizes = np.array(list(THESIS_GRADES.values())) * 1e-6
    features = WhiskFeatures(scene.calibration_hz, rate)
    graphs = {"decoder (ONNX)": _onnx(decoder), "thesis cues (ONNX)": _onnx(classical)}
    methods = dict(graphs)
    methods[peer.name] = peer.predict
    methods[bands.name] = bands.predict
    kinetic = KineticSignature(features, sizes, rate)
    methods[kinetic.name] = kinetic.predict

    _progress(f"{len(methods)} methods on {len(e)} held-out windows of {window_s:g} s")
    specimen = test["specimen"][owner]
    results, correct = [], {}
    for name, run in methods.items():
        pred = run(e, i, t)
        timed = _Timed(run)
        correct[name] = (pred["grade"] == truth).astype(float)
        row = {"name": name, "accuracy": float(np.mean(correct[name])),
               "interval": group_interval(correct[name], specimen),
               "confusion": confusion(truth, pred["grade"], 5).tolist(),
               "latency_s": latency_p50(timed, _Batch(e[:1], i[:1], t[:1]), 50,
                                        TIMING_BUDGET_S),
               "throughput": throughput(timed, _Batch(e[:64], i[:64], t[:64]), 5,
                                        TIMING_BUDGET_S),
               "robustness": _robustness(test, owner, pred["grade"] == truth)}
        if "in_domain" in pred:
            row["flagged"] = float(1 - np.mean(pred["in_domain"]))
        results.append(row)
    versus_peer, versus_bands = ({"name": name, "difference": float(gain.mean()),
                                  "interval": group_interval(gain, specimen)}
                                 for name in (peer.name, bands.name)
                                 for gain in [correct["decoder (ONNX)"] - correct[name]])
    _progress("the oracles")
    oracle, grain_oracle = (oracles(scene, oracle_draws) if oracle_file is None
                            else cached_oracles(scene, oracle_draws, oracle_file))
    _progress("accuracy against window length")
    by_window, parity = _by_window(test, export_in_torch(checkpoint, decoder), decoder,
                                   window_s, rate)
    _progress("unseen FEPA grades")
    fepa = load_shards(fepa_dir, list(range(read_manifest(fepa_dir)["n_shards"])))
    unseen = _unseen(fepa, graphs | {kinetic.name: kinetic.predict}, window_s, rate)
    _progress(f"ablation on {ablation_records} fresh held-out records per variant")
    ablation = _ablation(scene, graphs, window_s, ablation_records)
    fresh = transfer_scorer({k: run for k, run in methods.items()
                             if fresh_minirocket or k != peer.name},
                            lambda r: _windows(r, window_s, rate))
    transfer = run_variants(texture_variants(scene), transfer_records, scene.seed, fresh,
                            _progress)
    spread = run_variants(device_variants(scene), device_records, scene.seed, fresh, _progress,
                          paired=True)
    summary = {"task": "texture", "n_test_records": len(test["grade"]),
               "n_test_specimens": len(np.unique(specimen)),
               "n_test_windows": len(truth), "window_s": window_s,
               "n_train_windows": n_train_windows, "peer_fit_s": peer_fit_s,
               "onnx_torch_max_diff": parity,
               "methods": results, "decoder_minus_peer": versus_peer,
               "decoder_minus_bands": versus_bands,
               "oracle": _listed(oracle), "grain_oracle": _listed(grain_oracle),
               "by_window": by_window, "unseen": unseen, "ablation": ablation,
               "transfer": transfer, "device_spread": spread,
               "fresh_minirocket": fresh_minirocket,
               "device_verdict": device_verdict(spread)}
    report = _report(summary)
    (out / "report.md").write_text(report)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plots(summary, out)
    return report


def _robustness(test: dict, owner: np.ndarray, correct: np.ndarray) -> dict:
    """Accuracy in quartiles of each nuisance: ``{label: {"edges": (5,), "accuracy": (4,)}}``
    (edges in the plot's units)."""
    rows = {}
    for key, (_, _, factor) in NUISANCES.items():
        x = test[key][owner] * factor
        edges = np.quantile(x, np.linspace(0, 1, 5))
        k = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, 3)
        rows[key] = {"edges": edges.tolist(),
                     "accuracy": [float(correct[k == b].mean()) for b in range(4)]}
    return rows


def _torch(graph):
    """The torch graph on windows, :data:`~wtml.runtime.predict.RUN_BYTES` of input at a time
    (as the ONNX runtime batches: at once, 80 one-second windows' intermediates took 0.5 GB),
    in float32 as the graph computes, whatever the windows' dtype."""
    @torch.no_grad()
    def run(e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        step = rows_per_run(8 * e.shape[1])
        parts = [graph(*(torch.tensor(x, dtype=torch.float32) for x in
                         (e[k:k + step], i[k:k + step], *flat_parts(t[k:k + step]))))
                 for k in range(0, len(e), step)]
        grain, prob, inside = (torch.cat([p[j] for p in parts]) for j in (0, 2, 3))
        return {"grade": prob.argmax(1).numpy(), "grain": grain.double().numpy(),
                "in_domain": inside.numpy(), "probabilities": prob.double().numpy()}
    return run


def export_in_torch(checkpoint: str | Path, model) -> torch.nn.Module:
    """The export's decoder graph in torch, at any window length: the checkpoint's net and
    gate with the export's recalibration (``model.uncertainty``), built as
    :func:`wtml.exporters.texture.export_texture` built ``model.onnx``
    (:func:`~wtml.exporters.texture.decoder_graph`)."""
    return decoder_graph(load_decoder(checkpoint), tuple(json.loads(model.metadata["outputs"])),
                         model.uncertainty)


def _by_window(test: dict, graph, onnx_model, window_s: float, rate: float
               ) -> tuple[list[dict], float]:
    """Rows per window length: the decoder's graph in torch on windows of that length, and
    the ONNX graph's trained windows pooled per record where the length is a multiple of
    them; and the largest difference of the two graphs' probabilities on trained windows."""
    rows = []
    for seconds in WINDOWS_S:
        e, i, owner, t = _cut(test, seconds, rate)
        runs = {"decoder graph (torch)": _torch(graph)}
        per = seconds / window_s
        if per >= 1 and abs(per - round(per)) < 1e-9:
            runs[f"decoder (ONNX), {window_s:g} s windows pooled"] = _pooled(
                onnx_model, window_s, rate)
        for name, run in runs.items():
            pred = run(e, i, t)
            rows.append({"window_s": seconds, "name": name, "n": len(owner),
                         "accuracy": float(np.mean(pred["grade"] == test["grade"][owner])),
                         "flagged": float(1 - np.mean(pred["in_domain"])),
                         "latency_s": latency_p50(_Timed(run), _Batch(e[:1], i[:1], t[:1]), 30),
                         **_grain_errors(pred["grain"], test["grain_m"][owner])})
    e, i, _, t = _cut(test, window_s, rate)
    diff = np.abs(_torch(graph)(e, i, t)["probabilities"]
                  - run_windows(onnx_model, e, i, t)["probabilities"]).max()
    return rows, float(diff)


def _pooled(model, window_s: float, rate: float):
    """Longer windows as ``wtml predict`` answers them: the trained windows' mean
    log-probabilities and mean ln grain, in domain if all of them are."""
    n = int(round(window_s * rate))

    def run(e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
        cut, owner = windows(np.stack([e, i]), n)
        p = pool(run_windows(model, cut[0], cut[1], t[owner]), owner, len(e))
        return {"grade": p["probabilities"].argmax(1), "grain": p["grain"],
                "in_domain": p["in_domain"]}
    return run


def _unseen(fepa: dict, methods: dict, window_s: float, rate: float) -> dict:
    """Grain size on the unseen grades, per grade and pooled: interpolated (inside the
    thesis's 15.3-52.2 µm) and extrapolated."""
    e, i, owner, t = _cut(fepa, window_s, rate)
    true = fepa["grain_m"][owner]
    lo, hi = min(THESIS_GRADES.values()) * 1e-6, max(THESIS_GRADES.values()) * 1e-6
    inside = (true >= lo) & (true <= hi)
    out = {"grades": [], "pooled": []}
    preds = {name: run(e, i, t) for name, run in methods.items()}
    for grade, d_um in sorted(FEPA_GRADES.items(), key=lambda kv: kv[1]):
        sel = np.isclose(true, d_um * 1e-6)
        row = {"grade": grade, "d_um": d_um, "n": int(sel.sum())}
        for name, pred in preds.items():
            g = pred["grain"][sel]
            row[name] = {"median_um": float(np.median(g) * 1e6), **_grain_errors(g, true[sel]),
                         "flagged": float(1 - np.mean(pred["in_domain"][sel]))
                         if "in_domain" in pred else None}
        out["grades"].append(row)
    for name, pred in preds.items():
        for label, sel in (("interpolated", inside), ("extrapolated", ~inside)):
            row = {"name": name, "range": label, "n": int(sel.sum()),
                   **_grain_errors(pred["grain"][sel], true[sel])}
            if "in_domain" in pred:
                row["flagged"] = float(1 - np.mean(pred["in_domain"][sel]))
                kept = sel & pred["in_domain"]
                row["unflagged_rms_pct"] = (_grain_errors(pred["grain"][kept], true[kept])
                                            ["rms_pct"] if kept.any() else None)
            out["pooled"].append(row)
    return out


def _windows(records: dict, window_s: float, rate: float) -> tuple[np.ndarray, ...]:
    """Records cut into windows: ``(e, i, t, grade, specimen)`` of each window."""
    e, i, owner, t = _cut(records, window_s, rate)
    return e, i, t, records["grade"][owner], records["specimen"][owner]


def _ablation(scene, methods: dict, window_s: float, n: int) -> list[dict]:
    """The methods on fresh held-out specimens, one per record (one seed: the same specimens
    and nuisance in every variant) with both cues, asperities only and mean friction only."""
    rows = []
    variants = (("both cues", {}), ("asperities only", {"mean_friction": False}),
                ("mean friction only", {"asperities": False}))
    for label, kwargs in variants:
        data = scene.simulate_independent(n, np.random.default_rng([scene.seed, 2**20 + 3]),
                                          **kwargs)
        e, i, owner, t = _cut(data, window_s, scene.acquisition.sample_rate_hz)
        row = {"variant": label}
        for name, run in methods.items():
            pred = run(e, i, t)
            row[name] = float(np.mean(pred["grade"] == data["grade"][owner]))
        rows.append(row)
    return rows


def _pct(x: float) -> str:
    return f"{100 * x:.1f} %"


def _report(s: dict) -> str:
    names = list(THESIS_GRADES)
    lines = ["# wtml bench texture", "",
             f"Held-out specimens: the test shard, {s['n_test_records']} records of "
             f"{s['n_test_specimens']} specimens never seen in training, cut into "
             f"{s['n_test_windows']} windows of {s['window_s']:g} s. Accuracy intervals: 95 %, "
             "bootstrap over the specimens (their windows share one friction and one set of "
             f"grains). MiniRocket fitted here on {s['n_train_windows']} training "
             f"windows ({s['peer_fit_s']:.0f} s). Latency: p50 of one window at batch 1; "
             "throughput: windows per second at batch 64. The decoder's ONNX graph and its "
             f"torch graph differ by at most {s['onnx_torch_max_diff']:.1e} in probability "
             "on these windows.", "",
             "| method | accuracy | 95 % interval | flagged | p50 latency | throughput |",
             "|---|---|---|---|---|---|"]
    for r in s["methods"]:
        flag = _pct(r["flagged"]) if "flagged" in r else "-"
        lines.append(f"| {r['name']} | {_pct(r['accuracy'])} | {span(r['interval'])} | "
                     f"{flag} | {1e3 * r['latency_s']:.2f} ms | {r['throughput']:.3g} /s |")
    o, c, gain = s["oracle"], s["grain_oracle"], s["decoder_minus_peer"]
    lines += [f"| amplitude oracle (μN cosθ and the asperities' strength, exact; "
              f"{o['n']} draws of the prior) | {_pct(o['accuracy'])} | - | - | - | - |",
              f"| every-grain oracle (also the spacing and impulse of every grain swept) "
              f"| {_pct(c['accuracy'])} | - | - | - | - |", "",
              *(f"Decoder minus {g['name']} on the same windows: {100 * g['difference']:+.1f} "
                f"points (95 % interval {span(g['interval'], signed=True)}, paired over the "
                "specimens)." for g in (gain, s.get("decoder_minus_bands")) if g), "",
              "The oracles know exactly what the friction carries under the scene's prior; "
              "the every-grain oracle also sees each grain the tip sweeps (peak to peak at "
              "10 V: " + ", ".join(f"{x:.2f}" for x in c["sweep_mm"]) + " mm), its spacing "
              "and its impulse: the most the grains can add, a ceiling for any method on these "
              "records. The realised spacings and sizes of those few dozen grains stray from "
              "their grade's d, so even it cannot name every specimen.", "",
              "Confusion matrices (rows true, columns predicted; " + ", ".join(names) + "):", ""]
    fractions = [{"name": f"{label} (fractions)",
                  "confusion": np.round(np.array(x["confusion"])
                                        / np.sum(x["confusion"], 1, keepdims=True),
                                        3).tolist()}
                 for label, x in (("amplitude oracle", o), ("every-grain oracle", c))]
    for r in s["methods"] + fractions:
        lines += [f"**{r['name']}**", "", "| true \\ predicted | " + " | ".join(names) + " |",
                  "|---" * (len(names) + 1) + "|"]
        for k, row in enumerate(r["confusion"]):
            lines.append(f"| {names[k]} | " + " | ".join(str(v) for v in row) + " |")
        lines.append("")
    lines += ["## Window length", "",
              "| window | method | windows | accuracy | grain RMS | flagged | p50 latency |",
              "|---|---|---|---|---|---|---|"]
    for r in s["by_window"]:
        lines.append(f"| {r['window_s']:g} s | {r['name']} | {r['n']} | {_pct(r['accuracy'])} "
                     f"| {r['rms_pct']:.1f} % | {_pct(r['flagged'])} | "
                     f"{1e3 * r['latency_s']:.2f} ms |")
    lines += ["", "## Grain size on unseen FEPA grades", "",
              "| method | grades | windows | RMSE | RMS | flagged | RMS of the unflagged |",
              "|---|---|---|---|---|---|---|"]
    for r in s["unseen"]["pooled"]:
        flag = _pct(r["flagged"]) if "flagged" in r else "-"
        kept = r.get("unflagged_rms_pct")
        lines.append(f"| {r['name']} | {r['range']} | {r['n']} | {r['rmse_um']:.2f} µm | "
                     f"{r['rms_pct']:.1f} % | {flag} | "
                     f"{'-' if kept is None else f'{kept:.1f} %'} |")
    methods = [k for k in s["unseen"]["grades"][0] if k not in ("grade", "d_um", "n")]
    lines += ["", "Per grade, median prediction (µm) and RMS error:", "",
              "| grade | d (µm) | " + " | ".join(methods) + " |",
              "|---" * (len(methods) + 2) + "|"]
    for r in s["unseen"]["grades"]:
        lines.append(f"| {r['grade']} | {r['d_um']:g} | " + " | ".join(
            f"{r[m]['median_um']:.1f} ({r[m]['rms_pct']:.0f} %)" for m in methods) + " |")
    abl = s["ablation"]
    cols = [k for k in abl[0] if k != "variant"]
    lines += ["", "## Ablation: which cue the methods read", "",
              "Fresh held-out specimens, the same specimens and nuisance in each variant. "
              "*Asperities only*: every grade has the middle grade's mean friction; *mean "
              "friction only*: no grains.", "",
              "| variant | " + " | ".join(cols) + " |", "|---" * (len(cols) + 1) + "|"]
    for r in abl:
        lines.append(f"| {r['variant']} | " + " | ".join(_pct(r[c]) for c in cols) + " |")
    lines += ["", "## Transfer: held-out physics", "",
              "Fresh held-out specimens per row: the trained scene, each friction law alone "
              "(a law the training mixture leaves out is held out), a pre-sliding compliance "
              "(each specimen's own v_r, sharper reversals than trained: held out), an ideal "
              "acquisition, each acquisition effect alone, and 2e-4 N·s/m more viscous "
              "friction with every law's μ(d) fitted to Table 4.10 again (held out: the "
              "thesis's numbers cannot tell it from the trained law). Window accuracy (and "
              "the share the domain gate flags)"
              + ("." if s["fresh_minirocket"] else "; MiniRocket on the test shard only "
                 "(here it would take twice the other methods' time together)."),
              ""]
    lines += transfer_table(s["transfer"])
    v = s["device_verdict"]
    lines += ["", "## Device spread", "",
              "Fresh held-out specimens per row, the same specimens and nuisance in every row "
              "(paired): the nominal device, devices drawn from the trained spread (uniform in "
              "± the half-widths of the scene's `device` block), each class of parameter "
              "and each named parameter alone at its width, then devices off the spread (over "
              "it): a whisker 2 % longer and shorter, the beam with 8 whisker elements. Each "
              "record goes through its own device's calibrated T, "
              "the user's calibration. Window accuracy (95 % interval over the specimens) and "
              "the share the domain gate flags; the last column is the decoder's error rate "
              f"over the nominal row's (target over the spread ≤ {DEVICE_TARGET:g}×: "
              f"{'met' if v['met'] else 'MISSED'}; the class or parameter that costs most alone: "
              f"{v['limit']})" + ("." if s["fresh_minirocket"] else "; MiniRocket on the test "
                                 "shard only, as in the transfer table."), ""]
    lines += device_table(s["device_spread"])
    lines += ["", "## Robustness: accuracy by quartile of each nuisance", ""]
    for key, (label, unit, _) in NUISANCES.items():
        edges = s["methods"][0]["robustness"][key]["edges"]
        bins = [f"{a:.3g}-{b:.3g}" for a, b in zip(edges[:-1], edges[1:], strict=True)]
        lines += [f"**{label} ({unit})**", "", "| method | " + " | ".join(bins) + " |",
                  "|---" * (len(bins) + 1) + "|"]
        for r in s["methods"]:
            lines.append(f"| {r['name']} | " + " | ".join(
                _pct(a) for a in r["robustness"][key]["accuracy"]) + " |")
        lines.append("")
    lines += ["Plots: confusion.png, window.png, robustness.png, unseen.png."]
    return "\n".join(lines)


def _plots(s: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(THESIS_GRADES)
    mats = [(r["name"], np.array(r["confusion"], float)) for r in s["methods"]]
    mats.append(("amplitude oracle", np.array(s["oracle"]["confusion"], float)))
    fig, axes = plt.subplots(1, len(mats), figsize=(3.2 * len(mats), 3.4))
    for ax, (name, m) in zip(axes, mats, strict=True):
        frac = m / m.sum(1, keepdims=True)
        ax.imshow(frac, vmin=0, vmax=1, cmap="Blues")
        for (r, c), v in np.ndenumerate(frac):
            ax.text(c, r, f"{v:.2f}", ha="center", va="center", fontsize=7,
                    color="white" if v > 0.6 else "black")
        ax.set_xticks(range(5), names, rotation=90, fontsize=7)
        ax.set_yticks(range(5), names, fontsize=7)
        ax.set_title(f"{name}\n{100 * np.trace(m) / m.sum():.1f} %", fontsize=8)
    fig.tight_layout()
    fig.savefig(out / "confusion.png", dpi=110)
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9, 3.6))
    for name in dict.fromkeys(r["name"] for r in s["by_window"]):
        rows = [r for r in s["by_window"] if r["name"] == name]
        w = [r["window_s"] for r in rows]
        a1.plot(w, [100 * r["accuracy"] for r in rows], "o-", label=name)
        a2.plot([1e3 * r["latency_s"] for r in rows], [100 * r["accuracy"] for r in rows],
                "o-", label=name)
    a1.axhline(100 * s["oracle"]["accuracy"], color="k", ls=":", label="amplitude oracle")
    a1.axhline(100 * s["grain_oracle"]["accuracy"], color="k", ls="--",
               label="every-grain oracle")
    a1.set(xscale="log", xlabel="window (s)", ylabel="accuracy (%)", title="held-out specimens")
    a2.set(xscale="log", xlabel="p50 latency per window (ms)", ylabel="accuracy (%)",
           title="speed against accuracy")
    a1.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "window.png", dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, len(NUISANCES), figsize=(3.2 * len(NUISANCES), 3.2),
                             sharey=True)
    for ax, (key, (label, unit, _)) in zip(axes, NUISANCES.items(), strict=True):
        for r in s["methods"]:
            edges = np.array(r["robustness"][key]["edges"])
            ax.plot(0.5 * (edges[:-1] + edges[1:]),
                    [100 * a for a in r["robustness"][key]["accuracy"]], "o-", label=r["name"])
        ax.set(xlabel=f"{label} ({unit})", ylim=(0, 102))
    axes[0].set_ylabel("accuracy (%)")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(out / "robustness.png", dpi=110)
    plt.close(fig)

    fig, ax = plt.subplots(figsize=(5, 4))
    grades = s["unseen"]["grades"]
    d = [r["d_um"] for r in grades]
    methods = [k for k in grades[0] if k not in ("grade", "d_um", "n")]
    for m in methods:
        ax.plot(d, [r[m]["median_um"] for r in grades], "o", label=m)
    ax.plot([5, 90], [5, 90], "k:", lw=1)
    lo, hi = min(THESIS_GRADES.values()), max(THESIS_GRADES.values())
    ax.axvspan(lo, hi, color="0.9", label="trained grades' range")
    ax.set(xscale="log", yscale="log", xlabel="true mean grain size (µm)",
           ylabel="median predicted (µm)", title="unseen FEPA grades")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "unseen.png", dpi=110)
    plt.close(fig)


class _Windows:
    """A window classifier's ``run(e, i, t)`` (or ``predict``) behind the frontier's
    predictor interface."""

    def __init__(self, name: str, run) -> None:
        self.name, self.run = name, run

    def predict(self, e: np.ndarray, i: np.ndarray, t: np.ndarray) -> dict:
        return self.run(e, i, t)


def frontier_problem(data_dir: str | Path, model_dir: str | Path, *, threads: int = 2,
                     peer_kernels: int = 10000, oracle_draws: int = ORACLE_DRAWS,
                     rate_study: str | Path = RATE_SUMMARY) -> Problem:
    """The texture task for :mod:`wtml.bench.frontier`: accuracy (%) on the test shard's
    windows of the exported window length (its specimens never seen in training; the
    interval by resampling specimens), costs per second of signal. The thesis's cues
    (``model_dir``'s classical graph), MiniRocket and the band-power peer (both fitted here on
    the training shards' windows), the kinetic signature, and the amplitude and every-grain
    oracles (the best achievable from what they know; :func:`amplitude_oracle`), as rows;
    and the sampling rate as an axis, from the ``wtml bench texture-rate`` study at
    ``rate_study`` (:func:`wtml.bench.rate_axis.frontier_lines`)."""
    scene = dataset_scene(data_dir)
    rate = scene.acquisition.sample_rate_hz
    split = split_shards(read_manifest(data_dir)["n_shards"], 1, 1)
    test = load_shards(data_dir, split["test"])
    classical = Path(model_dir) / "classical.onnx"
    window_s = json.loads(load_export(model_dir)[0].metadata["window_s"])
    e, i, owner, t = _cut(test, window_s, rate)
    truth, specimen = test["grade"][owner], test["specimen"][owner]
    x_tr, t_tr, _ = _training_windows(data_dir, split, window_s, rate)
    pick = np.random.default_rng(0).permutation(len(x_tr))[:256]
    calibration = (x_tr[pick, 0], x_tr[pick, 1], t_tr[pick])  # copies
    del x_tr, t_tr  # _peers reads them again, to free them before MiniRocket's ridge
    peer, bands, _, _ = _peers(scene, data_dir, split, window_s, peer_kernels)
    kinetic = KineticSignature(WhiskFeatures(scene.calibration_hz, rate),
                               np.array(list(THESIS_GRADES.values())) * 1e-6, rate)

    def score(pred: dict) -> tuple[float, float, float, str]:
        correct = (pred["grade"] == truth).astype(float)
        low, high = group_interval(correct, specimen)
        detail = ""
        if "grain" in pred and np.isfinite(pred["grain"]).all():
            detail = f"grain size RMS {_grain_errors(pred['grain'], sizes)['rms_pct']:.1f} %"
        return 100 * correct.mean(), 100 * low, 100 * high, detail

    sizes = np.array(list(THESIS_GRADES.values()))[truth] * 1e-6
    _progress("the oracles")
    bounds = []
    for label, answer in zip(("amplitude oracle", "every-grain oracle"),
                             oracles(scene, oracle_draws), strict=True):
        acc = answer["accuracy"]
        half = 1.96 * np.sqrt(acc * (1 - acc) / oracle_draws)
        bounds.append(Method(label, "reference", score=(100 * acc, 100 * (acc - half),
                                                        100 * (acc + half)),
                             note="the Bayes rule on what it knows (gradient boosting on "
                                  f"{oracle_draws} draws)"))
    methods = [
        Method("thesis cues ONNX", "classical", open_graph(classical, "windows", threads),
               classical),
        Method(peer.name, "peer", _Windows(peer.name, peer.predict),
               note=f"{peer_kernels} kernels, fitted on the training windows"),
        Method(bands.name, "peer", bands,
               note=f"{len(bands.edges) - 1} bands of the current over |F1|² and the whisk "
                    "features, gradient boosting fitted on the training windows"),
        Method(kinetic.name, "classical", _Windows(kinetic.name, kinetic.predict),
               note="the kinetic signature (the hypothesis the thesis refuted)"),
        *bounds,
    ]
    return Problem(
        "texture", "accuracy", "%", True, "s of signal", window_s, (e, i, t), score, "windows",
        64, calibration, methods, notes=frontier_lines(rate_study),
        data=f"`{data_dir}` test shard {split['test']}: {len(truth)} windows of {window_s:g} s "
             f"from {len(np.unique(specimen))} specimens never seen in training")
