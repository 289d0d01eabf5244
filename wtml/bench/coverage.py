"""``wtml bench coverage``: whether every decoder's uncertainty is honest (issue 25 §4).

Per regression decoder and interval (radial distance, onset gap, fluid ln η and ρ, texture ln
grain size), the empirical coverage of its 68.27 % and 95 % intervals (±1σ and ±1.96σ raw;
recalibrated, ±1σ and ± the export's fitted 95 % width, ``<σ>_95`` of ``wtml predict``), overall
and per range of the target (quintiles of the test shard's truth, the same ranges on every
row), on the held-out test shard, on fresh records of the trained scene and on the held-out
physics its task's benches score: fluid, devices off the trained spread (issue 21's, the
sphere's radius); radial, devices off the preset and invalid contacts; onset, each contact
law alone, the wall's friction, each acquisition effect alone and the independent simulator;
texture, each friction law alone and each acquisition effect alone. Each row twice: the
checkpoint's own σ (where it has one: ``raw``) and the export's, recalibrated
(:mod:`wtml.decoders.recalibration`). Only in-domain answers have an interval (σ is NaN out of
domain): the flagged share is beside each row. Beside the fluid decoder's rows on its trained
scene, the best achievable: the exact Bayes posterior's own intervals, scored the same way
(:func:`fluid_bayes_rows`).

A coverage misses when it is more than :data:`TOLERANCE` from nominal and its binomial 95 %
interval (Wilson) leaves out the nominal rate too, on at least :data:`MIN_VERDICT` answers
(``✗``); more than :data:`TOLERANCE` off on too few answers to tell is marked ``?``. Where
answers come in groups that share their errors (texture: the windows of one specimen), the
interval counts the answers as many as they are worth (:func:`effective_count`), not one
each. A cell's verdict errs about one time in twenty, so each table ends with its ✗ count on
the physics it was trained on and on the rest beside what an exact interval earns by chance
on the same cells (:func:`chance_misses`): more than its 95th percentile is more than chance.

For the texture classifier: the expected calibration error (15 equal-width confidence bins)
before and after its recalibration (a temperature, then the top label's map) on its
in-domain windows (as the intervals: a flagged answer claims nothing), beside the ECE that
a perfectly calibrated classifier shows on as many windows with the same confidences (its
sampling floor, :func:`ece_floor`), judged against :data:`ECE_TARGET` (:func:`ece_verdict`),
and the reliability curve (``reliability.png``).

Writes ``report.md``, ``summary.json`` and ``reliability.png``.
"""

from __future__ import annotations

import dataclasses
import json
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from wtml.bench.extremes import strict_json
from wtml.bench.resampling import effective_count
from wtml.data.datamodule import split_shards
from wtml.data.shards import dataset_scene, load_shards, read_manifest
from wtml.decoders.checkpoint import load_decoder
from wtml.decoders.domain import Gated
from wtml.decoders.recalibration import (
    NOMINAL,
    binned_calibration,
    errors,
    expected_calibration_error,
    raw_sigma,
)
from wtml.physics.twoport import flat_parts
from wtml.runtime.metadata import WIDE
from wtml.runtime.onset import combine_pieces
from wtml.runtime.predict import load_export

TOLERANCE = 0.03
"""A coverage may be this far from nominal (3 points)."""
MIN_VERDICT = 20
"""Answers a cell needs before a miss is called one (fewer: ``?``, whatever the interval)."""
N_RANGES = 5
"""Ranges of the target per table (quintiles of the test shard's truth)."""
DISPLAY = {"distance": (1e6, "µm"), "gap": (1e6, "µm"), "grain": (1e6, "µm"),
           "eta": (1.0, "Pa·s"), "rho": (1.0, "kg/m³")}
"""How each value's ranges are written: a factor and a unit."""
BATCH = 64
"""Rows per call of the checkpoint's graph (texture windows are 12800 samples each)."""
ECE_TARGET = 0.02
"""Issue 25 §4: a classifier's expected calibration error on its in-domain answers at most
this (2 %)."""
CHANCE_DRAWS = 1000
"""Draws of an exact interval's answers behind each table's ✗ count by chance
(:func:`chance_misses`)."""
TRAINED_KINDS = ("test shard", "in family")
"""Rows of the physics the decoder was trained on; the others (held-out laws, acquisition
effects, devices, another simulator) are not."""


@dataclass(frozen=True)
class RecordSet:
    """One row's records: a name, what they hold out (``kind``) and a maker of
    ``(graph inputs, truth)`` (truth by value name; ``"probabilities"``: the classes;
    ``"groups"``, where answers share their errors: each answer's group, as
    :func:`effective_count` takes them)."""

    name: str
    kind: str
    make: Callable[[], tuple[tuple[np.ndarray, ...], dict[str, np.ndarray]]]
    pieces: int = 1
    """Records of this many times the graph's length, made as that many records each (a
    record's pieces one after another): its answer is theirs combined as the device combines
    them (:func:`wtml.runtime.onset.combine_pieces`, the export's ``pieces_limit``)."""


# ------------------------------------------------------------------------------ metrics


def wilson(k: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a share ``k / n`` (95 % at ``z`` 1.96); (0, 1) for
    ``n = 0``."""
    if n == 0:
        return 0.0, 1.0
    p = k / n
    mid = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * np.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return float(mid - half), float(mid + half)


def scores(err: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """``err/σ`` per row ``(n,)``: NaN where ``err`` or ``sigma`` is not finite (no answer,
    or no interval: out of domain), +inf for 0/0 (a zero σ misses even an exact answer)."""
    err, sigma = np.asarray(err, float), np.asarray(sigma, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        z = err / sigma
    z[np.isnan(z)] = np.inf
    z[~(np.isfinite(err) & np.isfinite(sigma))] = np.nan
    return z


def hits(err: np.ndarray, sigma: np.ndarray, wide: float | np.ndarray = WIDE
         ) -> np.ndarray:
    """Per row whether ±1σ and ±wide·σ (the 68 % and 95 % intervals; ``wide`` one, or
    ``(n,)`` per row: an export's fitted widths) hold the truth, ``(n, 2)`` float: 1, 0, or
    NaN where there is no answer (:func:`scores`)."""
    z = np.abs(scores(err, sigma))
    with np.errstate(invalid="ignore"):
        out = np.stack([z <= 1.0, z <= wide], 1).astype(float)
    out[np.isnan(z)] = np.nan
    return out


def coverage_cell(covered: np.ndarray, groups: np.ndarray | None = None) -> dict:
    """Coverage of the two intervals from :func:`hits` ``(n, 2)`` (rows of NaN left out):
    ``n``, ``cover`` (two shares), ``interval`` (their Wilson intervals, over
    :func:`effective_count` answers where ``groups`` ``(n,)`` labels rows that share their
    errors), ``n_effective`` (that count per level) and ``verdict`` per level
    (``"ok"``, ``"miss"``: off by more than :data:`TOLERANCE` and significantly so, ``"?"``:
    off by more on too few rows to tell)."""
    kept = np.isfinite(covered).all(1)
    covered = covered[kept]
    n = len(covered)
    if groups is not None:
        if np.shape(groups) != kept.shape:
            raise ValueError(f"groups: one label per row, {kept.shape}; got {np.shape(groups)}")
        groups = np.asarray(groups)[kept]
    cover, interval, verdict, worth = [], [], [], []
    for level, nominal in enumerate(NOMINAL):
        k = int(covered[:, level].sum())
        share = k / n if n else float("nan")
        m = n if groups is None else effective_count(covered[:, level], groups)
        lo, hi = wilson(k, n) if m == n else wilson(share * m, m)
        worth.append(m)
        cover.append(share)
        interval.append((lo, hi))
        off = not n or abs(share - nominal) > TOLERANCE
        sure = n >= MIN_VERDICT and not lo <= nominal <= hi
        verdict.append("ok" if not off else "miss" if sure else "?")
    return {"n": n, "cover": cover, "interval": interval, "verdict": verdict,
            "n_effective": worth}


def by_range(covered: np.ndarray, truth: np.ndarray, edges: np.ndarray,
             groups: np.ndarray | None = None) -> list[dict]:
    """:func:`coverage_cell` in each range of ``truth`` between ``edges`` ``(K+1,)`` (the
    outer edges widened to hold every row), then over all rows; ``groups``: as there."""
    inner = np.searchsorted(edges[1:-1], truth, side="right")
    cells = [coverage_cell(covered[inner == k], None if groups is None else groups[inner == k])
             for k in range(len(edges) - 1)]
    return cells + [coverage_cell(covered, groups)]


def misses(cells: list[dict]) -> int:
    """The ✗ verdicts over ``cells`` (:func:`coverage_cell`'s), both levels counted."""
    return sum(v == "miss" for c in cells for v in c["verdict"])


def exact_hits(answered: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One draw of an exact interval's :func:`hits` ``(n, 2)`` on the rows ``answered``
    ``(n,)`` bool (the others NaN): each covered by the 68 % interval with probability 0.6827
    and by the 95 % one, which holds it, with 0.95, independently of the other rows."""
    u = rng.random(len(answered))
    drawn = np.stack([u < NOMINAL[0], u < NOMINAL[1]], 1).astype(float)
    drawn[~answered] = np.nan
    return drawn


def chance_misses(covered: np.ndarray, truth: np.ndarray, edges: np.ndarray,
                  groups: np.ndarray | None = None, draws: int = CHANCE_DRAWS,
                  seed=0) -> np.ndarray:
    """How many ✗ an exact interval earns by chance on the cells of one row: its answers
    drawn ``draws`` times, each covered by the 68 % interval with probability 0.6827 and by
    the 95 % one (which holds it) with 0.95, independently, on the same answers as
    ``covered`` ``(n, 2)`` (:func:`hits`; rows of NaN stay without one), in the same ranges
    of ``truth`` ``(n,)`` between ``edges`` with the same ``groups``, judged as
    :func:`by_range` judges them. Returns the ✗ count of each draw ``(draws,)`` (both levels,
    every range and the row's whole: ``2 × (len(edges))`` verdicts). Each cell errs about
    one time in twenty (the binomial interval's 5 %, less where 3 points are wider than it),
    so a table of many cells shows some ✗ even for an exact interval; for groups this is
    the count of independent answers (answers of one group that fail together earn about as
    many where they share little, up to twice as many where they fail whole). ``seed``: any
    seed of numpy's ``default_rng``."""
    rng = np.random.default_rng(seed)
    answered = np.isfinite(covered).all(1)
    return np.array([misses(by_range(exact_hits(answered, rng), truth, edges, groups))
                     for _ in range(draws)], int)


def ece_floor(confidence: np.ndarray, draws: int = 400, seed: int = 0,
              worth: float | None = None) -> tuple[float, float]:
    """The expected calibration error of a perfectly calibrated classifier with these
    ``confidence`` values ``(n,)``: each answer right with probability its confidence; the
    median and the 95th percentile over ``draws`` draws (what sampling alone gives). ``worth``:
    how many independent answers the n are worth where they share their errors
    (:func:`~wtml.bench.resampling.effective_count`); each draw then judges that many of
    them, drawn at random (an ECE's sampling error shrinks with the answers' worth, not their
    count)."""
    rng = np.random.default_rng(seed)
    conf = np.asarray(confidence, float)
    take = len(conf) if worth is None else int(np.clip(round(worth), 1, len(conf)))
    eces = []
    for _ in range(draws):
        c = conf if take == len(conf) else rng.choice(conf, take, replace=False)
        eces.append(binned_calibration(c, rng.random(take) < c)[0])
    return float(np.median(eces)), float(np.quantile(eces, 0.95))


# ------------------------------------------------------------------------------ answers


@torch.no_grad()
def raw_answers(module, names: tuple[str, ...], inputs: tuple[np.ndarray, ...]
                ) -> dict[str, np.ndarray]:
    """The checkpoint's own graph before recalibration (its net and domain gate, σ NaN out
    of domain) on the export's inputs: each output by name."""
    graph = Gated(module.net, module.gate, tuple(
        k for k, n in enumerate(names) if n in ("sigma", "log_sigma"))).eval()
    parts = [graph(*(torch.tensor(np.asarray(x[s:s + BATCH]), dtype=torch.float32)
                     for x in inputs)) for s in range(0, len(inputs[0]), BATCH)]
    return {name: torch.cat([p[k] for p in parts]).double().numpy()
            for k, name in enumerate(names)} | {
        "in_domain": torch.cat([p[-2] for p in parts]).numpy()}


def score(decoder, module, names: tuple[str, ...], sets: list[RecordSet], progress=print
          ) -> dict:
    """Every set's answers from the export (``decoder``, recalibrated) and the checkpoint
    (``module``, raw): per interval of the export's metadata the errors, both σ and the
    export's 95 % width in σ per answer (``wide``; the raw σ's is 1.96), per set; and for a
    classifier its probabilities. Returns ``{"intervals": {sigma name: [per set {"name",
    "kind", "truth", "err", "groups", "sigma", "wide", "raw", "flagged"}]}, "classes": [per set
    {"name", "kind", "labels", "after", "before", "inside", "groups", "flagged"}]}``."""
    u = decoder.uncertainty
    out = {"intervals": {r.sigma: [] for r in u.intervals}, "classes": []}
    for s in sets:
        progress(f"coverage: {decoder.task}: {s.name}")
        inputs, truth = s.make()
        after = decoder.run(*inputs)
        before = raw_answers(module, names, inputs)
        if s.pieces > 1:
            limit = decoder.meta.domain.pieces_limit
            after, before = (combine_pieces(a, s.pieces, limit) for a in (after, before))
        inside = after["in_domain"]
        flagged = float(1 - inside.mean())
        for r in u.intervals:
            err = errors(after[r.value], truth[r.value], r.log_value)
            # the export's σ is in its output whatever the net had; the net's as it stored it
            sigma = np.exp(after[r.sigma]) if r.stored == "log_std" else after[r.sigma]
            raw = (None if r.stored == "none" else
                   raw_sigma({"sigma": r.sigma, "stored": r.stored}, before, len(err)))
            out["intervals"][r.sigma].append({
                "name": s.name, "kind": s.kind, "truth": truth[r.value], "err": err,
                "groups": truth.get("groups"),
                "sigma": np.where(inside, sigma, np.nan), "wide": r.wide(after[r.by], after),
                "raw": None if raw is None else np.where(inside, raw, np.nan),
                "flagged": flagged})
        if u.probabilities is not None:
            out["classes"].append({"name": s.name, "kind": s.kind,
                                   "labels": truth[u.probabilities],
                                   "after": after[u.probabilities],
                                   "before": before[u.probabilities], "inside": inside,
                                   "groups": truth.get("groups"), "flagged": flagged})
    return out


# ------------------------------------------------------------------------------ the tasks


def _test_shard(data_dir: Path, keys: tuple[str, ...], limit: int | None = None) -> dict:
    manifest = read_manifest(data_dir)
    test = split_shards(manifest["n_shards"], 1, 1)["test"]
    data = load_shards(data_dir, test)
    return {k: data[k][:limit] for k in keys}


def fluid_sets(paths: dict, scene, decoder, records: dict, seed: int) -> list[RecordSet]:
    """The test shard, fresh records of the trained scene, and devices of issue 21's spread
    (the sphere's radius ±1 % included) and of the radius alone (``records["fluid"]``
    each): held out, but where a row's spread is the trained one (a decoder trained with
    the radius declared, ``configs/scenes/fluid_radius.yaml``: issue 21's is its own)."""
    data_dir, n = Path(paths["data"]), records["fluid"]
    from wtml.bench.fluid import REFERENCE_SPREAD
    from wtml.scenes.fluid import DeviceSpread

    def made(records: dict):
        return ((records["ze"].real, records["ze"].imag, *flat_parts(records["t"])),
                {"eta": records["eta"], "rho": records["rho"]})

    def fresh(spread, k: int):
        return lambda: made(dataclasses.replace(scene, spread=spread).simulate(
            n, np.random.default_rng([seed, k])))

    return [RecordSet("test shard", "test shard",
                      lambda: made(_test_shard(data_dir, ("ze", "t", "eta", "rho")))),
            RecordSet("fresh records of the trained scene", "in family",
                      fresh(scene.spread, 0)),
            *(RecordSet(name, "in family" if spread == scene.spread else "held out",
                        fresh(spread, k))
              for k, (name, spread) in enumerate(
                  (("issue 21 spread (sphere radius ±1 % included)", REFERENCE_SPREAD),
                   ("sphere radius ±1 % alone",
                    DeviceSpread(sphere_radius=REFERENCE_SPREAD.sphere_radius))), 1))]


BAYES_KINDS = ("test shard", "in family")
"""The fluid rows on which the exact Bayes posterior is the best achievable (the trained
scene's prior, noise and spread: its own records)."""


def fluid_bayes_rows(scene, sets: list[RecordSet], progress=print) -> dict[str, list[dict]]:
    """The best achievable coverage beside the fluid decoder's: the exact posterior
    (:class:`~wtml.baselines.fluid_bayes.BayesFluid`) on the sets of :data:`BAYES_KINDS`,
    its mean ± 1σ / 1.96σ (the decoder's form of interval) and its central credible
    intervals, as ``interval_table``'s extra rows per value (``"eta"``: of ln η; ``"rho"``).
    Coverage per range of the truth is not guaranteed even here: the posterior is calibrated
    over the prior as a whole, and given the truth near an end of the prior its mass leans
    inward."""
    from wtml.baselines.fluid_bayes import BayesFluid

    bayes = BayesFluid(scene)
    rows: dict[str, list[dict]] = {"eta": [], "rho": []}
    for s in sets:
        if s.kind not in BAYES_KINDS:
            continue
        progress(f"coverage: fluid: the Bayes posterior on {s.name}")
        (ze_re, ze_im, t_re, t_im), truth = s.make()
        t = (t_re + 1j * t_im).reshape(*t_re.shape[:-1], 2, 2)
        got = bayes.intervals(ze_re + 1j * ze_im, t, NOMINAL)
        for name, value in (("eta", np.log(truth["eta"])), ("rho", truth["rho"])):
            g = got[name]
            low, high = g["central"][..., 0], g["central"][..., 1]
            central = ((low <= value[:, None]) & (value[:, None] <= high)).astype(float)
            for label, covered in (("Bayes posterior: mean ± zσ",
                                    hits(value - g["mean"], g["std"])),
                                   ("Bayes posterior: central credible", central)):
                rows[name].append({"name": s.name, "kind": s.kind, "label": label,
                                   "truth": truth[name], "hits": covered, "flagged": None})
    return rows


RADIAL_SPREAD_SCENE = "configs/scenes/radial_spread.yaml"
"""Devices off the preset for the radial rows: issue 21's manufacturing spread (its
``spread`` block, on the trained scene: on the shipped one the same records as this scene's)."""


def radial_sets(paths: dict, scene, decoder, records: dict, seed: int) -> list[RecordSet]:
    """The test shard (its first ``4 n``), ``n = records["radial"]`` fresh records, as many
    of devices of issue 21's spread (:data:`RADIAL_SPREAD_SCENE`) and, where the folder
    ``paths["invalid"]`` exists, the invalid contacts."""
    data_dir, n, invalid_dir = Path(paths["data"]), records["radial"], paths.get("invalid")
    from wtml.scenes import load_scene

    def made(records: dict):
        return ((records["ze"].real, records["ze"].imag, records["ref"].real,
                 records["ref"].imag), {"distance": records["distance"]})

    sets = [RecordSet("test shard", "test shard", lambda: made(_test_shard(
                data_dir, ("ze", "ref", "distance"), 4 * n))),
            RecordSet("fresh records of the trained scene", "in family",
                      lambda: made(scene.simulate(n, np.random.default_rng([seed, 0])))),
            RecordSet("devices of issue 21's spread", "held out",
                      lambda: made(dataclasses.replace(  # on the trained scene's tones
                          scene, spread=load_scene(RADIAL_SPREAD_SCENE).spread).simulate(
                          n, np.random.default_rng([seed, 1]))))]
    if invalid_dir is not None and Path(invalid_dir).is_dir():
        sets.append(RecordSet("invalid contacts (thesis §5.5.4)", "held out", lambda: made(
            load_shards(invalid_dir, list(range(read_manifest(invalid_dir)["n_shards"]))))))
    return sets


def onset_truth(records: dict) -> dict[str, np.ndarray]:
    """An onset row's truth: ``gap`` (m), and ``groups``, each record's device (one label per
    HUE(0): a device's calibration is its own) where the records come from more than one.
    A scene draws its devices per call (``spread.devices``, 256), so a row's records share
    them, and with them a part of their errors: 1020 answers of the main job's decoder on
    252 devices were worth 574 independent ones (:func:`effective_count`; 30 Nov), and such
    rows' coverage scattered 62.6–69.5 % between draws of 1200 records. One device (the
    preset alone) shares nothing the records do not each have: no groups. (A scene with a
    stored calibration gives every device the preset's HUE(0): its rows get no groups, and
    their verdicts count records of one device as independent.)"""
    _, device = np.unique(np.asarray(records["hue0"]), return_inverse=True)
    return {"gap": records["gap"]} | ({"groups": device} if device.max(initial=0) > 0 else {})


def onset_sets(paths: dict, scene, decoder, records: dict, seed: int) -> list[RecordSet]:
    """The test shard, then the onset transfer table's rows
    (:func:`wtml.bench.onset_transfer.onset_variants`, ``records["onset"]`` records each),
    the independent simulator's (``records["independent"]``; 0: none), and the trained
    scene and the object moving most with records of twice the whisk cycles, each answered
    as two pieces (``records["onset"]`` each; :attr:`RecordSet.pieces`), where the export
    states its pieces' limit."""
    data_dir, n = Path(paths["data"]), records["onset"]
    independent = records.get("independent", 0)
    from wtml.bench.onset_transfer import independent_variant, onset_variants
    from wtml.exporters.onset import piece_inputs, record_inputs, twice_as_long

    keys = ("e", "i", "t_probe", "hue0", "gap")

    def made(records: dict):
        return record_inputs(records), onset_truth(records)

    def pieces(records: dict):
        return piece_inputs(records, scene), onset_truth(records)

    sets = [RecordSet("test shard", "test shard", lambda: made(_test_shard(data_dir, keys)))]
    variants = onset_variants(scene) + ([independent_variant(scene)] if independent else [])
    for k, v in enumerate(variants):
        count = independent if v.kind == "independent" else n
        sets.append(RecordSet(v.name, v.kind, lambda v=v, k=k, count=count: made(
            v.make(count, np.random.default_rng([seed, 9100, k])))))
    if not decoder.meta.domain.pieces_limit:  # an export that refuses such records
        return sets
    twice = twice_as_long(scene)
    rows = onset_variants(twice)
    longer = [v for v in rows if v.kind == "in family"][:1] + [
        v for v in rows if "base" in v.name][-1:]
    for k, v in enumerate(longer):  # the trained scene; the object moving most
        sets.append(RecordSet(f"{v.name}; records of {twice.drive.cycles:g} whisk cycles read "
                              "as two", v.kind,
                              lambda v=v, k=k: pieces(v.make(n, np.random.default_rng(
                                  [seed, 9200, k]))), pieces=2))
    return sets


def texture_sets(paths: dict, scene, decoder, records: dict, seed: int) -> list[RecordSet]:
    """The test shard's windows (the export's), then the texture transfer table's rows
    (:func:`wtml.bench.texture_transfer.texture_variants`, ``records["texture"]`` records
    each); a window's group is its specimen (its records' windows share its grains)."""
    data_dir, n, window = Path(paths["data"]), records["texture"], decoder.meta.n_samples
    from wtml.bench.texture_transfer import texture_variants

    def made(records: dict):
        per = records["e"].shape[1] // window
        cut = [np.asarray(records[c])[:, :per * window].reshape(-1, window) for c in "ei"]
        t = np.repeat(records["t"], per, 0)
        return ((*cut, *flat_parts(t)),
                {"grain": np.repeat(records["grain_m"], per),
                 "probabilities": np.repeat(records["grade"], per),
                 "groups": np.repeat(records["specimen"], per)})

    keys = ("e", "i", "t", "grain_m", "grade", "specimen")
    sets = [RecordSet("test shard", "test shard", lambda: made(_test_shard(data_dir, keys)))]
    for k, v in enumerate(texture_variants(scene)):
        sets.append(RecordSet(v.name, v.kind, lambda v=v, k=k: made(
            v.make(n, np.random.default_rng([seed, 9100, k])))))
    return sets


# ------------------------------------------------------------------------------ report


def _fmt_range(value: str, lo: float, hi: float) -> str:
    f, unit = DISPLAY[value]
    if value == "eta":
        return f"{lo:.2g}–{hi:.2g} {unit}"
    return f"{f * lo:.4g}–{f * hi:.4g} {unit}"


def _cell(c: dict) -> str:
    if not c["n"]:
        return "–"
    marks = {"ok": "", "miss": " ✗", "?": " ?"}
    return " / ".join(f"{100 * x:.1f}{marks[v]}"
                      for x, v in zip(c["cover"], c["verdict"], strict=True))


def shape_of(err: np.ndarray, sigma: np.ndarray) -> tuple[float, float] | None:
    """Where an interval misses, whether its answers are off or scattered: the median of
    ``err/σ`` over the answers with a σ (a bias, in σ) and the 68th percentile of its
    distance from that median (the spread about it: 1 where ±1σ about the bias would
    cover 68 %), over the answers :func:`hits` judges (:func:`scores`). None without
    answers (every one flagged)."""
    z = scores(err, sigma)
    z = z[~np.isnan(z)]
    if not len(z):
        return None
    mid = float(np.median(z))
    with np.errstate(invalid="ignore"):
        return mid, float(np.quantile(np.abs(z - mid), NOMINAL[0]))


def interval_table(task: str, r, rows: list[dict], extra: list[dict] = ()
                   ) -> tuple[list[str], list]:
    """Markdown lines of one interval's coverage table and its rows as JSON-ready dicts;
    ``extra``: rows of another method (``{"name", "kind", "label", "truth", "hits",
    "flagged"}``: its own intervals' :func:`hits`, e.g. the sbi posterior's central credible
    intervals)."""
    truth = np.asarray(rows[0]["truth"], float)
    edges = np.quantile(truth[np.isfinite(truth)], np.linspace(0, 1, N_RANGES + 1))
    heads = [_fmt_range(r.value, a, b) for a, b in zip(edges[:-1], edges[1:], strict=True)]
    what = f"ln {r.value}" if r.log_value else r.value
    lines = [f"### {task}: {what} (σ output `{r.sigma}`)", "",
             "| records | kind | σ | n | flagged | err/σ: median, spread | all | "
             + " | ".join(heads) + " |",
             "|---" * (7 + len(heads)) + "|"]
    out, tally = [], {}
    for row in [*rows, *extra]:
        answers = ([(row["label"], row["hits"], None)] if "hits" in row else
                   [(label, hits(row["err"], sigma, wide), shape_of(row["err"], sigma))
                    for label, sigma, wide in (("raw", row["raw"], WIDE),
                                               ("recalibrated", row["sigma"], row["wide"]))
                    if sigma is not None])
        for label, covered, shape in answers:
            groups = row.get("groups")
            groups = None if groups is None else np.asarray(groups)
            row_truth = np.asarray(row["truth"], float)
            cells = by_range(covered, row_truth, edges, groups)
            flagged = row.get("flagged")
            lines.append(f"| {row['name']} | {row['kind']} | {label} | {cells[-1]['n']} | "
                         + ("–" if flagged is None else f"{100 * flagged:.1f} %") + " | "
                         + ("–" if shape is None else f"{shape[0]:+.2f}, {shape[1]:.2f}")
                         + " | " + " | ".join(_cell(c) for c in [cells[-1], *cells[:-1]])
                         + " |")
            chance = chance_misses(covered, row_truth, edges, groups,
                                   seed=[zlib.crc32(f"{task} {r.value}".encode()), len(out)])
            missed, high = misses(cells), float(np.quantile(chance, 0.95))
            out.append({"name": row["name"], "kind": row["kind"], "sigma": label,
                        "flagged": flagged, "z_median": None if shape is None else shape[0],
                        "z_spread": None if shape is None else shape[1],
                        "all": cells[-1], "ranges": cells[:-1],
                        "misses": missed, "chance_misses": [float(np.median(chance)), high]})
            physics = "trained" if row["kind"] in TRAINED_KINDS else "not trained"
            seen, count, drawn, beyond = tally.get((label, physics), (0, 0, 0, []))
            if missed > high:
                beyond = [*beyond, f"{row['name']} ({missed})"]
            tally[label, physics] = (seen + missed, count + 2 * len(cells), drawn + chance,
                                     beyond)
    lines += ["", f"✗ against chance: an exact interval's answers drawn {CHANCE_DRAWS} times "
              "on the same cells and judged alike (`wtml.bench.coverage.chance_misses`); "
              "rows beyond: those whose own ✗ exceed their chance's 95th percentile (each "
              "row by itself: among many, some exact ones would be named).", "",
              "| σ | physics | verdicts | ✗ | an exact interval's ✗: median | 95th pct | "
              "draws with as many or more | rows beyond |", "|---" * 8 + "|"]
    lines += [f"| {label} | {physics} | {count} | {seen} | {np.median(drawn):.0f} | "
              f"{np.quantile(drawn, 0.95):.0f} | {_share(np.mean(drawn >= seen))} | "
              f"{'; '.join(beyond) or 'none'} |"
              for (label, physics), (seen, count, drawn, beyond) in tally.items()]
    return lines, out


def ece_verdict(ece: float, floor_high: float) -> str:
    """``"ok"`` where ``ece`` meets :data:`ECE_TARGET`; ``"miss"`` where it does not and a
    perfectly calibrated classifier with the same confidences shows as much in fewer than 5 %
    of draws (above its 95th percentile ``floor_high``); ``"?"`` otherwise (over the target,
    but within what sampling alone gives on so few answers). The coverage cells' rule:
    off the target, and beyond chance."""
    if ece <= ECE_TARGET:
        return "ok"
    return "miss" if ece > floor_high else "?"


def recalibration_text(u) -> str:
    """A classifier's recalibration (:class:`~wtml.runtime.metadata.Uncertainty`) in words:
    its temperature, and its top label's slope and bias where it has them."""
    text = f"T = {u.temperature:.3g}"
    if u.top_slope is None:
        return text
    return text + f", top label: slope {u.top_slope:.3g}, bias {u.top_bias:+.3g}"


def class_table(rows: list[dict], how: str) -> tuple[list[str], list]:
    """Markdown lines of the classifier's calibration per set, on its in-domain windows
    (``how``: the recalibration's parameters, :func:`recalibration_text`)
    (``row["inside"]``), and its rows as dicts. Where a row's answers come in ``"groups"``
    that share their errors (a specimen's windows), its floor is drawn on what they are worth
    (:func:`ece_floor`'s ``worth``: the effective count of its right answers)."""
    marks = {"ok": "", "miss": " ✗", "?": " ?"}
    lines = ["| records | kind | windows in domain | flagged | accuracy | ECE raw | ECE "
             f"recalibrated ({how}) | ECE of a calibrated classifier (median, 95th pct) |",
             "|---" * 8 + "|"]
    out = []
    for row in rows:
        inside = np.asarray(row["inside"], bool)
        labels = np.asarray(row["labels"], int)[inside]
        after = np.asarray(row["after"])[inside]
        raw, _ = expected_calibration_error(np.asarray(row["before"])[inside], labels)
        ece, _ = expected_calibration_error(after, labels)
        hit = after.argmax(1) == labels
        groups = row.get("groups")
        worth = (None if groups is None or not len(labels) else
                 effective_count(hit, np.asarray(groups)[inside]))
        floor = ece_floor(after.max(1), worth=worth)
        verdict = ece_verdict(ece, floor[1])
        acc = float(np.mean(hit))
        worth_text = "" if worth is None else f" (worth {worth:.0f})"
        lines.append(f"| {row['name']} | {row['kind']} | {len(labels)}{worth_text} | "
                     f"{100 * row['flagged']:.1f} % | {100 * acc:.1f} % | {100 * raw:.1f} % | "
                     f"{100 * ece:.1f} %{marks[verdict]} | {100 * floor[0]:.1f} %, "
                     f"{100 * floor[1]:.1f} % |")
        out.append({"name": row["name"], "kind": row["kind"], "windows": len(labels),
                    "accuracy": acc, "ece_raw": raw, "ece": ece, "ece_floor": floor,
                    "worth": worth, "verdict": verdict, "flagged": row["flagged"]})
    return lines, out


def reliability_plot(row: dict, path: Path) -> None:
    """The reliability curve (accuracy against confidence per bin) of one set's in-domain
    windows, raw and recalibrated, with the diagonal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    inside = np.asarray(row["inside"], bool)
    labels = np.asarray(row["labels"], int)[inside]
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot([0, 1], [0, 1], color="0.6", lw=1, label="calibrated")
    for key, label in (("before", "raw"), ("after", "recalibrated")):
        ece, curve = expected_calibration_error(np.asarray(row[key])[inside], labels)
        ok = curve["count"] > 0
        ax.plot(curve["confidence"][ok], curve["accuracy"][ok], "o-",
                label=f"{label} (ECE {100 * ece:.1f} %)")
    ax.set_xlabel("confidence (top probability)")
    ax.set_ylabel("accuracy")
    ax.set_title(f"texture decoder, {row['name']} ({len(labels)} windows in domain)")
    ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ------------------------------------------------------------------------------ the bench


TASK_SETS = {"fluid": fluid_sets, "radial": radial_sets, "onset": onset_sets,
             "texture": texture_sets}
"""Each task's record sets (its test shard, fresh records, its held-out physics)."""


def pick_rows(sets: dict[str, list[RecordSet]], patterns: list[str]
              ) -> dict[str, list[RecordSet]]:
    """The tasks that have a row whose name holds one of ``patterns`` (case-insensitive),
    each with those rows after its first (the test shard: its truth sets the ranges, and its
    probabilities the reliability curve): one row measured on many records without every
    other row's cost. ``sets``: every row of each task, by task.

    Raises:
        ValueError: a pattern that matches no row of any task (naming the rows there are),
            before anything is measured."""
    def held(s: RecordSet, keys: list[str]) -> bool:
        return any(k.lower() in s.name.lower() for k in keys)

    every = [s for rows in sets.values() for s in rows]
    lost = [k for k in patterns if not any(held(s, [k]) for s in every)]
    if lost:
        raise ValueError(f"--rows {', '.join(map(repr, lost))} matches no row; the rows: "
                         f"{'; '.join(s.name for s in every)}")
    return {task: [rows[0], *[s for s in rows[1:] if held(s, patterns)]]
            for task, rows in sets.items() if any(held(s, patterns) for s in rows)}


def run_coverage(tasks: dict[str, dict], out: str | Path, *, records: dict[str, int],
                 seed: int = 2025, threads: int = 2, sbi_simulations: int = 0,
                 sbi_epochs: int = 50, only_rows: list[str] | None = None,
                 progress=print) -> str:
    """Run the bench; writes ``report.md``, ``summary.json`` and ``reliability.png`` under
    ``out`` and returns the report.

    Args:
        tasks: per task, ``{"data", "checkpoint", "model"}`` (and radial's ``"invalid"``).
        out: the folder.
        records: fresh records per row, per task (onset: and ``"independent"``).
        seed: the fresh records' seed.
        threads: torch and onnxruntime threads.
        sbi_simulations: with fluid, the simulations of ``sbi``'s NPE on the fluid scene
            (:func:`wtml.bench.sbi_fluid.run_npe`, at most ``sbi_epochs`` epochs), its rows
            beside the decoder's on the same fresh records; 0: none. Without the ``sbi``
            package the report says so.
        only_rows: only the rows whose names hold one of these, and their tasks' test
            shards (:func:`pick_rows`); None: every row.
    """
    torch.set_num_threads(threads)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    plans = {}  # each task's export, scene and rows, all named before any is measured
    for task, paths in tasks.items():
        decoder = load_export(paths["model"], threads=threads)[0]
        scene = dataset_scene(paths["data"])
        plans[task] = (decoder, scene, TASK_SETS[task](paths, scene, decoder, records, seed))
    if only_rows:
        kept = pick_rows({task: plan[2] for task, plan in plans.items()}, only_rows)
        plans = {task: (*plans[task][:2], rows) for task, rows in kept.items()}
    sbi, sbi_note = None, []
    if sbi_simulations and "fluid" in plans:
        from wtml.bench.sbi_fluid import run_npe

        scene = plans["fluid"][1]
        progress(f"coverage: sbi NPE on the fluid scene ({sbi_simulations} simulations)")
        try:  # the fluid rows' fresh records (fluid_sets: the same seed)
            sbi = run_npe(scene, scene.simulate(records["fluid"],
                                                np.random.default_rng([seed, 0])),
                          simulations=sbi_simulations, seed=seed, max_epochs=sbi_epochs,
                          threads=threads)
        except ModuleNotFoundError as err:
            if err.name != "sbi":
                raise
            sbi_note = ["## sbi", "", "Not run: the `sbi` package is not installed (pip "
                        "install -c constraints.txt -e '.[sbi]').", ""]
    lines = ["# wtml bench coverage: honest uncertainty", "",
             "Coverage of the 68 % / 95 % intervals in % (raw: ±1σ / ±1.96σ; recalibrated: ±1σ / "
             "± the export's 95 % width) over the in-domain answers, "
             f"overall and per range of the target (quintiles of the test shard's truth). ✗: "
             f"off by more than {100 * TOLERANCE:.0f} points and outside the binomial 95 % "
             f"interval (texture: over the answers' worth, windows of one specimen sharing "
             f"their errors); ?: off by more on too few answers to tell. raw: the checkpoint's "
             f"own σ; recalibrated: the export's. err/σ: its median over the row's answers (a "
             f"bias, in σ) and the 68th percentile of its distance from that median (the "
             f"spread about it: 1 where ±1σ about the bias would cover 68 %): a miss with "
             f"the median near 0 and the spread off 1 is σ's width, not a bias (–: a row of "
             f"another method's own intervals, or with every answer flagged).", ""]
    summary: dict = {"tolerance": TOLERANCE, "nominal": list(NOMINAL), "tasks": {}}
    for task, (decoder, scene, sets) in plans.items():
        paths = tasks[task]
        module = load_decoder(paths["checkpoint"])
        u = decoder.uncertainty
        added = {r.sigma for r in u.intervals if r.stored == "none"} - set(scene.OUTPUTS)
        names = tuple(name for name in decoder.outputs if name not in added)
        scored = score(decoder, module, names, sets, progress)
        bayes = fluid_bayes_rows(scene, sets, progress) if task == "fluid" else {}
        lines += [f"## {task} ({paths['model']}; recalibrated on {u.fitted_on})", ""]
        entry: dict = {"model": str(paths["model"]), "fitted_on": u.fitted_on,
                       "intervals": {}}
        for r in u.intervals:
            extra = ((sbi or {}).get("rows", {}).get(r.value, []) + bayes.get(r.value, [])
                     if task == "fluid" else [])
            table, rows = interval_table(task, r, scored["intervals"][r.sigma], extra)
            scales = ", ".join(f"{s:.3g}" for s in r.scales)
            widths = ", ".join(f"{w:.3g}" for w in r.widths or (WIDE,))
            lines += table + ["", f"Recalibration: {r.stored} σ × ({scales}), 95 % widths "
                              f"({widths})σ, in {len(r.scales)} range(s) of the answer "
                              f"`{r.by}`; on its {r.n} held-out answers "
                              f"coverage {_pair(r.coverage_before)} → "
                              f"{_pair(r.coverage_after)}.", ""]
            entry["intervals"][r.sigma] = {"recalibration": dataclasses.asdict(r),
                                           "rows": rows}
        if scored["classes"]:
            how = recalibration_text(u)
            table, rows = class_table(scored["classes"], how)
            lines += [f"### {task}: class probabilities (expected calibration error, 15 bins, "
                      f"in-domain windows; target ≤ {100 * ECE_TARGET:.0f} %: ✗ above it and "
                      "above a calibrated classifier's 95th percentile, ? above it but within)",
                      "", *table, "",
                      f"Recalibration ({how}) fitted on the held-out "
                      f"windows: ECE "
                      f"{100 * u.ece_before:.1f} % → {100 * u.ece_after:.1f} % there. "
                      "Reliability curve of the test shard: `reliability.png`.", ""]
            reliability_plot(scored["classes"][0], out / "reliability.png")
            entry["classes"] = {"temperature": u.temperature, "top_slope": u.top_slope,
                                "top_bias": u.top_bias, "rows": rows}
        summary["tasks"][task] = entry
    if sbi is not None:
        lines += sbi["report"]
        summary["sbi"] = sbi["summary"]
    lines += sbi_note
    report = "\n".join(lines) + "\n"
    (out / "report.md").write_text(report)
    (out / "summary.json").write_text(  # strict JSON: an empty cell's NaN as null
        json.dumps(strict_json(summary), indent=1, default=_plain, allow_nan=False) + "\n")
    return report


def _share(x: float) -> str:
    """A share of :data:`CHANCE_DRAWS` draws in %, ``< 1/draws`` where none."""
    return f"< {100 / CHANCE_DRAWS:.1g} %" if x == 0 else f"{100 * x:.1f} %"


def _pair(x) -> str:
    return "–" if not x else f"{100 * x[0]:.1f} / {100 * x[1]:.1f}"


def _plain(x):
    if isinstance(x, np.ndarray | np.generic):
        return x.tolist()
    raise TypeError(f"not JSON: {type(x).__name__}")
