"""``wtml bench texture-scale``: does more training data close the texture decoder's gap to
the amplitude oracle? (issue 25 §3)

Data: the texture scene (``configs/scenes/texture.yaml``) with only its name, seed, samples
and shards changed (:func:`split_scenes`): a training set from the scene's seed and a
held-out set from the seed + 1 (specimens never trained on), both in shards of the scene's
own size (the shipped scene: 40 specimens of 2 records of 1 s). The training sizes are
nested (:func:`plan_shards`): N specimens train on the first N/40 shards, so every size
holds the smaller ones. Shard k is what ``wtml generate --shard k`` makes, here in worker
processes of one thread each, which also compute the band-power peer's features of the
shard's windows; complete shards and features are kept, so a second run resumes. Then one
plain ``generate`` per set completes and verifies its manifest.

Decoders: each recipe (a training config of
:class:`~wtml.decoders.texture.TextureDecoder`: its model, ``data.init_args.batch_size``,
``trainer.max_epochs``, ``seed_everything``) is trained as ``train.py fit`` trains it, but
fast: the features of one random crop of every record per epoch (uniform start, drawn per
shard from :data:`CROP_SEED` and the shard's index: the same crops at every size) are
computed ahead in large batches by the decoder's own feature layer, on CUDA where there is
one; the steps then run on them: the net of
:meth:`~wtml.decoders.texture.TextureDecoder.net_on` (standardised over the first window of
every training record; weights drawn after seeding torch with the recipe's seed), each
epoch's batches in :class:`~wtml.data.datamodule.EpochBatches`'s order (the recipe's seed),
the loss :meth:`~wtml.decoders.texture.TextureDecoder.feature_loss`, AdamW under the
one-cycle schedule (:meth:`~wtml.decoders.base.DecoderModule.one_cycle`). Left out: the
validation split and the domain gate, which change no weight. The peer
(:class:`~wtml.baselines.texture_peers.BandPowerPeer`, as shipped) trains on every whole
window of the same records. Optionally (``minirocket_sizes``, none by default: it costs far
more than the rest on CPU), MiniRocket
(:class:`~wtml.baselines.texture_peers.MiniRocketPeer`, as shipped: aeon's
MiniRocketClassifier, :data:`MINIROCKET_KERNELS` kernels as ``wtml bench texture`` fits it)
trains on every whole window of the same records at those sizes, in the peer's two steps: the
windows, read straight into MiniRocket's float32 stack (1.05 GB per 10240 windows of 2 × 12800
samples; aeon's fit makes a float32 copy of it for a moment), are transformed a few at a time
into float64 features (0.82 GB per 10240 windows at 10000 kernels) and freed; then the scaler
and the ridge. Once the windows outnumber the features that is
:class:`~wtml.baselines.ridge_gcv.BlockRidgeClassifierCV`, scikit-learn's ``cov`` mode in row
blocks, beside the features one ``p × p`` matrix and its eigendecomposition (scikit-learn's
own held about four times the features: 15.6 GB at 40960 windows). So the peak is aeon's
copy: measured at 81920 windows (30 Nov), 21.2 GB of RSS at the transform's fit, 15.3 GB at
its end, 9.5 GB in the ridge; about 2.6 GB per 10240 windows.

Scores: every whole window (the recipes' ``window_s``) of every held-out record: accuracy,
its 95 % interval (bootstrap over the held-out specimens), P320/P280 confusion
(:func:`~wtml.bench.texture_rate.grade_scores`); paired differences on the same windows
(each decoder minus the peer and minus MiniRocket at each size; each size minus the
smallest, per method); the amplitude and every-grain oracles
(:func:`wtml.bench.texture.oracles`). Writes ``report.md``, ``summary.json`` and
``scale.png``.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import math
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

import numpy as np
import torch

from wtml.baselines.texture_peers import BandPowerPeer, MiniRocketPeer
from wtml.bench.resampling import group_interval, span
from wtml.bench.texture import oracles
from wtml.bench.texture_rate import (
    PAIR,
    difference_lines,
    grade_scores,
    pair_rates,
    pct,
)
from wtml.cores import THREADS_ENV, available_cores
from wtml.data.datamodule import EpochBatches, check_tensors, task_tensors
from wtml.data.shards import (
    SHARD_MAX_BYTES,
    checked_manifest,
    claim,
    generate,
    load_shards,
    shard_name,
)
from wtml.decoders.texture import TextureDecoder, WhiskFeatures, crop
from wtml.files import atomic_write, read_npz
from wtml.runtime.texture import windows
from wtml.scenes import config_hash, load_scene, scene_from_dict
from wtml.scenes.texture import TextureScene
from wtml.schema import read_yaml, to_dict
from wtml.workers import watch_parent

SCENE = "configs/scenes/texture.yaml"
"""The scene the training and held-out sets are drawn from."""
RECIPES = ("configs/texture.yaml", "configs/variants/texture_full.yaml")
"""The decoder recipes trained at every size: the shipped one and the full-size variant."""
SIZES = (640, 2560, 5120, 10240)
"""Training specimens of each row (the shipped dataset trains on 160)."""
TEST_SPECIMENS = 480
CROP_SEED = 20251128
"""The training crops' seed: shard k's come from ``SeedSequence([CROP_SEED, k])``."""
PEER = "band-power peer"
"""The peer's rows' label."""
MINIROCKET = "MiniRocket"
"""MiniRocket's rows' label."""
MINIROCKET_KERNELS = 10000
"""MiniRocket's kernels (``wtml bench texture --peer-kernels``'s default, aeon's)."""
CHUNK = {"cuda": 4096, "cpu": 256}
"""Windows per call of the feature layer on each device (4096 windows of 0.25 s at 51.2 kS/s:
210 MB each of e and i)."""


def _progress(text: str) -> None:
    print(f"bench texture-scale: {text}", file=sys.stderr, flush=True)


@dataclasses.dataclass(frozen=True)
class Plan:
    """The nested shards of a study.

    Attributes:
        specimens: specimens per shard (the scene's ``specimens_per_grade`` × 5 grades).
        records: records per shard (the scene's ``samples / shards``).
        sizes: training specimens -> the training shards they take (the first ones).
        test_shards: held-out shards.
    """

    specimens: int
    records: int
    sizes: dict[int, int]
    test_shards: int

    @property
    def train_shards(self) -> int:
        """Training shards: those of the largest size."""
        return max(self.sizes.values())


def plan_shards(scene: TextureScene, sizes, test_specimens: int) -> Plan:
    """The shards ``sizes`` (training specimens, ascending) and ``test_specimens`` take in
    shards of ``scene``'s size.

    Raises:
        ValueError: a scene of other grades, unequal shards or specimens of unequal records;
            a size or ``test_specimens`` that is not a positive whole number of shards' worth
            of specimens (each message names the option)."""
    if not isinstance(scene, TextureScene) or scene.grades != "thesis":
        raise ValueError(f"--scene: a texture scene of the thesis grades is needed, got "
                         f"{getattr(scene, 'task', '?')} ({getattr(scene, 'grades', '-')})")
    per, rest = divmod(scene.samples, scene.shards)
    specimens = 5 * scene.specimens_per_grade
    if rest or per % specimens:
        raise ValueError(f"--scene: samples ({scene.samples}) must fill its shards "
                         f"({scene.shards}) equally, each shard's records a multiple of its "
                         f"specimens ({specimens}: specimens_per_grade × 5 grades), got "
                         f"{scene.samples / scene.shards:g} records per shard")
    sizes = list(sizes)
    if not sizes or sizes != sorted(set(sizes)):
        raise ValueError(f"--sizes: distinct training sizes in ascending order, got {sizes}")
    for option, values in (("--sizes", sizes), ("--test-specimens", [test_specimens])):
        for n in values:
            if isinstance(n, bool) or not isinstance(n, int) or n < specimens or n % specimens:
                raise ValueError(f"{option}: whole shards of {specimens} specimens "
                                 f"({specimens}, {2 * specimens}, ...), got {n!r}")
    return Plan(specimens, per, {n: n // specimens for n in sizes}, test_specimens // specimens)


def split_scenes(base: TextureScene, plan: Plan) -> dict[str, TextureScene]:
    """``train`` (``base``'s seed) and ``test`` (the seed + 1): ``base`` with its name, seed,
    samples and shards changed, each checked as a scene file's would be."""
    out = {}
    for split, seed, shards in (("train", base.seed, plan.train_shards),
                                ("test", base.seed + 1, plan.test_shards)):
        out[split] = scene_from_dict(to_dict(base) | {
            "name": f"{base.name}_scale_{split}", "seed": seed,
            "samples": plan.records * shards, "shards": shards}, f"{split} scene")
    return out


@dataclasses.dataclass(frozen=True)
class Recipe:
    """A texture decoder's training config, as the bench trains it.

    Attributes:
        path: the config file.
        model: ``model.init_args`` (:class:`~wtml.decoders.texture.TextureDecoder`'s).
        batch: ``data.init_args.batch_size``.
        epochs: ``trainer.max_epochs`` (or the bench's ``epochs``).
        seed: ``seed_everything``.
    """

    path: str
    model: dict
    batch: int
    epochs: int
    seed: int

    @property
    def name(self) -> str:
        """The report's label: the config's name, its layers and batch."""
        return f"{Path(self.path).stem} ({list(self.decoder().hparams.hidden)}, batch " \
               f"{self.batch})"

    def decoder(self) -> TextureDecoder:
        """A new, untrained decoder of this recipe's model."""
        return TextureDecoder(**self.model)


def read_recipe(path: str | Path, epochs: int | None = None) -> Recipe:
    """The recipe in training config ``path``; ``epochs`` replaces its ``max_epochs``.

    Raises:
        ValueError: not a texture decoder's config, or a value out of range (naming the
            file and the key)."""
    cfg = read_yaml(path, what="training config")
    if not isinstance(cfg, dict):
        raise ValueError(f"{path}: a training config is a YAML mapping (configs/texture.yaml)")
    model = cfg.get("model") if isinstance(cfg.get("model"), dict) else {}
    if model.get("class_path") != f"{TextureDecoder.__module__}.TextureDecoder":
        raise ValueError(f"{path}: model.class_path must be wtml.decoders.texture."
                         f"TextureDecoder (a texture decoder's recipe), got "
                         f"{model.get('class_path')!r:.80}")
    init = dict(model.get("init_args") or {})
    try:
        TextureDecoder(**init)
    except TypeError as err:
        raise ValueError(f"{path}: model.init_args: {err}") from None
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    data = (cfg.get("data") or {}).get("init_args") or {}
    values = {"data.init_args.batch_size": (data.get("batch_size"), 1, 10**7),
              "trainer.max_epochs": ((cfg.get("trainer") or {}).get("max_epochs")
                                     if epochs is None else epochs, 1, 10**6),
              "seed_everything": (cfg.get("seed_everything"), 0, 2**32 - 1)}
    for key, (value, low, high) in values.items():
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"{path}: {key} must be a whole number in [{low}, {high}] (the "
                             f"bench trains as the config does), got {value!r:.80}")
    return Recipe(str(path), init, *(v[0] for v in values.values()))


def read_recipes(paths, epochs: int | None = None) -> list[Recipe]:
    """:func:`read_recipe` of each path; they must share one feature layer (the same
    ``window_s`` and ``band_frame_s``: one bank of features serves them all).

    Raises:
        ValueError: none, or recipes of different feature layers (naming ``--recipes``)."""
    cooks = [read_recipe(p, epochs) for p in paths]
    if not cooks:
        raise ValueError("--recipes: at least one training config")
    first = cooks[0].decoder().hparams
    for r in cooks[1:]:
        h = r.decoder().hparams
        if (h.window_s, h.band_frame_s) != (first.window_s, first.band_frame_s):
            raise ValueError(f"--recipes: {r.path}'s model.init_args window_s, band_frame_s "
                             f"({h.window_s}, {h.band_frame_s}) are not {cooks[0].path}'s "
                             f"({first.window_s}, {first.band_frame_s}): the recipes share one "
                             "feature layer")
    return cooks


# --- generation -------------------------------------------------------------------------
def _shard_job(scene: dict, folder: str, features: str, k: int, window: int) -> dict:
    """Worker (one thread): shard ``k`` of ``scene`` in ``folder`` (kept if complete) and
    the peer's features of its windows of ``window`` samples in ``features`` (kept if
    there). Returns ``k``, whether the shard was ``made`` and its ``seconds``."""
    from threadpoolctl import threadpool_limits

    os.environ[THREADS_ENV] = "1"
    torch.set_num_threads(1)
    with threadpool_limits(1):
        made_scene = scene_from_dict(scene)
        shard = Path(folder) / shard_name(k)
        side = shard.with_suffix(".json")
        before = side.stat().st_mtime_ns if side.exists() else None
        t0 = time.perf_counter()
        generate(made_scene, folder, shard=k, progress=False)
        seconds = time.perf_counter() - t0
        dst = Path(features) / shard_name(k)
        if not dst.exists():
            data = read_npz(shard, what="dataset shard", max_bytes=SHARD_MAX_BYTES)
            (e, i), owner = windows(np.stack([data["e"], data["i"]]), window)
            peer = BandPowerPeer(made_scene.calibration_hz,
                                 made_scene.acquisition.sample_rate_hz)
            atomic_write(dst, lambda fh: np.savez(
                fh, x=peer.features(e, i, data["t"][owner]), grade=data["grade"][owner],
                specimen=data["specimen"][owner]))
    return {"k": k, "made": before is None or side.stat().st_mtime_ns != before,
            "seconds": seconds}


def _listed(folder: Path, scene: TextureScene) -> set[int]:
    """The shards the manifest in ``folder`` lists (none without one)."""
    if not (folder / "manifest.json").exists():
        return set()
    manifest, _ = checked_manifest(folder, complete=False)
    return {e.index for e in manifest.shards} if manifest.scene_hash == config_hash(scene) \
        else set()


def make_sets(scenes: dict[str, TextureScene], work: Path, window: int, workers: int
              ) -> dict:
    """Every shard of each scene in ``work/<split>-<scene hash>``, its peer features in
    ``...-peer<window>``, on ``workers`` processes; then a plain ``generate`` per set
    verifies its manifest. Returns, per split, its ``folder``, ``features`` and
    ``shards``, and the shards ``made``, ``kept`` and the ``seconds`` of those made."""
    jobs, out = [], {}
    for split, scene in scenes.items():
        folder = work / f"{split}-{config_hash(scene)[:12]}"
        features = folder.with_name(f"{folder.name}-peer{window}")
        folder.mkdir(parents=True, exist_ok=True)
        claim(folder, scene, scene.shards)  # another scene's folder is refused here
        features.mkdir(exist_ok=True)
        listed = _listed(folder, scene)
        jobs += [(to_dict(scene), str(folder), str(features), k, window)
                 for k in range(scene.shards)
                 if k not in listed or not (features / shard_name(k)).exists()]
        out[split] = {"folder": str(folder), "features": str(features),
                      "shards": scene.shards}
    done = []
    if jobs:
        _progress(f"{len(jobs)} shards to make or check on {workers} processes")
        with ProcessPoolExecutor(min(workers, len(jobs)), mp_context=get_context("spawn"),
                                 initializer=watch_parent, initargs=(os.getpid(),)) as pool:
            futures = [pool.submit(_shard_job, *job) for job in jobs]
            step = max(1, len(jobs) // 20)
            for count, future in enumerate(as_completed(futures), start=1):
                done.append(future.result())
                if count % step == 0 or count == len(jobs):
                    _progress(f"shards {count}/{len(jobs)}")
    for split, scene in scenes.items():
        manifest = generate(scene, out[split]["folder"], progress=False)
        if not manifest["complete"]:
            raise RuntimeError(f"{out[split]['folder']}: incomplete after generation")
    made = [d["seconds"] for d in done if d["made"]]
    total = sum(s.shards for s in scenes.values())
    return {"sets": out, "made": len(made), "kept": total - len(made),
            "seconds_per_shard": float(np.mean(made)) if made else None}


# --- features and training ----------------------------------------------------------------
def features_at(layer: WhiskFeatures, tensors: tuple[torch.Tensor, ...], rows: torch.Tensor,
                start: torch.Tensor, n: int, chunk: int) -> torch.Tensor:
    """Features ``(m, n_features)`` of the windows of ``n`` samples of records ``rows``
    from samples ``start`` (``(m,)`` each; :func:`~wtml.decoders.texture.crop`), computed
    ``chunk`` windows at a time without gradients. ``tensors``: ``e, i, t_re, t_im``."""
    e, i, t_re, t_im = tensors
    out = []
    with torch.no_grad():
        for s in range(0, len(rows), chunk):
            r = rows[s:s + chunk].to(e.device)
            out.append(layer(*crop(e, i, start[s:s + chunk], n, r), t_re[r], t_im[r]))
    return torch.cat(out)


def shard_bank(layer: WhiskFeatures, tensors: tuple[torch.Tensor, ...], k: int, n: int,
               epochs: int, chunk: int) -> dict[str, torch.Tensor]:
    """Training shard ``k``'s features: ``first`` ``(records, F)`` (each record's first
    window) and ``crops`` ``(epochs, records, F)`` (one random window per record and epoch,
    uniform start from ``SeedSequence([CROP_SEED, k])``)."""
    e = tensors[0]
    records, length = e.shape
    gen = torch.Generator().manual_seed(
        int(np.random.SeedSequence([CROP_SEED, k]).generate_state(1)[0]))
    start = torch.randint(0, length - n + 1, (epochs, records), generator=gen)
    rows = torch.arange(records).repeat(epochs)
    crops = features_at(layer, tensors, rows, start.reshape(-1), n, chunk)
    first = features_at(layer, tensors, torch.arange(records),
                        torch.zeros(records, dtype=torch.long), n, chunk)
    return {"first": first, "crops": crops.reshape(epochs, records, -1)}


@contextlib.contextmanager
def _run_seed(seed: int):
    """``PL_GLOBAL_SEED`` (what ``seed_everything`` sets, and
    :func:`~wtml.data.datamodule.epoch_seed` reads) at ``seed``, as it was afterwards."""
    old = os.environ.get("PL_GLOBAL_SEED")
    os.environ["PL_GLOBAL_SEED"] = str(seed)
    try:
        yield
    finally:
        if old is None:
            os.environ.pop("PL_GLOBAL_SEED", None)
        else:
            os.environ["PL_GLOBAL_SEED"] = old


def train_recipe(recipe: Recipe, layer: WhiskFeatures, first: torch.Tensor,
                 crops: torch.Tensor, targets: torch.Tensor) -> tuple[TextureDecoder, dict]:
    """The decoder of ``recipe`` trained on precomputed features (module docstring):
    ``first`` ``(records, F)``, ``crops`` ``(epochs, records, F)``, ``targets``
    ``(records, 2)``, all on the training device. Returns it (its net on that device) and
    ``steps``, ``loss`` (each epoch's mean) and ``status`` (``done``, or where the loss
    stopped being finite)."""
    decoder = recipe.decoder()
    torch.manual_seed(recipe.seed)
    decoder.net = decoder.net_on(layer, first.cpu(), targets.cpu()).to(first.device)
    decoder.train()
    records = len(targets)
    per_epoch = math.ceil(records / recipe.batch)
    opt, sched = decoder.one_cycle(recipe.epochs * per_epoch)
    losses = []
    with _run_seed(recipe.seed):
        for epoch in range(recipe.epochs):
            total = torch.zeros((), device=first.device)
            for idx in EpochBatches(records, recipe.batch, True, lambda e=epoch: e):
                idx = idx.to(first.device)
                loss = decoder.feature_loss(crops[epoch, idx], targets[idx])
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
                sched.step()
                total += loss.detach()
            losses.append(float(total) / per_epoch)
            if not math.isfinite(losses[-1]):
                return decoder, {"steps": (epoch + 1) * per_epoch, "loss": losses,
                                 "status": f"diverged: loss {losses[-1]} in epoch {epoch + 1}"}
    return decoder, {"steps": recipe.epochs * per_epoch, "loss": losses, "status": "done"}


def paired_differences(rows: list[dict], preds: dict, grade: np.ndarray, specimen: np.ndarray
                       ) -> list[dict]:
    """Accuracy differences on the same held-out windows: each decoder minus the peer and
    minus MiniRocket at its size, each size minus the smallest (per method), where both rows
    ran. ``preds``: ``(method, size)`` -> predicted grades ``(n_windows,)``; ``grade``,
    ``specimen`` the windows'. Each: ``name``, ``difference`` (a fraction) and its 95 % ``interval``
    (bootstrap over specimens)."""
    out = []
    smallest = min(r["specimens"] for r in rows)
    for row in rows:
        key = (row["method"], row["specimens"])
        pairs = [(f"{row['method']} minus the peer, {row['specimens']} specimens",
                  (PEER, row["specimens"]), row["kind"] == "decoder"),
                 (f"{row['method']} minus {MINIROCKET}, {row['specimens']} specimens",
                  (MINIROCKET, row["specimens"]), row["kind"] == "decoder"),
                 (f"{row['method']}, {row['specimens']} minus {smallest} specimens",
                  (row["method"], smallest), row["specimens"] != smallest)]
        for name, other, wanted in pairs:
            if wanted and key in preds and other in preds:
                gain = ((preds[key] == grade).astype(float)
                        - (preds[other] == grade).astype(float))
                out.append({"name": name, "difference": float(gain.mean()),
                            "interval": group_interval(gain, specimen)})
    return out


class _Study:
    """The state of one run: the test set's features, the training shards' banks, the
    timings that estimate what a row costs, the clock against the deadline."""

    def __init__(self, sets: dict, scene: TextureScene, plan: Plan, recipes: list[Recipe],
                 n: int, deadline_s: float | None, start: float,
                 kernels: int = MINIROCKET_KERNELS) -> None:
        self.sets, self.scene, self.plan, self.n = sets, scene, plan, n
        self.deadline = None if deadline_s is None else start + deadline_s
        self.device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
        self.chunk = CHUNK[self.device.type]
        self.layer = recipes[0].decoder().feature_layer(scene).to(self.device)
        self.epochs = max(r.epochs for r in recipes)
        self.banks: dict[int, dict] = {}
        self.shard_s: float | None = None  # seconds to ingest a training shard
        self.step_s: dict[str, float] = {}  # recipe path -> seconds per step
        self.peer_s: float | None = None  # peer fit seconds per training window
        self.kernels = kernels  # MiniRocket's
        self.minirocket_s: tuple[float, float] | None = None  # fit s per window, predict s
        self.test = self._test()

    def _tensors(self, folder: str, k: int) -> tuple[tuple[torch.Tensor, ...], dict]:
        arrays = load_shards(folder, [k])
        tensors = task_tensors(arrays, "texture")
        check_tensors(tensors, "texture", [(str(Path(folder) / shard_name(k)),
                                            len(tensors[-1]))])
        return tuple(x.to(self.device) for x in tensors), arrays

    def _test(self) -> dict:
        """Every whole window of the held-out records: the decoders' features, the peer's,
        the grades and specimens (in :func:`wtml.runtime.texture.windows`'s order)."""
        held = self.sets["test"]
        x, grade, specimen, peer = [], [], [], []
        for k in range(held["shards"]):
            tensors, arrays = self._tensors(held["folder"], k)
            records, length = tensors[0].shape
            per = length // self.n
            rows = torch.arange(records).repeat_interleave(per)
            start = (torch.arange(per) * self.n).repeat(records)
            x.append(features_at(self.layer, tensors[:4], rows, start, self.n, self.chunk))
            grade.append(arrays["grade"][rows.numpy()])
            specimen.append(arrays["specimen"][rows.numpy()])
            peer.append(read_npz(Path(held["features"]) / shard_name(k), what="peer features"))
        test = {"x": torch.cat(x), "grade": np.concatenate(grade),
                "specimen": np.concatenate(specimen),
                "peer": np.concatenate([p["x"] for p in peer])}
        for key in ("grade", "specimen"):
            if not np.array_equal(np.concatenate([p[key] for p in peer]), test[key]):
                raise RuntimeError(f"{held['features']}: the peer's windows are not the "
                                   f"decoders' ({key}); delete the folder and run again")
        _progress(f"held-out set: {len(test['grade'])} windows of "
                  f"{len(np.unique(test['specimen']))} specimens on {self.device}")
        return test

    def _windows(self, split: str, shards: int) -> tuple[np.ndarray, ...]:
        """Every whole window of the first ``shards`` shards of ``split``, stacked as
        MiniRocket reads them: ``(m, 2, n)`` float32, e then i (filled shard by shard: one
        copy), and grade and specimen ``(m,)``, in :func:`wtml.runtime.texture.windows`'s
        order (the peer's features')."""
        folder = Path(self.sets[split]["folder"])
        x = None
        grade, specimen = [], []
        at = 0
        for k in range(shards):
            data = read_npz(folder / shard_name(k), what="dataset shard",
                            max_bytes=SHARD_MAX_BYTES)
            cut, owner = windows(np.stack([data["e"], data["i"]]), self.n)
            if x is None:
                x = np.empty((shards * len(owner), 2, self.n), np.float32)
            x[at:at + len(owner)] = cut.transpose(1, 0, 2)
            at += len(owner)
            grade.append(data["grade"][owner])
            specimen.append(data["specimen"][owner])
        if at != len(x):
            raise RuntimeError(f"{folder}: shards of unequal windows")
        return x, np.concatenate(grade), np.concatenate(specimen)

    def left(self) -> float:
        return math.inf if self.deadline is None else self.deadline - time.perf_counter()

    def skip(self, estimate: float | None) -> str | None:
        """Why a row estimated to take ``estimate`` s (None: unknown) is skipped, or None."""
        if self.left() <= 0:
            return "skipped: the deadline had passed"
        if estimate is not None and estimate > self.left():
            return f"skipped: estimated {estimate:.0f} s, {self.left():.0f} s left"
        return None

    def _bank(self, shards: int) -> dict[str, torch.Tensor]:
        """The training features of the first ``shards`` shards (ingesting those missing)."""
        train = self.sets["train"]
        for k in range(shards):
            if k not in self.banks:
                t0 = time.perf_counter()
                tensors, _ = self._tensors(train["folder"], k)
                self.banks[k] = shard_bank(self.layer, tensors[:4], k, self.n, self.epochs,
                                           self.chunk) | {"y": tensors[4]}
                if self.device.type == "cuda":
                    torch.cuda.synchronize()
                self.shard_s = time.perf_counter() - t0
        return {key: torch.cat([self.banks[k][key] for k in range(shards)],
                               1 if key == "crops" else 0)
                for key in ("first", "crops", "y")}

    def decoder_row(self, recipe: Recipe, size: int, shards: int) -> tuple[dict, np.ndarray]:
        """One recipe at one size: its row and its predictions on the held-out windows."""
        row = {"method": recipe.name, "kind": "decoder", "recipe": recipe.path,
               "specimens": size, "shards": shards, "epochs": recipe.epochs,
               "batch": recipe.batch}
        missing = shards - len(self.banks)
        estimate = None
        if recipe.path in self.step_s and (missing <= 0 or self.shard_s is not None):
            steps = recipe.epochs * math.ceil(shards * self.plan.records / recipe.batch)
            estimate = steps * self.step_s[recipe.path] + max(0, missing) * (self.shard_s or 0)
        why = self.skip(estimate)
        if why:
            return row | {"status": why}, None
        bank = self._bank(shards)
        t0 = time.perf_counter()
        decoder, info = train_recipe(recipe, recipe.decoder().feature_layer(self.scene),
                                     bank["first"], bank["crops"][:recipe.epochs], bank["y"])
        net = decoder.net.eval()
        with torch.no_grad():
            logits = torch.cat([net.heads(self.test["x"][s:s + 65536])[0]
                                for s in range(0, len(self.test["x"]), 65536)])
        pred = logits.argmax(1).cpu().numpy()  # waits for the device
        fit_s = time.perf_counter() - t0
        self.step_s[recipe.path] = fit_s / max(1, info["steps"])
        row |= {"train_records": len(bank["y"]), "steps": info["steps"], "fit_s": fit_s,
                "loss_first_last": [info["loss"][0], info["loss"][-1]],
                "status": info["status"]}
        if info["status"] != "done":
            return row, None
        return row | grade_scores(pred, self.test["grade"], self.test["specimen"]), pred

    def peer_row(self, size: int, shards: int) -> tuple[dict, np.ndarray]:
        """The band-power peer at one size: its row and its held-out predictions."""
        train = self.sets["train"]
        row = {"method": PEER, "kind": "peer", "specimens": size, "shards": shards}
        per_shard = len(self.test["grade"]) / self.plan.test_shards  # windows, as training's
        estimate = None if self.peer_s is None else self.peer_s * per_shard * shards
        why = self.skip(estimate)
        if why:
            return row | {"status": why}, None
        data = [read_npz(Path(train["features"]) / shard_name(k), what="peer features")
                for k in range(shards)]
        x = np.concatenate([d["x"] for d in data])
        t0 = time.perf_counter()
        peer = BandPowerPeer(self.scene.calibration_hz, self.scene.acquisition.sample_rate_hz)
        peer.fit_features(x, np.concatenate([d["grade"] for d in data]))
        pred = peer.predict_features(self.test["peer"])["grade"]
        fit_s = time.perf_counter() - t0
        self.peer_s = fit_s / len(x)
        row |= {"train_windows": len(x), "iterations": int(peer.model.n_iter_), "fit_s": fit_s,
                "status": "done"}
        return row | grade_scores(pred, self.test["grade"], self.test["specimen"]), pred

    def minirocket_row(self, size: int, shards: int) -> tuple[dict, np.ndarray]:
        """MiniRocket at one size: its row and its held-out predictions."""
        row = {"method": MINIROCKET, "kind": "minirocket", "specimens": size,
               "shards": shards, "kernels": self.kernels}
        per_shard = len(self.test["grade"]) / self.plan.test_shards  # windows, as training's
        estimate = None
        if self.minirocket_s is not None:
            estimate = self.minirocket_s[0] * per_shard * shards + self.minirocket_s[1]
        why = self.skip(estimate)
        if why:
            return row | {"status": why}, None
        x, grade, _ = self._windows("train", shards)
        trained = len(grade)
        _progress(f"{MINIROCKET}, {size} specimens: fitting {self.kernels} kernels on "
                  f"{trained} windows")
        t0 = time.perf_counter()
        peer = MiniRocketPeer(self.kernels)
        features = peer.fit_transform_stacked(x)
        del x  # the windows go before the ridge
        _progress(f"{MINIROCKET}, {size} specimens: transformed in "
                  f"{time.perf_counter() - t0:.0f} s; the ridge")
        peer.fit_features(features, grade)
        fit_s = time.perf_counter() - t0
        del features
        x, grade, specimen = self._windows("test", self.plan.test_shards)
        if not (np.array_equal(grade, self.test["grade"])
                and np.array_equal(specimen, self.test["specimen"])):
            raise RuntimeError(f"{self.sets['test']['folder']}: MiniRocket's windows are not "
                               "the decoders'")
        t0 = time.perf_counter()
        pred = peer.predict_stacked(x)["grade"]
        predict_s = time.perf_counter() - t0
        self.minirocket_s = (fit_s / trained, predict_s)
        row |= {"train_windows": trained, "fit_s": fit_s,
                "predict_s": predict_s, "status": "done"}
        return row | grade_scores(pred, self.test["grade"], self.test["specimen"]), pred


def run_scale(out: str | Path = "runs/texture/scale", *, scene: str | Path = SCENE,
              sizes=SIZES, test_specimens: int = TEST_SPECIMENS, recipes=RECIPES,
              workers: int | None = None, work: str | Path = "datasets/texture_scale",
              deadline_s: float | None = None, epochs: int | None = None,
              oracle_draws: int = 100_000, minirocket_sizes=(),
              minirocket_kernels: int = MINIROCKET_KERNELS) -> str:
    """The study (module docstring); returns the markdown report (also ``out/report.md``).

    Args:
        out: the folder for ``report.md``, ``summary.json`` and ``scale.png``.
        scene: the texture scene both sets are drawn from.
        sizes: training specimens of each row, ascending (whole shards).
        test_specimens: held-out specimens (whole shards).
        recipes: the decoders' training configs (one feature layer: the same ``window_s``
            and ``band_frame_s``).
        workers: generation processes (None: the available cores).
        work: where the shards and the peer's features go (kept: a second run resumes).
        deadline_s: seconds from the start after which no row begins, and a row estimated
            to end after them is skipped (None: none).
        epochs: every recipe's epochs instead of its ``max_epochs`` (None: the configs').
        oracle_draws: draws of each oracle's prior.
        minirocket_sizes: the sizes (each one of ``sizes``) at which MiniRocket is fitted
            too (none: no MiniRocket rows).
        minirocket_kernels: MiniRocket's kernels.

    Raises:
        ValueError: an option out of range (named), recipes of different feature layers.
    """
    start = time.perf_counter()
    workers = available_cores() if workers is None else workers
    for option, value, low, high in (("--workers", workers, 1, 1024),
                                     ("--oracle-draws", oracle_draws, 100, 10**7),
                                     ("--minirocket-kernels", minirocket_kernels, 84, 10**6)):
        if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
            raise ValueError(f"{option}: a whole number in [{low}, {high}], got {value!r}")
    if deadline_s is not None and not 0 < deadline_s <= 10**7:
        raise ValueError(f"--deadline-s: a number of seconds in (0, 1e7], got {deadline_s!r}")
    base = load_scene(scene)
    plan = plan_shards(base, sizes, test_specimens)
    minirocket_sizes = list(minirocket_sizes)
    if minirocket_sizes != sorted(set(minirocket_sizes)) or not set(minirocket_sizes) <= set(
            plan.sizes):
        raise ValueError(f"--minirocket-sizes: distinct sizes in ascending order, each one of "
                         f"--sizes ({', '.join(map(str, plan.sizes))}), got {minirocket_sizes}")
    cooks = read_recipes(recipes, epochs)
    n = cooks[0].decoder().window(base)
    scenes = split_scenes(base, plan)
    _progress(f"training set: {plan.train_shards} shards of {plan.specimens} specimens, "
              f"held-out set: {plan.test_shards}, in {work}")
    gen = make_sets(scenes, Path(work), n, workers)
    gen_s = time.perf_counter() - start
    study = _Study(gen["sets"], scenes["train"], plan, cooks, n, deadline_s, start,
                   minirocket_kernels)
    rows, preds = [], {}
    for size, shards in plan.sizes.items():
        for method in [PEER, *[MINIROCKET] * (size in minirocket_sizes), *cooks]:
            row, pred = (study.peer_row(size, shards) if method == PEER
                         else study.minirocket_row(size, shards) if method == MINIROCKET
                         else study.decoder_row(method, size, shards))
            rows.append(row)
            if pred is not None:
                preds[(row["method"], size)] = pred
            _progress(f"{row['method']}, {size} specimens: " + (
                f"{100 * row['accuracy']:.1f} % [{span(row['interval'])}], fit "
                f"{row['fit_s']:.1f} s" if "accuracy" in row else row["status"]))
    test = study.test
    differences = paired_differences(rows, preds, test["grade"], test["specimen"])
    _progress("the oracles")
    amplitude, grain = oracles(base, oracle_draws)
    summary = {
        "scene": str(scene), "scenes": {k: to_dict(s) for k, s in scenes.items()},
        "plan": dataclasses.asdict(plan), "window_s": n / base.acquisition.sample_rate_hz,
        "test_windows": len(test["grade"]),
        "test_specimens": int(len(np.unique(test["specimen"]))),
        "recipes": [dataclasses.asdict(r) for r in cooks],
        "minirocket": {"sizes": minirocket_sizes, "kernels": minirocket_kernels}, "rows": rows,
        "differences": differences,
        "oracle": amplitude | {"confusion": amplitude["confusion"].tolist()},
        "grain_oracle": grain | {"confusion": grain["confusion"].tolist()},
        "generation": gen | {"workers": workers, "seconds": gen_s},
        "machine": {"device": str(study.device), "cores": available_cores(),
                    "gpu": torch.cuda.get_device_name(0) if study.device.type == "cuda"
                    else None, "torch": torch.__version__},
        "deadline_s": deadline_s, "elapsed_s": time.perf_counter() - start}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report = _report(summary)
    (out / "report.md").write_text(report)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    _plot(summary, out)
    return report


def _report(s: dict) -> str:
    plan, o, g, m = s["plan"], s["oracle"], s["grain_oracle"], s["machine"]
    mr = s.get("minirocket") or {"sizes": []}
    recipes = "; ".join(f"`{r['path']}` ({r['model'].get('hidden')}, batch {r['batch']}, "
                        f"{r['epochs']} epochs, lr {r['model'].get('lr', 3e-3):g})"
                        for r in s["recipes"])
    lines = ["# wtml bench texture-scale", "",
             f"Training sets nested in shards of {plan['specimens']} specimens "
             f"({plan['records']} records) of `{s['scene']}` (its seed); held out: "
             f"{s['test_specimens']} specimens (the seed + 1), every whole window of "
             f"{s['window_s']:g} s ({s['test_windows']} windows). Decoders: {recipes}, "
             "one random crop of every record per epoch. The decoders and the band-power "
             "peer fit features computed beforehand (the features of the decoders' crops, shard by "
             "shard; the peer's band powers at generation), which `fit (s)` leaves out. "
             + (f"{MINIROCKET}: aeon's MiniRocketClassifier (`MiniRocketPeer`, "
                f"{mr['kernels']} kernels) on every whole window of the training records; its "
                "fit includes transforming them. " if mr["sizes"] else "")
             + "Intervals: 95 %, bootstrap over the held-out specimens.", "",
             f"| method | specimens | trained on | steps | accuracy | 95 % interval | "
             f"{PAIR[0]} as {PAIR[1]} | {PAIR[1]} as {PAIR[0]} | fit (s) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in s["rows"]:
        if "accuracy" not in r:
            lines.append(f"| {r['method']} | {r['specimens']} | {r['status']} | | | | | | |")
            continue
        trained = (f"{r['train_records']} records" if r["kind"] == "decoder"
                   else f"{r['train_windows']} windows")
        steps = (r["steps"] if r["kind"] == "decoder" else f"{r['iterations']} it."
                 if r["kind"] == "peer" else f"{r['kernels']} kernels")
        lines.append(f"| {r['method']} | {r['specimens']} | {trained} | {steps} | "
                     f"{pct(r['accuracy'])} | {span(r['interval'])} | "
                     f"{pct(r['p320_as_p280'])} | {pct(r['p280_as_p320'])} | "
                     f"{r['fit_s']:.1f} |")
    for label, x in (("amplitude oracle", o), ("every-grain oracle", g)):
        lines.append(f"| {label} ({x['n']} draws of the prior) | - | - | - | "
                     f"{pct(x['accuracy'])} | - | " + " | ".join(map(pct, pair_rates(
                         x["confusion"]))) + " | - |")
    lines += difference_lines(s["differences"])
    predict = [f"{r['predict_s']:.0f} s at {r['specimens']}" for r in s["rows"]
               if r["kind"] == "minirocket" and "predict_s" in r]
    if predict:
        lines += ["", f"{MINIROCKET}'s predictions on the held-out windows (their transform) "
                  f"took {', '.join(predict)} specimens."]
    gen = s["generation"]
    per = gen["seconds_per_shard"]
    lines += ["", f"Generation: {gen['made']} shards made"
              + (f" ({per:.1f} s each on one of {gen['workers']} processes)" if per else "")
              + f", {gen['kept']} kept; {gen['seconds']:.0f} s with the peer's features and "
              f"the manifests' checks. Decoders on {m['device']}"
              + (f" ({m['gpu']})" if m["gpu"] else "") + f", torch {m['torch']}, "
              f"{m['cores']} core{'s' * (m['cores'] != 1)}; {s['elapsed_s']:.0f} s in all"
              + (f" (deadline {s['deadline_s']:g} s)" if s["deadline_s"] else "") + ".", "",
              "Plot: scale.png."]
    return "\n".join(lines) + "\n"


def _plot(s: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.8))
    methods = list(dict.fromkeys(r["method"] for r in s["rows"]))
    for k, method in enumerate(methods):
        done = [r for r in s["rows"] if r["method"] == method and "accuracy" in r]
        if not done:
            continue
        x = np.array([r["specimens"] for r in done]) * 1.04 ** (k - (len(methods) - 1) / 2)
        acc = np.array([100 * r["accuracy"] for r in done])
        low, high = (np.array([100 * r["interval"][j] for r in done]) for j in (0, 1))
        ax.errorbar(x, acc, yerr=np.stack([acc - low, high - acc]), fmt="o-", capsize=3,
                    label=method)  # (2, n): a list of 1-element arrays warns in matplotlib
    ax.axhline(100 * s["oracle"]["accuracy"], color="k", ls=":", label="amplitude oracle")
    ax.axhline(100 * s["grain_oracle"]["accuracy"], color="k", ls="--",
               label="every-grain oracle")
    sizes = list(s["plan"]["sizes"])
    ax.set_xscale("log")
    ax.minorticks_off()
    ax.set(xticks=sizes, xticklabels=[str(n) for n in sizes], xlabel="training specimens",
           ylabel="accuracy (%)", title=f"{s['test_specimens']} held-out specimens, "
                                        f"{s['window_s']:g} s windows")
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2)
    fig.tight_layout()
    fig.savefig(out / "scale.png", dpi=110)
    plt.close(fig)
