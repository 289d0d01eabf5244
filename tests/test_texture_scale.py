"""``wtml bench texture-scale`` (issue 25 §3): the nested shard plan, the recipes, the fast
training's loss against the decoder's own, a tiny run end to end, resumed, and its MiniRocket
rows against MiniRocket fitted directly."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from wtml.baselines.texture_peers import MiniRocketPeer
from wtml.bench.texture_rate import grade_scores
from wtml.bench.texture_scale import (
    features_at,
    plan_shards,
    read_recipe,
    run_scale,
    shard_bank,
    split_scenes,
)
from wtml.cli import main
from wtml.data.datamodule import task_tensors
from wtml.data.shards import load_shards
from wtml.scenes import load_scene
from wtml.schema import to_dict

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs/scenes/texture.yaml"
RECIPES = [str(ROOT / "configs/texture.yaml"), str(ROOT / "configs/variants/texture_full.yaml")]
SIZES = (5, 10)


def _small_scene(folder: Path) -> Path:
    """The texture scene in shards of 5 specimens (one per grade) of 2 records of 0.5 s: 2
    windows of 0.25 s each."""
    d = to_dict(load_scene(SCENE))
    d.update(specimens_per_grade=1, samples=10, shards=1)
    d["drive"]["record_s"] = 0.5
    path = folder / "small.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


def _cli(scene: Path, work: Path, out: Path, *extra: str) -> list[str]:
    return ["bench", "texture-scale", "--scene", str(scene), "--sizes",
            ",".join(map(str, SIZES)), "--test-specimens", "10", "--epochs", "2", "--workers",
            "1", "--oracle-draws", "500", "--work", str(work), "--out", str(out),
            "--recipes", *RECIPES, *extra]


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """A tiny study run twice on the same work folder: ``(scene, work, first out, second
    out, shard files' mtimes after the first)``."""
    tmp = tmp_path_factory.mktemp("scale")
    scene = _small_scene(tmp)
    assert main(_cli(scene, tmp / "work", tmp / "one")) == 0
    stamps = {p: p.stat().st_mtime_ns for p in (tmp / "work").rglob("shard-*")}
    assert main(_cli(scene, tmp / "work", tmp / "two")) == 0
    return scene, tmp / "work", tmp / "one", tmp / "two", stamps


def test_the_training_sizes_nest_in_whole_shards_and_others_are_refused():
    scene = load_scene(SCENE)
    plan = plan_shards(scene, [640, 2560, 10240], 480)
    assert (plan.specimens, plan.records, plan.test_shards) == (40, 80, 12)
    assert plan.sizes == {640: 16, 2560: 64, 10240: 256} and plan.train_shards == 256
    for sizes, test, needle in (([100], 480, "--sizes: whole shards of 40 specimens"),
                                ([0], 480, "--sizes"), ([80, 40], 480, "ascending"),
                                ([40, 40], 480, "distinct"),
                                ([40], 20, "--test-specimens: whole shards of 40")):
        with pytest.raises(ValueError, match=needle):
            plan_shards(scene, sizes, test)
    with pytest.raises(ValueError, match=r"--scene: samples \(481\) must fill its shards"):
        plan_shards(dataclasses.replace(scene, samples=481), [40], 40)
    with pytest.raises(ValueError, match="--scene: a texture scene of the thesis grades"):
        plan_shards(load_scene(ROOT / "configs/scenes/texture_fepa.yaml"), [40], 40)


def test_the_sets_are_the_scene_but_name_seed_samples_and_shards_and_the_smaller_is_nested():
    base = load_scene(SCENE)
    small = split_scenes(base, plan_shards(base, [40, 80], 40))
    big = split_scenes(base, plan_shards(base, [40, 640], 120))
    assert (big["train"].seed, big["test"].seed) == (base.seed, base.seed + 1)
    assert (big["train"].samples, big["train"].shards) == (16 * 80, 16)
    assert (big["test"].samples, big["test"].shards) == (3 * 80, 3)
    for scene in (*small.values(), *big.values()):
        assert dataclasses.replace(scene, name=base.name, seed=base.seed, samples=base.samples,
                                   shards=base.shards) == base
    # shard k is drawn from (seed, k) with as many records: the small set's are the big one's
    assert dataclasses.replace(big["train"], samples=small["train"].samples,
                               shards=small["train"].shards) == small["train"]


def test_recipes_are_read_from_the_training_configs_and_bad_ones_are_refused(tmp_path):
    full = read_recipe(RECIPES[1])
    assert (full.model["hidden"], full.batch, full.epochs, full.seed) == ([256, 256], 128, 60, 0)
    assert read_recipe(RECIPES[0], epochs=3).epochs == 3
    assert full.name == "texture_full ([256, 256], batch 128)"
    with pytest.raises(ValueError, match="model.class_path must be wtml.decoders.texture"):
        read_recipe(ROOT / "configs/fluid.yaml")
    cfg = yaml.safe_load(Path(RECIPES[0]).read_text())
    for edit, needle in ((lambda c: c["data"]["init_args"].pop("batch_size"),
                          "data.init_args.batch_size must be a whole number"),
                         (lambda c: c["trainer"].update(max_epochs=0), "trainer.max_epochs"),
                         (lambda c: c.pop("seed_everything"), "seed_everything"),
                         (lambda c: c["model"]["init_args"].update(hidden=[0]),
                          "model.hidden must be a list of layer widths"),
                         (lambda c: c["model"]["init_args"].update(width=3),
                          "model.init_args: .*width")):
        bad = json.loads(json.dumps(cfg))
        edit(bad)
        path = tmp_path / "bad.yaml"
        path.write_text(yaml.safe_dump(bad))
        with pytest.raises(ValueError, match=needle):
            read_recipe(path)


def test_bad_options_are_refused_before_any_work(tmp_path, capsys):
    other = tmp_path / "other.yaml"
    cfg = yaml.safe_load(Path(RECIPES[0]).read_text())
    cfg["model"]["init_args"]["band_frame_s"] = 0.02
    other.write_text(yaml.safe_dump(cfg))
    work = tmp_path / "work"
    for kwargs, needle in (({"workers": 0}, "--workers"), ({"deadline_s": -1.0}, "--deadline-s"),
                           ({"oracle_draws": 5}, "--oracle-draws"),
                           ({"minirocket_kernels": 10}, "--minirocket-kernels"),
                           ({"minirocket_sizes": [80]}, r"--minirocket-sizes: .* each one of "
                                                        r"--sizes \(40\), got \[80\]"),
                           ({"recipes": []}, "--recipes: at least one"),
                           ({"recipes": [RECIPES[0], str(other)]},
                            "--recipes: .*band_frame_s .* share one feature layer")):
        with pytest.raises(ValueError, match=needle):
            run_scale(tmp_path / "out", sizes=[40], test_specimens=40, work=work, **kwargs)
    assert not work.exists()
    for argv, needle in ((["--sizes", "40,x"], "argument --sizes: expects distinct whole"),
                         (["--sizes", "80,40"], "ascending"),
                         (["--test-specimens", "0"], "argument --test-specimens"),
                         (["--workers", "0"], "argument --workers"),
                         (["--deadline-s", "-5"], "argument --deadline-s"),
                         (["--minirocket-sizes", "x"], "argument --minirocket-sizes"),
                         (["--minirocket-kernels", "83"], "argument --minirocket-kernels")):
        with pytest.raises(SystemExit) as done:
            main(["bench", "texture-scale", *argv])
        err = capsys.readouterr().err.strip()
        assert done.value.code == 2 and len(err.splitlines()) == 1 and needle in err, err
    assert main(["bench", "texture-scale", "--sizes", "100", "--work", str(work)]) == 2
    assert "--sizes: whole shards of 40 specimens" in capsys.readouterr().err


def test_the_fast_loop_has_the_decoders_loss_on_the_same_crops(tiny):
    """The features of crops drawn ahead (as the bench's banks hold them) give
    TextureDecoder.loss's value for the same crops; other crops do not."""
    scene_path, work, *_ = tiny
    scene = load_scene(scene_path)
    folder = next(p for p in work.iterdir() if p.name.startswith("train-") and "peer" not in
                  p.name)
    e, i, t_re, t_im, y = task_tensors(load_shards(folder, [0]), "texture")
    decoder = read_recipe(RECIPES[0]).decoder()
    decoder.net = decoder.build_net(scene, e, i, t_re, t_im, y)
    decoder.train()
    n = decoder.window(scene)
    torch.manual_seed(3)
    want = decoder.loss((e, i, t_re, t_im, y))
    torch.manual_seed(3)
    start = torch.randint(0, e.shape[1] - n + 1, (len(e),))
    x = features_at(decoder.net.features, (e, i, t_re, t_im), torch.arange(len(e)), start, n,
                    chunk=3)
    torch.testing.assert_close(decoder.feature_loss(x, y), want, rtol=1e-5, atol=1e-6)
    other = features_at(decoder.net.features, (e, i, t_re, t_im), torch.arange(len(e)),
                        torch.zeros(len(e), dtype=torch.long), n, chunk=len(e))
    assert (other - x).abs().mean() > 1e-2 * x.abs().mean()
    with pytest.raises(AssertionError):  # beyond the tolerance the same crops meet
        torch.testing.assert_close(decoder.feature_loss(other, y), want, rtol=1e-5, atol=1e-6)
    # a shard's bank: its first windows and, per epoch, the crops of SeedSequence([seed, k])
    bank = shard_bank(decoder.net.features, (e, i, t_re, t_im), 0, n, 2, chunk=4)
    torch.testing.assert_close(bank["first"], other)
    assert bank["crops"].shape == (2, len(e), decoder.net.features.n_features)
    again = shard_bank(decoder.net.features, (e, i, t_re, t_im), 0, n, 2, chunk=7)
    torch.testing.assert_close(again["crops"], bank["crops"])
    assert not torch.allclose(shard_bank(decoder.net.features, (e, i, t_re, t_im), 1, n, 2,
                                         chunk=4)["crops"], bank["crops"])


def test_a_tiny_run_reports_every_row_the_differences_and_the_oracles(tiny):
    _, _, one, _, _ = tiny
    s = json.loads((one / "summary.json").read_text())
    assert (one / "scale.png").stat().st_size > 10_000
    assert s["plan"]["sizes"] == {"5": 1, "10": 2} and s["plan"]["test_shards"] == 2
    assert (s["test_windows"], s["test_specimens"]) == (40, 10)  # 20 records of 2 windows
    rows = s["rows"]
    assert [(r["method"], r["specimens"]) for r in rows] == [
        (m, n) for n in SIZES for m in ("band-power peer", "texture ([64, 64], batch 32)",
                                        "texture_full ([256, 256], batch 128)")]
    for r in rows:
        assert r["status"] == "done" and 0 <= r["interval"][0] <= r["accuracy"] <= \
            r["interval"][1] <= 1
        assert sum(map(sum, r["confusion"])) == 40
    decoders = [r for r in rows if r["kind"] == "decoder"]
    assert [r["train_records"] for r in decoders] == [10, 10, 20, 20]
    assert [r["steps"] for r in decoders] == [2, 2, 2, 2]  # 2 epochs of one batch
    assert [r["train_windows"] for r in rows if r["kind"] == "peer"] == [20, 40]
    names = [d["name"] for d in s["differences"]]
    assert names == [
        "texture ([64, 64], batch 32) minus the peer, 5 specimens",
        "texture_full ([256, 256], batch 128) minus the peer, 5 specimens",
        "band-power peer, 10 minus 5 specimens",
        "texture ([64, 64], batch 32) minus the peer, 10 specimens",
        "texture ([64, 64], batch 32), 10 minus 5 specimens",
        "texture_full ([256, 256], batch 128) minus the peer, 10 specimens",
        "texture_full ([256, 256], batch 128), 10 minus 5 specimens"]
    for o in (s["oracle"], s["grain_oracle"]):
        assert o["n"] == 500 and 0.5 < o["accuracy"] <= 1
    report = (one / "report.md").read_text()
    for needle in ("| band-power peer | 10 | 40 windows |", "| texture_full ([256, 256], "
                   "batch 128) | 5 | 10 records | 2 |", "amplitude oracle (500 draws",
                   "every-grain oracle", "minus the peer, 10 specimens", "4 shards made",
                   "Plot: scale.png."):
        assert needle in report, needle
    from wtml.bench.texture_scale import _report

    for cores, word in ((1, "1 core;"), (16, "16 cores;")):  # not "1 cores"
        assert word in _report(s | {"machine": s["machine"] | {"cores": cores}})


def test_a_second_run_keeps_the_complete_shards_and_gives_the_same_answers(tiny):
    scene, work, one, two, stamps = tiny
    first, second = (json.loads((d / "summary.json").read_text()) for d in (one, two))
    assert (first["generation"]["made"], first["generation"]["kept"]) == (4, 0)
    assert (second["generation"]["made"], second["generation"]["kept"]) == (0, 4)
    assert {p: p.stat().st_mtime_ns for p in work.rglob("shard-*")} == stamps
    for a, b in zip(first["rows"], second["rows"], strict=True):
        assert (a["accuracy"], a["confusion"]) == (b["accuracy"], b["confusion"])
    # a deadline already passed: every row is skipped, and reported so
    report = run_scale(one.parent / "late", scene=scene, sizes=SIZES, test_specimens=10,
                       recipes=RECIPES, workers=1, work=work, deadline_s=1e-3, epochs=2,
                       oracle_draws=500)
    late = json.loads((one.parent / "late" / "summary.json").read_text())
    assert {r["status"] for r in late["rows"]} == {"skipped: the deadline had passed"}
    assert late["differences"] == [] and report.count("skipped: the deadline") == 6


def _windows(folder: Path, shards: int, n: int) -> tuple[np.ndarray, ...]:
    """Every whole window of n samples of the first shards in folder, record by record: e, i
    (m, n), grade and specimen (m,)."""
    data = load_shards(folder, list(range(shards)))
    per = data["e"].shape[1] // n
    e, i = (data[key][:, :per * n].reshape(-1, n) for key in ("e", "i"))
    return e, i, *(np.repeat(data[key], per) for key in ("grade", "specimen"))


def test_the_minirocket_rows_are_minirocket_fitted_on_the_same_windows(tiny):
    """--minirocket-sizes 10 on the tiny plan: one MiniRocket row, at 10 specimens, whose
    scores are those of MiniRocketPeer fitted directly on every whole window of the first two
    training shards and scored on every held-out window; the decoder minus MiniRocket there
    and nowhere else; the decoder's rows as without MiniRocket."""
    scene, work, one, _, _ = tiny
    out = one.parent / "minirocket"
    report = run_scale(out, scene=scene, sizes=SIZES, test_specimens=10, recipes=RECIPES[:1],
                       workers=1, work=work, epochs=2, oracle_draws=500,
                       minirocket_sizes=[10], minirocket_kernels=84)
    s = json.loads((out / "summary.json").read_text())
    decoder = "texture ([64, 64], batch 32)"
    assert [(r["method"], r["specimens"]) for r in s["rows"]] == [
        ("band-power peer", 5), (decoder, 5), ("band-power peer", 10), ("MiniRocket", 10),
        (decoder, 10)]
    assert s["minirocket"] == {"sizes": [10], "kernels": 84}
    row = s["rows"][3]
    assert (row["kind"], row["status"], row["kernels"], row["train_windows"]) == (
        "minirocket", "done", 84, 40)
    assert row["fit_s"] > 0 and row["predict_s"] > 0
    folders = {p.name.split("-")[0]: p for p in work.iterdir() if "peer" not in p.name}
    n = read_recipe(RECIPES[0]).decoder().window(load_scene(scene))
    e, i, grade, _ = _windows(folders["train"], 2, n)
    te, ti, test_grade, test_specimen = _windows(folders["test"], 2, n)
    pred = MiniRocketPeer(84).fit(e, i, grade).predict(te, ti)["grade"]
    want = grade_scores(pred, test_grade, test_specimen)
    for key in ("accuracy", "interval", "confusion", "p320_as_p280", "p280_as_p320"):
        assert row[key] == (list(want[key]) if key == "interval" else want[key]), key
    first = json.loads((one / "summary.json").read_text())
    for a, b in zip([r for r in first["rows"] if r["method"] == decoder],
                    [r for r in s["rows"] if r["method"] == decoder], strict=True):
        assert (a["accuracy"], a["confusion"]) == (b["accuracy"], b["confusion"])
    diffs = {d["name"]: d for d in s["differences"]}
    assert [name for name in diffs if "MiniRocket" in name] == [
        f"{decoder} minus MiniRocket, 10 specimens"]
    d = diffs[f"{decoder} minus MiniRocket, 10 specimens"]
    assert d["difference"] == pytest.approx(s["rows"][4]["accuracy"] - row["accuracy"])
    assert d["interval"][0] <= d["difference"] <= d["interval"][1]
    for needle in ("| MiniRocket | 10 | 40 windows | 84 kernels |",
                   f"| {decoder} minus MiniRocket, 10 specimens |",
                   "MiniRocket: aeon's MiniRocketClassifier (`MiniRocketPeer`, 84 kernels)"):
        assert needle in report, needle
